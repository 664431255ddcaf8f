// The grid file: bit-identical round trips, every truncation and random corruption refused, older
// files (without the index, version 1) still read; written while its index is built, the same bytes.
#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <random>

#include "adaptiso/prepare.hpp"

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "io/grid_file_stream.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

// The int16 sphere reduced at an absolute error bound, tetrahedralized, with its index.
PreparedGrid reduced_sphere_grid(int size, double max_error, std::uint32_t depth = kDefaultTreeDepth) {
  Volume s = make_synthetic("sphere", size, ScalarType::i16);
  ReduceOptions o;
  o.max_error = max_error;
  PreparedGrid p;
  p.grid = testutil::build_grid(s, reduce(s, o).kept);
  p.index = build_interval_tree(p.grid, depth);
  return p;
}

}  // namespace

TEST(GridFile, RoundTripIsBitIdentical) {
  testutil::TempDir t("grid");
  const PreparedGrid p = reduced_sphere_grid(20, 30, 5);
  const TetGrid& grid = p.grid;
  const IntervalTree& idx = p.index;
  save_grid(p, t / "a.adg");
  const PreparedGrid q = load_grid(t / "a.adg");
  const IntervalTree& loaded = q.index;
  const TetGrid& h = q.grid;
  EXPECT_EQ(loaded.depth, idx.depth);
  EXPECT_EQ(loaded.by_min, idx.by_min);
  EXPECT_EQ(loaded.by_max, idx.by_max);
  ASSERT_EQ(loaded.nodes.size(), idx.nodes.size());
  for (std::size_t i = 0; i < idx.nodes.size(); ++i) {
    EXPECT_EQ(loaded.nodes[i].split, idx.nodes[i].split);
    EXPECT_EQ(loaded.nodes[i].begin, idx.nodes[i].begin);
    EXPECT_EQ(loaded.nodes[i].lo, idx.nodes[i].lo);
    EXPECT_EQ(loaded.nodes[i].hi, idx.nodes[i].hi);
  }
  EXPECT_EQ(h.ijk, grid.ijk);
  EXPECT_EQ(h.values, grid.values);
  EXPECT_EQ(h.gradients, grid.gradients);
  EXPECT_EQ(h.tets, grid.tets);
  EXPECT_EQ(h.source.dims, grid.source.dims);
  save_grid(q, t / "b.adg");
  EXPECT_EQ(testutil::read_bytes(t / "a.adg"), testutil::read_bytes(t / "b.adg"));
}

TEST(GridFile, EveryTruncationAndRandomCorruptionIsRefused) {
  testutil::TempDir t("gridbad");
  save_grid(reduced_sphere_grid(8, 50, 3), t / "a.adg");
  ASSERT_NO_THROW(load_grid(t / "a.adg"));
  const std::string full = testutil::read_bytes(t / "a.adg");
  for (std::size_t len = 0; len < full.size(); ++len) {
    testutil::write_bytes(t / "t.adg", full.substr(0, len));
    EXPECT_THROW(load_grid(t / "t.adg"), InputError) << "length " << len;
  }
  std::mt19937 rng(9);
  for (int trial = 0; trial < 300; ++trial) {
    std::string c = full;
    int flips = 1 + static_cast<int>(rng() % 4);
    for (int f = 0; f < flips; ++f) c[rng() % c.size()] ^= static_cast<char>(1 + rng() % 255);
    testutil::write_bytes(t / "c.adg", c);
    EXPECT_THROW(load_grid(t / "c.adg"), InputError) << "trial " << trial;
  }
  testutil::write_bytes(t / "f.adg", "hello, not a grid at all, but long enough to have a header.............");
  EXPECT_THROW(load_grid(t / "f.adg"), InputError);
}

