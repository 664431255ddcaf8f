// The paper's grid (§2.2): the Delaunay property checked with CGAL's exact kernel (Epeck, not the
// triangulation's), tiling of the box in exact arithmetic, orientation, vertex use.
#include <gtest/gtest.h>

#include <CGAL/Exact_predicates_exact_constructions_kernel.h>

#include <map>
#include <random>
#include <set>

#include "adaptiso/delaunay.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/volume_io.hpp"
#include "test_util.hpp"

using namespace adaptiso;
using EK = CGAL::Exact_predicates_exact_constructions_kernel;

namespace {

TetGrid build(const Volume& v, const std::vector<std::int64_t>& kept) { return testutil::build_grid(v, kept); }

EK::Point_3 ept(const TetGrid& grid, std::uint32_t v) {
  // Exact grid-frame coordinates: spacing · index computed in exact arithmetic from the doubles.
  return EK::Point_3(EK::FT(grid.source.spacing[0]) * static_cast<int>(grid.ijk[v][0]),
                     EK::FT(grid.source.spacing[1]) * static_cast<int>(grid.ijk[v][1]),
                     EK::FT(grid.source.spacing[2]) * static_cast<int>(grid.ijk[v][2]));
}

// Checks every invariant of a grid; returns the number of interior faces checked.
std::size_t check_grid(const Volume& v, const TetGrid& grid) {
  // Orientation and tiling, exactly.
  EK::FT total = 0;
  std::vector<int> used(grid.vertex_count(), 0);
  for (const auto& t : grid.tets) {
    auto o = CGAL::orientation(ept(grid, t[0]), ept(grid, t[1]), ept(grid, t[2]), ept(grid, t[3]));
    EXPECT_EQ(o, CGAL::POSITIVE);
    total += CGAL::volume(ept(grid, t[0]), ept(grid, t[1]), ept(grid, t[2]), ept(grid, t[3]));
    total.exact();  // collapse the lazy expression DAG (it would otherwise grow one level per tet)
    for (auto x : t) used[x] = 1;
  }
  EK::FT box = EK::FT(v.spacing[0]) * static_cast<int>(v.dims[0] - 1) * EK::FT(v.spacing[1]) * static_cast<int>(v.dims[1] - 1) *
               EK::FT(v.spacing[2]) * static_cast<int>(v.dims[2] - 1);
  EXPECT_TRUE(total == box) << CGAL::to_double(total) << " vs " << CGAL::to_double(box);
  EXPECT_EQ(std::count(used.begin(), used.end(), 0), 0) << "unused vertices";
  // Delaunay: for each interior face, the far vertex of the other tet is not strictly inside.
  std::map<std::array<std::uint32_t, 3>, std::vector<std::pair<std::size_t, int>>> faces;
  for (std::size_t i = 0; i < grid.tets.size(); ++i)
    for (int f = 0; f < 4; ++f) {
      std::array<std::uint32_t, 3> k;
      int n = 0;
      for (int j = 0; j < 4; ++j)
        if (j != f) k[n++] = grid.tets[i][j];
      std::sort(k.begin(), k.end());
      faces[k].push_back({i, f});
    }
  std::size_t interior = 0;
  for (const auto& [k, ts] : faces) {
    EXPECT_LE(ts.size(), 2u);
    if (ts.size() != 2) continue;
    ++interior;
    const auto& t = grid.tets[ts[0].first];
    std::uint32_t opp = grid.tets[ts[1].first][ts[1].second];
    auto s = CGAL::side_of_oriented_sphere(ept(grid, t[0]), ept(grid, t[1]), ept(grid, t[2]), ept(grid, t[3]), ept(grid, opp));
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

using testutil::all_voxels;

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
  EXPECT_THROW(delaunay_grid(v, value_range(v), all_voxels(v)), InputError);
}
