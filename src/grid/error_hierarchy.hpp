// The error hierarchy of the longest-edge bisection grid, bottom-up over the scales (see
// bisection.hpp; the lattice geometry is in diamond.hpp). Internal to bisection_errors.cpp (the
// whole volume at once) and bisection_bricks.cpp (brick by brick, then a combine step).
//
// Bottom-up over the scales (h = 1, 2, 4, …; at each the edge midpoints, then the face centres,
// then the cube centres): per diamond a signed bound of value − interpolant over the voxels
// beneath it, from its children's bounds and its own δ, and a saturated one-byte code per voxel.
// The finest diamonds are evaluated on the fly from the voxels (storing them would cost 6 bytes
// per voxel); from the cube centres of scale 1 on, one scale's bounds are kept for the next.
//
// The hierarchy always lives on the whole volume's lattice (root cube, box, classification); a
// Window says which diamonds one run evaluates and where its arrays of values and codes start.
#pragma once
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/volume.hpp"
#include "grid/diamond.hpp"
#include "util/big_array.hpp"

namespace adaptiso::detail {

constexpr double kInf = std::numeric_limits<double>::infinity();

// value − interpolant lies in [lo, hi] over every voxel beneath a diamond, and g is the smallest
// gradient magnitude at a voxel beneath it where that error can be nonzero (not at the vertices:
// only at the centres of it and its descendants; +∞ when there is none). Computed in double;
// stored in float, rounded outwards (StoredBound), so the stored bound contains the computed one.
struct Bound {
  double lo = 0, hi = 0, g = kInf;
};
constexpr Bound kUnbounded{-kInf, kInf, 0};
constexpr Bound kEmpty{kInf, -kInf, kInf};  // the unit of unite

struct StoredBound {
  float lo = 0, hi = 0, g = std::numeric_limits<float>::infinity();
  StoredBound() = default;
  explicit StoredBound(Bound b) : lo(static_cast<float>(b.lo)), hi(static_cast<float>(b.hi)), g(static_cast<float>(b.g)) {
    if (lo > b.lo) lo = std::nextafter(lo, -std::numeric_limits<float>::infinity());
    if (hi < b.hi) hi = std::nextafter(hi, std::numeric_limits<float>::infinity());
    if (g > b.g) g = std::nextafter(g, 0.0f);
  }
  Bound get() const { return {lo, hi, g}; }
};

// The bound of a split tetrahedron from its halves': on each half, parent − half interpolant is δ
// times the midpoint's barycentric coordinate (0 … 1), so value − parent = (value − half) − δλ.
// The midpoint joins the voxels where the parent's error can be nonzero (gradient `at_centre`).
inline Bound widen(Bound halves, double delta, double at_centre) {
  return {halves.lo + std::min(0.0, -delta), halves.hi + std::max(0.0, -delta), std::min(halves.g, at_centre)};
}
inline Bound unite(Bound a, Bound b) { return {std::min(a.lo, b.lo), std::max(a.hi, b.hi), std::min(a.g, b.g)}; }
inline double magnitude(Bound b) { return std::max(-b.lo, b.hi); }

// The centres of one kind of diamond at one scale that lie in the box, as a dense 3D array: along
// axis a the coordinates base_a, base_a + 2h, … ≤ X_a.
struct Sublattice {
  Coord base{};
  std::int32_t step = 2;
  int shift = 1;  // log2(step)
  std::array<std::int64_t, 3> n{};
  std::size_t size() const { return static_cast<std::size_t>(n[0] * n[1] * n[2]); }
  // Within the box [lo, hi] (lo a multiple of 2h).
  Sublattice(const Coord& lo, const Coord& hi, DiamondKind kind, int axis, std::int32_t h)
      : step(2 * h), shift(std::countr_zero(static_cast<std::uint32_t>(2 * h))) {
    for (int a = 0; a < 3; ++a) {
      bool odd = kind == DiamondKind::cube || (kind == DiamondKind::face && a != axis) || (kind == DiamondKind::edge && a == axis);
      base[a] = lo[a] + (odd ? h : 0);
      n[a] = hi[a] >= base[a] ? (hi[a] - base[a]) / step + 1 : 0;
    }
  }
  Sublattice(const Lattice& lat, DiamondKind kind, int axis, std::int32_t h) : Sublattice(Coord{}, lat.X, kind, axis, h) {}
  std::size_t index(const Coord& c) const {
    return static_cast<std::size_t>((((c[2] - base[2]) >> shift) * n[1] + ((c[1] - base[1]) >> shift)) * n[0] +
                                    ((c[0] - base[0]) >> shift));
  }
  Coord at(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return {static_cast<std::int32_t>(base[0] + i * step), static_cast<std::int32_t>(base[1] + j * step),
            static_cast<std::int32_t>(base[2] + k * step)};
  }
};

// ErrorCodes::code in constant time (the hierarchy codes every voxel): a first guess from the
// binary exponent, corrected against a table of the codes' errors.
class CodeTable {
public:
  explicit CodeTable(const ErrorCodes& codes) : inverse_scale_(1 / codes.scale) {
    for (int c = 0; c < 255; ++c) error_[static_cast<std::size_t>(c)] = codes.error(static_cast<std::uint8_t>(c));
  }
  std::uint8_t code(double e) const {
    if (!(e > error_[0])) return 0;
    if (!(e <= error_[254])) return std::isfinite(e) ? 254 : ErrorCodes::kForced;
    // e / scale = y · 2^ex with y in [1, 2); 16·log2(y) ≈ 16·(y − 1), at most 1.4 codes low.
    const auto bits = std::bit_cast<std::uint64_t>(e * inverse_scale_);
    const int ex = static_cast<int>((bits >> 52) & 0x7ff) - 1023;
    const double y = std::bit_cast<double>((bits & ((std::uint64_t{1} << 52) - 1)) | (std::uint64_t{1023} << 52));
    int c = std::clamp(254 + 16 * ex + static_cast<int>(16 * (y - 1)), 1, 254);
    while (c < 254 && error_[static_cast<std::size_t>(c)] < e) ++c;
    while (c > 1 && error_[static_cast<std::size_t>(c - 1)] >= e) --c;
    return static_cast<std::uint8_t>(c);
  }

private:
  double inverse_scale_;
  std::array<double, 255> error_{};  // error_[c] for c = 0 … 254, ascending
};

// The 19 diamonds of a cube of side 2 around a scale-1 cube centre, as cells of the 3×3×3 block
// of voxels around it (cell = (x+1) + 3(y+1) + 9(z+1) for offsets −1 … 1): 12 edge midpoints (one
// zero offset, along that axis), 6 face centres (two zero offsets; normal along the other), the
// centre (cell 13). Each face's 4 children among the edges. A block owns (writes the code of) the
// diamonds at offsets 0 or +1 along every axis. A compile-time table, so the block's loops unroll
// into straight-line code over its 27 values.
struct FineBlock {
  struct Edge {
    int cell, axis;
    bool owned;
  };
  struct Face {
    int cell, normal, edges[4];
    bool owned;
  };
  Edge edges[12]{};
  Face faces[6]{};
};

constexpr int block_cell(int x, int y, int z) { return (x + 1) + 3 * (y + 1) + 9 * (z + 1); }

constexpr FineBlock make_fine_block() {
  FineBlock b{};
  int ne = 0, nf = 0;
  for (int z = -1; z <= 1; ++z)
    for (int y = -1; y <= 1; ++y)
      for (int x = -1; x <= 1; ++x) {
        const int zeros = (x == 0) + (y == 0) + (z == 0);
        const bool owned = x >= 0 && y >= 0 && z >= 0;
        if (zeros == 1) b.edges[ne++] = {block_cell(x, y, z), x == 0 ? 0 : y == 0 ? 1 : 2, owned};
        if (zeros == 2) b.faces[nf++] = {block_cell(x, y, z), x != 0 ? 0 : y != 0 ? 1 : 2, {0, 0, 0, 0}, owned};
      }
  // A face's children: the edges one step from its centre along its two in-face axes.
  for (auto& f : b.faces) {
    const int o[3] = {f.cell % 3 - 1, f.cell / 3 % 3 - 1, f.cell / 9 - 1};
    int k = 0;
    for (int a = 0; a < 3; ++a) {
      if (a == f.normal) continue;
      for (int sgn = -1; sgn <= 1; sgn += 2) {
        int e[3] = {o[0], o[1], o[2]};
        e[a] += sgn;
        for (int q = 0; q < 12; ++q)
          if (b.edges[q].cell == block_cell(e[0], e[1], e[2])) f.edges[k] = q;
        ++k;
      }
    }
  }
  return b;
}

inline constexpr FineBlock kFineBlock = make_fine_block();

// The displacement criterion, when asked for: per diamond the ratio of its error bound to the
// smallest gradient magnitude beneath it (floored at g0), in voxels, coded on a scale of its own.
constexpr double kDisplacementScale = kDisplacementCodeScale;  // voxels (bisection.hpp)
constexpr double kGradientFloor = 0.01;                        // of the value range per voxel (bisection.hpp)

struct Displacement {
  std::vector<std::uint8_t>* code = nullptr;  // per voxel, like the error codes
  ErrorCodes codes;
  double g0 = 0;  // data units per voxel
  double ratio(const Bound& b) const {
    const double e = magnitude(b);
    return e > 0 ? e / std::max(b.g, g0) : 0.0;
  }
};

// A volume's codes: its errors relative to the value range; its displacements, when asked for.
struct HierarchyCodes {
  ErrorCodes codes;
  Displacement displacement;
};
inline HierarchyCodes hierarchy_codes(const ValueRange& range, bool displacement) {
  HierarchyCodes h;
  const double spread = range.max > range.min ? range.max - range.min : 1.0;
  h.codes.scale = spread;
  h.codes.zero = error_tolerance(range, 0.0);
  if (displacement) {
    h.displacement.codes.scale = kDisplacementScale;
    h.displacement.codes.zero = 0;
    h.displacement.g0 = kGradientFloor * spread;
  }
  return h;
}

// The part of the global lattice one hierarchy works on: the diamonds centred in the box
// [lo, hi], and the arrays of values and codes (x fastest), which start at voxel `origin` and hold
// every voxel those diamonds read. The whole volume: lo = origin = 0, hi = X.
struct Window {
  Coord lo{}, hi{}, origin{};
  std::int64_t nx = 0, nxy = 0;  // strides of the arrays
  static Window whole(const Lattice& lat) { return {{}, lat.X, {}, lat.nx, lat.nxy}; }
  std::int64_t base() const { return origin[0] + nx * origin[1] + nxy * origin[2]; }
};

// The bricks of side B = 2^b (bisection_bricks.hpp): which diamonds a brick's hierarchy leaves to
// the combine step (the seam diamonds), and what it hands up for them.
struct Seams {
  std::int32_t B = 0;
  Coord X{};
  // A seam diamond: within its scale h of a brick face plane inside the box, a cube centre of
  // scale B/2 (what the coarse levels start from), or any coarser. Why that set, per axis a and
  // plane P (a multiple of B, 2h | B): a coordinate is an even multiple of h (0 or ≥ 2h from P) or
  // an odd one (h or ≥ 3h from P). Of the children, a cube centre's and a face centre's move one
  // coordinate by h, an edge midpoint's (scale h/2) every coordinate by h/2: from a diamond ≥ 2h
  // (even) or ≥ 3h (odd) from every plane they land ≥ 2h, ≥ 3h, or ≥ 3h/2 = 3·(h/2) from it, so
  // no seam diamond descends from one that is none, and all its voxels lie in one brick. Near a
  // plane the dependency is real: a cube centre h from P reads the complete bound of its face
  // child on P, whose tetrahedra lie on both sides. A seam diamond's children that are none are ≥
  // 2h (or 3h/2) from every plane and on its side of each, so they lie in the brick owning it.
  bool seam(const Diamond& d) const {
    if (d.h >= B || (2 * d.h == B && d.kind == DiamondKind::cube)) return true;
    return near(0, d.c[0], d.h) || near(1, d.c[1], d.h) || near(2, d.c[2], d.h);
  }
  // A coordinate x along axis a within h of a seam plane.
  bool near(int a, std::int32_t x, std::int32_t h) const {
    const std::int32_t below = x & (B - 1), plane = x - below;  // the plane at or below
    return (below <= h && plane > 0 && plane < X[a]) || (B - below <= h && plane + B < X[a]);
  }
  // Per seam diamond centred in the brick's owned voxels, in the order of their finding: its global
  // voxel, the union of its children's bounds the brick computes (the others are seam diamonds or
  // outside the box) and, where its own bound is evaluated (neither forced nor outside), its δ and
  // the gradient at its centre.
  struct Out {
    std::vector<std::int64_t> voxel;
    std::vector<double> lo, hi, g, delta, gradient;  // g, gradient: with the displacement criterion only
  };
  Coord owned_hi{};  // the brick owns its centres in [Window::lo, owned_hi]
  Out* out = nullptr;
};

// The diamond's bound over the voxels beneath it (those inside the box): forced or empty by its
// placement, else its children's bounds (child(c), united from `start`) widened by its own δ and
// the gradient at its centre (own(d) → {δ, gradient}).
template <class Child, class Own>
Bound diamond_bound(const Diamond& d, const Lattice& lat, Child&& child, Own&& own, Bound start = {}) {
  const Placement where = deep_inside(d, lat) ? Placement{false, true} : placement(d, lat);
  if (where.forced) return kUnbounded;
  if (!where.any_inside) return {};
  Coord kids[8];
  const int n = children(d, lat.S, kids);
  Bound halves = start;
  for (int i = 0; i < n; ++i) halves = unite(halves, child(kids[i]));
  const auto [delta, gradient] = own(d);
  return widen(halves, delta, gradient);
}

// A child outside the box: nothing beneath it is a voxel, unless its cubes cross the box (forced).
inline Bound outside_bound(const Coord& c, const Lattice& lat) { return placement(classify(c, lat.k), lat).forced ? kUnbounded : Bound{}; }
inline std::uint8_t outside_code(const Coord& c, const Lattice& lat) {
  return placement(classify(c, lat.k), lat).forced ? ErrorCodes::kForced : 0;
}

// A diamond's saturated codes: its own, raised to its children's (child(c, displacement) → code).
template <bool kDisplacement, class ChildCode>
std::array<std::uint8_t, 2> saturated_codes(const Diamond& d, const Bound& b, std::int32_t S, const CodeTable& codes,
                                            const CodeTable& dcodes, const Displacement& disp, ChildCode&& child) {
  std::uint8_t c = codes.code(magnitude(b));  // kForced for an unbounded one
  std::uint8_t m = kDisplacement ? dcodes.code(disp.ratio(b)) : 0;
  Coord kids[8];
  const int n = children(d, S, kids);
  for (int i = 0; i < n; ++i) {
    c = std::max(c, child(kids[i], false));
    if constexpr (kDisplacement) m = std::max(m, child(kids[i], true));
  }
  return {c, m};
}

// kBricked: one brick's hierarchy (bisection_bricks.cpp) over the scales below B, which leaves the
// seam diamonds to the combine step and hands up what it needs of them.
template <class T, bool kDisplacement, bool kBricked = false>
class ErrorHierarchy {
public:
  // It keeps references to the lattice, the displacement and the progress: no temporaries (a
  // Progress{} passed here once died before run() read it).
  ErrorHierarchy(const Lattice&, const Window&, const T*, const ErrorCodes&, std::vector<std::uint8_t>&, const Displacement&, Progress&&,
                 const Seams* = nullptr) = delete;
  ErrorHierarchy(const Lattice& lat, const Window& w, const T* values, const ErrorCodes& codes, std::vector<std::uint8_t>& code,
                 const Displacement& disp, const Progress& progress, const Seams* seams = nullptr)
      : lat_(lat),
        w_(w),
        base_(w.base()),
        f_(values),
        codes_(codes),
        code_(code),
        disp_(disp),
        dcodes_(disp.codes),
        progress_(progress),
        seams_(seams) {
    // Deep blocks (the finest scale's fast path) keep off the box's far faces and, in a brick,
    // 3 voxels off its seam planes (the block's diamonds are then no seam diamonds).
    for (int a = 0; a < 3; ++a) {
      deep_lo_[a] = w.lo[a] + (kBricked && w.lo[a] > 0 ? 3 : 1);
      deep_hi_[a] = w.hi[a];
    }
  }

