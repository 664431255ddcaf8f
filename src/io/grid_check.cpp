// The invariants of a grid read from a file (see grid_check.hpp). Each check is one pass over an
// array, in parallel; the bisection grid's adds one walk of its hierarchy, the walk its selection
// made, so its tetrahedra, vertices and value spans are compared with what the hierarchy itself
// gives rather than trusted.
#include "io/grid_check.hpp"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <optional>
#include <random>

#include "adaptiso/bisection.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/volume.hpp"
#include "grid/diamond.hpp"
#include "grid/share_agree.hpp"
#include "grid/traversal.hpp"
#include "util/big_array.hpp"
#include "util/memory.hpp"
#include "util/progress_counter.hpp"

namespace adaptiso::detail {
namespace {

// The largest dimension the bisection lattice takes (make_lattice); no grid is larger. Nor has
// any grid more voxels than a volume adaptiso could hold (256 TB of bytes): voxel indices then stay
// far inside 64 bits, and a grid whose dims multiply past that is refused before any product of
// them overflows.
constexpr std::int64_t kMaxDimension = (std::int64_t{1} << 30) + 1;
constexpr std::uint64_t kMaxVoxels = std::uint64_t{1} << 48;

// The first fault among items [0, n): check(i) returns nullptr or what is wrong with item i. Checked
// in parallel; the fault reported is the one of the smallest index, whatever the thread count.
struct Fault {
  std::size_t at = std::numeric_limits<std::size_t>::max();
  const char* why = nullptr;
};
template <class Check>
Fault first_fault_in(std::size_t begin, std::size_t end, const Check& check) {
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(begin, end, 1 << 14), Fault{},
      [&](const tbb::blocked_range<std::size_t>& r, Fault f) {
        for (std::size_t i = r.begin(); i < r.end() && i < f.at; ++i)
          if (const char* why = check(i)) return Fault{i, why};
        return f;
      },
      [](const Fault& a, const Fault& b) { return a.at <= b.at ? a : b; });
}
template <class Check>
Fault first_fault(std::size_t n, const Check& check) {
  return first_fault_in(0, n, check);
}

// The hierarchy's checks shared out over processes that each loaded the same file (check_grid's
// `share`): process p of P checks the p-th P-th of the vertices one by one and walks the subtrees
// f ≡ p (mod P), and what each found is combined on every process (share_agree.hpp), so that all
// reach the same verdict and throw the same message. Without a transport, one process does all.
struct CheckShare {
  ShareTransport* transport = nullptr;
  bool shared() const { return transport && transport->processes() > 1; }
  bool mine(std::size_t subtree) const {
    return !shared() || subtree % static_cast<std::size_t>(transport->processes()) == static_cast<std::size_t>(transport->process());
  }
  // This process's part [first, second) of n items in order.
  std::pair<std::size_t, std::size_t> part(std::size_t n) const {
    if (!shared()) return {0, n};
    const auto p = static_cast<std::size_t>(transport->process()), P = static_cast<std::size_t>(transport->processes());
    return {share::part_begin(n, P, p), share::part_begin(n, P, p + 1)};
  }
  template <class T, class Combine>
  void combine(std::span<T> values, Combine c) const {
    if (shared()) share::combine_at_zero(*transport, values, c);
  }
  // The smallest of every process's x.
  std::size_t least(std::size_t x) const {
    if (!shared()) return x;
    std::uint64_t v = x;
    combine(std::span(&v, 1), [](std::uint64_t& own, std::uint64_t theirs) { own = std::min(own, theirs); });
    return static_cast<std::size_t>(v);
  }
  // The fault of the smallest index any process found, its reason asked again of `check` where it
  // was found elsewhere (a reason's address is the process's own).
  template <class Check>
  Fault first(Fault f, const Check& check) const {
    if (!shared()) return f;
    const std::size_t at = least(f.at);
    if (at == f.at) return f;
    return Fault{at, check(at)};
  }
};

using Wide = __int128;
// Six times the volume of a tetrahedron of lattice points, exact: in 64 bits while coordinates stay
// within 2^20 (each product of three edge coordinates below 2^60), else in 128.
Wide six_volume(const Tet& t, bool narrow) {
  auto det = [&]<class I>(I) {
    I e[3][3];
    for (int r = 1; r < 4; ++r)
      for (int a = 0; a < 3; ++a) e[r - 1][a] = static_cast<I>(t[static_cast<std::size_t>(r)][a]) - t[0][a];
    return e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1]) - e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0]) +
           e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0]);
  };
  return narrow ? Wide{det(std::int64_t{})} : det(Wide{});
}
bool narrow_lattice(const Dims& dims) { return std::max({dims[0], dims[1], dims[2]}) <= (std::int64_t{1} << 20) + 1; }

