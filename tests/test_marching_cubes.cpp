// Full-resolution marching cubes: analytic fields (plane, sphere), topology on random volumes full
// of ties, and independence from the thread count. (Agreement with VTK is measured in bench/.)
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <random>

#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

testutil::EdgeCensus edge_census(const Mesh& m, const Volume& v) { return testutil::edge_census(m, v.dims, v.spacing); }

}  // namespace

TEST(MarchingCubes, LinearFieldGivesThePlane) {
  Volume v = make_volume({12, 9, 7}, ScalarType::f64);
  v.spacing = {0.5, 1.5, 2.0};
  const double a = 0.7, b = -1.1, c = 0.3;
  for (std::int64_t k = 0; k < 7; ++k)
    for (std::int64_t j = 0; j < 9; ++j)
      for (std::int64_t i = 0; i < 12; ++i) v.set(v.index(i, j, k), a * 0.5 * i + b * 1.5 * j + c * 2.0 * k);
  const double iso = -2.3456;
  Mesh m = marching_cubes(v, iso);
  ASSERT_GT(m.triangle_count(), 20u);
  const double n = std::sqrt(a * a + b * b + c * c);
  for (std::size_t i = 0; i < m.vertex_count(); ++i) {
    const auto& p = m.positions[i];
    EXPECT_NEAR(a * p[0] + b * p[1] + c * p[2], iso, 1e-5);
    EXPECT_NEAR(m.normals[i][0], -a / n, 1e-5);
    EXPECT_NEAR(m.normals[i][1], -b / n, 1e-5);
    EXPECT_NEAR(m.normals[i][2], -c / n, 1e-5);
  }
  auto e = edge_census(m, v);
  EXPECT_EQ(e.nonmanifold, 0u);
  EXPECT_EQ(e.misoriented, 0u);
  EXPECT_TRUE(e.boundary_on_box);
  EXPECT_EQ(e.euler, 1);
}

TEST(MarchingCubes, SphereIsClosedAndConverges) {
  double prev = 1e9;
  for (int n : {24, 48, 96}) {
    Volume v = make_synthetic("sphere", n, ScalarType::f32);
    const double iso = 700, R = n / 4.0, r = R * 1000 / iso;
    Mesh m = marching_cubes(v, iso);
    auto e = edge_census(m, v);
    EXPECT_EQ(e.boundary, 0u);
    EXPECT_EQ(e.nonmanifold, 0u);
    EXPECT_EQ(e.misoriented, 0u);
    EXPECT_EQ(e.euler, 2);
    const double vol = mesh_volume(m), area = mesh_area(m);
    EXPECT_GT(vol, 0);
    const double err = std::abs(vol / (4.0 / 3 * M_PI * r * r * r) - 1) + std::abs(area / (4 * M_PI * r * r) - 1);
    EXPECT_LT(err, prev) << n;
    prev = err;
  }
  EXPECT_LT(prev, 0.01);
}

TEST(MarchingCubes, RandomVolumesWithTiesAreCrackFree) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 60; ++trial) {
    Dims d{2 + std::int64_t(rng() % 9), 2 + std::int64_t(rng() % 9), 2 + std::int64_t(rng() % 9)};
    Volume v = make_volume(d, ScalarType::i16);
    const int levels = 2 + static_cast<int>(rng() % 4);
    for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, double(rng() % levels));
    for (double iso : {0.5, 1.0, double(levels - 1), 0.999}) {
      Mesh m = marching_cubes(v, iso);
      auto e = edge_census(m, v);
      ASSERT_EQ(e.nonmanifold, 0u) << trial << " " << iso;
      ASSERT_EQ(e.misoriented, 0u) << trial << " " << iso;
      ASSERT_TRUE(e.boundary_on_box) << trial << " " << iso;
      for (const auto& t : m.triangles) ASSERT_TRUE(t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
    }
  }
}

