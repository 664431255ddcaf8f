// prepare() as a whole: what it reports about memory, taking the volume, and writing the grid
// file as it is made (prepare_to_file).
#include <gtest/gtest.h>
#include <sys/mman.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "adaptiso/error.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/prepare_to_file.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

// The process's resident peak (VmHWM), 0 where /proc does not tell.
std::uint64_t process_peak() {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("VmHWM:", 0) == 0) return std::strtoull(line.c_str() + 6, nullptr, 10) * 1024;
  return 0;
}

// Raises the process's peak by `bytes` for a moment: mapped, written, unmapped.
void touch_and_release(std::size_t bytes) {
  void* p = mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  ASSERT_NE(p, MAP_FAILED);
  std::memset(p, 1, bytes);
  munmap(p, bytes);
}

}  // namespace

// prepare used to reset the kernel's peak (writing 5 to /proc/self/clear_refs) to time each
// stage's own, which also reset what getrusage, time(1) and a parent's wait4 report: the bunny's
// 2.8 GB peak, in the index, read as 2.0 GB. The process's peak must survive a prepare, and the
// stages' figures are the peak so far.
TEST(Prepare, LeavesTheProcessPeakMemoryReadingAlone) {
  if (process_peak() == 0) GTEST_SKIP() << "no VmHWM in /proc/self/status";
  touch_and_release(std::size_t{256} << 20);
  const std::uint64_t before = process_peak();
  PrepareOptions o;
  o.max_error = 0.05;
  o.relative = true;
  const PreparedGrid p = prepare(make_synthetic("sphere", 17, ScalarType::f32), o);
  EXPECT_GE(process_peak(), before);
  ASSERT_FALSE(p.stats.stages.empty());
  std::uint64_t previous = before;
  for (const auto& st : p.stats.stages) {
    EXPECT_GE(st.peak_bytes, previous) << st.name;
    previous = st.peak_bytes;
  }
}

// Taking the volume frees its voxels (before the index) and gives the same grid as lending it.
TEST(Prepare, TakingTheVolumeReleasesItsVoxelsAndGivesTheSameGrid) {
  PrepareOptions o;
  o.max_error = 0.02;
  o.relative = true;
  Volume v = make_synthetic("marschner-lobb", 20, ScalarType::f32);
  const PreparedGrid lent = prepare(v, o);
  const Dims dims = v.dims;
  const PreparedGrid taken = prepare(std::move(v), o);
  EXPECT_TRUE(v.bytes.empty());  // NOLINT(bugprone-use-after-move): released on purpose
  EXPECT_EQ(v.dims, dims);
  EXPECT_EQ(taken.grid.tets, lent.grid.tets);
  EXPECT_EQ(taken.grid.values, lent.grid.values);
  EXPECT_EQ(taken.grid.gradients, lent.grid.gradients);
  EXPECT_EQ(taken.index.by_min, lent.index.by_min);
  EXPECT_EQ(taken.stats.voxels, lent.stats.voxels);
}

// prepare_without_index then add_index is prepare: the same grid, index and index figures, on both
// grids, at a reduced tree depth and on a constant volume (no entries, an empty index); before
// add_index the figures are already the index's, and add_index does nothing twice.
TEST(Prepare, WithoutTheIndexThenAddingItIsPrepare) {
  struct Case {
    const char* name;
    Volume v;
    GridKind grid;
    std::uint32_t depth;
  };
  Volume flat = make_volume({9, 8, 7}, ScalarType::f32);  // zeros
  Case cases[] = {{"bisection", make_synthetic("marschner-lobb", 19, ScalarType::u16), GridKind::bisection, kDefaultTreeDepth},
                  {"bisection, depth 3", make_synthetic("sphere", 21, ScalarType::f32), GridKind::bisection, 3},
                  {"delaunay", make_synthetic("sphere", 17, ScalarType::f32), GridKind::delaunay, kDefaultTreeDepth},
                  {"constant", std::move(flat), GridKind::bisection, kDefaultTreeDepth}};
  for (Case& c : cases) {
    SCOPED_TRACE(c.name);
    PrepareOptions o;
    o.grid = c.grid;
    o.max_error = 0.05;
    o.relative = true;
    o.tree_depth = c.depth;
    const PreparedGrid full = prepare(c.v, o);
    PreparedGrid lazy = prepare_without_index(c.v, o);
    EXPECT_TRUE(lazy.index.nodes.empty());
    EXPECT_EQ(lazy.grid.tets, full.grid.tets);
    EXPECT_EQ(lazy.stats.index_depth, full.stats.index_depth);
    EXPECT_EQ(lazy.stats.grid_bytes_per_vertex, full.stats.grid_bytes_per_vertex);
    EXPECT_EQ(lazy.stats.tree_depth, full.stats.tree_depth);
    for (const auto& st : lazy.stats.stages) EXPECT_NE(st.name, "index");
    add_index(lazy);
    add_index(lazy);
    EXPECT_EQ(lazy.index.depth, full.index.depth);
    EXPECT_EQ(lazy.index.nodes.size(), full.index.nodes.size());
    EXPECT_EQ(lazy.index.by_min, full.index.by_min);
    EXPECT_EQ(lazy.index.by_max, full.index.by_max);
    EXPECT_EQ(lazy.stats.index_depth, full.stats.index_depth);
    EXPECT_EQ(lazy.stats.grid_bytes_per_vertex, full.stats.grid_bytes_per_vertex);
  }
}

