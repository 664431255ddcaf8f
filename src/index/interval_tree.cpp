// The interval tree's build (see interval_tree.hpp for the invariants): the splits from a sample,
// the entries placed in their nodes, each node's two lists sorted. Its validation against a loaded
// grid is interval_tree_validate.cpp's, the sweep and the queries interval_tree_sweep.cpp's.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.4 (finding the cut tetrahedra).
// - Shen, Johnson. Sweeping simplices: a fast iso-surface extraction algorithm for unstructured
//   grids. IEEE Visualization 1995 (the sweep).
// - Cignoni, Marino, Montani, Puppo, Scopigno. Speeding up isosurface extraction using interval
//   trees. IEEE TVCG, 1997 (the tree; after Edelsbrunner's interval tree, 1980).
#include "adaptiso/interval_tree.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include <fmt/format.h>
#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <functional>
#include <mutex>
#include <numeric>
#include <type_traits>
#include <utility>

#include "adaptiso/error.hpp"
#include "index/tet_range.hpp"
#include "util/big_array.hpp"
#include "util/memory.hpp"
#include "util/radix_sort.hpp"

namespace adaptiso {
namespace {
using detail::prefetch_values;
using detail::Range;
using detail::range_reading_ahead;
using detail::tet_max;
using detail::tet_min;
using detail::tet_range;

// Fills lo/hi of every node bottom-up from its own entries and its children.
void compute_bounds(IntervalTree& tree, const TetGrid& grid) {
  for (std::size_t i = tree.nodes.size(); i-- > 0;) {
    auto& n = tree.nodes[i];
    n.lo = std::numeric_limits<double>::infinity();
    n.hi = -std::numeric_limits<double>::infinity();
    if (n.end > n.begin) {
      n.lo = tet_min(grid, tree.by_min[n.begin]);
      n.hi = tet_max(grid, tree.by_max[n.end - 1]);
    }
    if (!tree.is_leaf(i))
      for (std::size_t c : {2 * i + 1, 2 * i + 2}) {
        n.lo = std::min(n.lo, tree.nodes[c].lo);
        n.hi = std::max(n.hi, tree.nodes[c].hi);
      }
  }
}

// The splits come from records of (tmin, tmax, id) laid out contiguously, so partitioning and
// selecting medians stream through memory. Keys are floats when every value of the grid is one
// exactly (integer and float32 volumes: half the bytes), doubles otherwise; either way the order
// is the exact order of the values.
template <class K>
struct Record {
  K lo, hi;
  std::uint32_t id;
  double mid() const { return 0.5 * static_cast<double>(lo) + 0.5 * static_cast<double>(hi); }
};

// Chooses every node's split by partitioning records top-down (their order is then pre-order).
template <class K>
struct SplitChooser {
  IntervalTree& tree;
  Record<K>* recs;

  // The median midpoint of recs[b, e); above kSampled records, of an evenly spaced sample of them:
  // the top of the tree would otherwise select among millions of records on one core, while the
  // median of 65,536 samples lies within about 0.4 % of the records of the true one (two standard
  // errors).
  static constexpr std::uint64_t kSampled = std::uint64_t{1} << 20, kSample = std::uint64_t{1} << 16;
  double split_value(std::uint64_t b, std::uint64_t e) const {
    if (e - b <= kSampled) {
      auto by_mid = [](const Record<K>& a, const Record<K>& c) { return a.mid() < c.mid() || (a.mid() == c.mid() && a.id < c.id); };
      std::nth_element(recs + b, recs + b + (e - b) / 2, recs + e, by_mid);
      return recs[b + (e - b) / 2].mid();
    }
    std::vector<double> mids(kSample);
    for (std::uint64_t k = 0; k < kSample; ++k) mids[k] = recs[b + (e - b) * k / kSample].mid();
    std::nth_element(mids.begin(), mids.begin() + kSample / 2, mids.end());
    return mids[kSample / 2];
  }

