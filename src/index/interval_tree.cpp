// Sweeping simplices (Lürig & Ertl §2.4): the interval tree, its per-client sweep state, and the
// brute-force scan used as the reference. See interval_tree.hpp for the invariants.
#include "adaptiso/interval_tree.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <fmt/format.h>
#include <algorithm>
#include <cmath>

#include "adaptiso/error.hpp"
#include "util/prefetch.hpp"

namespace adaptiso {
namespace {
using detail::prefetch_values;

struct Range {
  double lo, hi;
};

inline Range tet_range(const TetGrid& grid, std::uint32_t t) {
  const auto& q = grid.tets[t];
  const double* v = grid.values.data();
  double a = v[q[0]], b = v[q[1]], c = v[q[2]], d = v[q[3]];
  return {std::min(std::min(a, b), std::min(c, d)), std::max(std::max(a, b), std::max(c, d))};
}

inline double tet_min(const TetGrid& grid, std::uint32_t t) { return tet_range(grid, t).lo; }
inline double tet_max(const TetGrid& grid, std::uint32_t t) { return tet_range(grid, t).hi; }

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

// Sorts each node's range of by_min by (tmin, id) and of by_max by (tmax, id).
void sort_lists(IntervalTree& tree, const std::vector<double>& tmin, const std::vector<double>& tmax) {
  tbb::parallel_for(std::size_t{0}, tree.nodes.size(), [&](std::size_t i) {
    const auto& n = tree.nodes[i];
    std::sort(tree.by_min.begin() + n.begin, tree.by_min.begin() + n.end,
              [&](std::uint32_t a, std::uint32_t b) { return tmin[a] < tmin[b] || (tmin[a] == tmin[b] && a < b); });
    std::sort(tree.by_max.begin() + n.begin, tree.by_max.begin() + n.end,
              [&](std::uint32_t a, std::uint32_t b) { return tmax[a] < tmax[b] || (tmax[a] == tmax[b] && a < b); });
  });
}

struct Builder {
  IntervalTree& tree;
  const std::vector<double>& tmin;
  const std::vector<double>& tmax;

  double mid(std::uint32_t t) const { return 0.5 * tmin[t] + 0.5 * tmax[t]; }

  // ids[b, e) reach node i at level `level`; lays them out in pre-order: own entries first.
  void build(std::size_t i, std::uint32_t level, std::uint64_t b, std::uint64_t e) {
    auto& n = tree.nodes[i];
    auto* ids = tree.by_min.data();
    if (tree.is_leaf(i) || b == e) {
      n.begin = b;
      n.end = e;
      if (!tree.is_leaf(i)) {  // empty subtree: give the children empty ranges at e
        n.split = 0;
        build(2 * i + 1, level + 1, e, e);
        build(2 * i + 2, level + 1, e, e);
      }
      return;
    }
    auto by_mid = [&](std::uint32_t a, std::uint32_t c) { return mid(a) < mid(c) || (mid(a) == mid(c) && a < c); };
    std::nth_element(ids + b, ids + b + (e - b) / 2, ids + e, by_mid);
    const double s = mid(ids[b + (e - b) / 2]);
    auto* here_end = std::partition(ids + b, ids + e, [&](std::uint32_t t) { return tmin[t] < s && tmax[t] > s; });
    auto* left_end = std::partition(here_end, ids + e, [&](std::uint32_t t) { return tmax[t] <= s; });
    n.split = s;
    n.begin = b;
    n.end = static_cast<std::uint64_t>(here_end - ids);
    const std::uint64_t m = static_cast<std::uint64_t>(left_end - ids);
    if (e - b > (1u << 16))
      tbb::parallel_invoke([&] { build(2 * i + 1, level + 1, n.end, m); }, [&] { build(2 * i + 2, level + 1, m, e); });
    else {
      build(2 * i + 1, level + 1, n.end, m);
      build(2 * i + 2, level + 1, m, e);
    }
  }
};

}  // namespace

IntervalTree build_interval_tree(const TetGrid& grid, std::uint32_t depth) {
  const std::size_t T = grid.tet_count();
  if (T > std::numeric_limits<std::uint32_t>::max()) throw InputError("too many tetrahedra for the interval tree");
  std::vector<double> tmin(T), tmax(T);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T), [&](const auto& r) {
    for (std::size_t t = r.begin(); t < r.end(); ++t) {
      Range q = tet_range(grid, static_cast<std::uint32_t>(t));
      tmin[t] = q.lo;
      tmax[t] = q.hi;
    }
  });
  IntervalTree tree;
  tree.by_min.reserve(T);
  for (std::size_t t = 0; t < T; ++t)
    if (tmin[t] < tmax[t]) tree.by_min.push_back(static_cast<std::uint32_t>(t));
  depth = std::min<std::uint32_t>(depth, 30);
  while (depth > 0 && (std::uint64_t{1} << depth) > tree.by_min.size()) --depth;
  tree.depth = depth;
  tree.nodes.resize((std::size_t{2} << depth) - 1);
  Builder{tree, tmin, tmax}.build(0, 0, 0, tree.by_min.size());
  tree.by_max = tree.by_min;
  sort_lists(tree, tmin, tmax);
  compute_bounds(tree, grid);
  return tree;
}

