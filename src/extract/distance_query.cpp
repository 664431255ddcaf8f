// Surfaces within a distance of a bisection grid's own surface (hierarchy_query.hpp:
// extract_within): refinement that follows the surface of one iso-value.
//
// After Gerstner & Pajarola, "Topology preserving and controlled topology simplifying
// multiresolution isosurface extraction" (IEEE Visualization 2000), and Gregorski, Duchaineau,
// Lindstrom, Pascucci & Joy, "Interactive view-dependent rendering of large isosurfaces" (IEEE
// Visualization 2002): the diamond hierarchy of longest-edge bisection, refined where the surface
// of the iso-value asked for needs it, conforming because a split diamond's parents are split.
// Vertices are placed on the finest surface along each coarse edge, as Lengyel places those of
// coarse Transvoxel cells ("Voxel-based terrain for real-time virtual simulations", 2010): a cut
// point interpolated between far-apart corners misses a sharp boundary by up to half the cell, the
// grid's own cut point inside the coarse edge does not.
//
// A tetrahedron the surface may cross (the values beneath its diamond straddle the iso-value) is
// split when
// - its surface (one or two triangles through its edges' cut points, which lie on the grid's
//   surface) is too far: a triangle's centre farther than the distance from the grid's surface
//   (the grid's interpolant has the same sign at both ends of centre ± distance·normal), or, in a
//   triangle longer than 3·distance, one of its corner quarters' centres (triangle_far), or a cut
//   point the split adds (on the edges from the refinement edge's midpoint to the other two
//   corners) farther than the distance from its triangles;
// - or a surface hides beneath and its longest edge exceeds the distance: no corner shows it, or
//   (longer than √3·distance) the midpoint differs from both ends of the refinement edge.
// - or it shows the surface, passes those tests, its longest edge exceeds the distance and a
//   search beneath finds more surface (look_beneath): in the half of it whose corners all lie on
//   one side, or, when it shows only a speck, a part farther than the distance from the speck. A
//   speck of surface must not hide the rest of the tetrahedron.
// Hidden parts inside tetrahedra no longer than the distance are left out (and parts beside a
// larger surface inside a tetrahedron that shows it, not searched: the distance tests' triangles
// do not reach them), and so are the splits made to look for them: a split for a hidden surface
// is kept only when some tetrahedron beneath it shows the surface at its corners, so a part left
// out costs its neighbours no closure. Tetrahedra whose longest edge is within the
// distance are not probed: every point of their triangles lies within it of a cut point. A small
// triangle in a larger tetrahedron is probed all the same: the probe along its normal also finds
// the grid's surface bulging away from it inside the tetrahedron, which its corners cannot show
// (sparing it cost the FLAIR brain's p95 distance 2.3 -> 3.5 voxels at 2).
//
// Three passes:
// 1. Refine (parallel, top-down), each tetrahedron carrying its corners and its edges' cut points
//    (a split keeps the refinement edge's cut point in one half and adds at most two); the split
//    diamonds are marked in a bitmap over the voxels.
// 2. Close: every marked diamond's parents are marked, up to the roots, so the leaves form a
//    conforming mesh. A set: the same for any thread count.
// 3. Walk the marked hierarchy (traversal.hpp) and march its cut leaves in walk order, each mesh
//    vertex on the grid's cut edge inside the coarse edge; vertices numbered by first use,
//    chunk-parallel (march_detail.hpp). Clipped to the volume's box, and pieces smaller than the
//    distance dropped (specks.hpp: their bounding box's diagonal under it), before the collapses,
//    which cannot thin a closed piece below four triangles.
// 4. Rounds of edge collapses checked by the same tests (below, "Edge collapses"), and the pieces
//    they shrank below the distance dropped.
//
// Tried and not kept: whole cubes of the hierarchy contoured as marching cubes along their 12
// axis edges (loops of their faces' segments, the face diagonals' cuts dropped between whole
// cubes). On the CT bunny it saved 4 % of the triangles (whole cubes are few among the leaves)
// and moved the surface farther: its triangles were not the ones the refinement had tested.
#include <fmt/format.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <deque>
#include <memory>
#include <stdexcept>
#include <unordered_map>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "extract/box_clip.hpp"
#include "extract/hierarchy_index.hpp"
#include "extract/march_detail.hpp"
#include "extract/specks.hpp"
#include "extract/triangle_cover.hpp"
#include "grid/share_agree.hpp"
#include "grid/traversal.hpp"
#include "util/big_array.hpp"

namespace adaptiso {
namespace detail {
namespace {

using Point = std::array<double, 3>;

// |x − y|²
double distance2(const Point& x, const Point& y) {
  return (x[0] - y[0]) * (x[0] - y[0]) + (x[1] - y[1]) * (x[1] - y[1]) + (x[2] - y[2]) * (x[2] - y[2]);
}

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

// A corner of a cube or tetrahedron: lattice point, grid vertex, value.
struct Corner {
  Coord at;
  std::uint32_t id;
  double value;
};

// A cut point: the coarse edge it cuts (edge_key: below vertex << 32 | above vertex) and its place
// on the grid's surface (voxels).
struct CutPoint {
  std::uint64_t key;
  Point p;
};

// Which side of the plane through the refinement edge's midpoint m and the corners k < l off it
// corner i lies on, for a positively oriented tetrahedron split along edge (i, j): orient(m, t_k,
// t_l, t_i) = −½·det(t_k − t_i, t_l − t_i, t_j − t_i), the orientation of (t_i, t_k, t_l, t_j)
// negated: positive when that permutation of (0, 1, 2, 3) is odd. The descent of a probe then
// needs one orientation test a step, not two.
constexpr bool odd_permutation(std::array<int, 4> p) {
  int swaps = 0;
  for (int a = 0; a < 4; ++a)
    for (int b = a + 1; b < 4; ++b) swaps += p[static_cast<std::size_t>(a)] > p[static_cast<std::size_t>(b)];
  return swaps % 2;
}
constexpr std::array<std::array<bool, 4>, 4> corner_i_side() {
  std::array<std::array<bool, 4>, 4> side{};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      if (i == j) continue;
      int k = 0;
      while (k == i || k == j) ++k;
      int l = k + 1;
      while (l == i || l == j) ++l;
      side[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)] = odd_permutation({i, k, l, j});
    }
  return side;
}
inline constexpr auto kCornerISide = corner_i_side();
// The two corners off edge (i, j), k < l: both descents step with them.
constexpr std::array<std::array<std::array<std::uint8_t, 2>, 4>, 4> corners_off() {
  std::array<std::array<std::array<std::uint8_t, 2>, 4>, 4> off{};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      int n = 0;
      for (int k = 0; k < 4 && n < 2; ++k)
        if (k != i && k != j)
          off[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)][static_cast<std::size_t>(n++)] = static_cast<std::uint8_t>(k);
    }
  return off;
}
inline constexpr auto kCornersOff = corners_off();

// A tetrahedron inside the box during refinement: its corners and its edges' cut points (valid
// where the edge is cut), and the tetrahedron it was split from (on the refinement's stack).
constexpr int kEdgeOf[4][4] = {{-1, 0, 1, 2}, {0, -1, 3, 4}, {1, 3, -1, 5}, {2, 4, 5, -1}};
struct Subtree;
struct Node {
  Tet t;
  OrderState order;
  Corner c[4];
  Point cut[6];
  const Node* parent = nullptr;
  Subtree* sub = nullptr;  // a subtree dealt to this process (Dealing), refined whole here
};

struct Query {
  const Lattice& lat;
  const VertexNumbers& numbers;
  const LiningSpans& lining;
  const TetGrid& g;
  const BisectionHierarchy& h;
  double iso;
  double distance;  // voxels of the smallest spacing
  bool everything;  // distance 0: every diamond with a surface beneath is split
  Point unit;       // voxels of the smallest spacing per lattice step, per axis
  Marks& split;     // diamonds split (their test, or the closure)
  tbb::enumerable_thread_specific<std::vector<std::int64_t>>& marked;
  tbb::enumerable_thread_specific<std::size_t>& tested;
  const std::atomic<bool>* cancel;  // raised: stop (ExtractCancelled), or nullptr

  bool cancelled() const { return cancel && cancel->load(std::memory_order_relaxed); }
  void throw_if_cancelled() const {
    if (cancelled()) throw ExtractCancelled();
  }
  bool above(double v) const { return v >= iso; }
  Corner corner(const Coord& c) const {
    const std::uint32_t id = numbers.id(lat.index(c));
    return {c, id, g.values[id]};
  }
  // Grid vertex v's lattice point.
  Coord lattice_point(std::uint32_t v) const {
    const auto& p = g.ijk[v];
    return {static_cast<std::int32_t>(p[0]), static_cast<std::int32_t>(p[1]), static_cast<std::int32_t>(p[2])};
  }
  bool forced(std::uint32_t id) const { return h.error_code[id] == ErrorCodes::kForced; }
  bool may_cut(std::uint32_t id) const {
    const auto& span = h.value_span[id];
    return span[0] < iso && iso <= span[1];
  }

  // The grid's cut edge inside hierarchy edge (a, b), whose ends are grid vertices on either side
  // of the iso-value: bisect at the midpoints that are grid vertices, keeping the half whose ends
  // still differ. The grid's own edges are those whose midpoint is no vertex (or no lattice point).
  Cut snap(Corner a, Corner b) const {
    if (above(a.value)) std::swap(a, b);
    for (;;) {
      Coord m;
      for (int k = 0; k < 3; ++k) {
        const std::int32_t s = a.at[k] + b.at[k];
        if (s & 1) return {a.at, b.at, a.id, b.id, a.value, b.value};
        m[k] = s / 2;
      }
      const std::int64_t voxel = lat.index(m);
      if (!numbers.used(voxel)) return {a.at, b.at, a.id, b.id, a.value, b.value};
      const Corner c = corner(m);
      (above(c.value) ? b : a) = c;
    }
  }
  // Where the grid's surface crosses that edge, in voxels (the march's interpolation, in double).
  Point point(const Cut& c) const {
    const double t = std::clamp((iso - c.below_value) / (c.above_value - c.below_value), kEdgeMargin, 1 - kEdgeMargin);
    Point p;
    for (int k = 0; k < 3; ++k) p[k] = (c.below[k] + t * (c.above[k] - c.below[k])) * unit[k];
    return p;
  }
  CutPoint cut(const Corner& a, const Corner& b) const {
    const bool a_above = above(a.value);
    return {edge_key(a_above ? b.id : a.id, a_above ? a.id : b.id), point(snap(a, b))};
  }

  // ---- geometry ----

