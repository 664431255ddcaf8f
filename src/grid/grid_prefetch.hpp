// Prefetching a tetrahedral grid's scattered reads (the sweep, the marches, the Extractor's
// steps), a few iterations ahead; util/prefetch.hpp holds the general one. Internal.
#pragma once
#include <cstdint>

#include "adaptiso/tet_grid.hpp"
#include "util/prefetch.hpp"

namespace adaptiso::detail {

// A tetrahedron's four values lie at scattered places of the grid.
inline void prefetch_values(const TetGrid& grid, std::uint32_t t) {
  for (std::uint32_t v : grid.tets[t]) __builtin_prefetch(&grid.values[v]);
}

}  // namespace adaptiso::detail
