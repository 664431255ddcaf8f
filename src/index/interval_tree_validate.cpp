// Checking an interval tree loaded from disk against its grid (see interval_tree.hpp:
// validate_interval_tree): sizes, nested ranges, every entry once in each list, sorted lists.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.4 (finding the cut tetrahedra).
// - Shen, Johnson. Sweeping simplices: a fast iso-surface extraction algorithm for unstructured
//   grids. IEEE Visualization 1995 (the sweep).
// - Cignoni, Marino, Montani, Puppo, Scopigno. Speeding up isosurface extraction using interval
//   trees. IEEE TVCG, 1997 (the tree; after Edelsbrunner's interval tree, 1980).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <fmt/format.h>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <iterator>

#include "adaptiso/error.hpp"
#include "adaptiso/interval_tree.hpp"
#include "index/tet_range.hpp"
#include "util/big_array.hpp"
#include "util/progress_counter.hpp"

namespace adaptiso {
using detail::prefetch_values;
using detail::Range;
using detail::tet_max;
using detail::tet_min;
using detail::tet_range;

namespace {

// A non-empty node and its first entry: the nodes in pre-order tile the lists, so an entry's node
// is found by binary search and the entries can be checked in even chunks (the root alone holds
// a tenth of the bunny's 52 M).
struct NodeStart {
  std::uint64_t begin;
  std::size_t node;
};

// Calls check(node, b, e) on the pieces of nodes that tile each chunk of [0, entries), in
// parallel; check returns false to stop its chunk.
template <class Check>
void check_entries_in_chunks(const std::vector<NodeStart>& starts, const IntervalTree& tree, Check check) {
  tbb::parallel_for(tbb::blocked_range<std::uint64_t>(0, tree.entries(), std::uint64_t{1} << 16), [&](const auto& r) {
    auto s = std::upper_bound(starts.begin(), starts.end(), r.begin(), [](std::uint64_t k, const NodeStart& n) { return k < n.begin; });
    for (std::uint64_t k = r.begin(); k < r.end(); ++s) {
      const std::size_t i = std::prev(s)->node;
      const std::uint64_t e = std::min<std::uint64_t>(tree.nodes[i].end, r.end());
      if (!check(i, k, e)) return;
      k = e;
    }
  });
}

}  // namespace

void validate_interval_tree(const IntervalTree& tree, const TetGrid& grid, const std::string& what, const Progress& progress) {
  auto fail = [&](const std::string& why) { throw InputError(fmt::format("{}: extraction index is corrupt ({})", what, why)); };
  const std::size_t T = grid.tet_count();
  if (tree.depth > 30 || tree.nodes.size() != (std::size_t{2} << tree.depth) - 1) fail("node count");
  if (tree.by_min.size() != tree.by_max.size() || tree.by_min.size() > T) fail("list sizes");
  // 1. The nodes, in pre-order: own entries first, children follow; each with the key interval its
  // ancestors' splits allow.
  struct Allowed {
    double lo, hi;
  };
  std::vector<Allowed> allowed(tree.nodes.size());
  std::vector<NodeStart> starts;
  std::uint64_t cursor = 0;
  std::vector<std::size_t> stack{0};
  allowed[0] = {-std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  while (!stack.empty()) {
    const std::size_t i = stack.back();
    stack.pop_back();
    const auto& n = tree.nodes[i];
    if (n.begin != cursor || n.end < n.begin || n.end > tree.by_min.size()) fail("node ranges");
    if (n.end > n.begin) starts.push_back({n.begin, i});
    cursor = n.end;
    if (!tree.is_leaf(i)) {
      if (!std::isfinite(n.split) && n.end > n.begin) fail("split value");
      allowed[2 * i + 2] = {std::max(allowed[i].lo, n.split), allowed[i].hi};
      allowed[2 * i + 1] = {allowed[i].lo, std::min(allowed[i].hi, n.split)};
      stack.push_back(2 * i + 2);  // right first, so the left subtree is visited next
      stack.push_back(2 * i + 1);
    }
  }
  if (cursor != tree.by_min.size()) fail("node ranges do not cover the lists");
  // 2. Every node's entries, in parallel: in range, once each, inside their node's interval,
  // straddling its split, both lists sorted and holding the same tetrahedra. Each entry reads its
  // tetrahedron, four values and its node_of slot at scattered places: those are the cost (8 of
  // the bunny's 13 s load when read one by one), so they are prefetched a few entries ahead and
  // the previous entry's key is carried instead of read again.
  constexpr std::uint32_t kUnseen = std::numeric_limits<std::uint32_t>::max();
  std::vector<std::uint32_t> node_of;
  detail::assign_big(node_of, T, kUnseen);
  std::atomic<bool> bad{false};
  std::string why;
  std::mutex why_mutex;
  auto report = [&](const char* reason) {
    std::lock_guard lock(why_mutex);
    if (!bad.exchange(true)) why = reason;
    return false;
  };
  // Progress over both lists' entries, told at most a hundred times.
  detail::ProgressCounter checked(progress, "check index", 2 * tree.entries());
  auto advance = [&](std::uint64_t n) { checked.advance(n); };
  adaptiso::report(progress, "check index", 0);
  auto ahead = [&](const std::uint32_t* list, std::uint64_t k, std::uint64_t e) {
    if (k + 16 < e && list[k + 16] < T) {
      detail::prefetch(&grid.tets[list[k + 16]]);
      detail::prefetch(&node_of[list[k + 16]]);
    }
    if (k + 8 < e && list[k + 8] < T) prefetch_values(grid, list[k + 8]);
  };
  // One list's entries, chunk by chunk: entry(i, t, key) checks tetrahedron t in node i and gives
  // its key (false once it has reported); the keys must not decrease within a node. The key of the
  // entry before a chunk's first is read afresh (−∞ at a node's first).
  auto check_list = [&](const std::vector<std::uint32_t>& entries, auto key_of, const char* unsorted, auto entry) {
    check_entries_in_chunks(starts, tree, [&](std::size_t i, std::uint64_t b, std::uint64_t e) {
      if (bad.load(std::memory_order_relaxed)) return false;
      const std::uint32_t* list = entries.data();  // local, so the atomics below need not make it be reloaded
      double prev = -std::numeric_limits<double>::infinity();
      if (b > tree.nodes[i].begin) {
        if (list[b - 1] >= T) return report("entry out of range or repeated");
        prev = key_of(grid, list[b - 1]);
      }
      for (std::uint64_t k = b; k < e; ++k) {
        ahead(list, k, e);
        double key = 0;  // set by entry whenever it returns true
        if (!entry(i, list[k], key)) return false;
        if (prev > key) return report(unsorted);  // ties in any order (repeats are caught by entry)
        prev = key;
      }
      advance(e - b);
      return true;
    });
    if (bad) fail(why);
  };
  check_list(tree.by_min, tet_min, "list by minimum not sorted", [&](std::size_t i, std::uint32_t t, double& key) {
    std::uint32_t unseen = kUnseen;
    if (t >= T || !std::atomic_ref<std::uint32_t>(node_of[t]).compare_exchange_strong(unseen, static_cast<std::uint32_t>(i)))
      return report("entry out of range or repeated");
    const Range q = tet_range(grid, t);
    if (!(q.lo < q.hi) || q.lo < allowed[i].lo || q.hi > allowed[i].hi) return report("entry outside its node");
    if (!tree.is_leaf(i) && !(q.lo < tree.nodes[i].split && q.hi > tree.nodes[i].split)) return report("entry does not straddle its split");
    key = q.lo;
    return true;
  });
  check_list(tree.by_max, tet_max, "list by maximum not sorted", [&](std::size_t i, std::uint32_t t, double& key) {
    std::uint32_t mine = static_cast<std::uint32_t>(i);
    if (t >= T || !std::atomic_ref<std::uint32_t>(node_of[t]).compare_exchange_strong(mine, kUnseen - 1)) return report("lists disagree");
    key = tet_max(grid, t);
    return true;
  });
  // 3. Every tetrahedron that is not constant is in the lists.
  const std::size_t nonconstant = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, T, 1 << 16), std::size_t{0},
      [&](const auto& r, std::size_t c) {
        for (std::size_t t = r.begin(); t < r.end(); ++t) {
          const Range q = tet_range(grid, static_cast<std::uint32_t>(t));
          c += q.lo < q.hi;
        }
        return c;
      },
      std::plus<>());
  if (nonconstant != tree.by_min.size()) fail("tetrahedra missing");
}

}  // namespace adaptiso
