// adaptiso/tet_grid.hpp — the tetrahedral grid that extraction works on (Lürig & Ertl §2.2–2.3),
// as flat arrays. Both grid builders produce it: the paper's Delaunay grid (delaunay.hpp) and the
// longest-edge bisection grid (bisection.hpp).
//
// Vertex v sits at voxel index ijk[v] of the source volume; its grid-frame position is
// spacing ⊙ ijk[v] (physical units, before the volume's rotation and origin, see volume.hpp), its
// scalar is values[v] (the voxel's value, exact) and gradients[v] the gradient in value units per
// physical unit (grid frame). tets[t] holds 4 vertex indices, positively oriented in the grid frame
// (positive volume), with no zero-volume tetrahedron; together they tile the lattice's box
// [0, source.dims − 1] exactly (the volume's, or a padded one: GridSource::volume_dims).
// Vertices are numbered in ascending linear voxel index (x fastest).
//
// Global lattice keys. Vertex ids (indices into ijk) are the grid's own; a lattice key names a
// vertex, or an edge, the same way in every grid built over the same volume's voxel lattice, so
// that bricks, ranks and queries can tell they hold the same one:
// - a vertex's key is its linear voxel index in the volume, i + X·(j + Y·k) for dims (X, Y, Z),
//   x fastest (ascending with the vertex ids of one grid);
// - an edge's key is its two endpoints' keys in canonical order, the smaller first, whichever way
//   the edge is walked or cut (the Extractor's vertex_edges keep below/above order and ids).
// A grid built from a brick of a larger volume (a sub-volume whose voxel (0, 0, 0) is voxel o of
// the whole) names its vertices in the whole volume's lattice: lattice_key(whole dims, ijk + o).
// Grids that share a face then give each vertex and edge of the face one key; whether they cut
// the face into the same triangles is their builders' matter, not the keys'.
#pragma once
#include <array>
#include <compare>
#include <cstdint>
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"

namespace adaptiso {

using LatticeKey = std::uint64_t;

struct LatticeEdge {
  LatticeKey lo = 0, hi = 0;  // lo ≤ hi (equal only for a degenerate edge, which no grid has)
  friend auto operator<=>(const LatticeEdge&, const LatticeEdge&) = default;
};

// The key of the voxel at (i, j, k) of a volume of these dims (see above). No check: (i, j, k) is
// the caller's to keep inside dims.
inline LatticeKey lattice_key(const Dims& dims, const std::array<std::uint32_t, 3>& voxel) {
  return voxel[0] + static_cast<LatticeKey>(dims[0]) * (voxel[1] + static_cast<LatticeKey>(dims[1]) * voxel[2]);
}

// The edge between two vertices, in canonical order.
inline LatticeEdge lattice_edge(LatticeKey a, LatticeKey b) { return a < b ? LatticeEdge{a, b} : LatticeEdge{b, a}; }

// What the grid was built from and how (kept with the grid, and in the grid file).
struct GridSource {
  Dims dims{};  // the lattice's: the grid's vertices lie in [0, dims − 1]
  // The volume's own dims, where they differ from the lattice's (zeros: the same). prepare() pads
  // a bisection grid's lattice past the volume's far faces with copies of its last slices
  // (bisection.hpp: bisection_lattice_dims), so the tetrahedra there need not be the finest; its
  // surfaces are clipped to the volume's box [0, volume_dims − 1] on every extraction route.
  Dims volume_dims{};
  Vec3 spacing{1, 1, 1};
  Vec3 origin{0, 0, 0};
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};
  std::string type;         // source element type name
  double min = 0, max = 0;  // source value range
  std::string method;       // how the vertices were chosen: "bisection", or the reduction method
  double max_error = 0;     // the absolute error bound asked for (data units)
  double threshold = 0;     // structural analysis: the absolute gradient threshold used
  std::string file;         // the source's file name (no folders), informational

  Dims volume_box() const { return volume_dims[0] > 0 ? volume_dims : dims; }  // the volume's dims
  bool padded() const { return volume_box() != dims; }
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
  // Inside the volume's box [0, volume_box() − 1]: every vertex but a padded lattice's copies.
  bool in_volume_box(std::uint32_t v) const {
    const Dims box = source.volume_box();
    return ijk[v][0] < box[0] && ijk[v][1] < box[1] && ijk[v][2] < box[2];
  }
  // How many vertices are in the volume's box: the volume's voxels the grid keeps.
  std::size_t volume_vertex_count() const {
    if (!source.padded()) return vertex_count();
    std::size_t n = 0;
    for (std::uint32_t v = 0; v < vertex_count(); ++v) n += in_volume_box(v);
    return n;
  }
  // The global lattice keys (see above) of vertex v and of the edge between vertices a and b, in
  // the lattice of source.dims.
  LatticeKey lattice_key(std::uint32_t v) const { return adaptiso::lattice_key(source.dims, ijk[v]); }
  LatticeEdge lattice_edge(std::uint32_t a, std::uint32_t b) const { return adaptiso::lattice_edge(lattice_key(a), lattice_key(b)); }
};

}  // namespace adaptiso
