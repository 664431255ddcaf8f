// adaptiso/interval_tree.hpp — sweeping simplices (Lürig & Ertl §2.4): which tetrahedra does the
// iso-surface cut?
//
// A tetrahedron with value range [tmin, tmax] is *active* at iso-value c when tmin < c <= tmax
// (a vertex equal to c counts as above it, the one rule used everywhere). Constant tetrahedra are
// never active and are left out. The tree is binary with a fixed depth over the value range; each
// node has a split value chosen as the median of the midpoints of the tetrahedra that reach it (of
// an evenly spaced sample of 65,536 of them where more than 2^20 reach it; so the tree is as
// balanced as the data allows; above 2^22 tetrahedra the splits are chosen on a sample of at most
// about 2^22 of them, every k-th id), and a tetrahedron lives in the shallowest node whose
// split it straddles (tmin < split < tmax), i.e. the smallest node whose interval covers it; leaves
// keep the rest. Each node's tetrahedra appear twice: in `by_min` sorted by (tmin, id) and in
// `by_max` by (tmax, id), in the same [begin, end) range of both arrays. The build allocates
// little beyond the lists (per thread, 16 bytes an entry of the node it sorts; 2 bytes a
// tetrahedron while placing, before by_max exists): the CT bunny's 52 M entries at 0.02 add 0.6 GB
// at the peak, where records of every tetrahedron added 1.3 GB. Under a scratch budget the nodes
// too large for it take 2 bytes an entry instead (one at a time, each in parallel), at about 1.5
// times the time: prepare's budget keeps its peak within the saved grid plus 2.5 volumes.
//
// The tree is immutable and shared; a SweepState holds one client's position in it (the paper's
// per-node positions of the iso-value in both lists and the per-tetrahedron flags, indexed by
// tetrahedron id, which is the cross reference between the two lists). Moving the iso-value walks
// only the list entries between the old and the new positions. Any number of threads may use one
// tree with separate states.
#pragma once
#include <cstdint>
#include <limits>
#include <vector>

#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

struct IntervalTree {
  struct Node {
    double split = 0;                                      // values <= split go left
    double lo = std::numeric_limits<double>::infinity();   // smallest tmin in the subtree
    double hi = -std::numeric_limits<double>::infinity();  // largest tmax in the subtree
    std::uint64_t begin = 0, end = 0;                      // this node's entries in by_min / by_max
  };
  std::uint32_t depth = 0;  // a root-only tree has depth 0
  std::vector<Node> nodes;  // complete binary tree, 2^(depth+1) - 1 nodes; children of i: 2i+1, 2i+2
  std::vector<std::uint32_t> by_min, by_max;

  bool is_leaf(std::size_t i) const { return 2 * i + 1 >= nodes.size(); }
  std::size_t entries() const { return by_min.size(); }
};

constexpr std::uint32_t kDefaultTreeDepth = 12;  // bench_extract: query time flat from depth 8 to 20 (README)
constexpr std::uint32_t kMaxTreeDepth = 24;      // what prepare takes, and a grid file may ask to be built

// The scratch memory the build may hold at once by default, beyond the lists themselves (bytes).
constexpr std::size_t kDefaultIndexScratch = std::size_t{1} << 30;
// Builds the tree over grid.tets and grid.values; depth is reduced when the grid has fewer
// tetrahedra than leaves. Parallel. scratch_bytes bounds what sorting the lists holds at once:
// nodes too large for a thread's share of it at 16 bytes an entry (32 for values that are not all
// floats) are sorted one at a time with 2 bytes an entry, computing each key twice (slower).
IntervalTree build_interval_tree(const TetGrid& grid, std::uint32_t depth = kDefaultTreeDepth,
                                 std::size_t scratch_bytes = kDefaultIndexScratch);

// What build_interval_tree(grid, depth) gives, known without building it: its depth and its
// entries (the non-constant tetrahedra), for the statistics of a grid whose file leaves the index
// to loading (prepare_to_file). Two reads of the tetrahedra, parallel.
struct IntervalTreeShape {
  std::uint32_t depth = 0;
  std::uint64_t entries = 0;
  std::size_t nodes() const { return (std::size_t{2} << depth) - 1; }
};
IntervalTreeShape interval_tree_shape(const TetGrid& grid, std::uint32_t depth = kDefaultTreeDepth);
// The same from counts taken as the tetrahedra pass by, none of them kept (prepare_to_file writes
// them straight into the file): of `tets` tetrahedra, `entries` are non-constant, and `sampled` of
// those have an id that is a multiple of interval_tree_sample_stride(tets).
std::size_t interval_tree_sample_stride(std::uint64_t tets);
IntervalTreeShape interval_tree_shape(std::uint64_t tets, std::uint64_t entries, std::uint64_t sampled, std::uint32_t depth);

// Checks a tree loaded from disk against its grid: sizes, ranges nested in pre-order, every
// non-constant tetrahedron exactly once in each list, lists sorted, entries straddling their split.
// Throws InputError(what + ...) on the first violation. Reports "check index" progress.
void validate_interval_tree(const IntervalTree& tree, const TetGrid& grid, const std::string& what, const Progress& progress = {});

// Recomputes the derived per-node bounds (lo, hi) of a tree whose splits and lists were loaded.
void finish_interval_tree(IntervalTree& tree, const TetGrid& grid);

struct SweepState {
  double iso = 0;
  bool valid = false;               // false until the first sweep_to
  std::vector<std::uint32_t> pmin;  // per node: entries of by_min with tmin < iso
  std::vector<std::uint32_t> pmax;  // per node: entries of by_max with tmax < iso
  std::vector<std::uint8_t> flags;  // per tetrahedron: bit 0 tmin < iso, bit 1 tmax >= iso
  std::uint64_t walked = 0;         // list entries visited by the last sweep (statistics)
  // The entries the last (non-initial) sweep walked on the side that can make a tetrahedron active
  // (by minimum when the iso-value rose, by maximum when it fell), each tetrahedron at most once,
  // in node pre-order: the tetrahedra that became active are exactly those of them whose flags are
  // now 3, so a client updates its active set in O(changes). Incomplete (and cleared) once there
  // would be more than entering_limit of them, or after the initial sweep.
  std::vector<std::uint32_t> entering;
  bool entering_complete = false;
  std::size_t entering_limit = ~std::size_t{0};
};

// Moves the state to iso: the first call initialises every node (binary searches, O(T)); later
// calls walk only the entries whose tmin or tmax lies between the old and the new value, in the
// nodes whose subtree range meets that interval.
void sweep_to(const IntervalTree& tree, const TetGrid& grid, SweepState& state, double iso);

// The active tetrahedra of a swept state, appended to out in a deterministic order (root to leaf,
// list order within a node): prefixes and suffixes of the lists on the path, flags in the leaf.
void active_tetrahedra(const IntervalTree& tree, const SweepState& state, std::vector<std::uint32_t>& out);

// A fresh query without a state: binary searches on the root-to-leaf path. Same order as above.
void query_active(const IntervalTree& tree, const TetGrid& grid, double iso, std::vector<std::uint32_t>& out);

// The reference: test every tetrahedron (parallel), ascending ids, the order a fresh sweep's
// tetrahedra are marched in. For a few iso-values it costs less than building the index would
// (extractor.hpp: extract_scanned).
void scan_active(const TetGrid& grid, double iso, std::vector<std::uint32_t>& out);

}  // namespace adaptiso