  // recs[b, e) reach node i. A node no record reaches splits at 0 (any split is valid).
  void choose(std::size_t i, std::uint64_t b, std::uint64_t e) {
    if (tree.is_leaf(i)) return;
    auto& n = tree.nodes[i];
    n.split = b == e ? 0 : split_value(b, e);
    const double s = n.split;
    auto* here_end = std::partition(recs + b, recs + e, [&](const Record<K>& r) { return r.lo < s && r.hi > s; });
    auto* left_end = std::partition(here_end, recs + e, [&](const Record<K>& r) { return r.hi <= s; });
    const std::uint64_t h = static_cast<std::uint64_t>(here_end - recs), m = static_cast<std::uint64_t>(left_end - recs);
    if (e - b > (1u << 16))
      tbb::parallel_invoke([&] { choose(2 * i + 1, h, m); }, [&] { choose(2 * i + 2, m, e); });
    else {
      choose(2 * i + 1, h, m);
      choose(2 * i + 2, m, e);
    }
  }
};

// The node a tetrahedron lives in: down from the root until it straddles a split, or a leaf.
inline std::size_t node_of(const IntervalTree& tree, const Range& q) {
  std::size_t i = 0;
  while (!tree.is_leaf(i)) {
    const double s = tree.nodes[i].split;
    if (q.lo < s && q.hi > s) break;
    i = q.hi <= s ? 2 * i + 1 : 2 * i + 2;
  }
  return i;
}

// A float as an unsigned integer with the same order (−0 as +0, which compare equal), so a
// (key, id) pair sorts as one 64-bit integer.
inline std::uint64_t ordered(float f, std::uint32_t id) {
  if (f == 0) f = 0;
  const auto bits = std::bit_cast<std::uint32_t>(f);
  const std::uint32_t key = (bits & 0x80000000u) ? ~bits : bits | 0x80000000u;
  return (std::uint64_t{key} << 32) | id;
}

// Sorts keys (key << 32 | id, ids increasing) by the key alone, stably, so equal keys stay in id
// order, as a full sort leaves them. A radix sort but for the smallest nodes: the leaves of a
// large grid hold about ten thousand entries each, where std::sort took most of the index's time.
void sort_keys(std::vector<std::uint64_t>& keys, std::vector<std::uint64_t>& scratch) {
  if (keys.size() > 256)
    detail::radix_sort(keys, scratch, 32, keys.size() > (std::size_t{1} << 20) ? 16 : 11);
  else
    std::sort(keys.begin(), keys.end());
}

// Sorts one node's entries, in by_min[b, e) and by_max[b, e) in increasing id order, by (tmin, id)
// and (tmax, id). Each tetrahedron's range is read once (its tetrahedron and four values, from
// scattered places: prefetched ahead) for both keys.
//
// For float keys, two arrays of keys, not three: while the keys by minimum are sorted, the keys by
// maximum wait in by_max (32 bits) and the ids in by_min. They are the caller's, one pair per
// worker: not thread_local, since a thread waiting inside the nested parallel_for that populates
// a large array may run another node's sort meanwhile.
template <class K>
void sort_node(const TetGrid& grid, IntervalTree& tree, std::uint64_t b, std::uint64_t e, std::vector<std::uint64_t>& a,
               std::vector<std::uint64_t>& c) {
  std::uint32_t* by_min = tree.by_min.data();
  std::uint32_t* by_max = tree.by_max.data();
  if constexpr (std::is_same_v<K, float>) {
    detail::resize_big(a, e - b);  // a node of millions: faulted in on huge pages, not page by page
    for (std::uint64_t i = b; i < e; ++i) {
      const Range q = range_reading_ahead(grid, by_min, i, e);
      a[i - b] = ordered(static_cast<float>(q.lo), by_min[i]);
      by_max[i] = static_cast<std::uint32_t>(ordered(static_cast<float>(q.hi), 0) >> 32);
    }
    sort_keys(a, c);
    detail::resize_big(c, e - b);
    for (std::uint64_t i = b; i < e; ++i) c[i - b] = std::uint64_t{by_max[i]} << 32 | by_min[i];
    for (std::uint64_t i = b; i < e; ++i) by_min[i] = static_cast<std::uint32_t>(a[i - b]);
    sort_keys(c, a);
    for (std::uint64_t i = b; i < e; ++i) by_max[i] = static_cast<std::uint32_t>(c[i - b]);
    if (e - b > (std::uint64_t{1} << 16)) {  // do not keep tens of megabytes per thread
      std::vector<std::uint64_t>().swap(a);
      std::vector<std::uint64_t>().swap(c);
    }
  } else {
    std::vector<std::pair<K, std::uint32_t>> lo(e - b), hi(e - b);
    for (std::uint64_t i = b; i < e; ++i) {
      const Range q = tet_range(grid, by_min[i]);
      lo[i - b] = {q.lo, by_min[i]};
      hi[i - b] = {q.hi, by_min[i]};
    }
    for (auto* keys : {&lo, &hi}) {
      if (e - b > (std::uint64_t{1} << 16))
        tbb::parallel_sort(keys->begin(), keys->end());
      else
        std::sort(keys->begin(), keys->end());
    }
    for (std::uint64_t i = b; i < e; ++i) {
      by_min[i] = lo[i - b].second;
      by_max[i] = hi[i - b].second;
    }
  }
}

// A (key, id) pair as one comparable value: a 64-bit integer for float keys, a pair otherwise.
template <class K>
using SortKey = std::conditional_t<std::is_same_v<K, float>, std::uint64_t, std::pair<double, std::uint32_t>>;

template <class K>
SortKey<K> sort_key(double key, std::uint32_t id) {
  if constexpr (std::is_same_v<K, float>)
    return ordered(static_cast<float>(key), id);
  else
    return {key, id};
}

template <class K>
std::uint32_t id_of(const SortKey<K>& k) {
  if constexpr (std::is_same_v<K, float>)
    return static_cast<std::uint32_t>(k);
  else
    return k.second;
}

// Sorts (key, id) pairs: for float keys a radix sort, by the key alone (stable) when the ids come
// in increasing order, by key and id otherwise.
template <class K>
void sort_pairs(std::vector<SortKey<K>>& keys, std::vector<SortKey<K>>& scratch, bool ids_increasing) {
  if constexpr (std::is_same_v<K, float>) {
    if (ids_increasing)
      sort_keys(keys, scratch);
    else if (keys.size() > 256)
      detail::radix_sort(keys, scratch, 0, 11);
    else
      std::sort(keys.begin(), keys.end());
  } else {
    std::sort(keys.begin(), keys.end());
  }
}

// sort_node's result without a key per entry held: the memory-lean sort of the nodes too large
// for sort_node's 16 bytes an entry (the MR head's largest node holds 28 M entries: 426 MiB).
// Each entry gets a bucket by minimum and one by maximum, one byte each, from (key, id) splitters
// of a sample, in one read of the ranges in id order. The ids are then grouped by bucket, by
// maximum into by_max (a scatter) and by minimum within by_min (a permutation in place), and each
// bucket, n / 256 entries, is sorted on its own from its keys read again. Parallel but for the
// permutation.
template <class K>
void sort_node_lean(const TetGrid& grid, IntervalTree& tree, std::uint64_t b, std::uint64_t e) {
  using Key = SortKey<K>;
  constexpr std::size_t kBuckets = 256;
  std::uint32_t* by_min = tree.by_min.data() + b;
  std::uint32_t* by_max = tree.by_max.data() + b;
  const std::uint64_t n = e - b;
  auto key_lo = [](const Range& q, std::uint32_t t) { return sort_key<K>(q.lo, t); };
  auto key_hi = [](const Range& q, std::uint32_t t) { return sort_key<K>(q.hi, t); };
  // Splitters: bucket j holds the keys k with splitter[j - 1] <= k < splitter[j].
  auto splitters_of = [&](auto key_of) {
    const std::uint64_t stride = std::max<std::uint64_t>(1, n / (kBuckets * 64));
    std::vector<Key> sample;
    for (std::uint64_t i = 0; i < n; i += stride) sample.push_back(key_of(tet_range(grid, by_min[i]), by_min[i]));
    std::sort(sample.begin(), sample.end());
    std::vector<Key> splitters(kBuckets - 1);
    for (std::size_t j = 1; j < kBuckets; ++j) splitters[j - 1] = sample[sample.size() * j / kBuckets];
    return splitters;
  };
  const std::vector<Key> split_lo = splitters_of(key_lo), split_hi = splitters_of(key_hi);
  // The number of splitters <= k, branch-free (std::upper_bound's branches mispredict).
  auto bucket_of = [](const std::vector<Key>& splitters, const Key& k) {
    std::size_t j = 0;
    for (std::size_t half = kBuckets / 2; half > 0; half /= 2) j += splitters[j + half - 1] <= k ? half : 0;
    return static_cast<std::uint8_t>(j);
  };
  const std::size_t chunks = std::clamp<std::size_t>(n >> 16, 1, 256);
  auto chunk = [&](std::size_t c) { return std::pair{n * c / chunks, n * (c + 1) / chunks}; };
  std::vector<std::uint8_t> lo_bucket, hi_bucket;
  detail::resize_big(lo_bucket, n);
  detail::resize_big(hi_bucket, n);
  std::vector<std::uint64_t> at_hi(chunks * kBuckets, 0), count_lo(chunks * kBuckets, 0);
  tbb::parallel_for(std::size_t{0}, chunks, [&](std::size_t c) {
    const auto [cb, ce] = chunk(c);
    for (std::uint64_t i = cb; i < ce; ++i) {
      const Range q = range_reading_ahead(grid, by_min, i, ce);
      ++count_lo[c * kBuckets + (lo_bucket[i] = bucket_of(split_lo, key_lo(q, by_min[i])))];
      ++at_hi[c * kBuckets + (hi_bucket[i] = bucket_of(split_hi, key_hi(q, by_min[i])))];
    }
  });
  // Bucket starts; at_hi becomes each chunk's place within its bucket.
  std::vector<std::uint64_t> start_lo(kBuckets + 1, 0), start_hi(kBuckets + 1, 0);
  for (std::size_t j = 0; j < kBuckets; ++j) {
    start_lo[j + 1] = start_lo[j];
    start_hi[j + 1] = start_hi[j];
    for (std::size_t c = 0; c < chunks; ++c) {
      start_lo[j + 1] += count_lo[c * kBuckets + j];
      start_hi[j + 1] += std::exchange(at_hi[c * kBuckets + j], start_hi[j + 1]);
    }
  }
  tbb::parallel_for(std::size_t{0}, chunks, [&](std::size_t c) {
    const auto [cb, ce] = chunk(c);
    for (std::uint64_t i = cb; i < ce; ++i) by_max[at_hi[c * kBuckets + hi_bucket[i]]++] = by_min[i];
  });
  std::vector<std::uint8_t>().swap(hi_bucket);
  // by_min grouped by bucket in place: each misplaced entry is swapped into the next free place of
  // its bucket until the entry that belongs here arrives (American flag sort's permutation).
  std::vector<std::uint64_t> next(start_lo.begin(), start_lo.end() - 1);
  for (std::size_t j = 0; j < kBuckets; ++j)
    for (std::uint64_t i = next[j]; i < start_lo[j + 1]; i = ++next[j]) {
      std::uint32_t id = by_min[i];
      std::uint8_t k = lo_bucket[i];
      while (k != j) {
        const std::uint64_t to = next[k]++;
        std::swap(id, by_min[to]);
        std::swap(k, lo_bucket[to]);
      }
      by_min[i] = id;
    }
  std::vector<std::uint8_t>().swap(lo_bucket);
  // The scatter kept by_max's buckets in id order; the permutation did not keep by_min's.
  auto sort_buckets = [&](std::uint32_t* ids, const std::vector<std::uint64_t>& start, bool ids_increasing, auto key_of) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, kBuckets, 1), [&](const auto& r) {
      std::vector<Key> keys, scratch;
      for (std::size_t j = r.begin(); j < r.end(); ++j) {
        const std::uint64_t jb = start[j], je = start[j + 1];
        keys.resize(je - jb);
        for (std::uint64_t i = jb; i < je; ++i) keys[i - jb] = key_of(range_reading_ahead(grid, ids, i, je), ids[i]);
        sort_pairs<K>(keys, scratch, ids_increasing);
        for (std::uint64_t i = jb; i < je; ++i) ids[i] = id_of<K>(keys[i - jb]);
      }
    });
  };
  sort_buckets(by_min, start_lo, false, key_lo);
  sort_buckets(by_max, start_hi, true, key_hi);
}

