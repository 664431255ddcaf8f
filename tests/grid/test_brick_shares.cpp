// The error hierarchy shared out over processes (brick_shares.hpp), the processes played in turn
// by this one: every process's share, packed to bytes and unpacked, combines to the whole volume's
// hierarchy byte for byte; the shares partition the bricks; bytes cut short, with bytes left over
// or with a length beyond their end are refused. Regions sent by process 0 (processes played by
// threads) give the same hierarchy, and a region process 0 cannot read ends every process's step.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <future>
#include <random>
#include <set>
#include <stdexcept>

#include "adaptiso/bisection.hpp"
#include "adaptiso/brick_shares.hpp"
#include "adaptiso/error.hpp"
#include "thread_transport.hpp"

using namespace adaptiso;

namespace {

Volume noisy_sines(Dims d, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, 0.05);
  Volume v = make_volume(d, ScalarType::f32);
  for (std::int64_t z = 0; z < d[2]; ++z)
    for (std::int64_t y = 0; y < d[1]; ++y)
      for (std::int64_t x = 0; x < d[0]; ++x)
        v.set(v.index(x, y, z), std::sin(0.37 * x) + std::sin(0.23 * y + 1) + std::sin(0.51 * z + 2) + noise(rng));
  return v;
}

// What process 0 combines when `processes` processes each hand up their packed share.
BisectionErrors over_processes(const Volume& v, std::int64_t side, int processes, bool displacement, std::set<std::int64_t>* seen) {
  const ValueRange range = value_range(v);
  const BrickGrid bricks = brick_grid(v.dims, side);
  std::vector<BrickErrors> all;
  for (int p = 0; p < processes; ++p) {
    const std::vector<std::byte> bytes =
        pack_brick_errors(bisection_share_errors(bricks, p, processes, region_source(v), range, displacement));
    for (BrickErrors& b : unpack_brick_errors(bytes)) {
      EXPECT_EQ(b.brick % processes, p);
      EXPECT_TRUE(seen->insert(b.brick).second) << "brick " << b.brick << " twice";
      all.push_back(std::move(b));
    }
  }
  return bisection_combine_bricks(bricks, std::move(all), range, displacement);
}

}  // namespace

TEST(BrickShares, SharesPackedAndUnpackedCombineToTheWholeVolumesHierarchy) {
  for (const Dims d : {Dims{23, 18, 29}, Dims{2, 17, 9}, Dims{33, 33, 5}}) {
    const Volume v = noisy_sines(d, static_cast<unsigned>(d[0]));
    for (bool displacement : {false, true}) {
      const BisectionErrors whole = bisection_errors(v, value_range(v), displacement);
      for (std::int64_t side : {2, 8, 64})
        for (int processes : {1, 2, 3, 5}) {
          std::set<std::int64_t> seen;
          const BisectionErrors shared = over_processes(v, side, processes, displacement, &seen);
          const std::string what =
              fmt::format("{}x{}x{} side {} processes {} displacement {}", d[0], d[1], d[2], side, processes, displacement);
          EXPECT_EQ(static_cast<std::int64_t>(seen.size()), brick_grid(d, side).size()) << what;
          EXPECT_EQ(shared.code, whole.code) << what;
          EXPECT_EQ(shared.displacement_code, whole.displacement_code) << what;
          EXPECT_EQ(shared.codes.scale, whole.codes.scale) << what;
          EXPECT_EQ(shared.displacement_codes.scale, whole.displacement_codes.scale) << what;
        }
    }
  }
}

TEST(BrickShares, AProcessWithoutBricksHandsUpAnEmptyShare) {
  const Volume v = noisy_sines({9, 9, 9}, 3);
  const BrickGrid bricks = brick_grid(v.dims, 64);  // one brick
  const auto share = bisection_share_errors(bricks, 3, 4, region_source(v), value_range(v));
  EXPECT_TRUE(share.empty());
  EXPECT_TRUE(unpack_brick_errors(pack_brick_errors(share)).empty());
}