Wide six_box_volume(const Dims& dims) { return Wide{6} * (dims[0] - 1) * (dims[1] - 1) * (dims[2] - 1); }

void check_vertices(const TetGrid& g, const std::string& path) {
  const GridSource& s = g.source;
  const Fault f = first_fault(g.vertex_count(), [&](std::size_t v) -> const char* {
    for (int a = 0; a < 3; ++a)
      if (g.ijk[v][a] >= static_cast<std::uint64_t>(s.dims[a])) return "lies outside the volume";
    // Ascending voxel order is what lets a voxel's rank among the vertices stand for its number.
    if (v > 0 && !(lattice_key(s.dims, g.ijk[v - 1]) < lattice_key(s.dims, g.ijk[v])))
      return "is out of ascending voxel order (or repeats a voxel)";
    if (!std::isfinite(g.values[v])) return "has a non-finite value";
    if (g.values[v] < s.min || g.values[v] > s.max) return "has a value outside the grid's value range";
    for (float x : g.gradients[v])
      if (std::isnan(x)) return "has a gradient that is not a number";
    return nullptr;
  });
  if (f.why) throw InputError(fmt::format("{}: vertex {} {}", path, f.at, f.why));
}

// Every vertex a corner of some tetrahedron, from a byte per vertex the passes over the tetrahedra
// set (a relaxed atomic byte store is a plain store).
void check_used(const std::vector<std::uint8_t>& used, const std::string& path) {
  const Fault f = first_fault(used.size(), [&](std::size_t v) -> const char* { return used[v] ? nullptr : "x"; });
  if (f.why) throw InputError(fmt::format("{}: vertex {} is no corner of any tetrahedron", path, f.at));
}
void mark(std::vector<std::uint8_t>& used, std::uint32_t v) { std::atomic_ref<std::uint8_t>(used[v]).store(1, std::memory_order_relaxed); }

// A grid without a hierarchy (Delaunay, a floored level, older files): its tetrahedra must be
// positively oriented and fill the box's volume exactly. Together with a conforming mesh that is a
// tiling; conformity itself is not checked (it would take the faces' matching, not a pass).
void check_tiling(const TetGrid& g, const std::string& path) {
  std::vector<std::uint8_t> used;
  assign_big(used, g.vertex_count(), std::uint8_t{0});
  const bool narrow = narrow_lattice(g.source.dims);
  struct Sum {
    Wide volume = 0;
    Fault fault;
  };
  const Sum sum = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, g.tet_count(), 1 << 14), Sum{},
      [&](const tbb::blocked_range<std::size_t>& r, Sum s) {
        for (std::size_t t = r.begin(); t < r.end(); ++t) {
          Tet p;
          for (int k = 0; k < 4; ++k) {
            const std::uint32_t v = g.tets[t][static_cast<std::size_t>(k)];
            mark(used, v);
            for (int a = 0; a < 3; ++a) p[static_cast<std::size_t>(k)][a] = static_cast<std::int32_t>(g.ijk[v][a]);
          }
          const Wide six = six_volume(p, narrow);
          if (six <= 0 && t < s.fault.at) s.fault = {t, "is not positively oriented (its volume is zero or negative)"};
          s.volume += six;
        }
        return s;
      },
      [](Sum a, const Sum& b) {
        a.volume += b.volume;
        if (b.fault.at < a.fault.at) a.fault = b.fault;
        return a;
      });
  if (sum.fault.why) throw InputError(fmt::format("{}: tetrahedron {} {}", path, sum.fault.at, sum.fault.why));
  if (sum.volume != six_box_volume(g.source.dims))
    throw InputError(fmt::format("{}: the tetrahedra do not tile the volume's box (their volumes sum to {:.6g} of the box's)", path,
                                 static_cast<double>(sum.volume) / static_cast<double>(six_box_volume(g.source.dims))));
  check_used(used, path);
}

