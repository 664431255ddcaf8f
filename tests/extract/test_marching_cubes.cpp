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