  static double orient(const Coord& a, const Coord& b, const Coord& d, const Point& x) {
    const double u[3] = {double(b[0] - a[0]), double(b[1] - a[1]), double(b[2] - a[2])};
    const double v[3] = {double(d[0] - a[0]), double(d[1] - a[1]), double(d[2] - a[2])};
    const double w[3] = {x[0] - a[0], x[1] - a[1], x[2] - a[2]};
    return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0]);
  }
  // The root tetrahedron holding p: Kuhn's, 0 ≤ x_c ≤ x_b ≤ x_a ≤ S for its axis order (a, b, c).
  bool root_holding(const Point& p, Tet& t, OrderState& o) const {
    const auto roots = root_tetrahedra(lat.S);
    for (int r = 0; r < 6; ++r) {
      int axis[3] = {0, 0, 0};  // the path from corner 0: its first, second and last step
      for (const Coord& v : roots[static_cast<std::size_t>(r)])
        if ((v[0] != 0) + (v[1] != 0) + (v[2] != 0) == 1) axis[0] = v[1] != 0 ? 1 : v[2] != 0 ? 2 : 0;
      for (const Coord& v : roots[static_cast<std::size_t>(r)])
        if ((v[0] != 0) + (v[1] != 0) + (v[2] != 0) == 2)
          for (int a = 0; a < 3; ++a)
            if (v[a] != 0 && a != axis[0]) axis[1] = a;
      axis[2] = 3 - axis[0] - axis[1];
      if (p[axis[0]] >= p[axis[1]] && p[axis[1]] >= p[axis[2]]) {
        t = roots[static_cast<std::size_t>(r)];
        o = root_order(r);
        return true;
      }
    }
    return false;
  }
  // The grid's interpolant at p (lattice units), or a value on its side of the iso-value: descends
  // the hierarchy from the root tetrahedron holding p towards the grid's leaf holding it (each
  // split's halves lie on either side of the plane through the midpoint and the two corners off
  // the refinement edge), until everything beneath is on one side. Returns false off the grid.
  // Is p inside t, faces included? Every tetrahedron of the hierarchy is positively oriented, so
  // the corner opposite face k (corners k+1, k+2, k+3) lies on its negative side for even k and
  // on its positive side for odd k; p must lie on that side of every face, or on the face. The
  // faces' normals are integer cross products.
  static bool holds(const Tet& t, const Point& p) {
    for (int k = 0; k < 4; ++k) {
      const Coord &a = t[static_cast<std::size_t>((k + 1) % 4)], &b = t[static_cast<std::size_t>((k + 2) % 4)],
                  &c = t[static_cast<std::size_t>((k + 3) % 4)];
      const std::int64_t u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
      const double n[3] = {double(u[1] * v[2] - u[2] * v[1]), double(u[2] * v[0] - u[0] * v[2]), double(u[0] * v[1] - u[1] * v[0])};
      const double side = n[0] * (p[0] - a[0]) + n[1] * (p[1] - a[1]) + n[2] * (p[2] - a[2]);
      if (k % 2 ? side < 0 : side > 0) return false;
    }
    return true;
  }
  // With `near`, the descent starts from the nearest of it and its ancestors that holds p: a probe
  // beside the tetrahedron being tested is mostly inside it or its parent.
  bool value_at(const Point& p, double& value, const Node* near = nullptr) const {
    if (near && value_from_below(p, value, std::max(1, cube_scale(near->t) / 2)) == Cubes::answered) return true;
    Tet t;
    OrderState o;
    while (near && !holds(near->t, p)) near = near->parent;
    if (near)
      t = near->t, o = near->order;
    else if (!root_holding(p, t, o))
      return false;
    return descend(p, value, t, o);
  }
  // The same for a probe beside a mesh: cube by cube from the smallest cubes up, else from the
  // root tetrahedron holding p.
  struct FromCubes {};
  bool value_at(const Point& p, double& value, FromCubes) const {
    return value_from_below(p, value, lat.S / 2) == Cubes::answered || value_at(p, value);
  }
  // From t (which holds p) towards the grid's leaf holding p, until everything beneath is on one
  // side.
  bool descend(const Point& p, double& value, Tet t, OrderState o) const {
    for (;;) {
      Coord m;
      int i, j;
      if (!refinement(t, o, m, i, j)) break;
      if (lat.in_box(m)) {
        const std::int64_t voxel = lat.index(m);
        if (!numbers.used(voxel)) break;
        // Everything beneath on one side: so is p (most probes stop a few levels above the leaf).
        // A diamond across the box keeps the span of its tetrahedra inside it only.
        const std::uint32_t id = numbers.id(voxel);
        if (one_sided(id, value) && (tet_inside(lat, t) || !forced(id))) return true;  // the box test first: no load
      } else if (!placement(classify(m, lat.k), lat).forced) {
        break;
      }
      const auto& off = kCornersOff[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)];
      const bool keeps_i = (orient(m, t[off[0]], t[off[1]], p) >= 0) == kCornerISide[i][j];
      const auto& e = order_table::kTable[o];
      t[static_cast<std::size_t>(keeps_i ? j : i)] = m;
      o = keeps_i ? e.at_j : e.at_i;
    }
    if (!tet_inside(lat, t)) return false;
    return interpolate(t, p, value);
  }
  // The half side of the cubes whose Kuhn tetrahedra are as large as t, or larger: the first
  // cubes value_by_cubes looks at for a probe beside t.
  static std::int32_t cube_scale(const Tet& t) {
    std::int32_t extent = 0;
    for (int k = 0; k < 3; ++k)
      extent = std::max(extent, std::max({t[0][k], t[1][k], t[2][k], t[3][k]}) - std::min({t[0][k], t[1][k], t[2][k], t[3][k]}));
    return std::max<std::int32_t>(1, static_cast<std::int32_t>(std::bit_floor(static_cast<std::uint32_t>(std::max(extent, 1)))));
  }
  // Everything beneath the diamond of grid vertex id on one side of the iso-value: so is any point
  // of its tetrahedra, whose value this sets to one on that side.
  bool one_sided(std::uint32_t id, double& value) const {
    const auto& span = h.value_span[id];
    if (!(span[1] < iso || span[0] >= iso)) return false;
    value = span[0] >= iso ? iso : -std::numeric_limits<double>::infinity();
    return true;
  }
  // The grid's interpolant at p in its leaf t.
  bool interpolate(const Tet& t, const Point& p, double& value) const {
    double vol[4], total = 0;  // barycentric coordinates of p, by volumes
    for (int k = 0; k < 4; ++k) {
      vol[k] = std::abs(orient(t[static_cast<std::size_t>((k + 1) % 4)], t[static_cast<std::size_t>((k + 2) % 4)],
                               t[static_cast<std::size_t>((k + 3) % 4)], p));
      total += vol[k];
    }
    if (!(total > 0)) return false;
    value = 0;
    for (int k = 0; k < 4; ++k) value += vol[k] / total * g.values[numbers.id(lat.index(t[static_cast<std::size_t>(k)]))];
    return true;
  }

  // The same answer cube by cube. Every third level of the hierarchy is the Kuhn tetrahedra of
  // the cubes of side 2h aligned to multiples of 2h (h = S/2, S/4, …, 1), a cube's six split
  // together at its centre (diamond.hpp). So at that level the tetrahedron holding p lies in the
  // cube of side 2h holding p, it is split in the grid exactly when that cube's centre is a grid
  // vertex, and the centre's span covers the whole cube: three levels for one lookup of the
  // vertex bitmap and one of the span, with no orientation test and no table (the level-by-level
  // descent took 9.9 steps a probe on the CT bunny at 2 voxels). From the cubes of side 2·h0 down
  // (h0 a power of two, at most S/2), while they lie inside the box; below the last split cube
  // the leaf is found by bisecting that cube's Kuhn tetrahedron holding p at its longest edge
  // (unique in this hierarchy). Returns false where it cannot tell (a cube across the box's far
  // faces, or the first cube not split): the caller descends level by level.
  enum class Cubes { answered, unsplit, across };
  // Cube by cube from the smallest cubes holding p up (half sides 1, 2, 4, … up to `top`), the
  // first split one descended (value_by_cubes): the grid is conforming, so every cube above a
  // split one is split too, and starting at the smallest one found split gives the answer that
  // starting higher gives. Near the surface the grid's leaves are small, so a probe mostly starts
  // at a cube of side 2 or 4: one lookup where coming down from the tested tetrahedron's scale
  // took 3.4 (the CT bunny at D = 2), and the collapses' probes, which came down level by level
  // from the last probe's tetrahedra, 12.3.
  Cubes value_from_below(const Point& p, double& value, std::int32_t top) const {
    for (std::int32_t half = 1;; half *= 2) {
      const Cubes c = value_by_cubes(p, value, half);
      if (c != Cubes::unsplit || half >= std::min(top, lat.S / 2)) return c;
    }
  }
  Cubes value_by_cubes(const Point& p, double& value, std::int32_t h0) const {
    std::int32_t last = 0;  // the side of the last split cube, 0 before the first
    Coord lo_last{};
    h0 = std::min(h0, lat.S / 2);  // larger "cubes" hold no diamond: the root cube's centre is S/2
    for (std::int32_t half = h0; half >= 1; half >>= 1) {
      const std::int32_t side = 2 * half;
      Coord lo, c;
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(static_cast<std::int32_t>(p[a] / side) * side, lat.S - side);
        if (lo[a] + side > lat.X[a]) return Cubes::across;  // spans of the part inside only
        c[a] = lo[a] + half;
      }
      const std::int64_t voxel = lat.index(c);
      if (!numbers.used(voxel)) {
        if (last == 0) return Cubes::unsplit;
        break;
      }
      if (one_sided(numbers.id(voxel), value)) return Cubes::answered;
      last = side, lo_last = lo;
      if (half == 1) break;
    }
    if (last == 0) return Cubes::across;  // no cube looked at (S = 1)
    // The Kuhn tetrahedron of the last split cube holding p: from the cube's corner at odd
    // multiples of its side along the diagonal, the axes in decreasing order of p's distance from
    // that corner.
    Coord from, to;
    double along[3];
    for (int a = 0; a < 3; ++a) {
      const bool odd = (lo_last[a] / last) & 1;
      from[a] = odd ? lo_last[a] : lo_last[a] + last;
      to[a] = odd ? lo_last[a] + last : lo_last[a];
      along[a] = std::abs(p[a] - from[a]);
    }
    int order[3] = {0, 1, 2};
    if (along[order[0]] < along[order[1]]) std::swap(order[0], order[1]);
    if (along[order[1]] < along[order[2]]) std::swap(order[1], order[2]);
    if (along[order[0]] < along[order[1]]) std::swap(order[0], order[1]);
    Tet t;
    t[0] = from;
    t[1] = from, t[1][order[0]] = to[order[0]];
    t[2] = t[1], t[2][order[1]] = to[order[1]];
    t[3] = to;
    for (;;) {
      int i = 0, j = 1;
      std::int64_t longest = -1;
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b) {
          std::int64_t l2 = 0;
          for (int k = 0; k < 3; ++k) l2 += std::int64_t{t[a][k] - t[b][k]} * (t[a][k] - t[b][k]);
          if (l2 > longest) longest = l2, i = a, j = b;
        }
      Coord m;
      bool unit = false;
      for (int k = 0; k < 3; ++k) {
        const std::int32_t sum = t[i][k] + t[j][k];
        unit |= (sum & 1) != 0;
        m[k] = sum / 2;
      }
      if (unit) break;
      const std::int64_t voxel = lat.index(m);
      if (!numbers.used(voxel)) break;
      if (one_sided(numbers.id(voxel), value)) return Cubes::answered;
      const auto& off = kCornersOff[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)];
      const Point ti{double(t[i][0]), double(t[i][1]), double(t[i][2])};
      const double sp = orient(m, t[off[0]], t[off[1]], p), si = orient(m, t[off[0]], t[off[1]], ti);
      t[static_cast<std::size_t>((sp >= 0) == (si >= 0) ? j : i)] = m;
    }
    return interpolate(t, p, value) ? Cubes::answered : Cubes::across;
  }
  // Is p (voxels) farther than the distance from the grid's surface? It is within it when the
  // grid's interpolant has opposite signs at p ± distance·normal (the surface crosses the segment
  // between them); otherwise it is taken as farther (a surface meeting the segment obliquely, or
  // twice, costs a needless split). Points off the box are not judged.
  // Tried and not kept: looking inside the segment when its ends agree (at quarters of the
  // distance, or at ± distance/2). A segment through a thin layer then finds its crossing, and the
  // 512×512×120 MR head at 2 and 4 voxels had 1.75× and 3.2× fewer triangles; but the splits
  // that "needless" test made are what brought the layer's other sheet into the mesh: on a crop
  // of that head the grid's surface moved farther from ours (p95 1.09 -> 2.34 voxels at 2, 0.49 ->
  // 1.14 at 0.5 with its spacing made cubic; ± distance/2 alone: 1.09 -> 1.55 for 0.86× the
  // triangles). The one-sided guarantee held; the surface lost what the user would look for.
  // Tried and not kept: judging an end inside the tested tetrahedron without a probe, from its
  // diamond's error bound (the grid's interpolant lies within it of the tetrahedron's). The bounds
  // of tetrahedra the refinement tests are too wide: on the CT bunny 0.2 % of the ends were
  // decided so, on the FLAIR brain 7 % at 0.5 voxels and under 0.1 % at 2.
  // Tried and not kept (2026-11-29): stopping a descent at the first level whose diamond's error
  // bound decides the side (|interpolant − iso| above it), not only when its span does. It would
  // have saved 3.6 % of the descents' steps on the CT bunny at iso 1600.5 and D = 2, 6.4 % at 0.5,
  // 2.8 % at iso 438 and 2 (counted, not timed): the bounds a level above the span's stop are wide.
  // Nor a bounding-box test before `holds` on the way up (5.6 ancestors a probe at iso 438, D = 2):
  // the same surfaces, no time saved (5 alternated pairs, within the noise).
  // Tried and not kept: the ends of a tetrahedron's probes descending together, a level a round,
  // each lookup prefetched a phase before it is read (2 to 16 descents at once). The descents are
  // 65–70 % of the refinement on the CT bunny and perf charges most of it to the value span's
  // load, yet the same decisions took the same time (D = 2: 0.11–0.17 s either way, alternated).
  // Nor (2026-11-29) each descent of a triangle's probes starting from the deepest tetrahedron of
  // the last one's that holds its point (ProbeTrail, as the collapses' probes do), then from the
  // tested tetrahedron's ancestors: the same decisions, refinement 0.105–0.110 s against
  // 0.071–0.076 at D = 2 and 0.195–0.200 against 0.137–0.143 at 0.5 (the bunny, 2 alternated
  // pairs). Not counted why; likely the climb: the other end of a probe lies two distances away,
  // and each tetrahedron tested on the way up costs four face tests. Nor the value spans the
  // descents read packed into 4 bytes (16 bits of the value range each, rounded outwards; 40 MB
  // instead of 79 on the bunny): the same decisions, the refinement within 3 % (2 alternated pairs).
  // Nor the span read at every second or third step only (one load fewer, deeper descents): the
  // same decisions, the same time or up to 10 % more. Nor (2026-11-29, twenty-sixth session) the
  // descents asking a per-query map instead: 2 bits a vertex (straddles, above; 2.5 MB on the
  // bunny, filled in 8.5 ms before the refinement) saved about what it cost to fill; a bit a voxel
  // (used and straddling, 12 MB, each 64 filled the first time a walk asks) made the refinement
  // 1.08x slower at D = 2 (3 alternated pairs). The loads perf charges are not the descents' cost.
  // Counted (2026-12-01, the bunny at iso 1600.5, D = 2): 279 k descents of 9.9 steps on average
  // for 114 k tests, 41 k of them probing; 80 % of the descents stop on a one-sided span, mostly
  // in tetrahedra 2–4 voxels across, 20 % reach a leaf; 95 % of the probing tests pass. Three tries,
  // each the same PLY bytes at D = 0.5 and 2 and no faster (3 alternated pairs against the
  // previous build): looking two levels down first and skipping the child's word and span when
  // the grandchild is split (D = 2 0.105–0.112 s against 0.091–0.105, D = 0.5 0.197–0.242 against
  // 0.196–0.204); the corners off the refinement edge from a table instead of two loops (within the
  // noise); the one-sided tetrahedra a test's descents stopped in, reused by its later probes whose
  // points lie strictly inside one (14 % of the descents so decided with a per-thread list of 8,
  // too few within one test: 0.098–0.110 s against 0.096–0.104 at D = 2). Fewer loads alone saved
  // nothing: their latency is overlapped (the next level's midpoint needs no load). Kept: the
  // refinement's probes descend cube by cube (value_by_cubes), a lookup pair per three levels
  // with no orientation test, the same decisions (the same PLY bytes on nine shared volumes, 2–3
  // iso-values each, D = 0.25 to 8, 0 and 2 rounds): on the bunny the refinement 0.059–0.067 s
  // against 0.082–0.091 at D = 2 and 0.135–0.148 against 0.151–0.178 at 0.5 (3 alternated pairs).
  // Since 2026-12-07 both the refinement's and the collapses' probes search from the smallest
  // cubes up (value_from_below): on the bunny at D = 2, 1.1 cube lookups a probe where coming down
  // from the tested tetrahedron took 3.4 (the refinement about a tenth faster: the upper lookups
  // mostly hit the cache), and where the collapses' probes came down level by level from the
  // last probe's path (12.3 steps after a climb of 9.7; coming down cube by cube from the top, or
  // from four times the last probe's finest cube, had taken as long), 1.1 lookups and one
  // tetrahedron's step: the collapses 1.5-1.6x faster.
  // Not built (2026-12-03): a bit per cube of side 2 whose 19 inner lattice points are all grid
  // vertices, so that a probe there interpolates in its finest tetrahedron with no descent.
  // Counted first: on the CT bunny at iso 1600.5, 3 of the first 600 k probe ends at D = 0.5 and
  // none of 200 k at 2 fell in such a cube. The grid beside its surface is coarser than that.
  // Nor (2026-12-03) value_by_cubes prefetching the bitmap words of its first four cube centres
  // before the first lookup (the centres depend on p alone): the same PLY bytes, the refinement
  // 0.152-0.168 s against 0.153-0.164 at D = 0.5 (3 alternated pairs), within the noise.
  template <class Hint>
  bool far_from_surface(const Point& pv, const Point& normal, Hint&& near) const {
    bool side[2];
    for (int s = 0; s < 2; ++s) {
      if (!side_at(pv, normal, s ? -distance : distance, side[s], near)) return false;
    }
    return side[0] == side[1];
  }
  // The collapses' test: the same, and where the ends agree, the grid's side at p and at p ±
  // distance/2 too: two crossings within the distance (a thin layer, a fold, a bump of noise)
  // put p within it as surely as one. The refinement does not look inside (above: its "needless"
  // splits are what bring a layer's other sheet into the mesh); a collapse only moves triangles
  // the refinement placed, and keeps the vertex it removes within the distance of the new ones.
  // Measured (2026-12-07, two rounds at D = 0.5): of the collapses' probes that failed on ends
  // alone, 65-73 % had such crossings on the MR head, the chest CT and the FLAIR brain, 2 % on the
  // CT bunny.
  bool far_from_surface_looking_inside(const Point& pv, const Point& normal) const {
    bool end[2];
    for (int s = 0; s < 2; ++s)
      if (!side_at(pv, normal, s ? -distance : distance, end[s], FromCubes{})) return false;
    if (end[0] != end[1]) return false;
    for (const double t : {0.0, distance / 2, -distance / 2}) {
      bool inside;
      if (side_at(pv, normal, t, inside, FromCubes{}) && inside != end[0]) return false;
    }
    return true;
  }
  // The grid's side of the iso-value at pv + t·normal (voxels), clamped to the box; false where
  // no leaf inside the box judges it.
  template <class Hint>
  bool side_at(const Point& pv, const Point& normal, double t, bool& side, Hint&& near) const {
    Point x;
    for (int a = 0; a < 3; ++a) x[a] = std::clamp((pv[a] + t * normal[a]) / unit[a], 0.0, double(lat.X[a]));
    double v;
    if (!value_at(x, v, near)) return false;
    side = above(v);
    return true;
  }
};

