// Delaunay tetrahedrization — Lürig & Ertl §2.2. The paper's own O(n²) triangulator needed a
// workaround for coplanar points; CGAL's incremental Delaunay with exact predicates and symbolic
// perturbation handles the lattice's coplanar and cospherical sets by construction.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.2.
// - The CGAL 3D Triangulations package (Jamin, Pion, Teillaud): incremental Delaunay with exact
//   predicates and symbolic perturbation.
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "adaptiso/delaunay.hpp"
#include "util/memory.hpp"

namespace adaptiso {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;

template <class Tag>
struct DT {
  using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::uint32_t, K>;
  using Cb = CGAL::Delaunay_triangulation_cell_base_3<K>;
  using Tds = CGAL::Triangulation_data_structure_3<Vb, Cb, Tag>;
  using Type = CGAL::Delaunay_triangulation_3<K, Tds>;
};

template <class Tri>
void extract(Tri& dt, TetGrid& grid) {
  if (dt.dimension() < 3)
    throw InputError(
        fmt::format("the {} kept vertices are coplanar (is a dimension 1?): a flat volume has no tetrahedra", grid.ijk.size()));
  grid.tets.clear();
  grid.tets.reserve(dt.number_of_finite_cells());
  for (auto c = dt.finite_cells_begin(); c != dt.finite_cells_end(); ++c)
    grid.tets.push_back({c->vertex(0)->info(), c->vertex(1)->info(), c->vertex(2)->info(), c->vertex(3)->info()});
}

// Of the 12 even permutations of a tetrahedron's vertices (those keeping its orientation), the
// lexicographically smallest.
std::array<std::uint32_t, 4> canonical(const std::array<std::uint32_t, 4>& t) {
  static constexpr int even[12][4] = {{0, 1, 2, 3}, {0, 2, 3, 1}, {0, 3, 1, 2}, {1, 0, 3, 2}, {1, 2, 0, 3}, {1, 3, 2, 0},
                                      {2, 0, 1, 3}, {2, 1, 3, 0}, {2, 3, 0, 1}, {3, 0, 2, 1}, {3, 1, 0, 2}, {3, 2, 1, 0}};
  std::array<std::uint32_t, 4> best = t;
  for (const auto& p : even) {
    const std::array<std::uint32_t, 4> q{t[p[0]], t[p[1]], t[p[2]], t[p[3]]};
    best = std::min(best, q);
  }
  return best;
}

}  // namespace

Vec3 delaunay_metric(const Vec3& spacing) {
  const double smallest = std::min({spacing[0], spacing[1], spacing[2]});
  Vec3 scale;
  for (int a = 0; a < 3; ++a) scale[a] = std::ldexp(std::round(std::ldexp(spacing[a] / smallest, 20)), -20);
  return scale;
}

TetGrid delaunay_grid(const Volume& v, const ValueRange& range, const std::vector<std::int64_t>& kept, const DelaunayOptions& options,
                      const Progress& progress) {
  if (kept.size() >= std::numeric_limits<std::uint32_t>::max())
    throw OptionError("max_error", fmt::format("{} kept vertices exceed the grid's 32-bit vertex indices; raise it", kept.size()));
  // CGAL's triangulation holds about 6.5 cells a point (bench_tetrahedralize): some 400 bytes a
  // point at its peak, and about 8 µs a point on one core.
  const std::size_t n = kept.size();
  detail::check_memory(
      n * std::uint64_t{400},
      fmt::format("the Delaunay tetrahedrization of {} kept vertices (about {})", n, detail::duration_text(static_cast<double>(n) * 8e-6)),
      "max_error", "raise it, or use the bisection grid");
  TetGrid grid;
  grid.source = grid_source(v, range);
  grid.ijk.resize(n);
  grid.values.resize(n);
  // Lattice coordinates in exact arithmetic: the index times the spacing's ratio to the smallest
  // spacing rounded to 20 binary digits, a product a double holds exactly. Coplanar lattice points
  // then stay exactly coplanar (rounded physical coordinates made them slightly non-coplanar, and
  // the triangulation built flat slivers between them); the metric differs from the true spacing
  // by at most 2^-20 relative.
  const Vec3 scale = delaunay_metric(v.spacing);
  std::vector<std::pair<K::Point_3, std::uint32_t>> pts(n);
  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
    std::int64_t idx = kept[i];
    std::uint32_t x = static_cast<std::uint32_t>(idx % v.dims[0]), y = static_cast<std::uint32_t>((idx / v.dims[0]) % v.dims[1]),
                  z = static_cast<std::uint32_t>(idx / (v.dims[0] * v.dims[1]));
    grid.ijk[i] = {x, y, z};
    grid.values[i] = v.at(idx);
    pts[i] = {K::Point_3(scale[0] * x, scale[1] * y, scale[2] * z), static_cast<std::uint32_t>(i)};
  });
  report(progress, "tetrahedralize", 0.05);
  if (options.parallel) {
    using Tri = typename DT<CGAL::Parallel_tag>::Type;
    CGAL::Bbox_3 box(0, 0, 0, scale[0] * (v.dims[0] - 1), scale[1] * (v.dims[1] - 1), scale[2] * (v.dims[2] - 1));
    typename Tri::Lock_data_structure locks(box, 50);
    Tri dt(pts.begin(), pts.end(), &locks);  // range insertion sorts spatially (Hilbert order)
    report(progress, "tetrahedralize", 0.9);
    extract(dt, grid);
  } else {
    using Tri = typename DT<CGAL::Sequential_tag>::Type;
    Tri dt(pts.begin(), pts.end());
    report(progress, "tetrahedralize", 0.9);
    extract(dt, grid);
  }
  // Deterministic order (CGAL's cell and vertex order depends on insertion history): each
  // tetrahedron as the smallest of its 12 orientation-preserving vertex orders, then sorted.
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, grid.tets.size(), 1 << 14), [&](const auto& r) {
    for (std::size_t t = r.begin(); t < r.end(); ++t) grid.tets[t] = canonical(grid.tets[t]);
  });
  tbb::parallel_sort(grid.tets.begin(), grid.tets.end(), [](const auto& a, const auto& b) {
    auto ka = std::min({a[0], a[1], a[2], a[3]}), kb = std::min({b[0], b[1], b[2], b[3]});
    return ka != kb ? ka < kb : a < b;
  });
  report(progress, "tetrahedralize", 1.0);
  return grid;
}

}  // namespace adaptiso
