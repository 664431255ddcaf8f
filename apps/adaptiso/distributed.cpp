// prepare over MPI ranks (distributed.hpp): the library's shares of the bricks (brick_shares.hpp),
// carried by MPI.
#include "distributed.hpp"

#include <fmt/format.h>

#include <bit>
#include <chrono>
#include <cstring>
#include <span>

#include "adaptiso/brick_shares.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"

namespace adaptiso::cli {
namespace {

using Clock = std::chrono::steady_clock;

// A rank's message: its bricks (pack_brick_errors) and then what it tells of itself.
struct Trailer {
  std::uint64_t peak = 0;    // resident memory, bytes
  double brick_seconds = 0;  // its bricks' time
};

std::vector<std::byte> pack(const std::vector<BrickErrors>& bricks, const Trailer& t) {
  std::vector<std::byte> bytes = pack_brick_errors(bricks);
  const auto* p = reinterpret_cast<const std::byte*>(&t);
  bytes.insert(bytes.end(), p, p + sizeof t);
  return bytes;
}

std::vector<BrickErrors> unpack(std::span<const std::byte> bytes, Trailer& t) {
  if (bytes.size() < sizeof t) throw InputError("a rank's brick results are truncated");
  std::memcpy(&t, bytes.data() + bytes.size() - sizeof t, sizeof t);
  return unpack_brick_errors(bytes.first(bytes.size() - sizeof t));
}

}  // namespace

nlohmann::json DistributedStats::to_json(int ranks) const {
  nlohmann::json j = {
      {"ranks", ranks},
      {"brick_side", brick_side},
      {"bricks", bricks},
      {"bricks_per_rank", bricks_per_rank},
      {"bytes_exchanged", bytes_exchanged},
      {"regions_sent_bytes", regions_sent_bytes},
      {"select_bytes_exchanged", select_bytes_exchanged},
      {"peak_bytes_per_rank", peak_bytes_per_rank},
      {"seconds", {{"rank0_bricks", brick_seconds}, {"bricks_per_rank", brick_seconds_per_rank}, {"combine", combine_seconds}}}};
  if (!ranks_read.empty()) j["ranks_read"] = ranks_read;  // only under mpirun
  return j;
}

BisectionErrors distributed_errors(Ranks& ranks, Dims dims, ScalarType type, const std::function<ReaderSource(const ValueRange&)>& read,
                                   ValueRange range, std::int64_t brick_side, bool displacement, bool scatter, const Progress& progress,
                                   DistributedStats& stats) {
  // Rank 0's range on every rank, bit for bit (the codes are relative to it); only rank 0 reads
  // the whole volume. Its lattice and sample type too: a rank it sends its regions knows no other.
  range.min = std::bit_cast<double>(ranks.broadcast(std::bit_cast<std::uint64_t>(range.min)));
  range.max = std::bit_cast<double>(ranks.broadcast(std::bit_cast<std::uint64_t>(range.max)));
  for (int a = 0; a < 3; ++a) dims[a] = static_cast<std::int64_t>(ranks.broadcast(static_cast<std::uint64_t>(dims[a])));
  type = static_cast<ScalarType>(ranks.broadcast(static_cast<std::uint64_t>(type)));
  const BrickGrid bricks = brick_grid(dims, brick_side > 0 ? brick_side : default_share_brick_side(dims, ranks.size()));
  stats.brick_side = bricks.side;
  stats.bricks = bricks.size();
  const auto t0 = Clock::now();
  report(progress, "error hierarchy (bricks)", 0);
  std::vector<BrickErrors> results;
  if (scatter) {
    const std::uint64_t before = ranks.bytes_exchanged();
    results = bisection_scatter_errors(ranks, bricks, type, ranks.root() ? read(range).source : RegionSource{}, range, displacement);
    stats.regions_sent_bytes = ranks.bytes_exchanged() - before;
  } else {
    const ReaderSource source = read(range);
    results = bisection_share_errors(bricks, ranks.rank(), ranks.size(), source.source, range, displacement, source.hold);
  }
  stats.brick_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  const std::uint64_t sent_before = ranks.bytes_exchanged();
  auto all = ranks.gather(ranks.root() ? std::vector<std::byte>{} : pack(results, {peak_resident_bytes(), stats.brick_seconds}));
  stats.bytes_exchanged = ranks.bytes_exchanged() - sent_before;
  if (!ranks.root()) return {};
  stats.bricks_per_rank.assign(static_cast<std::size_t>(ranks.size()), 0);
  stats.peak_bytes_per_rank.assign(static_cast<std::size_t>(ranks.size()), 0);
  stats.brick_seconds_per_rank.assign(static_cast<std::size_t>(ranks.size()), 0);
  stats.brick_seconds_per_rank[0] = stats.brick_seconds;
  stats.bricks_per_rank[0] = static_cast<std::int64_t>(results.size());
  for (int r = 1; r < ranks.size(); ++r) {
    Trailer told;
    std::vector<BrickErrors> theirs = unpack(all[static_cast<std::size_t>(r)], told);
    std::vector<std::byte>().swap(all[static_cast<std::size_t>(r)]);
    stats.bricks_per_rank[static_cast<std::size_t>(r)] = static_cast<std::int64_t>(theirs.size());
    stats.peak_bytes_per_rank[static_cast<std::size_t>(r)] = told.peak;
    stats.brick_seconds_per_rank[static_cast<std::size_t>(r)] = told.brick_seconds;
    for (auto& b : theirs) results.push_back(std::move(b));
  }
  const auto t1 = Clock::now();
  BisectionErrors errors = bisection_combine_bricks(bricks, std::move(results), range, displacement, progress);
  stats.combine_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  return errors;
}

}  // namespace adaptiso::cli
