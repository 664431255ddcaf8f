// Queries of a bisection grid at a coarser error against preparing at that error: the same
// triangles; every voxel in the tetrahedra used within the reported bound (brute force, exact
// barycentric coordinates); closed, oriented surfaces; refusals.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <random>

#include "adaptiso/extractor.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

using Corner = std::array<float, 3>;
using Triangle = std::array<Corner, 3>;

std::vector<Triangle> triangles_of(const Mesh& m) { return testutil::sorted_triangles(m); }

}  // namespace

TEST(HierarchyQuery, EqualsPreparingAtThatErrorForEveryIsoAndError) {
  for (const char* name : {"sphere", "marschner-lobb", "torus"})
    for (std::int64_t n : {23, 33}) {
      Volume v = make_synthetic(name, n, ScalarType::f32);
      v.spacing = {1.0, 0.75, 1.5};
      const ValueRange r = value_range(v);
      const double range = r.max - r.min;
      const auto fine = testutil::prepared_at(v, 0.005 * range, false);
      const HierarchyQuery query(fine);
      for (double rel : {0.005, 0.02, 0.07, 0.25, std::numeric_limits<double>::infinity()}) {
        const auto coarse = testutil::prepared_at(v, rel * range, false);
        Extractor ex(coarse);
        for (double f : {0.3, 0.55, 0.8}) {
          const double iso = r.min + f * range;
          ex.extract(iso);
          HierarchyQueryStats st;
          const Mesh q = query.extract(iso, rel * range, 0, &st);
          EXPECT_EQ(triangles_of(q), triangles_of(ex.mesh())) << name << " " << n << " rel " << rel << " iso " << f;
          EXPECT_EQ(q.vertex_count(), ex.mesh().vertex_count());
          EXPECT_LE(st.error_bound, std::max(rel * range, query.prepared_error()));
        }
      }
    }
}

TEST(HierarchyQuery, EveryVoxelOfTheTetrahedraUsedIsWithinTheReportedBound) {
  std::mt19937 rng(8);
  for (auto d : {Dims{17, 17, 17}, Dims{30, 21, 12}, Dims{9, 40, 5}}) {
    Volume v = make_volume(d, ScalarType::f32);
    for (std::int64_t z = 0; z < d[2]; ++z)
      for (std::int64_t y = 0; y < d[1]; ++y)
        for (std::int64_t x = 0; x < d[0]; ++x)
          v.set(v.index(x, y, z), std::sin(0.3 * x) * std::cos(0.2 * y) + 0.05 * z + 0.02 * double(rng() % 10));
    const ValueRange r = value_range(v);
    const auto grid = testutil::prepared_at(v, 0.01, false);
    const HierarchyQuery query(grid);
    for (double e : {0.01, 0.05, 0.2, 0.6}) {
      for (double f : {0.25, 0.5, 0.75}) {
        HierarchyQueryStats st;
        std::vector<std::array<std::uint32_t, 4>> used;
        const Mesh m = query.extract(r.min + f * (r.max - r.min), e, 0, &st, &used);
        EXPECT_EQ(used.size(), st.tetrahedra);
        EXPECT_LE(st.error_bound, std::max(e, query.prepared_error()) + 1e-12);
        EXPECT_LE(testutil::largest_error(v, grid->grid, used), st.error_bound + 1e-9) << d[0] << " e " << e << " f " << f;
      }
    }
  }
}

TEST(HierarchyQuery, SurfacesAreClosedAndOrientedAtEveryError) {
  const Volume v = make_synthetic("sphere", 48, ScalarType::i16);
  const auto grid = testutil::prepared_at(v, 5, false);
  const HierarchyQuery query(grid);
  std::size_t previous = ~std::size_t{0};
  for (double e : {5.0, 20.0, 60.0, 150.0, 400.0}) {
    const Mesh m = query.extract(700, e);
    const auto c = testutil::edge_census(m, v.dims, v.spacing);
    EXPECT_EQ(c.boundary, 0u) << e;
    EXPECT_EQ(c.nonmanifold, 0u) << e;
    EXPECT_EQ(c.misoriented, 0u) << e;
    EXPECT_EQ(c.euler, 2) << e;
    EXPECT_GT(mesh_volume(m), 0) << e;
    EXPECT_LE(m.triangle_count(), previous) << "a coarser error gives no more triangles";
    previous = m.triangle_count();
  }
}

TEST(HierarchyQuery, SameSurfaceForAnyThreadCountAndRefusals) {
  const Volume v = make_synthetic("marschner-lobb", 40, ScalarType::f32);
  const auto grid = testutil::prepared_at(v, 0.002, false);
  const HierarchyQuery query(grid);
  Mesh one, four;
  tbb::task_arena(1).execute([&] { one = query.extract(0.5, 0.03); });
  tbb::task_arena(4).execute([&] { four = query.extract(0.5, 0.03); });
  EXPECT_EQ(one.triangles, four.triangles);
  EXPECT_EQ(one.positions, four.positions);
  // Below the prepared error: answered at the prepared error.
  HierarchyQueryStats st;
  query.extract(0.5, 0, 0, &st);
  EXPECT_EQ(st.max_error, query.prepared_error());
  EXPECT_THROW(query.extract(std::nan(""), 1), OptionError);
  EXPECT_THROW(query.extract(0.5, -1), OptionError);
  PrepareOptions o;
  o.grid = GridKind::delaunay;
  o.max_error = 0.1;
  EXPECT_THROW(HierarchyQuery(std::make_shared<const PreparedGrid>(prepare(v, o))), InputError);
}

