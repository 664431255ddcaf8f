// Surfaces within a distance of a bisection grid's own surface (hierarchy_query.hpp:
// extract_within): refinement that follows the surface of one iso-value.
//
// After Gerstner & Pajarola, "Topology preserving and controlled topology simplifying
// multiresolution isosurface extraction" (IEEE Visualization 2000), and Gregorski, Duchaineau,
// Lindstrom, Pascucci & Joy, "Interactive view-dependent rendering of large isosurfaces" (IEEE
// Visualization 2002): the diamond hierarchy of longest-edge bisection refined where the surface
// of the iso-value asked for needs it, conforming because a split diamond's parents are split. The
// vertices are placed on the finest surface along each coarse edge, as Lengyel places the vertices
// of coarse Transvoxel cells ("Voxel-based terrain for real-time virtual simulations", 2010, §3.4):
// a coarse cut point interpolated from far-apart corners misses a sharp boundary by up to half the
// cell, the grid's own cut point inside the coarse edge does not.
//
// Three passes:
// 1. Refine (parallel, top-down): a tetrahedron whose diamond's values beneath straddle the
//    iso-value is split when its corners do not show the surface and its longest edge exceeds
//    2·distance (something hides beneath), or when the cut points its split adds (on the edges from
//    the refinement edge's midpoint to the other two corners) lie farther than `distance` from the
//    surface it has now (its one or two triangles through its own cut points). A tetrahedron's cut
//    points are carried down: a split keeps the refinement edge's cut point in one half and adds
//    at most two. The split diamonds are marked in a bitmap over the voxels.
// 2. Close: every marked diamond's parents are marked, up to the roots, so the selection is
//    closed upwards like the prepared grid's and the leaves form a conforming mesh. The result is
//    a set, the same for any thread count and order.
// 3. Walk the marked hierarchy (traversal.hpp) and march its leaves the surface cuts, each mesh
//    vertex on the grid's cut edge inside the coarse edge (march_detail.hpp: EdgeRemap).
#include <fmt/format.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <memory>

#include "adaptiso/error.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "extract/hierarchy_index.hpp"
#include "extract/march_detail.hpp"
#include "grid/traversal.hpp"

