// Tetrahedral grid (§2.2–2.3): Delaunay property checked with CGAL's exact kernel (Epeck, not the
// triangulation's), tiling of the box in exact integer arithmetic, orientation, vertex use,
// gradients of analytic fields, the grid file's round trip and its refusal of damaged files.
#include <gtest/gtest.h>

#include <CGAL/Exact_predicates_exact_constructions_kernel.h>

#include <map>
#include <random>
#include <set>

#include "adaptiso/gradients.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/tetrahedralize.hpp"
#include "adaptiso/volume_io.hpp"
#include <nlohmann/json.hpp>
#include <numeric>

#include "test_util.hpp"

using namespace adaptiso;
using EK = CGAL::Exact_predicates_exact_constructions_kernel;

namespace {

TetGrid build(const Volume& v, const std::vector<std::int64_t>& kept) { return testutil::build_grid(v, kept); }

// The int16 sphere reduced at an absolute error bound, tetrahedralized with gradients.
TetGrid reduced_sphere_grid(int size, double max_error) {
  Volume s = make_synthetic("sphere", size, ScalarType::i16);
  ReduceOptions o;
  o.max_error = max_error;
  return build(s, reduce(s, o).kept);
}

EK::Point_3 ept(const TetGrid& g, std::uint32_t v) {
  // Exact grid-frame coordinates: spacing · index computed in exact arithmetic from the doubles.
  return EK::Point_3(EK::FT(g.source.spacing[0]) * static_cast<int>(g.ijk[v][0]),
                     EK::FT(g.source.spacing[1]) * static_cast<int>(g.ijk[v][1]),
                     EK::FT(g.source.spacing[2]) * static_cast<int>(g.ijk[v][2]));
}

// Checks every invariant of a grid; returns the number of interior faces checked.
std::size_t check_grid(const Volume& v, const TetGrid& g) {
  // Orientation and tiling, exactly.
  EK::FT total = 0;
  std::vector<int> used(g.vertex_count(), 0);
  for (const auto& t : g.tets) {
    auto o = CGAL::orientation(ept(g, t[0]), ept(g, t[1]), ept(g, t[2]), ept(g, t[3]));
    EXPECT_EQ(o, CGAL::POSITIVE);
    total += CGAL::volume(ept(g, t[0]), ept(g, t[1]), ept(g, t[2]), ept(g, t[3]));
    total.exact();  // collapse the lazy expression DAG (it would otherwise grow one level per tet)
    for (auto x : t) used[x] = 1;
  }
  EK::FT box = EK::FT(v.spacing[0]) * static_cast<int>(v.dims[0] - 1) * EK::FT(v.spacing[1]) * static_cast<int>(v.dims[1] - 1) *
               EK::FT(v.spacing[2]) * static_cast<int>(v.dims[2] - 1);
  EXPECT_TRUE(total == box) << CGAL::to_double(total) << " vs " << CGAL::to_double(box);
  EXPECT_EQ(std::count(used.begin(), used.end(), 0), 0) << "unused vertices";
  // Delaunay: for each interior face, the far vertex of the other tet is not strictly inside.
  std::map<std::array<std::uint32_t, 3>, std::vector<std::pair<std::size_t, int>>> faces;
  for (std::size_t i = 0; i < g.tets.size(); ++i)
    for (int f = 0; f < 4; ++f) {
      std::array<std::uint32_t, 3> k;
      int n = 0;
      for (int j = 0; j < 4; ++j)
        if (j != f) k[n++] = g.tets[i][j];
      std::sort(k.begin(), k.end());
      faces[k].push_back({i, f});
    }
  std::size_t interior = 0;
  for (const auto& [k, ts] : faces) {
    EXPECT_LE(ts.size(), 2u);
    if (ts.size() != 2) continue;
    ++interior;
    const auto& t = g.tets[ts[0].first];
    std::uint32_t opp = g.tets[ts[1].first][ts[1].second];
    auto s = CGAL::side_of_oriented_sphere(ept(g, t[0]), ept(g, t[1]), ept(g, t[2]), ept(g, t[3]), ept(g, opp));
    EXPECT_NE(s, CGAL::ON_POSITIVE_SIDE) << "face " << k[0] << "," << k[1] << "," << k[2];
  }
  return interior;
}

// A random subset of the voxels (about one in `every`) plus the 8 corners, sorted.
std::vector<std::int64_t> random_kept(const Volume& v, std::mt19937& rng, unsigned every) {
  std::vector<std::int64_t> kept;
  for (std::int64_t i = 0; i < v.voxel_count(); ++i)
    if (rng() % every == 0) kept.push_back(i);
  auto c = volume_corners(v);
  std::vector<std::int64_t> k;
  std::set_union(kept.begin(), kept.end(), c.begin(), c.end(), std::back_inserter(k));
  return k;
}

std::vector<std::int64_t> all_voxels(const Volume& v) {
  std::vector<std::int64_t> k(static_cast<std::size_t>(v.voxel_count()));
  std::iota(k.begin(), k.end(), 0);
  return k;
}

}  // namespace