// ---- The refinement shared over processes (extract_within with a transport) ----
//
// The tetrahedra kDealtDepth levels below the roots are dealt out by a hash of their place, and
// each process refines its own whole, recording their marks, tests and whether the surface shows
// beneath them, not applying them. Above that depth every process refines alike, taking each dealt
// tetrahedron as showing the surface: the answers only decide which marks are kept and which half
// a look beneath searches next, so all processes meet the same dealt tetrahedra, all those one
// process meets and perhaps more. Process 0 then gathers the records and refines the top levels
// again with the owners' answers, taking the marks and tests of the dealt tetrahedra it meets:
// one process's marks, which close_upwards turns into one process's selection.
struct Subtree {
  std::uint64_t key = 0;  // dealt_key
  bool shows = false;
  std::uint64_t tested = 0;
  std::vector<std::int64_t> marks;  // as the refinement marks them, repeats included
};
struct Dealing {
  enum class Pass { deal, finish };
  Pass pass = Pass::deal;
  int process = 0, processes = 1;
  tbb::enumerable_thread_specific<std::deque<Subtree>> owned;  // deal: this process's, refined
  std::unordered_map<std::uint64_t, Subtree> all;              // finish: every process's, by key
};
// 6·2^12 tetrahedra at most (cubes of a sixteenth of the lattice's side), most outside the box or
// without a surface: enough to balance the processes, few enough that the levels above cost little.
constexpr int kDealtDepth = 12;
std::atomic<std::size_t> refinement_fallbacks{0};
// A tetrahedron's place: the sum of its corners (four times its centre), unique among the
// tetrahedra of one level, which do not overlap.
std::uint64_t dealt_key(const Tet& t, std::int32_t S) {
  const auto side = static_cast<std::uint64_t>(4) * static_cast<std::uint64_t>(S) + 1;
  std::uint64_t sum[3];
  for (int k = 0; k < 3; ++k) sum[k] = static_cast<std::uint64_t>(t[0][k] + t[1][k] + t[2][k] + t[3][k]);
  return sum[0] + side * (sum[1] + side * sum[2]);
}
int dealt_owner(std::uint64_t key, int processes) {
  std::uint64_t z = key + 0x9E3779B97F4A7C15ull;  // splitmix64: neighbours land on any process
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return static_cast<int>((z ^ (z >> 31)) % static_cast<std::uint64_t>(processes));
}

class Refine {
public:
  explicit Refine(const Query& q, Dealing* dealing = nullptr) : q_(q), dealing_(dealing) {}

  // Returns whether the surface shows in t or beneath it when t lies inside the box (the
  // refinement's roots and the tetrahedra across the box ignore it).
  bool tetrahedron(const Tet& t, OrderState o, int depth, Subtree* sub = nullptr) const {
    if (tet_outside(q_.lat, t) || q_.cancelled()) return false;  // cancelled: the caller throws
    if (dealt_here(depth, sub)) return dealt(dealt_key(t, q_.lat.S), [&](Subtree& s) { return tetrahedron(t, o, depth, &s); });
    Coord m;
    int i, j;
    if (!refinement(t, o, m, i, j)) return false;  // a unit tetrahedron
    if (tet_inside(q_.lat, t)) {
      std::uint32_t id;
      if (!worth_deciding(m, id)) return false;  // before the corners' lookups: most of the box's lining stops here
      Node n{t, o, {}, {}};
      n.sub = sub;
      for (int k = 0; k < 4; ++k) n.c[k] = q_.corner(t[static_cast<std::size_t>(k)]);
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b)
          if (q_.above(n.c[a].value) != q_.above(n.c[b].value)) n.cut[kEdgeOf[a][b]] = q_.cut(n.c[a], n.c[b]).p;
      return decide(n, m, i, j, id, depth);
    }
    // Across the box's far faces: split when the grid splits it, unless nothing beneath matters.
    if (q_.lat.in_box(m) ? !q_.numbers.used(q_.lat.index(m)) : !placement(classify(m, q_.lat.k), q_.lat).forced) return false;
    if (!q_.lining.may_cut(q_.lat, m, q_.iso)) return false;
    const auto split = halves(t, o, m, i, j);  // no structured binding: clang 14 cannot capture one
    both(
        depth, sub, [&] { tetrahedron(split[0].tet, split[0].order, depth + 1, sub); },
        [&] { tetrahedron(split[1].tet, split[1].order, depth + 1, sub); });
    return false;
  }

private:
  const Query& q_;
  Dealing* dealing_;  // null: this process refines alone
  static constexpr int kParallelDepth = 14;

  // A dealt subtree is refined by one thread (its record is its own), the levels above in parallel.
  template <class A, class B>
  static void both(int depth, const Subtree* sub, A&& a, B&& b) {
    if (depth < kParallelDepth && !sub)
      tbb::parallel_invoke(a, b);
    else
      a(), b();
  }

  bool dealt_here(int depth, const Subtree* sub) const { return dealing_ && depth == kDealtDepth && !sub; }
  // At the dealt tetrahedron `key`; `refine(record)` refines it whole into the record and says
  // whether the surface shows. Dealing: its owner refines it, and every process goes on as if it
  // showed the surface. Finishing: its owner's record, its marks and tests applied; refined here
  // if no process dealt it, which the deal pass's superset rules out (counted for the tests:
  // shared_refinement_fallbacks).
  template <class F>
  bool dealt(std::uint64_t key, F&& refine) const {
    if (dealing_->pass == Dealing::Pass::deal) {
      if (dealt_owner(key, dealing_->processes) == dealing_->process) {
        Subtree& s = dealing_->owned.local().emplace_back();
        s.key = key;
        s.shows = refine(s);
        std::sort(s.marks.begin(), s.marks.end());  // a diamond is marked once per tetrahedron of it
        s.marks.erase(std::unique(s.marks.begin(), s.marks.end()), s.marks.end());
      }
      return true;
    }
    const auto it = dealing_->all.find(key);
    Subtree local;
    if (it == dealing_->all.end()) {
      refinement_fallbacks.fetch_add(1, std::memory_order_relaxed);
      local.shows = refine(local);
    }
    const Subtree& s = it != dealing_->all.end() ? it->second : local;
    for (const std::int64_t v : s.marks)
      if (q_.split.mark(v)) q_.marked.local().push_back(v);
    q_.tested.local() += s.tested;
    return s.shows;
  }
  // Diamond m split: recorded in a dealt subtree while dealing, else marked (not at all in the
  // top levels while dealing: process 0 marks them when it finishes).
  void mark(const Coord& m, Subtree* sub) const {
    const std::int64_t v = q_.lat.index(m);
    if (sub)
      sub->marks.push_back(v);
    else if (top_levels_count() && q_.split.mark(v))
      q_.marked.local().push_back(v);
  }
  void count_test(Subtree* sub) const {
    if (sub)
      ++sub->tested;
    else if (top_levels_count())
      ++q_.tested.local();
  }
  // The levels above the dealt ones count (marks, tests) alone or when finishing, not while dealing.
  bool top_levels_count() const { return !dealing_ || dealing_->pass == Dealing::Pass::finish; }

  // Is the tetrahedron split in the grid, with a surface beneath?
  bool worth_deciding(const Coord& m, std::uint32_t& id) const {
    const std::int64_t voxel = q_.lat.index(m);
    if (!q_.numbers.used(voxel)) return false;  // a leaf of the grid
    id = q_.numbers.id(voxel);
    return q_.may_cut(id);
  }

  // Does the surface show in this tetrahedron or beneath it, as the refinement leaves it?
  bool node(const Node& n, int depth) const {
    if (dealt_here(depth, n.sub))
      return dealt(dealt_key(n.t, q_.lat.S), [&](Subtree& s) {
        Node own = n;
        own.sub = &s;
        return node(own, depth);
      });
    Coord m;
    int i, j;
    std::uint32_t id;
    if (refinement(n.t, n.order, m, i, j) && worth_deciding(m, id)) return decide(n, m, i, j, id, depth);
    return shows_surface(n);
  }
  bool shows_surface(const Node& n) const {
    const bool first = q_.above(n.c[0].value);
    return q_.above(n.c[1].value) != first || q_.above(n.c[2].value) != first || q_.above(n.c[3].value) != first;
  }

  // Splits the tetrahedron when a test says so, and its halves in turn. A split made only to look
  // for a surface hidden beneath (no corner shows one) is kept only when the halves' refinement
  // finds it; otherwise the part is one the distance leaves out, and marking the splits that
  // looked for it would only refine its neighbours for the closure. Returns whether the surface
  // shows in this tetrahedron or beneath it.
  bool decide(const Node& n, const Coord& m, int i, int j, std::uint32_t id, int depth) const {
    const Corner mid{m, id, q_.g.values[id]};
    // The other two corners, and the cut points the split adds on the edges from m to them.
    int others[2], n_others = 0;
    for (int k = 0; k < 4; ++k)
      if (k != i && k != j) others[n_others++] = k;
    Point added[2];
    bool cut[2];
    for (int s = 0; s < 2; ++s) {
      cut[s] = q_.above(mid.value) != q_.above(n.c[others[s]].value);
      if (cut[s]) added[s] = q_.cut(mid, n.c[others[s]]).p;
    }
    const bool shows = shows_surface(n);
    const double longest2 = this->longest2(n);
    const bool split = q_.forced(id) || q_.everything || splits(n, longest2, mid, i, j, added, cut);
    if (!split && !(shows && longest2 > q_.distance * q_.distance)) return shows;
    Node a = n, b = n;  // a: the midpoint in slot j; b: in slot i
    a.parent = b.parent = &n;
    place_halves(n, mid, i, j, a, b);
    for (int s = 0; s < 2; ++s) {
      if (!cut[s]) continue;
      a.cut[kEdgeOf[j][others[s]]] = added[s];
      b.cut[kEdgeOf[i][others[s]]] = added[s];
    }
    // The refinement edge's halves: its cut point stays in the half whose ends differ, unless the
    // edge was not cut and the midpoint differs from both ends (a surface hidden between).
    if (q_.above(n.c[i].value) == q_.above(n.c[j].value) && q_.above(mid.value) != q_.above(n.c[i].value)) {
      a.cut[kEdgeOf[i][j]] = q_.cut(n.c[i], mid).p;
      b.cut[kEdgeOf[i][j]] = q_.cut(mid, n.c[j]).p;
    }
    if (!split) return look_beneath(a, b, m, depth) || shows;
    bool found[2] = {false, false};
    both(
        depth, n.sub, [&] { found[0] = node(a, depth + 1); }, [&] { found[1] = node(b, depth + 1); });
    const bool keep = shows || found[0] || found[1];
    if (keep && !q_.forced(id)) mark(m, n.sub);
    return keep;
  }

  // A tetrahedron longer than the distance that shows the surface and passes the tests may still
  // hide other parts of it. Its half whose corners all lie on one side (at most one half's do) is
  // searched as a tetrahedron whose corners show nothing would be. When that finds nothing (or
  // both halves show the surface) and what the tetrahedron shows is a speck (triangles whose
  // edges are within the distance), its halves that show it are searched for a surface farther
  // than the distance from it (hides_far). The split is kept, and the halves refined in turn,
  // when a search finds a surface.
  // - Without the first search a coarse tetrahedron showing a speck at one corner hid everything
  //   else inside: on the padded lattice, whose far faces no longer force the top levels' splits,
  //   the chest CT at D = 2 lost its thin vessels across whole 128-voxel tetrahedra (p95 from the
  //   grid's surface 7.5 voxels; 1.34 so).
  // - Without the second, a speck at a corner both halves share hid them all the same:
  //   HeadMRVolume's ventricles at D = 2 (iso 150.5) lost pieces 8 voxels across inside a
  //   28-voxel tetrahedron (p95 from the grid's surface 7.07 voxels).
  // - The second search only for specks: searching every tetrahedron that shows a larger surface
  //   follows that surface down to the distance, 130 tetrahedra a search on the CT bunny at
  //   D = 2, and made the query 5x slower (0.12 -> 0.66 s) for 10 % more triangles; for specks
  //   it follows a small piece, the same time within the noise.
  bool look_beneath(const Node& a, const Node& b, const Coord& m, int depth) const {
    const bool a_hides = !shows_surface(a), b_hides = !shows_surface(b);
    const Node* hiding = a_hides ? &a : b_hides ? &b : nullptr;
    if (hiding && node(*hiding, depth + 1)) {
      node(hiding == &a ? b : a, depth + 1);
    } else {
      const Shown s = shown(*a.parent);
      if (!s.within(q_.distance)) return false;  // a larger surface: see above
      const bool more_in_a = !a_hides && hides_far(a, s), more_in_b = !more_in_a && !b_hides && hides_far(b, s);
      if (!more_in_a && !more_in_b) return false;
      if (!a_hides) node(a, depth + 1);
      if (!b_hides) node(b, depth + 1);
    }
    mark(m, a.sub);
    return true;
  }
  // A tetrahedron's triangles (one or two), through its edges' cut points.
  struct Shown {
    Point tri[2][3];
    int count = 0;
    bool within(double L) const {  // every edge within L
      for (int k = 0; k < count; ++k)
        if (std::max({distance2(tri[k][0], tri[k][1]), distance2(tri[k][1], tri[k][2]), distance2(tri[k][2], tri[k][0])}) > L * L)
          return false;
      return true;
    }
  };
  Shown shown(const Node& n) const {
    Shown s;
    const Case& cs = kCases[code_of(n)];
    s.count = cs.triangles;
    for (int k = 0; k < cs.triangles; ++k)
      for (int v = 0; v < 3; ++v) s.tri[k][v] = n.cut[kEdgeOf[cs.tri[k][v].below][cs.tri[k][v].above]];
    return s;
  }
  std::uint8_t code_of(const Node& n) const {
    return static_cast<std::uint8_t>(q_.above(n.c[0].value) | (q_.above(n.c[1].value) << 1) | (q_.above(n.c[2].value) << 2) |
                                     (q_.above(n.c[3].value) << 3));
  }
  bool near_shown(const Point& p, const Shown& s) const {
    for (int k = 0; k < s.count; ++k)
      if (distance2_to_triangle(p, s.tri[k][0], s.tri[k][1], s.tri[k][2]) <= q_.distance * q_.distance) return true;
    return false;
  }
  // Does n hide a part of the surface farther than the distance from s (the triangles of the
  // tetrahedron being tested, n inside it) that the refinement would find: a cut point of a
  // tetrahedron beneath n longer than the distance, or of its halves? Reads the grid only: no marks,
  // no probes. Pruned where nothing beneath can be that far: a diamond with nothing beneath (its
  // span), or a tetrahedron within the distance of one of s's triangles (its corners are: the
  // distance to a triangle is convex).
  bool hides_far(const Node& n, const Shown& s) const {
    if (longest2(n) <= q_.distance * q_.distance || within_shown(n, s)) return false;
    Node h[2];
    int i, j;
    if (!halves_of(n, h[0], h[1], i, j)) return false;
    return shows_far(h[0], j, s) || shows_far(h[1], i, s) || hides_far(h[0], s) || hides_far(h[1], s);
  }
  bool within_shown(const Node& n, const Shown& s) const {
    const double d2 = q_.distance * q_.distance;
    for (int k = 0; k < s.count; ++k) {
      bool all = true;
      for (int c = 0; c < 4 && all; ++c) {
        const Point p{n.t[c][0] * q_.unit[0], n.t[c][1] * q_.unit[1], n.t[c][2] * q_.unit[2]};
        all = distance2_to_triangle(p, s.tri[k][0], s.tri[k][1], s.tri[k][2]) <= d2;
      }
      if (all) return true;
    }
    return false;
  }
  // A cut point on an edge from n's corner `mid` (the split's midpoint; its other edges' cut
  // points are its parent's, already looked at) farther than the distance from s.
  bool shows_far(const Node& n, int mid, const Shown& s) const {
    for (int k = 0; k < 4; ++k)
      if (k != mid && q_.above(n.c[k].value) != q_.above(n.c[mid].value) && !near_shown(q_.cut(n.c[mid], n.c[k]).p, s)) return true;
    return false;
  }
  // n's halves, corners only, when the grid splits n with a surface beneath.
  bool halves_of(const Node& n, Node& a, Node& b, int& i, int& j) const {
    Coord m;
    std::uint32_t id;
    if (!tet_inside(q_.lat, n.t) || !refinement(n.t, n.order, m, i, j) || !worth_deciding(m, id)) return false;
    place_halves(n, {m, id, q_.g.values[id]}, i, j, a, b);
    return true;
  }
  // The halves' tetrahedra, orders and corners (a: the midpoint in slot j; b: in slot i), the rest
  // of a and b left as they are.
  static void place_halves(const Node& n, const Corner& mid, int i, int j, Node& a, Node& b) {
    const auto h = halves(n.t, n.order, mid.at, i, j);
    a.t = h[0].tet, a.order = h[0].order, b.t = h[1].tet, b.order = h[1].order;
    for (int k = 0; k < 4; ++k) a.c[k] = b.c[k] = n.c[k];
    a.c[j] = b.c[i] = mid;
  }

  double longest2(const Node& n) const {
    double longest = 0;
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) {
        double d2 = 0;
        for (int k = 0; k < 3; ++k) d2 += std::pow((n.t[a][k] - n.t[b][k]) * q_.unit[k], 2);
        longest = std::max(longest, d2);
      }
    return longest;
  }

  // The tests of the top of this file.
  // longest2: the squared length of the tetrahedron's longest edge.
  bool splits(const Node& n, double longest2, const Corner& mid, int i, int j, const Point added[2], const bool cut[2]) const {
    count_test(n.sub);
    const std::uint8_t code = code_of(n);
    const double d2 = q_.distance * q_.distance;
    if (code == 0 || code == 15) return longest2 > d2;  // hidden beneath
    // Every point of a triangle with edges up to L lies within L/√3 of a corner: of a cut point.
    if (longest2 <= 3 * d2) return false;
    const bool mid_above = q_.above(mid.value);
    if (mid_above != q_.above(n.c[i].value) && mid_above != q_.above(n.c[j].value))
      return true;  // hidden between (longer than √3·distance)
    if (sheets_between(n, i, j, 4 * d2)) return true;
    const Shown s = shown(n);
    for (int a = 0; a < 2; ++a)
      if (cut[a] && !near_shown(added[a], s)) return true;
    for (int k = 0; k < s.count; ++k)
      if (triangle_far(s.tri[k][0], s.tri[k][1], s.tri[k][2], n)) return true;
    return false;
  }

  // Two sheets across another edge longer than 2·distance whose ends agree: the grid's value at
  // its midpoint lies on the other side. The tetrahedron's own surface then joins what the grid
  // keeps apart (nested spheres 7 voxels apart came out as one surface with handles at 1 voxel).
  // No probe needed: every edge of the hierarchy is some diamond's refinement edge, centred at its
  // midpoint; where the grid splits that diamond the midpoint is a grid vertex, and where it does
  // not the edge is one of the grid's, its interpolant linear, its midpoint on the ends' side.
  bool sheets_between(const Node& n, int i, int j, double longer2) const {
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) {
        if ((a == i && b == j) || (a == j && b == i)) continue;
        const bool end = q_.above(n.c[a].value);
        if (q_.above(n.c[b].value) != end) continue;
        double d2 = 0;
        Coord mid;
        bool lattice = true;
        for (int k = 0; k < 3; ++k) {
          d2 += std::pow((n.t[a][k] - n.t[b][k]) * q_.unit[k], 2);
          lattice &= (n.t[a][k] + n.t[b][k]) % 2 == 0;
          mid[k] = (n.t[a][k] + n.t[b][k]) / 2;
        }
        if (d2 <= longer2 || !lattice || !q_.lat.in_box(mid)) continue;
        const std::int64_t voxel = q_.lat.index(mid);
        if (q_.numbers.used(voxel) && q_.above(q_.g.values[q_.numbers.id(voxel)]) != end) return true;
      }
    return false;
  }

  bool triangle_far(const Point& a, const Point& b, const Point& c, const Node& near) const {
    Point centre, u, v;
    for (int k = 0; k < 3; ++k) centre[k] = (a[k] + b[k] + c[k]) / 3, u[k] = b[k] - a[k], v[k] = c[k] - a[k];
    Point nrm{u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
    const double len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
    if (!(len > 0)) return false;
    for (double& x : nrm) x /= len;
    if (q_.far_from_surface(centre, nrm, &near)) return true;
    // A triangle longer than 3·distance is probed at its corner quarters' centres too, (4a + b + c)
    // / 6, which lie up to a third of its longest edge from a corner (a cut point, on the grid's
    // surface). The centre alone let the grid's surface bulge away near a large triangle's corners:
    // on the padded lattice, whose far faces no longer force small tetrahedra across the volume,
    // the small MR head's surface lay up to 1.10 voxels (p95) from the query's at 0.5, 0.42 so.
    const double L2 = std::max({distance2(a, b), distance2(b, c), distance2(c, a)});
    if (L2 <= 9 * q_.distance * q_.distance) return false;
    const Point* p[3] = {&a, &b, &c};
    for (int s = 0; s < 3; ++s) {
      Point x;
      for (int k = 0; k < 3; ++k) x[k] = (4 * (*p[s])[k] + (*p[(s + 1) % 3])[k] + (*p[(s + 2) % 3])[k]) / 6;
      if (q_.far_from_surface(x, nrm, &near)) return true;
    }
    return false;
  }
};

