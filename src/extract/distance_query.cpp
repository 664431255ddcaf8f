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
// Refinement is decided per cube, as in an octree. The hierarchy's cube diamonds (a cube of side
// 2h, 6 tetrahedra around its diagonal) are split when their own test says so; a face diamond is
// split when both cubes beside it are, an edge diamond when the four cubes around it are. So the
// leaves are mostly whole cubes, contoured like marching cubes (Lorensen & Cline 1987) along their
// 12 axis edges, with loops assembled from each face's segments; marching tetrahedra, with their
// 7 edge directions per cube, remain for the tetrahedra between cubes of two sizes. On a cube face
// the two sides must agree: the face is cut as its two triangles are (its diagonal decides an
// ambiguous face), and the diagonal's cut point is kept where the other side is not a whole cube
// of the same size (its tetrahedra use it) and dropped where it is. About 2.5× fewer triangles
// than marching tetrahedra in the same cells.
//
// A cube's own test, at its marching-cubes surface with vertices on the grid's surface: split when
// the centre of one of its triangles lies farther than the distance from the grid's surface (the
// grid's interpolant has the same sign at both ends of the segment centre ± distance·normal), or,
// when no corner shows the surface but the values beneath straddle the iso-value, when its side
// exceeds 2·distance (smaller hidden parts are left out).
//
// Three passes:
// 1. Refine (parallel, top-down): the walk splits by the rules above, each cube's test computed
//    once (bitmaps over the voxels, zero pages until written).
// 2. Close: every split cube's coarser neighbours that its parents need are split too, up to the
//    roots (octree balance), so the mesh is conforming. A set: the same for any thread count.
// 3. Walk the final hierarchy (traversal.hpp), contour its whole cubes and march its other cut
//    leaves in walk order, each mesh vertex on the grid's cut edge inside the coarse edge
//    (march_detail.hpp: EdgeRemap); vertices numbered by first use, chunk-parallel.
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

using Point = std::array<double, 3>;

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

// A mesh vertex as the coarse edge it cuts (edge_key: below vertex << 32 | above vertex), with its
// place on the grid's surface (voxels) while refining.
struct CutPoint {
  std::uint64_t key;
  Point p;
};

// The cube of side 2h centred at c: corner k at c + h·(±1, ±1, ±1), bit a of k set for +.
Coord cube_corner(const Coord& c, std::int32_t h, int k) {
  return {c[0] + (k & 1 ? h : -h), c[1] + (k & 2 ? h : -h), c[2] + (k & 4 ? h : -h)};
}

