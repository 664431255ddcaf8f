// From a split rule to a grid: the walk over the bisection hierarchy that the selection
// (bisection.cpp) and coarsening (bisection_coarsen.cpp) share, and their split rules. Internal.
#pragma once
#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <span>
#include <stdexcept>
#include <utility>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/select_shares.hpp"
#include "grid/diamond.hpp"
#include "grid/share_agree.hpp"
#include "grid/traversal.hpp"
#include "util/big_array.hpp"
#include "util/memory.hpp"

namespace adaptiso::detail {

// Float bounds of doubles, rounded outwards, and their atomic updates (several tetrahedra of one
// diamond lie in different subtrees).
inline float down(double x) {
  const auto f = static_cast<float>(x);
  return f > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
inline float up(double x) {
  const auto f = static_cast<float>(x);
  return f < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}
inline void atomic_min(float& target, float v) {
  std::atomic_ref<float> a(target);
  for (float cur = a.load(std::memory_order_relaxed); v < cur && !a.compare_exchange_weak(cur, v, std::memory_order_relaxed);) {
  }
}
template <class T>
void atomic_max(T& target, T v) {
  std::atomic_ref<T> a(target);
  for (T cur = a.load(std::memory_order_relaxed); v > cur && !a.compare_exchange_weak(cur, v, std::memory_order_relaxed);) {
  }
}

// The selection at a bound: split where a diamond's codes exceed the thresholds.
struct CodedSplits {
  static constexpr bool kUpwardClosed = true;  // the codes are saturated
  const std::vector<std::uint8_t>& code;
  std::uint8_t threshold;
  const std::vector<std::uint8_t>* displacement;  // displacement codes, when that criterion is used
  std::uint8_t displacement_threshold;
  bool split(std::int64_t voxel) const {
    const auto i = static_cast<std::size_t>(voxel);
    return code[i] > threshold || (displacement && (*displacement)[i] > displacement_threshold);
  }
  Decision decide(std::int64_t voxel) const { return split(voxel) ? Decision::descend : Decision::leaf; }
};

// The selection under a cell floor: a diamond centred at (x, y, z) splits cubes of side 2^(t+1)
// into cubes of side 2^t, t the fewest trailing zeros among x, y, z (ctz(x | y | z)), so the
// diamonds of scale below the floor stay whole, but those the box forces (their codes say so,
// and so do their ancestors'). The largest codes of the diamonds the floor kept whole are the
// grid's measured bounds.
struct FlooredSplits {
  static constexpr bool kUpwardClosed = false;  // a diamond below the floor stays whole, though its parents split
  CodedSplits coded;
  std::int64_t nx, nxy;
  std::int64_t below;                                          // 2^floor − 1: a centre with any of these bits set is below the floor
  mutable std::uint8_t kept_error = 0, kept_displacement = 0;  // raised atomically by the walks' threads
  bool split(std::int64_t voxel) const {
    if (!coded.split(voxel)) return false;
    const auto i = static_cast<std::size_t>(voxel);
    if (coded.code[i] == ErrorCodes::kForced) return true;
    const std::int64_t x = voxel % nx, y = voxel % nxy / nx, z = voxel / nxy;
    if (((x | y | z) & below) == 0) return true;
    atomic_max(kept_error, coded.code[i]);
    if (coded.displacement) atomic_max(kept_displacement, (*coded.displacement)[i]);
    return false;
  }
  Decision decide(std::int64_t voxel) const { return split(voxel) ? Decision::descend : Decision::leaf; }
};

// The grid's vertices under a rule whose splits are closed upwards (a split diamond's parents
// split too: the codes are saturated), without a walk: the centres of the split diamonds in the
// box and the root cube's corners in it. A split tetrahedron's midpoint is a vertex of both
// halves, and of every descendant that contains it, so of the leaves that cover it; and every
// vertex of a leaf is a root corner or the midpoint of an ancestor's split.
template <class Rule>
void split_centres(const Lattice& lat, const Rule& rule, std::size_t voxels, VertexNumbers& numbers) {
  numbers.reset(voxels);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numbers.words.size(), 4096), [&](const auto& r) {
    for (std::size_t w = r.begin(); w < r.end(); ++w) {
      std::uint64_t word = 0;
      const std::size_t n = std::min<std::size_t>(64, voxels - w * 64);
      for (std::size_t b = 0; b < n; ++b) word |= std::uint64_t{rule.split(static_cast<std::int64_t>(w * 64 + b))} << b;
      numbers.words[w].bits = word;
    }
  });
  for (int corner = 0; corner < 8; ++corner) {
    const Coord c{corner & 1 ? lat.S : 0, corner & 2 ? lat.S : 0, corner & 4 ? lat.S : 0};
    if (!lat.in_box(c)) continue;
    numbers.set(static_cast<std::uint64_t>(lat.index(c)));
  }
}

