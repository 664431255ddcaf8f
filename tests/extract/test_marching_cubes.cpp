// Full-resolution marching cubes: analytic fields (plane, sphere), topology on random volumes full
// of ties, and independence from the thread count. (Agreement with VTK is measured in bench/.)
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <numeric>
#include <random>
#include <set>

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

// ---- Hand-built cases: one cube, every configuration ----
//
//        6 ------- 7         corner c of the 2×2×2 volume is voxel (c & 1, c >> 1 & 1, c >> 2 & 1);
//       /|        /|         configuration m puts value 1 on the corners of its bits, 0 on the
//      4 ------- 5 |         others, and the iso-value 0.5 cuts each edge between a 0 and a 1
//      | 2 ------|-3         at its midpoint, exactly.
//      |/        |/
//      0 ------- 1           z up the page, y into it.
namespace {

Volume one_cube(int m) {
  Volume v = make_volume({2, 2, 2}, ScalarType::u8);
  for (int c = 0; c < 8; ++c) v.set(v.index(c & 1, c >> 1 & 1, c >> 2 & 1), (m >> c) & 1);
  return v;
}

// The cut edges' midpoints, sorted: where the mesh's vertices must be.
std::vector<std::array<float, 3>> cut_midpoints(int m) {
  std::vector<std::array<float, 3>> out;
  for (int c = 0; c < 8; ++c)
    for (int axis = 0; axis < 3; ++axis) {
      const int d = c | 1 << axis;
      if (d == c || ((m >> c) & 1) == ((m >> d) & 1)) continue;
      std::array<float, 3> p{float(c & 1), float(c >> 1 & 1), float(c >> 2 & 1)};
      p[axis] = 0.5f;
      out.push_back(p);
    }
  std::sort(out.begin(), out.end());
  return out;
}

// Corner components: the corners above joined by cube edges only (on a face with two diagonal
// corners above, those are cut off: marching_cubes.hpp), the corners below by edges and by the
// diagonals of such faces. The surface's pieces are disks in the cube, each between two regions,
// so there are (above components) + (below components) − 1 of them.
int expected_pieces(int m) {
  std::array<int, 8> parent{};
  std::iota(parent.begin(), parent.end(), 0);
  std::function<int(int)> find = [&](int a) { return parent[a] == a ? a : parent[a] = find(parent[a]); };
  auto above = [&](int c) { return (m >> c) & 1; };
  for (int c = 0; c < 8; ++c)
    for (int axis = 0; axis < 3; ++axis) {
      const int d = c | 1 << axis;
      if (d != c && above(c) == above(d)) parent[find(c)] = find(d);
    }
  for (int c = 0; c < 8; ++c)  // face diagonals: c and c ^ (two axes' bits), both below, the other two above
    for (int a = 0; a < 3; ++a)
      for (int b = a + 1; b < 3; ++b) {
        const int d = c ^ (1 << a | 1 << b), e = c ^ 1 << a, f = c ^ 1 << b;
        if (!above(c) && !above(d) && above(e) && above(f)) parent[find(c)] = find(d);
      }
  std::set<int> roots;
  for (int c = 0; c < 8; ++c) roots.insert(find(c));
  return static_cast<int>(roots.size()) - 1;
}

int mesh_pieces(const Mesh& mesh) {
  const std::vector<std::uint32_t> piece = testutil::vertex_pieces(mesh);
  return static_cast<int>(std::set<std::uint32_t>(piece.begin(), piece.end()).size());
}

}  // namespace

TEST(MarchingCubesByHand, EveryConfigurationOfOneCube) {
  for (int m = 0; m < 256; ++m) {
    SCOPED_TRACE(m);
    const Volume v = one_cube(m);
    MarchingCubesStats st;
    const Mesh mesh = marching_cubes(v, 0.5, &st);
    std::vector<std::array<float, 3>> at = mesh.positions;
    std::sort(at.begin(), at.end());
    EXPECT_EQ(at, cut_midpoints(m)) << "one vertex at the midpoint of each cut edge, no other";
    EXPECT_EQ(st.cubes_cut, m == 0 || m == 255 ? 0u : 1u);
    const int pieces = m == 0 || m == 255 ? 0 : expected_pieces(m);
    EXPECT_EQ(mesh_pieces(mesh), pieces);
    // Every vertex lies on the cube's boundary, each piece is a polygon fanned from a vertex:
    // V − 2 triangles a piece, and its V edges around it are the mesh's boundary, on the faces.
    EXPECT_EQ(mesh.triangle_count(), mesh.vertex_count() - 2 * static_cast<std::size_t>(pieces));
    const auto e = edge_census(mesh, v);
    EXPECT_EQ(e.boundary, mesh.vertex_count());
    EXPECT_TRUE(e.boundary_on_box);
    EXPECT_EQ(e.nonmanifold + e.misoriented + e.degenerate, 0u);
    // The complement cuts the same edges; it separates the other corners on ambiguous faces.
    std::vector<std::array<float, 3>> complement = marching_cubes(one_cube(255 - m), 0.5).positions;
    std::sort(complement.begin(), complement.end());
    EXPECT_EQ(complement, at);
  }
}

TEST(MarchingCubesByHand, FiveConfigurationsWrittenOut) {
  struct Case {
    int m;
    std::size_t triangles, vertices;
  };
  // One corner; an edge (corners 0, 1); a face (0, 1, 2, 3: the plane z = 0.5); two corners
  // diagonal on a face (0, 3: cut off apart); two opposite corners (0, 7).
  for (const Case c :
       {Case{0b00000001, 1, 3}, Case{0b00000011, 2, 4}, Case{0b00001111, 2, 4}, Case{0b00001001, 2, 6}, Case{0b10000001, 2, 6}}) {
    SCOPED_TRACE(c.m);
    const Mesh mesh = marching_cubes(one_cube(c.m), 0.5);
    EXPECT_EQ(mesh.triangle_count(), c.triangles);
    EXPECT_EQ(mesh.vertex_count(), c.vertices);
  }
  // Corner 0 above (value 1) alone: the triangle (0.5,0,0), (0,0.5,0), (0,0,0.5), its normal
  // towards the lower values, away from corner 0: +(1,1,1)/√3, counter-clockwise seen from there.
  const Mesh corner = marching_cubes(one_cube(1), 0.5);
  ASSERT_EQ(corner.triangle_count(), 1u);
  const auto& t = corner.triangles[0];
  const auto& a = corner.positions[t[0]];
  const auto& b = corner.positions[t[1]];
  const auto& c = corner.positions[t[2]];
  const std::array<double, 3> u{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w{c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  const std::array<double, 3> n{u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
  EXPECT_DOUBLE_EQ(n[0], 0.25);  // (b − a) × (c − a) of that triangle, either way round it is listed
  EXPECT_DOUBLE_EQ(n[1], 0.25);
  EXPECT_DOUBLE_EQ(n[2], 0.25);
  for (const auto& normal : corner.normals) EXPECT_GT(normal[0] + normal[1] + normal[2], 0.0f);
}