// Every split diamond's parents split, up to the roots (or to diamonds the box forces, split in
// any case like their parents), so the leaves form a conforming mesh. Returns how many were added.
std::size_t close_upwards(const Query& q, std::vector<std::int64_t> pending) {
  std::size_t added = 0;
  for (std::size_t step = 0; !pending.empty(); ++step) {
    if ((step & 0xffff) == 0) q.throw_if_cancelled();
    const std::int64_t v = pending.back();
    pending.pop_back();
    const Coord c{static_cast<std::int32_t>(v % q.lat.nx), static_cast<std::int32_t>(v % q.lat.nxy / q.lat.nx),
                  static_cast<std::int32_t>(v / q.lat.nxy)};
    Coord up[4];
    const int n = parents(classify(c, q.lat.k), q.lat.S, up);
    for (int p = 0; p < n; ++p) {
      if (!q.lat.in_box(up[p]) || !classify(up[p], q.lat.k).valid) continue;  // across the box (forced), or a root corner
      const std::int64_t pv = q.lat.index(up[p]);
      if (!q.numbers.used(pv) || q.forced(q.numbers.id(pv))) continue;
      if (q.split.mark(pv)) {
        ++added;
        pending.push_back(pv);
      }
    }
  }
  return added;
}

// The final walk: split as the final selection says, pruned where nothing beneath straddles.
struct FinalRule {
  const Query& q;
  bool may_cut_across(const Coord& m) const { return q.lining.may_cut(q.lat, m, q.iso); }
  // Split in the final selection (after the closure): marked, or forced by the box. Only
  // diamonds the grid splits can be.
  bool split(std::int64_t voxel) const {
    if (!q.numbers.used(voxel)) return false;
    return q.everything || q.split.test(voxel) || q.forced(q.numbers.id(voxel));
  }
  Decision decide(std::int64_t voxel) const {
    if (!split(voxel)) return Decision::leaf;
    return q.may_cut(q.numbers.id(voxel)) ? Decision::descend : Decision::prune;
  }
};

// Per unit of the final walk: the triangles found, as their corners' cut edges.
struct Found {
  std::vector<std::uint64_t> keys;  // 3 per triangle
  std::size_t leaves = 0, visited = 0;
};

// A cut leaf of the final walk, marched: its triangles as their corners' cut edges.
void march_leaf(const Query& q, const Corners& c, Found& out) {
  ++out.visited;
  const double lo = std::min({c.value[0], c.value[1], c.value[2], c.value[3]});
  const double hi = std::max({c.value[0], c.value[1], c.value[2], c.value[3]});
  if (!(lo < q.iso && q.iso <= hi)) return;
  ++out.leaves;
  const auto code =
      static_cast<std::uint8_t>(q.above(c.value[0]) | (q.above(c.value[1]) << 1) | (q.above(c.value[2]) << 2) | (q.above(c.value[3]) << 3));
  const Case& cs = kCases[code];
  for (int k = 0; k < cs.triangles; ++k)
    for (int v = 0; v < 3; ++v) out.keys.push_back(edge_key(c.id[cs.tri[k][v].below], c.id[cs.tri[k][v].above]));
}

// Coarse cut edges to the grid's cut edges inside them, for the vertices' places.
class SnapRemap : public EdgeRemap {
public:
  explicit SnapRemap(const Query& q) : q_(q) {}
  std::uint64_t fine(std::uint64_t key) const override {
    const Cut c = q_.snap(corner(static_cast<std::uint32_t>(key >> 32)), corner(static_cast<std::uint32_t>(key)));
    return edge_key(c.below_id, c.above_id);
  }

private:
  const Query& q_;
  Corner corner(std::uint32_t v) const { return {q_.lattice_point(v), v, q_.g.values[v]}; }
};

// One unit's cut-edge keys numbered by first use into `map` (new edges appended to `order`), their
// numbers appended to `local`. The keys' home slots are scattered misses: each is fetched 16 keys
// before it is probed (on the CT bunny's noisy iso 438, 866 k triangles, the maps took 110-140 ms
// without).
void number_keys(const std::vector<std::uint64_t>& keys, EdgeMap& map, std::vector<std::uint64_t>& order,
                 std::vector<std::uint32_t>& local) {
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (i + 16 < keys.size()) map.prefetch(keys[i + 16]);
    local.push_back(map.find_or_add(keys[i], order));
  }
}

// The vertices of coarse cut edges `keys`, in their order: each snapped to the grid's cut edge
// inside it and placed where the grid's surface crosses that (positions and normals of `mesh`).
void place_vertices(const Query& q, std::vector<std::uint64_t> keys, const EdgeRemap& remap, Mesh& mesh) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, keys.size(), 1024), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) keys[i] = remap.fine(keys[i]);
  });
  interpolate_vertices(q.g, keys, q.iso, mesh);
}

// The mesh of triangles given as cut-edge keys, per unit in walk order: vertices numbered by
// first use (chunk-parallel, the same numbering as one thread's), placed on the grid's cut edges.
void assemble(const Query& q, std::vector<Found>& found, const EdgeRemap& remap, Mesh& mesh) {
  // As many chunks as threads: each chunk's edges are looked up in every earlier chunk's map.
  const std::size_t C =
      std::max<std::size_t>(1, std::min<std::size_t>(found.size(), static_cast<std::size_t>(tbb::this_task_arena::max_concurrency())));
  std::vector<MarchChunk> chunks(C);
  std::vector<std::size_t> first(C + 1, 0);
  for (std::size_t c = 0; c <= C; ++c) first[c] = found.size() * c / C;
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = chunks[c];
    std::size_t n = 0;
    for (std::size_t f = first[c]; f < first[c + 1]; ++f) n += found[f].keys.size();
    // Sized for the vertices, not the keys: a manifold surface has about a sixth as many (three
    // keys a triangle, half as many vertices as triangles; the map grows if there are more). Sized
    // for n / 2 it held a slot per key, 536 MB of fresh pages on the 512×512×120 MR head at 0.5
    // voxels (7.3 M triangles), whose faulting in was most of this phase: 1.4–1.9 s, 0.4–1.0 s so.
    ch.map = std::make_shared<EdgeMap>(n / 6 + 16, ch.slots);
    resize_for_overwrite(ch.local, n);  // faulted in at once (march_detail.hpp), then filled in order
    ch.local.clear();
    for (std::size_t f = first[c]; f < first[c + 1]; ++f) number_keys(found[f].keys, *ch.map, ch.order, ch.local);
  });
  q.throw_if_cancelled();  // between the phases: a cancelled query stops within a phase (0.2 s on 1.9 M triangles)
  std::vector<std::uint64_t> order;
  number_chunk_edges(chunks, order);
  std::vector<std::size_t> tri_at(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) tri_at[c + 1] = tri_at[c] + chunks[c].local.size() / 3;
  resize_for_overwrite(mesh.triangles, tri_at[C]);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    const auto& ch = chunks[c];
    for (std::size_t j = 0; j < ch.local.size() / 3; ++j)
      for (int k = 0; k < 3; ++k) mesh.triangles[tri_at[c] + j][k] = ch.global[ch.local[3 * j + k]];
  });
  q.throw_if_cancelled();
  place_vertices(q, std::move(order), remap, mesh);
}

// ---- The assembly shared over processes (extract_within with a transport) ----
//
// The final walk's units in contiguous chunks, kChunksPerProcess a process, chunk c walked and
// numbered by process c mod P: each numbers its chunks' cut edges by first use and places their
// vertices (the snap to the grid's cut edge and the interpolation, most of the assembly), and
// process 0 numbers the chunks' edges again in chunk order, one lookup per edge of a chunk instead
// of three per triangle. A chunk's edges in its own first-use order, taken chunk after chunk, give
// the first-use order of the whole walk: one process's numbering, with one process's places (a
// vertex's place depends on its edge alone). Several chunks a process, so that a surface lying in
// part of the box still keeps every process busy. Process 0 looks up only the edges that may lie
// in another unit too (`open`: both ends on one face of their unit's tetrahedron); any other edge
// is new wherever it comes, and takes the next number without a lookup.
constexpr std::size_t kChunksPerProcess = 4;

struct ChunkPlan {
  std::size_t units = 0, chunks = 1, processes = 1;
  std::size_t first(std::size_t c) const { return units * c / chunks; }
  // Process `p`'s units: those of the chunks it owns.
  std::vector<std::uint8_t> walked_by(std::size_t p) const {
    std::vector<std::uint8_t> mine(units, 0);
    for (std::size_t c = p; c < chunks; c += processes) std::fill(mine.begin() + first(c), mine.begin() + first(c + 1), 1);
    return mine;
  }
};

