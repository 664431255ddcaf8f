// Helpers the command-line benchmarks share: lists given as "a,b,c" and the median of repeated runs.
#pragma once
#include <algorithm>
#include <chrono>
#include <sstream>
#include <string>
#include <vector>

namespace bench {

// "0.1,0.25,0.5" → {0.1, 0.25, 0.5}; std::stod throws on a bad entry.
inline std::vector<double> parse_list(const char* s) {
  std::vector<double> out;
  std::stringstream ss(s);
  for (std::string tok; std::getline(ss, tok, ',');) out.push_back(std::stod(tok));
  return out;
}

// The median wall time of `reps` runs of f, in seconds.
template <class F>
double median_time(F&& f, int reps = 5) {
  std::vector<double> t;
  for (int r = 0; r < reps; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

}  // namespace bench
