// Vertex gradients (§2.3) of analytic fields, and the piecewise-linear error of a linear field.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <iterator>
#include <random>

#include "adaptiso/gradients.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {}  // namespace

TEST(Gradients, LinearFieldIsExact) {
  Volume v = make_volume({9, 8, 7}, ScalarType::f64);
  v.spacing = {0.5, 1.0, 2.0};
  for (std::int64_t z = 0; z < 7; ++z)
    for (std::int64_t y = 0; y < 8; ++y)
      for (std::int64_t x = 0; x < 9; ++x) v.set(v.index(x, y, z), 3 + 2 * (0.5 * x) - 1.5 * y + 0.25 * (2.0 * z));
  std::mt19937 rng(2);
  TetGrid g = testutil::build_grid(v, testutil::random_kept(v, rng, 3));
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
  TetGrid g = testutil::build_grid(v, testutil::all_voxels(v));
  double worst = 0;
  for (std::size_t i = 0; i < g.vertex_count(); ++i) {
    const auto& p = g.ijk[i];
    if (p[0] == 0 || p[1] == 0 || p[2] == 0 || p[0] == n - 1 || p[1] == n - 1 || p[2] == n - 1) continue;  // one-sided at the border
    worst = std::max(
        {worst, std::abs(g.gradients[i][0] - 0.02 * p[0]), std::abs(g.gradients[i][1] - 0.04 * p[1]), std::abs(g.gradients[i][2] - 0.5)});
  }
  EXPECT_LT(worst, 0.05);  // second-order terms over a 1-voxel ring
}

// Grid files record the RMS error; two identical runs wrote different bytes because voxels on
// shared faces were measured in whichever tetrahedron claimed them first and the squares were
// summed in thread order.
TEST(Gradients, PiecewiseLinearErrorIsTheSameForAnyThreadCount) {
  Volume v = make_synthetic("marschner-lobb", 24, ScalarType::f32);
  std::mt19937 rng(5);
  const TetGrid g = testutil::build_grid(v, testutil::random_kept(v, rng, 7));
  ReconstructionError one, many;
  tbb::task_arena(1).execute([&] { one = piecewise_linear_error(v, g); });
  for (int run = 0; run < 5; ++run) {
    tbb::task_arena(4).execute([&] { many = piecewise_linear_error(v, g); });
    EXPECT_EQ(one.max, many.max);
    EXPECT_EQ(one.rms, many.rms);
    EXPECT_EQ(one.voxels, many.voxels);
  }
  EXPECT_EQ(one.voxels, v.voxel_count());
}
