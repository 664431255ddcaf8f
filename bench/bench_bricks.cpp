// bench_bricks — times bisection_errors against bisection_errors_bricked on one volume: wall time and the peak
// resident memory added during the step (RSS sampled every 2 ms), bytes handed across faces.
//   bench_bricks FILE whole|bricked|both SIDE THREADS DISPLACEMENT(0|1)   (both: bricked, then checked)
#include <tbb/global_control.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <string>
#include <thread>

#include "adaptiso/bisection.hpp"
#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/volume_io.hpp"

using namespace adaptiso;

static long rss_kb() {
  std::ifstream f("/proc/self/statm");
  long size = 0, res = 0;
  f >> size >> res;
  return res * (sysconf(_SC_PAGESIZE) / 1024);
}

int main(int argc, char** argv) {
  if (argc < 6) return 2;
  const Volume v = read_volume(argv[1]);
  const std::string mode = argv[2];
  const long side = std::stol(argv[3]);
  const int threads = std::stoi(argv[4]);
  const bool displacement = std::stoi(argv[5]) != 0;
  tbb::global_control gc(tbb::global_control::max_allowed_parallelism, threads);
  const ValueRange range = value_range(v);
  const long base = rss_kb();
  std::atomic<bool> stop{false};
  std::atomic<long> peak{base};
  std::thread sampler([&] {
    while (!stop) {
      peak = std::max(peak.load(), rss_kb());
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  });
  const auto t0 = std::chrono::steady_clock::now();
  std::uint64_t bytes = 0;
  // When each stage reported last (seconds from the start): the bricks, then the combine step.
  std::mutex stages_mutex;
  std::map<std::string, double> stages;
  const Progress progress = [&](std::string_view stage, double) {
    const std::lock_guard lock(stages_mutex);
    stages[std::string(stage)] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  BisectionErrors e = mode == "whole" ? bisection_errors(v, range, displacement, progress)
                                      : bisection_errors_bricked(v.dims, range, side, region_source(v), displacement, progress, &bytes);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  stop = true;
  sampler.join();
  for (const auto& [stage, at] : stages) std::printf("%s: done at %.3f s\n", stage.c_str(), at);
  std::uint64_t sum = 0;
  for (auto c : e.code) sum += c;
  if (mode == "both") {  // and the whole volume's, byte for byte
    const BisectionErrors whole = bisection_errors(v, range, displacement);
    std::printf("bytes equal to bisection_errors: %s\n",
                whole.code == e.code && whole.displacement_code == e.displacement_code ? "yes" : "NO");
  }
  std::printf(
      "{\"mode\":\"%s\",\"side\":%ld,\"threads\":%d,\"displacement\":%d,\"seconds\":%.3f,\"peak_extra_mb\":%.1f,\"bytes_exchanged\":%llu,"
      "\"voxels\":%lld,\"code_sum\":%llu}\n",
      mode.c_str(), side, threads, displacement ? 1 : 0, seconds, (peak - base) / 1024.0, static_cast<unsigned long long>(bytes),
      static_cast<long long>(v.voxel_count()), static_cast<unsigned long long>(sum));
}