// ---- the bisection hierarchy

// The selection the file claims: the diamonds split are those whose centres are vertices (that
// these are the diamonds its thresholds split is checked vertex by vertex first).
struct FileSplits {
  const VertexNumbers& numbers;
  bool split(std::int64_t voxel) const { return numbers.used(voxel); }
  Decision decide(std::int64_t voxel) const { return numbers.used(voxel) ? Decision::descend : Decision::leaf; }
};

// The file's tetrahedra against the walk's leaves, position by position, without holding the leaves:
// per subtree of the walk a sum of a keyed mix of (position, tetrahedron). The key is drawn for each
// process, so no file can be made to match a wrong sequence; a mismatch at any position changes the
// sum but with probability about 2^-64.
struct TetHash {
  std::uint64_t a, b, c;
  static std::uint64_t mix(std::uint64_t x) {  // MurmurHash3's finalizer, a bijection
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdULL;
    x ^= x >> 33;
    x *= 0xc4ceb9fe1a85ec53ULL;
    return x ^ (x >> 33);
  }
  std::uint64_t operator()(std::uint64_t position, const std::array<std::uint32_t, 4>& t) const {
    const std::uint64_t lo = (std::uint64_t{t[0]} << 32 | t[1]) ^ a, hi = (std::uint64_t{t[2]} << 32 | t[3]) ^ b;
    return mix(mix(lo + position * c) ^ hi);
  }
  static TetHash draw() {
    static const TetHash key = [] {
      std::random_device rd;
      auto word = [&] { return std::uint64_t{rd()} << 32 | rd(); };
      return TetHash{word(), word(), word() | 1};
    }();
    return key;
  }
};