// A chunk numbered: its coarse cut edges by first use, each with its vertex's place; its triangles
// as indices into them.
struct NumberedChunk {
  std::vector<std::uint64_t> order;
  std::vector<std::uint8_t> open;    // per edge of order: 1 where another unit may hold it too
  std::vector<std::uint32_t> local;  // 3 per triangle
  std::vector<std::array<float, 3>> positions, normals;
  std::uint64_t counts[2] = {0, 0};  // leaves marched, tetrahedra visited
};

// Do lattice points a and b, corners of leaves inside t, both lie on one face of t? Only then can
// the edge between them belong to a leaf outside t: an edge whose ends lie on different faces, or
// one inside, crosses t's interior, which no other unit's leaves reach. Exact: integer orientations.
bool on_one_face(const Tet& t, const Coord& a, const Coord& b) {
  const auto on_plane = [](const Coord& p0, const Coord& p1, const Coord& p2, const Coord& x) {
    std::int64_t u[3], v[3], w[3];
    for (int k = 0; k < 3; ++k) u[k] = p1[k] - p0[k], v[k] = p2[k] - p0[k], w[k] = x[k] - p0[k];
    const std::int64_t n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
    return __int128{n[0]} * w[0] + __int128{n[1]} * w[1] + __int128{n[2]} * w[2] == 0;
  };
  for (int k = 0; k < 4; ++k) {
    const Coord &p0 = t[static_cast<std::size_t>((k + 1) % 4)], &p1 = t[static_cast<std::size_t>((k + 2) % 4)],
                &p2 = t[static_cast<std::size_t>((k + 3) % 4)];
    if (on_plane(p0, p1, p2, a) && on_plane(p0, p1, p2, b)) return true;  // in t and on the face's plane: on the face
  }
  return false;
}

NumberedChunk number_chunk(const Query& q, const std::vector<adaptiso::detail::Subtree>& units, std::vector<Found>& found, std::size_t lo,
                           std::size_t hi, const EdgeRemap& remap) {
  NumberedChunk out;
  std::size_t n = 0;
  for (std::size_t f = lo; f < hi; ++f) n += found[f].keys.size();
  std::vector<std::uint64_t> slots;
  EdgeMap map(n / 6 + 16, slots);  // sized for the vertices, as assemble's
  out.local.reserve(n);
  for (std::size_t f = lo; f < hi; ++f) {
    const std::size_t before = out.order.size();
    number_keys(found[f].keys, map, out.order, out.local);
    for (std::size_t j = before; j < out.order.size(); ++j) {
      const std::uint64_t key = out.order[j];
      out.open.push_back(on_one_face(units[f].tet, q.lattice_point(static_cast<std::uint32_t>(key >> 32)),
                                     q.lattice_point(static_cast<std::uint32_t>(key))));
    }
    out.counts[0] += found[f].leaves, out.counts[1] += found[f].visited;
    std::vector<std::uint64_t>().swap(found[f].keys);
  }
  Mesh placed;
  place_vertices(q, out.order, remap, placed);  // a copy: process 0 numbers the coarse keys again
  out.positions = std::move(placed.positions), out.normals = std::move(placed.normals);
  return out;
}

void send_chunk(ShareTransport& t, const NumberedChunk& c) {
  share::send_vector(t, std::vector<std::uint64_t>{c.counts[0], c.counts[1]});
  share::send_vector(t, c.order);
  share::send_vector(t, c.open);
  share::send_vector(t, c.local);
  share::send_vector(t, c.positions);
  share::send_vector(t, c.normals);
}

NumberedChunk receive_chunk(ShareTransport& t, int from) {
  NumberedChunk c;
  const auto counts = share::receive_vector<std::uint64_t>(t, from);
  c.order = share::receive_vector<std::uint64_t>(t, from);
  c.open = share::receive_vector<std::uint8_t>(t, from);
  c.local = share::receive_vector<std::uint32_t>(t, from);
  c.positions = share::receive_vector<std::array<float, 3>>(t, from);
  c.normals = share::receive_vector<std::array<float, 3>>(t, from);
  const bool broken = counts.size() != 2 || c.positions.size() != c.order.size() || c.normals.size() != c.order.size() ||
                      c.open.size() != c.order.size() || c.local.size() % 3 != 0 ||
                      std::any_of(c.local.begin(), c.local.end(), [&](std::uint32_t i) { return i >= c.order.size(); });
  if (broken) throw std::logic_error(fmt::format("process {} sent a broken record of its share of the assembly", from));
  c.counts[0] = counts[0], c.counts[1] = counts[1];
  return c;
}

// Every process: its chunks numbered and placed; process 0 receives the others' and returns the
// mesh of them all, in chunk order (the others an empty one), with the leaves marched and the
// tetrahedra visited.
Mesh assemble_shared(const Query& q, ShareTransport& t, const ChunkPlan& plan, const std::vector<adaptiso::detail::Subtree>& units,
                     std::vector<Found>& found, const EdgeRemap& remap, std::uint64_t counts[2]) {
  const auto me = static_cast<std::size_t>(t.process());
  std::vector<std::size_t> own;
  for (std::size_t c = me; c < plan.chunks; c += plan.processes) own.push_back(c);
  std::vector<NumberedChunk> numbered(plan.chunks);
  tbb::parallel_for(std::size_t{0}, own.size(), [&](std::size_t i) {
    const std::size_t c = own[i];
    numbered[c] = number_chunk(q, units, found, plan.first(c), plan.first(c + 1), remap);
  });
  Mesh mesh;
  if (me != 0) {
    for (const std::size_t c : own) send_chunk(t, numbered[c]);
    return mesh;
  }
  for (int p = 1; p < t.processes(); ++p)
    for (std::size_t c = static_cast<std::size_t>(p); c < plan.chunks; c += plan.processes) numbered[c] = receive_chunk(t, p);
  std::size_t edges = 0, open = 0, triangles = 0;
  for (const auto& c : numbered) {
    edges += c.order.size(), triangles += c.local.size() / 3;
    open += static_cast<std::size_t>(std::count(c.open.begin(), c.open.end(), std::uint8_t{1}));
  }
  // The map holds the open edges only, at most `open` keys: sized so that it never grows (below
  // 7/10 full), and no larger (its slots are fresh pages, faulted in at about 0.5 GB/s a thread
  // on this machine). Its numbers index `open_keys`; `open_global` gives theirs in the mesh.
  std::vector<std::uint64_t> slots, open_keys;
  std::vector<std::uint32_t> open_global, global;
  EdgeMap map(open * 5 / 7 + 1, slots);
  open_keys.reserve(open), open_global.reserve(open);
  resize_for_overwrite(mesh.positions, edges), resize_for_overwrite(mesh.normals, edges);
  resize_for_overwrite(mesh.triangles, triangles);
  std::size_t vertices = 0, tri = 0;
  const auto add_vertex = [&](const NumberedChunk& c, std::size_t j) {
    mesh.positions[vertices] = c.positions[j], mesh.normals[vertices] = c.normals[j];
    return static_cast<std::uint32_t>(vertices++);
  };
  for (auto& c : numbered) {
    global.resize(c.order.size());
    for (std::size_t j = 0; j < c.order.size(); ++j) {
      if (!c.open[j]) {
        global[j] = add_vertex(c, j);
        continue;
      }
      if (j + 16 < c.order.size() && c.open[j + 16]) map.prefetch(c.order[j + 16]);
      const std::size_t before = open_keys.size();
      const std::uint32_t m = map.find_or_add(c.order[j], open_keys);
      if (open_keys.size() > before) open_global.push_back(add_vertex(c, j));
      global[j] = open_global[m];
    }
    for (std::size_t k = 0; k < c.local.size(); k += 3)
      mesh.triangles[tri++] = {global[c.local[k]], global[c.local[k + 1]], global[c.local[k + 2]]};
    counts[0] += c.counts[0], counts[1] += c.counts[1];
    c = NumberedChunk{};
  }
  mesh.positions.resize(vertices), mesh.normals.resize(vertices);
  return mesh;
}

// ---- Edge collapses after the query ----
//
// Marching tetrahedra make 2–3× marching cubes' triangles per cut cell, and most of them are not
// needed to stay within the distance: in each round, an edge (v, u) of the surface is collapsed
// into u when the refinement's own tests pass on the result (every new triangle's centre within
// the distance of the grid's surface: within it of a corner or of v, else probed as the
// refinement probes, unless every point of the triangle lies within the distance of a corner; v
// and the vertices removed before that v holds within the distance of the new triangles, and
// those v's ring holds within the distance of their holders' stars as the collapse leaves them),
// no new triangle turns by more than 60°, and the link condition keeps the surface 2-manifold. A
// collapse whose probes failed is not chosen again while v's star stays (Collapser::failed_).
// Vertices on the surface's border (the box) stay. A
// round's collapses have disjoint stars (a collapse locks v's ring), so they are chosen in vertex
// order without the probes, the probes then run in parallel, and the chosen collapses whose probes
// pass are applied: the same surface for any thread count. The vertices that stay keep their order
// and their places (cut points of the grid's surface). A vertex of fewer than 4 triangles is not
// collapsed: the link condition would then need its ring's edges too (a closed tetrahedron would
// fold flat).
//
// Cost (CT bunny, 2 cores): the probes, 3.4 per collapse, each found from the smallest cubes up
// (Query::value_from_below: 1.1 cube lookups and one tetrahedron's step on average); then the
// rings and the choice. Counted (2026-12-03, the bunny at iso 1600.5, D = 0.5, 2 rounds): 96 % of
// the chosen collapses pass, and 87.5 % of the probes end in a grid leaf, not on a one-sided span
// (near the surface the spans straddle). A round's choice is serial for a mesh of one block (7-9
// ms a round there after 4 ms of rings built in parallel).
// Until 2026-12-07 each chunk's probes came down from the last probe's path (a trail of
// tetrahedra: a climb of 9.7 levels, then 9.7 down, the bunny at 0.5): the collapses took 1.5-1.6x
// as long (D = 0.5: 0.154 s against 0.103, D = 2: 0.072 against 0.044, medians of 6 alternated
// runs), and a probe on the box's far face was judged or not by where the last one had gone (the
// descent from the root does not judge it, nor now the collapses: the bunny at iso 800 is the
// one surface of 168 compared whose bytes changed).
// Tried and not kept (2026-12-03), for the trail: a per-chunk cache of the grid leaves the probes
// ended in, tested before the climb (0.6 % of the probes fell in a cached leaf keyed by voxel and
// Kuhn tetrahedron, 2.3 % in one of the last 64 leaves: the probes seldom share a leaf); the
// vertices collapsed in earlier rounds as more known points of the grid's surface (1.2 k of round
// 2's 45.8 k probes spared); a round's probes gathered and run in Morton order of their centres,
// so that the trail climbs less (the gathering and sorting cost more than the shorter climbs saved).
// Where a round's time goes (2026-12-07, timed inside, eight rounds at D = 0.5, 2 cores): on the
// FLAIR brain (934 k triangles → 214 k) the stars 5-21 ms a round, the rings 15-38, the rest of the
// choice 22-46, the verdicts 57-69 and applying 4-14; of the verdicts' CPU over the eight rounds
// the probes took 58 %, the ring's held vertices 31 % (none in the first round) and v's own 11 %.
// On the CT bunny (157 k → 40 k) the verdicts 15-30 ms a round, mostly probes, and the choice (one
// block, serial) 7-20 ms. Tried and not kept, both the same PLY bytes on nine shared grids: a shape
// that fails keeps_shape marked in failed_ like failed probes (it reads only v's star), the choice
// within the noise (the bunny 81-99 ms over eight rounds against 90-91, FLAIR 414-426 against
// 372-417); a witness per held vertex, the triangle of its holder's star it was last found near,
// taken as it is while that triangle stays (no distance computed): only 20 % of the ring's checks
// found theirs in the later rounds (most stars change every round), and the ring's check took as
// long. Nor a looser turn limit (75° or 90° instead of 60°): a few per cent either way (the bunny
// +1-2 % at 0.5 and 2, FLAIR and the stent +1-3 % at 0.5 and -3-6 % at 2), so the distance tests,
// not the shapes, set the floor.

struct Collapse {
  std::uint32_t v, u;
};

thread_local std::function<void(const std::vector<SeenCollapse>&)> collapse_observer;  // observe_collapse_rounds

// Vertex → triangles, and each vertex's ring (sorted) and whether it lies on the surface's border.
// Rebuilt each round in the same buffers; the rings only for the vertices asked (build_rings,
// ensure_ring): a surface made together chooses each block of vertices on one process.
struct Stars {
  static constexpr std::uint32_t kUnbuilt = ~std::uint32_t{0};
  std::vector<std::uint32_t> start, tris;       // CSR: vertex v's triangles
  std::vector<std::uint32_t> ring, ring_count;  // v's ring from start[v] + v (at most its triangles + 1); count kUnbuilt until built
  std::vector<std::uint8_t> border;

  // The triangles of every vertex; no ring yet.
  void build(const Mesh& mesh) {
    const std::size_t V = mesh.positions.size(), T = mesh.triangles.size();
    assign_big(start, V + 1, std::uint32_t{0});
    for (const auto& t : mesh.triangles)
      for (std::uint32_t v : t) ++start[v + 1];
    for (std::size_t v = 0; v < V; ++v) start[v + 1] += start[v];
    resize_big(tris, 3 * T);
    fill_.assign(start.begin(), start.end() - 1);
    for (std::uint32_t t = 0; t < T; ++t)
      for (std::uint32_t v : mesh.triangles[t]) tris[fill_[v]++] = t;
    resize_big(ring, 3 * T + V);
    assign_big(ring_count, V, kUnbuilt);
    resize_big(border, V);
  }
  // The rings of vertices [lo, hi), in parallel.
  void build_rings(const Mesh& mesh, std::uint32_t lo, std::uint32_t hi) {
    tbb::parallel_for(tbb::blocked_range<std::uint32_t>(lo, hi, 4096), [&](const auto& r) {
      for (std::uint32_t v = r.begin(); v < r.end(); ++v) build_ring(mesh, v);
    });
  }
  void ensure_ring(const Mesh& mesh, std::uint32_t v) {
    if (ring_count[v] == kUnbuilt) build_ring(mesh, v);
  }
  const std::uint32_t* ring_of(std::uint32_t v) const { return &ring[start[v] + v]; }

private:
  std::vector<std::uint32_t> fill_;

