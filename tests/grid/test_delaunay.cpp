// The paper's grid (§2.2): the Delaunay property checked with CGAL's exact kernel (Epeck, not the
// triangulation's), tiling of the box in exact arithmetic, orientation, vertex use.
#include <gtest/gtest.h>

#include <CGAL/Exact_predicates_exact_constructions_kernel.h>

#include <tbb/task_arena.h>

#include <algorithm>
#include <random>

#include "adaptiso/delaunay.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/volume_io.hpp"
#include "test_util.hpp"

using namespace adaptiso;
using EK = CGAL::Exact_predicates_exact_constructions_kernel;

namespace {

EK::Point_3 ept(const TetGrid& grid, std::uint32_t v) {
  // Exact coordinates in the triangulation's metric: the index times delaunay_metric's scales.
  const Vec3 scale = delaunay_metric(grid.source.spacing);
  return EK::Point_3(EK::FT(scale[0]) * static_cast<int>(grid.ijk[v][0]), EK::FT(scale[1]) * static_cast<int>(grid.ijk[v][1]),
                     EK::FT(scale[2]) * static_cast<int>(grid.ijk[v][2]));
}

// Checks every invariant of a grid; returns the number of interior faces checked.
std::size_t check_grid(const Volume& v, const TetGrid& grid) {
  // Orientation and tiling, exactly in lattice units (a positive scale per axis changes neither
  // sign nor ratio): six times a lattice tetrahedron's volume is an integer. (In the metric's
  // exact kernel, as before, this check took most of the test's 130 s under ASan.)
  std::int64_t total6 = 0;
  std::vector<int> used(grid.vertex_count(), 0);
  for (const auto& t : grid.tets) {
    std::int64_t e[3][3];
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) e[i][a] = std::int64_t{grid.ijk[t[i + 1]][a]} - grid.ijk[t[0]][a];
    const std::int64_t det = e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1]) - e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0]) +
                             e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0]);
    EXPECT_GT(det, 0);
    total6 += det;
    for (auto x : t) used[x] = 1;
  }
  const std::int64_t box6 = std::int64_t{6} * (v.dims[0] - 1) * (v.dims[1] - 1) * (v.dims[2] - 1);
  EXPECT_EQ(total6, box6);
  EXPECT_EQ(std::count(used.begin(), used.end(), 0), 0) << "unused vertices";
  // Delaunay in the triangulation's metric (anisotropic spacing changes it): for each interior
  // face, the far vertex of the other tet is not strictly inside, in exact arithmetic.
  std::vector<EK::Point_3> points;
  points.reserve(grid.vertex_count());
  for (std::uint32_t i = 0; i < grid.vertex_count(); ++i) points.push_back(ept(grid, i));
  struct Face {
    std::array<std::uint32_t, 3> key;
    std::uint32_t tet;
    int opposite;
  };
  std::vector<Face> faces;
  faces.reserve(grid.tets.size() * 4);
  for (std::size_t i = 0; i < grid.tets.size(); ++i)
    for (int f = 0; f < 4; ++f) {
      std::array<std::uint32_t, 3> k;
      int n = 0;
      for (int j = 0; j < 4; ++j)
        if (j != f) k[n++] = grid.tets[i][j];
      std::sort(k.begin(), k.end());
      faces.push_back({k, static_cast<std::uint32_t>(i), f});
    }
  std::sort(faces.begin(), faces.end(), [](const Face& x, const Face& y) { return x.key < y.key; });
  std::size_t interior = 0;
  for (std::size_t f = 0; f < faces.size();) {
    std::size_t end = f + 1;
    while (end < faces.size() && faces[end].key == faces[f].key) ++end;
    EXPECT_LE(end - f, 2u);
    if (end - f == 2) {
      ++interior;
      const auto& t = grid.tets[faces[f].tet];
      const std::uint32_t opp = grid.tets[faces[f + 1].tet][static_cast<std::size_t>(faces[f + 1].opposite)];
      const auto s = CGAL::side_of_oriented_sphere(points[t[0]], points[t[1]], points[t[2]], points[t[3]], points[opp]);
      EXPECT_NE(s, CGAL::ON_POSITIVE_SIDE) << "face " << faces[f].key[0] << "," << faces[f].key[1] << "," << faces[f].key[2];
    }
    f = end;
  }
  return interior;
}

using testutil::all_voxels;

}  // namespace

TEST(Delaunay, FullLatticeManyCosphericalPoints) {
  Volume v = make_volume({6, 5, 4}, ScalarType::f32);
  v.spacing = {1.0, 0.5, 2.5};
  TetGrid g = testutil::build_grid(v, all_voxels(v));
  EXPECT_GT(check_grid(v, g), 100u);
  EXPECT_EQ(g.vertex_count(), 120u);
}

