// Walking the bisection hierarchy top-down (see bisection.hpp, diamond.hpp): from the 6 root
// tetrahedra, each split at the midpoint of its longest edge while a rule says so. Shared by the
// selection of a grid (bisection.cpp) and the queries at a coarser error (hierarchy_query.cpp).
// Internal.
#pragma once
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

#include "adaptiso/error.hpp"
#include "adaptiso/tet_grid.hpp"
#include "adaptiso/volume.hpp"
#include "grid/diamond.hpp"
#include "util/big_array.hpp"

namespace adaptiso::detail {

using Tet = std::array<Coord, 4>;

inline Lattice make_lattice(const Dims& dims) {
  Lattice lat;
  std::int64_t extent = 1;
  for (int a = 0; a < 3; ++a) {
    if (dims[a] < 2)
      throw InputError(fmt::format("a volume of {} x {} x {} voxels is flat: a grid of tetrahedra needs at least 2 voxels along every axis",
                                   dims[0], dims[1], dims[2]));
    if (dims[a] - 1 > (std::int64_t{1} << 30)) throw InputError(fmt::format("dimension {} is too large for the bisection grid", dims[a]));
    lat.X[a] = static_cast<std::int32_t>(dims[a] - 1);
    extent = std::max(extent, dims[a] - 1);
  }
  lat.S = static_cast<std::int32_t>(std::bit_ceil(static_cast<std::uint64_t>(extent)));
  lat.k = std::countr_zero(static_cast<std::uint32_t>(lat.S));
  lat.nx = dims[0];
  lat.nxy = dims[0] * dims[1];
  return lat;
}

// The 6 root tetrahedra around the root cube's diagonal, positively oriented.
inline std::array<Tet, 6> root_tetrahedra(std::int32_t S) {
  std::array<Tet, 6> out;
  const int perms[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1}, {0, 2, 1}, {2, 1, 0}, {1, 0, 2}};
  for (int t = 0; t < 6; ++t) {
    Coord v1{0, 0, 0};
    v1[perms[t][0]] = S;
    Coord v2 = v1;
    v2[perms[t][1]] = S;
    out[t] = {Coord{0, 0, 0}, v1, v2, Coord{S, S, S}};
    if (t >= 3) std::swap(out[t][1], out[t][2]);  // odd permutations
  }
  return out;
}

// Maubach's order of a tetrahedron of the hierarchy: which of its slots hold x0 … x3, and its tag
// k; its refinement edge is x0–xk. The roots are Kuhn's paths (x0 = 0, x1, x2 one axis step
// apart, x3 the far corner) with k = 3; of the halves at z = (x0 + xk)/2, one keeps x0 (z in
// xk's slot), the other drops it (x1 … xk move down one, z takes x0's slot as the new xk); both get
// k − 1, or 3 after 1 (Maubach 1995). That edge is the longest one, as the tests check at every
// node of the hierarchy, so the walk needs no edge lengths (they took 8.6 % of the bunny's whole
// preparation, whose selection visits 120 M tetrahedra twice; without them it runs in 0.8× the
// time).
struct Order {
  std::array<std::uint8_t, 4> slot{0, 1, 2, 3};
  std::uint8_t k = 3;
};

