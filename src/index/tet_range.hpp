// A tetrahedron's value range [tmin, tmax], the key of the interval tree: read by its build,
// its validation and its sweep (interval_tree*.cpp), and the count of its entries prepare_to_file
// takes as the tetrahedra pass. Internal.
#pragma once
#include <algorithm>
#include <array>
#include <cstdint>

#include "adaptiso/tet_grid.hpp"
#include "grid/grid_prefetch.hpp"

namespace adaptiso::detail {

struct Range {
  double lo, hi;
};

// Of the tetrahedron q over the vertices' values v (a tetrahedron held apart from its grid: the
// pieces prepare_to_file counts as they go into the file).
inline Range tet_range(const double* v, const std::array<std::uint32_t, 4>& q) {
  double a = v[q[0]], b = v[q[1]], c = v[q[2]], d = v[q[3]];
  return {std::min(std::min(a, b), std::min(c, d)), std::max(std::max(a, b), std::max(c, d))};
}

inline Range tet_range(const TetGrid& grid, std::uint32_t t) { return tet_range(grid.values.data(), grid.tets[t]); }

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
