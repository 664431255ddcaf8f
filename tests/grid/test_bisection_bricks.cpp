// The error hierarchy brick by brick (bisection_bricks.hpp) against the whole-volume one: the same
// bytes (codes, displacement codes, scales) for random, analytic and real volumes of odd and
// anisotropic sizes, every brick side from 2 to beyond the root cube, with and without the
// displacement criterion; bricks combined in any order; the same grid selected from either; and a
// perturbed hand-up that must show.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "adaptiso/bisection.hpp"
#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/volume_io.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

template <class F>
Volume field(Dims d, ScalarType type, F&& f) {
  Volume v = make_volume(d, type);
  for (std::int64_t z = 0; z < d[2]; ++z)
    for (std::int64_t y = 0; y < d[1]; ++y)
      for (std::int64_t x = 0; x < d[0]; ++x) v.set(v.index(x, y, z), f(double(x), double(y), double(z)));
  return v;
}

Volume random_volume(Dims d, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-100, 100);
  return field(d, ScalarType::f32, [&](double, double, double) { return u(rng); });
}

Volume sphere(Dims d) {
  return field(d, ScalarType::i16, [&](double x, double y, double z) {
    return 40 * std::sqrt((x - d[0] / 2.3) * (x - d[0] / 2.3) + (y - d[1] / 2.1) * (y - d[1] / 2.1) + (z - d[2] / 1.9) * (z - d[2] / 1.9));
  });
}

Volume sines(Dims d) {
  return field(d, ScalarType::f32,
               [](double x, double y, double z) { return std::sin(0.37 * x) + std::sin(0.23 * y + 1) + std::sin(0.51 * z + 2); });
}

void expect_same(const BisectionErrors& a, const BisectionErrors& b, const std::string& what) {
  EXPECT_EQ(a.root_size, b.root_size) << what;
  EXPECT_EQ(a.codes.scale, b.codes.scale) << what;
  EXPECT_EQ(a.codes.zero, b.codes.zero) << what;
  EXPECT_EQ(a.displacement_codes.scale, b.displacement_codes.scale) << what;
  EXPECT_EQ(a.displacement_codes.zero, b.displacement_codes.zero) << what;
  ASSERT_EQ(a.code.size(), b.code.size()) << what;
  ASSERT_EQ(a.displacement_code.size(), b.displacement_code.size()) << what;
  std::size_t differ = 0, first = a.code.size();
  for (std::size_t i = 0; i < a.code.size(); ++i)
    if (a.code[i] != b.code[i] || (!a.displacement_code.empty() && a.displacement_code[i] != b.displacement_code[i])) {
      ++differ;
      first = std::min(first, i);
    }
  EXPECT_EQ(differ, 0u) << what << ": first at voxel " << first;
}

// Every brick side from 2 to twice the root cube, with and without the displacement criterion.
void expect_bricked_equal(const Volume& v, const std::string& name) {
  const ValueRange range = value_range(v);
  for (bool displacement : {false, true}) {
    const BisectionErrors whole = bisection_errors(v, range, displacement);
    for (std::int64_t side = 2; side <= 2 * whole.root_size; side *= 2) {
      std::uint64_t bytes = 0;
      const BisectionErrors bricked = bisection_errors_bricked(v.dims, range, side, region_source(v), displacement, {}, &bytes);
      expect_same(whole, bricked,
                  fmt::format("{} {}x{}x{} side {} displacement {}", name, v.dims[0], v.dims[1], v.dims[2], side, displacement));
      if (side >= whole.root_size) {
        EXPECT_LE(bytes, 64u * 8) << "one brick hands up only its coarse point and root centre";
      }
    }
  }
}

}  // namespace

TEST(BisectionBricks, RandomVolumesOfOddAndAnisotropicSizes) {
  unsigned seed = 1;
  for (Dims d : {Dims{17, 9, 33}, Dims{2, 40, 7}, Dims{31, 64, 5}, Dims{2, 2, 2}, Dims{3, 2, 5}, Dims{33, 17, 2}})
    expect_bricked_equal(random_volume(d, seed++), "random");
}

TEST(BisectionBricks, AnalyticFields) {
  for (Dims d : {Dims{64, 64, 64}, Dims{17, 9, 33}, Dims{31, 64, 5}}) {
    expect_bricked_equal(sphere(d), "sphere");
    expect_bricked_equal(sines(d), "sines");
  }
}

TEST(BisectionBricks, PowerOfTwoPlusOne) { expect_bricked_equal(sines({65, 65, 65}), "sines"); }

TEST(BisectionBricks, SaddleFlatRegionAndFarFacesOnBrickPlanes) {
  // x² − y²: zero δ along the diagonals; a constant half: every bound 0 across the planes there;
  // dims 2^k + 1 and 2^k·3 + 1 put the box's far faces on brick planes.
  for (Dims d : {Dims{33, 33, 17}, Dims{25, 49, 13}}) {
    expect_bricked_equal(field(d, ScalarType::f32, [](double x, double y, double) { return (x - 11) * (x - 11) - (y - 9) * (y - 9); }),
                         "saddle");
    expect_bricked_equal(
        field(d, ScalarType::u16, [](double x, double y, double z) { return x < 16 ? 500.0 : 500 + 7 * (x - 16) * y + z; }), "flat half");
  }
}