TEST(MarchingCubes, SameOutputForAnyThreadCount) {
  Volume v = make_synthetic("marschner-lobb", 40, ScalarType::f32);
  const double iso = 0.5;
  Mesh many = marching_cubes(v, iso);
  Mesh one;
  tbb::task_arena single(1);
  single.execute([&] { one = marching_cubes(v, iso); });
  EXPECT_EQ(one.triangles, many.triangles);
  EXPECT_EQ(one.positions, many.positions);
  EXPECT_EQ(one.normals, many.normals);
  EXPECT_GT(many.triangle_count(), 1000u);
  // Every vertex is used and no two vertices coincide (one per cut edge).
  std::vector<int> used(many.vertex_count(), 0);
  for (const auto& t : many.triangles)
    for (auto id : t) used[id] = 1;
  EXPECT_EQ(std::count(used.begin(), used.end(), 0), 0);
}

TEST(MarchingCubes, CliJsonAndEmptyOutsideRange) {
  testutil::TempDir t("mc");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 30 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("mc " + (t / "s.nrrd") + " --iso 700,5000 --json -o " + (t / "m.stl"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"triangles\""), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(t / "m-700.stl"));
  EXPECT_TRUE(std::filesystem::exists(t / "m-5000.stl"));
  EXPECT_EQ(std::filesystem::file_size(t / "m-5000.stl"), 84u);  // empty mesh: header and count only
  auto b = testutil::run_cli("mc " + (t / "s.nrrd") + " --iso inf -o " + (t / "x.ply"));
  EXPECT_EQ(b.code, 2);
}

// ---- surface distance against analytic cases ----
#include "adaptiso/surface_distance.hpp"

namespace {

// A UV sphere of radius r: vertices exactly on the sphere.
Mesh uv_sphere(double r, int n) {
  Mesh m;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j < 2 * n; ++j) {
      double th = M_PI * i / n, ph = M_PI * j / n;
      m.positions.push_back({float(r * std::sin(th) * std::cos(ph)), float(r * std::sin(th) * std::sin(ph)), float(r * std::cos(th))});
    }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < 2 * n; ++j) {
      std::uint32_t a = i * 2 * n + j, b = i * 2 * n + (j + 1) % (2 * n), c = a + 2 * n, d = b + 2 * n;
      if (i > 0) m.triangles.push_back({a, c, b});
      if (i + 1 < n) m.triangles.push_back({b, c, d});
    }
  return m;
}

Mesh square(double z, int n) {
  Mesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.positions.push_back({float(i) / n, float(j) / n, float(z)});
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      std::uint32_t a = j * (n + 1) + i;
      m.triangles.push_back({a, a + 1, a + n + 2});
      m.triangles.push_back({a, a + n + 2, a + n + 1});
    }
  return m;
}

}  // namespace

TEST(SurfaceDistance, PlaneAndItsOffset) {
  Mesh a = square(0, 10), b = square(0.25, 7);  // different tessellations, same square
  auto d = surface_distance(a, b);
  for (const auto* s : {&d.a_to_b, &d.b_to_a}) {
    EXPECT_NEAR(s->mean, 0.25, 1e-6);
    EXPECT_NEAR(s->rms, 0.25, 1e-6);
    EXPECT_NEAR(s->p95, 0.25, 1e-6);
    EXPECT_NEAR(s->max, 0.25, 1e-6);
    EXPECT_GE(s->samples, 200'000u);
  }
}

TEST(SurfaceDistance, ConcentricSpheres) {
  // Finely tessellated spheres of radius 10 and 10.5: every distance is close to 0.5 (the chordal
  // error of the tessellation is about 0.002 at this resolution).
  Mesh a = uv_sphere(10, 100), b = uv_sphere(10.5, 90);
  auto d = surface_distance(a, b);
  EXPECT_NEAR(d.a_to_b.mean, 0.5, 0.005);
  EXPECT_NEAR(d.b_to_a.mean, 0.5, 0.005);
  EXPECT_NEAR(d.a_to_b.max, 0.5, 0.005);
  EXPECT_NEAR(d.b_to_a.max, 0.5, 0.01);
  EXPECT_NEAR(d.hausdorff(), 0.5, 0.01);
  // A surface against itself: zero.
  auto z = surface_distance(a, a);
  EXPECT_LT(z.a_to_b.max, 1e-5);
  EXPECT_THROW(surface_distance(a, Mesh{}), InputError);
}