  void run() {
    const int levels = kBricked ? std::min(lat_.k, std::countr_zero(static_cast<std::uint32_t>(seams_->B))) : lat_.k;
    for (int s = 0; s < levels; ++s) {
      const std::int32_t h = std::int32_t{1} << s;
      if (h == 1) {
        finest();
      } else {
        for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube}) level(kind, h);
      }
      if constexpr (kBricked) hand_up(h);
      report(progress_, "error hierarchy", static_cast<double>(s + 1) / levels);
      // The edges of the next scale read only this scale's cube centres.
      for (auto& b : edges_) std::vector<StoredBound>().swap(b);
      for (auto& b : faces_) std::vector<StoredBound>().swap(b);
      cubes_below_.swap(cubes_);
      std::vector<StoredBound>().swap(cubes_);
    }
  }

  double value(const Coord& c) const { return static_cast<double>(f_[index(c)]); }

  // The gradient magnitude at a voxel (central differences, one-sided at the border; data units
  // per voxel step), for the displacement criterion only.
  double gradient(const Coord& c) const {
    if constexpr (!kDisplacement) return kInf;
    double sq = 0;
    const std::int64_t i = index(c);
    for (int a = 0; a < 3; ++a) {
      const std::int64_t st = stride(a);
      double d = 0;
      if (lat_.X[a] == 0)
        d = 0;
      else if (c[a] == 0)
        d = at(i + st) - at(i);
      else if (c[a] == lat_.X[a])
        d = at(i) - at(i - st);
      else
        d = 0.5 * (at(i + st) - at(i - st));
      sq += d * d;
    }
    return std::sqrt(sq);
  }

