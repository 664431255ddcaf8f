// LSD radix sort of 64-bit keys by their bits [from, 64), `bits` bits a pass (16 for arrays of
// millions; fewer for smaller ones, whose passes would otherwise be spent clearing and summing
// the counts), stable: for arrays too large to sort in cache, where the low bits carry a payload
// (an id) in the order it should keep among equal keys.
#pragma once
#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "util/big_array.hpp"

namespace adaptiso::detail {

inline void radix_sort(std::vector<std::uint64_t>& keys, std::vector<std::uint64_t>& scratch, int from, int bits = 16) {
  resize_big(scratch, keys.size());
  const std::uint64_t mask = (std::uint64_t{1} << bits) - 1;
  std::vector<std::uint64_t> count(std::size_t{1} << bits);
  for (int shift = from; shift < 64; shift += bits) {
    std::fill(count.begin(), count.end(), 0);
    for (std::uint64_t k : keys) ++count[(k >> shift) & mask];
    if (std::find(count.begin(), count.end(), keys.size()) != count.end()) continue;  // one digit value: nothing moves
    std::uint64_t sum = 0;
    for (auto& c : count) sum += std::exchange(c, sum);
    for (std::uint64_t k : keys) scratch[count[(k >> shift) & mask]++] = k;
    keys.swap(scratch);
  }
}

}  // namespace adaptiso::detail