// The selection shared with other processes (select_shares.hpp): the same steps on every process,
// these the moves between them.
namespace share {

// Each process counted its own subtrees (the others' counts 0): the sums, on every process.
inline void sum_counts(ShareTransport& t, std::vector<std::uint64_t>& counts) {
  combine_at_zero(t, std::span(counts), [](std::uint64_t& own, std::uint64_t theirs) { own += theirs; });
}

// The subtrees [runs[p], runs[p + 1]) process p writes: consecutive, about as many leaves each
// (`leaves`: the leaves before each subtree, and the total last).
inline std::vector<std::size_t> runs(const std::vector<std::uint64_t>& leaves, int processes) {
  std::vector<std::size_t> at(static_cast<std::size_t>(processes) + 1, leaves.size() - 1);
  at[0] = 0;
  for (int p = 1; p < processes; ++p) {
    const std::uint64_t target = leaves.back() * static_cast<std::uint64_t>(p) / static_cast<std::uint64_t>(processes);
    at[static_cast<std::size_t>(p)] = static_cast<std::size_t>(std::lower_bound(leaves.begin(), leaves.end() - 1, target) - leaves.begin());
  }
  return at;
}

// Process p's run goes to process 0 in pieces of `piece` tetrahedra (so process 0 can hand each
// to a sink as it comes instead of holding them all): in place in its tetrahedra, or to its sink
// through `buffer`; its spans merge into process 0's.
inline void gather_runs(ShareTransport& t, const std::vector<std::uint64_t>& leaves, const std::vector<std::size_t>& run,
                        std::vector<std::array<std::uint32_t, 4>>& tets, std::vector<std::array<float, 2>>& spans,
                        std::vector<ValueSpan>& root_spans, TetrahedraSink* sink, std::uint64_t piece,
                        std::vector<std::array<std::uint32_t, 4>>& buffer) {
  const auto own = [&](int p) { return std::pair{run[static_cast<std::size_t>(p)], run[static_cast<std::size_t>(p) + 1]}; };
  if (t.process() != 0) {
    const auto [first, last] = own(t.process());
    for (std::uint64_t at = 0; at < tets.size(); at += piece)
      t.send(bytes(tets).subspan(at * sizeof tets[0], std::min<std::uint64_t>(piece, tets.size() - at) * sizeof tets[0]));
    t.send(bytes(spans));
    t.send(std::as_bytes(std::span(root_spans).subspan(first, last - first)));
    return;
  }
  std::vector<std::array<float, 2>> theirs(spans.size());
  for (int p = 1; p < t.processes(); ++p) {
    const auto [first, last] = own(p);
    for (std::uint64_t at = leaves[first]; at < leaves[last]; at += piece) {
      const std::uint64_t n = std::min(piece, leaves[last] - at);
      if (sink) {
        buffer.resize(n);
        t.receive(p, bytes(buffer));
        sink->write(buffer);
      } else {
        t.receive(p, bytes(tets).subspan(at * sizeof tets[0], n * sizeof tets[0]));
      }
    }
    t.receive(p, bytes(theirs));
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, spans.size(), 1 << 16), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) {
        spans[i][0] = std::min(spans[i][0], theirs[i][0]);
        spans[i][1] = std::max(spans[i][1], theirs[i][1]);
      }
    });
    t.receive(p, std::as_writable_bytes(std::span(root_spans).subspan(first, last - first)));
  }
}

}  // namespace share

