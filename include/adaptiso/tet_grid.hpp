// adaptiso/tet_grid.hpp — the tetrahedral grid that extraction works on (Lürig & Ertl §2.2–2.3),
// as flat arrays. Both grid builders produce it: the paper's Delaunay grid (delaunay.hpp) and the
// longest-edge bisection grid (bisection.hpp).
//
// Vertex v sits at voxel index ijk[v] of the source volume; its grid-frame position is
// spacing ⊙ ijk[v] (physical units, before the volume's rotation and origin, see volume.hpp), its
// scalar is values[v] (the voxel's value, exact) and gradients[v] the gradient in value units per
// physical unit (grid frame). tets[t] holds 4 vertex indices, positively oriented in the grid frame
// (positive volume), with no zero-volume tetrahedron; together they tile the volume's box exactly.
// Vertices are numbered in ascending linear voxel index (x fastest).
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"

namespace adaptiso {

// What the grid was built from and how (kept with the grid, and in the grid file).
struct GridSource {
  Dims dims{};
  Vec3 spacing{1, 1, 1};
  Vec3 origin{0, 0, 0};
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};
  std::string type;         // source element type name
  double min = 0, max = 0;  // source value range
  std::string method;       // how the vertices were chosen: "bisection", or the reduction method
  double max_error = 0;     // the absolute error bound asked for (data units)
  double threshold = 0;     // structural analysis: the absolute gradient threshold used
  std::string file;         // the source's file name (no folders), informational
};

// The geometry and value range of a volume; method, bounds and file are left for the builder.
GridSource grid_source(const Volume& v, const ValueRange& range);

struct TetGrid {
  GridSource source;
  std::vector<std::array<std::uint32_t, 3>> ijk;
  std::vector<double> values;
  std::vector<std::array<float, 3>> gradients;
  std::vector<std::array<std::uint32_t, 4>> tets;

  std::size_t vertex_count() const { return ijk.size(); }
  std::size_t tet_count() const { return tets.size(); }
  Vec3 position(std::uint32_t v) const {
    return {source.spacing[0] * ijk[v][0], source.spacing[1] * ijk[v][1], source.spacing[2] * ijk[v][2]};
  }
  Vec3 world_position(std::uint32_t v) const { return grid_to_world(source.origin, source.direction, position(v)); }
};

}  // namespace adaptiso
