// The selection shared over processes (select_shares.hpp), the processes played by threads of this
// one over an in-process transport: process 0's grid is the one bisection_select makes alone, byte
// for byte (vertices, values, tetrahedra in order, codes and value spans), for 2 to 5 processes,
// volumes of odd, anisotropic and 2-voxel-thick sizes, bounds from 0 to the coarsest, with the
// displacement criterion; a sink on process 0 gets the tetrahedra in order, in pieces; a message
// another process cannot use is refused; process 0 can stop the others before the selection, and a
// check one process fails ends every process's selection.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <future>
#include <map>
#include <mutex>
#include <random>
#include <stdexcept>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"
#include "adaptiso/select_shares.hpp"
#include "thread_transport.hpp"
#include "util/memory.hpp"

using namespace adaptiso;
using testutil::Hub;
using testutil::ThreadTransport;

namespace {

Volume random_volume(Dims d, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Volume v = make_volume(d, ScalarType::f32);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, u(rng));
  return v;
}

Volume smooth_volume(Dims d) {
  Volume v = make_volume(d, ScalarType::i16);
  for (std::int64_t z = 0; z < d[2]; ++z)
    for (std::int64_t y = 0; y < d[1]; ++y)
      for (std::int64_t x = 0; x < d[0]; ++x) {
        const double r = std::sqrt((x - 0.4 * d[0]) * (x - 0.4 * d[0]) + (y - 0.6 * d[1]) * (y - 0.6 * d[1]) +
                                   4.0 * (z - 0.5 * d[2]) * (z - 0.5 * d[2]));
        v.set(v.index(x, y, z), std::round(1000 * std::sin(r / 3.0) + 20 * x));
      }
  return v;
}

// Process 0's grid, the other processes run alongside on threads.
BisectionGrid shared_select(const Volume& v, const ValueRange& range, const BisectionErrors& errors, BisectionOptions o, int processes) {
  Hub hub;
  std::vector<std::future<void>> others;
  for (int p = 1; p < processes; ++p)
    others.push_back(std::async(std::launch::async, [&hub, p, processes] {
      ThreadTransport t(hub, p, processes);
      EXPECT_TRUE(bisection_select_share(t));
    }));
  ThreadTransport t0(hub, 0, processes);
  o.share = &t0;
  BisectionGrid g = bisection_select(v, range, errors, o);
  for (auto& f : others) f.get();
  EXPECT_EQ(hub.left(), 0u) << "messages left unread";
  return g;
}

void expect_same(const BisectionGrid& a, const BisectionGrid& b, const std::string& what) {
  EXPECT_EQ(a.grid.ijk, b.grid.ijk) << what;
  EXPECT_EQ(a.grid.values, b.grid.values) << what;
  EXPECT_EQ(a.grid.tets, b.grid.tets) << what;
  EXPECT_EQ(a.hierarchy.error_code, b.hierarchy.error_code) << what;
  EXPECT_EQ(a.hierarchy.displacement_code, b.hierarchy.displacement_code) << what;
  ASSERT_EQ(a.hierarchy.value_span.size(), b.hierarchy.value_span.size()) << what;
  EXPECT_EQ(0, std::memcmp(a.hierarchy.value_span.data(), b.hierarchy.value_span.data(), a.hierarchy.value_span.size() * 8)) << what;
  EXPECT_EQ(a.error_bound, b.error_bound) << what;
  EXPECT_EQ(a.displacement_bound, b.displacement_bound) << what;
}

void check_shares(const Volume& v, const std::string& name, bool displacement) {
  const ValueRange range = value_range(v);
  const BisectionErrors errors = bisection_errors(v, range, displacement);
  const double width = range.max - range.min;
  for (const double bound : {0.0, 0.01 * width, 0.1 * width, 2.0 * width}) {
    BisectionOptions o;
    o.max_error = bound;
    if (displacement) o.max_displacement = 0.5;
    const BisectionGrid alone = bisection_select(v, range, errors, o);
    for (int processes : {2, 3, 5})
      expect_same(alone, shared_select(v, range, errors, o, processes),
                  fmt::format("{} {}x{}x{}, bound {}, {} processes", name, v.dims[0], v.dims[1], v.dims[2], bound, processes));
  }
}

}  // namespace