namespace adaptiso {
namespace detail {
namespace {

// A tetrahedron's six edges by its slots, and back.
constexpr int kEdgeOf[4][4] = {{-1, 0, 1, 2}, {0, -1, 3, 4}, {1, 3, -1, 5}, {2, 4, 5, -1}};

using Point = std::array<double, 3>;

// A bitmap over the voxels, zero pages until written (calloc of a large block maps fresh pages):
// a query marks the few diamonds along one surface, not the volume.
class Marks {
public:
  explicit Marks(std::size_t voxels)
      : words_((voxels + 63) / 64), bits_(static_cast<std::uint64_t*>(std::calloc(std::max<std::size_t>(1, words_), 8))) {
    if (!bits_) throw std::bad_alloc();
  }
  bool test(std::int64_t v) const {
    return (std::atomic_ref<std::uint64_t>(bits_.get()[v >> 6]).load(std::memory_order_relaxed) >> (v & 63)) & 1;
  }
  // True when v was not marked before.
  bool mark(std::int64_t v) {
    const std::uint64_t bit = std::uint64_t{1} << (v & 63);
    return !(std::atomic_ref<std::uint64_t>(bits_.get()[v >> 6]).fetch_or(bit, std::memory_order_relaxed) & bit);
  }

private:
  struct Free {
    void operator()(std::uint64_t* p) const { std::free(p); }
  };
  std::size_t words_;
  std::unique_ptr<std::uint64_t, Free> bits_;
};

// The closest point of triangle abc to p (Ericson, "Real-Time Collision Detection", §5.1.5),
// returned as the squared distance.
double distance2_to_triangle(const Point& p, const Point& a, const Point& b, const Point& c) {
  auto sub = [](const Point& u, const Point& v) { return Point{u[0] - v[0], u[1] - v[1], u[2] - v[2]}; };
  auto dot = [](const Point& u, const Point& v) { return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]; };
  auto at = [&](const Point& base, const Point& d1, double s, const Point& d2, double t) {
    return Point{base[0] + s * d1[0] + t * d2[0], base[1] + s * d1[1] + t * d2[1], base[2] + s * d1[2] + t * d2[2]};
  };
  auto d2 = [&](const Point& q) {
    const Point d = sub(p, q);
    return dot(d, d);
  };
  const Point ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
  const double d1 = dot(ab, ap), d2v = dot(ac, ap);
  if (d1 <= 0 && d2v <= 0) return d2(a);
  const Point bp = sub(p, b);
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return d2(b);
  const double vc = d1 * d4 - d3 * d2v;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return d2(at(a, ab, d1 / (d1 - d3), ac, 0));
  const Point cp = sub(p, c);
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return d2(c);
  const double vb = d5 * d2v - d1 * d6;
  if (vb <= 0 && d2v >= 0 && d6 <= 0) return d2(at(a, ab, 0, ac, d2v / (d2v - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return d2(Point{b[0] + w * (c[0] - b[0]), b[1] + w * (c[1] - b[1]), b[2] + w * (c[2] - b[2])});
  }
  if (!(va + vb + vc > 0)) return std::min({d2(a), d2(b), d2(c)});  // a degenerate triangle
  const double denom = 1 / (va + vb + vc);
  return d2(at(a, ab, vb * denom, ac, vc * denom));
}

// The grid's cut edge inside a hierarchy edge.
struct Cut {
  Coord below, above;
  std::uint32_t below_id, above_id;
  double below_value, above_value;
};

// A tetrahedron inside the box during refinement, with its corners and the cut points of its
// edges (valid where the edge is cut).
struct Node {
  Tet t;
  OrderState order;
  Corners c;
  std::array<Point, 6> cut;
};

struct Query {
  const Lattice& lat;
  const VertexNumbers& numbers;
  const LiningSpans& lining;
  const TetGrid& g;
  const BisectionHierarchy& h;
  double iso;
  double distance;   // voxels of the smallest spacing
  double distance2;
  double hidden2;    // (2·distance)²: longest edges up to which a hidden surface is left out
  double probe2;     // longest edges² above which a tetrahedron's triangles are probed
  bool everything;   // distance 0: every diamond the surface may cross is split
  Point unit;        // voxels of the smallest spacing per lattice step, per axis
  Marks& marks;
  tbb::enumerable_thread_specific<std::vector<std::int64_t>>& marked;
  tbb::enumerable_thread_specific<std::size_t>& explored;

  bool above(double v) const { return v >= iso; }

  // The grid's cut edge inside hierarchy edge (a, b), whose ends are grid vertices on either side
  // of the iso-value: bisect at the midpoints that are grid vertices, keeping the half whose ends
  // still differ. The grid's own edges are those whose midpoint is no vertex (or no lattice point).
  Cut snap(Coord a, std::uint32_t ia, double va, Coord b, std::uint32_t ib, double vb) const {
    if (above(va)) std::swap(a, b), std::swap(ia, ib), std::swap(va, vb);
    for (;;) {
      Coord m;
      for (int k = 0; k < 3; ++k) {
        const std::int32_t s = a[k] + b[k];
        if (s & 1) return {a, b, ia, ib, va, vb};
        m[k] = s / 2;
      }
      const std::int64_t voxel = lat.index(m);
      if (!numbers.used(voxel)) return {a, b, ia, ib, va, vb};
      const std::uint32_t id = numbers.id(voxel);
      const double vm = g.values[id];
      if (above(vm))
        b = m, ib = id, vb = vm;
      else
        a = m, ia = id, va = vm;
    }
  }
  // Where the grid's surface crosses that edge, in voxels (the march's interpolation, in double).
  Point point(const Cut& c) const {
    const double t = std::clamp((iso - c.below_value) / (c.above_value - c.below_value), kEdgeMargin, 1 - kEdgeMargin);
    Point p;
    for (int k = 0; k < 3; ++k) p[k] = (c.below[k] + t * (c.above[k] - c.below[k])) * unit[k];
    return p;
  }
  // The grid's interpolant at p (lattice units), and whether p lies in the box's grid at all:
  // descends the hierarchy from the root tetrahedron holding p to the grid's leaf holding it. Each
  // split's halves lie on either side of the plane through the midpoint and the two corners off
  // the refinement edge.
  static double orient(const Coord& a, const Coord& b, const Coord& d, const Point& x) {
    const double u[3] = {double(b[0] - a[0]), double(b[1] - a[1]), double(b[2] - a[2])};
    const double v[3] = {double(d[0] - a[0]), double(d[1] - a[1]), double(d[2] - a[2])};
    const double w[3] = {x[0] - a[0], x[1] - a[1], x[2] - a[2]};
    return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0]);
  }
  // Is p inside t (positively oriented), faces included?
  static bool holds(const Tet& t, const Point& p) {
    return orient(t[1], t[2], t[3], p) >= 0 && orient(t[0], t[3], t[2], p) >= 0 && orient(t[0], t[1], t[3], p) >= 0 &&
           orient(t[0], t[2], t[1], p) >= 0;
  }
  // The same, starting from tetrahedron `from` of the hierarchy when it holds p (a probe near the
  // tetrahedron being decided saves the descent from the root).
  bool value_at(const Point& p, double& value, const Tet& from, OrderState from_order) const {
    if (holds(from, p)) return value_at(p, value, &from, from_order);
    return value_at(p, value, nullptr, 0);
  }
  bool value_at(const Point& p, double& value, const Tet* from = nullptr, OrderState from_order = 0) const {
    Tet t;
    OrderState o;
    if (from) {
      t = *from, o = from_order;
    } else if (!root_holding(p, t, o)) {
      return false;
    }
    for (;;) {
      Coord m;
      int i, j;
      if (!refinement(t, o, m, i, j)) break;
      if (lat.in_box(m) ? !numbers.used(lat.index(m)) : !placement(classify(m, lat.k), lat).forced) break;
      int k = 0;
      while (k == i || k == j) ++k;
      int l = k + 1;
      while (l == i || l == j) ++l;
      const Point ti{double(t[i][0]), double(t[i][1]), double(t[i][2])};
      const bool keeps_i = (orient(m, t[k], t[l], p) >= 0) == (orient(m, t[k], t[l], ti) >= 0);
      const auto& e = order_table::kTable[o];
      t[static_cast<std::size_t>(keeps_i ? j : i)] = m;
      o = keeps_i ? e.at_j : e.at_i;
    }
    if (!tet_inside(lat, t)) return false;
    // Barycentric coordinates of p in t, by volumes.
    double vol[4], total = 0;
    for (int k = 0; k < 4; ++k) {
      const Coord& a = t[static_cast<std::size_t>((k + 1) % 4)];
      const Coord& b = t[static_cast<std::size_t>((k + 2) % 4)];
      const Coord& d = t[static_cast<std::size_t>((k + 3) % 4)];
      vol[k] = std::abs(orient(a, b, d, p));
      total += vol[k];
    }
    if (!(total > 0)) return false;
    value = 0;
    for (int k = 0; k < 4; ++k) value += vol[k] / total * g.values[numbers.id(lat.index(t[static_cast<std::size_t>(k)]))];
    return true;
  }
  // The root tetrahedron holding p: Kuhn's, 0 ≤ x_c ≤ x_b ≤ x_a ≤ S for its axis order (a, b, c).
  bool root_holding(const Point& p, Tet& t, OrderState& o) const {
    const auto roots = root_tetrahedra(lat.S);
    int r = 0;
    for (; r < 6; ++r) {
      int axis[3] = {0, 0, 0};  // the path from corner 0: its first, second and last step
      for (const Coord& v : roots[static_cast<std::size_t>(r)])
        if ((v[0] != 0) + (v[1] != 0) + (v[2] != 0) == 1) axis[0] = v[1] != 0 ? 1 : v[2] != 0 ? 2 : 0;
      for (const Coord& v : roots[static_cast<std::size_t>(r)])
        if ((v[0] != 0) + (v[1] != 0) + (v[2] != 0) == 2)
          for (int a = 0; a < 3; ++a)
            if (v[a] != 0 && a != axis[0]) axis[1] = a;
      axis[2] = 3 - axis[0] - axis[1];
      if (p[axis[0]] >= p[axis[1]] && p[axis[1]] >= p[axis[2]]) break;
    }
    if (r == 6) return false;
    t = roots[static_cast<std::size_t>(r)];
    o = root_order(r);
    return true;
  }

