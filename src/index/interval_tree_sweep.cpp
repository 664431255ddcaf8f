// Sweeping the interval tree (see interval_tree.hpp): a client's state moved from one iso-value to
// the next, the active tetrahedra of a state, a query without one, and the brute-force scan used
// as the reference.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.4 (finding the cut tetrahedra).
// - Shen, Johnson. Sweeping simplices: a fast iso-surface extraction algorithm for unstructured
//   grids. IEEE Visualization 1995 (the sweep).
// - Cignoni, Marino, Montani, Puppo, Scopigno. Speeding up isosurface extraction using interval
//   trees. IEEE TVCG, 1997 (the tree; after Edelsbrunner's interval tree, 1980).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "adaptiso/error.hpp"
#include "adaptiso/interval_tree.hpp"
#include "index/tet_range.hpp"
#include "util/big_array.hpp"

namespace adaptiso {
using detail::prefetch_values;
using detail::Range;
using detail::tet_max;
using detail::tet_min;
using detail::tet_range;

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
    detail::assign_big(s.flags, grid.tet_count(), std::uint8_t{0});
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
