// Queries of a bisection grid at a coarser error (see hierarchy_query.hpp): the walk of the
// selection (grid/traversal.hpp) with the query's threshold, pruned where the values beneath a
// diamond do not straddle the iso-value, then marching tetrahedra over the leaves it finds.
//
// This work is based on:
// - Gregorski, Duchaineau, Lindstrom, Pascucci, Joy. Interactive view-dependent rendering of large
//   isosurfaces. IEEE Visualization 2002 (the diamond hierarchy walked at a coarser error).
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.4 (marching the tetrahedra found).
#include "adaptiso/hierarchy_query.hpp"

#include <fmt/format.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <bit>
#include <limits>

#include <chrono>
#include <cmath>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "extract/box_clip.hpp"
#include "extract/hierarchy_index.hpp"
#include "extract/march_detail.hpp"
#include "grid/traversal.hpp"
#include "util/big_array.hpp"

namespace adaptiso {
namespace detail {
void LiningSpans::build(const Lattice& lat, const VertexNumbers& numbers, const TetGrid& grid, const BisectionHierarchy& h) {
  struct Entry {
    std::uint64_t key;
    float lo, hi;
  };
  tbb::enumerable_thread_specific<std::vector<Entry>> found;
  // The span beneath a tetrahedron: inside the box, its corners' and (when the grid splits it) its
  // diamond's; across the box, its halves'.
  auto span_of = [&](auto&& self, const Tet& t, OrderState o, int depth) -> ValueSpan {
    if (tet_outside(lat, t)) return {};
    ValueSpan s;
    Coord m;
    int i, j;
    const bool splits = refinement(t, o, m, i, j);
    if (tet_inside(lat, t)) {
      for (const Coord& c : t) {
        const double v = grid.values[numbers.id(lat.index(c))];
        s.add({v, v});
      }
      if (splits && numbers.used(lat.index(m))) {
        const auto& d = h.value_span[numbers.id(lat.index(m))];
        s.add({d[0], d[1]});
      }
      return s;
    }
    if (!splits || !(lat.in_box(m) ? numbers.used(lat.index(m)) : placement(classify(m, lat.k), lat).forced)) return s;
    // Not a structured binding: clang before 16 (the fuzz build's) cannot capture one in a lambda.
    const auto both = halves(t, o, m, i, j);
    const auto& a = both[0];
    const auto& b = both[1];
    ValueSpan sa, sb;
    if (depth < 12)
      tbb::parallel_invoke([&] { sa = self(self, a.tet, a.order, depth + 1); }, [&] { sb = self(self, b.tet, b.order, depth + 1); });
    else
      sa = self(self, a.tet, a.order, depth + 1), sb = self(self, b.tet, b.order, depth + 1);
    s.add(sa);
    s.add(sb);
    found.local().push_back({key(lat, m), static_cast<float>(s.lo), static_cast<float>(s.hi)});
    return s;
  };
  const auto roots = root_tetrahedra(lat.S);
  tbb::parallel_for(0, 6, [&](int r) { span_of(span_of, roots[static_cast<std::size_t>(r)], root_order(r), 0); });
  std::size_t n = 0;
  for (const auto& part : found) n += part.size();
  const std::size_t cap = std::bit_ceil(std::max<std::size_t>(16, 2 * n));
  shift_ = 64 - std::countr_zero(cap);
  slots_.assign(cap, Slot{});
  count_ = 0;
  for (const auto& part : found)
    for (const Entry& e : part) {
      // Floats rounded outwards, so the stored span holds the values.
      const float lo = e.lo, hi = e.hi;
      std::size_t at = home(e.key);
      while (slots_[at].key != kEmpty && slots_[at].key != e.key) at = (at + 1) & (cap - 1);
      Slot& s = slots_[at];
      if (s.key == kEmpty) {
        s = {e.key, std::nextafter(lo, -std::numeric_limits<float>::infinity()),
             std::nextafter(hi, std::numeric_limits<float>::infinity())};
        ++count_;
      } else {
        s.lo = std::min(s.lo, std::nextafter(lo, -std::numeric_limits<float>::infinity()));
        s.hi = std::max(s.hi, std::nextafter(hi, std::numeric_limits<float>::infinity()));
      }
    }
}

bool LiningSpans::may_cut(const Lattice& lat, const Coord& m, double iso) const {
  if (slots_.empty()) return true;
  const std::uint64_t k = key(lat, m);
  for (std::size_t at = home(k);; at = (at + 1) & (slots_.size() - 1)) {
    const Slot& s = slots_[at];
    if (s.key == kEmpty) return true;
    if (s.key == k) return s.lo < iso && iso <= s.hi;
  }
}

namespace {

struct QueryRule {
  const Lattice& lat;
  const LiningSpans& lining;
  const VertexNumbers& numbers;
  const BisectionHierarchy& h;
  std::uint8_t threshold, displacement_threshold;
  bool displacement;
  double iso;