// Every node's two lists sorted. Nodes whose sort_node would take more than this thread's share
// of scratch_bytes (16 bytes an entry; 32 for double keys) are sorted first, one at a time, each
// in parallel, by sort_node_lean (2 bytes an entry); the others in parallel, largest first, so the
// threads finish together.
template <class K>
void sort_lists(IntervalTree& tree, const TetGrid& grid, std::size_t scratch_bytes) {
  std::vector<std::size_t> order(tree.nodes.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  auto size = [&](std::size_t i) { return tree.nodes[i].end - tree.nodes[i].begin; };
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return size(a) > size(b); });
  const std::size_t share = scratch_bytes / static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  const std::size_t per_entry = std::is_same_v<K, float> ? 16 : 32;
  std::size_t lean = 0;
  while (lean < order.size() && size(order[lean]) * per_entry > share) ++lean;
  for (std::size_t k = 0; k < lean; ++k) sort_node_lean<K>(grid, tree, tree.nodes[order[k]].begin, tree.nodes[order[k]].end);
  // Each worker takes the largest node left. A parallel_for over the nodes did not: its threads
  // steal the far half of each other's ranges, the small nodes, and it left the two largest (the
  // bunny's 12 and 11 M entries) to one thread, one after the other, while the other idled. Each
  // node's sort is isolated, so that a worker waiting in its nested populate does not start
  // another worker's loop in the meantime.
  std::atomic<std::size_t> next{lean};
  const int threads = tbb::this_task_arena::max_concurrency();
  tbb::parallel_for(0, threads, [&](int) {
    std::vector<std::uint64_t> a, c;
    for (std::size_t k; (k = next.fetch_add(1, std::memory_order_relaxed)) < order.size();)
      tbb::this_task_arena::isolate([&] { sort_node<K>(grid, tree, tree.nodes[order[k]].begin, tree.nodes[order[k]].end, a, c); });
  });
}

