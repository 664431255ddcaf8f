// Large arrays, faulted in by the kernel in one call, on huge pages where it has them.
//
// On virtual machines a first touch of a 4 KiB page can cost microseconds: measured here, writing
// 512 MiB of fresh memory took 1.36 s page by page and 0.05 s after madvise(MADV_HUGEPAGE) and
// madvise(MADV_POPULATE_WRITE) (Linux ≥ 5.14; elsewhere the advice is ignored and the pages fault
// in as usual). Every stage that fills an array of tens of megabytes or more sizes it this way.
#pragma once
#include <sys/mman.h>

#include <cstdint>
#include <cstdlib>
#include <vector>

namespace adaptiso::detail {

constexpr std::size_t kBigArrayBytes = std::size_t{32} << 20;

// Asks for huge pages on [p, p + bytes) and for the pages to be present.
inline void populate(void* p, std::size_t bytes) {
  if (bytes < kBigArrayBytes) return;
  constexpr std::uintptr_t page = 4096;
  const auto begin = reinterpret_cast<std::uintptr_t>(p) & ~(page - 1);
  const auto end = (reinterpret_cast<std::uintptr_t>(p) + bytes + page - 1) & ~(page - 1);
#ifdef MADV_HUGEPAGE
  static const bool huge = !std::getenv("ADAPTISO_NO_HUGEPAGES");
  if (huge) madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE);
#endif
#ifdef MADV_POPULATE_WRITE
  madvise(reinterpret_cast<void*>(begin), end - begin, MADV_POPULATE_WRITE);
#endif
}

// v.resize(n) for a vector about to be filled: a large one is allocated anew and populated first.
template <class T, class A>
void resize_big(std::vector<T, A>& v, std::size_t n) {
  if (n * sizeof(T) >= kBigArrayBytes && n > v.capacity()) {
    std::vector<T, A>().swap(v);
    v.reserve(n);
    populate(v.data(), n * sizeof(T));
  }
  v.resize(n);
}

// v.assign(n, x) likewise.
template <class T, class A>
void assign_big(std::vector<T, A>& v, std::size_t n, const T& x) {
  if (n * sizeof(T) >= kBigArrayBytes && n > v.capacity()) {
    std::vector<T, A>().swap(v);
    v.reserve(n);
    populate(v.data(), n * sizeof(T));
  }
  v.assign(n, x);
}

}  // namespace adaptiso::detail
