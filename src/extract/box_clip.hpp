// Surfaces of a padded lattice clipped to the volume's box (tet_grid.hpp: GridSource::volume_dims;
// bisection.hpp: why prepare pads). Every extraction route runs its surface through here, so a
// surface ends on the volume's far faces as one of an unpadded grid does, and never runs on into
// the copies of the last slices.
//
// The clip is geometric, in index space: a vertex's index coordinates come from its world
// position through the grid frame's inverse. A triangle wholly inside is kept as it is, one wholly
// past a face goes, one across is cut by the face planes (up to three, at a corner) into a convex
// polygon and fanned into triangles. A cut point is made once per edge and plane, the same for
// both triangles of the edge (its ends in canonical order), so the surface stays connected and
// manifold where it was; its normal is the normalised interpolation of its ends'. Pieces that lie
// in a face plane (no area off it: a triangle of the padding touching the face) go too.
// Vertices within a few float roundings of a face count as on it (world positions are floats).
//
// Deterministic: the same output for any thread count (the cut points are numbered in triangle
// order).
#pragma once
#include <cstdint>
#include <vector>

#include "adaptiso/mesh.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso::detail {

// Where a clipped mesh's parts come from.
struct ClipMap {
  static constexpr std::uint32_t kNew = ~std::uint32_t{0};
  std::vector<std::uint32_t> first;        // per input triangle, its first output triangle (size: triangles + 1)
  std::vector<std::uint32_t> vertex_from;  // per output vertex, its input vertex, or kNew for a cut point
};

// The mesh clipped to source's volume box into `out` (and `map`): false, with both untouched,
// when the lattice is not padded or no vertex lies past the box.
bool clip_to_volume_box(const Mesh& in, const GridSource& source, Mesh& out, ClipMap* map = nullptr);

// The same in place: the same output, written over the input's arrays where every triangle's
// pieces land at or before its own place (no fresh memory), else through a copy. Says which.
enum class Clipped { nothing, in_place, copied };
Clipped clip_to_volume_box(Mesh& mesh, const GridSource& source);

// Per-vertex keys of the input mesh carried to the clipped mesh's vertices: a cut point gets `cut`.
void carry_vertex_keys(const ClipMap& map, const std::vector<std::uint64_t>& keys, std::uint64_t cut, std::vector<std::uint64_t>& out);

}  // namespace adaptiso::detail
