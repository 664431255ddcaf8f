// Whether a triangle's corners cover it within a distance: the distance query's triangles whose
// corners lie on the grid's surface need no probe when they do (distance_query.cpp).
#pragma once
#include <algorithm>
#include <array>

namespace adaptiso::detail {

// Does every point of triangle abc lie within √d2 of a corner? The farthest point from the corners
// is the circumcentre when the triangle is acute (radius R = abc / 4·area), and otherwise lies on
// an edge, at most half the longest edge from that edge's nearer end. Both are at most L/√3 for a
// longest edge L (the equilateral triangle's R), the bound the tests used before: a right-angled
// cut triangle, common in the lattice, is covered up to L = 2·√d2 instead of √3·√d2.
inline bool corners_cover(const std::array<double, 3>& a, const std::array<double, 3>& b, const std::array<double, 3>& c, double d2) {
  double e[3];
  std::array<double, 3> u, v;
  for (int k = 0; k < 3; ++k) u[k] = b[k] - a[k], v[k] = c[k] - a[k];
  e[0] = (u[0] - v[0]) * (u[0] - v[0]) + (u[1] - v[1]) * (u[1] - v[1]) + (u[2] - v[2]) * (u[2] - v[2]);  // |bc|²
  e[1] = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];                                                        // |ca|²
  e[2] = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];                                                        // |ab|²
  const double longest = std::max({e[0], e[1], e[2]});
  if (2 * longest >= e[0] + e[1] + e[2]) return longest <= 4 * d2;  // not acute: half the longest edge
  const std::array<double, 3> n{u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
  const double n2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];  // (2·area)²
  return n2 > 0 && e[0] * e[1] * e[2] <= 4 * n2 * d2;         // R² = |bc|²|ca|²|ab|² / 4(2·area)²
}

}  // namespace adaptiso::detail
