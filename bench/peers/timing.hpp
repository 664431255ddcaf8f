// Timing of the peer drivers: one warm-up run, then the best of `repeat` runs (C++17: shared with
// the VTK part).
#pragma once
#include <algorithm>
#include <chrono>

template <class F>
double best_of(int repeat, F f) {
  f();
  double best = 1e30;
  for (int r = 0; r < repeat; ++r) {
    auto t0 = std::chrono::steady_clock::now();
    f();
    best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return best;
}
