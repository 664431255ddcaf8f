// Prefetching for loops that read the grid at scattered places (the sweep, the marches, the
// Extractor's steps): the misses are the cost, so the reads are issued a few iterations ahead.
// A grid's scattered reads: grid/grid_prefetch.hpp.
#pragma once
namespace adaptiso::detail {

inline void prefetch(const void* p) { __builtin_prefetch(p); }

}  // namespace adaptiso::detail