// Calls f(block, t, range) for every non-constant tetrahedron and constant(t) for the others,
// blocks of consecutive ids in parallel, each block's in id order.
template <class F, class G = void (*)(std::uint32_t)>
void for_each_nonconstant(
    const TetGrid& grid, std::size_t blocks, F f, G constant = [](std::uint32_t) {}) {
  const std::size_t T = grid.tet_count();
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    for (std::size_t t = T * b / blocks; t < T * (b + 1) / blocks; ++t) {
      const Range q = tet_range(grid, static_cast<std::uint32_t>(t));
      if (q.lo < q.hi)
        f(b, static_cast<std::uint32_t>(t), q);
      else
        constant(static_cast<std::uint32_t>(t));
    }
  });
}

constexpr std::size_t kSampleTarget = std::size_t{1} << 22;
// Odd (an even stride in step with a periodic order of the tetrahedra would sample one kind of
// them only), rounded up, so at most about kSampleTarget records are held (the chest CT at 0.05, 7.6 M
// tetrahedra, held 60 MiB of them at every id).
std::size_t sample_stride(std::size_t tets) { return tets <= kSampleTarget ? 1 : ((tets + kSampleTarget - 1) / kSampleTarget) | 1; }

// The depth asked for, reduced while there would be more leaves than entries (estimated from the
// non-constant tetrahedra among the sampled ones).
std::uint32_t reduced_depth(std::uint32_t depth, std::uint64_t sampled_nonconstant, std::size_t stride) {
  depth = std::min<std::uint32_t>(depth, 30);
  while (depth > 0 && (std::uint64_t{1} << depth) > sampled_nonconstant * stride) --depth;
  return depth;
}