TEST(GridFile, FilesWithoutAnIndexAndVersion1FilesGetOneBuiltOnLoad) {
  testutil::TempDir t("gridv1");
  const PreparedGrid p = reduced_sphere_grid(12, 40);
  const TetGrid& grid = p.grid;
  save_grid(p, t / "plain.adg", false);  // version 2 without the index
  const PreparedGrid q = load_grid(t / "plain.adg");
  const IntervalTree expect = build_interval_tree(q.grid);
  EXPECT_EQ(q.index.by_min, expect.by_min);
  EXPECT_EQ(q.index.by_max, expect.by_max);
  // The same content as a version 1 file: 48-byte header, version 1, flags 0, fresh checksum.
  const std::string v2 = testutil::read_bytes(t / "plain.adg");
  std::string v1 = v2.substr(0, 48) + v2.substr(64, v2.size() - 64 - 4);
  const std::uint32_t one = 1;
  std::memcpy(v1.data() + 16, &one, 4);
  const std::uint32_t crc =
      static_cast<std::uint32_t>(crc32(crc32(0, nullptr, 0), reinterpret_cast<const Bytef*>(v1.data()), static_cast<uInt>(v1.size())));
  v1.append(reinterpret_cast<const char*>(&crc), 4);
  testutil::write_bytes(t / "v1.adg", v1);
  const PreparedGrid q1 = load_grid(t / "v1.adg");
  EXPECT_EQ(q1.grid.tets, grid.tets);
  EXPECT_EQ(q1.index.by_min, expect.by_min);
  std::string bad = v1;
  bad[20] = 1;  // a version 1 file cannot announce an index
  testutil::write_bytes(t / "v1bad.adg", bad);
  EXPECT_THROW(load_grid(t / "v1bad.adg"), InputError);
}

TEST(GridFile, BisectionGridsKeepTheirHierarchy) {
  testutil::TempDir t("gridbis");
  for (double displacement : {0.0, 0.5}) {
    PrepareOptions o;
    o.max_error = 0.03;
    o.max_displacement = displacement;
    const Volume v = make_synthetic("marschner-lobb", 19, ScalarType::f32);
    const PreparedGrid p = prepare(v, o);
    ASSERT_TRUE(p.hierarchy);
    save_grid(p, t / "b.adg");
    const PreparedGrid q = load_grid(t / "b.adg");
    ASSERT_TRUE(q.hierarchy);
    EXPECT_EQ(q.hierarchy->error_code, p.hierarchy->error_code);
    EXPECT_EQ(q.hierarchy->displacement_code, p.hierarchy->displacement_code);
    EXPECT_EQ(q.hierarchy->value_span, p.hierarchy->value_span);
    EXPECT_EQ(q.hierarchy->error_threshold, p.hierarchy->error_threshold);
    EXPECT_EQ(q.hierarchy->root_size, p.hierarchy->root_size);
    EXPECT_EQ(q.hierarchy->codes.scale, p.hierarchy->codes.scale);
    save_grid(q, t / "c.adg");
    EXPECT_EQ(testutil::read_bytes(t / "b.adg"), testutil::read_bytes(t / "c.adg"));
    // Damage anywhere, including the hierarchy at the end, is refused.
    const std::string full = testutil::read_bytes(t / "b.adg");
    std::mt19937 rng(4);
    for (int trial = 0; trial < 100; ++trial) {
      std::string c = full;
      const std::size_t at = trial < 50 ? full.size() - 1 - rng() % std::min<std::size_t>(full.size(), 4000) : rng() % full.size();
      c[at] ^= static_cast<char>(1 + rng() % 255);
      testutil::write_bytes(t / "d.adg", c);
      EXPECT_THROW(load_grid(t / "d.adg"), InputError) << "byte " << at;
    }
    for (std::size_t len : {full.size() - 1, full.size() - 5, full.size() - 1000}) {
      testutil::write_bytes(t / "e.adg", full.substr(0, len));
      EXPECT_THROW(load_grid(t / "e.adg"), InputError) << len;
    }
  }
}

