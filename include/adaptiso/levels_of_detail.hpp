// adaptiso/levels_of_detail.hpp — a ladder of coarser grids for browsing a large scan
// interactively (the viewer): a coarse surface at once while the iso-value moves, the prepared one
// when it rests, and always the guaranteed error of what is shown.
//
// Level 0 is the prepared bisection grid, with its guaranteed bound e0 (data units). The ladder
// has two kinds of coarser levels, each an ordinary PreparedGrid with its own index (so every
// client keeps an incremental Extractor per level):
// - error levels: the grid coarsened (prepare.hpp: coarsen) to the bound e0·2^k, without the
//   volume, up to the first bound that reaches the value range (nothing coarser is worth having);
//   that coarsest one comes last in the ladder;
// - floored levels, between them: the grid coarsened to e0 under a cell floor of 2^f voxels
//   (coarsen_floored), f = 2 … log2(S) − 4 for the hierarchy's root cube of side S (at least 16
//   cells across it; coarser floors leave little but the tetrahedra that meet the lattice's far
//   faces). A coarser bound alone may leave a noisy scan's surface at millions of triangles up to
//   errors of half the range, and the next level is then a blob of a few hundred; a floor cuts a
//   surface some 4× a step on any data. Their bounds are measured when they are built (bound()),
//   and guaranteed like the others; a surface on one has the bound of the tetrahedra it cuts
//   (prepared_grid.hpp: surface_error_bound).
// Levels are built from the last (cheapest) towards level 1 by build(), meant for a background
// thread; until a level is built it is simply not offered.
//
// Choosing a level: for an error E, the coarsest built error level whose bound is at most E
// (level 0 when E is below e0: finer cannot be had); for a triangle budget T, the built level of
// the smallest bound among those expected to fit (the more triangles on a tie), never more
// accurate than a given level. Expected triangles come from the counts reported by record(),
// kept per level and per band of iso-values (64 bands across the value range): a count depends on
// the iso-value, and a level once seen over the budget at one iso-value must not be shunned at
// all others. In the iso-value's band, a level not seen is estimated from the nearest levels seen,
// finer and coarser, at a factor of 2 a level (4 between floored levels), the larger estimate
// kept; with nothing in the band, from the last counts at any iso-value likewise. Thread-safe
// throughout.
// Throws InputError when the grid has no bisection hierarchy (a Delaunay grid).
#pragma once
#include <atomic>
#include <cstddef>
#include <limits>
#include <memory>
#include <mutex>
#include <vector>

#include "adaptiso/prepared_grid.hpp"

namespace adaptiso {

class LevelsOfDetail {
public:
  explicit LevelsOfDetail(std::shared_ptr<const PreparedGrid> fine);

  std::size_t size() const { return bounds_.size(); }  // levels, level 0 included
  // The level's guaranteed bound (data units): asked for an error level; measured once built for
  // a floored one (before, the bound asked for it, e0: a lower bound).
  double bound(std::size_t level) const;
  int cell_floor(std::size_t level) const { return floors_.at(level); }  // log2 of the floor's cell; 0: an error level
  std::shared_ptr<const PreparedGrid> grid(std::size_t level) const;     // null until built
  std::size_t built() const;                                             // levels built, level 0 included

  // Builds the missing levels, coarsest first; returns early when *stop becomes true.
  void build(const std::atomic<bool>* stop = nullptr);

  std::size_t level_for_error(double max_error) const;
  // Never more accurate than `finest`; iso NaN: the last counts at any iso-value.
  std::size_t level_for_budget(std::size_t triangles, std::size_t finest = 0, double iso = std::numeric_limits<double>::quiet_NaN()) const;
  // The triangle count of a surface at that level (and iso-value, when known).
  void record(std::size_t level, std::size_t triangles, double iso = std::numeric_limits<double>::quiet_NaN());

private:
  std::vector<double> bounds_;  // asked
  std::vector<int> floors_;
  mutable std::mutex mutex_;
  std::vector<std::shared_ptr<const PreparedGrid>> grids_;
  static constexpr std::size_t kBands = 64;
  std::vector<std::size_t> triangles_;       // per level, last recorded at any iso-value; 0: none yet
  std::vector<std::size_t> band_triangles_;  // per band and level (band · size() + level), likewise
  double bound_locked(std::size_t level) const;
  std::size_t band(double iso) const;  // of the value range; kBands for NaN
  std::vector<double> expected_locked(const std::size_t* counts) const;
};

}  // namespace adaptiso