// Value spans as the selection keeps them (bisection.cpp): floats rounded outwards.
float round_down(double x) {
  const auto f = static_cast<float>(x);
  return f > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
float round_up(double x) {
  const auto f = static_cast<float>(x);
  return f < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}

// The file's value spans against the walk's, without a second array of spans: a diamond's span is
// the union of what its tetrahedra hold (they lie in several subtrees, walked by several threads),
// so each of them must lie within the file's span, and between them they must reach both ends. A
// byte per vertex records the ends reached; the smallest vertex whose span is exceeded is kept.
class SpanCheck {
public:
  SpanCheck(const std::vector<std::array<float, 2>>& file, std::size_t n) : file_(file) { assign_big(reached_, n, std::uint8_t{0}); }
  void add(std::uint32_t id, const ValueSpan& s) {
    const float lo = round_down(s.lo), hi = round_up(s.hi);
    const auto& f = file_[id];
    if (!(f[0] <= lo && hi <= f[1])) {
      std::atomic_ref<std::uint32_t> w(worst_);
      for (std::uint32_t cur = w.load(std::memory_order_relaxed);
           id < cur && !w.compare_exchange_weak(cur, id, std::memory_order_relaxed);) {
      }
      return;
    }
    const std::uint8_t bits = static_cast<std::uint8_t>((lo == f[0] ? 1 : 0) | (hi == f[1] ? 2 : 0));
    std::atomic_ref<std::uint8_t> r(reached_[id]);
    if ((r.load(std::memory_order_relaxed) & bits) != bits)
      r.fetch_or(bits, std::memory_order_relaxed);  // a locked write only the first time
  }
  // Every process's findings (the ends reached, the smallest vertex exceeded) in every process's.
  void combine(const CheckShare& share) {
    share.combine(std::span(reached_), [](std::uint8_t& own, std::uint8_t theirs) { own |= theirs; });
    share.combine(std::span(&worst_, 1), [](std::uint32_t& own, std::uint32_t theirs) { own = std::min(own, theirs); });
  }
  // The first vertex whose span is not the union of its tetrahedra's (an empty span, +∞ … −∞, for
  // a vertex no split reached), or none.
  std::optional<std::uint32_t> first_wrong() const {
    const Fault f = first_fault(reached_.size(), [&](std::size_t v) -> const char* {
      const bool empty = file_[v][0] == std::numeric_limits<float>::infinity() && file_[v][1] == -file_[v][0];
      return v == worst_ || (empty ? reached_[v] != 0 : reached_[v] != 3) ? "x" : nullptr;
    });
    if (f.why) return static_cast<std::uint32_t>(f.at);
    return std::nullopt;
  }

private:
  const std::vector<std::array<float, 2>>& file_;
  std::vector<std::uint8_t> reached_;
  std::uint32_t worst_ = VertexNumbers::kNone;
};

[[noreturn]] void corrupt_hierarchy(const std::string& path, const std::string& why) {
  throw InputError(fmt::format("{}: grid hierarchy is corrupt ({})", path, why));
}

// The file's tetrahedra against a walk of its hierarchy: as many as its leaves (file_leaves when
// they were not kept) and, when kept, the leaves themselves in the walk's order (per subtree, a
// keyed hash of its leaves, TetHash).
void check_leaves(const TetGrid& g, const std::string& path, const std::vector<std::uint64_t>& leaves,
                  const std::vector<std::uint64_t>& hashes, std::optional<std::uint64_t> file_leaves, const CheckShare& share = {}) {
  const std::uint64_t in_file = file_leaves ? *file_leaves : g.tet_count();
  if (leaves.back() != in_file)
    corrupt_hierarchy(path, fmt::format("the hierarchy has {} leaves, the file {} tetrahedra", leaves.back(), in_file));
  if (file_leaves) return;
  const TetHash hash = TetHash::draw();
  // The subtrees this process walked: their hashes are its own (the key is drawn per process).
  auto wrong = [&](std::size_t f) -> const char* {
    if (!share.mine(f)) return nullptr;
    std::uint64_t sum = 0;
    for (std::uint64_t t = leaves[f]; t < leaves[f + 1]; ++t) sum += hash(t - leaves[f], g.tets[t]);
    return sum == hashes[f] ? nullptr : "x";
  };
  const std::size_t at = share.least(first_fault(hashes.size(), wrong).at);
  if (at < hashes.size())
    corrupt_hierarchy(path, fmt::format("the tetrahedra {} to {} are not the hierarchy's leaves", leaves[at], leaves[at + 1] - 1));
}

void check_hierarchy(const PreparedGrid& p, const std::string& path, std::optional<std::uint64_t> file_leaves, HierarchyWalk* walked,
                     const Progress& progress, const CheckShare& share) {
  const TetGrid& g = p.grid;
  const BisectionHierarchy& h = *p.hierarchy;
  auto fail = [&](const std::string& why) { corrupt_hierarchy(path, why); };
  const std::size_t n = g.vertex_count();
  if (g.source.method != "bisection") fail(fmt::format("a bisection hierarchy in a grid made by '{}'", g.source.method.substr(0, 40)));
  const bool moves = !h.displacement_code.empty();
  if (h.error_code.size() != n || h.value_span.size() != n || (moves && h.displacement_code.size() != n)) fail("array sizes");
  const Lattice lat = make_lattice(g.source.dims);
  if (h.root_size != lat.S) fail("root cube");
  // The codes' scales and thresholds are those prepare derives from the metadata: a query at an
  // error E splits where a code exceeds threshold(E), so any other scale answers for another error.
  const ValueRange range{g.source.min, g.source.max};
  if (h.codes.scale != (range.max > range.min ? range.max - range.min : 1.0) || h.codes.zero != error_tolerance(range, 0.0))
    fail("error code scale");
  if (h.error_threshold != h.codes.threshold(g.source.max_error)) fail("error threshold");
  if (moves) {
    if (h.displacement_codes.scale != kDisplacementCodeScale || h.displacement_codes.zero != 0) fail("displacement code scale");
    if (!(p.stats.max_displacement > 0) || h.displacement_threshold != h.displacement_codes.threshold(p.stats.max_displacement))
      fail("displacement threshold");
  } else if (h.displacement_threshold != 0) {
    fail("displacement threshold without displacement codes");
  }

  // The vertices by voxel: a bit per voxel and a count per 64, as the walks number them.
  const auto voxels = static_cast<std::uint64_t>(g.source.dims[0] * g.source.dims[1] * g.source.dims[2]);
  // The bitmap and its counts (a quarter byte a voxel), and a byte each for the vertices used and
  // the value spans reached.
  check_memory(voxels / 4 + n * 2, fmt::format("checking the hierarchy of a grid over {} voxels", voxels), "", "");
  const VertexNumbers numbers = grid_vertex_numbers(g);
  // The walks number a tetrahedron's corners from the bitmap without asking whether they are
  // vertices: the root cube's corners, and the centres of the diamonds split above them.
  for (int corner = 0; corner < 8; ++corner) {
    const Coord c{corner & 1 ? lat.S : 0, corner & 2 ? lat.S : 0, corner & 4 ? lat.S : 0};
    if (lat.in_box(c) && !numbers.used(lat.index(c)))
      fail(fmt::format("the root cube's corner {},{},{} inside the volume is no vertex", c[0], c[1], c[2]));
  }
  auto local_fault = [&](std::size_t v) -> const char* {
    const Coord c{static_cast<std::int32_t>(g.ijk[v][0]), static_cast<std::int32_t>(g.ijk[v][1]), static_cast<std::int32_t>(g.ijk[v][2])};
    const Diamond d = classify(c, lat.k);
    if (!d.valid) return nullptr;  // a root cube's corner
    const std::uint8_t code = h.error_code[v], moved = moves ? h.displacement_code[v] : std::uint8_t{0};
    if (!(code > h.error_threshold || (moves && moved > h.displacement_threshold)))
      return "is the centre of a diamond the grid's bound does not split";
    if (code != ErrorCodes::kForced && !deep_inside(d, lat) && placement(d, lat).forced)
      return "is the centre of a diamond across the volume's box not coded as always split";
    const auto [a, b] = refinement_edge(d);
    if (lat.in_box(a) && lat.in_box(b)) {
      const std::uint32_t ia = numbers.find(lat.index(a)), ib = numbers.find(lat.index(b));
      if (ia == VertexNumbers::kNone || ib == VertexNumbers::kNone) return "is split, but an end of its refinement edge is no vertex";
      // Its own deviation from the edge's interpolant is part of its bound (bisection.cpp, widen).
      if (!(std::abs(0.5 * (g.values[ia] + g.values[ib]) - g.values[v]) <= h.codes.error(code)))
        return "has an error code below its own deviation from its refinement edge";
    }
    Coord parent[4];
    const int np = parents(d, lat.S, parent);
    for (int i = 0; i < np; ++i) {
      // The root cube's centre has the root's corners for parents: no diamonds, no codes.
      if (!lat.in_box(parent[i]) || !classify(parent[i], lat.k).valid) continue;
      const std::uint32_t ip = numbers.find(lat.index(parent[i]));
      if (ip == VertexNumbers::kNone) return "is split, but a parent diamond is not (the grid would not be conforming)";
      if (h.error_code[ip] < code || (moves && h.displacement_code[ip] < moved)) return "has a code above a parent's (codes grow upwards)";
    }
    return nullptr;
  };
  const auto [first_vertex, end_vertex] = share.part(n);
  const Fault local = share.first(first_fault_in(first_vertex, end_vertex, local_fault), local_fault);
  if (local.why)
    fail(fmt::format("vertex {} at {},{},{} {}", local.at, g.ijk[local.at][0], g.ijk[local.at][1], g.ijk[local.at][2], local.why));

  // The walk of the selection at the file's splits: its leaves, in the order assemble writes them.
  const FileSplits rule{numbers};
  const Traversal<FileSplits> walk(lat, rule);
  const Frontier top = walk.frontier(12);
  const std::size_t roots = top.roots.size();
  std::vector<std::uint64_t> leaves(roots + 1, 0), hashes(roots, 0);
  std::vector<Wide> volumes(roots, 0);
  std::vector<ValueSpan> root_spans(roots);
  std::vector<std::uint8_t> used;
  assign_big(used, n, std::uint8_t{0});
  SpanCheck spans(h.value_span, n);
  const bool narrow = narrow_lattice(g.source.dims);
  const TetHash hash = TetHash::draw();
  // The leaves' hashes are for tetrahedra read now, or later against the walk (check_tets_walked).
  const bool hashing = !file_leaves || walked;
  // The walk is most of the check: told by the subtrees done, at most a hundred times.
  report(progress, "check grid", 0.1);
  std::vector<std::size_t> own;  // the subtrees this process walks
  for (std::size_t f = 0; f < roots; ++f)
    if (share.mine(f)) own.push_back(f);
  detail::ProgressCounter walked_roots(progress, "check grid", own.size(), 0.1, 1);
  tbb::parallel_for(std::size_t{0}, own.size(), [&](std::size_t i) {
    const std::size_t f = own[i];
    std::uint64_t count = 0, sum = 0;
    Wide volume = 0;
    root_spans[f] = walk.visit(
        top.roots[f], numbers, g.values,
        [&](const Tet& t, const Corners& c, std::int64_t) {
          if (hashing) sum += hash(count, c.id);
          ++count;
          for (std::uint32_t id : c.id) mark(used, id);
          volume += six_volume(t, narrow);
          return ValueSpan{std::min({c.value[0], c.value[1], c.value[2], c.value[3]}),
                           std::max({c.value[0], c.value[1], c.value[2], c.value[3]})};
        },
        [&](std::int64_t, std::uint32_t id, const Tet&, const ValueSpan& s) { spans.add(id, s); });
    leaves[f + 1] = count;
    hashes[f] = sum;
    volumes[f] = volume;
    walked_roots.advance(1);
  });
  // Every process's subtrees in every process's findings: the others' counts, volumes and spans
  // are zero and empty here, so sums and unions combine them.
  share.combine(std::span(leaves), [](std::uint64_t& a, std::uint64_t b) { a += b; });
  share.combine(std::span(volumes), [](Wide& a, Wide b) { a += b; });
  share.combine(std::span(root_spans), [](ValueSpan& a, const ValueSpan& b) { a.add(b); });
  share.combine(std::span(used), [](std::uint8_t& a, std::uint8_t b) { a |= b; });
  spans.combine(share);
  for (const auto& split : top.splits) {  // above the subtrees
    ValueSpan s;
    for (std::size_t r = split.first; r < split.last; ++r) s.add(root_spans[r]);
    spans.add(numbers.id(split.voxel), s);
  }
  Wide volume = 0;
  for (std::size_t f = 0; f < roots; ++f) {
    leaves[f + 1] += leaves[f];
    volume += volumes[f];
  }
  // Holes: a diamond across the box's boundary left whole leaves tetrahedra reaching outside it,
  // which the walk drops.
  if (volume != six_box_volume(g.source.dims)) fail("its leaves do not tile the volume's box");
  check_leaves(g, path, leaves, hashes, file_leaves, share);
  if (const auto v = spans.first_wrong()) fail(fmt::format("the value span of vertex {} is not that of the values beneath it", *v));
  check_used(used, path);
  if (walked) {
    walked->leaves = std::move(leaves);
    walked->hashes = std::move(hashes);
  }
}

// Every index a vertex (the tetrahedra's first check in check_grid).
void check_indices(const TetGrid& g, const std::string& path) {
  const std::size_t n = g.vertex_count();
  const Fault f = first_fault(g.tet_count(), [&](std::size_t t) -> const char* {
    for (std::uint32_t v : g.tets[t])
      if (v >= n) return "references a vertex that does not exist";
    return nullptr;
  });
  if (f.why) throw InputError(fmt::format("{}: tetrahedron {} {}", path, f.at, f.why));
}

[[noreturn]] void invalid_metadata(const std::string& path, const std::string& why) {
  throw InputError(fmt::format("{}: grid metadata is invalid ({})", path, why));
}

}  // namespace

