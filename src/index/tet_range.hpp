// A tetrahedron's value range [tmin, tmax], the key of the interval tree: read by its build,
// its validation and its sweep (interval_tree*.cpp). Internal.
#pragma once
#include <algorithm>
#include <cstdint>

#include "adaptiso/tet_grid.hpp"
#include "grid/grid_prefetch.hpp"

namespace adaptiso::detail {

struct Range {
  double lo, hi;
};

inline Range tet_range(const TetGrid& grid, std::uint32_t t) {
  const auto& q = grid.tets[t];
  const double* v = grid.values.data();
  double a = v[q[0]], b = v[q[1]], c = v[q[2]], d = v[q[3]];
  return {std::min(std::min(a, b), std::min(c, d)), std::max(std::max(a, b), std::max(c, d))};
}

inline double tet_min(const TetGrid& grid, std::uint32_t t) { return tet_range(grid, t).lo; }
inline double tet_max(const TetGrid& grid, std::uint32_t t) { return tet_range(grid, t).hi; }

// The range of ids[i], in a loop over ids[begin, end) that reads ahead: the tetrahedra and their
// values lie at scattered places, so later ones are prefetched.
inline Range range_reading_ahead(const TetGrid& grid, const std::uint32_t* ids, std::uint64_t i, std::uint64_t end) {
  if (i + 16 < end) detail::prefetch(&grid.tets[ids[i + 16]]);
  if (i + 8 < end) prefetch_values(grid, ids[i + 8]);
  return tet_range(grid, ids[i]);
}

}  // namespace adaptiso::detail