TEST(Delaunay, FullLatticeManyCosphericalPoints) {
  Volume v = make_volume({6, 5, 4}, ScalarType::f32);
  v.spacing = {1.0, 0.5, 2.5};
  TetGrid g = build(v, all_voxels(v));
  EXPECT_GT(check_grid(v, g), 100u);
  EXPECT_EQ(g.vertex_count(), 120u);
}

TEST(Delaunay, RandomLatticeSubsets) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 5; ++trial) {
    Volume v = make_volume({9, 7, 8}, ScalarType::f32);
    TetGrid g = build(v, random_kept(v, rng, 4));
    check_grid(v, g);
  }
}

TEST(Delaunay, PaperSphereAndRealKeptSets) {
  Volume s = make_synthetic("sphere", 50, ScalarType::i16);
  ReduceOptions o;
  o.max_error = 0.15;
  o.relative = true;
  auto r = reduce(s, o);
  check_grid(s, build(s, r.kept));
  REQUIRE_DATA(data);
  Volume m = read_volume(data + "/mr_head_HeadMRVolume/HeadMRVolume.mhd");
  o.max_error = 0.05;
  auto rm = reduce(m, o);
  check_grid(m, build(m, rm.kept));
}

TEST(Delaunay, FlatVolumeIsRefused) {
  Volume v = make_volume({5, 5, 1}, ScalarType::f32);
  TetGrid g;
  g.source.dims = v.dims;
  EXPECT_THROW(tetrahedralize(v, all_voxels(v), g), InputError);
}

TEST(Gradients, LinearFieldIsExact) {
  Volume v = make_volume({9, 8, 7}, ScalarType::f64);
  v.spacing = {0.5, 1.0, 2.0};
  for (std::int64_t z = 0; z < 7; ++z)
    for (std::int64_t y = 0; y < 8; ++y)
      for (std::int64_t x = 0; x < 9; ++x) v.set(v.index(x, y, z), 3 + 2 * (0.5 * x) - 1.5 * y + 0.25 * (2.0 * z));
  std::mt19937 rng(2);
  TetGrid g = build(v, random_kept(v, rng, 3));
  for (const auto& gr : g.gradients) {
    EXPECT_NEAR(gr[0], 2.0, 1e-5);
    EXPECT_NEAR(gr[1], -1.5, 1e-5);
    EXPECT_NEAR(gr[2], 0.25, 1e-5);
  }
  // And the piecewise-linear reconstruction of a linear field is exact everywhere.
  auto e = piecewise_linear_error(v, g);
  EXPECT_LT(e.max, 1e-9);
  EXPECT_EQ(e.voxels, v.voxel_count());
}

TEST(Gradients, QuadraticFieldCloseToAnalytic) {
  const std::int64_t n = 21;
  Volume v = make_volume({n, n, n}, ScalarType::f64);
  for (std::int64_t z = 0; z < n; ++z)
    for (std::int64_t y = 0; y < n; ++y)
      for (std::int64_t x = 0; x < n; ++x) v.set(v.index(x, y, z), 0.01 * (x * x + 2.0 * y * y) + 0.5 * z);
  TetGrid g = build(v, all_voxels(v));
  double worst = 0;
  for (std::size_t i = 0; i < g.vertex_count(); ++i) {
    const auto& p = g.ijk[i];
    if (p[0] == 0 || p[1] == 0 || p[2] == 0 || p[0] == n - 1 || p[1] == n - 1 || p[2] == n - 1) continue;  // one-sided at the border
    worst = std::max({worst, std::abs(g.gradients[i][0] - 0.02 * p[0]), std::abs(g.gradients[i][1] - 0.04 * p[1]),
                      std::abs(g.gradients[i][2] - 0.5)});
  }
  EXPECT_LT(worst, 0.05);  // second-order terms over a 1-voxel ring
}

TEST(GridFile, RoundTripIsBitIdentical) {
  testutil::TempDir t("grid");
  TetGrid g = reduced_sphere_grid(20, 30);
  IntervalTree idx = build_interval_tree(g, 5);
  save_grid(g, t / "a.adg", "{}", &idx);
  IntervalTree loaded;
  TetGrid h = load_grid(t / "a.adg", nullptr, &loaded);
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
  EXPECT_EQ(h.ijk, g.ijk);
  EXPECT_EQ(h.values, g.values);
  EXPECT_EQ(h.gradients, g.gradients);
  EXPECT_EQ(h.tets, g.tets);
  EXPECT_EQ(h.source.dims, g.source.dims);
  save_grid(h, t / "b.adg", "{}", &loaded);
  EXPECT_EQ(testutil::read_bytes(t / "a.adg"), testutil::read_bytes(t / "b.adg"));
}

