// adaptiso/marching_tetrahedra.hpp — iso-surfaces of a tetrahedral grid by marching tetrahedra
// (Lürig & Ertl §2.4), over a given list of active tetrahedra.
//
// Rule for ties: a vertex whose value equals the iso-value counts as above it, so a tetrahedron
// is cut iff min < iso <= max, and each cut edge joins a vertex below and one at or above. Each cut
// grid edge gives exactly one mesh vertex (shared by every triangle using it), so a closed surface
// is watertight and 2-manifold. Cut points are kept at least 1/1024 of the edge length away from
// the edge's ends, so no triangle collapses when vertices lie exactly on the iso-value (the surface
// then passes within that distance of them, as if the iso-value were lowered infinitesimally).
// Normals are the linearly interpolated vertex gradients, normalised and negated: they point
// towards lower values (outward for a bright object); triangles are counter-clockwise seen from
// that side. Output order: triangles in the order of the given tetrahedra, vertices by first use
// (the same for any thread count).
#pragma once
#include <atomic>
#include <cstdint>
#include <span>
#include <vector>

#include "adaptiso/mesh.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

struct MarchOptions {
  std::size_t parallel_min_tetrahedra = 65536;  // below this many, one thread numbers the vertices
  // Raised from another thread: the march stops within about 0.1 s and throws ExtractCancelled
  // (extractor.hpp); nullptr: never.
  const std::atomic<bool>* cancel = nullptr;
};

// A vertex the clip to the volume's box made (a padded lattice, tet_grid.hpp): it lies on one of
// the box's far faces, on no grid edge.
inline constexpr std::uint64_t kClippedVertex = ~std::uint64_t{0};

// The surface cut by `active` (each must be cut at iso: min < iso <= max), clipped to the volume's
// box on a padded lattice. With vertex_edges, also each mesh vertex's grid edge as (below vertex
// << 32 | above vertex), or kClippedVertex.
Mesh march_tetrahedra(const TetGrid& grid, std::span<const std::uint32_t> active, double iso, const MarchOptions& options = {},
                      std::vector<std::uint64_t>* vertex_edges = nullptr);

}  // namespace adaptiso
