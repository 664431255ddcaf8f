// What the viewer's caches cost (see memory_budget.hpp).
#include "view/memory_budget.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "util/memory.hpp"

namespace adaptiso::detail {

std::uint64_t resident_bytes() {
  // statm rather than status: one short line, read on every extraction the budget admits.
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long long size = 0, resident = 0;
  const int got = std::fscanf(f, "%llu %llu", &size, &resident);
  std::fclose(f);
  const long page = sysconf(_SC_PAGESIZE);
  return got == 2 && page > 0 ? resident * static_cast<std::uint64_t>(page) : 0;
}

namespace {

std::uint64_t physical_memory() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(page) : 0;
}

template <class V>
std::uint64_t capacity_bytes(const V& v) {
  return v.capacity() * sizeof(typename V::value_type);
}

}  // namespace

std::uint64_t default_memory_budget() {
  const std::uint64_t half = physical_memory() / 2;
  const std::uint64_t reachable = resident_bytes() + available_memory();
  const std::uint64_t budget = half ? std::min(half, reachable) : reachable;
  return budget ? budget : std::uint64_t{4} << 30;  // nothing known: 4 GiB
}

std::string byte_size_text(std::uint64_t bytes) {
  const double x = static_cast<double>(bytes);
  if (x >= 1e9) return fmt::format("{:.1f} GB", x / 1e9);
  if (x >= 1e6) return fmt::format("{:.0f} MB", x / 1e6);
  return fmt::format("{:.0f} kB", x / 1e3);
}

std::uint64_t grid_bytes(const PreparedGrid& p) {
  const TetGrid& g = p.grid;
  std::uint64_t b = capacity_bytes(g.ijk) + capacity_bytes(g.values) + capacity_bytes(g.gradients) + capacity_bytes(g.tets);
  b += capacity_bytes(p.index.nodes) + capacity_bytes(p.index.by_min) + capacity_bytes(p.index.by_max);
  b += capacity_bytes(p.tet_error_code);
  if (p.hierarchy) {
    const auto& h = *p.hierarchy;
    b += capacity_bytes(h.error_code) + capacity_bytes(h.value_span) + capacity_bytes(h.displacement_code);
  }
  return b;
}

std::uint64_t extractor_fixed_bytes(const PreparedGrid& p) {
  const std::uint64_t tets = p.grid.tet_count();
  return tets + tets / 8 + 8 * std::uint64_t{p.index.nodes.size()};
}

std::uint64_t extractor_bytes(const PreparedGrid& p, std::size_t triangles) {
  return extractor_fixed_bytes(p) + kExtractorBytesPerTriangle * std::uint64_t{triangles};
}

void SurfaceSizes::reset(double min, double max) {
  std::lock_guard lock(mutex_);
  min_ = min;
  max_ = max;
  counts_.clear();
}

std::size_t SurfaceSizes::band(double iso) const {
  if (!(max_ > min_) || !std::isfinite(iso)) return 0;
  const double t = std::clamp((iso - min_) / (max_ - min_), 0.0, 1.0);
  return std::min(kBands - 1, static_cast<std::size_t>(t * kBands));
}

void SurfaceSizes::record(std::size_t key, double iso, std::size_t triangles) {
  std::lock_guard lock(mutex_);
  auto& c = counts_[key];
  if (c.empty()) c.assign(kBands, kNone);
  c[band(iso)] = triangles;
}

std::size_t SurfaceSizes::expected(std::size_t key, double iso, std::size_t unknown) const {
  std::lock_guard lock(mutex_);
  const auto it = counts_.find(key);
  if (it == counts_.end()) return unknown;
  const auto& c = it->second;
  const std::size_t b = band(iso);
  for (std::size_t d = 0; d < kBands; ++d) {  // the nearest band seen, the larger count on a tie
    const std::size_t lo = b >= d ? c[b - d] : kNone, hi = b + d < kBands ? c[b + d] : kNone;
    if (lo != kNone || hi != kNone) return lo == kNone ? hi : hi == kNone ? lo : std::max(lo, hi);
  }
  return unknown;
}

}  // namespace adaptiso::detail
