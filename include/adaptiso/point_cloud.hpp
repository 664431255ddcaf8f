// adaptiso/point_cloud.hpp — the kept vertices as a PLY point cloud (what the paper's Figures 1
// and 3 show): binary little-endian, per vertex float x,y,z in world coordinates, int i,j,k the
// voxel index, and float value. Written atomically.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"

namespace adaptiso {

void write_points_ply(const std::string& path, const Volume& v, const std::vector<std::int64_t>& kept);

// The vertices of a tetrahedral grid, same layout, in the grid's vertex order: those inside the
// volume's box (a padded lattice's copies of the last slices are left out, tet_grid.hpp).
struct TetGrid;
void write_points_ply(const std::string& path, const TetGrid& grid);

}  // namespace adaptiso