// The splits, from a sample of the non-constant tetrahedra: all of them up to kSampleTarget
// tetrahedra, beyond that those whose id is a multiple of an odd stride (at most about kSampleTarget).
// Sets tree.depth (reduced where there are fewer entries, or estimated entries, than leaves) and
// every node's split.
// The tetrahedra with ids k·stride, taken in blocks of 2^16 k: f(t, range) for each non-constant
// one of block b, in id order.
constexpr std::size_t kSampleBlock = std::size_t{1} << 16;
template <class F>
void for_each_sampled(const TetGrid& grid, std::size_t stride, std::size_t b, F f) {
  const std::size_t sampled = (grid.tet_count() + stride - 1) / stride;
  for (std::size_t k = b * kSampleBlock; k < std::min(sampled, (b + 1) * kSampleBlock); ++k) {
    const auto t = static_cast<std::uint32_t>(k * stride);
    const Range q = tet_range(grid, t);
    if (q.lo < q.hi) f(t, q);
  }
}

// Where each block's non-constant sampled tetrahedra start among all of them (blocks + 1 values,
// the last their count). Parallel.
std::vector<std::uint64_t> sampled_starts(const TetGrid& grid, std::size_t stride) {
  const std::size_t blocks = ((grid.tet_count() + stride - 1) / stride + kSampleBlock - 1) / kSampleBlock;
  std::vector<std::uint64_t> at(blocks + 1, 0);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    std::uint64_t n = 0;  // counted here, stored once: neighbouring blocks' counters share cache lines
    for_each_sampled(grid, stride, b, [&](std::uint32_t, const Range&) { ++n; });
    at[b + 1] = n;
  });
  std::partial_sum(at.begin(), at.end(), at.begin());
  return at;
}

