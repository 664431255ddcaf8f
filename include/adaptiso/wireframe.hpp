// adaptiso/wireframe.hpp — the edges of a set of tetrahedra, for drawing them (the viewer's
// "active tetrahedra"): each grid edge once, its vertices renumbered compactly.
#pragma once
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

struct Wireframe {
  std::vector<std::array<float, 3>> positions;      // world coordinates, one per vertex used
  std::vector<std::array<std::uint32_t, 2>> edges;  // into positions, sorted by grid vertex ids
};

// Throws InputError when there would be more than max_edges edges.
Wireframe tetrahedra_wireframe(const TetGrid& grid, std::span<const std::uint32_t> tets, std::size_t max_edges);

}  // namespace adaptiso