  // Each neighbour of an inner vertex appears in exactly two of its triangles. Stars of more than
  // 60 triangles count as border (never collapsed).
  void build_ring(const Mesh& mesh, std::uint32_t v) {
    const std::uint32_t n_tris = start[v + 1] - start[v];
    ring_count[v] = 0;
    border[v] = n_tris > 60;
    if (border[v] || (n_tris <= 8 && closed_fan(mesh, v, n_tris))) return;
    // The distinct neighbours with their counts (a linear search among half a dozen), then sorted:
    // half the entries to sort, and fewer mispredicted swaps, than sorting all a dozen first.
    std::uint32_t neighbour[120], count[120];
    std::uint32_t m = 0;
    for (std::uint32_t k = start[v]; k < start[v + 1]; ++k)
      for (std::uint32_t w : mesh.triangles[tris[k]]) {
        if (w == v) continue;
        std::uint32_t i = 0;
        while (i < m && neighbour[i] != w) ++i;
        if (i == m) neighbour[m] = w, count[m++] = 0;
        ++count[i];
      }
    for (std::uint32_t i = 0; i < m; ++i)
      if (count[i] != 2) border[v] = 1;
    for (std::uint32_t i = 1; i < m; ++i)  // insertion sort of half a dozen
      for (std::uint32_t j = i; j > 0 && neighbour[j - 1] > neighbour[j]; --j) std::swap(neighbour[j - 1], neighbour[j]);
    const std::uint32_t n = std::min(m, n_tris + 1);  // room for a border vertex's extra neighbour
    std::copy(neighbour, neighbour + n, &ring[start[v] + v]);
    ring_count[v] = n;
  }
  // The common case without a branch on the data: v's star of up to 8 triangles, each giving the
  // edge opposite v in the triangle's order (from, to). When the froms are distinct and the tos
  // are the same set, every neighbour lies in exactly two triangles: an inner vertex, whose ring is
  // the sorted froms (what build_ring's search finds). Otherwise false, and build_ring decides as
  // before. Most vertices have at most 8 triangles (87-92 % on the FLAIR brain, the PD brain and
  // the CT bunny); the search's mispredicted branches took half of build_ring's time.
  bool closed_fan(const Mesh& mesh, std::uint32_t v, std::uint32_t n_tris) {
    constexpr std::uint32_t kPad = ~std::uint32_t{0};
    std::array<std::uint32_t, 8> from, to;
    from.fill(kPad), to.fill(kPad);
    for (std::uint32_t k = 0; k < n_tris; ++k) {
      const auto& t = mesh.triangles[tris[start[v] + k]];
      const int at = t[1] == v ? 1 : t[2] == v ? 2 : 0;
      from[k] = t[(at + 1) % 3], to[k] = t[(at + 2) % 3];
    }
    sort8(from), sort8(to);
    bool inner = true;
    for (std::uint32_t i = 0; i < 8; ++i) inner &= from[i] == to[i];
    for (std::uint32_t i = 0; i + 1 < n_tris; ++i) inner &= from[i] < from[i + 1];
    if (!inner) return false;
    std::copy(from.begin(), from.begin() + n_tris, &ring[start[v] + v]);
    ring_count[v] = n_tris;
    return true;
  }
  // Green's 19-comparator network for 8 keys (checked on all 256 inputs of 0s and 1s), unrolled
  // with constant indices so that the keys stay in registers and each exchange is two cmovs.
  template <int I, int J>
  static void exchange(std::array<std::uint32_t, 8>& a) {
    const std::uint32_t x = a[I], y = a[J];
    const bool swap = y < x;
    a[I] = swap ? y : x, a[J] = swap ? x : y;
  }
  static void sort8(std::array<std::uint32_t, 8>& a) {
    exchange<0, 2>(a), exchange<1, 3>(a), exchange<4, 6>(a), exchange<5, 7>(a);
    exchange<0, 4>(a), exchange<1, 5>(a), exchange<2, 6>(a), exchange<3, 7>(a);
    exchange<0, 1>(a), exchange<2, 3>(a), exchange<4, 5>(a), exchange<6, 7>(a);
    exchange<2, 4>(a), exchange<3, 5>(a);
    exchange<1, 4>(a), exchange<3, 6>(a);
    exchange<1, 2>(a), exchange<3, 4>(a), exchange<5, 6>(a);
  }
};

class Collapser {
public:
  // With `share`, every process holds the same mesh and chooses the same collapses; each probes
  // its chunks of them (c ≡ process mod processes), and the verdicts are combined.
  // The mesh's positions are world coordinates (the volume's origin and direction applied); the
  // probes' frame is the grid's (index ⊙ spacing), so they are taken back through the direction's
  // inverse. Distances and angles are the same in both: the direction is a rotation, perhaps with
  // a reflection.
  Collapser(const Query& q, Mesh& mesh, double smallest, ShareTransport* share)
      : q_(q), mesh_(mesh), d2_(q.distance * q.distance), share_(share) {
    resize_big(at_, mesh.positions.size());
    assign_big(failed_, mesh.positions.size(), std::uint64_t{0});
    assign_big(waited_, mesh.positions.size(), std::uint64_t{0});
    assign_big(first_removed_, mesh.positions.size(), kNone);
    assign_big(last_removed_, mesh.positions.size(), kNone);
    assign_big(next_removed_, mesh.positions.size(), kNone);
    const GridSource& s = q.g.source;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, at_.size(), 16384), [&](const auto& r) {
      for (std::size_t v = r.begin(); v < r.end(); ++v) {
        const auto& w = mesh.positions[v];
        const Vec3 g = world_to_grid(s.origin, s.direction, {w[0], w[1], w[2]});
        for (int k = 0; k < 3; ++k) at_[v][k] = g[k] / smallest;
      }
    });
  }

  // One round; returns the collapses applied.
  std::size_t round() {
    q_.throw_if_cancelled();
    stars_.build(mesh_);
    const std::vector<Collapse> chosen = choose();  // checks the flag before it returns
    for (std::uint32_t v : waiting_) waited_[v] = 0;
    waiting_.clear();
    const Stars& s = stars_;
    const RoundChoice choice = round_choice(s, chosen);
    std::vector<std::uint8_t> pass(chosen.size(), kPassed);
    std::vector<std::uint32_t> depends(chosen.size(), 0);
    const std::size_t chunk = 256;
    const std::size_t P = share_ ? static_cast<std::size_t>(share_->processes()) : 1,
                      me = share_ ? static_cast<std::size_t>(share_->process()) : 0;
    tbb::parallel_for(std::size_t{0}, (chosen.size() + chunk - 1) / chunk, [&](std::size_t c) {
      if (q_.cancelled()) return;
      const std::size_t end = std::min(chosen.size(), (c + 1) * chunk);
      for (std::size_t i = c * chunk; i < end; ++i) pass[i] = c % P == me ? verdict(s, chosen[i], choice, depends[i]) : 0;
    });
    q_.throw_if_cancelled();  // before any collapse is applied: the probes of some were skipped
    if (P > 1) {
      share::combine_at_zero(*share_, std::span(pass), [](std::uint8_t& own, std::uint8_t theirs) { own |= theirs; });
      share::combine_at_zero(*share_, std::span(depends), [](std::uint32_t& own, std::uint32_t theirs) { own |= theirs; });
    }
    wait_for_the_next_round(pass, depends);
    if (collapse_observer) show_observer(s, chosen, pass);
    for (std::size_t i = 0; i < chosen.size(); ++i)
      if (pass[i] != kPassed) {
        stars_.ensure_ring(mesh_, chosen[i].v);  // another process's block: its ring is not built here
        const std::uint64_t bit = std::uint64_t{1} << ring_slot(s, chosen[i]);
        if (pass[i] == kFailed)
          failed_[chosen[i].v] |= bit;
        else
          waited_[chosen[i].v] |= bit, waiting_.push_back(chosen[i].v);
      }
    failed_probes_ += static_cast<std::size_t>(std::count_if(pass.begin(), pass.end(), [](std::uint8_t p) { return p != kPassed; }));
    probed_ += chosen.size();
    std::vector<std::uint8_t> dead(mesh_.triangles.size(), 0);
    std::size_t applied = 0;
    for (std::size_t i = 0; i < chosen.size(); ++i) {
      if (pass[i] != kPassed) continue;
      const auto [v, u] = chosen[i];
      for (std::uint32_t k = s.start[v]; k < s.start[v + 1]; ++k) {
        auto& t = mesh_.triangles[s.tris[k]];
        for (std::uint32_t w : t) failed_[w] = waited_[w] = 0;  // its star changes (v's ring, u, v)
        if (has(t, u))
          dead[s.tris[k]] = 1;
        else
          for (auto& w : t) w = w == v ? u : w;
      }
      hand_over(v, u);
      ++applied;
    }
    std::size_t o = 0;
    for (std::size_t t = 0; t < mesh_.triangles.size(); ++t)
      if (!dead[t]) mesh_.triangles[o++] = mesh_.triangles[t];
    mesh_.triangles.resize(o);
    return applied;
  }

  // The collapses chosen and probed, and those whose probes failed, over the rounds so far.
  std::size_t probed() const { return probed_; }
  std::size_t failed_probes() const { return failed_probes_; }

  // Drops the vertices no triangle uses any more, keeping the others' order.
  void compact() {
    std::vector<std::uint32_t> id(mesh_.positions.size(), 0);
    for (const auto& t : mesh_.triangles)
      for (std::uint32_t w : t) id[w] = 1;
    std::uint32_t n = 0;
    for (std::size_t v = 0; v < id.size(); ++v) {
      const bool used = id[v];
      id[v] = n;
      if (used) mesh_.positions[n] = mesh_.positions[v], mesh_.normals[n] = mesh_.normals[v], ++n;
    }
    mesh_.positions.resize(n), mesh_.normals.resize(n);
    for (auto& t : mesh_.triangles)
      for (auto& w : t) w = id[w];
  }