// The walk carries an order as one of its 72 states (24 slot permutations × 3 tags), and a table
// made at compile time gives each state's refinement slots and its halves' states: a lookup a node.
namespace order_table {
constexpr int index(const Order& o) {
  int rank = 0;  // the permutation's lexicographic rank (Lehmer code)
  for (int a = 0; a < 4; ++a) {
    int smaller = 0;
    for (int b = a + 1; b < 4; ++b) smaller += o.slot[static_cast<std::size_t>(b)] < o.slot[static_cast<std::size_t>(a)];
    rank = rank * (4 - a) + smaller;
  }
  return rank * 3 + (o.k - 1);
}
struct Entry {
  std::uint8_t i = 0, j = 0, at_j = 0, at_i = 0;  // refinement slots i < j; the halves' states
};
constexpr std::array<Entry, 72> make() {
  std::array<Entry, 72> table{};
  std::array<std::uint8_t, 4> slot{0, 1, 2, 3};
  do {
    for (std::uint8_t k = 1; k <= 3; ++k) {
      const Order o{slot, k};
      const std::uint8_t p = o.slot[0], q = o.slot[k], next = k > 1 ? static_cast<std::uint8_t>(k - 1) : std::uint8_t{3};
      Order keeps{o.slot, next}, drops{o.slot, next};
      for (int n = 0; n < k; ++n) drops.slot[static_cast<std::size_t>(n)] = o.slot[static_cast<std::size_t>(n + 1)];
      drops.slot[k] = o.slot[0];
      Entry& e = table[static_cast<std::size_t>(index(o))];
      e.i = std::min(p, q);
      e.j = std::max(p, q);
      const bool j_is_xk = e.j == q;  // the half whose slot j takes the midpoint keeps x0 when j held xk
      e.at_j = static_cast<std::uint8_t>(index(j_is_xk ? keeps : drops));
      e.at_i = static_cast<std::uint8_t>(index(j_is_xk ? drops : keeps));
    }
  } while (std::next_permutation(slot.begin(), slot.end()));
  return table;
}
inline constexpr std::array<Entry, 72> kTable = make();
}  // namespace order_table

using OrderState = std::uint8_t;

inline OrderState root_order(int root) {  // root_tetrahedra swaps slots 1 and 2 of the odd ones
  return static_cast<OrderState>(order_table::index(root < 3 ? Order{} : Order{{0, 2, 1, 3}, 3}));
}

// The refinement edge's slots i < j and its midpoint m, or false when m is not a lattice point
// (a unit tetrahedron: a leaf of the hierarchy).
inline bool refinement(const Tet& t, OrderState o, Coord& m, int& i, int& j) {
  const auto& e = order_table::kTable[o];
  i = e.i;
  j = e.j;
  for (int a = 0; a < 3; ++a) {
    const std::int32_t sum = t[static_cast<std::size_t>(i)][a] + t[static_cast<std::size_t>(j)][a];
    if (sum & 1) return false;
    m[a] = sum / 2;
  }
  return true;
}

// Wholly beyond a far face of the box.
inline bool tet_outside(const Lattice& lat, const Tet& t) {
  for (int a = 0; a < 3; ++a)
    if (std::min({t[0][a], t[1][a], t[2][a], t[3][a]}) >= lat.X[a]) return true;
  return false;
}
inline bool tet_inside(const Lattice& lat, const Tet& t) {
  for (const Coord& v : t)
    if (!lat.in_box(v)) return false;
  return true;
}

// A tetrahedron of the hierarchy with its order.
struct Subtree {
  Tet tet;
  OrderState order;
};

// The halves of t split at m, its refinement edge's midpoint (slots i < j), with their orders: the
// first has m in slot j, the second in slot i (replacing an end by the midpoint keeps the
// orientation).
inline std::array<Subtree, 2> halves(const Tet& t, OrderState o, const Coord& m, int i, int j) {
  std::array<Subtree, 2> h{Subtree{t, order_table::kTable[o].at_j}, Subtree{t, order_table::kTable[o].at_i}};
  h[0].tet[static_cast<std::size_t>(j)] = m;
  h[1].tet[static_cast<std::size_t>(i)] = m;
  return h;
}

// The values under a subtree (of its leaves' vertices), combined upwards.
struct ValueSpan {
  double lo = std::numeric_limits<double>::infinity(), hi = -std::numeric_limits<double>::infinity();
  void add(const ValueSpan& o) {
    lo = std::min(lo, o.lo);
    hi = std::max(hi, o.hi);
  }
};