TEST(BrickShares, BytesCutShortOrWithBytesLeftOverAreRefused) {
  const Volume v = noisy_sines({17, 9, 12}, 4);
  const BrickGrid bricks = brick_grid(v.dims, 4);
  const std::vector<std::byte> bytes = pack_brick_errors(bisection_share_errors(bricks, 1, 2, region_source(v), value_range(v), true));
  ASSERT_GT(bytes.size(), 100u);
  for (std::size_t cut : {std::size_t{0}, std::size_t{7}, bytes.size() / 2, bytes.size() - 1})
    EXPECT_THROW(unpack_brick_errors(std::span(bytes).first(cut)), InputError) << cut;
  std::vector<std::byte> longer = bytes;
  longer.push_back(std::byte{0});
  EXPECT_THROW(unpack_brick_errors(longer), InputError);
  // A length field claiming more elements than the bytes hold (the first brick's code array).
  std::vector<std::byte> lying = bytes;
  const std::uint64_t huge = std::uint64_t{1} << 60;
  std::memcpy(lying.data() + 16, &huge, sizeof huge);
  EXPECT_THROW(unpack_brick_errors(lying), InputError);
}

TEST(BrickShares, AProcessNumberOutsideTheJobIsRefused) {
  const Volume v = noisy_sines({9, 9, 9}, 5);
  const BrickGrid bricks = brick_grid(v.dims, 4);
  for (auto [p, n] : {std::pair{2, 2}, std::pair{-1, 2}, std::pair{0, 0}})
    EXPECT_THROW(bisection_share_errors(bricks, p, n, region_source(v), value_range(v)), InputError) << p << " of " << n;
}

// UBSan caught memcpy from an empty vector's null data() when a brick handed up no seams.
TEST(BrickShares, EmptyArraysRoundTripWithoutACopyFromNull) {
  std::vector<BrickErrors> bricks(2);
  bricks[1].brick = 7;
  bricks[1].code = {1, 2, 3};
  const std::vector<BrickErrors> back = unpack_brick_errors(pack_brick_errors(bricks));
  ASSERT_EQ(back.size(), 2u);
  EXPECT_TRUE(back[0].code.empty() && back[0].seam_voxel.empty() && back[0].coarse_value.empty());
  EXPECT_EQ(back[1].brick, 7);
  EXPECT_EQ(back[1].code, (std::vector<std::uint8_t>{1, 2, 3}));
}

// The default side is the largest power of two up to 256 that leaves 4 bricks a process, counted
// here brick by brick from the lattice's extent, independently of brick_grid.
TEST(BrickShares, DefaultSideIsTheLargestUpTo256LeavingFourBricksAProcess) {
  auto bricks_at = [](const Dims& d, std::int64_t side) {
    std::int64_t extent = 1;
    for (int a = 0; a < 3; ++a) extent = std::max(extent, d[a] - 1);
    std::int64_t root = 1;
    while (root < extent) root *= 2;
    const std::int64_t s = std::min(side, root);
    std::int64_t n = 1;
    for (int a = 0; a < 3; ++a) n *= (d[a] - 1 + s - 1) / s;
    return n;
  };
  for (const Dims& d : {Dims{513, 513, 361}, Dims{257, 257, 133}, Dims{9, 9, 9}, Dims{2, 2, 2}, Dims{1025, 3, 2}, Dims{2049, 1025, 1025}})
    for (int processes : {1, 2, 3, 4, 16, 64}) {
      std::int64_t expect = 2;
      for (std::int64_t side = 256; side > 2; side /= 2)
        if (bricks_at(d, side) >= 4 * processes) {
          expect = side;
          break;
        }
      EXPECT_EQ(default_share_brick_side(d, processes), expect) << fmt::format("{}x{}x{}, {} processes", d[0], d[1], d[2], processes);
    }
  // The figures its comment gives: the CT bunny's lattice over 2 and 4 ranks, the chest CT's over 2.
  EXPECT_EQ(default_share_brick_side({513, 513, 361}, 2), 256);
  EXPECT_EQ(default_share_brick_side({513, 513, 361}, 4), 128);
  EXPECT_EQ(default_share_brick_side({257, 257, 133}, 2), 128);
}