private:
  const Query& q_;
  Mesh& mesh_;
  double d2_;
  ShareTransport* share_;  // null: this process alone
  std::vector<Point> at_;  // grid frame, voxels of the smallest spacing
  Stars stars_;
  // The triangles a collapse makes: v's star without the two on the edge, v moved to u (a
  // collapsible star has at most 60 triangles), made once for the held vertices and the probes.
  struct Made {
    Point tri[60][3];
    std::array<std::uint32_t, 3> id[60];  // its vertices, v already u
    int count = 0;
  };
  // Per vertex, the collapses whose probes failed (bit i: into the i-th vertex of its ring, which
  // is sorted), while its star stays as it was: the probes read only the star's triangles and the
  // fixed positions, so they would fail again. Cleared when a collapse changes the star.
  std::vector<std::uint64_t> failed_;
  // The same for the collapses that failed what their ring holds or waited, for the next round
  // only (other collapses change what the ring holds): v tries its next neighbour instead of
  // the same one again (on the CT bunny 44 of the 50 pairs chosen again in a ninth round failed again).
  std::vector<std::uint64_t> waited_;
  std::vector<std::uint32_t> waiting_;  // the vertices with bits in waited_
  // The vertices removed so far, each held by a vertex that stays (a list per holder: first, last,
  // next): a removed vertex goes to u with those v held. Each was within the distance of the
  // triangles that replaced it; a later collapse of its holder must keep it so (probes_pass), or
  // rounds would carry the surface away from them: without it the CT bunny's surface at 0.5
  // voxels lay 0.51 voxels from the grid's at the 95th percentile after 16 rounds.
  static constexpr std::uint32_t kNone = ~std::uint32_t{0};
  std::vector<std::uint32_t> first_removed_, last_removed_, next_removed_;

  void hand_over(std::uint32_t v, std::uint32_t u) {
    // v, then what v held, appended to what u holds.
    next_removed_[v] = first_removed_[v];
    const std::uint32_t head = v, tail = last_removed_[v] == kNone ? v : last_removed_[v];
    if (first_removed_[u] == kNone)
      first_removed_[u] = head;
    else
      next_removed_[last_removed_[u]] = head;
    last_removed_[u] = tail;
    first_removed_[v] = last_removed_[v] = kNone;
  }
  // Every vertex v holds within the distance of the new triangles.
  bool keeps_removed(const Collapse& c, const Made& made) const {
    for (std::uint32_t w = first_removed_[c.v]; w != kNone; w = next_removed_[w]) {
      bool near = false;
      for (int k = 0; k < made.count && !near; ++k)
        near = distance2_to_triangle(at_[w], made.tri[k][0], made.tri[k][1], made.tri[k][2]) <= d2_;
      if (!near) return false;
    }
    return true;
  }
  // A collapse that passed relying on a triangle another collapse of the round changes waits when
  // that one passed too (the codes before any wait: the same on every process, in any order).
  static void wait_for_the_next_round(std::vector<std::uint8_t>& pass, const std::vector<std::uint32_t>& depends) {
    std::vector<std::uint8_t> waits(pass.size(), 0);
    for (std::size_t i = 0; i < pass.size(); ++i) waits[i] = pass[i] == kPassed && depends[i] != 0 && pass[depends[i] - 1] == kPassed;
    for (std::size_t i = 0; i < pass.size(); ++i)
      if (waits[i]) pass[i] = kRingHeld;
  }
  // A round's chosen collapses, and per triangle the one whose star holds it (the stars are
  // disjoint).
  struct RoundChoice {
    const std::vector<Collapse>& chosen;
    std::vector<std::uint32_t> touched;
  };
  RoundChoice round_choice(const Stars& s, const std::vector<Collapse>& chosen) const {
    RoundChoice r{chosen, std::vector<std::uint32_t>(mesh_.triangles.size(), kNone)};
    tbb::parallel_for(std::size_t{0}, chosen.size(), [&](std::size_t i) {
      for (std::uint32_t k = s.start[chosen[i].v]; k < s.start[chosen[i].v + 1]; ++k) r.touched[s.tris[k]] = static_cast<std::uint32_t>(i);
    });
    return r;
  }
  // What v's ring holds, within the distance of each holder's star as this collapse leaves it:
  // the collapse takes the triangles through v out of the ring's stars (and puts the new ones in),
  // so a vertex a neighbour holds may have been near only those. Within the distance of the
  // holder itself, a vertex is near its star. The round's collapses are probed at once, so a
  // triangle another collapse j of the round changes is a witness as it is only while j is not
  // applied: `depends` names that j (+1; 0: none), and the collapse waits for the next round if
  // j passes. One such j at most.
  bool keeps_ring_held(const Stars& s, const Collapse& c, const Made& made, const RoundChoice& round, std::uint32_t& depends) const {
    // From v's star, not Stars::ring_of: under a transport v's ring is built only on the process
    // that chose v's block, and building it here would race with the other probes.
    std::uint32_t ring[64];  // collapsible: at most 64
    int n = 0;
    for (std::uint32_t k = s.start[c.v]; k < s.start[c.v + 1]; ++k)
      for (std::uint32_t w : mesh_.triangles[s.tris[k]])
        if (w != c.v && std::find(ring, ring + n, w) == ring + n) ring[n++] = w;
    depends = 0;
    for (int r = 0; r < n; ++r) {
      const std::uint32_t h = ring[r];
      for (std::uint32_t w = first_removed_[h]; w != kNone; w = next_removed_[w]) {
        if (distance2(at_[w], at_[h]) <= d2_) continue;
        const std::uint32_t near = near_star_after(s, c, h, at_[w], made, round);
        if (near == kAlways) continue;
        if (near == kNone || (depends != 0 && depends != near + 1)) return false;
        depends = near + 1;
      }
    }
    return true;
  }
  // Whether p lies within the distance of h's star after c, whatever the round's other
  // collapses (kAlways): of a triangle c makes through h, of one of h's others that no collapse
  // changes, or, for another collapse j, of one of j's triangles through h both as it is and as j
  // would leave it (moved to j's u); else only while the j of a triangle it is near is not applied
  // (j), or not at all (kNone). When h is j's u, j's triangles through h all go, and the ones j
  // makes are not looked at: such a collapse waits more often than it must.
  static constexpr std::uint32_t kAlways = kNone - 1;
  std::uint32_t near_star_after(const Stars& s, const Collapse& c, std::uint32_t h, const Point& p, const Made& made,
                                const RoundChoice& round) const {
    for (int k = 0; k < made.count; ++k)
      if (has(made.id[k], h) && distance2_to_triangle(p, made.tri[k][0], made.tri[k][1], made.tri[k][2]) <= d2_) return kAlways;
    // The other collapses through h's star (a few), and whether p is near their triangles before and after.
    struct Other {
      std::uint32_t j;
      bool before, after;
    } other[64];
    int others = 0;
    for (std::uint32_t k = s.start[h]; k < s.start[h + 1]; ++k) {
      const auto& t = mesh_.triangles[s.tris[k]];
      if (has(t, c.v)) continue;
      const std::uint32_t j = round.touched[s.tris[k]];
      const bool near = distance2_to_triangle(p, at_[t[0]], at_[t[1]], at_[t[2]]) <= d2_;
      if (j == kNone) {
        if (near) return kAlways;
        continue;
      }
      int o = 0;
      while (o < others && other[o].j != j) ++o;
      if (o == others) {
        if (others == 64) continue;  // a vertex of valence over 128: the rest are no witnesses
        other[others++] = {j, false, false};
      }
      other[o].before = other[o].before || near;
      const Collapse& oc = round.chosen[j];
      if (!other[o].after && !has(t, oc.u)) {
        Point after[3];
        corners(moved(t, oc), after);
        other[o].after = distance2_to_triangle(p, after[0], after[1], after[2]) <= d2_;
      }
      if (other[o].before && other[o].after) return kAlways;
    }
    for (int o = 0; o < others; ++o)
      if (other[o].before) return other[o].j;
    return kNone;
  }
  std::size_t probed_ = 0, failed_probes_ = 0;

  void show_observer(const Stars& s, const std::vector<Collapse>& chosen, const std::vector<std::uint8_t>& pass) const {
    std::vector<SeenCollapse> seen(chosen.size());
    for (std::size_t i = 0; i < chosen.size(); ++i) {
      seen[i].v = chosen[i].v, seen[i].u = chosen[i].u, seen[i].passed = pass[i] == kPassed;
      seen[i].ring_held_failed = pass[i] == kRingHeld;
      for (std::uint32_t k = s.start[chosen[i].v]; k < s.start[chosen[i].v + 1]; ++k) {
        auto t = mesh_.triangles[s.tris[k]];
        std::rotate(t.begin(), std::min_element(t.begin(), t.end()), t.end());
        seen[i].star.push_back(t);
      }
      std::sort(seen[i].star.begin(), seen[i].star.end());
      const Made made = made_by(s, chosen[i]);
      for (int k = 0; k < made.count; ++k) seen[i].made.push_back({made.tri[k][0], made.tri[k][1], made.tri[k][2]});
      seen[i].held.push_back(at_[chosen[i].v]);
      for (std::uint32_t w = first_removed_[chosen[i].v]; w != kNone; w = next_removed_[w]) seen[i].held.push_back(at_[w]);
    }
    collapse_observer(seen);
  }

  static bool has(const std::array<std::uint32_t, 3>& t, std::uint32_t u) { return t[0] == u || t[1] == u || t[2] == u; }
  static double dot(const Point& x, const Point& y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; }
  static Point minus(const Point& x, const Point& y) { return {x[0] - y[0], x[1] - y[1], x[2] - y[2]}; }
  static Point cross(const Point& x, const Point& y) {
    return {x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]};
  }
  static Point normal(const Point& a, const Point& b, const Point& c) { return cross(minus(b, a), minus(c, a)); }

  // Triangle t with c's v moved to its u, and a triangle's corners.
  static std::array<std::uint32_t, 3> moved(std::array<std::uint32_t, 3> t, const Collapse& c) {
    for (auto& w : t) w = w == c.v ? c.u : w;
    return t;
  }
  void corners(const std::array<std::uint32_t, 3>& t, Point out[3]) const {
    for (int i = 0; i < 3; ++i) out[i] = at_[t[static_cast<std::size_t>(i)]];
  }
  Made made_by(const Stars& s, const Collapse& c) const {
    Made m;
    for (std::uint32_t k = s.start[c.v]; k < s.start[c.v + 1]; ++k) {
      const auto& t = mesh_.triangles[s.tris[k]];
      if (has(t, c.u)) continue;
      m.id[m.count] = moved(t, c);
      corners(m.id[m.count], m.tri[m.count]);
      ++m.count;
    }
    return m;
  }

  // The collapses of a round, without the probes: each vertex into the nearest neighbour that
  // passes, disjoint stars. In blocks of 2^18 vertex numbers, in parallel, each in vertex order,
  // where a vertex's ring lies inside its block (its locks are then the block's alone); the others
  // after, in vertex order. The blocks are fixed, so the choice is the same for any thread count,
  // and a surface of one block is chosen as in one pass. Vertices are numbered by first use in the
  // walk, so most rings lie inside one block: on the 512×512×120 MR head at 0.5 voxels (3.6 M
  // vertices) 2.2 % did not, the choice took 0.31-0.33 s a round instead of 0.54-0.64 in one pass,
  // for 0.01 % more triangles. Blocks of 8192 cost the CT bunny's 79 k vertices 1.4 % more
  // triangles (14 % of its rings across blocks) for 5 ms less.
  // With a transport, block b's rings are built and its collapses chosen by process b mod P alone
  // (rings and choice were a third of a round's time on the bunny's iso 800, one thread), which
  // sends process 0 its choice, its vertices across blocks and its locks (a block's choice locks
  // only its own vertices); process 0 chooses across the blocks (building the rings it needs) and
  // broadcasts the collapses: one process's choice.
  static constexpr std::uint32_t kBlock = 1u << 18;
  struct BlockChoice {
    std::vector<Collapse> chosen;
    std::vector<std::uint32_t> across;  // collapsible, unlocked, ring across the block's bounds
  };

  std::vector<Collapse> choose() {
    const auto V = static_cast<std::uint32_t>(at_.size());
    const auto blocks = static_cast<std::uint32_t>((std::uint64_t{V} + kBlock - 1) / kBlock);
    const std::uint32_t P = share_ ? static_cast<std::uint32_t>(share_->processes()) : 1,
                        me = share_ ? static_cast<std::uint32_t>(share_->process()) : 0;
    std::vector<std::uint32_t> own;
    for (std::uint32_t b = me; b < blocks; b += P) own.push_back(b);
    for (std::uint32_t b : own) stars_.build_rings(mesh_, block_begin(b), block_end(b));
    std::vector<std::uint8_t> locked(V, 0);
    std::vector<BlockChoice> part(blocks);
    tbb::parallel_for(std::size_t{0}, own.size(), [&](std::size_t i) {
      if (!q_.cancelled()) choose_in_block(own[i], locked, part[own[i]]);
    });
    q_.throw_if_cancelled();
    std::vector<Collapse> all;
    if (P > 1 && me != 0) {
      for (std::uint32_t b : own) {
        share::send_vector(*share_, part[b].chosen);
        share::send_vector(*share_, part[b].across);
        share::send_vector(*share_, std::vector<std::uint8_t>(locked.begin() + block_begin(b), locked.begin() + block_end(b)));
      }
      share::broadcast_vector(*share_, all);
      return all;
    }
    for (std::uint32_t p = 1; p < P; ++p)
      for (std::uint32_t b = p; b < blocks; b += P) receive_block(static_cast<int>(p), b, part[b], locked);
    std::vector<Collapse> across;
    for (const auto& bc : part)
      for (std::uint32_t v : bc.across)
        if (!locked[v]) {
          stars_.ensure_ring(mesh_, v);
          const std::uint32_t* rv = stars_.ring_of(v);
          for (std::uint32_t k = 0; k < stars_.ring_count[v]; ++k) stars_.ensure_ring(mesh_, rv[k]);
          choose_at(stars_, v, locked, across);
        }
    for (const auto& bc : part) all.insert(all.end(), bc.chosen.begin(), bc.chosen.end());
    all.insert(all.end(), across.begin(), across.end());
    if (P > 1) share::broadcast_vector(*share_, all);
    return all;
  }

  // In 64 bits: the last block of a mesh of nearly 2^32 vertices ends past 32 bits.
  std::uint32_t block_begin(std::uint32_t b) const { return static_cast<std::uint32_t>(std::uint64_t{b} * kBlock); }
  std::uint32_t block_end(std::uint32_t b) const {
    return static_cast<std::uint32_t>(std::min<std::uint64_t>(at_.size(), (std::uint64_t{b} + 1) * kBlock));
  }

  // Block b's collapses whose rings lie inside it, in vertex order, and its vertices whose do not.
  void choose_in_block(std::uint32_t b, std::vector<std::uint8_t>& locked, BlockChoice& out) const {
    const Stars& s = stars_;
    const std::uint32_t lo = block_begin(b), hi = block_end(b);
    for (std::uint32_t v = lo; v < hi; ++v) {
      if (locked[v] || !collapsible(s, v)) continue;
      const std::uint32_t* rv = s.ring_of(v);
      if (rv[0] < lo || rv[s.ring_count[v] - 1] >= hi)  // sorted
        out.across.push_back(v);
      else
        choose_at(s, v, locked, out.chosen);
    }
  }

  // Process `from`'s choice in block b, checked: its collapses and locks inside the block.
  void receive_block(int from, std::uint32_t b, BlockChoice& into, std::vector<std::uint8_t>& locked) const {
    const std::uint32_t lo = block_begin(b), hi = block_end(b);
    into.chosen = share::receive_vector<Collapse>(*share_, from);
    into.across = share::receive_vector<std::uint32_t>(*share_, from);
    const auto locks = share::receive_vector<std::uint8_t>(*share_, from);
    const auto inside = [&](std::uint32_t v) { return v >= lo && v < hi; };
    const bool broken =
        locks.size() != hi - lo ||
        std::any_of(into.chosen.begin(), into.chosen.end(), [&](const Collapse& c) { return !inside(c.v) || !inside(c.u); }) ||
        !std::all_of(into.across.begin(), into.across.end(), inside) || !std::is_sorted(into.across.begin(), into.across.end());
    if (broken) throw std::logic_error(fmt::format("process {} sent a broken record of its choice of collapses", from));
    std::copy(locks.begin(), locks.end(), locked.begin() + lo);
  }

  bool collapsible(const Stars& s, std::uint32_t v) const {
    const auto nv = s.ring_count[v];
    return !s.border[v] && nv >= 4 && nv <= 64;  // valence 3: the link condition would also need its edges
  }

  // The slot of c.u in c.v's ring (collapsible: at most 64).
  static int ring_slot(const Stars& s, const Collapse& c) {
    const std::uint32_t* rv = s.ring_of(c.v);
    return static_cast<int>(std::lower_bound(rv, rv + s.ring_count[c.v], c.u) - rv);
  }

  // v into its nearest neighbour that is not locked, did not fail its probes with v's star as it
  // is, and passes (links, keeps_shape), locking v's ring.
  void choose_at(const Stars& s, std::uint32_t v, std::vector<std::uint8_t>& locked, std::vector<Collapse>& out) const {
    struct Near {
      double d2;
      std::uint32_t u;
      int slot;
      bool operator<(const Near& o) const { return d2 < o.d2 || (d2 == o.d2 && u < o.u); }
    } order[64];
    const int nv = static_cast<int>(s.ring_count[v]);
    const std::uint32_t* rv = s.ring_of(v);
    const Point& pv = at_[v];
    for (int i = 0; i < nv; ++i) order[i] = {distance2(at_[rv[i]], pv), rv[i], i};
    std::sort(order, order + nv);
    for (int i = 0; i < nv; ++i) {
      const Collapse c{v, order[i].u};
      if (locked[c.u] || ((failed_[v] | waited_[v]) >> order[i].slot & 1) || !links(s, c) || !keeps_shape(s, c)) continue;
      out.push_back(c);
      locked[v] = locked[c.u] = 1;
      for (int k = 0; k < nv; ++k) locked[rv[k]] = 1;
      return;
    }
  }

  // The link condition: the rings of v and u share exactly the two vertices opposite the edge.
  static bool links(const Stars& s, const Collapse& c) {
    const std::uint32_t *rv = s.ring_of(c.v), *ru = s.ring_of(c.u);
    const std::uint32_t nv = s.ring_count[c.v], nu = s.ring_count[c.u];
    int common = 0;
    for (std::uint32_t i = 0, j = 0; i < nv && j < nu;) {
      if (rv[i] < ru[j])
        ++i;
      else if (ru[j] < rv[i])
        ++j;
      else
        ++common, ++i, ++j;
    }
    return common == 2;
  }

  // No new triangle degenerate or turned by more than 60°, and v within the distance of them.
  bool keeps_shape(const Stars& s, const Collapse& c) const {
    double best = std::numeric_limits<double>::infinity();
    for (std::uint32_t k = s.start[c.v]; k < s.start[c.v + 1]; ++k) {
      const auto& t = mesh_.triangles[s.tris[k]];
      if (has(t, c.u)) continue;
      Point b[3];
      corners(moved(t, c), b);
      const Point n0 = normal(at_[t[0]], at_[t[1]], at_[t[2]]), n1 = normal(b[0], b[1], b[2]);
      const double l0 = std::sqrt(dot(n0, n0)), l1 = std::sqrt(dot(n1, n1));
      if (!(l1 > 1e-12) || dot(n0, n1) < 0.5 * l0 * l1) return false;
      best = std::min(best, distance2_to_triangle(at_[c.v], b[0], b[1], b[2]));
    }
    return best <= d2_;
  }

  bool near_a_point(const Point& x, std::initializer_list<const Point*> points) const {
    for (const Point* p : points)
      if (distance2(x, *p) <= d2_) return true;
    return false;
  }

  // A collapse's verdict: passed, failed its own tests (which read only v's star, what v holds and
  // the fixed positions: not tried again while they stay), or failed what its ring holds (which
  // other collapses change: tried again). Codes ORed over processes (the others' 0).
  static constexpr std::uint8_t kFailed = 0, kPassed = 1, kRingHeld = 2;
  std::uint8_t verdict(const Stars& s, const Collapse& c, const RoundChoice& round, std::uint32_t& depends) const {
    const Made made = made_by(s, c);
    if (!keeps_removed(c, made) || !probes_pass(c, made)) return kFailed;
    return keeps_ring_held(s, c, made, round, depends) ? kPassed : kRingHeld;
  }

  // Every new triangle's centre within the distance of the grid's surface, as the refinement
  // tests its triangles: within it of a corner or of v (cut points), or probed.
  bool probes_pass(const Collapse& c, const Made& made) const {
    for (int k = 0; k < made.count; ++k) {
      const Point* b = made.tri[k];
      // A triangle whose corners (on the grid's surface) cover it is not probed, as in the refinement.
      if (corners_cover(b[0], b[1], b[2], d2_)) continue;
      const Point n = normal(b[0], b[1], b[2]);
      const double len = std::sqrt(dot(n, n));
      Point centre, unit;
      for (int i = 0; i < 3; ++i) centre[i] = (b[0][i] + b[1][i] + b[2][i]) / 3, unit[i] = n[i] / len;
      if (near_a_point(centre, {&b[0], &b[1], &b[2], &at_[c.v]})) continue;
      if (q_.far_from_surface_looking_inside(centre, unit)) return false;
    }
    return true;
  }
};