TEST(Delaunay, RandomLatticeSubsets) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 5; ++trial) {
    Volume v = make_volume({9, 7, 8}, ScalarType::f32);
    TetGrid g = testutil::build_grid(v, testutil::random_kept(v, rng, 4));
    check_grid(v, g);
  }
}

TEST(Delaunay, PaperSphereAndRealKeptSets) {
  Volume s = make_synthetic("sphere", 50, ScalarType::i16);
  ReduceOptions o;
  o.max_error = 0.15;
  o.relative = true;
  auto r = reduce(s, o);
  check_grid(s, testutil::build_grid(s, r.kept));
  REQUIRE_DATA(data);
  Volume m = read_volume(data + "/mr_head_HeadMRVolume/HeadMRVolume.mhd");
  o.max_error = 0.05;
  auto rm = reduce(m, o);
  check_grid(m, testutil::build_grid(m, rm.kept));
}

TEST(Delaunay, FlatVolumeIsRefused) {
  Volume v = make_volume({5, 5, 1}, ScalarType::f32);
  TetGrid g;
  g.source.dims = v.dims;
  EXPECT_THROW(delaunay_grid(v, value_range(v), all_voxels(v)), InputError);
}

TEST(Delaunay, AnisotropicSpacingGivesNoFlatTetrahedronAndNoZeroAreaTriangle) {
  // A CT-like phantom at 0.9 × 0.9 × 1.6 mm: in rounded physical coordinates coplanar lattice
  // points became slightly non-coplanar and CGAL built slivers between them (108 of 2.1 M
  // tetrahedra were flat in exact lattice arithmetic).
  for (Vec3 spacing : {Vec3{0.9, 0.9, 1.6}, Vec3{0.3378, 0.3378, 0.5}, Vec3{1.40625, 1.40625, 2.5}, Vec3{1, 3, 7}}) {
    Volume v = make_synthetic("sphere", 40, ScalarType::i16);
    v.spacing = spacing;
    ReduceOptions o;
    o.max_error = 0.08;
    o.relative = true;
    const TetGrid g = testutil::build_grid(v, reduce(v, o).kept);
    check_grid(v, g);
    std::size_t flat = 0;
    for (const auto& t : g.tets) {
      std::int64_t P[4][3];
      for (int i = 0; i < 4; ++i)
        for (int a = 0; a < 3; ++a) P[i][a] = g.ijk[t[i]][a];
      std::int64_t u[3], w[3], z[3];
      for (int a = 0; a < 3; ++a) u[a] = P[1][a] - P[0][a], w[a] = P[2][a] - P[0][a], z[a] = P[3][a] - P[0][a];
      flat += u[0] * (w[1] * z[2] - w[2] * z[1]) - u[1] * (w[0] * z[2] - w[2] * z[0]) + u[2] * (w[0] * z[1] - w[1] * z[0]) <= 0;
    }
    EXPECT_EQ(flat, 0u) << spacing[2];
    Extractor ex(testutil::prepared(g));
    for (double iso : {450.0, 700.0, 950.0}) {
      ex.extract(iso);
      const Mesh& m = ex.mesh();
      ASSERT_GT(m.triangle_count(), 0u);
      for (const auto& tri : m.triangles) {
        Mesh one;
        one.positions = {m.positions[tri[0]], m.positions[tri[1]], m.positions[tri[2]]};
        one.triangles = {{0, 1, 2}};
        ASSERT_GT(mesh_area(one), 0) << "spacing z " << spacing[2] << " iso " << iso;
      }
    }
  }
}

TEST(Delaunay, SameGridForAnyThreadCount) {
  // Degenerate lattice input admits many Delaunay tetrahedrizations; symbolic perturbation picks
  // one whatever the insertion order, and the tetrahedra are written in a canonical order.
  Volume v = make_synthetic("sphere", 36, ScalarType::i16);
  v.spacing = {0.9, 0.9, 1.6};
  ReduceOptions o;
  o.max_error = 0.05;
  o.relative = true;
  const auto kept = reduce(v, o).kept;
  TetGrid one, four;
  tbb::task_arena(1).execute([&] { one = delaunay_grid(v, value_range(v), kept); });
  tbb::task_arena(4).execute([&] { four = delaunay_grid(v, value_range(v), kept); });
  EXPECT_EQ(one.tets, four.tets);
  DelaunayOptions sequential;
  sequential.parallel = false;
  EXPECT_EQ(delaunay_grid(v, value_range(v), kept, sequential).tets, one.tets);
}