TEST(HierarchyQuery, IsoValuesEqualToVertexValuesGiveThePreparedSurface) {
  // Ties: a vertex at the iso-value counts as above it, in the pruning as in marching.
  std::mt19937 rng(21);
  for (int trial = 0; trial < 6; ++trial) {
    const Dims d{9 + std::int64_t(rng() % 9), 9 + std::int64_t(rng() % 9), 5 + std::int64_t(rng() % 9)};
    Volume v = make_volume(d, ScalarType::i16);
    for (std::int64_t z = 0; z < d[2]; ++z)
      for (std::int64_t y = 0; y < d[1]; ++y)
        for (std::int64_t x = 0; x < d[0]; ++x)
          v.set(v.index(x, y, z), std::round(4 * std::sin(0.4 * x + 0.3 * y) + z % 3 + double(rng() % 2)));
    const auto fine = testutil::prepared_at(v, 0, false);
    const HierarchyQuery query(fine);
    for (double e : {0.5, 1.0, 2.5})
      for (double iso : {-3.0, -1.0, 0.0, 1.0, 2.0, 4.0}) {
        Extractor ex(testutil::prepared_at(v, e, false));
        ex.extract(iso);
        EXPECT_EQ(triangles_of(query.extract(iso, e)), triangles_of(ex.mesh())) << trial << " e " << e << " iso " << iso;
      }
  }
}

TEST(Coarsen, GivesTheGridPreparedAtThatErrorWithoutTheVolume) {
  for (const char* name : {"sphere", "marschner-lobb"})
    for (Dims d : {Dims{33, 33, 33}, Dims{40, 23, 17}}) {
      Volume v = make_synthetic(name, d[0], ScalarType::f32);
      if (d[1] != d[0]) {  // a box that is not a cube: crop
        Volume c = make_volume(d, ScalarType::f32);
        for (std::int64_t z = 0; z < d[2]; ++z)
          for (std::int64_t y = 0; y < d[1]; ++y)
            for (std::int64_t x = 0; x < d[0]; ++x) c.set(c.index(x, y, z), v.at(x, y, z));
        v = c;
      }
      const ValueRange r = value_range(v);
      const auto fine = testutil::prepared_at(v, 0.003 * (r.max - r.min), false);
      for (double rel : {0.003, 0.01, 0.05, 0.3, std::numeric_limits<double>::infinity()}) {
        const PreparedGrid coarse = coarsen(*fine, rel * (r.max - r.min));
        const auto direct = testutil::prepared_at(v, rel * (r.max - r.min), false);
        EXPECT_EQ(coarse.grid.tets, direct->grid.tets) << name << " rel " << rel;
        EXPECT_EQ(coarse.grid.ijk, direct->grid.ijk);
        EXPECT_EQ(coarse.grid.values, direct->grid.values);
        EXPECT_EQ(coarse.grid.gradients, direct->grid.gradients);
        EXPECT_EQ(coarse.hierarchy->error_code, direct->hierarchy->error_code);
        EXPECT_EQ(coarse.hierarchy->value_span, direct->hierarchy->value_span);
        EXPECT_EQ(coarse.hierarchy->error_threshold, direct->hierarchy->error_threshold);
        EXPECT_EQ(coarse.index.by_min, direct->index.by_min);
      }
    }
}

TEST(HierarchyQuery, ACancelledQueryThrowsAndNeverReturnsAPartialSurface) {
  // Python's Ctrl-C raises the flag (interruptible, adaptiso_module.cpp). Before the flag was
  // taken, grid.extract(iso, max_error=...) ran to its end whatever the user pressed.
  const Volume v = make_synthetic("marschner-lobb", 65, ScalarType::f32);
  const auto grid = testutil::prepared_at(v, 0.002, false);
  const HierarchyQuery query(grid);
  const Mesh reference = query.extract(0.4, 0);
  std::atomic<bool> raised{true};
  EXPECT_THROW(query.extract(0.4, 0, 0, nullptr, nullptr, &raised), ExtractCancelled);
  std::atomic<bool> lowered{false};
  EXPECT_EQ(query.extract(0.4, 0, 0, nullptr, nullptr, &lowered).triangles, reference.triangles);
  // Raised from another thread at some point of the query: whole or cancelled, nothing between.
  for (int delay_us : {0, 200, 1000, 3000, 10000})
    testutil::expect_whole_or_cancelled([&](const std::atomic<bool>* flag) { return query.extract(0.4, 0, 0, nullptr, nullptr, flag); },
                                        reference, delay_us);
}