void finish_interval_tree(IntervalTree& tree, const TetGrid& grid) { compute_bounds(tree, grid); }

void validate_interval_tree(const IntervalTree& tree, const TetGrid& grid, const std::string& what) {
  auto fail = [&](const std::string& why) { throw InputError(fmt::format("{}: extraction index is corrupt ({})", what, why)); };
  const std::size_t T = grid.tet_count();
  if (tree.depth > 30 || tree.nodes.size() != (std::size_t{2} << tree.depth) - 1) fail("node count");
  if (tree.by_min.size() != tree.by_max.size() || tree.by_min.size() > T) fail("list sizes");
  // Ranges: pre-order, own entries first, children follow; keys inside the interval inherited from
  // the ancestors' splits; interior entries straddle their split.
  std::vector<std::uint32_t> node_of(T, std::numeric_limits<std::uint32_t>::max());
  struct Item {
    std::size_t i;
    double lo, hi;
  };  // node, and the key interval its ancestors allow
  std::uint64_t cursor = 0;
  std::vector<Item> stack{{0, -std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()}};
  while (!stack.empty()) {
    Item it = stack.back();
    stack.pop_back();
    const auto& n = tree.nodes[it.i];
    if (n.begin != cursor || n.end < n.begin || n.end > tree.by_min.size()) fail("node ranges");
    cursor = n.end;
    const bool leaf = tree.is_leaf(it.i);
    if (!leaf && !std::isfinite(n.split) && n.end > n.begin) fail("split value");
    for (std::uint64_t k = n.begin; k < n.end; ++k) {
      std::uint32_t t = tree.by_min[k];
      if (t >= T || node_of[t] != std::numeric_limits<std::uint32_t>::max()) fail("entry out of range or repeated");
      node_of[t] = static_cast<std::uint32_t>(it.i);
      Range q = tet_range(grid, t);
      if (!(q.lo < q.hi) || q.lo < it.lo || q.hi > it.hi) fail("entry outside its node");
      if (!leaf && !(q.lo < n.split && q.hi > n.split)) fail("entry does not straddle its split");
      if (k > n.begin) {
        std::uint32_t p = tree.by_min[k - 1];
        double pk = tet_min(grid, p);
        if (pk > q.lo || (pk == q.lo && p >= t)) fail("list by minimum not sorted");
      }
    }
    if (!leaf) {  // push right first so the left subtree is visited next (pre-order)
      stack.push_back({2 * it.i + 2, std::max(it.lo, n.split), it.hi});
      stack.push_back({2 * it.i + 1, it.lo, std::min(it.hi, n.split)});
    }
  }
  if (cursor != tree.by_min.size()) fail("node ranges do not cover the lists");
  std::size_t nonconstant = 0;
  for (std::size_t t = 0; t < T; ++t) {
    Range q = tet_range(grid, static_cast<std::uint32_t>(t));
    nonconstant += q.lo < q.hi;
  }
  if (nonconstant != tree.by_min.size()) fail("tetrahedra missing");
  for (std::size_t i = 0; i < tree.nodes.size(); ++i) {
    const auto& n = tree.nodes[i];
    for (std::uint64_t k = n.begin; k < n.end; ++k) {
      std::uint32_t t = tree.by_max[k];
      if (t >= T || node_of[t] != i) fail("lists disagree");
      node_of[t] = std::numeric_limits<std::uint32_t>::max() - 1;  // seen in by_max
      if (k > n.begin) {
        std::uint32_t p = tree.by_max[k - 1];
        double pk = tet_max(grid, p), qk = tet_max(grid, t);
        if (pk > qk || (pk == qk && p >= t)) fail("list by maximum not sorted");
      }
    }
  }
}