  // Is p (voxels) farther than the distance from the grid's surface? p is within it when the
  // grid's interpolant has opposite signs at p ± distance·normal (the surface crosses the segment
  // between them); otherwise it is taken as farther (a surface meeting the segment obliquely or
  // twice costs a needless split). Points off the grid's box are not judged.
  bool far_from_surface(const Point& pv, const Point& normal, const Tet& near, OrderState near_order) const {
    bool side[2];
    for (int s = 0; s < 2; ++s) {
      const double sign = s ? -1 : 1;
      Point x;
      for (int a = 0; a < 3; ++a) x[a] = std::clamp((pv[a] + sign * distance * normal[a]) / unit[a], 0.0, double(lat.X[a]));
      double v;
      if (!value_at(x, v, near, near_order)) return false;
      side[s] = above(v);
    }
    return side[0] == side[1];
  }

  double longest_edge2(const Tet& t) const {
    double best = 0;
    for (int i = 0; i < 4; ++i)
      for (int j = i + 1; j < 4; ++j) {
        double d = 0;
        for (int k = 0; k < 3; ++k) {
          const double e = (t[i][k] - t[j][k]) * unit[k];
          d += e * e;
        }
        best = std::max(best, d);
      }
    return best;
  }
};

class Refine {
public:
  explicit Refine(const Query& q) : q_(q) {}

