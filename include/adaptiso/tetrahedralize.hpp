// adaptiso/tetrahedralize.hpp — Delaunay tetrahedrization of the kept vertices (Lürig & Ertl §2.2).
//
// CGAL's Delaunay_triangulation_3 with exact predicates (Epick), in the grid frame
// (spacing ⊙ index, so anisotropic spacing is respected); points are inserted spatially sorted.
// Lattice input is full of coplanar and cospherical sets: exact predicates with CGAL's symbolic
// perturbation decide them consistently, and finite Delaunay cells never have zero volume.
// Throws InputError when the kept vertices are coplanar (a volume with a dimension of 1).
#pragma once
#include <cstdint>
#include <vector>

#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

struct TetrahedralizeOptions {
  bool parallel = true;  // CGAL Parallel_tag triangulation (TBB): 1.5x faster on 2 cores (bench_tetrahedralize)
};

// Fills grid.ijk, grid.values and grid.tets from the kept voxel indices (grid.source must hold the
// volume's metadata). Vertex v of the grid is kept[v].
void tetrahedralize(const Volume& v, const std::vector<std::int64_t>& kept, TetGrid& grid,
                    const TetrahedralizeOptions& options = {}, const Progress& progress = {});

// Sorted, unique vertex neighbours of every vertex (edges of the tetrahedra), as CSR arrays.
struct VertexRings {
  std::vector<std::uint64_t> offsets;  // size n+1
  std::vector<std::uint32_t> neighbours;
};
VertexRings vertex_rings(const TetGrid& grid);

}  // namespace adaptiso
