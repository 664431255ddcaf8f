// Volume model: types, indexing, coordinates, value range, histogram, size checks.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "adaptiso/error.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/volume.hpp"
#include "test_util.hpp"

using namespace adaptiso;

TEST(Volume, ScalarTypesRoundTrip) {
  for (auto t : {ScalarType::u8, ScalarType::i8, ScalarType::u16, ScalarType::i16, ScalarType::u32, ScalarType::i32, ScalarType::f32,
                 ScalarType::f64}) {
    auto p = parse_scalar_type(scalar_name(t));
    ASSERT_TRUE(p);
    EXPECT_EQ(*p, t);
  }
  EXPECT_EQ(parse_scalar_type("short"), ScalarType::i16);
  EXPECT_EQ(parse_scalar_type("double"), ScalarType::f64);
  EXPECT_FALSE(parse_scalar_type("complex"));
  EXPECT_EQ(scalar_size(ScalarType::f64), 8u);
}

TEST(Volume, IndexAndTypedAccessAllTypes) {
  for (auto t : {ScalarType::u8, ScalarType::i8, ScalarType::u16, ScalarType::i16, ScalarType::u32, ScalarType::i32, ScalarType::f32,
                 ScalarType::f64}) {
    Volume v = testutil::pattern_volume({5, 4, 3}, t);
    EXPECT_EQ(v.voxel_count(), 60);
    EXPECT_EQ(v.bytes.size(), 60 * scalar_size(t));
    EXPECT_EQ(v.index(2, 3, 1), 2 + 5 * (3 + 4 * 1));
    bool uns = t == ScalarType::u8 || t == ScalarType::u16 || t == ScalarType::u32;
    EXPECT_EQ(v.at(2, 3, 1), (2 + 9 + 7) % 100 - (uns ? 0 : 20));
    double sum = visit_values(v, [](auto s) {
      double acc = 0;
      for (auto x : s) acc += static_cast<double>(x);
      return acc;
    });
    double ref = 0;
    for (std::int64_t i = 0; i < 60; ++i) ref += v.at(i);
    EXPECT_EQ(sum, ref);
  }
}

TEST(Volume, SetClampsAndRounds) {
  Volume v = make_volume({2, 1, 1}, ScalarType::u8);
  v.set(0, 300);
  v.set(1, -5.7);
  EXPECT_EQ(v.at(0), 255);
  EXPECT_EQ(v.at(1), 0);
  Volume w = make_volume({1, 1, 1}, ScalarType::i16);
  w.set(0, 2.5);
  EXPECT_EQ(w.at(0), 3);
}

TEST(Volume, CoordinatesWithSpacingOriginAndDirection) {
  Volume v = make_volume({4, 4, 4}, ScalarType::f32);
  v.spacing = {0.5, 2, 3};
  v.origin = {10, 20, 30};
  auto w = v.voxel_to_world(2, 1, 1);
  EXPECT_DOUBLE_EQ(w[0], 11);
  EXPECT_DOUBLE_EQ(w[1], 22);
  EXPECT_DOUBLE_EQ(w[2], 33);
  // A rotation by 90° about z: index x runs along world y, index y along world −x.
  v.direction = {0, -1, 0, 1, 0, 0, 0, 0, 1};
  EXPECT_TRUE(v.is_oblique());
  w = v.voxel_to_world(2, 1, 1);
  EXPECT_DOUBLE_EQ(w[0], 10 - 2);
  EXPECT_DOUBLE_EQ(w[1], 20 + 1);
  auto back = v.world_to_voxel(w);
  EXPECT_NEAR(back[0], 2, 1e-12);
  EXPECT_NEAR(back[1], 1, 1e-12);
  EXPECT_NEAR(back[2], 1, 1e-12);
}

TEST(Volume, ValueRangeAndHistogram) {
  Volume v = make_volume({10, 10, 10}, ScalarType::i16);
  for (std::int64_t i = 0; i < 1000; ++i) v.set(i, static_cast<double>(i % 10) - 3);
  auto r = value_range(v);
  EXPECT_EQ(r.min, -3);
  EXPECT_EQ(r.max, 6);
  auto h = histogram(v, 10);
  ASSERT_EQ(h.counts.size(), 10u);
  for (auto c : h.counts) EXPECT_EQ(c, 100u);  // the maximum falls into the last bin
  auto h1 = histogram(v, 1);
  EXPECT_EQ(h1.counts[0], 1000u);
}

