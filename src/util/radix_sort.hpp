// LSD radix sort of 64-bit keys by their bits [from, 64), 16 bits a pass, stable: for arrays too
// large to sort in cache, where the low bits carry a payload (an id) in the order it should keep
// among equal keys.
#pragma once
#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "util/big_array.hpp"

namespace adaptiso::detail {

inline void radix_sort(std::vector<std::uint64_t>& keys, std::vector<std::uint64_t>& scratch, int from) {
  resize_big(scratch, keys.size());
  std::vector<std::uint64_t> count(1 << 16);
  for (int shift = from; shift < 64; shift += 16) {
    std::fill(count.begin(), count.end(), 0);
    for (std::uint64_t k : keys) ++count[(k >> shift) & 0xffff];
    if (std::find(count.begin(), count.end(), keys.size()) != count.end()) continue;  // one digit value: nothing moves
    std::uint64_t sum = 0;
    for (auto& c : count) sum += std::exchange(c, sum);
    for (std::uint64_t k : keys) scratch[count[(k >> shift) & 0xffff]++] = k;
    keys.swap(scratch);
  }
}

}  // namespace adaptiso::detail
