// Progress of a stage whose work is counted from many threads (a parallel walk, a parallel loop
// over chunks). Counting is one atomic add; telling is under a lock and only when the count has
// passed a step not yet told, so the listener sees the stage's fractions in order and at most
// `steps` times. Why the lock: two threads that count 27 and 28 of 100 can otherwise report 28
// first and then 27 (a loaded CI machine did, in the grid check's walk).
#pragma once
#include <adaptiso/progress.hpp>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <mutex>
#include <string_view>

namespace adaptiso::detail {

class ProgressCounter {
public:
  // Reports `from` + (`to` − `from`) × done / total for `stage`; the stage itself reports its
  // start and end (a total of 0 tells nothing).
  ProgressCounter(const Progress& progress, std::string_view stage, std::uint64_t total, double from = 0, double to = 1,
                  std::uint64_t steps = 100)
      : progress_(progress), stage_(stage), total_(total), from_(from), to_(to), steps_(std::max<std::uint64_t>(steps, 1)) {}

  void advance(std::uint64_t n) {
    if (!progress_ || total_ == 0) return;
    const std::uint64_t done = std::min(done_.fetch_add(n, std::memory_order_relaxed) + n, total_);
    const std::uint64_t step = step_of(done);
    if (step <= told_.load(std::memory_order_relaxed)) return;
    const std::lock_guard lock(mutex_);
    if (step <= told_.load(std::memory_order_relaxed)) return;  // a later count told it first
    told_.store(step, std::memory_order_relaxed);
    progress_(stage_, from_ + (to_ - from_) * static_cast<double>(done) / static_cast<double>(total_));
  }

private:
  // In 128 bits: a count of nearly 2^64 times a hundred steps does not wrap.
  std::uint64_t step_of(std::uint64_t done) const {
    return static_cast<std::uint64_t>(static_cast<unsigned __int128>(done) * steps_ / total_);
  }

  const Progress progress_;  // a copy: a caller may pass a temporary (Progress{} for none)
  std::string_view stage_;
  std::uint64_t total_;
  double from_, to_;
  std::uint64_t steps_;
  std::atomic<std::uint64_t> done_{0}, told_{0};
  std::mutex mutex_;
};

}  // namespace adaptiso::detail