private:
  const Lattice& lat_;
  const Window w_;
  const std::int64_t base_;
  const T* f_;
  CodeTable codes_;
  std::vector<std::uint8_t>& code_;
  const Displacement& disp_;
  CodeTable dcodes_;
  const Progress& progress_;
  const Seams* seams_;
  Coord deep_lo_{}, deep_hi_{};
  // Stored bounds: this scale's edges and faces (per axis) and cube centres, the finer scale's cube centres.
  std::vector<StoredBound> edges_[3], faces_[3], cubes_, cubes_below_;

  std::int64_t index(const Coord& c) const { return c[0] + w_.nx * c[1] + w_.nxy * c[2] - base_; }
  bool skip(const Diamond& d) const {
    if constexpr (kBricked) return seams_->seam(d);
    return false;
  }
  double at(std::int64_t i) const { return static_cast<double>(f_[i]); }
  std::int64_t stride(int axis) const { return axis == 0 ? 1 : axis == 1 ? w_.nx : w_.nxy; }
  // Of c ± 1 (c odd), the direction towards the end at an odd multiple of 2 (a parent cube's centre).
  static int towards_odd_end(std::int32_t c) { return ((c + 1) / 2) & 1 ? 1 : -1; }

  double delta(const Diamond& d) const {
    const auto [p, q] = refinement_edge(d);
    return 0.5 * (value(p) + value(q)) - value(d.c);
  }

  void write_codes(std::size_t at, std::uint8_t error, std::uint8_t displacement) {
    code_[at] = error;
    if constexpr (kDisplacement) (*disp_.code)[at] = displacement;
  }

  // ---- the finest scale, where 7 of 8 voxels are diamond centres. Deep inside the box (no
  // diamond crossing it, every neighbour a voxel) a cube centre's 3×3×3 block of voxels gives its
  // 19 diamonds at once; elsewhere they are evaluated the general way. Edges and faces of this
  // scale are never stored (that would cost 6 bytes per voxel).

  // A scale-1 cube centre whose block holds only deep diamonds.
  bool deep_block(const Coord& c) const {
    for (int a = 0; a < 3; ++a)
      if (c[a] < deep_lo_[a] || c[a] + 3 > deep_hi_[a]) return false;
    return true;
  }
  // The deep block that writes a scale-1 centre's code: the one whose centre is 1 below it along
  // its even axes (so each block owns 3 edges, 3 faces and its centre).
  bool owned_by_deep_block(Coord c) const {
    for (int a = 0; a < 3; ++a) c[a] -= (c[a] & 1) ? 0 : 1;
    return deep_block(c);
  }
  Coord cell_coord(const Coord& c, int cell) const { return {c[0] + cell % 3 - 1, c[1] + cell / 3 % 3 - 1, c[2] + cell / 9 - 1}; }
  std::int64_t offset(int cell) const { return (cell % 3 - 1) + (cell / 3 % 3 - 1) * w_.nx + (cell / 9 - 1) * w_.nxy; }

  // A block's 19 diamonds from its 27 voxels. A saturated code is the code of the largest error
  // (or displacement) beneath the diamond (codes are monotone), so only the block's own 7
  // diamonds are coded.
  void fine_block(const Coord& c, std::int64_t i, StoredBound& out) {
    double v[27];
    for (int z = -1, n = 0; z <= 1; ++z)
      for (int y = -1; y <= 1; ++y)
        for (int x = -1; x <= 1; ++x) v[n++] = at(i + x + y * w_.nx + z * w_.nxy);
    constexpr int axis_step[3] = {1, 3, 9};
    Bound edge_bound[12];
    double edge_worst[12], edge_moves[12];
#pragma GCC unroll 12
    for (int e = 0; e < 12; ++e) {
      const auto& E = kFineBlock.edges[e];
      const int st = axis_step[E.axis];
      const double d = 0.5 * (v[E.cell - st] + v[E.cell + st]) - v[E.cell];
      edge_bound[e] = widen({0, 0, kInf}, d, gradient(cell_coord(c, E.cell)));
      edge_worst[e] = std::abs(d);
      edge_moves[e] = kDisplacement ? disp_.ratio(edge_bound[e]) : 0;
      if (E.owned) write_codes(static_cast<std::size_t>(i + offset(E.cell)), codes_.code(edge_worst[e]), dcodes_.code(edge_moves[e]));
    }
    // Faces' and the cube's diagonals run towards the parent cubes' centres (odd multiples of 2).
    const int s[3] = {towards_odd_end(c[0]), towards_odd_end(c[1]), towards_odd_end(c[2])};
    Bound halves = kEmpty;
    double worst = 0, moves = 0;
#pragma GCC unroll 6
    for (int k = 0; k < 6; ++k) {
      const auto& F = kFineBlock.faces[k];
      Bound fb = kEmpty;
      double face_worst = 0, face_moves = 0;
      for (int e : F.edges) {
        fb = unite(fb, edge_bound[e]);
        face_worst = std::max(face_worst, edge_worst[e]);
        face_moves = std::max(face_moves, edge_moves[e]);
      }
      int diagonal = 0;
      for (int a = 0; a < 3; ++a)
        if (a != F.normal) diagonal += s[a] * axis_step[a];
      fb = widen(fb, 0.5 * (v[F.cell + diagonal] + v[F.cell - diagonal]) - v[F.cell], gradient(cell_coord(c, F.cell)));
      face_worst = std::max(face_worst, magnitude(fb));
      if constexpr (kDisplacement) face_moves = std::max(face_moves, disp_.ratio(fb));
      if (F.owned) write_codes(static_cast<std::size_t>(i + offset(F.cell)), codes_.code(face_worst), dcodes_.code(face_moves));
      halves = unite(halves, fb);
      worst = std::max(worst, face_worst);
      moves = std::max(moves, face_moves);
    }
    const int diagonal = s[0] + 3 * s[1] + 9 * s[2];
    const Bound cube = widen(halves, 0.5 * (v[13 + diagonal] + v[13 - diagonal]) - v[13], gradient(c));
    out = StoredBound(cube);
    if constexpr (kDisplacement) moves = std::max(moves, disp_.ratio(cube));
    write_codes(static_cast<std::size_t>(i), codes_.code(std::max(worst, magnitude(cube))), dcodes_.code(moves));
  }

  void finest() {
    const Sublattice cubes(w_.lo, w_.hi, DiamondKind::cube, 0, 1);
    assign_big(cubes_, static_cast<std::size_t>(cubes.size()), StoredBound{});
    // 1. The deep blocks.
    tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, cubes.n[2] * cubes.n[1], 4), [&](const auto& r) {
      for (std::int64_t jk = r.begin(); jk < r.end(); ++jk)
        for (std::int64_t n = 0; n < cubes.n[0]; ++n) {
          const Coord c = cubes.at(n, jk % cubes.n[1], jk / cubes.n[1]);
          if (deep_block(c)) fine_block(c, index(c), cubes_[cubes.index(c)]);
        }
    });
    // 2. The rest, in order (edges, faces, cubes: each reads its children's codes).
    for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube})
      for (int axis = 0; axis < (kind == DiamondKind::cube ? 1 : 3); ++axis) {
        const Sublattice sub(w_.lo, w_.hi, kind, axis, 1);
        tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, sub.n[2] * sub.n[1], 8), [&](const auto& r) {
          for (std::int64_t jk = r.begin(); jk < r.end(); ++jk)
            for (std::int64_t n = 0; n < sub.n[0]; ++n) {
              const Coord c = sub.at(n, jk % sub.n[1], jk / sub.n[1]);
              if (owned_by_deep_block(c)) continue;
              const Diamond d = classify(c, lat_.k);
              if (!d.valid || skip(d)) continue;
              const Bound b = bound(d);
              if (kind == DiamondKind::cube) cubes_[sub.index(c)] = StoredBound(b);
              saturate(d, b);
            }
        });
      }
  }

  // ---- the general way.

  // The stored or, for the finest scale's edges and faces, computed bound of a child.
  Bound child_bound(const Coord& c) const {
    const Diamond d = classify(c, lat_.k);
    if (!lat_.in_box(c)) return outside_bound(c, lat_);
    if (d.h == 1 && d.kind != DiamondKind::cube) return bound(d);
    const Sublattice sub(w_.lo, w_.hi, d.kind, d.axis, d.h);
    switch (d.kind) {
      case DiamondKind::edge:
        return edges_[d.axis][sub.index(c)].get();
      case DiamondKind::face:
        return faces_[d.axis][sub.index(c)].get();
      case DiamondKind::cube:
        break;
    }
    return cubes_below_[sub.index(c)].get();  // an edge's children: the finer cube centres
  }

  // Children are a finer level, complete before this one starts.
  std::uint8_t child_code(const Coord& c, const std::vector<std::uint8_t>& codes) const {
    if (lat_.in_box(c)) return codes[static_cast<std::size_t>(index(c))];
    return outside_code(c, lat_);
  }

  // The diamond's bound over the voxels beneath it (those inside the box).
  Bound bound(const Diamond& d) const {
    return diamond_bound(
        d, lat_, [&](const Coord& c) { return child_bound(c); },
        [&](const Diamond& e) {
          return std::array{delta(e), gradient(e.c)};
        });
  }

  // Writes the diamond's saturated codes: its own, raised to its children's.
  void saturate(const Diamond& d, const Bound& b) {
    const auto [c, m] = saturated_codes<kDisplacement>(d, b, lat_.S, codes_, dcodes_, disp_, [&](const Coord& x, bool displacement) {
      return child_code(x, displacement ? *disp_.code : code_);
    });
    write_codes(static_cast<std::size_t>(index(d.c)), c, m);  // one writer per centre
  }

  // The seam diamonds of scale h the brick owns: what the combine step needs of them, while this
  // scale's bounds are at hand. Their children that are no seam diamonds lie in this brick (a
  // seam diamond's centre is at most h from a seam plane and its children move away from it
  // by h, or h/2 along every axis, towards the brick holding it).
  void hand_up(std::int32_t h) {
    Seams::Out& out = *seams_->out;
    for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube})
      for (int axis = 0; axis < (kind == DiamondKind::cube ? 1 : 3); ++axis) {
        // Every centre of the sublattice has scale h: seam diamonds are the cube centres of
        // scale B/2 and those with a coordinate near a plane, so rows along x far from planes
        // need only their near columns.
        const Sublattice sub(w_.lo, seams_->owned_hi, kind, axis, h);
        const bool every = 2 * h == seams_->B && kind == DiamondKind::cube;
        std::vector<std::int64_t> columns, near_columns;
        for (std::int64_t i = 0; i < sub.n[0]; ++i) {
          columns.push_back(i);
          if (seams_->near(0, sub.at(i, 0, 0)[0], h)) near_columns.push_back(i);
        }
        for (std::int64_t k = 0; k < sub.n[2]; ++k)
          for (std::int64_t j = 0; j < sub.n[1]; ++j) {
            const Coord row = sub.at(0, j, k);
            for (std::int64_t i : every || seams_->near(1, row[1], h) || seams_->near(2, row[2], h) ? columns : near_columns) {
              const Diamond d = classify(sub.at(i, j, k), lat_.k);
              if (!d.valid || !skip(d)) continue;
              Bound own{0, 0, kInf};  // δ and gradient: none where the bound is not evaluated
              const Bound halves = diamond_bound(
                  d, lat_,
                  [&](const Coord& c) {
                    if (!lat_.in_box(c)) return Bound{};
                    const Diamond e = classify(c, lat_.k);
                    return skip(e) ? Bound{} : child_bound(c);
                  },
                  [&](const Diamond& e) {
                    own = {delta(e), 0, gradient(e.c)};
                    return std::array{0.0, kInf};
                  });
              out.voxel.push_back(d.c[0] + (lat_.X[0] + std::int64_t{1}) * (d.c[1] + (lat_.X[1] + std::int64_t{1}) * d.c[2]));
              out.lo.push_back(halves.lo);
              out.hi.push_back(halves.hi);
              out.delta.push_back(own.lo);
              if constexpr (kDisplacement) {
                out.g.push_back(halves.g);
                out.gradient.push_back(own.g);
              }
            }
          }
      }
  }

  // Every diamond of one kind and scale (above the finest) in the box: its bound, stored for the
  // next level, and its saturated codes. Diamonds deep inside the box, with all children present,
  // read their children straight from the stored arrays; the rest go the general way.
  void level(DiamondKind kind, std::int32_t h) {
    const std::int32_t g = h / 2;
    const Sublattice finer_cubes(w_.lo, w_.hi, DiamondKind::cube, 0, g);
    const Sublattice edges[3] = {
        {w_.lo, w_.hi, DiamondKind::edge, 0, h}, {w_.lo, w_.hi, DiamondKind::edge, 1, h}, {w_.lo, w_.hi, DiamondKind::edge, 2, h}};
    const Sublattice faces[3] = {
        {w_.lo, w_.hi, DiamondKind::face, 0, h}, {w_.lo, w_.hi, DiamondKind::face, 1, h}, {w_.lo, w_.hi, DiamondKind::face, 2, h}};
    // Deep inside: the children's places in the stored arrays follow from the centre directly.
    struct Codes {
      std::uint8_t error = 0, displacement = 0;
    };
    auto take = [&](const Coord& x, const std::vector<StoredBound>& from, const Sublattice& sub, Bound& b, Codes& codes) {
      const auto at = static_cast<std::size_t>(index(x));
      codes.error = std::max(codes.error, code_[at]);
      if constexpr (kDisplacement) codes.displacement = std::max(codes.displacement, (*disp_.code)[at]);
      b = unite(b, from[sub.index(x)].get());
    };
    auto fast = [&](const Diamond& d, Codes& codes) {
      Bound halves = kEmpty;
      const Coord& c = d.c;
      double delta = 0;
      if (d.kind == DiamondKind::edge) {
        for (int q = 0; q < 8; ++q)
          take({c[0] + (q & 1 ? g : -g), c[1] + (q & 2 ? g : -g), c[2] + (q & 4 ? g : -g)}, cubes_below_, finer_cubes, halves, codes);
        Coord p = c, r = c;
        p[d.axis] -= h;
        r[d.axis] += h;
        delta = 0.5 * (value(p) + value(r)) - value(c);
      } else if (d.kind == DiamondKind::face) {
        const int a = (d.axis + 1) % 3, b = (d.axis + 2) % 3;
        Coord p = c, r = c;
        for (int sgn : {-1, 1}) {
          Coord x = c;
          x[a] += sgn * h;  // an edge along b
          take(x, edges_[b], edges[b], halves, codes);
          x = c;
          x[b] += sgn * h;  // an edge along a
          take(x, edges_[a], edges[a], halves, codes);
        }
        p[a] = odd_end(c[a], h), r[a] = even_end(c[a], h);
        p[b] = odd_end(c[b], h), r[b] = even_end(c[b], h);
        delta = 0.5 * (value(p) + value(r)) - value(c);
      } else {
        for (int a = 0; a < 3; ++a)
          for (int sgn : {-1, 1}) {
            Coord x = c;
            x[a] += sgn * h;  // a face with normal a
            take(x, faces_[a], faces[a], halves, codes);
          }
        const Coord p{odd_end(c[0], h), odd_end(c[1], h), odd_end(c[2], h)}, r{even_end(c[0], h), even_end(c[1], h), even_end(c[2], h)};
        delta = 0.5 * (value(p) + value(r)) - value(c);
      }
      const Bound b = widen(halves, delta, gradient(c));
      codes.error = std::max(codes.error, codes_.code(magnitude(b)));
      if constexpr (kDisplacement) codes.displacement = std::max(codes.displacement, dcodes_.code(disp_.ratio(b)));
      return b;
    };
    for (int axis = 0; axis < (kind == DiamondKind::cube ? 1 : 3); ++axis) {
      const Sublattice sub(w_.lo, w_.hi, kind, axis, h);
      std::vector<StoredBound>& out = kind == DiamondKind::edge ? edges_[axis] : kind == DiamondKind::face ? faces_[axis] : cubes_;
      assign_big(out, static_cast<std::size_t>(sub.size()), StoredBound{});
      tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, sub.n[2] * sub.n[1], 16), [&](const auto& r) {
        for (std::int64_t jk = r.begin(); jk < r.end(); ++jk) {
          const std::int64_t j = jk % sub.n[1], k = jk / sub.n[1];
          for (std::int64_t i = 0; i < sub.n[0]; ++i) {
            const Diamond d = classify(sub.at(i, j, k), lat_.k);
            if (!d.valid || skip(d)) continue;  // a corner of the root cube, or left to the combine step
            if (deep_inside(d, lat_) && d.c[0] >= h && d.c[1] >= h && d.c[2] >= h) {
              Codes codes;
              out[sub.index(d.c)] = StoredBound(fast(d, codes));
              write_codes(static_cast<std::size_t>(index(d.c)), codes.error, codes.displacement);
            } else {
              const Bound b = bound(d);
              out[sub.index(d.c)] = StoredBound(b);
              saturate(d, b);
            }
          }
        }
      });
    }
  }
};

}  // namespace adaptiso::detail