namespace {

void init_node(const IntervalTree& tree, const TetGrid& grid, SweepState& s, std::size_t i, double iso) {
  const auto& n = tree.nodes[i];
  const auto* mn = tree.by_min.data();
  const auto* mx = tree.by_max.data();
  auto pm = std::partition_point(mn + n.begin, mn + n.end, [&](std::uint32_t t) { return tet_min(grid, t) < iso; });
  auto px = std::partition_point(mx + n.begin, mx + n.end, [&](std::uint32_t t) { return tet_max(grid, t) < iso; });
  s.pmin[i] = static_cast<std::uint32_t>(pm - (mn + n.begin));
  s.pmax[i] = static_cast<std::uint32_t>(px - (mx + n.begin));
}

// Walks node i's two positions from the state's iso to `iso`, flipping the flags of the entries
// passed. Each entry's range needs its tetrahedron and four values from scattered places, so both
// are prefetched a few entries ahead (a few wasted fetches past the stopping point are cheap).
void walk_node(const IntervalTree& tree, const TetGrid& grid, SweepState& s, std::size_t i, double iso) {
  const auto& n = tree.nodes[i];
  const std::uint32_t size = static_cast<std::uint32_t>(n.end - n.begin);
  const std::uint32_t* mn = tree.by_min.data() + n.begin;
  const std::uint32_t* mx = tree.by_max.data() + n.begin;
  std::uint8_t* f = s.flags.data();
  auto ahead = [&](const std::uint32_t* list, std::int64_t k, int dir) {
    const std::int64_t far = k + 16 * dir, near = k + 8 * dir;
    if (far >= 0 && far < size) __builtin_prefetch(&grid.tets[list[far]]);
    if (near >= 0 && near < size) prefetch_values(grid, list[near]);
  };
  std::uint32_t p = s.pmin[i], q = s.pmax[i];
  if (iso > s.iso) {
    for (; p < size && (ahead(mn, p, 1), tet_min(grid, mn[p]) < iso); ++p) f[mn[p]] |= 1;
    for (; q < size && (ahead(mx, q, 1), tet_max(grid, mx[q]) < iso); ++q) f[mx[q]] &= std::uint8_t(~2);
  } else {
    for (; p > 0 && (ahead(mn, p - 1, -1), tet_min(grid, mn[p - 1]) >= iso); --p) f[mn[p - 1]] &= std::uint8_t(~1);
    for (; q > 0 && (ahead(mx, q - 1, -1), tet_max(grid, mx[q - 1]) >= iso); --q) f[mx[q - 1]] |= 2;
  }
  s.pmin[i] = p;
  s.pmax[i] = q;
}

}  // namespace

void sweep_to(const IntervalTree& tree, const TetGrid& grid, SweepState& s, double iso) {
  if (!std::isfinite(iso)) throw InputError("the iso-value must be a finite number");
  if (!s.valid || s.flags.size() != grid.tet_count() || s.pmin.size() != tree.nodes.size()) {
    s.pmin.assign(tree.nodes.size(), 0);
    s.pmax.assign(tree.nodes.size(), 0);
    s.flags.assign(grid.tet_count(), 0);
    tbb::parallel_for(std::size_t{0}, tree.nodes.size(), [&](std::size_t i) { init_node(tree, grid, s, i, iso); });
    // Flags in tetrahedron order (coherent memory access), not list order; constant ones stay 0.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, grid.tet_count(), 16384), [&](const auto& r) {
      for (std::size_t t = r.begin(); t < r.end(); ++t) {
        Range q = tet_range(grid, static_cast<std::uint32_t>(t));
        if (q.lo < q.hi) s.flags[t] = static_cast<std::uint8_t>((q.lo < iso) | ((q.hi >= iso) << 1));
      }
    });
    s.iso = iso;
    s.valid = true;
    s.walked = tree.entries();
    s.entering.clear();
    s.entering_complete = false;
    return;
  }
  s.walked = 0;
  s.entering.clear();
  s.entering_complete = true;
  if (iso == s.iso) return;
  // A key crosses when it lies in [L, H); prune subtrees whose keys all lie outside. The nodes to
  // walk are listed in pre-order and walked in parallel: each tetrahedron lives in one node, so the
  // walks write disjoint flags; the entering entries are then concatenated in the same pre-order.
  const double L = std::min(iso, s.iso), H = std::max(iso, s.iso);
  struct Visit {
    std::size_t node;
    std::uint32_t p0, q0;
  };
  std::vector<Visit> visits;
  std::vector<std::size_t> stack{0};
  while (!stack.empty()) {
    std::size_t i = stack.back();
    stack.pop_back();
    const auto& n = tree.nodes[i];
    if (!(n.lo < H && n.hi >= L)) continue;
    visits.push_back({i, s.pmin[i], s.pmax[i]});
    if (!tree.is_leaf(i)) {
      stack.push_back(2 * i + 2);
      stack.push_back(2 * i + 1);
    }
  }
  tbb::parallel_for(std::size_t{0}, visits.size(), [&](std::size_t k) { walk_node(tree, grid, s, visits[k].node, iso); });
  // Per visited node, the entries walked in each list: [min(old, new), max(old, new)) positions.
  auto span = [&](const Visit& v, bool by_max) {
    const std::uint32_t now = by_max ? s.pmax[v.node] : s.pmin[v.node], then = by_max ? v.q0 : v.p0;
    return std::pair{std::min(now, then), std::max(now, then)};
  };
  // A tetrahedron becomes active when its minimum drops below a rising iso-value, or its maximum
  // reaches a falling one: only that list's walked entries can enter.
  const bool rising = iso > s.iso;
  std::vector<std::uint64_t> at(visits.size() + 1, 0);
  for (std::size_t k = 0; k < visits.size(); ++k) {
    const auto [a, b] = span(visits[k], false);
    const auto [c, d] = span(visits[k], true);
    s.walked += (b - a) + (d - c);
    at[k + 1] = at[k] + (rising ? b - a : d - c);
  }
  s.iso = iso;
  if (at.back() > s.entering_limit) {
    s.entering_complete = false;
    return;
  }
  s.entering.resize(at.back());
  const auto& list = rising ? tree.by_min : tree.by_max;
  tbb::parallel_for(std::size_t{0}, visits.size(), [&](std::size_t k) {
    const auto& n = tree.nodes[visits[k].node];
    const auto [a, b] = span(visits[k], !rising);
    std::copy(list.begin() + static_cast<std::ptrdiff_t>(n.begin + a), list.begin() + static_cast<std::ptrdiff_t>(n.begin + b),
              s.entering.begin() + static_cast<std::ptrdiff_t>(at[k]));
  });
}

