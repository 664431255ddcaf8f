// adaptiso/levels_of_detail.hpp — a ladder of coarser grids for browsing a large scan
// interactively (the viewer): a coarse surface at once while the iso-value moves, the prepared one
// when it rests, and always the guaranteed error of what is shown.
//
// Level 0 is the prepared bisection grid, with its guaranteed bound e0 (data units). Level k is the
// same grid coarsened (prepare.hpp: coarsen) to the bound e0·2^k, without the volume; the ladder
// ends at the first level whose bound reaches the value range (nothing coarser is worth having).
// Each level is an ordinary PreparedGrid with its own index, so every client keeps an incremental
// Extractor per level. Levels are built from the coarsest (cheapest) towards level 1 by build(),
// meant for a background thread; until a level is built it is simply not offered.
//
// Choosing a level: for an error E, the coarsest built level whose bound is at most E (level 0 when
// E is below e0: finer cannot be had); for a triangle budget T, the finest built level whose
// surface is expected to fit, from the triangle counts reported by record() (a level not seen yet
// is estimated from the nearest levels seen, finer and coarser, at a factor of 2 a level, the larger
// estimate kept). Thread-safe throughout.
// Throws InputError when the grid has no bisection hierarchy (a Delaunay grid).
#pragma once
#include <atomic>
#include <cstddef>
#include <memory>
#include <mutex>
#include <vector>

#include "adaptiso/prepare.hpp"

namespace adaptiso {

class LevelsOfDetail {
public:
  explicit LevelsOfDetail(std::shared_ptr<const PreparedGrid> fine);

  std::size_t size() const { return bounds_.size(); }                 // levels, level 0 included
  double bound(std::size_t level) const;                              // the bound asked for the level (data units)
  std::shared_ptr<const PreparedGrid> grid(std::size_t level) const;  // null until built
  std::size_t built() const;                                          // levels built, level 0 included

  // Builds the missing levels, coarsest first; returns early when *stop becomes true.
  void build(const std::atomic<bool>* stop = nullptr);

  std::size_t level_for_error(double max_error) const;
  std::size_t level_for_budget(std::size_t triangles, std::size_t finest = 0) const;  // never finer than `finest`
  void record(std::size_t level, std::size_t triangles);                              // the triangle count of a surface at that level

private:
  std::vector<double> bounds_;
  mutable std::mutex mutex_;
  std::vector<std::shared_ptr<const PreparedGrid>> grids_;
  std::vector<std::size_t> triangles_;  // last recorded, 0: none yet
};

}  // namespace adaptiso
