// adaptiso/gradients.hpp — vertex gradients (Lürig & Ertl §2.3) and the error of the grid's
// piecewise-linear reconstruction.
//
// Two ways to get a gradient per grid vertex, in value units per physical unit (grid frame):
// - least squares (the paper's): the fit g(x,y,z) = a + b·x + c·y + d·z over the vertex and its
//   edge-connected neighbours, solved by SVD (Eigen). A linear field is reproduced exactly (to
//   rounding). When the neighbourhood is degenerate (all points coplanar or collinear — possible
//   on the volume's faces), the SVD's minimum-norm solution is used: the gradient's component
//   normal to that plane, which the data cannot determine, is set to zero.
// - central differences of the volume at the vertex's voxel (one-sided at the border; zero along
//   an axis of one voxel): the natural choice when every grid vertex is a voxel and the volume is
//   at hand, and much cheaper.
#pragma once
#include <cstdint>
#include <vector>

#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

// Sorted, unique vertex neighbours of every vertex (edges of the tetrahedra), as CSR arrays.
struct VertexRings {
  std::vector<std::uint64_t> offsets;  // size n+1
  std::vector<std::uint32_t> neighbours;
};
VertexRings vertex_rings(const TetGrid& grid);

// Fills grid.gradients by least squares over each vertex's ring (parallel over vertices).
void least_squares_gradients(TetGrid& grid, const Progress& progress = {});
// Fills grid.gradients by central differences of the volume the grid was built from.
void central_difference_gradients(TetGrid& grid, const Volume& v, const Progress& progress = {});

struct ReconstructionError {
  double max = 0, rms = 0;
  std::int64_t voxels = 0;  // voxels evaluated (every voxel of the volume, once)
};
// Linear interpolation in the tetrahedron that holds each original voxel, against its value.
// Exact integer containment tests in index space; each voxel is evaluated once.
ReconstructionError piecewise_linear_error(const Volume& v, const TetGrid& grid, const Progress& progress = {});

}  // namespace adaptiso