// The top of the traversal, cut into subtrees to run in parallel: the subtrees' roots in
// depth-first order, and the split tetrahedra inside the box above them, each with the range of
// subtrees below it (children before parents, so spans combine in one pass).
struct Frontier {
  std::vector<Subtree> roots;
  struct Split {
    std::int64_t voxel;
    Tet tet;
    std::size_t first, last;  // roots[first, last)
  };
  std::vector<Split> splits;
};

// Without a popcount instruction in the baseline instruction set, std::popcount is a library
// call; numbering asks it for every vertex of every tetrahedron.
inline int bit_count(std::uint64_t x) {
  x = x - ((x >> 1) & 0x5555555555555555ull);
  x = (x & 0x3333333333333333ull) + ((x >> 2) & 0x3333333333333333ull);
  x = (x + (x >> 4)) & 0x0f0f0f0f0f0f0f0full;
  return static_cast<int>((x * 0x0101010101010101ull) >> 56);
}

// Vertex numbers from a bitmap of used voxels: the rank of a voxel among the used ones (ascending
// linear index, the grid's vertex order). Set the bits (reset, set), then count.
struct VertexNumbers {
  static constexpr std::uint32_t kNone = ~std::uint32_t{0};
  // Per 64 voxels, side by side: which are vertices, and how many vertices the words before hold.
  // The walks look up scattered voxels, several per tetrahedron (the distance query's probes one
  // per level): one cache line per lookup instead of two (3–6 % of the distance query's
  // refinement on the CT bunny, none measurable on the smaller chest CT, whose bitmap stays cached).
  struct Word {
    std::uint64_t bits = 0, before = 0;
  };
  std::vector<Word> words;

  void reset(std::uint64_t voxels) { assign_big(words, static_cast<std::size_t>((voxels + 63) / 64), Word{}); }
  void set(std::uint64_t voxel) { words[static_cast<std::size_t>(voxel >> 6)].bits |= std::uint64_t{1} << (voxel & 63); }
  void count() {
    std::uint64_t n = 0;
    for (Word& w : words) w.before = n, n += static_cast<std::uint64_t>(bit_count(w.bits));
  }
  std::uint64_t total() const { return words.empty() ? 0 : words.back().before + static_cast<std::uint64_t>(bit_count(words.back().bits)); }

  std::uint32_t id(std::int64_t voxel) const {
    const Word& w = words[static_cast<std::size_t>(voxel) >> 6];
    const std::uint64_t below = w.bits & ((std::uint64_t{1} << (voxel & 63)) - 1);
    return static_cast<std::uint32_t>(w.before + static_cast<std::uint64_t>(bit_count(below)));
  }
  bool used(std::int64_t voxel) const { return (words[static_cast<std::size_t>(voxel) >> 6].bits >> (voxel & 63)) & 1; }
  // kNone for a voxel that is no vertex.
  std::uint32_t find(std::int64_t voxel) const { return used(voxel) ? id(voxel) : kNone; }
};

// The numbers of a grid's own vertices, by their voxels (lattice keys, tet_grid.hpp): a grid's
// vertex ids ascend with their voxels, so these are its ids.
inline VertexNumbers grid_vertex_numbers(const TetGrid& g) {
  VertexNumbers n;
  n.reset(static_cast<std::uint64_t>(g.source.dims[0] * g.source.dims[1] * g.source.dims[2]));
  for (const auto& p : g.ijk) n.set(lattice_key(g.source.dims, p));
  n.count();
  return n;
}

// A numbered walk's tetrahedron: its vertices' numbers and values, in the slots of its corners.
struct Corners {
  std::array<std::uint32_t, 4> id;
  std::array<double, 4> value;
};

// What a rule says of a tetrahedron inside the box, by the voxel at its refinement edge's midpoint.
enum class Decision { leaf, descend, prune };

