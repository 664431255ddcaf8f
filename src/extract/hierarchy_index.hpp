// What the queries of a bisection grid need beside the grid (hierarchy_query.cpp,
// distance_query.cpp): the lattice, the voxel → vertex numbering, and the values beneath the
// diamonds that cross the box's far faces. Internal.
#pragma once
#include <tbb/enumerable_thread_specific.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <vector>

#include "adaptiso/prepared_grid.hpp"
#include "grid/traversal.hpp"

namespace adaptiso::detail {

// The grid keeps the span of the values beneath each split diamond from its tetrahedra inside the
// box; a diamond across the box's far faces is always split and its tetrahedra there have none.
// Without them a query walks the whole lining of the far faces (on the CT bunny most of the
// tetrahedra a query met, before prepare padded the lattice: bisection.hpp; a lattice whose far
// faces lie at multiples of 8 still has such diamonds above that size). Kept per diamond centre
// (a lattice point, in or beyond the box), in an open-addressing table.
class LiningSpans {
public:
  void build(const Lattice& lat, const VertexNumbers& numbers, const TetGrid& grid, const BisectionHierarchy& h);
  // Could a tetrahedron across the box, of the diamond centred at m, hold a cut of iso beneath it?
  // (True for a diamond not in the table.)
  bool may_cut(const Lattice& lat, const Coord& m, double iso) const;
  std::size_t size() const { return count_; }

private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  struct Slot {
    std::uint64_t key = kEmpty;
    float lo = 0, hi = 0;
  };
  std::vector<Slot> slots_;
  std::size_t count_ = 0;
  int shift_ = 64;
  static std::uint64_t key(const Lattice& lat, const Coord& m) {
    const auto side = static_cast<std::uint64_t>(lat.S) + 1;
    return static_cast<std::uint64_t>(m[0]) + side * (static_cast<std::uint64_t>(m[1]) + side * static_cast<std::uint64_t>(m[2]));
  }
  std::size_t home(std::uint64_t k) const { return static_cast<std::size_t>((k * 0x9E3779B97F4A7C15ull) >> shift_); }
};

// A bitmap over the voxels for one query's marks, kept for the next query: the words it set are
// cleared after it, not the whole map (a fresh zeroed map of the bunny's 95 M voxels, 12 MB, cost
// the kernel more than the query: its pages are zeroed 2 MB at a time). Marking is thread-safe.
class Marks {
public:
  explicit Marks(std::size_t voxels) : words_((voxels + 63) / 64, 0) {}
  bool test(std::int64_t v) const {
    return (std::atomic_ref<const std::uint64_t>(words_[static_cast<std::size_t>(v >> 6)]).load(std::memory_order_acquire) >> (v & 63)) & 1;
  }
  // True when v was not marked before.
  bool mark(std::int64_t v) {
    const std::uint64_t bit = std::uint64_t{1} << (v & 63);
    const auto w = static_cast<std::size_t>(v >> 6);
    const std::uint64_t old = std::atomic_ref<std::uint64_t>(words_[w]).fetch_or(bit, std::memory_order_acq_rel);
    if (old == 0) touched_.local().push_back(w);  // one thread finds each word empty
    return !(old & bit);
  }
  void clear() {
    for (auto& list : touched_) {
      for (std::size_t w : list) words_[w] = 0;
      list.clear();
    }
  }

private:
  std::vector<std::uint64_t> words_;
  tbb::enumerable_thread_specific<std::vector<std::size_t>> touched_;
};

// What a distance query marks (distance_query.cpp): the diamonds split.
struct DistanceMarks {
  explicit DistanceMarks(std::size_t voxels) : split(voxels) {}
  Marks split;
  void clear() { split.clear(); }
};

struct HierarchyIndex {
  Lattice lat;
  VertexNumbers numbers;
  LiningSpans lining;
  // Marks of finished queries, for the next ones (as many as ran at once).
  std::mutex pool_mutex;
  std::vector<std::unique_ptr<DistanceMarks>> pool;
  std::unique_ptr<DistanceMarks> take_marks() {
    {
      std::lock_guard lock(pool_mutex);
      if (!pool.empty()) {
        auto m = std::move(pool.back());
        pool.pop_back();
        return m;
      }
    }
    return std::make_unique<DistanceMarks>(static_cast<std::size_t>(lat.nxy * (lat.X[2] + 1)));
  }
  void give_back(std::unique_ptr<DistanceMarks> m) {
    m->clear();
    std::lock_guard lock(pool_mutex);
    pool.push_back(std::move(m));
  }
};

// The index of a bisection grid's queries (HierarchyQuery's). Throws InputError for a grid
// without a hierarchy, or one that does not match its dimensions.
std::unique_ptr<HierarchyIndex> make_hierarchy_index(const PreparedGrid& grid);

// For the tests of a surface made by several processes (distance_query.cpp): how many dealt
// subtrees process 0 met that no process had refined (then refined again there, the same mesh
// but the work not shared), since the program started. The deal pass rules them out.
std::size_t shared_refinement_fallbacks();

// For the tests of the distance query's probes (distance_query.cpp): at each point (lattice
// units, inside the box) the side of iso on which the grid's interpolant lies, found level by
// level from the root tetrahedron holding it, cube by cube down from each scale in `from_halves`
// (halves of cube sides, powers of two), and cube by cube from the smallest cubes up to each
// scale; counted: the answers the cubes gave each way, and of those the ones that disagree with
// the level-by-level descent or that it does not judge (off the grid: a leaf across the box's
// far faces).
struct ProbeRouteCounts {
  std::size_t points = 0;  // those the level-by-level descent judges
  std::size_t by_cubes = 0, from_below = 0, disagreed = 0;
};
ProbeRouteCounts compare_probe_routes(const PreparedGrid& grid, double iso, const std::vector<std::array<double, 3>>& points,
                                      const std::vector<std::int32_t>& from_halves);

// For the tests of the collapses' probes (distance_query.cpp): does the test a collapse's new
// triangle takes find no surface of the grid within `distance` of `centre` along the unit
// `normal` (voxels of the smallest spacing, in the grid's frame)?
bool collapse_test_says_far(const PreparedGrid& grid, double iso, double distance, const std::array<double, 3>& centre,
                            const std::array<double, 3>& normal);

// For the tests of the collapses (distance_query.cpp): called after each round's probes, in the
// round's order, with every chosen collapse (v into u, vertex numbers of the march's mesh, which
// stay until the last round), whether its probes passed, and v's star as the round saw it (its
// triangles, each rotated to start at its smallest number, sorted), the triangles it makes and the
// removed vertices it must keep near them. Set for one thread's queries
// (thread_local); empty: nothing is called, and no star is gathered.
struct SeenCollapse {
  std::uint32_t v = 0, u = 0;
  bool passed = false;
  bool ring_held_failed = false;  // failed only what its ring holds, or waited (tried again after a round)
  std::vector<std::array<std::uint32_t, 3>> star;
  // In the probes' frame (voxels of the smallest spacing): the triangles the collapse makes, and
  // v with the vertices removed before that v holds (each must stay within the distance of them).
  std::vector<std::array<std::array<double, 3>, 3>> made;
  std::vector<std::array<double, 3>> held;
};
void observe_collapse_rounds(std::function<void(const std::vector<SeenCollapse>&)> observer);

}  // namespace adaptiso::detail
