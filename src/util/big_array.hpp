// Large arrays, faulted in by the kernel before they are filled, on huge pages where it has them.
//
// On virtual machines a first touch of a 4 KiB page can cost microseconds: measured here, writing
// 512 MiB of fresh memory took 1.36 s page by page and 0.05 s after madvise(MADV_HUGEPAGE) and
// madvise(MADV_POPULATE_WRITE) (Linux ≥ 5.14; elsewhere the advice is ignored and the pages fault
// in as usual). Every stage that fills an array of tens of megabytes or more sizes it this way.
#pragma once
#include <cstdint>
#include <vector>

namespace adaptiso::detail {

constexpr std::size_t kBigArrayBytes = std::size_t{32} << 20;

// Asks for huge pages on [p, p + bytes) and for the pages to be present, in parallel: zeroing
// fresh huge pages is the kernel's work, and on this VM it ran at 0.5 GB/s on one thread (the
// bunny's preparation spent 5.4 of its 15 s populating 3 GB); two threads populate 1 GiB in
// 0.74–0.82 s against 1.6–2.4 s on one.
void populate(void* p, std::size_t bytes);

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