GridSource grid_source_from_json(const nlohmann::json& s, const std::string& path) {
  auto fail = [&](const std::string& why) { invalid_metadata(path, why); };
  if (!s.is_object()) fail("no \"source\" object");
  auto field = [&](const char* key) -> const nlohmann::json& {
    const auto it = s.find(key);
    if (it == s.end()) invalid_metadata(path, fmt::format("no \"{}\"", key));
    return *it;
  };
  auto number = [&](const char* key, const nlohmann::json& x) {
    if (!x.is_number()) fail(fmt::format("\"{}\" holds something other than a number", key));
    const double v = x.get<double>();
    if (!std::isfinite(v)) fail(fmt::format("\"{}\" is not finite", key));
    return v;
  };
  auto numbers = [&]<std::size_t N>(const char* key, std::array<double, N>& out) {
    const auto& a = field(key);
    if (!a.is_array() || a.size() != N) fail(fmt::format("\"{}\" must be {} numbers", key, N));
    for (std::size_t i = 0; i < N; ++i) out[i] = number(key, a[i]);
  };
  auto text = [&](const char* key) {
    const auto& x = field(key);
    if (!x.is_string()) fail(fmt::format("\"{}\" is not a string", key));
    return x.get<std::string>();
  };
  GridSource g;
  const auto& dims = field("dims");
  if (!dims.is_array() || dims.size() != 3) fail("\"dims\" must be 3 whole numbers");
  for (int a = 0; a < 3; ++a) {
    const auto& d = dims[static_cast<std::size_t>(a)];
    if (!d.is_number_integer() || d.get<std::int64_t>() < 2 || d.get<std::int64_t>() > kMaxDimension)
      fail(fmt::format("\"dims\" must be 3 whole numbers from 2 to {} (a grid of tetrahedra needs 2 voxels along every axis)",
                       kMaxDimension));
    g.dims[a] = d.get<std::int64_t>();
  }
  if (static_cast<std::uint64_t>(g.dims[0]) * static_cast<std::uint64_t>(g.dims[1]) > kMaxVoxels / static_cast<std::uint64_t>(g.dims[2]))
    fail(fmt::format("\"dims\" {} x {} x {} are more voxels than any volume (2^48)", g.dims[0], g.dims[1], g.dims[2]));
  if (s.contains("volume_dims")) {
    const auto& vd = s["volume_dims"];
    if (!vd.is_array() || vd.size() != 3) fail("\"volume_dims\" must be 3 whole numbers");
    for (int a = 0; a < 3; ++a) {
      const auto& d = vd[static_cast<std::size_t>(a)];
      if (!d.is_number_integer() || d.get<std::int64_t>() < 2 || d.get<std::int64_t>() > g.dims[a])
        fail(fmt::format("\"volume_dims\" must be 3 whole numbers from 2 to the lattice's \"dims\" {} x {} x {}", g.dims[0], g.dims[1],
                         g.dims[2]));
      g.volume_dims[a] = d.get<std::int64_t>();
    }
  }
  numbers("spacing", g.spacing);
  numbers("origin", g.origin);
  numbers("direction", g.direction);
  g.type = text("type");
  const auto type = parse_scalar_type(g.type);
  if (!type || scalar_name(*type) != g.type) fail(fmt::format("unknown element type '{}'", g.type.substr(0, 40)));
  g.min = number("min", field("min"));
  g.max = number("max", field("max"));
  if (!(g.min <= g.max)) fail("min exceeds max");
  g.method = text("method");
  // No error criterion (+∞) is written as null, JSON having no infinity.
  const auto& e = field("max_error");
  g.max_error = e.is_null() ? std::numeric_limits<double>::infinity() : number("max_error", e);
  if (!(g.max_error >= 0)) fail("max_error is negative");
  g.threshold = number("threshold", field("threshold"));
  g.file = text("file");
  check_geometry(g.dims, g.spacing, g.origin, g.direction, path);
  return g;
}

