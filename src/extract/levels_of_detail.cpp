// Levels of detail of a bisection grid (see levels_of_detail.hpp).
#include "adaptiso/levels_of_detail.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "adaptiso/error.hpp"

namespace adaptiso {

LevelsOfDetail::LevelsOfDetail(std::shared_ptr<const PreparedGrid> fine) {
  if (!fine || !fine->hierarchy) throw InputError("levels of detail need a bisection grid with its hierarchy");
  const double span = fine->grid.source.max - fine->grid.source.min;
  // A lossless grid (bound 0) starts the ladder at 1/4096 of the range.
  double e = fine->stats.error_bound > 0 ? fine->stats.error_bound : span / 4096;
  bounds_.push_back(std::max(fine->stats.error_bound, 0.0));
  while (span > 0 && e < span) {
    e *= 2;
    bounds_.push_back(e);
  }
  grids_.assign(bounds_.size(), nullptr);
  grids_[0] = std::move(fine);
  triangles_.assign(bounds_.size(), 0);
}

double LevelsOfDetail::bound(std::size_t level) const { return bounds_.at(level); }

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
    auto g = std::make_shared<const PreparedGrid>(coarsen(*fine, bounds_[level]));
    std::lock_guard lock(mutex_);
    grids_[level] = std::move(g);
  }
}

std::size_t LevelsOfDetail::level_for_error(double max_error) const {
  std::lock_guard lock(mutex_);
  std::size_t best = 0;
  for (std::size_t k = 1; k < bounds_.size(); ++k)
    if (grids_[k] && bounds_[k] <= max_error) best = k;
  return best;
}

std::size_t LevelsOfDetail::level_for_budget(std::size_t triangles, std::size_t finest) const {
  std::lock_guard lock(mutex_);
  // Expected triangles per level: recorded, or else the largest of the estimates from the nearest
  // recorded finer level (half as many per level coarser) and the nearest recorded coarser one
  // (twice as many per level finer); a level nothing is known about is expected to be too large.
  const std::size_t n = bounds_.size();
  std::vector<double> expected(n, std::numeric_limits<double>::infinity());
  for (std::size_t k = 0; k < n; ++k) {
    if (triangles_[k]) {
      expected[k] = static_cast<double>(triangles_[k]);
      continue;
    }
    double estimate = -1;
    for (std::size_t j = k; j-- > 0;)
      if (triangles_[j]) {
        estimate = std::max(estimate, static_cast<double>(triangles_[j]) / std::ldexp(1.0, static_cast<int>(k - j)));
        break;
      }
    for (std::size_t j = k + 1; j < n; ++j)
      if (triangles_[j]) {
        estimate = std::max(estimate, static_cast<double>(triangles_[j]) * std::ldexp(1.0, static_cast<int>(j - k)));
        break;
      }
    if (estimate >= 0) expected[k] = estimate;
  }
  std::size_t coarsest_built = 0;
  for (std::size_t k = 0; k < bounds_.size(); ++k)
    if (grids_[k]) coarsest_built = k;
  for (std::size_t k = finest; k < bounds_.size(); ++k)
    if (grids_[k] && expected[k] <= static_cast<double>(triangles)) return k;
  return std::max(coarsest_built, finest);
}

void LevelsOfDetail::record(std::size_t level, std::size_t triangles) {
  std::lock_guard lock(mutex_);
  triangles_.at(level) = std::max<std::size_t>(triangles, 1);
}

}  // namespace adaptiso
