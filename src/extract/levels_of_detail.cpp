// Levels of detail of a bisection grid (see levels_of_detail.hpp).
//
// This work is based on:
// - Gregorski, Duchaineau, Lindstrom, Pascucci, Joy. Interactive view-dependent rendering of large
//   isosurfaces. IEEE Visualization 2002 (coarser selections of the diamond hierarchy).
#include "adaptiso/levels_of_detail.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include "adaptiso/error.hpp"
#include "adaptiso/prepare.hpp"

namespace adaptiso {

LevelsOfDetail::LevelsOfDetail(std::shared_ptr<const PreparedGrid> fine) {
  if (!fine || !fine->hierarchy) throw InputError("levels of detail need a bisection grid with its hierarchy");
  const double span = fine->grid.source.max - fine->grid.source.min;
  const double e0 = std::max(fine->stats.error_bound, 0.0);
  // A lossless grid (bound 0) starts the ladder at 1/4096 of the range.
  double e = e0 > 0 ? e0 : span / 4096;
  bounds_.push_back(e0);
  while (span > 0 && e < span) {
    e *= 2;
    bounds_.push_back(e);
  }
  floors_.assign(bounds_.size(), 0);
  if (bounds_.size() > 1) {  // the floored levels go before the coarsest error level
    const double coarsest = bounds_.back();
    bounds_.pop_back();
    floors_.pop_back();
    const int k = std::countr_zero(static_cast<std::uint32_t>(std::max(fine->hierarchy->root_size, 1)));
    for (int f = 2; f <= k - 4; ++f) {  // down to 16 cells across the root cube: coarser ones only keep the box's far faces
      bounds_.push_back(e0);
      floors_.push_back(f);
    }
    bounds_.push_back(coarsest);
    floors_.push_back(0);
  }
  grids_.assign(bounds_.size(), nullptr);
  grids_[0] = std::move(fine);
  triangles_.assign(bounds_.size(), 0);
  band_triangles_.assign(kBands * bounds_.size(), 0);
}

std::size_t LevelsOfDetail::band(double iso) const {
  if (std::isnan(iso)) return kBands;
  const double lo = grids_[0]->grid.source.min, hi = grids_[0]->grid.source.max;  // level 0 never changes
  if (!(hi > lo)) return 0;
  const double t = std::clamp((iso - lo) / (hi - lo), 0.0, 1.0);
  return std::min(kBands - 1, static_cast<std::size_t>(t * kBands));
}

double LevelsOfDetail::bound_locked(std::size_t level) const {
  const auto& g = grids_.at(level);
  return floors_[level] && g ? g->stats.error_bound : bounds_[level];
}

double LevelsOfDetail::bound(std::size_t level) const {
  std::lock_guard lock(mutex_);
  return bound_locked(level);
}

std::shared_ptr<const PreparedGrid> LevelsOfDetail::grid(std::size_t level) const {
  std::lock_guard lock(mutex_);
  return grids_.at(level);
}

std::size_t LevelsOfDetail::built() const {
  std::lock_guard lock(mutex_);
  return static_cast<std::size_t>(std::count_if(grids_.begin(), grids_.end(), [](const auto& g) { return g != nullptr; }));
}

void LevelsOfDetail::build(const std::atomic<bool>* stop) {
  const auto fine = grid(0);
  for (std::size_t level = size(); level-- > 1;) {
    if (stop && stop->load()) return;
    if (grid(level)) continue;
    auto g = std::make_shared<const PreparedGrid>(floors_[level] ? coarsen_floored(*fine, bounds_[level], floors_[level])
                                                                 : coarsen(*fine, bounds_[level]));
    std::lock_guard lock(mutex_);
    grids_[level] = std::move(g);
  }
}

std::size_t LevelsOfDetail::level_for_error(double max_error) const {
  std::lock_guard lock(mutex_);
  std::size_t best = 0;
  for (std::size_t k = 1; k < bounds_.size(); ++k)
    if (grids_[k] && !floors_[k] && bounds_[k] <= max_error) best = k;
  return best;
}

// Expected triangles per level: recorded, or else the largest of the estimates from the nearest
// recorded level on either side, a factor a step (4 between floored levels, whose cells shrink
// 2× along each axis; 2 otherwise); a level nothing is known about is expected to be too large.
std::vector<double> LevelsOfDetail::expected_locked(const std::size_t* counts) const {
  const std::size_t n = bounds_.size();
  auto factor = [&](std::size_t k) { return floors_[k] && floors_[k + 1] ? 4.0 : 2.0; };  // from level k to k + 1
  std::vector<double> expected(n, std::numeric_limits<double>::infinity());
  for (std::size_t k = 0; k < n; ++k) {
    if (counts[k]) {
      expected[k] = static_cast<double>(counts[k]);
      continue;
    }
    double estimate = -1, scale = 1;
    for (std::size_t j = k; j-- > 0;) {
      scale *= factor(j);
      if (counts[j]) {
        estimate = std::max(estimate, static_cast<double>(counts[j]) / scale);
        break;
      }
    }
    scale = 1;
    for (std::size_t j = k + 1; j < n; ++j) {
      scale *= factor(j - 1);
      if (counts[j]) {
        estimate = std::max(estimate, static_cast<double>(counts[j]) * scale);
        break;
      }
    }
    if (estimate >= 0) expected[k] = estimate;
  }
  return expected;
}

std::size_t LevelsOfDetail::level_for_budget(std::size_t triangles, std::size_t finest, double iso) const {
  std::lock_guard lock(mutex_);
  // The iso-value's band first; levels it knows nothing of, from the last counts at any iso-value.
  std::vector<double> expected = expected_locked(triangles_.data());
  const std::size_t b = band(iso);
  if (b < kBands) {
    const std::vector<double> in_band = expected_locked(band_triangles_.data() + b * bounds_.size());
    for (std::size_t k = 0; k < expected.size(); ++k)
      if (std::isfinite(in_band[k])) expected[k] = in_band[k];
  }
  const double floor_bound = bound_locked(finest);
  std::size_t best = finest, coarsest_built = finest;
  bool found = false;
  for (std::size_t k = 0; k < bounds_.size(); ++k) {
    const bool finer_error_level = k < finest && !floors_[k];
    if (!grids_[k] || (k != finest && (finer_error_level || bound_locked(k) < floor_bound))) continue;
    coarsest_built = std::max(coarsest_built, k);
    if (expected[k] > static_cast<double>(triangles)) continue;
    const double b = bound_locked(k), best_b = bound_locked(best);
    if (!found || b < best_b || (b == best_b && expected[k] > expected[best])) best = k;
    found = true;
  }
  return found ? best : coarsest_built;
}

void LevelsOfDetail::record(std::size_t level, std::size_t triangles, double iso) {
  std::lock_guard lock(mutex_);
  const std::size_t count = std::max<std::size_t>(triangles, 1), b = band(iso);
  triangles_.at(level) = count;
  if (b < kBands) band_triangles_[b * bounds_.size() + level] = count;
}

}  // namespace adaptiso
