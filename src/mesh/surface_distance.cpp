// Symmetric surface distance (see surface_distance.hpp).
//
// This work is based on:
// - Cignoni, Rocchini, Scopigno. Metro: measuring error on simplified surfaces. Computer
//   Graphics Forum, 1998 (distances from dense samples of one surface to the other).
#include "adaptiso/surface_distance.hpp"

#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>

#include "adaptiso/error.hpp"
#include "mesh/triangle_tree.hpp"

namespace adaptiso {
namespace {

using K = detail::TreeKernel;
using Triangle = detail::TreeTriangle;
using Tree = detail::TriangleTree;
using detail::tree_point;

std::vector<Triangle> triangles(const Mesh& m) {
  std::vector<Triangle> t;
  t.reserve(m.triangle_count());
  for (const auto& q : m.triangles) {
    Triangle tri(tree_point(m.positions[q[0]]), tree_point(m.positions[q[1]]), tree_point(m.positions[q[2]]));
    if (!tri.is_degenerate()) t.push_back(tri);
  }
  return t;
}

// Area-uniform random points on `from` (seeded, so deterministic) and all its vertices.
std::vector<K::Point_3> samples(const Mesh& from, const std::vector<Triangle>& tris, const DistanceOptions& o) {
  std::vector<double> cumulative(tris.size());
  double total = 0;
  for (std::size_t i = 0; i < tris.size(); ++i) cumulative[i] = total += std::sqrt(tris[i].squared_area());
  const std::size_t n = std::min(o.max_samples, std::max(o.min_samples, 4 * tris.size()));
  std::vector<K::Point_3> pts;
  pts.reserve(n + from.vertex_count());
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(0, 1);
  for (std::size_t s = 0; s < n && total > 0; ++s) {
    const std::size_t i =
        std::min<std::size_t>(std::lower_bound(cumulative.begin(), cumulative.end(), u(rng) * total) - cumulative.begin(), tris.size() - 1);
    double r1 = std::sqrt(u(rng)), r2 = u(rng);
    const auto &a = tris[i][0], &b = tris[i][1], &c = tris[i][2];
    pts.emplace_back(a.x() * (1 - r1) + r1 * ((1 - r2) * b.x() + r2 * c.x()), a.y() * (1 - r1) + r1 * ((1 - r2) * b.y() + r2 * c.y()),
                     a.z() * (1 - r1) + r1 * ((1 - r2) * b.z() + r2 * c.z()));
  }
  for (const auto& p : from.positions) pts.push_back(tree_point(p));
  return pts;
}

// The points' indices along a Z-order curve of their bounding box (21 bits an axis), so that
// consecutive queries meet the same branches of the tree and each can start from the last one's
// answer.
std::vector<std::uint32_t> z_order(const std::vector<K::Point_3>& pts) {
  double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (const auto& p : pts)
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-300});
  auto spread = [](std::uint64_t x) {  // bit i of x to bit 3i
    x &= 0x1fffff;
    x = (x | x << 32) & 0x1f00000000ffffULL;
    x = (x | x << 16) & 0x1f0000ff0000ffULL;
    x = (x | x << 8) & 0x100f00f00f00f00fULL;
    x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
    return (x | x << 2) & 0x1249249249249249ULL;
  };
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(pts.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pts.size(), 1 << 14), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      std::uint64_t key = 0;
      for (int a = 0; a < 3; ++a) {
        const double t = (pts[i][a] - lo[a]) / extent;  // NaN (a NaN corner) or above 1 (an infinite extent) clamped
        key |= spread(static_cast<std::uint64_t>((t >= 0 ? std::min(t, 1.0) : 0.0) * double(0x1fffff))) << a;
      }
      keyed[i] = {key, static_cast<std::uint32_t>(i)};
    }
  });
  tbb::parallel_sort(keyed.begin(), keyed.end());  // unique keys (the index breaks ties): one order
  std::vector<std::uint32_t> order(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) order[i] = keyed[i].second;
  return order;
}

DistanceStats one_way(const Mesh& from, const std::vector<Triangle>& from_tris, const Tree& to, const DistanceOptions& o) {
  const auto pts = samples(from, from_tris, o);
  const auto order = z_order(pts);
  // Each point's distance lands at its own index, so the figures do not depend on the order. The
  // last point's nearest point bounds the next one's search (a hint); the first of a block searches
  // from scratch. 2.9x fewer seconds than unordered, unhinted queries on 2.1 M points (a noisy 41³
  // field's surface of 470 k triangles).
  std::vector<double> d(pts.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pts.size(), 4096), [&](const auto& r) {
    K::Point_3 hint = to.closest_point(pts[order[r.begin()]]);
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const K::Point_3& p = pts[order[i]];
      hint = to.closest_point(p, hint);
      d[order[i]] = std::sqrt(CGAL::squared_distance(p, hint));
    }
  });
  DistanceStats s;
  s.samples = d.size();
  double sum = 0, sum2 = 0;
  for (double x : d) sum += x, sum2 += x * x, s.max = std::max(s.max, x);
  s.mean = sum / double(d.size());
  s.rms = std::sqrt(sum2 / double(d.size()));
  auto k = d.begin() + static_cast<std::ptrdiff_t>(std::min(d.size() - 1, static_cast<std::size_t>(0.95 * double(d.size()))));
  std::nth_element(d.begin(), k, d.end());
  s.p95 = *k;
  return s;
}

}  // namespace

SurfaceDistance surface_distance(const Mesh& a, const Mesh& b, const DistanceOptions& o) {
  auto ta = triangles(a), tb = triangles(b);
  if (ta.empty() || tb.empty()) throw InputError("surface distance needs two meshes with triangles");
  Tree tree_a(ta.begin(), ta.end()), tree_b(tb.begin(), tb.end());
  // No k-d tree of the triangles' points for unhinted searches: only a block's first query has no
  // hint. Not building it: bunny against marching cubes, peak 744 -> 618 MB, the same figures.
  tree_a.do_not_accelerate_distance_queries();
  tree_b.do_not_accelerate_distance_queries();
  SurfaceDistance r;
  r.a_to_b = one_way(a, ta, tree_b, o);
  r.b_to_a = one_way(b, tb, tree_a, o);
  return r;
}

}  // namespace adaptiso