// A load shows its progress: the bunny's default grid took 5 s to load without a word (1 s read,
// 4 s checked). Every stage starts at 0 and ends at 1, its fractions never go back, and the
// stages come in order: read, check the grid, check the index (a load in part skips the index).
TEST(GridFile, LoadingReportsReadAndCheckProgressInOrder) {
  testutil::TempDir t("gridprogress");
  PrepareOptions o;
  o.max_error = 0.01;
  const PreparedGrid p = prepare(make_synthetic("marschner-lobb", 33, ScalarType::f32), o);
  save_grid(p, t / "g.adg");
  const PreparedGrid delaunay = reduced_sphere_grid(20, 30, 5);
  save_grid(delaunay, t / "d.adg");
  struct Case {
    std::string file;
    GridParts parts;
    std::vector<std::string> stages;
  };
  for (const Case& c : {Case{"g.adg", GridParts::all, {"read grid", "check grid", "check index"}},
                        Case{"g.adg", GridParts::hierarchy, {"read grid", "check grid"}},
                        Case{"d.adg", GridParts::all, {"read grid", "check grid", "check index"}}}) {
    std::mutex m;
    std::vector<std::pair<std::string, double>> seen;
    const Progress progress = [&](std::string_view stage, double f) {
      std::lock_guard lock(m);
      seen.emplace_back(std::string(stage), f);
    };
    const PreparedGrid q = load_grid(t / c.file, c.parts, progress);
    std::vector<std::string> stages;
    std::map<std::string, double> last;
    for (const auto& [stage, f] : seen) {
      if (stages.empty() || stages.back() != stage) {
        EXPECT_EQ(std::count(stages.begin(), stages.end(), stage), 0) << c.file << ": " << stage << " came back";
        stages.push_back(stage);
        EXPECT_EQ(f, 0) << c.file << ": " << stage << " starts at " << f;
        last[stage] = 0;
      }
      EXPECT_GE(f, last[stage]) << c.file << ": " << stage;
      EXPECT_LE(f, 1) << c.file << ": " << stage;
      last[stage] = f;
    }
    EXPECT_EQ(stages, c.stages) << c.file;
    for (const auto& stage : c.stages) EXPECT_EQ(last[stage], 1) << c.file << ": " << stage << " ends at " << last[stage];
  }
}

// The grid file written while its index is built (detail::save_grid_building_index, under
// prepare_to_file): the same bytes as save_grid whether the tetrahedra are written before the
// index (little scratch left) or while it is built (plenty), with the grid's arrays freed; an
// index that fails, or does not have the shape promised, leaves no file.
TEST(GridFile, WrittenWhileTheIndexIsBuiltGivesTheSameBytesAndFailsCleanly) {
  testutil::TempDir t("grid_stream");
  PrepareOptions o;
  o.max_error = 0.02;
  o.relative = true;
  const PreparedGrid reference = prepare(make_synthetic("marschner-lobb", 24, ScalarType::f32), o);
  save_grid(reference, t / "saved.adg");
  const IntervalTreeShape shape{reference.index.depth, reference.index.entries()};
  for (const std::size_t left : {std::size_t{0}, std::size_t{1} << 40}) {
    PreparedGrid p = reference;
    p.index = IntervalTree{};
    std::size_t scratch_seen = 0;
    detail::save_grid_building_index(
        p, t / "streamed.adg", shape, [&](std::uint64_t) { return left; },
        [&](const TetGrid& grid, std::size_t scratch) {
          EXPECT_TRUE(grid.ijk.empty() && grid.gradients.empty());  // freed once written
          EXPECT_EQ(grid.tets, reference.grid.tets);
          scratch_seen = scratch;
          return build_interval_tree(grid, o.tree_depth);
        });
    EXPECT_EQ(scratch_seen, left ? left - kAtomicFileBufferBytes : 0);  // the writer's buffers held while it writes
    EXPECT_TRUE(p.grid.tets.empty() && p.grid.values.empty());
    EXPECT_TRUE(testutil::read_bytes(t / "streamed.adg") == testutil::read_bytes(t / "saved.adg")) << "scratch left " << left;
    std::filesystem::remove(t / "streamed.adg");
    for (const bool wrong_shape : {false, true}) {
      PreparedGrid q = reference;
      auto build = [&](const TetGrid& grid, std::size_t) -> IntervalTree {
        if (!wrong_shape) throw InputError("the index failed");
        return build_interval_tree(grid, o.tree_depth + 1);
      };
      auto call = [&] {
        detail::save_grid_building_index(
            q, t / "failed.adg", shape, [&](std::uint64_t) { return left; }, build);
      };
      if (wrong_shape)
        EXPECT_THROW(call(), std::logic_error);
      else
        EXPECT_THROW(call(), InputError);
      EXPECT_FALSE(std::filesystem::exists(t / "failed.adg"));
    }
  }
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(t.path), std::filesystem::directory_iterator{}), 1);  // no temporaries
}
