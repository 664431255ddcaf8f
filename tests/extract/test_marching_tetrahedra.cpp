// Marching tetrahedra (§2.4) against analytic fields (plane, sphere) and on random grids: watertight,
// 2-manifold, oriented, no degenerate triangles, the same numbering for any chunking.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "adaptiso/extractor.hpp"
#include "adaptiso/marching_tetrahedra.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

using testutil::all_voxels;

testutil::EdgeCensus topology(const Mesh& m, const GridSource& s) { return testutil::edge_census(m, s.dims, s.spacing); }

double triangle_area(const Mesh& m, const std::array<std::uint32_t, 3>& t) {
  Mesh one;
  one.positions = {m.positions[t[0]], m.positions[t[1]], m.positions[t[2]]};
  one.triangles = {{0, 1, 2}};
  return mesh_area(one);
}

ExtractStats extract_into(Extractor& ex, double iso, Mesh& m) {
  ExtractStats st = ex.extract(iso);
  m = ex.mesh();
  return st;
}

}  // namespace

TEST(MarchingTets, LinearFieldGivesThePlaneWithItsNormal) {
  Volume v = make_volume({9, 8, 7}, ScalarType::f64);
  v.spacing = {0.5, 1.25, 2.0};
  const double a = 1.5, b = -0.75, c = 0.4;  // value = a x + b y + c z in physical units
  for (std::int64_t k = 0; k < 7; ++k)
    for (std::int64_t j = 0; j < 8; ++j)
      for (std::int64_t i = 0; i < 9; ++i) v.set(v.index(i, j, k), a * i * 0.5 + b * j * 1.25 + c * k * 2.0);
  TetGrid g = testutil::build_grid(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor ex(testutil::prepared(g, tree));
  Mesh m;
  const double norm = std::sqrt(a * a + b * b + c * c);
  for (double iso : {0.1234, 1.00713, 2.71828}) {  // no vertex lies exactly on these
    auto st = extract_into(ex, iso, m);
    ASSERT_GT(st.triangles, 10u);
    for (std::size_t i = 0; i < m.vertex_count(); ++i) {
      const auto& p = m.positions[i];
      EXPECT_NEAR(a * p[0] + b * p[1] + c * p[2], iso, 1e-5) << i;
      EXPECT_NEAR(m.normals[i][0], -a / norm, 1e-5);
      EXPECT_NEAR(m.normals[i][1], -b / norm, 1e-5);
      EXPECT_NEAR(m.normals[i][2], -c / norm, 1e-5);
    }
    // Triangles face their normals (counter-clockwise seen from the lower side).
    for (const auto& t : m.triangles) {
      const auto &p0 = m.positions[t[0]], &p1 = m.positions[t[1]], &p2 = m.positions[t[2]];
      double u[3], w[3];
      for (int k = 0; k < 3; ++k) u[k] = double(p1[k]) - p0[k], w[k] = double(p2[k]) - p0[k];
      double n[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
      EXPECT_LT(n[0] * a + n[1] * b + n[2] * c, 0);
    }
    auto topo = topology(m, g.source);
    EXPECT_EQ(topo.nonmanifold, 0u);
    EXPECT_EQ(topo.misoriented, 0u);
    EXPECT_EQ(topo.euler, 1);  // a disc
  }
}

TEST(MarchingTets, SphereIsClosedOrientedAndConverges) {
  double prev_err = 1e9;
  for (int n : {16, 28, 40}) {  // full grids: the reconstruction error shrinks with the voxel size
    Volume v = make_synthetic("sphere", n, ScalarType::f32);
    TetGrid g = testutil::build_grid(v, all_voxels(v));
    IntervalTree tree = build_interval_tree(g);
    Extractor ex(testutil::prepared(g, tree));
    Mesh m;
    const double iso = 700;  // outside the core: value 1000 R / r, so r = R · 1000 / 700
    extract_into(ex, iso, m);
    auto topo = topology(m, g.source);
    EXPECT_EQ(topo.boundary, 0u) << n;
    EXPECT_EQ(topo.nonmanifold, 0u) << n;
    EXPECT_EQ(topo.misoriented, 0u) << n;
    EXPECT_EQ(topo.degenerate, 0u) << n;
    EXPECT_EQ(topo.euler, 2) << n;
    // The sphere's centre and radius as the generator defines them (voxel units, spacing 1).
    const double R = n / 4.0, r = R * 1000.0 / iso, c = (n - 1) / 2.0;
    const double vol = mesh_volume(m), area = mesh_area(m);
    EXPECT_GT(vol, 0) << "outward orientation gives a positive enclosed volume";
    std::size_t outward = 0;
    for (std::size_t i = 0; i < m.vertex_count(); ++i) {
      const auto& p = m.positions[i];
      const auto& q = m.normals[i];
      outward += (p[0] - c) * q[0] + (p[1] - c) * q[1] + (p[2] - c) * q[2] > 0;
    }
    EXPECT_EQ(outward, m.vertex_count()) << n;
    const double err = std::abs(vol / (4.0 / 3.0 * M_PI * r * r * r) - 1) + std::abs(area / (4 * M_PI * r * r) - 1);
    EXPECT_LT(err, prev_err) << n;
    prev_err = err;
  }
  EXPECT_LT(prev_err, 0.03);
}

TEST(MarchingTets, RandomGridsAreWatertightInsideTheBoxWithoutDegenerateTriangles) {
  std::mt19937 rng(17);
  std::size_t meshes = 0;
  for (int trial = 0; trial < 80; ++trial) {
    TetGrid g = testutil::random_grid(rng, 2 + static_cast<int>(rng() % 5));
    IntervalTree tree = build_interval_tree(g, rng() % 6);
    Extractor ex(testutil::prepared(g, tree));
    Mesh m;
    for (int q = 0; q < 6; ++q) {
      // Half of the iso-values equal vertex values exactly: the tie rule must keep the mesh clean.
      double iso = (q % 2) ? double(rng() % 5) : (rng() % 1000) / 200.0;
      extract_into(ex, iso, m);
      if (m.triangles.empty()) continue;
      ++meshes;
      auto topo = topology(m, g.source);
      ASSERT_TRUE(topo.boundary_on_box) << "trial " << trial << " iso " << iso;
      ASSERT_EQ(topo.nonmanifold, 0u) << "trial " << trial << " iso " << iso;
      ASSERT_EQ(topo.misoriented, 0u) << "trial " << trial << " iso " << iso;
      for (const auto& t : m.triangles) ASSERT_GT(triangle_area(m, t), 0) << "trial " << trial << " iso " << iso;
    }
  }
  EXPECT_GT(meshes, 200u);
}

TEST(MarchingTets, ParallelNumberingEqualsSequentialFirstUse) {
  Volume v = make_synthetic("marschner-lobb", 20, ScalarType::f32);
  TetGrid g = testutil::build_grid(v, all_voxels(v));
  std::vector<std::uint32_t> act;
  const double iso = 0.5 * (g.source.min + g.source.max);
  scan_active(g, iso, act);
  const Mesh one = march_tetrahedra(g, act, iso, MarchOptions{~std::size_t{0}});
  for (int run = 0; run < 3; ++run) {
    const Mesh many = march_tetrahedra(g, act, iso, MarchOptions{1});
    ASSERT_EQ(one.triangles, many.triangles);
    ASSERT_EQ(one.positions, many.positions);
  }
  // First-use order: scanning the corners, each new vertex is the next id.
  std::uint32_t next = 0;
  for (const auto& t : one.triangles)
    for (auto id : t) {
      ASSERT_LE(id, next);
      if (id == next) ++next;
    }
  EXPECT_EQ(next, one.vertex_count());
  // Distinct cut edges give distinct points.
  std::set<std::array<float, 3>> pts(one.positions.begin(), one.positions.end());
  EXPECT_EQ(pts.size(), one.vertex_count());
}

TEST(MarchingTets, OutsideTheRangeGivesAnEmptyMesh) {
  Volume v = make_synthetic("sphere", 16, ScalarType::i16);
  TetGrid g = testutil::build_grid(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor ex(testutil::prepared(g, tree));
  Mesh m;
  auto st = extract_into(ex, g.source.max + 1, m);
  EXPECT_FALSE(st.in_range);
  EXPECT_EQ(st.triangles, 0u);
  st = extract_into(ex, g.source.min, m);  // everything is at or above the minimum: nothing below
  EXPECT_EQ(st.triangles, 0u);
  EXPECT_THROW(extract_into(ex, std::nan(""), m), InputError);
}

// ---- Hand-built cases: one tetrahedron cut by hand ----
//
//      z
//      3            The tetrahedron 0 (0,0,0), 1 (1,0,0), 2 (0,1,0), 3 (0,0,1): positive volume
//      |            (det[1−0, 2−0, 3−0] = 1). Values 0 or 1 on its corners, iso-value 0.5: every
//      |            cut edge is cut at its midpoint, exactly; the vertex gradients are the linear
//      0------2  y  field's, so every normal is the field's, negated.
//     /
//    1
//   x
namespace {

TetGrid one_tetrahedron(std::array<double, 4> values) {
  TetGrid g;
  g.source.dims = {2, 2, 2};
  g.source.min = 0;
  g.source.max = 1;
  g.ijk = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};  // voxels 0, 1, 2, 4: ascending
  g.values.assign(values.begin(), values.end());
  const std::array<float, 3> gradient{float(values[1] - values[0]), float(values[2] - values[0]), float(values[3] - values[0])};
  g.gradients.assign(4, gradient);
  g.tets = {{0, 1, 2, 3}};
  return g;
}

std::array<double, 3> cross_of(const Mesh& m, const std::array<std::uint32_t, 3>& t) {
  const auto &a = m.positions[t[0]], &b = m.positions[t[1]], &c = m.positions[t[2]];
  const std::array<double, 3> u{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w{c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  return {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
}

}  // namespace

TEST(MarchingTetsByHand, OneCornerAboveGivesOneTriangle) {
  // Corner 0 below, 1, 2, 3 above (f = x + y + z): the triangle at the midpoints of 0-1, 0-2, 0-3.
  const TetGrid g = one_tetrahedron({0, 1, 1, 1});
  std::vector<std::uint64_t> edges;
  const std::uint32_t active[] = {0};
  const Mesh m = march_tetrahedra(g, active, 0.5, {}, &edges);
  ASSERT_EQ(m.triangle_count(), 1u);
  ASSERT_EQ(m.vertex_count(), 3u);
  std::vector<std::array<float, 3>> at = m.positions;
  std::sort(at.begin(), at.end());
  EXPECT_EQ(at, (std::vector<std::array<float, 3>>{{0, 0, 0.5f}, {0, 0.5f, 0}, {0.5f, 0, 0}}));
  // Normals towards lower values, −(1,1,1)/√3; the triangle counter-clockwise seen from there.
  const float s = float(-1 / std::sqrt(3.0));
  for (const auto& n : m.normals)
    for (float x : n) EXPECT_FLOAT_EQ(x, s);
  EXPECT_EQ(cross_of(m, m.triangles[0]), (std::array<double, 3>{-0.25, -0.25, -0.25}));
  // Each vertex's edge, below vertex first: 0 → 1, 0 → 2, 0 → 3 in some order.
  std::sort(edges.begin(), edges.end());
  EXPECT_EQ(edges, (std::vector<std::uint64_t>{1, 2, 3}));
  // The same edges by their global lattice keys (tet_grid.hpp): voxel indices, smaller first.
  EXPECT_EQ(g.lattice_edge(2, 0), (LatticeEdge{0, 2}));
  EXPECT_EQ(g.lattice_edge(0, 3), (LatticeEdge{0, 4}));
}

TEST(MarchingTetsByHand, TwoCornersAboveGiveAQuadOfTwoTriangles) {
  // 0, 1 below, 2, 3 above (f = y + z): the parallelogram at the midpoints of 0-2, 0-3, 1-2, 1-3,
  // area |(½,0,0) × (0,−½,½)| = √2/4, normals −(0,1,1)/√2.
  const TetGrid g = one_tetrahedron({0, 0, 1, 1});
  const std::uint32_t active[] = {0};
  const Mesh m = march_tetrahedra(g, active, 0.5);
  ASSERT_EQ(m.triangle_count(), 2u);
  ASSERT_EQ(m.vertex_count(), 4u);
  std::vector<std::array<float, 3>> at = m.positions;
  std::sort(at.begin(), at.end());
  EXPECT_EQ(at, (std::vector<std::array<float, 3>>{{0, 0, 0.5f}, {0, 0.5f, 0}, {0.5f, 0, 0.5f}, {0.5f, 0.5f, 0}}));
  EXPECT_DOUBLE_EQ(mesh_area(m), std::sqrt(2.0) / 4);
  const float s = float(-1 / std::sqrt(2.0));
  for (const auto& n : m.normals) {
    EXPECT_EQ(n[0], 0.0f);
    EXPECT_FLOAT_EQ(n[1], s);
    EXPECT_FLOAT_EQ(n[2], s);
  }
  for (const auto& t : m.triangles) {
    const auto c = cross_of(m, t);
    EXPECT_EQ(c[0], 0.0);
    EXPECT_EQ(c[1], -0.25);
    EXPECT_EQ(c[2], -0.25);
  }
}

TEST(MarchingTetsByHand, CornerOnTheIsoValueCountsAsAbove) {
  // Values 0, 0.5, 0.5, 0.5 at iso 0.5: corners 1, 2, 3 are "above" (equal counts as above), so
  // the tetrahedron is cut (min < iso <= max) and its triangle lies 1/1024 of each edge from
  // them, not on them (marching_tetrahedra.hpp): no collapsed triangle.
  const TetGrid g = one_tetrahedron({0, 0.5, 0.5, 0.5});
  const std::uint32_t active[] = {0};
  const Mesh m = march_tetrahedra(g, active, 0.5);
  ASSERT_EQ(m.triangle_count(), 1u);
  for (const auto& p : m.positions) EXPECT_FLOAT_EQ(p[0] + p[1] + p[2], float(1 - 1.0 / 1024));
}