TEST(BisectionBricks, RealVolumeCrop) {
  REQUIRE_DATA(data);
  const Volume full = read_volume(data + "/ct_chest_lidc2.nhdr");
  Volume v = make_volume({41, 37, 23}, full.type);
  for (std::int64_t z = 0; z < 23; ++z)
    for (std::int64_t y = 0; y < 37; ++y)
      for (std::int64_t x = 0; x < 41; ++x) v.set(v.index(x, y, z), full.at(100 + x, 110 + y, 60 + z));
  expect_bricked_equal(v, "chest crop");
}

TEST(BisectionBricks, ShuffledBricksGiveTheSameBytes) {
  const Volume v = random_volume({23, 18, 29}, 7);
  const ValueRange range = value_range(v);
  const RegionSource source = region_source(v);
  for (bool displacement : {false, true}) {
    const BisectionErrors whole = bisection_errors(v, range, displacement);
    for (std::int64_t side : {2, 4, 8}) {
      const BrickGrid bricks = brick_grid(v.dims, side);
      std::vector<BrickErrors> results;
      for (std::int64_t n = 0; n < bricks.size(); ++n)
        results.push_back(bisection_brick_errors(bricks, n, source(bricks.reads(n, displacement)), range, displacement));
      std::shuffle(results.begin(), results.end(), std::mt19937(static_cast<unsigned>(side)));
      expect_same(whole, bisection_combine_bricks(bricks, std::move(results), range, displacement), fmt::format("shuffled side {}", side));
    }
  }
}

TEST(BisectionBricks, PerturbedHandUpShows) {
  const Volume v = sines({33, 20, 17});
  const ValueRange range = value_range(v);
  const RegionSource source = region_source(v);
  const BisectionErrors whole = bisection_errors(v, range, true);
  const BrickGrid bricks = brick_grid(v.dims, 8);
  std::vector<BrickErrors> results;
  for (std::int64_t n = 0; n < bricks.size(); ++n)
    results.push_back(bisection_brick_errors(bricks, n, source(bricks.reads(n, true)), range, true));
  // A seam diamond whose code is small: a larger bound handed up for it must raise it.
  BrickErrors& r = results[results.size() / 2];
  std::size_t pick = r.seam_voxel.size();
  for (std::size_t i = 0; i < r.seam_voxel.size(); ++i)
    if (whole.code[static_cast<std::size_t>(r.seam_voxel[i])] < 200) pick = i;
  ASSERT_LT(pick, r.seam_voxel.size());
  const auto voxel = static_cast<std::size_t>(r.seam_voxel[pick]);
  r.seam_hi[pick] += range.max - range.min;
  const BisectionErrors perturbed = bisection_combine_bricks(bricks, std::move(results), range, true);
  EXPECT_GT(perturbed.code[voxel], whole.code[voxel]);
}

TEST(BisectionBricks, SelectedGridIsTheWholeVolumes) {
  for (bool displacement : {false, true}) {
    const Volume v = sphere({37, 29, 41});
    const ValueRange range = value_range(v);
    BisectionOptions o;
    o.max_error = 0.02 * (range.max - range.min);
    o.max_displacement = displacement ? 0.5 : 0;
    const BisectionGrid whole = bisection_select(v, range, bisection_errors(v, range, displacement), o);
    const BisectionGrid bricked = bisection_select(v, range, bisection_errors_bricked(v.dims, range, 8, region_source(v), displacement), o);
    EXPECT_EQ(whole.grid.ijk, bricked.grid.ijk);
    EXPECT_EQ(whole.grid.tets, bricked.grid.tets);
    EXPECT_EQ(whole.grid.values, bricked.grid.values);
    EXPECT_EQ(whole.hierarchy.error_code, bricked.hierarchy.error_code);
    EXPECT_EQ(whole.hierarchy.displacement_code, bricked.hierarchy.displacement_code);
    EXPECT_EQ(whole.error_bound, bricked.error_bound);
  }
}

TEST(BisectionBricks, BadBrickSidesAndFlatVolumesAreRefused) {
  for (std::int64_t side : {0, 1, 3, 6, -4}) {
    try {
      brick_grid({9, 9, 9}, side);
      ADD_FAILURE() << side;
    } catch (const OptionError& e) {
      EXPECT_EQ(e.option(), "brick_side");
    }
  }
  EXPECT_THROW(brick_grid({1, 9, 9}, 4), InputError);
  EXPECT_THROW(brick_grid({9, 9, 1}, 4), InputError);
  EXPECT_EQ(brick_grid({9, 9, 9}, 64).size(), 1);  // beyond the root cube: one brick
  const Volume v = sines({9, 9, 9});
  const BrickGrid bricks = brick_grid(v.dims, 4);
  EXPECT_THROW(bisection_brick_errors(bricks, 0, v, value_range(v)), InputError);  // not the brick's region
  EXPECT_THROW(bisection_combine_bricks(bricks, {}, value_range(v)), InputError);  // bricks missing
}