template <class K>
void choose_splits(IntervalTree& tree, const TetGrid& grid, std::uint32_t depth) {
  const std::size_t stride = sample_stride(grid.tet_count());
  // Counted, then written in place: the records are held once (not per block and then gathered,
  // which freed blocks in the worker threads' arenas would keep resident beside the whole).
  std::vector<std::uint64_t> at = sampled_starts(grid, stride);
  std::vector<Record<K>> recs;
  detail::resize_big(recs, at.back());
  tbb::parallel_for(std::size_t{0}, at.size() - 1, [&](std::size_t b) {
    for_each_sampled(grid, stride, b, [&](std::uint32_t t, const Range& q) {
      recs[at[b]++] = {static_cast<K>(q.lo), static_cast<K>(q.hi), t};
    });
  });
  tree.depth = reduced_depth(depth, recs.size(), stride);
  tree.nodes.resize((std::size_t{2} << tree.depth) - 1);
  SplitChooser<K>{tree, recs.data()}.choose(0, 0, recs.size());
}

// Lays every non-constant tetrahedron into its node's range of by_min (nodes in pre-order, ids
// increasing within each) and sizes by_max alike: count per block and node, then place.
void place_entries(IntervalTree& tree, const TetGrid& grid) {
  const std::size_t nodes = tree.nodes.size();
  // Per-block counters, at most 16 M of them in all (64 MB); 256 blocks keep both cores busy.
  const std::size_t blocks = std::clamp<std::size_t>(std::min<std::size_t>((grid.tet_count() >> 16) + 1, 256), 1,
                                                     std::max<std::size_t>(1, (std::size_t{1} << 24) / nodes));
  std::vector<std::uint32_t> at(blocks * nodes, 0);
  // Each tetrahedron's node, kept from counting to placing where it fits 16 bits (2 bytes a
  // tetrahedron for a second walk down the splits saved); kNone for a constant one.
  constexpr std::uint16_t kNone = 0xffff;
  std::vector<std::uint16_t> kept;
  if (nodes < kNone) detail::resize_big(kept, grid.tet_count());
  for_each_nonconstant(
      grid, blocks,
      [&](std::size_t b, std::uint32_t t, const Range& q) {
        const std::size_t i = node_of(tree, q);
        ++at[b * nodes + i];
        if (!kept.empty()) kept[t] = static_cast<std::uint16_t>(i);
      },
      [&](std::uint32_t t) {
        if (!kept.empty()) kept[t] = kNone;
      });
  // Nodes in pre-order, each a range; then each block's start within its node's range.
  std::uint64_t cursor = 0;
  std::vector<std::size_t> stack{0};
  while (!stack.empty()) {
    const std::size_t i = stack.back();
    stack.pop_back();
    auto& n = tree.nodes[i];
    n.begin = cursor;
    for (std::size_t b = 0; b < blocks; ++b) cursor += std::exchange(at[b * nodes + i], static_cast<std::uint32_t>(cursor));
    n.end = cursor;
    if (!tree.is_leaf(i)) {
      stack.push_back(2 * i + 2);
      stack.push_back(2 * i + 1);
    }
  }
  detail::resize_big(tree.by_min, cursor);
  if (kept.empty()) {
    for_each_nonconstant(grid, blocks,
                         [&](std::size_t b, std::uint32_t t, const Range& q) { tree.by_min[at[b * nodes + node_of(tree, q)]++] = t; });
  } else {
    const std::size_t T = grid.tet_count();
    tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
      for (std::size_t t = T * b / blocks; t < T * (b + 1) / blocks; ++t)
        if (kept[t] != kNone) tree.by_min[at[b * nodes + kept[t]]++] = static_cast<std::uint32_t>(t);
    });
  }
  // by_max, written when the nodes are sorted, only once the nodes kept are gone: the two never
  // add to the peak together (the MR head: 160 MiB of nodes, 321 MiB of by_max).
  std::vector<std::uint16_t>().swap(kept);
  detail::release_free_heap();  // the nodes kept, from the heap (under 32 MiB, the chest's 20 MiB)
  detail::resize_big(tree.by_max, cursor);
}