void check_grid(const PreparedGrid& p, const std::string& path, std::optional<std::uint64_t> leaves, HierarchyWalk* walked,
                const Progress& progress, ShareTransport* share) {
  if (share && share->processes() > 1 && walked) throw std::logic_error("check_grid: a shared check walks only part of the hierarchy");
  const TetGrid& g = p.grid;
  if ((leaves ? *leaves : g.tet_count()) == 0)
    throw InputError(fmt::format("{}: the grid has no tetrahedra (a grid tiles its volume's box)", path));
  report(progress, "check grid", 0);
  check_vertices(g, path);
  check_indices(g, path);
  if (p.hierarchy)
    check_hierarchy(p, path, leaves, walked, progress, CheckShare{share});
  else
    check_tiling(g, path);
  report(progress, "check grid", 1);
}

void check_tets_walked(const PreparedGrid& p, const std::string& path, const HierarchyWalk& walked) {
  const TetGrid& g = p.grid;
  if (!p.hierarchy || walked.leaves.size() != walked.hashes.size() + 1)
    throw std::logic_error("check_tets_walked: not the walk of a bisection grid's hierarchy");
  check_indices(g, path);
  check_leaves(g, path, walked.leaves, walked.hashes, std::nullopt);
}

}  // namespace adaptiso::detail