TEST(Volume, ConstantVolumeHistogram) {
  Volume v = make_volume({3, 3, 3}, ScalarType::f32);
  auto h = histogram(v, 4);
  EXPECT_EQ(h.counts[0], 27u);
}

TEST(Volume, RejectsBadDimensions) {
  EXPECT_THROW(make_volume({0, 4, 4}, ScalarType::u8), InputError);
  EXPECT_THROW(make_volume({-1, 4, 4}, ScalarType::u8), InputError);
  EXPECT_THROW(make_volume({std::int64_t{1} << 40, std::int64_t{1} << 40, 4}, ScalarType::u8), InputError);
  EXPECT_THROW(make_volume({std::numeric_limits<std::int64_t>::max(), 2, 2}, ScalarType::f64), InputError);
}

TEST(Volume, CheckFiniteRejectsNaNAndInf) {
  Volume v = make_volume({3, 3, 3}, ScalarType::f32);
  EXPECT_NO_THROW(check_finite(v, "x"));
  v.set(13, std::numeric_limits<double>::quiet_NaN());
  try {
    check_finite(v, "file.nrrd");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("file.nrrd"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("1,1,1"), std::string::npos);
  }
  v.set(13, 0);
  v.set(0, std::numeric_limits<double>::infinity());
  EXPECT_THROW(check_finite(v, "x"), InputError);
}

TEST(Volume, FractionOfTheValueRange) {
  const ValueRange r{-100, 300};
  EXPECT_EQ(from_fraction(r, 0.25, FractionOf::value, "iso"), 0.0);  // an iso-value: min + f·(max − min)
  EXPECT_EQ(from_fraction(r, 1, FractionOf::value, "iso"), 300.0);
  EXPECT_EQ(from_fraction(r, 0.25, FractionOf::width, "max_error"), 100.0);  // an error bound: f·(max − min)
  EXPECT_EQ(from_fraction(r, 0, FractionOf::width, "max_error"), 0.0);
  // The same arithmetic the command line and Python used before, bit for bit.
  const ValueRange ct{-1024, 3071};
  EXPECT_EQ(from_fraction(ct, 0.37, FractionOf::value, "iso"), ct.min + 0.37 * (ct.max - ct.min));
  EXPECT_EQ(from_fraction(ct, 0.02, FractionOf::width, "max_error"), 0.02 * (ct.max - ct.min));
  // A range from corrupt metadata overflows when scaled: refused, naming what was scaled.
  const ValueRange wide{-1e308, 1e308};
  try {
    from_fraction(wide, 0.5, FractionOf::width, "--max-error");
    FAIL() << "no throw";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("--max-error: the value range"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("too wide to scale"), std::string::npos) << e.what();
  }
  EXPECT_THROW(from_fraction(wide, 0.75, FractionOf::value, "iso"), InputError);
}

TEST(Synthetic, SphereMatchesDocumentedDefinition) {
  Volume v = make_synthetic("sphere", 50, ScalarType::i16);
  EXPECT_EQ(v.type, ScalarType::i16);
  const double c = 24.5, R = 12.5;
  EXPECT_EQ(v.at(25, 25, 25), 1000);  // inside
  double r = std::sqrt(3 * c * c);
  EXPECT_EQ(v.at(0, 0, 0), std::round(1000 * R / r));
  auto range = value_range(v);
  EXPECT_EQ(range.max, 1000);
  EXPECT_EQ(range.min, std::round(1000 * R / r));
  EXPECT_THROW(make_synthetic("nope", 10, ScalarType::f32), InputError);
  EXPECT_THROW(make_synthetic("sphere", 1, ScalarType::f32), InputError);
}

TEST(Synthetic, MarschnerLobbRange) {
  Volume v = make_synthetic("marschner-lobb", 41, ScalarType::f32);
  auto r = value_range(v);
  EXPECT_GE(r.min, 0.0);
  EXPECT_LE(r.max, 1.0);
  EXPECT_GT(r.max - r.min, 0.9);
}