TEST(SelectShares, RandomVolumesOfOddAnisotropicAndThinSizes) {
  unsigned seed = 1;
  for (const Dims& d : {Dims{9, 9, 9}, Dims{17, 6, 11}, Dims{2, 13, 7}, Dims{23, 2, 2}, Dims{33, 17, 5}})
    check_shares(random_volume(d, seed++), "random", false);
}

TEST(SelectShares, SmoothFieldsWithAndWithoutTheDisplacementCriterion) {
  check_shares(smooth_volume({41, 29, 25}), "smooth", false);
  check_shares(smooth_volume({41, 29, 25}), "smooth", true);
  check_shares(random_volume({19, 12, 7}, 99), "random", true);
}

namespace {

// Collects what a selection hands over, checking the order of the calls.
class CollectingSink final : public TetrahedraSink {
public:
  void begin(BisectionGrid& grid, std::uint64_t tets) override {
    EXPECT_EQ(begun++, 0) << "begin twice";
    expected = tets;
    ijk = grid.grid.ijk;
    values = grid.grid.values;
    error_bound = grid.error_bound;
  }
  void write(std::span<const std::array<std::uint32_t, 4>> t) override {
    EXPECT_EQ(begun, 1) << "tetrahedra before begin";
    tets.insert(tets.end(), t.begin(), t.end());
    largest = std::max<std::uint64_t>(largest, t.size());
    ++writes;
  }
  int begun = 0, writes = 0;
  std::uint64_t expected = 0, largest = 0;
  std::vector<std::array<std::uint32_t, 3>> ijk;
  std::vector<double> values;
  std::vector<std::array<std::uint32_t, 4>> tets;
  double error_bound = -1;
};

}  // namespace

// A sink on process 0 gets the grid's tetrahedra in order, in pieces, whatever their size and
// whether the others share the selection: the grid it returns has none and is the rest of the grid
// alone (vertices, values and codes final at begin; spans complete at the end).
TEST(SelectShares, ASinkGetsTheTetrahedraInOrderInPiecesAloneOrShared) {
  const Volume v = smooth_volume({41, 29, 25});
  const ValueRange range = value_range(v);
  const BisectionErrors errors = bisection_errors(v, range);
  BisectionOptions o;
  o.max_error = 0.01 * (range.max - range.min);
  const BisectionGrid alone = bisection_select(v, range, errors, o);
  ASSERT_GT(alone.grid.tet_count(), 20000u);
  for (const std::uint64_t piece : {std::uint64_t{1}, std::uint64_t{37}, std::uint64_t{5000}, o.piece})
    for (int processes : {1, 2, 3}) {
      const std::string what = fmt::format("pieces of {}, {} processes", piece, processes);
      CollectingSink sink;
      BisectionOptions so = o;
      so.sink = &sink;
      so.piece = piece;
      BisectionGrid sunk = processes == 1 ? bisection_select(v, range, errors, so) : shared_select(v, range, errors, so, processes);
      EXPECT_TRUE(sunk.grid.tets.empty()) << what;
      EXPECT_EQ(sink.expected, alone.grid.tet_count()) << what;
      EXPECT_EQ(sink.ijk, alone.grid.ijk) << what;
      EXPECT_EQ(sink.values, alone.grid.values) << what;
      EXPECT_EQ(sink.error_bound, alone.error_bound) << what;
      EXPECT_TRUE(sink.tets == alone.grid.tets) << what;
      // Subtrees go whole (up to some 50 tetrahedra here), so small pieces are exceeded; larger
      // ones are not, and the default holds a process's whole run.
      if (piece >= 5000) {
        EXPECT_LE(sink.largest, piece) << what;
        EXPECT_GE(static_cast<std::uint64_t>(sink.writes), (alone.grid.tet_count() + piece - 1) / piece) << what;
      }
      if (piece == o.piece) {
        EXPECT_EQ(sink.writes, processes) << what;
      }
      sunk.grid.tets = alone.grid.tets;
      expect_same(alone, sunk, what);
    }
  BisectionOptions none = o;
  none.piece = 0;
  EXPECT_THROW(bisection_select(v, range, errors, none), OptionError);
}

