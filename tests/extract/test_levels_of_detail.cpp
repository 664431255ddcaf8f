// Levels of detail (levels_of_detail.hpp): the ladder of bounds, each level the grid coarsen()
// gives, and the choice of a level for an error or a triangle budget.
#include <gtest/gtest.h>

#include <memory>

#include "adaptiso/extractor.hpp"
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

TEST(LevelsOfDetail, OnlyForBisectionGrids) { EXPECT_THROW(LevelsOfDetail(torus(0.05, GridKind::delaunay)), InputError); }
