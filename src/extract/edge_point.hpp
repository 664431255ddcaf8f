// Where a surface vertex goes on a cut edge, shared by marching cubes and marching tetrahedra so
// both follow the same conventions (extractor.hpp, marching_cubes.hpp).
#pragma once
#include <array>
#include <cmath>

#include "adaptiso/volume.hpp"

namespace adaptiso::detail {

// Cut points stay this fraction of an edge away from its ends, so vertices lying exactly on the
// iso-value do not collapse triangles.
constexpr double kEdgeMargin = 1.0 / 1024;

// A grid-frame point and (unnormalised) normal to float world coordinates and a unit normal:
// world = origin + D · p with D the row-major direction matrix (columns = index axes).
inline void to_world(const Vec3& origin, const std::array<double, 9>& D, const double p[3], const double n[3], std::array<float, 3>& wp,
                     std::array<float, 3>& wn) {
  const Vec3 w = grid_to_world(origin, D, {p[0], p[1], p[2]});
  const Vec3 m = grid_to_world({0, 0, 0}, D, {n[0], n[1], n[2]});  // a direction: no origin
  double len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
  if (!(len > 0)) len = 1;
  wp = {float(w[0]), float(w[1]), float(w[2])};
  wn = {float(m[0] / len), float(m[1] / len), float(m[2] / len)};
}

}  // namespace adaptiso::detail