namespace {

// Process 0 sends the others their regions from `source` (a region it cannot read throws there);
// every process's share, as process 0 gathers them. The others' errors come back in `theirs`.
std::vector<BrickErrors> scattered(const Volume& v, std::int64_t side, int processes, const RegionSource& source,
                                   std::vector<std::string>* theirs = nullptr) {
  const ValueRange range = value_range(v);
  const BrickGrid bricks = brick_grid(v.dims, side);
  testutil::Hub hub;
  std::vector<std::future<std::vector<BrickErrors>>> others;
  for (int p = 1; p < processes; ++p)
    others.push_back(std::async(std::launch::async, [&, p] {
      testutil::ThreadTransport t(hub, p, processes);
      return bisection_scatter_errors(t, bricks, v.type, {}, range);
    }));
  testutil::ThreadTransport t0(hub, 0, processes);
  std::vector<BrickErrors> all;
  std::exception_ptr failed;
  try {
    all = bisection_scatter_errors(t0, bricks, v.type, source, range);
  } catch (...) {
    failed = std::current_exception();
  }
  for (auto& f : others) try {
      for (BrickErrors& b : f.get()) all.push_back(std::move(b));
    } catch (const std::exception& e) {
      if (theirs) theirs->push_back(e.what());
    }
  EXPECT_EQ(hub.left(), 0u) << "messages left unread";
  if (failed) std::rethrow_exception(failed);
  return all;
}

}  // namespace

// Process 0 reads every region and sends the others theirs, slab after slab: the bricks combine to
// the whole volume's hierarchy byte for byte, for 2 to 4 processes, bricks of 2 to 8 voxels, on
// odd and 2-voxel-thick volumes, with processes that have no brick at all.
TEST(BrickShares, RegionsSentByProcessZeroCombineToTheWholeVolumesHierarchy) {
  for (const Dims& d : {Dims{13, 9, 11}, Dims{17, 2, 9}, Dims{5, 5, 5}}) {
    const Volume v = noisy_sines(d, static_cast<unsigned>(d[0]));
    const ValueRange range = value_range(v);
    const BisectionErrors whole = bisection_errors(v, range);
    for (const std::int64_t side : {2, 4, 8})
      for (int processes : {2, 3, 4}) {
        SCOPED_TRACE(fmt::format("{}x{}x{}, side {}, {} processes", d[0], d[1], d[2], side, processes));
        const BrickGrid bricks = brick_grid(v.dims, side);
        const BisectionErrors combined = bisection_combine_bricks(bricks, scattered(v, side, processes, region_source(v)), range);
        EXPECT_TRUE(combined.code == whole.code);
      }
  }
}

// A region process 0 cannot read (its third) ends its step with its own error and the others'
// with one naming process 0, none left waiting, no message left unread.
TEST(BrickShares, ARegionProcessZeroCannotReadEndsEveryProcesssStep) {
  const Volume v = noisy_sines({17, 13, 9}, 5);
  int reads = 0;
  const RegionSource base = region_source(v);
  const RegionSource failing = [&](const VoxelBox& box) {
    if (++reads == 3) throw InputError("bricks.raw: truncated at slice 4");
    return base(box);
  };
  std::vector<std::string> theirs;
  try {
    scattered(v, 4, 3, failing, &theirs);
    ADD_FAILURE() << "process 0 did not fail";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("truncated at slice 4"), std::string::npos) << e.what();
  }
  ASSERT_FALSE(theirs.empty());
  for (const auto& m : theirs) EXPECT_NE(m.find("process 0 could not read"), std::string::npos) << m;
}
