// Delaunay tetrahedrization — Lürig & Ertl §2.2. The paper's own O(n²) triangulator needed a
// workaround for coplanar points; CGAL's incremental Delaunay with exact predicates and symbolic
// perturbation handles the lattice's coplanar and cospherical sets by construction.
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <fmt/format.h>
#include <numeric>

#include "adaptiso/tetrahedralize.hpp"

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
    throw InputError(fmt::format("the {} kept vertices are coplanar (is a dimension 1?): a flat volume has no tetrahedra",
                                 grid.ijk.size()));
  grid.tets.clear();
  grid.tets.reserve(dt.number_of_finite_cells());
  for (auto c = dt.finite_cells_begin(); c != dt.finite_cells_end(); ++c)
    grid.tets.push_back({c->vertex(0)->info(), c->vertex(1)->info(), c->vertex(2)->info(), c->vertex(3)->info()});
}

}  // namespace

void tetrahedralize(const Volume& v, const std::vector<std::int64_t>& kept, TetGrid& grid,
                    const TetrahedralizeOptions& options, const Progress& progress) {
  if (kept.size() >= std::numeric_limits<std::uint32_t>::max())
    throw InputError(fmt::format("{} kept vertices exceed the grid's 32-bit vertex indices; raise --max-error", kept.size()));
  const std::size_t n = kept.size();
  grid.ijk.resize(n);
  grid.values.resize(n);
  std::vector<std::pair<K::Point_3, std::uint32_t>> pts(n);
  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
    std::int64_t idx = kept[i];
    std::uint32_t x = static_cast<std::uint32_t>(idx % v.dims[0]), y = static_cast<std::uint32_t>((idx / v.dims[0]) % v.dims[1]),
                  z = static_cast<std::uint32_t>(idx / (v.dims[0] * v.dims[1]));
    grid.ijk[i] = {x, y, z};
    grid.values[i] = v.at(idx);
    pts[i] = {K::Point_3(v.spacing[0] * x, v.spacing[1] * y, v.spacing[2] * z), static_cast<std::uint32_t>(i)};
  });
  report(progress, "tetrahedralize", 0.05);
  if (options.parallel) {
    using Tri = typename DT<CGAL::Parallel_tag>::Type;
    CGAL::Bbox_3 box(0, 0, 0, v.spacing[0] * (v.dims[0] - 1), v.spacing[1] * (v.dims[1] - 1), v.spacing[2] * (v.dims[2] - 1));
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
  // Deterministic order (CGAL's cell order depends on insertion history): sort by vertex ids.
  tbb::parallel_sort(grid.tets.begin(), grid.tets.end(), [](const auto& a, const auto& b) {
    auto ka = std::min({a[0], a[1], a[2], a[3]}), kb = std::min({b[0], b[1], b[2], b[3]});
    return ka != kb ? ka < kb : a < b;
  });
  report(progress, "tetrahedralize", 1.0);
}

VertexRings vertex_rings(const TetGrid& g) {
  const std::size_t n = g.vertex_count();
  VertexRings r;
  r.offsets.assign(n + 1, 0);
  // Count directed edge slots per vertex (with duplicates), fill, then sort and unique per vertex.
  for (const auto& t : g.tets)
    for (int i = 0; i < 4; ++i) r.offsets[t[i] + 1] += 3;
  for (std::size_t i = 0; i < n; ++i) r.offsets[i + 1] += r.offsets[i];
  std::vector<std::uint32_t> nb(r.offsets[n]);
  std::vector<std::uint64_t> fill(r.offsets.begin(), r.offsets.end() - 1);
  for (const auto& t : g.tets)
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        if (i != j) nb[fill[t[i]]++] = t[j];
  std::vector<std::uint64_t> counts(n);
  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t v) {
    auto b = nb.begin() + static_cast<long>(r.offsets[v]), e = nb.begin() + static_cast<long>(r.offsets[v + 1]);
    std::sort(b, e);
    counts[v] = static_cast<std::uint64_t>(std::unique(b, e) - b);
  });
  r.neighbours.reserve(std::accumulate(counts.begin(), counts.end(), std::uint64_t{0}));
  std::vector<std::uint64_t> off(n + 1, 0);
  for (std::size_t v = 0; v < n; ++v) {
    r.neighbours.insert(r.neighbours.end(), nb.begin() + static_cast<long>(r.offsets[v]),
                        nb.begin() + static_cast<long>(r.offsets[v] + counts[v]));
    off[v + 1] = r.neighbours.size();
  }
  r.offsets = std::move(off);
  return r;
}

}  // namespace adaptiso
