// The longest-edge bisection grid (see bisection.hpp; the lattice geometry is in diamond.hpp).
//
// Two steps. The error hierarchy, bottom-up over the scales (h = 1, 2, 4, …; at each the edge
// midpoints, then the face centres, then the cube centres): per diamond a signed bound of
// value − interpolant over the voxels beneath it, from its children's bounds and its own δ, and a
// saturated one-byte code per voxel. The finest diamonds are evaluated on the fly from the voxels
// (storing them would cost 6 bytes per voxel); from the cube centres of scale 1 on, one scale's
// bounds are kept for the next. Then the selection, top-down from the 6 root tetrahedra: a
// tetrahedron is split where its diamond's code exceeds the bound's (or its diamond crosses the
// box), and the leaves inside the box are the grid. The traversal runs twice, once to mark the
// vertices it uses and once to write the tetrahedra with their final numbers, so no intermediate
// list of tetrahedra is needed; subtrees are cut at a fixed depth and processed in parallel, and
// results are placed in depth-first order, the same for any thread count.
#include "adaptiso/bisection.hpp"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>

#include "adaptiso/error.hpp"
#include "adaptiso/reduce.hpp"
#include "grid/diamond.hpp"
#include "grid/traversal.hpp"
#include "util/big_array.hpp"
#include "util/memory.hpp"

namespace adaptiso {

// ---- error codes ----

std::uint8_t ErrorCodes::code(double e) const {
  if (!(e > zero)) return 0;
  if (!std::isfinite(e)) return kForced;
  if (e >= scale) return 254;
  int c = static_cast<int>(std::ceil(254 + 16 * std::log2(e / scale)));
  c = std::clamp(c, 1, 254);
  while (c < 254 && error(static_cast<std::uint8_t>(c)) < e) ++c;  // rounding of log2 and exp2
  while (c > 1 && error(static_cast<std::uint8_t>(c - 1)) >= e) --c;
  return static_cast<std::uint8_t>(c);
}

double ErrorCodes::error(std::uint8_t c) const {
  if (c == 0) return zero;
  if (c == kForced) return std::numeric_limits<double>::infinity();
  return scale * std::exp2((static_cast<int>(c) - 254) / 16.0);
}

std::uint8_t ErrorCodes::threshold(double bound) const {
  int c = 0;
  while (c < 254 && error(static_cast<std::uint8_t>(c + 1)) <= bound) ++c;
  return static_cast<std::uint8_t>(c);
}

namespace detail {
namespace {

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
Bound widen(Bound halves, double delta, double at_centre) {
  return {halves.lo + std::min(0.0, -delta), halves.hi + std::max(0.0, -delta), std::min(halves.g, at_centre)};
}
Bound unite(Bound a, Bound b) { return {std::min(a.lo, b.lo), std::max(a.hi, b.hi), std::min(a.g, b.g)}; }
double magnitude(Bound b) { return std::max(-b.lo, b.hi); }

// The centres of one kind of diamond at one scale that lie in the box, as a dense 3D array: along
// axis a the coordinates base_a, base_a + 2h, … ≤ X_a.
struct Sublattice {
  Coord base{};
  std::int32_t step = 2;
  int shift = 1;  // log2(step)
  std::array<std::int64_t, 3> n{};
  std::size_t size() const { return static_cast<std::size_t>(n[0] * n[1] * n[2]); }
  Sublattice(const Lattice& lat, DiamondKind kind, int axis, std::int32_t h)
      : step(2 * h), shift(std::countr_zero(static_cast<std::uint32_t>(2 * h))) {
    for (int a = 0; a < 3; ++a) {
      bool odd = kind == DiamondKind::cube || (kind == DiamondKind::face && a != axis) || (kind == DiamondKind::edge && a == axis);
      base[a] = odd ? h : 0;
      n[a] = lat.X[a] >= base[a] ? (lat.X[a] - base[a]) / step + 1 : 0;
    }
  }
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

template <class T, bool kDisplacement>
class ErrorHierarchy {
public:
  ErrorHierarchy(const Lattice& lat, const T* values, const ErrorCodes& codes, std::vector<std::uint8_t>& code, const Displacement& disp,
                 const Progress& progress)
      : lat_(lat), f_(values), codes_(codes), code_(code), disp_(disp), dcodes_(disp.codes), progress_(progress) {}

