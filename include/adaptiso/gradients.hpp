// adaptiso/gradients.hpp — vertex gradients (Lürig & Ertl §2.3) and the error of the grid's
// piecewise-linear reconstruction.
//
// Per vertex, the least-squares fit g(x,y,z) = a + b·x + c·y + d·z over the vertex and its
// edge-connected neighbours, solved by SVD (Eigen); the gradient is (b, c, d) in value units per
// physical unit, grid frame. A linear field is reproduced exactly (to rounding). When the
// neighbourhood is degenerate (all points coplanar or collinear — possible on the volume's faces),
// the SVD's minimum-norm solution is used: the gradient's component normal to that plane, which
// the data cannot determine, is set to zero, and the in-plane part is still the best fit.
#pragma once
#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"
#include "adaptiso/tetrahedralize.hpp"

namespace adaptiso {

// Fills grid.gradients (parallel over vertices).
void compute_gradients(TetGrid& grid, const VertexRings& rings, const Progress& progress = {});

struct ReconstructionError {
  double max = 0, rms = 0;
  std::int64_t voxels = 0;  // voxels evaluated (every voxel of the volume, once)
};
// Linear interpolation in the tetrahedron that holds each original voxel, against its value.
// Exact integer containment tests in index space; each voxel is evaluated once.
ReconstructionError piecewise_linear_error(const Volume& v, const TetGrid& grid, const Progress& progress = {});

}  // namespace adaptiso