// A face of a cube, its corners counter-clockwise seen from outside, the first on the cube's
// diagonal (so the face's diagonal, in the tetrahedra, runs from corner 0 to corner 2).
struct Face {
  int axis, side;  // outward normal: (2·side − 1)·e_axis
  std::array<int, 4> corner;
};
std::array<Face, 6> cube_faces(int diagonal_end_a, int diagonal_end_b) {
  std::array<Face, 6> faces{};
  int n = 0;
  for (int a = 0; a < 3; ++a)
    for (int side = 0; side < 2; ++side) {
      const int b = (a + 1) % 3, c = (a + 2) % 3;
      auto at = [&](int u, int v) { return (side << a) | (u << b) | (v << c); };
      // e_b × e_c = e_a: (0,0) → (1,0) → (1,1) → (0,1) is counter-clockwise seen from +a.
      std::array<int, 4> q = side ? std::array<int, 4>{at(0, 0), at(1, 0), at(1, 1), at(0, 1)}
                                  : std::array<int, 4>{at(0, 0), at(0, 1), at(1, 1), at(1, 0)};
      int r = 0;
      while (q[static_cast<std::size_t>(r)] != diagonal_end_a && q[static_cast<std::size_t>(r)] != diagonal_end_b) ++r;
      std::rotate(q.begin(), q.begin() + r, q.end());
      faces[static_cast<std::size_t>(n++)] = {a, side, q};
    }
  return faces;
}

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
  Marks& split;     // cubes split (their own test, or the closure)
  Marks& decided;   // cubes whose own test has run; its answer in `own`
  Marks& own;
  tbb::enumerable_thread_specific<std::vector<std::int64_t>>& marked;
  tbb::enumerable_thread_specific<std::size_t>& tested;

  bool above(double v) const { return v >= iso; }
  Corner corner(const Coord& c) const {
    const std::uint32_t id = numbers.id(lat.index(c));
    return {c, id, g.values[id]};
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

  // ---- the split of any diamond, from the cubes' ----

  // Split in the final selection (after the closure): cubes as marked (or forced by the box),
  // faces and edges when every parent is. Only diamonds the grid splits can be.
  bool final_split(const Coord& m) const {
    const Diamond d = classify(m, lat.k);
    if (!d.valid) return true;  // a root corner, above every diamond
    if (!lat.in_box(m)) return placement(d, lat).forced;
    const std::int64_t voxel = lat.index(m);
    if (!numbers.used(voxel)) return false;
    const std::uint32_t id = numbers.id(voxel);
    return forced(id) || everything || split.test(voxel);
  }
  template <class Split>
  bool parents_split(const Diamond& d, Split&& is_split) const {
    Coord up[4];
    const int n = parents(d, lat.S, up);
    for (int p = 0; p < n; ++p)
      if (!is_split(up[p])) return false;
    return true;
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
  // Is p inside t (positively oriented), faces included?
  static bool holds(const Tet& t, const Point& p) {
    return orient(t[1], t[2], t[3], p) >= 0 && orient(t[0], t[3], t[2], p) >= 0 && orient(t[0], t[1], t[3], p) >= 0 &&
           orient(t[0], t[2], t[1], p) >= 0;
  }
  // With `near`, a tetrahedron of the hierarchy (and its order) where the descent starts when it
  // holds p: a probe beside the tetrahedron being tested is mostly inside it.
  bool value_at(const Point& p, double& value, const Tet* near = nullptr, OrderState near_order = 0) const {
    Tet t;
    OrderState o;
    if (near && holds(*near, p))
      t = *near, o = near_order;
    else if (!root_holding(p, t, o))
      return false;
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
        const auto& span = h.value_span[id];
        if ((span[1] < iso || span[0] >= iso) && (!forced(id) || tet_inside(lat, t))) {
          value = span[0] >= iso ? iso : -std::numeric_limits<double>::infinity();
          return true;
        }
      } else if (!placement(classify(m, lat.k), lat).forced) {
        break;
      }
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
  // Is p (voxels) farther than the distance from the grid's surface? It is within it when the
  // grid's interpolant has opposite signs at p ± distance·normal (the surface crosses the segment
  // between them); otherwise it is taken as farther (a surface meeting the segment obliquely, or
  // twice, costs a needless split). Points off the box are not judged.
  bool far_from_surface(const Point& pv, const Point& normal, const Tet* near = nullptr, OrderState near_order = 0) const {
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
};

// The surface of a whole cube: loops of cut points from its faces' segments (see the top).
// `drop_diagonal` per face (in cube_faces order): the other side is a whole cube of the same size.
class CubeContour {
public:
  CubeContour(const Query& q, const Coord& centre, std::int32_t h) : q_(q) {
    const Diamond d = classify(centre, q.lat.k);
    const auto [p, r] = refinement_edge(d);
    int ends[2] = {0, 0};
    for (int k = 0; k < 8; ++k) {
      corner_[k] = q.corner(cube_corner(centre, h, k));
      if (corner_[k].at == p) ends[0] = k;
      if (corner_[k].at == r) ends[1] = k;
    }
    faces_ = cube_faces(ends[0], ends[1]);
  }
  bool shown() const {
    for (int k = 1; k < 8; ++k)
      if (q_.above(corner_[k].value) != q_.above(corner_[0].value)) return true;
    return false;
  }
  const std::array<Face, 6>& faces() const { return faces_; }
  const Corner& corner(int k) const { return corner_[k]; }

  // The loops, each counter-clockwise around the part of the cube's boundary above the iso-value
  // (seen from outside); `with_points` computes the cut points' places too.
  void loops(const std::array<bool, 6>& drop_diagonal, bool with_points, std::vector<std::vector<CutPoint>>& out) {
    segments_.clear();
    for (int f = 0; f < 6; ++f) face_segments(faces_[static_cast<std::size_t>(f)], drop_diagonal[static_cast<std::size_t>(f)], with_points);
    out.clear();
    std::vector<bool> used(segments_.size(), false);
    for (std::size_t s0 = 0; s0 < segments_.size(); ++s0) {
      if (used[s0]) continue;
      std::vector<CutPoint> loop;
      for (std::size_t s = s0; !used[s];) {
        used[s] = true;
        loop.push_back(segments_[s].from);
        const std::uint64_t next = segments_[s].to.key;
        std::size_t n = 0;
        while (n < segments_.size() && (used[n] || segments_[n].from.key != next)) ++n;
        if (n == segments_.size()) break;  // closed (the start is used)
        s = n;
      }
      out.push_back(std::move(loop));
    }
  }

private:
  struct Segment {
    CutPoint from, to;
  };
  const Query& q_;
  Corner corner_[8];
  std::array<Face, 6> faces_;
  std::vector<Segment> segments_;

  CutPoint cut(int a, int b, bool with_points) const {
    if (with_points) return q_.cut(corner_[a], corner_[b]);
    const bool a_above = q_.above(corner_[a].value);
    return {edge_key(a_above ? corner_[b].id : corner_[a].id, a_above ? corner_[a].id : corner_[b].id), {}};
  }
  // A face's segments: those of its two triangles (0, 1, 2) and (0, 2, 3), each from the cut of
  // the edge its counter-clockwise boundary crosses downwards to the one it crosses upwards (the
  // part above the iso-value on the left); joined at the diagonal's cut point when it is dropped.
  void face_segments(const Face& f, bool drop_diagonal, bool with_points) {
    const int c[4] = {f.corner[0], f.corner[1], f.corner[2], f.corner[3]};
    const int tris[2][3] = {{c[0], c[1], c[2]}, {c[0], c[2], c[3]}};
    Segment part[2];
    bool has[2] = {false, false};
    for (int t = 0; t < 2; ++t) {
      int down = -1, up = -1;
      for (int e = 0; e < 3; ++e) {
        const int a = tris[t][e], b = tris[t][(e + 1) % 3];
        const bool aa = q_.above(corner_[a].value), ba = q_.above(corner_[b].value);
        if (aa && !ba) down = e;
        if (!aa && ba) up = e;
      }
      if (down < 0) continue;
      has[t] = true;
      part[t] = {cut(tris[t][down], tris[t][(down + 1) % 3], with_points), cut(tris[t][up], tris[t][(up + 1) % 3], with_points)};
    }
    const bool diagonal_cut = q_.above(corner_[c[0]].value) != q_.above(corner_[c[2]].value);
    if (drop_diagonal && diagonal_cut && has[0] && has[1]) {
      // One triangle's segment ends at the diagonal's cut, the other's starts there.
      const int first = part[0].to.key == part[1].from.key ? 0 : 1;
      segments_.push_back({part[first].from, part[1 - first].to});
      return;
    }
    for (int t = 0; t < 2; ++t)
      if (has[t]) segments_.push_back(part[t]);
  }
};

// Splitting decisions during refinement: a cube's own test, memoized; faces and edges from their
// parents (their cubes' own tests, run on demand).
class Refine {
public:
  explicit Refine(const Query& q) : q_(q) {}

  void tetrahedron(const Tet& t, OrderState o, int depth) const {
    if (tet_outside(q_.lat, t)) return;
    Coord m;
    int i, j;
    if (!refinement(t, o, m, i, j)) return;  // a unit tetrahedron
    if (tet_inside(q_.lat, t)) {
      const std::int64_t voxel = q_.lat.index(m);
      if (!q_.numbers.used(voxel)) return;  // a leaf of the grid
      const std::uint32_t id = q_.numbers.id(voxel);
      if (!q_.may_cut(id)) return;  // no surface beneath
      if (!q_.forced(id) && !q_.everything) {
        const Diamond d = classify(m, q_.lat.k);
        if (!(d.kind == DiamondKind::cube ? cube_splits(d, voxel) : tetrahedron_splits(t, o, voxel))) return;
      }
    } else {
      // Across the box's far faces: split when the grid splits it, unless nothing beneath matters.
      if (q_.lat.in_box(m) ? !q_.numbers.used(q_.lat.index(m)) : !placement(classify(m, q_.lat.k), q_.lat).forced) return;
      if (!q_.lining.may_cut(q_.lat, m, q_.iso)) return;
    }
    const auto [a, b] = halves(t, o, m, i, j);
    if (depth < kParallelDepth)
      tbb::parallel_invoke([&] { tetrahedron(a.tet, a.order, depth + 1); }, [&] { tetrahedron(b.tet, b.order, depth + 1); });
    else
      tetrahedron(a.tet, a.order, depth + 1), tetrahedron(b.tet, b.order, depth + 1);
  }

private:
  const Query& q_;
  static constexpr int kParallelDepth = 14;

  bool cube_splits(const Diamond& d, std::int64_t voxel) const {
    if (q_.decided.test(voxel)) return q_.own.test(voxel);
    const bool s = own_test(d);
    if (s) {
      q_.own.mark(voxel);
      mark(voxel);
    }
    q_.decided.mark(voxel);  // after `own`: a reader that sees it decided sees the answer
    return s;
  }
  void mark(std::int64_t voxel) const {
    if (q_.split.mark(voxel)) q_.marked.local().push_back(voxel);
  }

  // A tetrahedron between cubes of two sizes, tested alone at its marching-tetrahedra surface.
  bool tetrahedron_splits(const Tet& t, OrderState order, std::int64_t voxel) const {
    ++q_.tested.local();
    Corner c[4];
    for (int k = 0; k < 4; ++k) c[k] = q_.corner(t[static_cast<std::size_t>(k)]);
    double longest = 0;
    for (int i = 0; i < 4; ++i)
      for (int j = i + 1; j < 4; ++j) {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) d2 += std::pow((t[i][a] - t[j][a]) * q_.unit[a], 2);
        longest = std::max(longest, std::sqrt(d2));
      }
    const auto code =
        static_cast<std::uint8_t>(q_.above(c[0].value) | (q_.above(c[1].value) << 1) | (q_.above(c[2].value) << 2) | (q_.above(c[3].value) << 3));
    bool split = false;
    if (code == 0 || code == 15) {
      split = longest > 2 * q_.distance;  // a surface hidden beneath
    } else if (longest > q_.distance) {
      const Case& cs = kCases[code];
      for (int k = 0; k < cs.triangles && !split; ++k) {
        Point x[3];
        for (int v = 0; v < 3; ++v) x[v] = q_.cut(c[cs.tri[k][v].below], c[cs.tri[k][v].above]).p;
        split = triangle_far(x[0], x[1], x[2], &t, order);
      }
    }
    if (split) mark(voxel);
    return split;
  }

  // The cube's own test (see the top).
  bool own_test(const Diamond& d) const {
    ++q_.tested.local();
    double side = 0;
    for (int a = 0; a < 3; ++a) side = std::max(side, 2.0 * d.h * q_.unit[a]);
    CubeContour cube(q_, d.c, d.h);
    if (!cube.shown()) return side > 2 * q_.distance;
    if (side * std::sqrt(3.0) <= q_.distance) return false;  // every point within the distance of a cut point
    thread_local std::vector<std::vector<CutPoint>> loops;
    cube.loops({true, true, true, true, true, true}, true, loops);
    for (const auto& loop : loops)
      for (std::size_t k = 1; k + 1 < loop.size(); ++k)
        if (triangle_far(loop[0].p, loop[k].p, loop[k + 1].p)) return true;
    return false;
  }

  bool triangle_far(const Point& a, const Point& b, const Point& c, const Tet* near = nullptr, OrderState near_order = 0) const {
    Point centre, u, v;
    for (int k = 0; k < 3; ++k) centre[k] = (a[k] + b[k] + c[k]) / 3, u[k] = b[k] - a[k], v[k] = c[k] - a[k];
    Point n{u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(len > 0)) return false;
    for (double& x : n) x /= len;
    return q_.far_from_surface(centre, n, near, near_order);
  }
};

// Every split diamond's parents split, up to the roots (or to diamonds the box forces, split in
// any case like their parents), so the leaves form a conforming mesh. Returns how many were added.
std::size_t close_upwards(const Query& q, std::vector<std::int64_t> pending) {
  std::size_t added = 0;
  while (!pending.empty()) {
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
  bool split(std::int64_t voxel) const { return q.final_split(coord(voxel)); }
  Decision decide(std::int64_t voxel) const {
    if (!split(voxel)) return Decision::leaf;
    return q.may_cut(q.numbers.id(voxel)) ? Decision::descend : Decision::prune;
  }
  Coord coord(std::int64_t v) const {
    return {static_cast<std::int32_t>(v % q.lat.nx), static_cast<std::int32_t>(v % q.lat.nxy / q.lat.nx),
            static_cast<std::int32_t>(v / q.lat.nxy)};
  }
};

// Per unit of the final walk: the triangles found, as their corners' cut edges.
struct Found {
  std::vector<std::uint64_t> keys;  // 3 per triangle
  std::size_t leaves = 0, cubes = 0, visited = 0;
};

// The leaves of the final walk, contoured: whole cubes once (from one of their 6 tetrahedra),
// other cut leaves by marching tetrahedra.
class Contour {
public:
  explicit Contour(const Query& q) : q_(q) {}

  void leaf(const Tet& t, const Corners& c, std::int64_t voxel, Found& out) const {
    ++out.visited;
    if (voxel >= 0 && !q_.everything) {  // distance 0: the grid's own surface, marching tetrahedra throughout
      const Coord m{static_cast<std::int32_t>(voxel % q_.lat.nx), static_cast<std::int32_t>(voxel % q_.lat.nxy / q_.lat.nx),
                    static_cast<std::int32_t>(voxel / q_.lat.nxy)};
      const Diamond d = classify(m, q_.lat.k);
      // A cube's tetrahedron: the cube is whole (its 6 tetrahedra leaves) when its parents are
      // split; otherwise coarser neighbours hold its diagonal too, and this one is marched alone.
      if (d.kind == DiamondKind::cube && q_.parents_split(d, [&](const Coord& p) { return q_.final_split(p); })) {
        if (canonical(t, d)) whole_cube(d, out);
        return;
      }
    }
    const double lo = std::min({c.value[0], c.value[1], c.value[2], c.value[3]});
    const double hi = std::max({c.value[0], c.value[1], c.value[2], c.value[3]});
    if (!(lo < q_.iso && q_.iso <= hi)) return;
    ++out.leaves;
    const auto code = static_cast<std::uint8_t>(q_.above(c.value[0]) | (q_.above(c.value[1]) << 1) | (q_.above(c.value[2]) << 2) |
                                                (q_.above(c.value[3]) << 3));
    const Case& cs = kCases[code];
    for (int k = 0; k < cs.triangles; ++k)
      for (int v = 0; v < 3; ++v) out.keys.push_back(edge_key(c.id[cs.tri[k][v].below], c.id[cs.tri[k][v].above]));
  }

private:
  const Query& q_;

  // Of a whole cube's 6 tetrahedra (around its diagonal pr, each with two of the other 6 corners,
  // neighbours on the hexagon they form), the first the surface cuts, in the order of their pairs'
  // smaller corner index, then larger: a cut tetrahedron is never in a pruned subtree, and which
  // one it is depends on the cube alone.
  bool canonical(const Tet& t, const Diamond& d) const {
    const auto [p, r] = refinement_edge(d);
    Corner ring[6];
    int n = 0;
    for (int k = 0; k < 8; ++k) {
      const Coord c = cube_corner(d.c, d.h, k);
      if (c != p && c != r) ring[n++] = q_.corner(c);
    }
    const bool p_above = q_.above(q_.corner(p).value), r_above = q_.above(q_.corner(r).value);
    std::int64_t best[2] = {-1, -1};
    for (int a = 0; a < 6; ++a)
      for (int b = a + 1; b < 6; ++b) {
        int differ = 0;
        for (int k = 0; k < 3; ++k) differ += ring[a].at[k] != ring[b].at[k];
        if (differ != 1) continue;  // not neighbours on the hexagon: no tetrahedron holds both
        const bool aa = q_.above(ring[a].value), ba = q_.above(ring[b].value);
        if (aa == ba && ba == p_above && p_above == r_above) continue;  // not cut
        std::int64_t key[2] = {q_.lat.index(ring[a].at), q_.lat.index(ring[b].at)};
        if (key[0] > key[1]) std::swap(key[0], key[1]);
        if (best[0] < 0 || key[0] < best[0] || (key[0] == best[0] && key[1] < best[1])) best[0] = key[0], best[1] = key[1];
      }
    int has = 0;
    for (const Coord& c : t) has += q_.lat.index(c) == best[0] || q_.lat.index(c) == best[1];
    return best[0] >= 0 && has == 2;
  }

  // Is the cube centred at c (side 2h) whole in the final mesh: its tetrahedra exist (its parents
  // split) and it is not split?
  bool whole(const Coord& c) const {
    if (!q_.lat.in_box(c)) return false;
    const Diamond d = classify(c, q_.lat.k);
    if (!d.valid || d.kind != DiamondKind::cube) return false;
    if (q_.final_split(c)) return false;
    return q_.parents_split(d, [&](const Coord& p) { return q_.final_split(p); });
  }

  void whole_cube(const Diamond& d, Found& out) const {
    CubeContour cube(q_, d.c, d.h);
    if (!cube.shown()) return;
    ++out.cubes;
    std::array<bool, 6> drop{};
    for (int f = 0; f < 6; ++f) {
      const Face& face = cube.faces()[static_cast<std::size_t>(f)];
      Coord next = d.c;
      next[face.axis] += (face.side ? 2 : -2) * d.h;
      drop[static_cast<std::size_t>(f)] = whole(next);
    }
    thread_local std::vector<std::vector<CutPoint>> loops;
    cube.loops(drop, false, loops);
    // Each loop runs counter-clockwise around the part above the iso-value: its fan, turned over,
    // faces the lower values, as the marching tetrahedra's triangles do.
    for (const auto& loop : loops)
      for (std::size_t k = 1; k + 1 < loop.size(); ++k) {
        out.keys.push_back(loop[0].key);
        out.keys.push_back(loop[k + 1].key);
        out.keys.push_back(loop[k].key);
      }
  }
};

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
  Corner corner(std::uint32_t v) const {
    const auto& p = q_.g.ijk[v];
    return {{static_cast<std::int32_t>(p[0]), static_cast<std::int32_t>(p[1]), static_cast<std::int32_t>(p[2])}, v, q_.g.values[v]};
  }
};

// The mesh of triangles given as cut-edge keys, per unit in walk order: vertices numbered by
// first use (chunk-parallel, the same numbering as one thread's), placed on the grid's cut edges.
void assemble(const TetGrid& g, std::vector<Found>& found, double iso, const EdgeRemap& remap, Mesh& mesh) {
  const std::size_t C = std::max<std::size_t>(1, std::min<std::size_t>(found.size(), 64));
  std::vector<MarchChunk> chunks(C);
  std::vector<std::size_t> first(C + 1, 0);
  for (std::size_t c = 0; c <= C; ++c) first[c] = found.size() * c / C;
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = chunks[c];
    std::size_t n = 0;
    for (std::size_t f = first[c]; f < first[c + 1]; ++f) n += found[f].keys.size();
    ch.map = std::make_shared<EdgeMap>(n / 2 + 16, ch.slots);
    ch.local.reserve(n);
    for (std::size_t f = first[c]; f < first[c + 1]; ++f)
      for (std::uint64_t key : found[f].keys) ch.local.push_back(ch.map->find_or_add(key, ch.order));
  });
  std::vector<std::uint64_t> order;
  number_chunk_edges(chunks, order);
  std::vector<std::size_t> tri_at(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) tri_at[c + 1] = tri_at[c] + chunks[c].local.size() / 3;
  mesh.triangles.resize(tri_at[C]);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    const auto& ch = chunks[c];
    for (std::size_t j = 0; j < ch.local.size() / 3; ++j)
      for (int k = 0; k < 3; ++k) mesh.triangles[tri_at[c] + j][k] = ch.global[ch.local[3 * j + k]];
  });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, order.size(), 1024), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) order[i] = remap.fine(order[i]);
  });
  interpolate_vertices(g, order, iso, mesh);
}

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
  // The marks go back to the pool however the query ends.
  struct Lease {
    HierarchyIndex& index;
    std::unique_ptr<DistanceMarks> marks;
    ~Lease() { index.give_back(std::move(marks)); }
  } lease{*index_, index_->take_marks()};
  Marks &split = lease.marks->split, &decided = lease.marks->decided, &own = lease.marks->own;
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
                decided,
                own,
                marked,
                tested};
  const Refine refine(q);
  const auto roots = root_tetrahedra(lat.S);
  tbb::parallel_for(0, 6, [&](int r) { refine.tetrahedron(roots[static_cast<std::size_t>(r)], root_order(r), 0); });
  std::vector<std::int64_t> pending;
  for (auto& part : marked) pending.insert(pending.end(), part.begin(), part.end());
  const std::size_t refined = pending.size();
  const std::size_t closure = close_upwards(q, std::move(pending));
  const auto t1 = Clock::now();

  const FinalRule rule{q};
  const Traversal<FinalRule> walk(lat, rule);
  const Frontier top = walk.frontier(10);
  std::vector<Found> found(top.roots.size());
  const Contour contour(q);
  tbb::parallel_for(std::size_t{0}, top.roots.size(), [&](std::size_t f) {
    walk.visit(
        top.roots[f], index_->numbers, g.values,
        [&](const Tet& t, const Corners& c, std::int64_t voxel) {
          contour.leaf(t, c, voxel, found[f]);
          return ValueSpan{};
        },
        [&](std::int64_t, std::uint32_t, const Tet&, const ValueSpan&) { ++found[f].visited; });
  });
  const auto t2 = Clock::now();
  Mesh mesh;
  const SnapRemap remap(q);
  assemble(g, found, iso, remap, mesh);
  if (stats) {
    stats->iso = iso;
    stats->distance = distance;
    stats->tetrahedra = 0;
    stats->cubes = 0;
    stats->visited = top.roots.size() + top.splits.size();
    for (const Found& f : found) stats->tetrahedra += f.leaves, stats->cubes += f.cubes, stats->visited += f.visited;
    stats->tested = tested.combine(std::plus<>());
    stats->refined = refined + closure;
    stats->closure = closure;
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