// prepare_to_file writes the grid without building its index: the file must be
// save_grid(prepare(...))'s (which leaves the index out too), byte for byte, on both grids, with the
// displacement criterion, on values that are not floats (the index's double keys), on a constant
// volume (no index entries), on a single cell, a 2-voxel slab and an odd anisotropic box, at a reduced
// and an unreduced tree depth; and the statistics must be prepare's.
TEST(PrepareToFile, WritesTheBytesOfPrepareThenSave) {
  testutil::TempDir dir("prepare_to_file");
  struct Case {
    std::string name;
    Volume volume;
    PrepareOptions options;
  };
  auto options = [](GridKind grid, double max_error, double displacement = 0, std::uint32_t depth = kDefaultTreeDepth) {
    PrepareOptions o;
    o.grid = grid;
    o.max_error = max_error;
    o.relative = true;
    o.max_displacement = displacement;
    o.tree_depth = depth;
    return o;
  };
  Volume slab = testutil::pattern_volume({9, 7, 2}, ScalarType::i16);
  Volume odd = testutil::pattern_volume({6, 11, 5}, ScalarType::u8);
  odd.spacing = {0.5, 1.0, 2.5};
  Volume constant = make_volume({5, 5, 5}, ScalarType::f32);
  std::vector<Case> cases;
  cases.push_back({"sphere bisection", make_synthetic("sphere", 17, ScalarType::i16), options(GridKind::bisection, 0.05)});
  cases.push_back({"marschner-lobb f64", make_synthetic("marschner-lobb", 20, ScalarType::f64), options(GridKind::bisection, 0.02)});
  cases.push_back({"displacement", make_synthetic("marschner-lobb", 16, ScalarType::f32), options(GridKind::bisection, 0.1, 0.5)});
  cases.push_back({"delaunay", make_synthetic("sphere", 12, ScalarType::f32), options(GridKind::delaunay, 0.1)});
  cases.push_back({"depth 3", make_synthetic("torus", 16, ScalarType::f32), options(GridKind::bisection, 0.05, 0, 3)});
  cases.push_back({"slab", std::move(slab), options(GridKind::bisection, 0)});
  cases.push_back({"odd anisotropic", std::move(odd), options(GridKind::bisection, 0.1)});
  cases.push_back({"constant", std::move(constant), options(GridKind::bisection, 0)});
  cases.push_back({"one cell", make_volume({2, 2, 2}, ScalarType::u8), options(GridKind::bisection, 0)});
  for (auto& c : cases) {
    SCOPED_TRACE(c.name);
    const PreparedGrid p = prepare(c.volume, c.options);
    const std::string saved = (dir.path / "saved.adg").string(), streamed = (dir.path / "streamed.adg").string();
    save_grid(p, saved);
    const PrepareStats stats = prepare_to_file(std::move(c.volume), c.options, streamed);
    EXPECT_TRUE(c.volume.bytes.empty());  // NOLINT(bugprone-use-after-move): released on purpose
    EXPECT_TRUE(testutil::read_bytes(streamed) == testutil::read_bytes(saved));
    EXPECT_EQ(stats.index_depth, p.stats.index_depth);
    EXPECT_EQ(stats.grid_bytes_per_vertex, p.stats.grid_bytes_per_vertex);
    EXPECT_EQ(stats.kept, p.stats.kept);
    EXPECT_EQ(stats.tetrahedra, p.stats.tetrahedra);
    EXPECT_GT(stats.seconds("save"), 0);
    EXPECT_EQ(stats.seconds("index"), 0);  // not built
  }
}

// A bisection grid's tetrahedra go into the file in pieces of 4 M as the selection makes them, and
// the index's figures are counted as they pass, its sample then every third tetrahedron: more
// than one piece must still give save_grid(prepare(...))'s bytes and prepare's figures.
TEST(PrepareToFile, AGridOfSeveralPiecesIsTheSavedGridWithTheIndexFigures) {
  testutil::TempDir dir("prepare_to_file_pieces");
  Volume v = make_volume({90, 90, 90}, ScalarType::u8);
  std::uint32_t x = 12345;
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) {
    x = x * 1664525u + 1013904223u;
    v.set(i, (x >> 24) & 0x1f);  // a few values, so some tetrahedra are constant
  }
  PrepareOptions o;
  o.max_error = 0;
  const PreparedGrid p = prepare(v, o);
  ASSERT_GT(p.grid.tet_count(), BisectionOptions{}.piece);
  const PrepareStats stats = prepare_to_file(v, o, (dir.path / "streamed.adg").string());
  save_grid(p, (dir.path / "saved.adg").string());
  EXPECT_TRUE(testutil::read_bytes(dir.path / "streamed.adg") == testutil::read_bytes(dir.path / "saved.adg"));
  EXPECT_EQ(stats.tetrahedra, p.stats.tetrahedra);
  EXPECT_EQ(stats.index_depth, p.stats.index_depth);
  EXPECT_EQ(stats.grid_bytes_per_vertex, p.stats.grid_bytes_per_vertex);
  EXPECT_LT(p.index.entries(), p.grid.tet_count());
}

// Bad options and an unwritable path fail as prepare and save_grid do (the path before any work),
// and leave no file behind.
TEST(PrepareToFile, FailuresLeaveNoFile) {
  testutil::TempDir dir("prepare_to_file_fail");
  PrepareOptions bad;
  bad.max_error = -1;
  EXPECT_THROW(prepare_to_file(make_synthetic("sphere", 9, ScalarType::f32), bad, (dir.path / "a.adg").string()), OptionError);
  EXPECT_THROW(prepare_to_file(make_synthetic("sphere", 9, ScalarType::f32), PrepareOptions{}, (dir.path / "no" / "a.adg").string()),
               InputError);
  EXPECT_TRUE(std::filesystem::is_empty(dir.path));
}