  void run() {
    const int levels = lat_.k;
    for (int s = 0; s < lat_.k; ++s) {
      const std::int32_t h = std::int32_t{1} << s;
      if (h == 1) {
        finest();
      } else {
        for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube}) level(kind, h);
      }
      report(progress_, "error hierarchy", static_cast<double>(s + 1) / levels);
      // The edges of the next scale read only this scale's cube centres.
      for (auto& b : edges_) std::vector<StoredBound>().swap(b);
      for (auto& b : faces_) std::vector<StoredBound>().swap(b);
      cubes_below_.swap(cubes_);
      std::vector<StoredBound>().swap(cubes_);
    }
  }

private:
  const Lattice& lat_;
  const T* f_;
  CodeTable codes_;
  std::vector<std::uint8_t>& code_;
  const Displacement& disp_;
  CodeTable dcodes_;
  const Progress& progress_;
  // Stored bounds: this scale's edges and faces (per axis) and cube centres, the finer scale's cube centres.
  std::vector<StoredBound> edges_[3], faces_[3], cubes_, cubes_below_;

  double value(const Coord& c) const { return static_cast<double>(f_[lat_.index(c)]); }
  double at(std::int64_t i) const { return static_cast<double>(f_[i]); }
  std::int64_t stride(int axis) const { return axis == 0 ? 1 : axis == 1 ? lat_.nx : lat_.nxy; }
  // Of c ± 1 (c odd), the direction towards the end at an odd multiple of 2 (a parent cube's centre).
  static int towards_odd_end(std::int32_t c) { return ((c + 1) / 2) & 1 ? 1 : -1; }

  double delta(const Diamond& d) const {
    const auto [p, q] = refinement_edge(d);
    return 0.5 * (value(p) + value(q)) - value(d.c);
  }

  // The gradient magnitude at a voxel (central differences, one-sided at the border; data units
  // per voxel step), for the displacement criterion only.
  double gradient(const Coord& c) const {
    if constexpr (!kDisplacement) return kInf;
    double sq = 0;
    const std::int64_t i = lat_.index(c);
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
      if (c[a] < 1 || c[a] + 3 > lat_.X[a]) return false;
    return true;
  }
  // The deep block that writes a scale-1 centre's code: the one whose centre is 1 below it along
  // its even axes (so each block owns 3 edges, 3 faces and its centre).
  bool owned_by_deep_block(Coord c) const {
    for (int a = 0; a < 3; ++a) c[a] -= (c[a] & 1) ? 0 : 1;
    return deep_block(c);
  }
  Coord cell_coord(const Coord& c, int cell) const { return {c[0] + cell % 3 - 1, c[1] + cell / 3 % 3 - 1, c[2] + cell / 9 - 1}; }
  std::int64_t offset(int cell) const { return (cell % 3 - 1) + (cell / 3 % 3 - 1) * lat_.nx + (cell / 9 - 1) * lat_.nxy; }

