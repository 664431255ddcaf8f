// Specks (specks.hpp): pieces of a surface whose bounding box in the volume's grid frame has a
// diagonal under a distance are dropped, the rest kept in order, wherever the volume sits in the
// world and whatever its spacing.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "adaptiso/volume.hpp"
#include "extract/specks.hpp"

using namespace adaptiso;

namespace {

// A closed tetrahedron (four triangles) with corners `c` in the grid frame (voxels of spacing
// 1), placed in the world through `s`, appended to `m`.
void add_tetrahedron(Mesh& m, const GridSource& s, const std::array<Vec3, 4>& c) {
  const auto base = static_cast<std::uint32_t>(m.positions.size());
  const double smallest = std::min({s.spacing[0], s.spacing[1], s.spacing[2]});
  for (const Vec3& p : c) {
    const Vec3 w = grid_to_world(s.origin, s.direction, {p[0] * smallest, p[1] * smallest, p[2] * smallest});
    m.positions.push_back({float(w[0]), float(w[1]), float(w[2])});
    m.normals.push_back({float(base), 0, 0});  // which vertex it was, to follow the renumbering
  }
  for (const auto& t : {std::array<std::uint32_t, 3>{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {0, 3, 2}})
    m.triangles.push_back({base + t[0], base + t[1], base + t[2]});
}

// Rotated about an oblique axis and mirrored, away from the origin, anisotropic voxels.
GridSource oblique() {
  GridSource s;
  s.spacing = {0.7, 1.9, 1.2};
  s.origin = {-31.5, 12.25, 101};
  const double a = 0.61, c = std::cos(a), n = std::sin(a);
  // Rotation about (1, 1, 1)/√3 by a, then x mirrored.
  const double k = 1 / std::sqrt(3.0), t = 1 - c;
  const std::array<double, 9> r{t * k * k + c,     t * k * k - n * k, t * k * k + n * k, t * k * k + n * k, t * k * k + c,
                                t * k * k - n * k, t * k * k - n * k, t * k * k + n * k, t * k * k + c};
  for (int i = 0; i < 9; ++i) s.direction[i] = (i % 3 == 0 ? -1 : 1) * r[i];
  return s;
}

}  // namespace

TEST(Specks, PiecesUnderTheDistanceGoTheRestStayInOrder) {
  const GridSource s = oblique();
  Mesh m;
  add_tetrahedron(m, s, {Vec3{0, 0, 0}, {9, 0, 0}, {0, 9, 0}, {0, 0, 9}});              // box diagonal 9√3 ≈ 15.6
  add_tetrahedron(m, s, {Vec3{20, 20, 20}, {21, 20, 20}, {20, 21, 20}, {20, 20, 21}});  // √3 ≈ 1.73
  add_tetrahedron(m, s, {Vec3{40, 0, 0}, {43, 0, 0}, {40, 4, 0}, {40, 0, 0.5}});        // √(9 + 16 + 0.25) ≈ 5.02
  add_tetrahedron(m, s, {Vec3{0, 40, 0}, {1, 40, 0}, {0, 41, 0}, {0, 40, 1}});          // √3 again
  const Mesh whole = m;

  Mesh none = whole;
  EXPECT_EQ(detail::drop_specks(none, s, 0).pieces, 0u);
  EXPECT_EQ(none.triangles, whole.triangles);

  Mesh two = whole;
  const detail::Specks dropped = detail::drop_specks(two, s, 2);
  EXPECT_EQ(dropped.pieces, 2u);
  EXPECT_EQ(dropped.triangles, 8u);
  ASSERT_EQ(two.vertex_count(), 8u);
  ASSERT_EQ(two.triangle_count(), 8u);
  // The first and third tetrahedra, vertices in their order, triangles as they were.
  for (std::uint32_t v = 0; v < 8; ++v) {
    const std::uint32_t was = v < 4 ? v : v + 4;
    EXPECT_EQ(two.positions[v], whole.positions[was]);
    EXPECT_EQ(two.normals[v], whole.normals[was]);
  }
  for (std::uint32_t t = 0; t < 8; ++t) {
    const std::uint32_t was = t < 4 ? t : t + 4;
    for (int k = 0; k < 3; ++k) EXPECT_EQ(two.triangles[t][k], whole.triangles[was][k] - (t < 4 ? 0 : 4));
  }

  // Just above the third's diagonal it goes too; just below, it stays.
  const double third = std::sqrt(9 + 16 + 0.25);
  Mesh below = whole, above = whole;
  EXPECT_EQ(detail::drop_specks(below, s, third * (1 - 1e-4)).pieces, 2u);
  EXPECT_EQ(detail::drop_specks(above, s, third * (1 + 1e-4)).pieces, 3u);
  EXPECT_EQ(above.triangle_count(), 4u);
}

// The boxes are the grid frame's, in voxels of the smallest spacing: the same pieces go whatever
// the frame, and a piece's world box (larger, when rotated) does not decide.
TEST(Specks, TheSamePiecesGoWhereverTheVolumeSits) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> at(0, 30), size(0.2, 4);
  std::vector<std::array<Vec3, 4>> tets;
  for (int i = 0; i < 60; ++i) {
    const Vec3 o{at(rng), at(rng), at(rng)};
    const double a = size(rng), b = size(rng), c = size(rng);
    tets.push_back({o, Vec3{o[0] + a, o[1], o[2]}, Vec3{o[0], o[1] + b, o[2]}, Vec3{o[0], o[1], o[2] + c}});
  }
  // Pieces are joined by shared vertices (indices), not by places: each tetrahedron is one.
  for (const GridSource& s : {GridSource{}, oblique()}) {
    Mesh m;
    for (const auto& t : tets) add_tetrahedron(m, s, t);
    std::size_t expected = 0;
    for (std::size_t i = 0; i < tets.size(); ++i) {
      const auto& t = tets[i];
      const double d = std::sqrt(std::pow(t[1][0] - t[0][0], 2) + std::pow(t[2][1] - t[0][1], 2) + std::pow(t[3][2] - t[0][2], 2));
      expected += d < 3.5;
    }
    ASSERT_GT(expected, 5u);  // both kinds, many of each
    ASSERT_LT(expected, tets.size() - 5);
    Mesh kept = m;
    EXPECT_EQ(detail::drop_specks(kept, s, 3.5).pieces, expected);
    EXPECT_EQ(kept.triangle_count(), m.triangle_count() - 4 * expected);
  }
}
