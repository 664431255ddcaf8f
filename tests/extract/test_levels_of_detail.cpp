// Levels of detail (levels_of_detail.hpp): the ladder of bounds, each level the grid coarsen()
// gives, and the choice of a level for an error or a triangle budget.
#include <gtest/gtest.h>

#include <memory>
#include <random>

#include "adaptiso/extractor.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/levels_of_detail.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

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
    Extractor ex(g);
    triangles[k] = ex.extract(iso).triangles;
    lod.record(k, triangles[k]);
    // The surface's own error: that of the tetrahedra it cuts, voxel by voxel.
    std::vector<std::array<std::uint32_t, 4>> cut;
    for (std::uint32_t t : ex.active()) cut.push_back(g->grid.tets[t]);
    const double own = surface_error_bound(*g, ex.active());
    EXPECT_LE(testutil::largest_error(v, g->grid, cut), own * (1 + 1e-9)) << "level " << k;
    EXPECT_LE(own, lod.bound(k)) << "level " << k;
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
      if (best < lod.size()) {
        EXPECT_EQ(lod.level_for_budget(triangles[k], finest), best) << "budget " << triangles[k] << " finest " << finest;
      }
    }
  for (std::size_t k = 0; k < lod.size(); ++k) EXPECT_EQ(lod.cell_floor(lod.level_for_error(lod.bound(k))), 0) << k;
}

TEST(LevelsOfDetail, FlooredSurfaceErrorIsThatOfTheTetrahedraItCuts) {
  // A sphere with one spike of the whole range far from the surface: the floored grid's bound is
  // the spike's, the surface's only that of the tetrahedra it cuts, and holds voxel by voxel.
  Volume v = make_synthetic("sphere", 33, ScalarType::f32);
  const ValueRange r = value_range(v);
  v.set(v.index(2, 2, 2), r.max + (r.max - r.min));
  PrepareOptions o;
  o.max_error = 0.01;
  o.relative = true;
  const auto fine = std::make_shared<const PreparedGrid>(prepare(v, o));
  const auto floored = std::make_shared<const PreparedGrid>(coarsen_floored(*fine, fine->stats.error_bound, 2));
  EXPECT_FALSE(floored->hierarchy.has_value());
  ASSERT_EQ(floored->tet_error_code.size(), floored->grid.tet_count());
  EXPECT_EQ(surface_error_bound(*fine, {}), fine->stats.error_bound) << "elsewhere the grid's bound";
  const double iso = 0.5 * (r.min + r.max);
  Extractor ex(floored);
  ASSERT_GT(ex.extract(iso).triangles, 0u);
  std::vector<std::array<std::uint32_t, 4>> cut;
  for (std::uint32_t t : ex.active()) cut.push_back(floored->grid.tets[t]);
  const double own = surface_error_bound(*floored, ex.active());
  EXPECT_LE(testutil::largest_error(v, floored->grid, cut), own * (1 + 1e-9));
  EXPECT_LT(own, 0.25 * floored->stats.error_bound);
  EXPECT_GE(floored->stats.error_bound, r.max - r.min) << "the spike's diamond, kept whole";
  EXPECT_EQ(surface_error_bound(*floored, {}), 0.0);
}

TEST(LevelsOfDetail, BudgetFollowsTheCountsAtTheIsoValueAsked) {
  // A level over the budget at one iso-value must not be shunned at another where it fits.
  const auto fine = torus(0.001);
  LevelsOfDetail lod(fine);
  lod.build();
  ASSERT_GE(lod.size(), 6u);
  const double lo = fine->grid.source.min, hi = fine->grid.source.max;
  const double big = lo + 0.2 * (hi - lo), small = lo + 0.8 * (hi - lo);
  for (std::size_t k = 0; k < lod.size(); ++k) {
    lod.record(k, std::size_t{1000} >> k, big);
    lod.record(k, std::size_t{100} >> k, small);
  }
  EXPECT_EQ(lod.level_for_budget(60, 0, big), 5u);    // 1000 / 32
  EXPECT_EQ(lod.level_for_budget(60, 0, small), 1u);  // 100 / 2
  EXPECT_EQ(lod.level_for_budget(60, 0), 1u);         // no iso-value: the last counts
  // An iso-value never seen: the last counts at any iso-value.
  EXPECT_EQ(lod.level_for_budget(60, 0, lo + 0.5 * (hi - lo)), 1u);
  // A band that saw one level estimates the others from it, at a factor of 2 a level.
  lod.record(3, 40, hi);
  EXPECT_EQ(lod.level_for_budget(60, 0, hi), 3u);
  EXPECT_EQ(lod.level_for_budget(80, 0, hi), 2u);
}

TEST(LevelsOfDetail, OnlyForBisectionGrids) { EXPECT_THROW(LevelsOfDetail(torus(0.05, GridKind::delaunay)), InputError); }
