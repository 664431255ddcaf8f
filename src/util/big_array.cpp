// Large arrays populated in parallel (see big_array.hpp).
#include "util/big_array.hpp"

#include <sys/mman.h>
#include <tbb/parallel_for.h>

#include <cstdlib>

namespace adaptiso::detail {

void populate(void* p, std::size_t bytes) {
  if (bytes < kBigArrayBytes) return;
  constexpr std::uintptr_t page = 4096;
  const auto begin = reinterpret_cast<std::uintptr_t>(p) & ~(page - 1);
  const auto end = (reinterpret_cast<std::uintptr_t>(p) + bytes + page - 1) & ~(page - 1);
#ifdef MADV_HUGEPAGE
  static const bool huge = !std::getenv("ADAPTISO_NO_HUGEPAGES");
  if (huge) madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE);
#endif
#ifdef MADV_POPULATE_WRITE
  // Chunks on huge-page boundaries, so no huge page is split between two threads.
  constexpr std::uintptr_t chunk = std::uintptr_t{16} << 20;
  const std::uintptr_t first = (begin + chunk - 1) & ~(chunk - 1);
  tbb::parallel_for(std::uintptr_t{0}, (end - std::min(first, end) + chunk - 1) / chunk + 1, [&](std::uintptr_t c) {
    const std::uintptr_t from = c == 0 ? begin : first + (c - 1) * chunk, to = c == 0 ? std::min(first, end) : std::min(end, from + chunk);
    if (from < to) madvise(reinterpret_cast<void*>(from), to - from, MADV_POPULATE_WRITE);
  });
#endif
}

}  // namespace adaptiso::detail