void active_tetrahedra(const IntervalTree& tree, const SweepState& s, std::vector<std::uint32_t>& out) {
  if (!s.valid) return;
  for (std::size_t i = 0;;) {
    const auto& n = tree.nodes[i];
    const std::uint32_t* mn = tree.by_min.data() + n.begin;
    if (tree.is_leaf(i)) {
      for (std::uint32_t k = 0; k < s.pmin[i]; ++k)
        if (s.flags[mn[k]] & 2) out.push_back(mn[k]);
      return;
    }
    if (s.iso <= n.split) {  // every entry has tmax > split >= iso: active iff tmin < iso
      out.insert(out.end(), mn, mn + s.pmin[i]);
      i = 2 * i + 1;
    } else {  // every entry has tmin < split < iso: active iff tmax >= iso
      out.insert(out.end(), tree.by_max.begin() + static_cast<std::ptrdiff_t>(n.begin + s.pmax[i]),
                 tree.by_max.begin() + static_cast<std::ptrdiff_t>(n.end));
      i = 2 * i + 2;
    }
  }
}

void query_active(const IntervalTree& tree, const TetGrid& grid, double iso, std::vector<std::uint32_t>& out) {
  if (!std::isfinite(iso)) throw InputError("the iso-value must be a finite number");
  if (tree.nodes.empty()) return;
  for (std::size_t i = 0;;) {
    const auto& n = tree.nodes[i];
    const std::uint32_t* mn = tree.by_min.data() + n.begin;
    const std::uint32_t* mx = tree.by_max.data() + n.begin;
    const std::uint32_t size = static_cast<std::uint32_t>(n.end - n.begin);
    if (tree.is_leaf(i)) {
      for (std::uint32_t k = 0; k < size; ++k) {
        Range q = tet_range(grid, mn[k]);
        if (q.lo >= iso) break;
        if (q.hi >= iso) out.push_back(mn[k]);
      }
      return;
    }
    if (iso <= n.split) {
      auto e = std::partition_point(mn, mn + size, [&](std::uint32_t t) { return tet_min(grid, t) < iso; });
      out.insert(out.end(), mn, e);
      i = 2 * i + 1;
    } else {
      auto b = std::partition_point(mx, mx + size, [&](std::uint32_t t) { return tet_max(grid, t) < iso; });
      out.insert(out.end(), b, mx + size);
      i = 2 * i + 2;
    }
  }
}

void scan_active(const TetGrid& grid, double iso, std::vector<std::uint32_t>& out) {
  const std::size_t T = grid.tet_count();
  const std::size_t chunks = std::max<std::size_t>(1, std::min<std::size_t>(256, T / 65536 + 1));
  std::vector<std::vector<std::uint32_t>> parts(chunks);
  tbb::parallel_for(std::size_t{0}, chunks, [&](std::size_t c) {
    const std::size_t b = T * c / chunks, e = T * (c + 1) / chunks;
    for (std::size_t t = b; t < e; ++t) {
      Range q = tet_range(grid, static_cast<std::uint32_t>(t));
      if (q.lo < iso && q.hi >= iso) parts[c].push_back(static_cast<std::uint32_t>(t));
    }
  });
  for (const auto& p : parts) out.insert(out.end(), p.begin(), p.end());
}

}  // namespace adaptiso