template <class K>
IntervalTree build_with(const TetGrid& grid, std::uint32_t depth, std::size_t scratch_bytes) {
  IntervalTree tree;
  choose_splits<K>(tree, grid, depth);
  // The sample's records, and what earlier stages freed, can stay in the heap once those stages
  // have raised glibc's mmap threshold (15–31 MiB on the chest CT), under the lists otherwise.
  detail::release_free_heap();
  place_entries(tree, grid);
  // What choosing and placing freed (the sample's records, the counters) can stay in the heap's
  // arenas, resident through the sort: returning it lowered the MR head's peak by 51 MiB.
  detail::release_free_heap();
  sort_lists<K>(tree, grid, scratch_bytes);
  return tree;
}

}  // namespace

IntervalTree build_interval_tree(const TetGrid& grid, std::uint32_t depth, std::size_t scratch_bytes) {
  if (grid.tet_count() > std::numeric_limits<std::uint32_t>::max()) throw InputError("too many tetrahedra for the interval tree");
  const bool floats = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, grid.values.size(), 1 << 16), true,
      [&](const auto& r, bool ok) {
        for (std::size_t v = r.begin(); ok && v < r.end(); ++v)
          ok = static_cast<double>(static_cast<float>(grid.values[v])) == grid.values[v];
        return ok;
      },
      [](bool a, bool b) { return a && b; });
  IntervalTree tree = floats ? build_with<float>(grid, depth, scratch_bytes) : build_with<double>(grid, depth, scratch_bytes);
  compute_bounds(tree, grid);
  return tree;
}

IntervalTreeShape interval_tree_shape(const TetGrid& grid, std::uint32_t depth) {
  const std::size_t stride = sample_stride(grid.tet_count());
  // The entries are every non-constant tetrahedron; the depth, choose_splits' from its sample.
  const std::uint64_t entries = sampled_starts(grid, 1).back();
  return interval_tree_shape(grid.tet_count(), entries, stride == 1 ? entries : sampled_starts(grid, stride).back(), depth);
}

std::size_t interval_tree_sample_stride(std::uint64_t tets) { return sample_stride(static_cast<std::size_t>(tets)); }

IntervalTreeShape interval_tree_shape(std::uint64_t tets, std::uint64_t entries, std::uint64_t sampled, std::uint32_t depth) {
  return {reduced_depth(depth, sampled, sample_stride(static_cast<std::size_t>(tets))), entries};
}

void finish_interval_tree(IntervalTree& tree, const TetGrid& grid) { compute_bounds(tree, grid); }

}  // namespace adaptiso
