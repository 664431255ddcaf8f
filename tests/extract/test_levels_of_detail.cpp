// Levels of detail (levels_of_detail.hpp): the ladder of bounds, each level the grid coarsen()
// gives, and the choice of a level for an error or a triangle budget.
#include <gtest/gtest.h>

#include <memory>
#include <random>

#include "adaptiso/extractor.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/levels_of_detail.hpp"
#include "adaptiso/synthetic.hpp"

using namespace adaptiso;

namespace {

std::shared_ptr<const PreparedGrid> torus(double relative_error, GridKind kind = GridKind::bisection) {
  PrepareOptions o;
  o.grid = kind;
  o.max_error = relative_error;
  o.relative = true;
  return std::make_shared<const PreparedGrid>(prepare(make_synthetic("torus", 33, ScalarType::f32), o));
}

}  // namespace

TEST(LevelsOfDetail, LadderDoublesTheBoundUpToTheValueRange) {
  const auto fine = torus(0.001);
  LevelsOfDetail lod(fine);
  const double span = fine->grid.source.max - fine->grid.source.min;
  ASSERT_GE(lod.size(), 3u);
  EXPECT_EQ(lod.bound(0), fine->stats.error_bound);
  for (std::size_t k = 1; k < lod.size(); ++k) EXPECT_DOUBLE_EQ(lod.bound(k), 2 * lod.bound(k - 1));
  EXPECT_GE(lod.bound(lod.size() - 1), span);
  EXPECT_LT(lod.bound(lod.size() - 2), span);
  EXPECT_EQ(lod.built(), 1u);
  EXPECT_EQ(lod.level_for_error(1e9), 0u);  // nothing coarser is built yet
  lod.build();
  EXPECT_EQ(lod.built(), lod.size());
  for (std::size_t k = 1; k < lod.size(); ++k) {
    const auto g = lod.grid(k);
    EXPECT_LE(g->stats.error_bound, lod.bound(k));
    EXPECT_LE(g->grid.tet_count(), lod.grid(k - 1)->grid.tet_count());
    EXPECT_EQ(g->grid.tets, coarsen(*fine, lod.bound(k)).grid.tets);
  }
  EXPECT_EQ(lod.level_for_error(0), 0u);
  EXPECT_EQ(lod.level_for_error(lod.bound(2)), 2u);
  EXPECT_EQ(lod.level_for_error(0.99 * lod.bound(2)), 1u);
}

TEST(LevelsOfDetail, BudgetPicksTheFinestLevelExpectedToFit) {
  LevelsOfDetail lod(torus(0.001));
  lod.build();
  std::vector<std::size_t> triangles(lod.size());
  for (std::size_t k = 0; k < lod.size(); ++k) {
    Extractor ex(lod.grid(k));
    triangles[k] = ex.extract(0.5).triangles;
    lod.record(k, triangles[k]);
  }
  for (std::size_t k = 0; k < lod.size(); ++k) {
    const std::size_t level = lod.level_for_budget(triangles[k]);
    EXPECT_LE(triangles[level], triangles[k]);
    if (level > 0) {
      EXPECT_GT(triangles[level - 1], triangles[k]) << "a finer level fits too";
    }
  }
  EXPECT_GE(lod.level_for_budget(0, 2), 2u);  // never finer than asked
}

TEST(LevelsOfDetail, FlooredLevelsFitABudgetThatCoarserBoundsCannot) {
  // A sphere under noise of a third of the range: coarser bounds leave the noise's surface, a floor
  // of 4 voxels cuts it. Every level's bound holds voxel by voxel; the budget takes the level of
  // the smallest bound among those that fit (a brute-force reference of the rule); an error asked
  // for never lands on a floored level.
  Volume v = make_synthetic("sphere", 65, ScalarType::f32);
  std::mt19937 rng(5);
  const ValueRange r0 = value_range(v);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i)
    v.set(i, v.at(i) + std::uniform_real_distribution<double>(0, (r0.max - r0.min) / 3)(rng));
  PrepareOptions o;
  o.max_error = 0.02;
  o.relative = true;
  LevelsOfDetail lod(std::make_shared<const PreparedGrid>(prepare(v, o)));
  lod.build();
  ASSERT_EQ(lod.cell_floor(lod.size() - 2), 2) << "one floor (4 voxels) for a root cube of 64, before the coarsest level";
  EXPECT_EQ(lod.cell_floor(lod.size() - 1), 0);
  const double iso = 0.5 * (r0.min + r0.max);
  std::vector<std::size_t> triangles(lod.size());
  for (std::size_t k = 0; k < lod.size(); ++k) {
    const auto g = lod.grid(k);
    EXPECT_LE(piecewise_linear_error(v, g->grid).max, lod.bound(k) * (1 + 1e-9)) << "level " << k;
    EXPECT_EQ(g->hierarchy.has_value(), lod.cell_floor(k) == 0) << "level " << k;
    triangles[k] = Extractor(g).extract(iso).triangles;
    lod.record(k, triangles[k]);
  }
  const std::size_t floored = lod.size() - 2;
  EXPECT_GE(lod.bound(floored), lod.bound(0));
  EXPECT_LT(4 * triangles[floored], triangles[0]) << "a floor of 4 voxels cuts the noise's surface";
  for (std::size_t finest = 0; finest < lod.size(); ++finest)
    for (std::size_t k = 0; k < lod.size(); ++k) {
      std::size_t best = lod.size();
      for (std::size_t j = 0; j < lod.size(); ++j) {
        const bool allowed = j == finest || (lod.bound(j) >= lod.bound(finest) && (j > finest || lod.cell_floor(j)));
        if (!allowed || triangles[j] > triangles[k]) continue;
        if (best == lod.size() || lod.bound(j) < lod.bound(best) || (lod.bound(j) == lod.bound(best) && triangles[j] > triangles[best]))
          best = j;
      }
      if (best < lod.size())
        EXPECT_EQ(lod.level_for_budget(triangles[k], finest), best) << "budget " << triangles[k] << " finest " << finest;
    }
  for (std::size_t k = 0; k < lod.size(); ++k) EXPECT_EQ(lod.cell_floor(lod.level_for_error(lod.bound(k))), 0) << k;
}

TEST(LevelsOfDetail, OnlyForBisectionGrids) { EXPECT_THROW(LevelsOfDetail(torus(0.05, GridKind::delaunay)), InputError); }