// Up to `rounds` rounds; a round that removes less than a sixteenth of the triangles is the last
// (the next would remove fewer still at about the same cost). Rounds mostly remove a fifth to a
// quarter (the 512×512×120 MR head at 0.5 voxels: 7.27 M → 5.76 M → 4.66 M, 1.5 s a round); the
// rule was set when its collapses probed the wrong frame and removed 1.7 %, then 0.8 %.
struct CollapseCounts {
  std::size_t collapsed = 0, rounds = 0, probed = 0, failed = 0;
};
CollapseCounts collapse_edges(const Query& q, Mesh& mesh, double smallest, int rounds, ShareTransport* share, const Progress& progress) {
  CollapseCounts n;
  if (rounds == 0) return n;
  Collapser c(q, mesh, smallest, share);
  report(progress, "collapse", 0);
  for (int r = 0; r < rounds; ++r) {
    const std::size_t before = mesh.triangles.size(), applied = c.round();
    n.collapsed += applied, ++n.rounds;
    report(progress, "collapse", double(r + 1) / rounds);
    if (32 * applied < before) break;  // 2·applied triangles removed, fewer than before / 16
  }
  report(progress, "collapse", 1);
  if (n.collapsed) c.compact();
  n.probed = c.probed(), n.failed = c.failed_probes();
  return n;
}

// A query for the test hooks (compare_probe_routes, collapse_test_says_far), which probe and
// never split: its tests and marks are never read.
struct ProbeOnlyQuery {
  std::unique_ptr<HierarchyIndex> index;
  Marks split{1};
  tbb::enumerable_thread_specific<std::vector<std::int64_t>> marked;
  tbb::enumerable_thread_specific<std::size_t> tested{0};
  Query q;
  ProbeOnlyQuery(const PreparedGrid& grid, double iso, double distance, const Point& unit)
      : index(make_hierarchy_index(grid)), q{index->lat, index->numbers, index->lining, grid.grid, *grid.hierarchy, iso,    distance,
                                             false,      unit,           split,         marked,    tested,          nullptr} {}
};

}  // namespace

std::size_t shared_refinement_fallbacks() { return refinement_fallbacks.load(); }

void observe_collapse_rounds(std::function<void(const std::vector<SeenCollapse>&)> observer) { collapse_observer = std::move(observer); }

ProbeRouteCounts compare_probe_routes(const PreparedGrid& grid, double iso, const std::vector<std::array<double, 3>>& points,
                                      const std::vector<std::int32_t>& from_halves) {
  const ProbeOnlyQuery probe(grid, iso, 1, {1, 1, 1});  // only the probes' fields matter: the distance is never read
  const Query& q = probe.q;
  ProbeRouteCounts n;
  for (const auto& p : points) {
    double level = 0;
    const bool judged = q.value_at(p, level);
    n.points += judged;
    for (const std::int32_t half : from_halves) {
      double cubes = 0;
      if (q.value_by_cubes(p, cubes, half) == Query::Cubes::answered) {
        ++n.by_cubes;
        n.disagreed += !judged || q.above(cubes) != q.above(level);  // off the grid one way, not the other
      }
      double below = 0;
      if (q.value_from_below(p, below, half) == Query::Cubes::answered) {
        ++n.from_below;
        n.disagreed += !judged || q.above(below) != q.above(level);
      }
    }
  }
  return n;
}

bool collapse_test_says_far(const PreparedGrid& grid, double iso, double distance, const std::array<double, 3>& centre,
                            const std::array<double, 3>& normal) {
  const auto& s = grid.grid.source.spacing;
  const double smallest = std::min({s[0], s[1], s[2]});
  const ProbeOnlyQuery probe(grid, iso, distance, {s[0] / smallest, s[1] / smallest, s[2] / smallest});
  return probe.q.far_from_surface_looking_inside(centre, normal);
}

}  // namespace detail

namespace detail {
namespace {

// Every process asks for the same valid surface of grids of the same shape, or all refuse before
// any share is made: a process whose arguments were refused (`bad`) or differ from process 0's
// with its own message, the others naming it (share::agree). Otherwise a process would throw alone
// and leave the others waiting, or their shares would be of different surfaces.
void agree_on_the_surface(ShareTransport& t, std::exception_ptr bad, double iso, double distance, double piece, int rounds,
                          std::size_t vertices, const Lattice& lat) {
  const std::array<std::uint64_t, 8> mine{std::bit_cast<std::uint64_t>(iso),
                                          std::bit_cast<std::uint64_t>(distance),
                                          std::bit_cast<std::uint64_t>(piece),
                                          static_cast<std::uint64_t>(rounds),
                                          vertices,
                                          static_cast<std::uint64_t>(lat.X[0]),
                                          static_cast<std::uint64_t>(lat.X[1]),
                                          static_cast<std::uint64_t>(lat.X[2])};
  auto zero = mine;
  if (share::differs_from_zero(t, zero) && !bad)
    bad = std::make_exception_ptr(InputError(fmt::format(
        "process {} asked for another surface than process 0 (iso {}, distance {}, pieces from {}, {} rounds of collapses, a grid of {} "
        "vertices on a {}x{}x{} lattice; process 0: iso {}, distance {}, pieces from {}, {} rounds, {} vertices, {}x{}x{}): every "
        "process must ask for the same surface of the same grid",
        t.process(), iso, distance, piece, rounds, vertices, mine[5], mine[6], mine[7], std::bit_cast<double>(zero[0]),
        std::bit_cast<double>(zero[1]), std::bit_cast<double>(zero[2]), zero[3], zero[4], zero[5], zero[6], zero[7])));
  share::agree(t, bad, "the surface made together");
}

// Process 0: every process's dealt subtrees, by key. The others: theirs sent to it, as words (key,
// shows, tests, marks' count, marks).
void gather_dealt(ShareTransport& t, Dealing& d) {
  if (t.process() != 0) {
    std::vector<std::uint64_t> words;
    for (const auto& part : d.owned)
      for (const Subtree& s : part) {
        words.insert(words.end(), {s.key, std::uint64_t{s.shows}, s.tested, s.marks.size()});
        for (const std::int64_t v : s.marks) words.push_back(static_cast<std::uint64_t>(v));
      }
    share::send_vector(t, words);
    return;
  }
  for (auto& part : d.owned)
    for (Subtree& s : part) d.all.emplace(s.key, std::move(s));
  for (int p = 1; p < t.processes(); ++p) {
    const auto words = share::receive_vector<std::uint64_t>(t, p);
    for (std::size_t i = 0; i < words.size();) {
      if (words.size() - i < 4 || words[i + 3] > words.size() - i - 4)
        throw std::logic_error(fmt::format("process {} sent a broken record of its share of the refinement", p));
      Subtree s;
      s.key = words[i], s.shows = words[i + 1] != 0, s.tested = words[i + 2];
      const std::uint64_t n = words[i + 3];
      s.marks.assign(words.begin() + static_cast<std::ptrdiff_t>(i + 4), words.begin() + static_cast<std::ptrdiff_t>(i + 4 + n));
      i += 4 + n;
      const std::uint64_t key = s.key;
      d.all.emplace(key, std::move(s));
    }
  }
}

}  // namespace
}  // namespace detail

Mesh HierarchyQuery::extract_within(double iso, double distance, DistanceQueryStats* stats, int collapse_rounds,
                                    const std::atomic<bool>* cancel, const Progress& progress, std::optional<double> min_piece) const {
  return within(iso, distance, stats, collapse_rounds, cancel, nullptr, progress, min_piece);
}

Mesh HierarchyQuery::extract_within(ShareTransport& share, double iso, double distance, DistanceQueryStats* stats, int collapse_rounds,
                                    std::optional<double> min_piece) const {
  return within(iso, distance, stats, collapse_rounds, nullptr, &share, {}, min_piece);
}

Mesh HierarchyQuery::within(double iso, double distance, DistanceQueryStats* stats, int collapse_rounds, const std::atomic<bool>* cancel,
                            ShareTransport* share, const Progress& progress, std::optional<double> min_piece) const {
  using namespace detail;
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  const TetGrid& g = grid_->grid;
  const BisectionHierarchy& h = *grid_->hierarchy;
  const Lattice& lat = index_->lat;
  std::exception_ptr bad;
  try {
    if (!std::isfinite(iso)) throw OptionError("iso", "must be a finite number");
    if (!(distance >= 0) || !std::isfinite(distance))
      throw OptionError("distance", fmt::format("must be a non-negative number of voxels, got {}", distance));
    if (collapse_rounds < 0 || collapse_rounds > kMaxCollapseRounds)
      throw OptionError("collapse", fmt::format("must be a number of rounds from 0 to {}, got {}", kMaxCollapseRounds, collapse_rounds));
    if (min_piece && (!(*min_piece >= 0) || !std::isfinite(*min_piece)))
      throw OptionError("min-piece", fmt::format("must be a non-negative number of voxels, got {}", *min_piece));
  } catch (const OptionError&) {
    bad = std::current_exception();
  }
  const bool shared = share && share->processes() > 1;
  const double piece = min_piece.value_or(distance);
  if (shared)
    agree_on_the_surface(*share, bad, iso, distance, piece, collapse_rounds, g.vertex_count(), lat);
  else if (bad)
    std::rethrow_exception(bad);
  const double smallest = std::min({g.source.spacing[0], g.source.spacing[1], g.source.spacing[2]});
  // The marks go back to the pool however the query ends.
  struct Lease {
    HierarchyIndex& index;
    std::unique_ptr<DistanceMarks> marks;
    ~Lease() { index.give_back(std::move(marks)); }
  } lease{*index_, index_->take_marks()};
  Marks& split = lease.marks->split;
  tbb::enumerable_thread_specific<std::vector<std::int64_t>> marked;
  tbb::enumerable_thread_specific<std::size_t> tested(0);
  const Query q{lat,
                index_->numbers,
                index_->lining,
                g,
                h,
                iso,
                distance,
                distance == 0,
                {g.source.spacing[0] / smallest, g.source.spacing[1] / smallest, g.source.spacing[2] / smallest},
                split,
                marked,
                tested,
                cancel};
  // Shared: every process refines its dealt subtrees, process 0 the top levels with their answers
  // (Dealing), and its marks reach every process.
  const std::size_t P = shared ? static_cast<std::size_t>(share->processes()) : 1,
                    me = shared ? static_cast<std::size_t>(share->process()) : 0;
  Dealing dealing;
  dealing.process = static_cast<int>(me), dealing.processes = static_cast<int>(P);
  const Refine refine(q, shared ? &dealing : nullptr);
  const auto roots = root_tetrahedra(lat.S);
  const auto refine_roots = [&] {
    tbb::parallel_for(0, 6, [&](int r) { refine.tetrahedron(roots[static_cast<std::size_t>(r)], root_order(r), 0); });
  };
  report(progress, "refine", 0);
  refine_roots();
  q.throw_if_cancelled();  // the marks go back cleared however the query ends (Lease)
  if (shared) {
    gather_dealt(*share, dealing);
    dealing.pass = Dealing::Pass::finish;
    if (me == 0) refine_roots();
  }
  std::vector<std::int64_t> pending;
  for (auto& part : marked) pending.insert(pending.end(), part.begin(), part.end());
  if (shared) {
    share::broadcast_vector(*share, pending);
    if (me != 0)
      for (const std::int64_t v : pending) split.mark(v);
  }
  const std::size_t refined = pending.size();
  const std::size_t closure = close_upwards(q, std::move(pending));
  const auto t1 = Clock::now();
  report(progress, "refine", 1);
  report(progress, "march", 0);

  const FinalRule rule{q};
  const Traversal<FinalRule> walk(lat, rule);
  const Frontier top = walk.frontier(10);
  std::vector<Found> found(top.roots.size());
  const ChunkPlan plan{top.roots.size(), shared ? kChunksPerProcess * P : 1, P};
  const std::vector<std::uint8_t> mine = plan.walked_by(me);
  tbb::parallel_for(std::size_t{0}, top.roots.size(), [&](std::size_t f) {
    if (q.cancelled() || !mine[f]) return;  // shared: each process walks the units of its chunks
    walk.visit(
        top.roots[f], index_->numbers, g.values,
        [&](const Tet&, const Corners& c, std::int64_t) {
          march_leaf(q, c, found[f]);
          return ValueSpan{};
        },
        [&](std::int64_t, std::uint32_t, const Tet&, const ValueSpan&) { ++found[f].visited; });
  });
  const auto t2 = Clock::now();
  q.throw_if_cancelled();
  Mesh mesh;
  std::uint64_t counts[3] = {0, top.roots.size() + top.splits.size(), tested.combine(std::plus<>())};  // marched, visited, tested
  const SnapRemap remap(q);
  if (shared) {
    mesh = assemble_shared(q, *share, plan, top.roots, found, remap, counts);
  } else {
    assemble(q, found, remap, mesh);
    for (const Found& f : found) counts[0] += f.leaves, counts[1] += f.visited;
  }
  Specks specks;
  if (me == 0) {
    // Clipped before the collapses: its cut points on the volume's far faces are border vertices,
    // which the collapses keep as they keep every border, so the surface still ends on the box.
    clip_to_volume_box(mesh, g.source);
    specks = drop_specks(mesh, g.source, piece);
  }
  std::vector<Found>().swap(found);  // the triangles' keys: not held through the collapses
  if (shared) {                      // process 0's surface and counts on every process, for the collapses
    share::broadcast_vector(*share, mesh.positions);
    share::broadcast_vector(*share, mesh.normals);
    share::broadcast_vector(*share, mesh.triangles);
    share->broadcast(std::as_writable_bytes(std::span(counts)));
    share->broadcast(std::as_writable_bytes(std::span(&specks, 1)));
  }
  const std::size_t marched = counts[0], visited = counts[1];
  report(progress, "march", 1);
  const auto t4 = Clock::now();
  const CollapseCounts collapses =
      distance > 0 ? collapse_edges(q, mesh, smallest, collapse_rounds, shared ? share : nullptr, progress) : CollapseCounts{};
  if (collapses.collapsed > 0) {  // the collapses shrink pieces' boxes (every process holds the same mesh)
    const Specks shrunk = drop_specks(mesh, g.source, piece);
    specks.pieces += shrunk.pieces, specks.triangles += shrunk.triangles;
  }
  if (stats) {
    stats->iso = iso;
    stats->distance = distance;
    stats->tetrahedra = marched;
    stats->visited = visited;
    stats->tested = counts[2];
    stats->refined = refined + closure;
    stats->closure = closure;
    stats->triangles = mesh.triangle_count();
    stats->vertices = mesh.vertex_count();
    stats->in_range = iso >= g.source.min && iso <= g.source.max;
    stats->min_piece = piece;
    stats->specks = specks.pieces;
    stats->speck_triangles = specks.triangles;
    stats->refine_seconds = std::chrono::duration<double>(t1 - t0).count();
    stats->walk_seconds = std::chrono::duration<double>(t2 - t1).count();
    stats->march_seconds = std::chrono::duration<double>(t4 - t2).count();  // the clip with the march
    stats->collapsed = collapses.collapsed;
    stats->collapse_rounds = collapses.rounds;
    stats->collapses_probed = collapses.probed;
    stats->collapses_failed = collapses.failed;
    stats->collapse_seconds = std::chrono::duration<double>(Clock::now() - t4).count();
  }
  return mesh;
}

}  // namespace adaptiso