// Where a selection's tetrahedra go besides this process's grid: the processes sharing it, a sink
// (BisectionOptions::share, sink, piece).
struct Handover {
  ShareTransport* shared = nullptr;
  TetrahedraSink* sink = nullptr;
  std::uint64_t piece = BisectionOptions{}.piece;
};

// The grid of a traversal's leaves inside the box. A first walk counts the leaves of each subtree.
// The vertices are the split diamonds' centres (split_centres) under a rule closed upwards; under
// another, the first walk marks the leaves' corners among the `voxels` voxels, a byte each (a
// relaxed atomic byte store is a plain store; a bit would need a locked read-modify-write). They
// are numbered in voxel order, size(count) sizes the arrays and fill(voxel, id) gives each vertex
// its data (out.grid.values at least); then a second walk writes the tetrahedra with their final
// numbers, and each split diamond gets the span of the values beneath it. Both walks cut the
// hierarchy 12 splits below the roots into subtrees run in parallel and placed in depth-first
// order, so the grid is the same for any thread count.
//
// With `own_code` (the codes by voxel), each tetrahedron's own bound is kept too, in
// out.tet_code: the code of the diamond it would split at, at least `own_least` (0 for a unit
// tetrahedron).
//
// With `shared` (select_shares.hpp; a rule closed upwards), on every process alike: it counts its
// subtrees, writes its run of them and hands them to process 0, whose `out` gets the grid; another
// process's size and fill do nothing, and its `out` holds its run only.
//
// With `sink` (BisectionOptions::sink; not with own_code), process 0 hands it the tetrahedra in
// order, its own run walked in pieces of consecutive subtrees (`piece` tetrahedra, or one larger
// subtree), the others' as they arrive: out.grid.tets stays empty.
template <class Rule, class Size, class Fill>
void assemble(const Lattice& lat, const Rule& rule, std::size_t voxels, Size size, Fill fill, BisectionGrid& out, const Progress& progress,
              const std::vector<std::uint8_t>* own_code = nullptr, std::uint8_t own_least = 0, const Handover& handover = {}) {
  ShareTransport* const shared = handover.shared;
  TetrahedraSink* sink = handover.sink;
  const std::uint64_t piece_size = std::max<std::uint64_t>(handover.piece, 1);
  const Traversal<Rule> walk(lat, rule);
  const Frontier top = walk.frontier(12);
  const std::vector<Subtree>& roots = top.roots;
  std::vector<std::uint64_t> leaves(roots.size() + 1, 0);
  const std::size_t processes = shared ? static_cast<std::size_t>(shared->processes()) : 1;
  const std::size_t me = shared ? static_cast<std::size_t>(shared->process()) : 0;
  if (shared && (!Rule::kUpwardClosed || own_code)) throw std::logic_error("assemble: only a selection at a bound is shared");
  if (sink && own_code) throw std::logic_error("assemble: a sink takes no tetrahedra's own codes");
  if (me != 0) sink = nullptr;  // process 0's alone
  report(progress, "select", 0);
  constexpr bool kMarked = !Rule::kUpwardClosed;  // the vertices marked by the leaves, not found from the codes
  std::vector<std::uint8_t> used;
  if constexpr (kMarked) assign_big(used, voxels, std::uint8_t{0});
  tbb::parallel_for(std::size_t{0}, roots.size(), [&](std::size_t f) {
    if (f % processes != me) return;  // another process's to count
    std::uint64_t count = 0;
    walk.visit(
        roots[f],
        [&](const Tet& t, std::int64_t) {
          ++count;
          if constexpr (kMarked)
            for (const Coord& c : t)
              std::atomic_ref<std::uint8_t>(used[static_cast<std::size_t>(lat.index(c))]).store(1, std::memory_order_relaxed);
          return ValueSpan{};
        },
        [](std::int64_t, const Tet&, const ValueSpan&) {});
    leaves[f + 1] = count;
  });
  VertexNumbers numbers;  // over the voxels
  if constexpr (kMarked) {
    numbers.reset(used.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numbers.words.size(), 4096), [&](const auto& r) {
      for (std::size_t w = r.begin(); w < r.end(); ++w) {
        std::uint64_t bits = 0;
        for (std::size_t b = 0; b < 64 && w * 64 + b < used.size(); ++b) bits |= std::uint64_t{used[w * 64 + b]} << b;
        numbers.words[w].bits = bits;
      }
    });
    std::vector<std::uint8_t>().swap(used);
  } else {
    split_centres(lat, rule, voxels, numbers);
  }
  if (shared) share::sum_counts(*shared, leaves);
  for (std::size_t f = 0; f < roots.size(); ++f) leaves[f + 1] += leaves[f];
  numbers.count();
  const std::uint64_t vertices = numbers.total(), tets = leaves.back();
  const std::vector<std::size_t> run = share::runs(leaves, static_cast<int>(processes));
  const std::size_t first = run[me], last = run[me + 1];
  const std::uint64_t base = leaves[first];  // where this process's run starts (0 on process 0)
  // The grid and the rest of the preparation: tetrahedra (16 bytes), their index (8 bytes, and
  // while built 16 more for each entry of the two nodes being sorted: about 8 a tetrahedron on the
  // noisiest scan here, the MR head, whose two largest nodes hold 39 M of 84 M entries), vertices
  // with values, gradients and codes (33 bytes).
  // Shared: process 0 also receives the others' spans (8 bytes a vertex); another process holds its
  // run, the vertices' values and its spans.
  std::exception_ptr refused;
  try {
    if (me == 0)  // with a sink, a piece of tetrahedra instead of them all and their index
      check_memory((sink ? std::min(tets, piece_size) * 16 : tets * 36) + vertices * (shared ? 41 : 33),
                   fmt::format("a grid of {} tetrahedra", tets), "max_error", "raise it");
    else
      check_memory((leaves[last] - base) * 16 + vertices * 16,
                   fmt::format("process {}'s {} of {} tetrahedra", me, leaves[last] - base, tets), "max_error",
                   "raise it, or share over more processes");
    if (vertices >= std::numeric_limits<std::uint32_t>::max() || tets >= std::numeric_limits<std::uint32_t>::max())
      throw OptionError("max_error",
                        fmt::format("{} vertices and {} tetrahedra exceed the grid's 32-bit indices; raise it", vertices, tets));
  } catch (...) {
    if (!shared) throw;
    refused = std::current_exception();
  }
  if (shared) share::agree(*shared, refused);
  report(progress, "select", 0.5);
  TetGrid& g = out.grid;
  out.hierarchy.root_size = lat.S;
  size(vertices);
  if (me == 0)
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numbers.words.size(), 1024), [&](const auto& r) {
      for (std::size_t w = r.begin(); w < r.end(); ++w) {
        std::uint64_t id = numbers.words[w].before;
        for (std::uint64_t b = numbers.words[w].bits; b; b &= b - 1) fill(w * 64 + static_cast<std::size_t>(std::countr_zero(b)), id++);
      }
    });
  if (shared) {  // the vertices' values, for the spans
    if (me != 0) resize_big(g.values, vertices);
    shared->broadcast(share::bytes(g.values));
  }
  if (!sink) resize_big(g.tets, me == 0 ? tets : leaves[last] - base);
  if (own_code) resize_big(out.tet_code, tets);
  auto& spans = out.hierarchy.value_span;
  assign_big(spans, vertices, {std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity()});
  auto merge = [&](std::uint32_t id, const ValueSpan& s) {
    auto& span = spans[id];
    atomic_min(span[0], down(s.lo));
    atomic_max(span[1], up(s.hi));
  };
  std::vector<ValueSpan> root_spans(roots.size());
  // Subtree f's tetrahedra written from `to` on (its tetrahedron `at` of the grid first).
  auto write_subtree = [&](std::size_t f, std::array<std::uint32_t, 4>* to, std::uint64_t at) {
    root_spans[f] = walk.visit(
        roots[f], numbers, g.values,
        [&](const Tet&, const Corners& c, std::int64_t split_at) {
          if (own_code)
            out.tet_code[at++] = split_at >= 0 ? std::max((*own_code)[static_cast<std::size_t>(split_at)], own_least) : std::uint8_t{0};
          *to++ = c.id;
          return ValueSpan{std::min({c.value[0], c.value[1], c.value[2], c.value[3]}),
                           std::max({c.value[0], c.value[1], c.value[2], c.value[3]})};
        },
        [&](std::int64_t, std::uint32_t id, const Tet&, const ValueSpan& s) { merge(id, s); });
  };
  std::vector<std::array<std::uint32_t, 4>> piece;  // the sink's
  if (sink) {
    sink->begin(out, tets);
    // Pieces of consecutive subtrees: [cut[i], cut[i + 1]).
    std::vector<std::size_t> cut{first};
    std::uint64_t largest = 0;
    for (std::size_t f = first; f < last; ++f)
      if (f > cut.back() && leaves[f + 1] - leaves[cut.back()] > piece_size) {
        largest = std::max(largest, leaves[f] - leaves[cut.back()]);
        cut.push_back(f);
      }
    largest = std::max(largest, leaves[last] - leaves[cut.back()]);
    cut.push_back(last);
    resize_big(piece, largest);
    for (std::size_t i = 0; i + 1 < cut.size(); ++i) {
      const std::uint64_t start = leaves[cut[i]];
      tbb::parallel_for(cut[i], cut[i + 1], [&](std::size_t f) { write_subtree(f, piece.data() + (leaves[f] - start), leaves[f]); });
      sink->write(std::span(piece).first(leaves[cut[i + 1]] - start));
    }
  } else {
    tbb::parallel_for(first, last, [&](std::size_t f) { write_subtree(f, g.tets.data() + (leaves[f] - base), leaves[f]); });
  }
  if (shared) {
    share::gather_runs(*shared, leaves, run, g.tets, spans, root_spans, sink, piece_size, piece);
    if (me != 0) return;
  }
  for (const auto& split : top.splits) {  // children first: the spans of the subtrees below
    ValueSpan s;
    for (std::size_t r = split.first; r < split.last; ++r) s.add(root_spans[r]);
    merge(numbers.id(split.voxel), s);
  }
  report(progress, "select", 1);
}

inline void check_bounds(const BisectionOptions& o) {
  if (o.cell_floor < 0 || o.cell_floor > 30)
    throw OptionError("cell_floor", fmt::format("must be between 0 and 30 (cubes of 1 to 2^30 voxels), got {}", o.cell_floor));
  if (!(o.max_error >= 0))  // +∞: no error criterion (the displacement alone, or the coarsest grid)
    throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", o.max_error));
  if (!(o.max_displacement >= 0) || !std::isfinite(o.max_displacement))
    throw OptionError("max_displacement", fmt::format("must be a non-negative number, got {}", o.max_displacement));
  if (o.piece == 0 || o.piece > std::numeric_limits<std::int64_t>::max())
    throw OptionError("piece", fmt::format("must be positive, got {}", o.piece));
}

}  // namespace adaptiso::detail