TEST(GridFile, EveryTruncationAndRandomCorruptionIsRefused) {
  testutil::TempDir t("gridbad");
  TetGrid g = reduced_sphere_grid(8, 50);
  IntervalTree idx = build_interval_tree(g, 3);
  save_grid(g, t / "a.adg", "{}", &idx);
  IntervalTree loaded;
  ASSERT_NO_THROW(load_grid(t / "a.adg", nullptr, &loaded));
  const std::string full = testutil::read_bytes(t / "a.adg");
  for (std::size_t len = 0; len < full.size(); ++len) {
    testutil::write_bytes(t / "t.adg", full.substr(0, len));
    EXPECT_THROW(load_grid(t / "t.adg", nullptr, &loaded), InputError) << "length " << len;
  }
  std::mt19937 rng(9);
  for (int trial = 0; trial < 300; ++trial) {
    std::string c = full;
    int flips = 1 + static_cast<int>(rng() % 4);
    for (int f = 0; f < flips; ++f) c[rng() % c.size()] ^= static_cast<char>(1 + rng() % 255);
    testutil::write_bytes(t / "c.adg", c);
    EXPECT_THROW(load_grid(t / "c.adg", nullptr, &loaded), InputError) << "trial " << trial;
  }
  testutil::write_bytes(t / "f.adg", "hello, not a grid at all, but long enough to have a header.............");
  EXPECT_THROW(load_grid(t / "f.adg"), InputError);
}

TEST(PrepareCli, JsonFieldsAndExport) {
  testutil::TempDir t("prep");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 30 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("prepare " + (t / "s.nrrd") + " --max-error 0.15 --relative --json -o " + (t / "s.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  for (const char* k : {"voxels", "kept", "tetrahedra", "pl_max_error", "pl_rms_error", "seconds"}) EXPECT_TRUE(j.contains(k)) << k;
  for (const char* k : {"reduce", "tetrahedralize", "gradients"}) EXPECT_TRUE(j["seconds"].contains(k)) << k;
  EXPECT_EQ(testutil::run_cli("export " + (t / "s.adg") + " -o " + (t / "s.vtu")).code, 0);
  EXPECT_EQ(testutil::run_cli("export " + (t / "s.adg") + " -o " + (t / "s.ply")).code, 0);
  testutil::write_bytes(t / "bad.adg", "garbage");
  auto bad = testutil::run_cli("export " + (t / "bad.adg") + " -o " + (t / "x.vtu"));
  EXPECT_EQ(bad.code, 2);
  EXPECT_FALSE(std::filesystem::exists(t / "x.vtu"));
}

TEST(GridFile, FilesWithoutAnIndexAndVersion1FilesGetOneBuiltOnLoad) {
  testutil::TempDir t("gridv1");
  TetGrid g = reduced_sphere_grid(12, 40);
  save_grid(g, t / "plain.adg");  // version 2 without the index
  IntervalTree idx;
  TetGrid h = load_grid(t / "plain.adg", nullptr, &idx);
  IntervalTree expect = build_interval_tree(h);
  EXPECT_EQ(idx.by_min, expect.by_min);
  EXPECT_EQ(idx.by_max, expect.by_max);
  // The same content as a version 1 file: 48-byte header, version 1, flags 0, fresh checksum.
  const std::string v2 = testutil::read_bytes(t / "plain.adg");
  std::string v1 = v2.substr(0, 48) + v2.substr(64, v2.size() - 64 - 4);
  const std::uint32_t one = 1;
  std::memcpy(v1.data() + 16, &one, 4);
  const std::uint32_t crc = static_cast<std::uint32_t>(crc32(crc32(0, nullptr, 0), reinterpret_cast<const Bytef*>(v1.data()),
                                                             static_cast<uInt>(v1.size())));
  v1.append(reinterpret_cast<const char*>(&crc), 4);
  testutil::write_bytes(t / "v1.adg", v1);
  IntervalTree idx1;
  TetGrid h1 = load_grid(t / "v1.adg", nullptr, &idx1);
  EXPECT_EQ(h1.tets, g.tets);
  EXPECT_EQ(idx1.by_min, expect.by_min);
  std::string bad = v1;
  bad[20] = 1;  // a version 1 file cannot announce an index
  testutil::write_bytes(t / "v1bad.adg", bad);
  EXPECT_THROW(load_grid(t / "v1bad.adg", nullptr, &idx1), InputError);
}