// Rule: decide(voxel) — is a tetrahedron inside the box, whose midpoint is that voxel, a leaf, or
// split (and then is its subtree walked or pruned)? split(voxel) — is it split at all (for
// tetrahedra across the box's faces, whose midpoint lies in the box)? Diamonds that cross the
// box's far faces are always split (no tetrahedron reaches outside the volume); the leaves inside
// the box are the grid, and a leaf that is not inside lies beyond a far face.
template <class Rule>
class Traversal {
public:
  Traversal(const Lattice& lat, const Rule& rule) : lat_(lat), rule_(rule) {}

  // Subtrees cut `depth` splits below the roots (leaves above that depth included): the units of
  // parallel work, in the order the whole traversal would meet them.
  Frontier frontier(int depth) const {
    Frontier f;
    const auto roots = root_tetrahedra(lat_.S);
    for (int r = 0; r < 6; ++r) collect(roots[static_cast<std::size_t>(r)], root_order(r), depth, f);
    return f;
  }

  // Calls leaf(t, voxel) for every leaf inside the box below t, depth first (voxel: its
  // refinement edge's midpoint, −1 for a unit tetrahedron), and split(voxel, t, span)
  // once the subtree of a split tetrahedron inside the box (midpoint at voxel) is done, with the
  // span the leaves below it returned. Returns the span of the whole subtree.
  template <class Leaf, class Split>
  ValueSpan visit(const Subtree& root, Leaf&& leaf, Split&& split) const {
    return visit(root.tet, root.order, Plain{}, leaf, split);
  }

  // The same walk over a grid's vertices (every corner of a tetrahedron walked inside the box is
  // one of them): leaf(t, corners, voxel) and split(voxel, id, t, span), with the numbers and
  // values carried down from the splits, so a leaf looks up none of its four.
  template <class Leaf, class Split>
  ValueSpan visit(const Subtree& root, const VertexNumbers& numbers, const std::vector<double>& values, Leaf&& leaf, Split&& split) const {
    return visit(root.tet, root.order, Numbered{numbers, values}, leaf, split);
  }

  const Lattice& lattice() const { return lat_; }

private:
  const Lattice& lat_;
  const Rule& rule_;

  struct Plain {};
  struct Numbered {
    const VertexNumbers& numbers;
    const std::vector<double>& values;
  };

  template <class Walk, class Leaf, class Split>
  ValueSpan visit(const Tet& t, OrderState o, const Walk& walk, Leaf& leaf, Split& split) const {
    if (inside(t)) {
      Tet scratch = t;
      if constexpr (std::is_same_v<Walk, Plain>) {
        return visit_in_place(scratch, o, leaf, split);
      } else {
        Corners corners;
        for (int k = 0; k < 4; ++k) {
          corners.id[k] = walk.numbers.id(lat_.index(t[k]));
          corners.value[k] = walk.values[corners.id[k]];
        }
        return visit_in_place(scratch, corners, o, walk, leaf, split);
      }
    }
    if (outside(t)) return {};
    Coord m;
    int i, j;
    if (!refinement(t, o, m, i, j) || !split_across(m)) return {};  // a leaf not inside is beyond the box
    if (!may_cut_across(m)) return {};
    const auto [a, b] = halves(t, o, m, i, j);
    ValueSpan s = visit(a.tet, a.order, walk, leaf, split);
    s.add(visit(b.tet, b.order, walk, leaf, split));
    return s;
  }

  // Inside the box, so are the halves: no more checks against it. The halves are made in t
  // itself, one vertex replaced by the midpoint and put back after (copying both halves a node
  // made the bunny's counting walk 1.07× slower).
  template <class Leaf, class Split>
  ValueSpan visit_in_place(Tet& t, OrderState o, Leaf& leaf, Split& split) const {
    Coord m;
    int i, j;
    if (!refinement(t, o, m, i, j)) return leaf(std::as_const(t), std::int64_t{-1});
    const std::int64_t voxel = lat_.index(m);
    const Decision d = rule_.decide(voxel);
    if (d == Decision::leaf) return leaf(std::as_const(t), voxel);
    if (d == Decision::prune) return {};
    const auto& e = order_table::kTable[o];
    const Coord end_j = t[static_cast<std::size_t>(j)], end_i = t[static_cast<std::size_t>(i)];
    t[static_cast<std::size_t>(j)] = m;
    ValueSpan s = visit_in_place(t, e.at_j, leaf, split);
    t[static_cast<std::size_t>(j)] = end_j;
    t[static_cast<std::size_t>(i)] = m;
    s.add(visit_in_place(t, e.at_i, leaf, split));
    t[static_cast<std::size_t>(i)] = end_i;
    split(voxel, std::as_const(t), s);
    return s;
  }