  void tetrahedron(const Tet& t, OrderState o, int depth) const {
    if (tet_outside(q_.lat, t)) return;
    if (tet_inside(q_.lat, t)) {
      Split at;
      if (!worth_deciding(t, o, at)) return;  // before the corners' lookups: most of the box's lining stops here
      Node n{t, o, {}, {}};
      for (int k = 0; k < 4; ++k) {
        n.c.id[k] = q_.numbers.id(q_.lat.index(t[k]));
        n.c.value[k] = q_.g.values[n.c.id[k]];
      }
      for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j)
          if (q_.above(n.c.value[i]) != q_.above(n.c.value[j]))
            n.cut[kEdgeOf[i][j]] = q_.point(q_.snap(t[i], n.c.id[i], n.c.value[i], t[j], n.c.id[j], n.c.value[j]));
      return decide(n, at, depth);
    }
    // Across the box's far faces: split when its diamond is (the grid's forced splits).
    Coord m;
    int i, j;
    if (!refinement(t, o, m, i, j)) return;
    if (q_.lat.in_box(m) ? !q_.numbers.used(q_.lat.index(m)) : !placement(classify(m, q_.lat.k), q_.lat).forced) return;
    if (!q_.lining.may_cut(q_.lat, m, q_.iso)) return;
    const auto [a, b] = halves(t, o, m, i, j);
    both(depth, [&] { tetrahedron(a.tet, a.order, depth + 1); }, [&] { tetrahedron(b.tet, b.order, depth + 1); });
  }

private:
  const Query& q_;
  static constexpr int kParallelDepth = 14;

  template <class A, class B>
  static void both(int depth, A&& a, B&& b) {
    if (depth < kParallelDepth)
      tbb::parallel_invoke(a, b);
    else
      a(), b();
  }

  // The squared distance from p to the surface the tetrahedron has now (+∞ without one).
  double distance2_to_surface(const Node& n, const Point& p) const {
    const std::uint8_t code = static_cast<std::uint8_t>(q_.above(n.c.value[0]) | (q_.above(n.c.value[1]) << 1) |
                                                        (q_.above(n.c.value[2]) << 2) | (q_.above(n.c.value[3]) << 3));
    const Case& cs = kCases[code];
    double best = std::numeric_limits<double>::infinity();
    for (int t = 0; t < cs.triangles; ++t) {
      const auto& tri = cs.tri[t];
      best = std::min(best, distance2_to_triangle(p, n.cut[kEdgeOf[tri[0].below][tri[0].above]], n.cut[kEdgeOf[tri[1].below][tri[1].above]],
                                                  n.cut[kEdgeOf[tri[2].below][tri[2].above]]));
    }
    return best;
  }