  bool split_vertex(std::uint32_t id) const {
    return h.error_code[id] > threshold || (displacement && h.displacement_code[id] > displacement_threshold);
  }
  // A diamond that is not a vertex of the grid was not split at the prepared error: nor at a coarser one.
  bool split(std::int64_t voxel) const {
    const std::uint32_t id = numbers.find(voxel);
    return id != VertexNumbers::kNone && split_vertex(id);
  }
  bool may_cut_across(const Coord& m) const { return lining.may_cut(lat, m, iso); }
  Decision decide(std::int64_t voxel) const {
    const std::uint32_t id = numbers.find(voxel);
    if (id == VertexNumbers::kNone || !split_vertex(id)) return Decision::leaf;
    const auto& span = h.value_span[id];
    return span[0] < iso && iso <= span[1] ? Decision::descend : Decision::prune;  // a cut needs a value below and one at or above
  }
};

}  // namespace
}  // namespace detail

namespace detail {
std::unique_ptr<HierarchyIndex> make_hierarchy_index(const PreparedGrid& grid) {
  if (!grid.hierarchy || grid.hierarchy->error_code.size() != grid.grid.vertex_count() ||
      grid.hierarchy->value_span.size() != grid.grid.vertex_count())
    throw InputError("this grid has no bisection hierarchy: queries at another error need a bisection grid");
  const TetGrid& g = grid.grid;
  auto index = std::make_unique<HierarchyIndex>();
  index->lat = make_lattice(g.source.dims);
  if (grid.hierarchy->root_size != index->lat.S) throw InputError("the grid's hierarchy does not match its dimensions");
  index->numbers = grid_vertex_numbers(g);
  index->lining.build(index->lat, index->numbers, g, *grid.hierarchy);
  return index;
}
}  // namespace detail

HierarchyQuery::HierarchyQuery(std::shared_ptr<const PreparedGrid> grid) : grid_(std::move(grid)) {
  if (!grid_) throw InputError("this grid has no bisection hierarchy: queries at another error need a bisection grid");
  index_ = detail::make_hierarchy_index(*grid_);
}

HierarchyQuery::~HierarchyQuery() = default;
HierarchyQuery::HierarchyQuery(HierarchyQuery&&) noexcept = default;
HierarchyQuery& HierarchyQuery::operator=(HierarchyQuery&&) noexcept = default;

const PreparedGrid& HierarchyQuery::grid() const { return *grid_; }

double HierarchyQuery::prepared_error() const {
  const auto& h = *grid_->hierarchy;
  return h.codes.error(h.error_threshold);
}

Mesh HierarchyQuery::extract(double iso, double max_error, double max_displacement, HierarchyQueryStats* stats,
                             std::vector<std::array<std::uint32_t, 4>>* used, const std::atomic<bool>* cancel) const {
  using namespace detail;
  using Clock = std::chrono::steady_clock;
  if (!std::isfinite(iso)) throw OptionError("iso", "must be a finite number");
  if (!(max_error >= 0)) throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", max_error));
  if (!(max_displacement >= 0))
    throw OptionError("max_displacement", fmt::format("must be a non-negative number, got {}", max_displacement));
  const auto t0 = Clock::now();
  const TetGrid& g = grid_->grid;
  const BisectionHierarchy& h = *grid_->hierarchy;
  const bool displacement = !h.displacement_code.empty();
  // Never finer than prepared: the finer diamonds are not in the grid.
  const std::uint8_t threshold = std::max(h.codes.threshold(max_error), h.error_threshold);
  const std::uint8_t displacement_threshold =
      displacement
          ? std::max(max_displacement > 0 ? h.displacement_codes.threshold(max_displacement) : std::uint8_t{0}, h.displacement_threshold)
          : 0;
  const QueryRule rule{index_->lat, index_->lining, index_->numbers, h, threshold, displacement_threshold, displacement, iso};
  const Traversal<QueryRule> walk(index_->lat, rule);
  const Frontier top = walk.frontier(10);
  const double unsplit_bound = h.codes.error(h.error_threshold);  // leaves whose diamond the grid never split
  std::vector<std::vector<Quad>> found(top.roots.size());
  std::vector<double> bound(top.roots.size(), 0);
  std::vector<std::size_t> visited(top.roots.size(), 0);
  auto cancelled = [cancel] { return cancel && cancel->load(std::memory_order_relaxed); };
  tbb::parallel_for(std::size_t{0}, top.roots.size(), [&](std::size_t f) {
    if (cancelled()) return;
    auto& out = found[f];
    double worst = 0;
    std::size_t seen = 0;
    walk.visit(
        top.roots[f], index_->numbers, g.values,
        [&](const Tet&, const Corners& c, std::int64_t voxel) {
          ++seen;
          const double lo = std::min({c.value[0], c.value[1], c.value[2], c.value[3]});
          const double hi = std::max({c.value[0], c.value[1], c.value[2], c.value[3]});
          if (lo < iso && iso <= hi) {
            out.push_back(c.id);
            if (voxel >= 0) {
              const std::uint32_t id = index_->numbers.find(voxel);
              worst = std::max(worst, id == VertexNumbers::kNone ? unsplit_bound : h.codes.error(h.error_code[id]));
            }
          }
          return ValueSpan{};
        },
        [&](std::int64_t, std::uint32_t, const Tet&, const ValueSpan&) { ++seen; });
    bound[f] = worst;
    visited[f] = seen;
  });
  if (cancelled()) throw ExtractCancelled();  // some subtrees were not walked
  std::vector<Quad> quads;
  std::size_t total = 0;
  for (const auto& part : found) total += part.size();
  quads.reserve(total);
  for (const auto& part : found) quads.insert(quads.end(), part.begin(), part.end());
  const auto t1 = Clock::now();
  Mesh mesh;
  MarchScratch scratch;
  scratch.cancel = cancel;  // the march throws ExtractCancelled itself
  march_into(g, QuadTets{g, quads}, iso, mesh, scratch, nullptr, nullptr);
  clip_to_volume_box(mesh, g.source);
  if (used) *used = quads;
  if (stats) {
    stats->iso = iso;
    stats->max_error = std::max(max_error, prepared_error());
    stats->error_bound = 0;
    for (double b : bound) stats->error_bound = std::max(stats->error_bound, b);
    stats->tetrahedra = quads.size();
    stats->visited = top.roots.size() + top.splits.size();
    for (std::size_t v : visited) stats->visited += v;
    stats->triangles = mesh.triangle_count();
    stats->vertices = mesh.vertex_count();
    stats->in_range = iso >= g.source.min && iso <= g.source.max;
    stats->walk_seconds = std::chrono::duration<double>(t1 - t0).count();
    stats->march_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  }
  return mesh;
}

}  // namespace adaptiso
