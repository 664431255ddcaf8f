// adaptiso/delaunay.hpp — the paper's grid: Delaunay tetrahedrization of the kept vertices
// (Lürig & Ertl §2.2).
//
// CGAL's Delaunay_triangulation_3 with exact predicates (Epick) on the voxel indices scaled by the
// spacing's ratios to the smallest spacing, each rounded to 20 binary digits (delaunay_metric): the
// coordinates are then exact, so coplanar lattice points stay exactly coplanar, and the metric is
// the grid frame's up to a relative 2^-20. Lattice input is full of coplanar and cospherical
// sets: exact predicates with CGAL's symbolic perturbation decide them the same way whatever the
// insertion order, so the grid is unique (the same for any thread count, tetrahedra in a canonical
// order), and finite Delaunay cells never have zero volume.
// Throws InputError when the kept vertices are coplanar (a volume with a dimension of 1), and
// OptionError("max_error") when they exceed the grid's 32-bit vertex indices.
#pragma once
#include <cstdint>
#include <vector>

#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

// The scale of each index axis in the triangulation (see above).
Vec3 delaunay_metric(const Vec3& spacing);

struct DelaunayOptions {
  bool parallel = true;  // CGAL Parallel_tag triangulation (TBB): 1.5x faster on 2 cores (bench_tetrahedralize)
};

// The grid of the kept voxels (sorted linear indices, see reduce.hpp): vertex v is kept[v], with
// its value; gradients are left empty (gradients.hpp fills them). grid.source describes the volume.
TetGrid delaunay_grid(const Volume& v, const ValueRange& range, const std::vector<std::int64_t>& kept, const DelaunayOptions& options = {},
                      const Progress& progress = {});

}  // namespace adaptiso
