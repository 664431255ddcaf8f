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
#include "adaptiso/prepare_to_file.hpp"

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "io/grid_file_sections.hpp"
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
// stages come in order: read, check the grid, build the index or check a stored one (a load in
// part skips the index).
TEST(GridFile, LoadingReportsReadAndCheckProgressInOrder) {
  testutil::TempDir t("gridprogress");
  PrepareOptions o;
  o.max_error = 0.01;
  const PreparedGrid p = prepare(make_synthetic("marschner-lobb", 33, ScalarType::f32), o);
  save_grid(p, t / "g.adg");
  save_grid(p, t / "indexed.adg", true);
  const PreparedGrid delaunay = reduced_sphere_grid(20, 30, 5);
  save_grid(delaunay, t / "d.adg");
  struct Case {
    std::string file;
    GridParts parts;
    std::vector<std::string> stages;
  };
  for (const Case& c : {Case{"g.adg", GridParts::all, {"read grid", "check grid", "build index"}},
                        Case{"indexed.adg", GridParts::all, {"read grid", "check grid", "check index"}},
                        Case{"g.adg", GridParts::hierarchy, {"read grid", "check grid"}},
                        Case{"d.adg", GridParts::all, {"read grid", "check grid", "build index"}}}) {
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

// Grid files leave their index out (version 6): prepare_to_file does not build it, and loading
// builds the one prepare() would have, at the depth the file gives (a depth other than the default
// here), faster than it would check a stored one (grid_file.hpp). The file is smaller by the index.
TEST(GridFile, PreparedFilesLeaveTheIndexOutAndLoadingBuildsItAtTheirDepth) {
  testutil::TempDir t("grid_unindexed");
  for (const GridKind kind : {GridKind::bisection, GridKind::delaunay}) {
    PrepareOptions o;
    o.grid = kind;
    o.max_error = 0.02;
    o.relative = true;
    o.tree_depth = 7;
    const Volume v = make_synthetic("marschner-lobb", 24, ScalarType::f32);
    const PreparedGrid reference = prepare(v, o);
    ASSERT_GT(reference.index.entries(), 0u);
    const PrepareStats st = prepare_to_file(v, o, t / "p.adg");
    EXPECT_TRUE(std::none_of(st.stages.begin(), st.stages.end(), [](const auto& s) { return s.name == "index"; }));
    const auto sections = detail::GridSections::parse(testutil::read_bytes(t / "p.adg"));
    ASSERT_TRUE(sections);
    EXPECT_EQ(sections->version, 6u);
    EXPECT_EQ(sections->flags & detail::GridSections::kHasIndex, 0u);
    EXPECT_EQ(sections->depth, 7u);
    EXPECT_TRUE(sections->by_min.empty() && sections->nodes.empty());
    const PreparedGrid loaded = load_grid(t / "p.adg");
    EXPECT_EQ(loaded.grid.tets, reference.grid.tets);
    EXPECT_EQ(loaded.index.depth, reference.index.depth);
    EXPECT_EQ(loaded.index.by_min, reference.index.by_min);
    EXPECT_EQ(loaded.index.by_max, reference.index.by_max);
    ASSERT_EQ(loaded.index.nodes.size(), reference.index.nodes.size());
    for (std::size_t i = 0; i < loaded.index.nodes.size(); ++i) {
      EXPECT_EQ(loaded.index.nodes[i].split, reference.index.nodes[i].split);
      EXPECT_EQ(loaded.index.nodes[i].begin, reference.index.nodes[i].begin);
      EXPECT_EQ(loaded.index.nodes[i].end, reference.index.nodes[i].end);
    }
    // Saved with its index a grid is larger by exactly the index, and loads the same index.
    save_grid(reference, t / "indexed.adg", true);
    save_grid(reference, t / "unindexed.adg");
    EXPECT_EQ(std::filesystem::file_size(t / "indexed.adg") - std::filesystem::file_size(t / "unindexed.adg"),
              reference.index.nodes.size() * 24 + reference.index.entries() * 8);
    EXPECT_EQ(load_grid(t / "indexed.adg").index.by_min, reference.index.by_min);
    EXPECT_EQ(load_grid(t / "unindexed.adg").index.by_max, reference.index.by_max);
  }
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(t.path), std::filesystem::directory_iterator{}), 3);  // no temporaries
}