  // Does the grid's surface lie farther than the distance from the centre of one of the
  // tetrahedron's triangles? To first order the distance from a point p to it is
  // |f(p) − iso| / |∇f| in the grid's tetrahedron holding p (found by descending the hierarchy
  // from this one): a triangle across a thin wall, or under a bulge, has its centre deep on one
  // side.
  bool probe_far(const Node& n) const {
    const std::uint8_t code = static_cast<std::uint8_t>(q_.above(n.c.value[0]) | (q_.above(n.c.value[1]) << 1) |
                                                        (q_.above(n.c.value[2]) << 2) | (q_.above(n.c.value[3]) << 3));
    const Case& cs = kCases[code];
    for (int t = 0; t < cs.triangles; ++t) {
      const Point& x0 = n.cut[kEdgeOf[cs.tri[t][0].below][cs.tri[t][0].above]];
      const Point& x1 = n.cut[kEdgeOf[cs.tri[t][1].below][cs.tri[t][1].above]];
      const Point& x2 = n.cut[kEdgeOf[cs.tri[t][2].below][cs.tri[t][2].above]];
      Point p, u, v;
      for (int a = 0; a < 3; ++a) p[a] = (x0[a] + x1[a] + x2[a]) / 3, u[a] = x1[a] - x0[a], v[a] = x2[a] - x0[a];
      Point nrm{u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
      const double len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
      if (!(len > 0)) continue;
      for (double& c : nrm) c /= len;
      if (q_.far_from_surface(p, nrm, n.t, n.order)) return true;
    }
    return false;
  }

  // The split of a tetrahedron inside the box: its refinement edge's midpoint and slots, and the
  // midpoint's vertex.
  struct Split {
    Coord m;
    int i, j;
    std::uint32_t id;
  };
  // Could the tetrahedron be split at all: is it split in the grid, with a surface beneath?
  bool worth_deciding(const Tet& t, OrderState o, Split& at) const {
    if (!refinement(t, o, at.m, at.i, at.j)) return false;  // a unit tetrahedron
    const std::int64_t voxel = q_.lat.index(at.m);
    if (!q_.numbers.used(voxel)) return false;  // a leaf of the grid
    at.id = q_.numbers.id(voxel);
    const auto& span = q_.h.value_span[at.id];
    return span[0] < q_.iso && q_.iso <= span[1];  // else no surface beneath
  }

  void node(const Node& n, int depth) const {
    Split at;
    if (worth_deciding(n.t, n.order, at)) decide(n, at, depth);
  }

  void decide(const Node& n, const Split& at, int depth) const {
    ++q_.explored.local();
    const Coord& m = at.m;
    const int i = at.i, j = at.j;
    const std::uint32_t id = at.id;
    const std::int64_t voxel = q_.lat.index(m);
    const bool forced = q_.h.error_code[id] == ErrorCodes::kForced;
    const double vm = q_.g.values[id];
    // The other two corners, and the cut points the split adds on the edges from m to them.
    int others[2], n_others = 0;
    for (int k = 0; k < 4; ++k)
      if (k != i && k != j) others[n_others++] = k;
    Point added[2];
    bool cut[2];
    for (int s = 0; s < 2; ++s) {
      const int k = others[s];
      cut[s] = q_.above(vm) != q_.above(n.c.value[k]);
      if (cut[s]) added[s] = q_.point(q_.snap(m, id, vm, n.t[k], n.c.id[k], n.c.value[k]));
    }
    bool split = forced || q_.everything;
    if (!split) {
      const bool shown = q_.above(n.c.value[0]) != q_.above(n.c.value[1]) || q_.above(n.c.value[0]) != q_.above(n.c.value[2]) ||
                         q_.above(n.c.value[0]) != q_.above(n.c.value[3]);
      const double longest2 = q_.longest_edge2(n.t);
      if (!shown) {
        split = longest2 > q_.hidden2;
      } else {
        for (int s = 0; s < 2 && !split; ++s) split = cut[s] && distance2_to_surface(n, added[s]) > q_.distance2;
        // A triangle whose edges are shorter than the distance lies within it of its corners,
        // which are on the grid's surface; a larger one is probed at its centre.
        if (!split && longest2 > q_.probe2) split = probe_far(n);
      }
    }
    if (!split) return;
    if (!forced && q_.marks.mark(voxel)) q_.marked.local().push_back(voxel);
    const auto& e = order_table::kTable[n.order];
    Node a = n, b = n;  // a: m in slot j; b: m in slot i
    a.t[static_cast<std::size_t>(j)] = m, a.order = e.at_j, a.c.id[j] = id, a.c.value[j] = vm;
    b.t[static_cast<std::size_t>(i)] = m, b.order = e.at_i, b.c.id[i] = id, b.c.value[i] = vm;
    for (int s = 0; s < 2; ++s) {
      if (!cut[s]) continue;
      a.cut[kEdgeOf[j][others[s]]] = added[s];
      b.cut[kEdgeOf[i][others[s]]] = added[s];
    }
    // The refinement edge's halves: the cut point stays in the half whose ends differ, unless the
    // edge was not cut at all and the midpoint differs from both ends (a surface hidden between).
    if (q_.above(n.c.value[i]) == q_.above(n.c.value[j]) && q_.above(vm) != q_.above(n.c.value[i])) {
      a.cut[kEdgeOf[i][j]] = q_.point(q_.snap(n.t[i], n.c.id[i], n.c.value[i], m, id, vm));
      b.cut[kEdgeOf[i][j]] = q_.point(q_.snap(m, id, vm, n.t[j], n.c.id[j], n.c.value[j]));
    }
    both(depth, [&] { node(a, depth + 1); }, [&] { node(b, depth + 1); });
  }
};

// Every marked diamond's parents marked, up to the roots (or to diamonds the box forces, split in
// any case, like their parents). Returns how many were added.
std::size_t close_upwards(const Query& q, std::vector<std::int64_t> pending) {
  std::size_t added = 0;
  while (!pending.empty()) {
    const std::int64_t v = pending.back();
    pending.pop_back();
    const Coord c{static_cast<std::int32_t>(v % q.lat.nx), static_cast<std::int32_t>(v % q.lat.nxy / q.lat.nx),
                  static_cast<std::int32_t>(v / q.lat.nxy)};
    const Diamond d = classify(c, q.lat.k);
    Coord up[4];
    const int n = parents(d, q.lat.S, up);
    for (int p = 0; p < n; ++p) {
      if (!q.lat.in_box(up[p])) continue;  // a diamond across the box: forced
      const std::int64_t pv = q.lat.index(up[p]);
      if (!q.numbers.used(pv)) continue;  // a root corner (no diamond)
      if (q.h.error_code[q.numbers.id(pv)] == ErrorCodes::kForced) continue;
      if (q.marks.mark(pv)) {
        ++added;
        pending.push_back(pv);
      }
    }
  }
  return added;
}

// The final walk: split where marked (or forced), pruned where nothing beneath straddles.
struct MarkedRule {
  const Lattice& lat;
  const VertexNumbers& numbers;
  const LiningSpans& lining;
  const BisectionHierarchy& h;
  const Marks& marks;
  double iso;
  bool may_cut_across(const Coord& m) const { return lining.may_cut(lat, m, iso); }
  bool split(std::int64_t voxel) const {
    const std::uint32_t id = numbers.find(voxel);
    return id != VertexNumbers::kNone && (h.error_code[id] == ErrorCodes::kForced || marks.test(voxel));
  }
  Decision decide(std::int64_t voxel) const {
    const std::uint32_t id = numbers.find(voxel);
    if (id == VertexNumbers::kNone || !(h.error_code[id] == ErrorCodes::kForced || marks.test(voxel))) return Decision::leaf;
    const auto& span = h.value_span[id];
    return span[0] < iso && iso <= span[1] ? Decision::descend : Decision::prune;
  }
};

// Coarse cut edges to the grid's cut edges inside them, for the march.
class SnapRemap : public EdgeRemap {
public:
  SnapRemap(const Query& q) : q_(q) {}
  std::uint64_t fine(std::uint64_t key) const override {
    const auto below = static_cast<std::uint32_t>(key >> 32), above = static_cast<std::uint32_t>(key);
    const Cut c = q_.snap(coord(below), below, q_.g.values[below], coord(above), above, q_.g.values[above]);
    return edge_key(c.below_id, c.above_id);
  }

private:
  const Query& q_;
  Coord coord(std::uint32_t v) const {
    const auto& p = q_.g.ijk[v];
    return {static_cast<std::int32_t>(p[0]), static_cast<std::int32_t>(p[1]), static_cast<std::int32_t>(p[2])};
  }
};

}  // namespace
}  // namespace detail