// Process 0 played by hand: a head process 1 cannot use, then its side of the agreement, which
// learns that process 1 refused.
TEST(SelectShares, AMessageAnotherProcessCannotUseIsRefusedAndProcessZeroLearnsIt) {
  Hub hub;
  ThreadTransport zero(hub, 0, 2), one(hub, 1, 2);
  auto agree_on_zero = [&] {
    return std::async(std::launch::async, [&] {
      std::int64_t first = -1, theirs = -1;
      zero.receive(1, std::as_writable_bytes(std::span(&theirs, 1)));
      if (first < 0) first = theirs;
      zero.broadcast(std::as_writable_bytes(std::span(&first, 1)));
      return first;
    });
  };
  std::int64_t head[7] = {9, 9, 9, 300, 0, 0, 1};  // a threshold beyond a byte
  zero.broadcast(std::as_writable_bytes(std::span(head)));
  auto told = agree_on_zero();
  EXPECT_THROW(bisection_select_share(one), InputError);
  EXPECT_EQ(told.get(), 1);
  std::int64_t flat[7] = {9, 1, 9, 3, 0, 0, 1};  // a flat lattice
  zero.broadcast(std::as_writable_bytes(std::span(flat)));
  told = agree_on_zero();
  EXPECT_THROW(bisection_select_share(one), InputError);
  EXPECT_EQ(told.get(), 1);
  std::int64_t empty_pieces[7] = {9, 9, 9, 3, 0, 0, 0};  // runs in pieces of no tetrahedra
  zero.broadcast(std::as_writable_bytes(std::span(empty_pieces)));
  told = agree_on_zero();
  EXPECT_THROW(bisection_select_share(one), InputError);
  EXPECT_EQ(told.get(), 1);
  EXPECT_EQ(hub.left(), 0u);
  EXPECT_THROW(bisection_select_share(zero), std::logic_error);  // process 0 runs bisection_select
}

TEST(SelectShares, ProcessZeroThatWillNotSelectStopsTheOthers) {
  Hub hub;
  ThreadTransport zero(hub, 0, 3), one(hub, 1, 3), two(hub, 2, 3);
  bisection_select_stop(zero);
  EXPECT_FALSE(bisection_select_share(one));
  EXPECT_FALSE(bisection_select_share(two));
  EXPECT_EQ(hub.left(), 0u);
  EXPECT_THROW(bisection_select_stop(one), std::logic_error);
}

// Process 1 cannot hold the codes (a memory limit just above what this process holds): it throws
// its own refusal, process 0 an InputError naming it, and neither waits for the other.
TEST(SelectShares, ACheckOneProcessFailsEndsEveryProcesssSelection) {
  const Volume v = random_volume({129, 65, 65}, 7);  // codes of 545 K voxels
  const ValueRange range = value_range(v);
  const BisectionErrors errors = bisection_errors(v, range);
  BisectionOptions o;
  o.max_error = 0.1;
  Hub hub;
  set_memory_limit(detail::process_status_bytes("VmRSS") + (std::uint64_t{1} << 18));
  auto other = std::async(std::launch::async, [&hub] {
    ThreadTransport t(hub, 1, 2);
    return bisection_select_share(t);
  });
  ThreadTransport t0(hub, 0, 2);
  o.share = &t0;
  std::string zero_said;
  try {
    bisection_select(v, range, errors, o);
  } catch (const InputError& e) {
    zero_said = e.what();
  }
  std::string one_said;
  try {
    other.get();
  } catch (const std::exception& e) {
    one_said = e.what();
  }
  set_memory_limit(0);
  EXPECT_NE(zero_said.find("process 1 cannot take its share of the selection"), std::string::npos) << zero_said;
  EXPECT_NE(one_said.find("process 1's copy of the selection's codes"), std::string::npos) << one_said;
  EXPECT_EQ(hub.left(), 0u);
}