// GridParts::tetrahedra (export to .vtu): the whole load's grid without building an index, a
// stored one checksummed but not kept; an Extractor refuses such a grid. A constant volume's grid
// (no index entries) still gets a root, so the refusal is not of an empty index.
TEST(GridFile, TetrahedraWithoutTheIndexAreTheWholeLoadsGrid) {
  testutil::TempDir t("grid_tets");
  PrepareOptions o;
  o.max_error = 0.02;
  o.relative = true;
  const PreparedGrid p = prepare(make_synthetic("marschner-lobb", 20, ScalarType::f32), o);
  save_grid(p, t / "g.adg");
  save_grid(p, t / "indexed.adg", true);
  for (const char* file : {"g.adg", "indexed.adg"}) {
    const PreparedGrid whole = load_grid(t / file);
    std::vector<std::string> stages;
    const auto tets = std::make_shared<const PreparedGrid>(load_grid(t / file, GridParts::tetrahedra, [&](std::string_view s, double) {
      if (stages.empty() || stages.back() != s) stages.emplace_back(s);
    }));
    EXPECT_EQ(stages, (std::vector<std::string>{"read grid", "check grid"})) << file;
    EXPECT_EQ(tets->grid.tets, whole.grid.tets) << file;
    EXPECT_EQ(tets->grid.values, whole.grid.values) << file;
    EXPECT_EQ(tets->hierarchy->value_span, whole.hierarchy->value_span) << file;
    EXPECT_TRUE(tets->index.nodes.empty() && tets->index.by_min.empty()) << file;
    EXPECT_FALSE(loaded_in_part(*tets));
    EXPECT_THROW(Extractor{tets}, std::invalid_argument) << file;
  }
  // A stored index is not looked at (a lie in it, with its checksum made to match, loads here and
  // is refused by the whole load), but damage to it still fails the checksum.
  auto lying = detail::GridSections::parse(testutil::read_bytes(t / "indexed.adg"));
  ASSERT_TRUE(lying && lying->by_min.size() >= 8);
  std::swap_ranges(lying->by_min.begin(), lying->by_min.begin() + 4, lying->by_min.end() - 4);
  testutil::write_bytes(t / "lying.adg", lying->assemble());
  EXPECT_THROW(load_grid(t / "lying.adg"), InputError);
  EXPECT_EQ(load_grid(t / "lying.adg", GridParts::tetrahedra).grid.tets, p.grid.tets);
  std::string bytes = testutil::read_bytes(t / "indexed.adg");
  bytes[bytes.size() - 4 - p.hierarchy->value_span.size() * 8 - p.hierarchy->error_code.size() - 40 - 3] ^= 0x20;
  testutil::write_bytes(t / "damaged.adg", bytes);
  EXPECT_THROW(load_grid(t / "damaged.adg", GridParts::tetrahedra), InputError);
  Volume constant = make_volume({6, 5, 4}, ScalarType::f32);
  for (std::size_t i = 0; i < 6 * 5 * 4; ++i) constant.set(static_cast<std::int64_t>(i), 2.0);
  const auto flat = std::make_shared<const PreparedGrid>(prepare(constant, o));
  EXPECT_EQ(flat->index.entries(), 0u);
  EXPECT_NO_THROW(Extractor{flat});
}

// The depth of an index to build is read from version 6 on, up to 24 (a deeper one would allocate
// 2^26 nodes and more for nothing); a version 5 file without its index gives none, and builds it at
// the default depth as it always did.
TEST(GridFile, DepthWithoutAnIndexIsReadFromVersion6UpTo24) {
  testutil::TempDir t("grid_depth");
  PrepareOptions o;
  o.max_error = 0.02;
  o.relative = true;
  o.tree_depth = 7;
  const Volume v = make_synthetic("marschner-lobb", 24, ScalarType::f32);
  prepare_to_file(v, o, t / "p.adg");
  const auto honest = detail::GridSections::parse(testutil::read_bytes(t / "p.adg"));
  ASSERT_TRUE(honest);
  auto with = [&](std::uint32_t version, std::uint32_t depth) {
    detail::GridSections s = *honest;
    s.version = version;
    s.depth = depth;
    testutil::write_bytes(t / "m.adg", s.assemble());
    return t / "m.adg";
  };
  const PreparedGrid grid = load_grid(t / "p.adg");
  EXPECT_EQ(load_grid(with(6, 24)).index.by_min, build_interval_tree(grid.grid, 24).by_min);
  EXPECT_EQ(load_grid(with(5, 0)).index.depth, build_interval_tree(grid.grid, kDefaultTreeDepth).depth);
  for (const auto& [version, depth] : {std::pair{6u, 25u}, std::pair{6u, 31u}, std::pair{5u, 7u}, std::pair{6u, ~0u}}) {
    try {
      load_grid(with(version, depth));
      ADD_FAILURE() << "version " << version << " depth " << depth << " loaded";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("bad header flags"), std::string::npos) << e.what();
    }
  }
}
