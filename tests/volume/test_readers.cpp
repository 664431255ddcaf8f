// Readers on files the tests write themselves (with independent encoders), and bad input.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <nlohmann/json.hpp>
#include "adaptiso/volume_io.hpp"

#include "test_util.hpp"
#include "volume/nifti_writer.hpp"

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

const ScalarType kAllTypes[] = {ScalarType::u8,  ScalarType::i8,  ScalarType::u16, ScalarType::i16,
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
      testutil::write_bytes(f,
                            fmt::format("NRRD0004\ntype: {}\ndimension: 3\nsizes: 5 3 7\nspacings: 0.5 1 2\nendian: {}\nencoding: raw\n\n",
                                        nrrd_type(type), big ? "big" : "little") +
                                data);
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
  testutil::write_bytes(t / "d.nhdr",
                        "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 6 4\nendian: little\nencoding: gzip\ndata file: d.raw.gz\n");
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
  testutil::write_bytes(t / "fmt.nhdr",
                        "NRRD0004\ntype: ushort\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: raw\ndata file: s%02d.raw 1 5 1\n");
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

TEST(ReadNifti, Nifti1And2PlainAndGzip) {
  TempDir t("nifti");
  Volume ref = testutil::pattern_volume({7, 5, 3}, ScalarType::i16);
  for (int ver : {1, 2})
    for (const char* ext : {".nii", ".nii.gz"}) {
      std::string f = t / (fmt::format("v{}", ver) + ext);
      testutil::write_nifti(f, ref, ver, 0, 0);
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
  testutil::write_nifti(t / "s.nii", ref, 1, 2.5, -10);
  Volume v = read_volume(t / "s.nii");
  EXPECT_EQ(v.type, ScalarType::f32);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) ASSERT_FLOAT_EQ(v.at(i), ref.at(i) * 2.5 - 10);
}

// ---------------- MetaImage ----------------

TEST(ReadMetaImage, LocalCompressedAndDetached) {
  TempDir t("mha");
  Volume ref = testutil::pattern_volume({6, 4, 5}, ScalarType::i16);
  std::string hdr =
      "ObjectType = Image\nNDims = 3\nDimSize = 6 4 5\nElementType = MET_SHORT\nElementSpacing = 1 2 3\n"
      "Offset = 10 20 30\nTransformMatrix = 1 0 0 0 -1 0 0 0 1\nElementByteOrderMSB = False\n";
  std::string z = testutil::compress(testutil::bytes_of(ref), false);
  testutil::write_bytes(t / "c.mha",
                        hdr + fmt::format("CompressedData = True\nCompressedDataSize = {}\nElementDataFile = LOCAL\n", z.size()) + z);
  Volume v = read_volume(t / "c.mha");
  expect_same_values(v, ref);
  EXPECT_EQ(v.spacing, (Vec3{1, 2, 3}));
  EXPECT_EQ(v.origin, (Vec3{10, 20, 30}));
  EXPECT_EQ(v.direction[4], -1);
  testutil::write_bytes(t / "d.raw", testutil::swapped(testutil::bytes_of(ref), 2));
  testutil::write_bytes(t / "d.mhd",
                        "NDims = 3\nDimSize = 6 4 5\nElementType = MET_SHORT\nElementSize = 1 1 1\n"
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
         "<PointData Scalars=\"s\">\n<DataArray type=\"Float32\" Name=\"s\" " +
         array_attrs + ">" + body + "</DataArray>\n</PointData>\n</Piece>\n</ImageData>\n" + appended + "</VTKFile>\n";
}
}  // namespace

TEST(ReadVti, AsciiBinaryAppendedCompressed) {
  TempDir t("vti");
  Volume ref = testutil::pattern_volume({5, 4, 3}, ScalarType::f32);
  std::string raw = testutil::bytes_of(ref);
  std::string ascii;
  for (std::int64_t i = 0; i < ref.voxel_count(); ++i) ascii += fmt::format("{} ", ref.at(i));
  std::string z = testutil::compress(raw, false);
  std::string zhdr = testutil::u32(1) + testutil::u32(static_cast<std::uint32_t>(raw.size())) +
                     testutil::u32(static_cast<std::uint32_t>(raw.size())) + testutil::u32(static_cast<std::uint32_t>(z.size()));
  struct Case {
    std::string name, text;
  };
  std::vector<Case> cases = {
      {"ascii", vti("", "format=\"ascii\"", ascii, "")},
      {"base64", vti("header_type=\"UInt32\"", "format=\"binary\"",
                     testutil::base64(testutil::u32(static_cast<std::uint32_t>(raw.size())) + raw), "")},
      {"base64z", vti("header_type=\"UInt32\" compressor=\"vtkZLibDataCompressor\"", "format=\"binary\"",
                      testutil::base64(zhdr) + testutil::base64(z), "")},
      {"appraw",
       vti("header_type=\"UInt32\"", "format=\"appended\" offset=\"0\"", "",
           "<AppendedData encoding=\"raw\">\n_" + testutil::u32(static_cast<std::uint32_t>(raw.size())) + raw + "\n</AppendedData>\n")},
      {"appz", vti("header_type=\"UInt32\" compressor=\"vtkZLibDataCompressor\"", "format=\"appended\" offset=\"0\"", "",
                   "<AppendedData encoding=\"raw\">\n_" + zhdr + z + "\n</AppendedData>\n")},
      {"app64", vti("header_type=\"UInt32\"", "format=\"appended\" offset=\"0\"", "",
                    "<AppendedData encoding=\"base64\">\n_" +
                        testutil::base64(testutil::u32(static_cast<std::uint32_t>(raw.size())) + raw) + "\n</AppendedData>\n")},
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
  std::string hdr =
      "# vtk DataFile Version 3.0\ntest\n{}\nDATASET STRUCTURED_POINTS\nDIMENSIONS 4 3 2\n\nSPACING 1 2 3\nORIGIN 0 0 5\n"
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