Mesh HierarchyQuery::extract_within(double iso, double distance, DistanceQueryStats* stats) const {
  using namespace detail;
  using Clock = std::chrono::steady_clock;
  if (!std::isfinite(iso)) throw OptionError("iso", "must be a finite number");
  if (!(distance >= 0) || !std::isfinite(distance))
    throw OptionError("distance", fmt::format("must be a non-negative number of voxels, got {}", distance));
  const auto t0 = Clock::now();
  const TetGrid& g = grid_->grid;
  const BisectionHierarchy& h = *grid_->hierarchy;
  const Lattice& lat = index_->lat;
  const double smallest = std::min({g.source.spacing[0], g.source.spacing[1], g.source.spacing[2]});
  Marks marks(static_cast<std::size_t>(lat.nxy * (lat.X[2] + 1)));
  tbb::enumerable_thread_specific<std::vector<std::int64_t>> marked;
  tbb::enumerable_thread_specific<std::size_t> explored(0);
  const Query q{lat,
                index_->numbers,
                index_->lining,
                g,
                h,
                iso,
                distance,
                distance * distance,
                4 * distance * distance,
                std::max(4.0, distance * distance),
                distance == 0,
                {g.source.spacing[0] / smallest, g.source.spacing[1] / smallest, g.source.spacing[2] / smallest},
                marks,
                marked,
                explored};
  const Refine refine(q);
  const auto roots = root_tetrahedra(lat.S);
  tbb::parallel_for(0, 6, [&](int r) { refine.tetrahedron(roots[static_cast<std::size_t>(r)], root_order(r), 0); });
  std::vector<std::int64_t> pending;
  for (auto& part : marked) pending.insert(pending.end(), part.begin(), part.end());
  const std::size_t refined = pending.size();
  const std::size_t closure = close_upwards(q, std::move(pending));
  const auto t1 = Clock::now();

  const MarkedRule rule{lat, index_->numbers, index_->lining, h, marks, iso};
  const Traversal<MarkedRule> walk(lat, rule);
  const Frontier top = walk.frontier(10);
  std::vector<std::vector<Quad>> found(top.roots.size());
  std::vector<std::size_t> visited(top.roots.size(), 0);
  tbb::parallel_for(std::size_t{0}, top.roots.size(), [&](std::size_t f) {
    auto& out = found[f];
    std::size_t seen = 0;
    walk.visit(
        top.roots[f], index_->numbers, g.values,
        [&](const Tet&, const Corners& c, std::int64_t) {
          ++seen;
          const double lo = std::min({c.value[0], c.value[1], c.value[2], c.value[3]});
          const double hi = std::max({c.value[0], c.value[1], c.value[2], c.value[3]});
          if (lo < iso && iso <= hi) out.push_back(c.id);
          return ValueSpan{};
        },
        [&](std::int64_t, std::uint32_t, const Tet&, const ValueSpan&) { ++seen; });
    visited[f] = seen;
  });
  std::vector<Quad> quads;
  std::size_t total = 0;
  for (const auto& part : found) total += part.size();
  quads.reserve(total);
  for (const auto& part : found) quads.insert(quads.end(), part.begin(), part.end());
  const auto t2 = Clock::now();
  Mesh mesh;
  MarchScratch scratch;
  const SnapRemap remap(q);
  scratch.remap = &remap;
  march_into(g, QuadTets{g, quads}, iso, mesh, scratch, nullptr, nullptr);
  if (stats) {
    stats->iso = iso;
    stats->distance = distance;
    stats->tetrahedra = quads.size();
    stats->explored = explored.combine(std::plus<>());
    stats->refined = refined + closure;
    stats->closure = closure;
    stats->visited = top.roots.size() + top.splits.size();
    for (std::size_t v : visited) stats->visited += v;
    stats->triangles = mesh.triangle_count();
    stats->vertices = mesh.vertex_count();
    stats->in_range = iso >= g.source.min && iso <= g.source.max;
    stats->refine_seconds = std::chrono::duration<double>(t1 - t0).count();
    stats->walk_seconds = std::chrono::duration<double>(t2 - t1).count();
    stats->march_seconds = std::chrono::duration<double>(Clock::now() - t2).count();
  }
  return mesh;
}

}  // namespace adaptiso
