// The clip of a padded lattice's surface to the volume's box (src/extract/box_clip.hpp): written
// over the input's arrays, it is the mesh the copying clip makes, whichever way it goes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "adaptiso/volume.hpp"
#include "extract/box_clip.hpp"

using namespace adaptiso;
using detail::clip_to_volume_box;
using detail::Clipped;

namespace {

// A lattice of 6³ points padding a volume of 5 x 4 x 5 voxels, its far faces at x = 4, y = 3, z = 4,
// in a frame with spacing, origin and a rotation (the clip works in index space).
GridSource clip_test_source() {
  GridSource s;
  s.dims = {6, 6, 6};
  s.volume_dims = {5, 4, 5};
  s.spacing = {0.5, 1.0, 2.0};
  s.origin = {10, -3, 7};
  const double c = std::cos(0.4), n = std::sin(0.4);
  s.direction = {c, -n, 0, n, c, 0, 0, 0, 1};
  return s;
}

// A strip of triangles (i, i + 1, i + 2) along a random walk of steps up to 0.8 voxels through
// [0, upto]³ (past the far faces in part), mapped to the world; random normals. Its start decides
// whether the first triangles cut are cut before any is dropped (the in-place clip then copies).
Mesh clip_test_mesh(std::mt19937& rng, std::size_t triangles, const GridSource& s, double upto) {
  Volume frame;
  frame.dims = s.dims, frame.spacing = s.spacing, frame.origin = s.origin, frame.direction = s.direction;
  std::uniform_real_distribution<double> start(0, upto), step(-0.8, 0.8), unit(-1, 1);
  Vec3 p{start(rng), start(rng), start(rng)};
  Mesh m;
  for (std::size_t v = 0; v < triangles + 2; ++v) {
    const Vec3 w = frame.voxel_to_world(p[0], p[1], p[2]);
    m.positions.push_back({float(w[0]), float(w[1]), float(w[2])});
    m.normals.push_back({float(unit(rng)), float(unit(rng)), float(unit(rng))});
    for (double& x : p) x = std::clamp(x + step(rng), 0.0, upto);
  }
  for (std::uint32_t t = 0; t < triangles; ++t) m.triangles.push_back({t, t + 1, t + 2});
  return m;
}

}  // namespace

// Random meshes cut by up to three face planes: the in-place clip equals the copying one, both
// ways it can go are met (in place, and through a copy where a triangle's pieces would run ahead
// of its place), and a surface inside the box is left as it is.
TEST(BoxClip, InPlaceClipIsTheCopyingClipsMesh) {
  const GridSource s = clip_test_source();
  std::mt19937 rng(5);
  int ways[3] = {0, 0, 0};
  for (int round = 0; round < 200; ++round) {
    const Mesh in = clip_test_mesh(rng, 1 + round % 80, s, 4 + 0.5 * (round % 4));
    Mesh copied;
    const bool cut = clip_to_volume_box(in, s, copied);
    Mesh inplace = in;
    const Clipped how = clip_to_volume_box(inplace, s);
    ++ways[static_cast<int>(how)];
    if (!cut) {
      EXPECT_EQ(how, Clipped::nothing);
      EXPECT_EQ(inplace.triangles, in.triangles);
      continue;
    }
    ASSERT_NE(how, Clipped::nothing) << round;
    EXPECT_EQ(inplace.positions, copied.positions) << round;
    EXPECT_EQ(inplace.normals, copied.normals) << round;
    EXPECT_EQ(inplace.triangles, copied.triangles) << round;
  }
  EXPECT_GT(ways[static_cast<int>(Clipped::in_place)], 10);
  EXPECT_GT(ways[static_cast<int>(Clipped::copied)], 10);
}

// A lattice that is not padded is never clipped.
TEST(BoxClip, AnUnpaddedLatticeIsLeftAlone) {
  GridSource s = clip_test_source();
  s.volume_dims = s.dims;
  std::mt19937 rng(6);
  Mesh m = clip_test_mesh(rng, 40, s, 5);
  const Mesh before = m;
  EXPECT_EQ(clip_to_volume_box(m, s), Clipped::nothing);
  EXPECT_EQ(m.triangles, before.triangles);
  EXPECT_EQ(m.positions, before.positions);
}