  // The numbered walk: the midpoint's number and value are looked up once, at its split.
  template <class Leaf, class Split>
  ValueSpan visit_in_place(Tet& t, Corners& c, OrderState o, const Numbered& walk, Leaf& leaf, Split& split) const {
    Coord m;
    int i, j;
    if (!refinement(t, o, m, i, j)) return leaf(std::as_const(t), std::as_const(c), std::int64_t{-1});
    const std::int64_t voxel = lat_.index(m);
    const Decision d = rule_.decide(voxel);
    if (d == Decision::leaf) return leaf(std::as_const(t), std::as_const(c), voxel);
    if (d == Decision::prune) return {};
    const auto& e = order_table::kTable[o];
    const std::uint32_t id = walk.numbers.id(voxel);
    const double value = walk.values[id];
    const auto si = static_cast<std::size_t>(i), sj = static_cast<std::size_t>(j);
    const Coord end_j = t[sj], end_i = t[si];
    const std::uint32_t id_j = c.id[sj], id_i = c.id[si];
    const double value_j = c.value[sj], value_i = c.value[si];
    t[sj] = m, c.id[sj] = id, c.value[sj] = value;
    ValueSpan s = visit_in_place(t, c, e.at_j, walk, leaf, split);
    t[sj] = end_j, c.id[sj] = id_j, c.value[sj] = value_j;
    t[si] = m, c.id[si] = id, c.value[si] = value;
    s.add(visit_in_place(t, c, e.at_i, walk, leaf, split));
    t[si] = end_i, c.id[si] = id_i, c.value[si] = value_i;
    split(voxel, id, std::as_const(t), s);
    return s;
  }

  void collect(const Tet& t, OrderState o, int depth, Frontier& f) const {
    if (outside(t)) return;
    Coord m;
    int i, j;
    if (depth == 0 || !refinement(t, o, m, i, j)) return f.roots.push_back({t, o});
    const bool in = inside(t);
    if (in) {
      const Decision d = rule_.decide(lat_.index(m));
      if (d == Decision::leaf) return f.roots.push_back({t, o});
      if (d == Decision::prune) return;
    } else if (!split_across(m) || !may_cut_across(m)) {
      return;  // a leaf not inside is beyond the box, or nothing beneath matters to the rule
    }
    const std::size_t first = f.roots.size();
    const auto [a, b] = halves(t, o, m, i, j);
    collect(a.tet, a.order, depth - 1, f);
    collect(b.tet, b.order, depth - 1, f);
    if (in) f.splits.push_back({lat_.index(m), t, first, f.roots.size()});
  }

  bool outside(const Tet& t) const { return tet_outside(lat_, t); }
  bool inside(const Tet& t) const { return tet_inside(lat_, t); }
  // A tetrahedron not inside the box: split when its diamond crosses the box (the rule decides
  // for a midpoint in the box, whose diamond may have tetrahedra inside).
  bool split_across(const Coord& m) const {
    if (lat_.in_box(m)) return rule_.split(lat_.index(m));
    return placement(classify(m, lat_.k), lat_).forced;
  }
  // A rule that prunes (a query for one iso-value) may prune tetrahedra across the box too, by
  // their diamond's centre.
  bool may_cut_across(const Coord& m) const {
    if constexpr (requires { rule_.may_cut_across(m); })
      return rule_.may_cut_across(m);
    else
      return true;
  }
};

}  // namespace adaptiso::detail