  // A block's 19 diamonds from its 27 voxels. A saturated code is the code of the largest error
  // (or displacement) beneath the diamond (codes are monotone), so only the block's own 7
  // diamonds are coded.
  void fine_block(const Coord& c, std::int64_t i, StoredBound& out) {
    double v[27];
    for (int z = -1, n = 0; z <= 1; ++z)
      for (int y = -1; y <= 1; ++y)
        for (int x = -1; x <= 1; ++x) v[n++] = at(i + x + y * lat_.nx + z * lat_.nxy);
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
    const Sublattice cubes(lat_, DiamondKind::cube, 0, 1);
    assign_big(cubes_, static_cast<std::size_t>(cubes.size()), StoredBound{});
    // 1. The deep blocks.
    tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, cubes.n[2] * cubes.n[1], 4), [&](const auto& r) {
      for (std::int64_t jk = r.begin(); jk < r.end(); ++jk)
        for (std::int64_t n = 0; n < cubes.n[0]; ++n) {
          const Coord c = cubes.at(n, jk % cubes.n[1], jk / cubes.n[1]);
          if (deep_block(c)) fine_block(c, lat_.index(c), cubes_[cubes.index(c)]);
        }
    });
    // 2. The rest, in order (edges, faces, cubes: each reads its children's codes).
    for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube})
      for (int axis = 0; axis < (kind == DiamondKind::cube ? 1 : 3); ++axis) {
        const Sublattice sub(lat_, kind, axis, 1);
        tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, sub.n[2] * sub.n[1], 8), [&](const auto& r) {
          for (std::int64_t jk = r.begin(); jk < r.end(); ++jk)
            for (std::int64_t n = 0; n < sub.n[0]; ++n) {
              const Coord c = sub.at(n, jk % sub.n[1], jk / sub.n[1]);
              if (owned_by_deep_block(c)) continue;
              const Diamond d = classify(c, lat_.k);
              if (!d.valid) continue;
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
    if (!lat_.in_box(c)) return placement(d, lat_).forced ? kUnbounded : Bound{};  // nothing beneath it is a voxel
    if (d.h == 1 && d.kind != DiamondKind::cube) return bound(d);
    const Sublattice sub(lat_, d.kind, d.axis, d.h);
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
    if (lat_.in_box(c)) return codes[static_cast<std::size_t>(lat_.index(c))];
    return placement(classify(c, lat_.k), lat_).forced ? ErrorCodes::kForced : 0;
  }

  // The diamond's bound over the voxels beneath it (those inside the box).
  Bound bound(const Diamond& d) const {
    const Placement where = deep_inside(d, lat_) ? Placement{false, true} : placement(d, lat_);
    if (where.forced) return kUnbounded;
    if (!where.any_inside) return {};
    Coord kids[8];
    const int n = children(d, lat_.S, kids);
    Bound halves{};
    for (int i = 0; i < n; ++i) halves = unite(halves, child_bound(kids[i]));
    return widen(halves, delta(d), gradient(d.c));
  }

  // Writes the diamond's saturated codes: its own, raised to its children's.
  void saturate(const Diamond& d, const Bound& b) {
    std::uint8_t c = codes_.code(magnitude(b));  // kForced for an unbounded one
    std::uint8_t m = kDisplacement ? dcodes_.code(disp_.ratio(b)) : 0;
    Coord kids[8];
    const int n = children(d, lat_.S, kids);
    for (int i = 0; i < n; ++i) {
      c = std::max(c, child_code(kids[i], code_));
      if constexpr (kDisplacement) m = std::max(m, child_code(kids[i], *disp_.code));
    }
    write_codes(static_cast<std::size_t>(lat_.index(d.c)), c, m);  // one writer per centre
  }

  // Every diamond of one kind and scale (above the finest) in the box: its bound, stored for the
  // next level, and its saturated codes. Diamonds deep inside the box, with all children present,
  // read their children straight from the stored arrays; the rest go the general way.
  void level(DiamondKind kind, std::int32_t h) {
    const std::int32_t g = h / 2;
    const Sublattice finer_cubes(lat_, DiamondKind::cube, 0, g);
    const Sublattice edges[3] = {{lat_, DiamondKind::edge, 0, h}, {lat_, DiamondKind::edge, 1, h}, {lat_, DiamondKind::edge, 2, h}};
    const Sublattice faces[3] = {{lat_, DiamondKind::face, 0, h}, {lat_, DiamondKind::face, 1, h}, {lat_, DiamondKind::face, 2, h}};
    // Deep inside: the children's places in the stored arrays follow from the centre directly.
    struct Codes {
      std::uint8_t error = 0, displacement = 0;
    };
    auto take = [&](const Coord& x, const std::vector<StoredBound>& from, const Sublattice& sub, Bound& b, Codes& codes) {
      const auto at = static_cast<std::size_t>(lat_.index(x));
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
      const Sublattice sub(lat_, kind, axis, h);
      std::vector<StoredBound>& out = kind == DiamondKind::edge ? edges_[axis] : kind == DiamondKind::face ? faces_[axis] : cubes_;
      assign_big(out, static_cast<std::size_t>(sub.size()), StoredBound{});
      tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, sub.n[2] * sub.n[1], 16), [&](const auto& r) {
        for (std::int64_t jk = r.begin(); jk < r.end(); ++jk) {
          const std::int64_t j = jk % sub.n[1], k = jk / sub.n[1];
          for (std::int64_t i = 0; i < sub.n[0]; ++i) {
            const Diamond d = classify(sub.at(i, j, k), lat_.k);
            if (!d.valid) continue;  // a corner of the root cube
            if (deep_inside(d, lat_) && d.c[0] >= h && d.c[1] >= h && d.c[2] >= h) {
              Codes codes;
              out[sub.index(d.c)] = StoredBound(fast(d, codes));
              write_codes(static_cast<std::size_t>(lat_.index(d.c)), codes.error, codes.displacement);
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

// Float bounds of doubles, rounded outwards, and their atomic updates (several tetrahedra of one
// diamond lie in different subtrees).
float down(double x) {
  const auto f = static_cast<float>(x);
  return f > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
float up(double x) {
  const auto f = static_cast<float>(x);
  return f < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}
void atomic_min(float& target, float v) {
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

}  // namespace
}  // namespace detail

BisectionErrors bisection_errors(const Volume& v, const ValueRange& range, bool displacement, const Progress& progress) {
  using namespace detail;
  const Lattice lat = make_lattice(v.dims);
  // A code byte per voxel (two with the displacement), 12 bytes per cube centre of the finest scale.
  const auto voxels = static_cast<std::uint64_t>(v.voxel_count());
  check_memory(voxels * (displacement ? 2 : 1) + voxels / 8 * 14, fmt::format("the error hierarchy of {} voxels", voxels), "",
               "crop or subsample the volume");
  BisectionErrors e;
  e.root_size = lat.S;
  const double spread = range.max > range.min ? range.max - range.min : 1.0;
  e.codes.scale = spread;
  e.codes.zero = error_tolerance(range, 0.0);
  assign_big(e.code, static_cast<std::size_t>(v.voxel_count()), std::uint8_t{0});
  Displacement disp;
  if (displacement) {
    e.displacement_codes.scale = kDisplacementScale;
    e.displacement_codes.zero = 0;
    assign_big(e.displacement_code, static_cast<std::size_t>(v.voxel_count()), std::uint8_t{0});
    disp.code = &e.displacement_code;
    disp.codes = e.displacement_codes;
    disp.g0 = kGradientFloor * spread;
  }
  visit_values(v, [&]<class T>(std::span<const T> values) {
    if (displacement)
      ErrorHierarchy<T, true>(lat, values.data(), e.codes, e.code, disp, progress).run();
    else
      ErrorHierarchy<T, false>(lat, values.data(), e.codes, e.code, disp, progress).run();
  });
  return e;
}

namespace detail {
namespace {

// The grid's vertices under a rule whose splits are closed upwards (a split diamond's parents
// split too: the codes are saturated), without a walk: the centres of the split diamonds in the
// box and the root cube's corners in it. A split tetrahedron's midpoint is a vertex of both
// halves, and of every descendant that contains it, so of the leaves that cover it; and every
// vertex of a leaf is a root corner or the midpoint of an ancestor's split.
template <class Rule>
std::vector<std::uint64_t> split_centres(const Lattice& lat, const Rule& rule, std::size_t voxels) {
  std::vector<std::uint64_t> bits;
  assign_big(bits, (voxels + 63) / 64, std::uint64_t{0});
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, bits.size(), 4096), [&](const auto& r) {
    for (std::size_t w = r.begin(); w < r.end(); ++w) {
      std::uint64_t word = 0;
      const std::size_t n = std::min<std::size_t>(64, voxels - w * 64);
      for (std::size_t b = 0; b < n; ++b) word |= std::uint64_t{rule.split(static_cast<std::int64_t>(w * 64 + b))} << b;
      bits[w] = word;
    }
  });
  for (int corner = 0; corner < 8; ++corner) {
    const Coord c{corner & 1 ? lat.S : 0, corner & 2 ? lat.S : 0, corner & 4 ? lat.S : 0};
    if (!lat.in_box(c)) continue;
    const auto v = static_cast<std::size_t>(lat.index(c));
    bits[v >> 6] |= std::uint64_t{1} << (v & 63);
  }
  return bits;
}

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
template <class Rule, class Size, class Fill>
void assemble(const Lattice& lat, const Rule& rule, std::size_t voxels, Size size, Fill fill, BisectionGrid& out, const Progress& progress,
              const std::vector<std::uint8_t>* own_code = nullptr, std::uint8_t own_least = 0) {
  const Traversal<Rule> walk(lat, rule);
  const Frontier top = walk.frontier(12);
  const std::vector<Subtree>& roots = top.roots;
  std::vector<std::uint64_t> leaves(roots.size() + 1, 0);
  report(progress, "select", 0);
  constexpr bool kMarked = !Rule::kUpwardClosed;  // the vertices marked by the leaves, not found from the codes
  std::vector<std::uint8_t> used;
  if constexpr (kMarked) assign_big(used, voxels, std::uint8_t{0});
  tbb::parallel_for(std::size_t{0}, roots.size(), [&](std::size_t f) {
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
    numbers.bits.assign((used.size() + 63) / 64, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numbers.bits.size(), 4096), [&](const auto& r) {
      for (std::size_t w = r.begin(); w < r.end(); ++w) {
        std::uint64_t bits = 0;
        for (std::size_t b = 0; b < 64 && w * 64 + b < used.size(); ++b) bits |= std::uint64_t{used[w * 64 + b]} << b;
        numbers.bits[w] = bits;
      }
    });
    std::vector<std::uint8_t>().swap(used);
  } else {
    numbers.bits = split_centres(lat, rule, voxels);
  }
  for (std::size_t f = 0; f < roots.size(); ++f) leaves[f + 1] += leaves[f];
  numbers.count();
  const std::uint64_t vertices = numbers.before.back(), tets = leaves.back();
  // The grid and the rest of the preparation: tetrahedra (16 bytes), their index (8 bytes, and
  // while built 16 more for each entry of the two nodes being sorted: about 8 a tetrahedron on the
  // noisiest scan here, the MR head, whose two largest nodes hold 39 M of 84 M entries), vertices
  // with values, gradients and codes (33 bytes).
  check_memory(tets * 36 + vertices * 33, fmt::format("a grid of {} tetrahedra", tets), "max_error", "raise it");
  if (vertices >= std::numeric_limits<std::uint32_t>::max() || tets >= std::numeric_limits<std::uint32_t>::max())
    throw OptionError("max_error", fmt::format("{} vertices and {} tetrahedra exceed the grid's 32-bit indices; raise it", vertices, tets));
  report(progress, "select", 0.5);
  TetGrid& g = out.grid;
  size(vertices);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numbers.bits.size(), 1024), [&](const auto& r) {
    for (std::size_t w = r.begin(); w < r.end(); ++w) {
      std::uint64_t id = numbers.before[w];
      for (std::uint64_t b = numbers.bits[w]; b; b &= b - 1) fill(w * 64 + static_cast<std::size_t>(std::countr_zero(b)), id++);
    }
  });
  resize_big(g.tets, tets);
  if (own_code) resize_big(out.tet_code, tets);
  auto& spans = out.hierarchy.value_span;
  assign_big(spans, vertices, {std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity()});
  auto merge = [&](std::uint32_t id, const ValueSpan& s) {
    auto& span = spans[id];
    atomic_min(span[0], down(s.lo));
    atomic_max(span[1], up(s.hi));
  };
  std::vector<ValueSpan> root_spans(roots.size());
  tbb::parallel_for(std::size_t{0}, roots.size(), [&](std::size_t f) {
    std::uint64_t at = leaves[f];
    root_spans[f] = walk.visit(
        roots[f], numbers, g.values,
        [&](const Tet&, const Corners& c, std::int64_t split_at) {
          if (own_code)
            out.tet_code[at] = split_at >= 0 ? std::max((*own_code)[static_cast<std::size_t>(split_at)], own_least) : std::uint8_t{0};
          g.tets[at++] = c.id;
          return ValueSpan{std::min({c.value[0], c.value[1], c.value[2], c.value[3]}),
                           std::max({c.value[0], c.value[1], c.value[2], c.value[3]})};
        },
        [&](std::int64_t, std::uint32_t id, const Tet&, const ValueSpan& s) { merge(id, s); });
  });
  for (const auto& split : top.splits) {  // children first: the spans of the subtrees below
    ValueSpan s;
    for (std::size_t r = split.first; r < split.last; ++r) s.add(root_spans[r]);
    merge(numbers.id(split.voxel), s);
  }
  report(progress, "select", 1);
  out.hierarchy.root_size = lat.S;
}

void check_bounds(const BisectionOptions& o) {
  if (o.cell_floor < 0 || o.cell_floor > 30)
    throw OptionError("cell_floor", fmt::format("must be between 0 and 30 (cubes of 1 to 2^30 voxels), got {}", o.cell_floor));
  if (!(o.max_error >= 0))  // +∞: no error criterion (the displacement alone, or the coarsest grid)
    throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", o.max_error));
  if (!(o.max_displacement >= 0) || !std::isfinite(o.max_displacement))
    throw OptionError("max_displacement", fmt::format("must be a non-negative number, got {}", o.max_displacement));
}

}  // namespace
}  // namespace detail

BisectionGrid bisection_select(const Volume& v, const ValueRange& range, const BisectionErrors& errors, const BisectionOptions& o,
                               const Progress& progress) {
  using namespace detail;
  check_bounds(o);
  if (o.cell_floor != 0) throw OptionError("cell_floor", "only a coarsening takes a cell floor (a grid prepared under one keeps no bound)");
  const Lattice lat = make_lattice(v.dims);
  if (errors.code.size() != static_cast<std::size_t>(v.voxel_count()) || errors.root_size != lat.S)
    throw std::invalid_argument("bisection_select: the errors belong to another volume");
  const bool displacement = o.max_displacement > 0;
  if (displacement && errors.displacement_code.size() != errors.code.size())
    throw std::invalid_argument("bisection_select: the errors were computed without the displacement criterion");
  BisectionGrid out;
  out.hierarchy.codes = errors.codes;
  const std::uint8_t threshold = errors.codes.threshold(o.max_error);
  const std::uint8_t displacement_threshold = displacement ? errors.displacement_codes.threshold(o.max_displacement) : 0;
  const CodedSplits rule{errors.code, threshold, displacement ? &errors.displacement_code : nullptr, displacement_threshold};
  TetGrid& g = out.grid;
  g.source = grid_source(v, range);
  g.source.method = "bisection";
  g.source.max_error = o.max_error;
  auto& h = out.hierarchy;
  visit_values(v, [&]<class T>(std::span<const T> values) {
    auto size = [&](std::uint64_t n) {
      resize_big(g.ijk, n);
      resize_big(g.values, n);
      resize_big(h.error_code, n);
      if (displacement) resize_big(h.displacement_code, n);
    };
    auto fill = [&](std::size_t i, std::uint64_t id) {
      g.ijk[id] = {static_cast<std::uint32_t>(static_cast<std::int64_t>(i) % v.dims[0]),
                   static_cast<std::uint32_t>((static_cast<std::int64_t>(i) / v.dims[0]) % v.dims[1]),
                   static_cast<std::uint32_t>(static_cast<std::int64_t>(i) / lat.nxy)};
      g.values[id] = static_cast<double>(values[i]);
      h.error_code[id] = errors.code[i];
      if (displacement) h.displacement_code[id] = errors.displacement_code[i];
    };
    assemble(lat, rule, static_cast<std::size_t>(v.voxel_count()), size, fill, out, progress);
  });
  h.error_threshold = threshold;
  if (displacement) {
    h.displacement_codes = errors.displacement_codes;
    h.displacement_threshold = displacement_threshold;
    out.displacement_bound = errors.displacement_codes.error(displacement_threshold);
  }
  out.error_bound = errors.codes.error(threshold);
  return out;
}

BisectionGrid bisection_coarsen(const TetGrid& fine, const BisectionHierarchy& fh, const BisectionOptions& o, const Progress& progress) {
  using namespace detail;
  check_bounds(o);
  const Lattice lat = make_lattice(fine.source.dims);
  if (fh.root_size != lat.S || fh.error_code.size() != fine.vertex_count() || fh.value_span.size() != fine.vertex_count())
    throw InputError("this grid's hierarchy does not match it");
  const bool displacement = !fh.displacement_code.empty();
  if (o.max_displacement > 0 && !displacement)
    throw OptionError("max_displacement", "this grid was prepared without the displacement criterion");
  auto voxel_of = [&](const std::array<std::uint32_t, 3>& p) {
    return static_cast<std::size_t>(
        lat.index({static_cast<std::int32_t>(p[0]), static_cast<std::int32_t>(p[1]), static_cast<std::int32_t>(p[2])}));
  };
  // The fine grid's vertices by voxel: its vertices are numbered in ascending voxel order.
  VertexNumbers fine_numbers;
  assign_big(fine_numbers.bits, static_cast<std::size_t>((lat.nxy * (lat.X[2] + 1) + 63) / 64), std::uint64_t{0});
  for (const auto& p : fine.ijk) {
    const std::size_t i = voxel_of(p);
    fine_numbers.bits[i >> 6] |= std::uint64_t{1} << (i & 63);
  }
  fine_numbers.count();
  // The selection below numbers the root cube's corners by their rank among the fine vertices
  // without asking whether they are vertices (load_grid refuses a file without them; a grid made
  // any other way is checked here, 8 lookups).
  for (int corner = 0; corner < 8; ++corner) {
    const Coord c{corner & 1 ? lat.S : 0, corner & 2 ? lat.S : 0, corner & 4 ? lat.S : 0};
    if (lat.in_box(c) && !fine_numbers.used(lat.index(c)))
      throw InputError("this grid's hierarchy does not match it (a root cube's corner is no vertex)");
  }
  BisectionGrid out;
  auto& h = out.hierarchy;
  h.codes = fh.codes;
  h.error_threshold = std::max(fh.codes.threshold(o.max_error), fh.error_threshold);  // never finer than the fine grid
  if (displacement) {
    h.displacement_codes = fh.displacement_codes;
    h.displacement_threshold =
        std::max(o.max_displacement > 0 ? fh.displacement_codes.threshold(o.max_displacement) : std::uint8_t{0}, fh.displacement_threshold);
    out.displacement_bound = fh.displacement_codes.error(h.displacement_threshold);
  }
  // The fine grid's codes spread back over the voxels (a voxel that is no vertex of the fine grid
  // was not split, code 0), so the walk tests a voxel as directly as the selection from the volume.
  const auto voxels = static_cast<std::size_t>(lat.nxy * (lat.X[2] + 1));
  std::vector<std::uint8_t> code, moves;
  assign_big(code, voxels, std::uint8_t{0});
  if (displacement) assign_big(moves, voxels, std::uint8_t{0});
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, fine.vertex_count(), 1 << 16), [&](const auto& r) {
    for (std::size_t f = r.begin(); f < r.end(); ++f) {
      const std::size_t i = voxel_of(fine.ijk[f]);
      code[i] = fh.error_code[f];
      if (displacement) moves[i] = fh.displacement_code[f];
    }
  });
  const CodedSplits coded{code, h.error_threshold, displacement ? &moves : nullptr, h.displacement_threshold};
  TetGrid& g = out.grid;
  g.source = fine.source;
  g.source.max_error = std::max(o.max_error, fh.codes.error(fh.error_threshold));
  auto size = [&](std::uint64_t n) {
    resize_big(g.ijk, n);
    resize_big(g.values, n);
    if (!fine.gradients.empty()) resize_big(g.gradients, n);
    resize_big(h.error_code, n);
    if (displacement) resize_big(h.displacement_code, n);
  };
  auto fill = [&](std::size_t voxel, std::uint64_t id) {
    const std::uint32_t f = fine_numbers.id(static_cast<std::int64_t>(voxel));
    g.ijk[id] = fine.ijk[f];
    g.values[id] = fine.values[f];
    if (!fine.gradients.empty()) g.gradients[id] = fine.gradients[f];
    h.error_code[id] = fh.error_code[f];
    if (displacement) h.displacement_code[id] = fh.displacement_code[f];
  };
  out.error_bound = fh.codes.error(h.error_threshold);
  if (o.cell_floor == 0) {
    assemble(lat, coded, voxels, size, fill, out, progress);
    return out;
  }
  const FlooredSplits floored{coded, lat.nx, lat.nxy, (std::int64_t{1} << o.cell_floor) - 1};
  // A diamond the fine grid left whole has no code of its own here (0): the fine bound holds.
  assemble(lat, floored, voxels, size, fill, out, progress, &code, fh.error_threshold);
  out.error_bound = std::max(out.error_bound, fh.codes.error(floored.kept_error));
  if (displacement) out.displacement_bound = std::max(out.displacement_bound, fh.displacement_codes.error(floored.kept_displacement));
  return out;
}

BisectionGrid bisection_grid(const Volume& v, const ValueRange& range, const BisectionOptions& options, const Progress& progress) {
  detail::check_bounds(options);  // before the error hierarchy, not after it
  return bisection_select(v, range, bisection_errors(v, range, options.max_displacement > 0, progress), options, progress);
}

}  // namespace adaptiso
