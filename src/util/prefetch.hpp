// Prefetching for loops that read the grid at scattered places (the sweep, the marches, the
// Extractor's steps): the misses are the cost, so the reads are issued a few iterations ahead.
#pragma once
#include <cstdint>

#include "adaptiso/tet_grid.hpp"

namespace adaptiso::detail {

inline void prefetch(const void* p) { __builtin_prefetch(p); }

// A tetrahedron's four values lie at scattered places of the grid.
inline void prefetch_values(const TetGrid& grid, std::uint32_t t) {
  for (std::uint32_t v : grid.tets[t]) __builtin_prefetch(&grid.values[v]);
}

}  // namespace adaptiso::detail
