// prepare over MPI ranks (distributed.hpp). A rank's bricks travel as one flat message: per brick
// its number and its arrays, each as a length and its elements (the ranks run one build on one
// kind of machine, so the bytes are the machine's own).
#include "distributed.hpp"

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstring>
#include <span>

#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"

namespace adaptiso::cli {
namespace {

using Clock = std::chrono::steady_clock;

class Writer {
public:
  template <class T>
  void put(const T& x) {
    const auto* p = reinterpret_cast<const std::byte*>(&x);
    bytes_.insert(bytes_.end(), p, p + sizeof(T));
  }
  template <class T>
  void put(const std::vector<T>& v) {
    put(static_cast<std::uint64_t>(v.size()));
    const auto* p = reinterpret_cast<const std::byte*>(v.data());
    bytes_.insert(bytes_.end(), p, p + v.size() * sizeof(T));
  }
  std::vector<std::byte> take() { return std::move(bytes_); }

private:
  std::vector<std::byte> bytes_;
};

class Reader {
public:
  explicit Reader(std::span<const std::byte> bytes) : bytes_(bytes) {}
  template <class T>
  void get(T& x) {
    need(sizeof(T));
    std::memcpy(&x, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
  }
  template <class T>
  void get(std::vector<T>& v) {
    std::uint64_t n = 0;
    get(n);
    if (n > (bytes_.size() - at_) / sizeof(T)) throw InputError("a rank's brick results are truncated");
    v.resize(n);
    std::memcpy(v.data(), bytes_.data() + at_, n * sizeof(T));
    at_ += n * sizeof(T);
  }
  bool done() const { return at_ == bytes_.size(); }

private:
  void need(std::size_t n) const {
    if (bytes_.size() - at_ < n) throw InputError("a rank's brick results are truncated");
  }
  std::span<const std::byte> bytes_;
  std::size_t at_ = 0;
};

template <class IO, class B>
void each_array(IO& io, B& b) {
  io(b.code), io(b.displacement_code), io(b.seam_voxel), io(b.seam_lo), io(b.seam_hi), io(b.seam_delta), io(b.seam_g), io(b.seam_gradient),
      io(b.coarse_voxel), io(b.coarse_value), io(b.coarse_gradient);
}

std::vector<std::byte> pack(const std::vector<BrickErrors>& bricks, std::uint64_t peak) {
  Writer w;
  w.put(peak);
  w.put(static_cast<std::uint64_t>(bricks.size()));
  for (const BrickErrors& b : bricks) {
    w.put(b.brick);
    auto put = [&](const auto& v) { w.put(v); };
    each_array(put, b);
  }
  return w.take();
}

std::vector<BrickErrors> unpack(std::span<const std::byte> bytes, std::uint64_t& peak) {
  Reader r(bytes);
  r.get(peak);
  std::uint64_t n = 0;
  r.get(n);
  std::vector<BrickErrors> bricks;
  for (std::uint64_t i = 0; i < n; ++i) {
    BrickErrors& b = bricks.emplace_back();
    r.get(b.brick);
    auto get = [&](auto& v) { r.get(v); };
    each_array(get, b);
  }
  if (!r.done()) throw InputError("a rank's brick results have trailing bytes");
  return bricks;
}

// Refuses up front (--memory-limit, or the machine's free memory) what this rank's bricks would
// hold: a code per owned voxel (two with the displacement criterion) until they are sent, and per
// thread one brick at work: its region (at most 8 bytes a sample), codes and the hierarchy's
// state (as bisection_errors counts it: 14 bytes per 8 voxels); from a stream, one slab of slices.
void check_rank_memory(const Ranks& ranks, const BrickGrid& bricks, const std::vector<std::int64_t>& mine, bool slabs, bool displacement) {
  if (mine.empty()) return;
  const std::uint64_t per_code = displacement ? 2 : 1;
  std::uint64_t owned = 0, brick = 0;
  for (const std::int64_t n : mine) {
    const VoxelBox o = bricks.owns(n), r = bricks.reads(n, displacement);
    owned += static_cast<std::uint64_t>(o.voxel_count());
    brick = std::max(brick, static_cast<std::uint64_t>(r.voxel_count()));
  }
  const auto threads = static_cast<std::uint64_t>(std::min<std::size_t>(tbb::this_task_arena::max_concurrency(), mine.size()));
  const std::uint64_t slab =
      slabs ? static_cast<std::uint64_t>(bricks.side + 2) * static_cast<std::uint64_t>(bricks.dims[0] * bricks.dims[1]) * 8 : 0;
  const std::uint64_t bytes = owned * per_code + threads * brick * (8 + per_code + 2) + slab;
  require_memory(bytes,
                 fmt::format("the error hierarchy of rank {}'s {} bricks of side {} ({} at a time{})", ranks.rank(), mine.size(),
                             bricks.side, threads, slabs ? ", from a slab of the stream" : ""),
                 "brick_side", "more ranks, or a smaller brick side");
}

// This rank's bricks (n ≡ rank mod size), in parallel on its threads. With `hold` (a compressed
// stream read front to back), slab after slab of bricks: hold(z0, z1) is told the slices the next
// slab reads before its bricks are read.
std::vector<BrickErrors> my_bricks(const Ranks& ranks, const BrickGrid& bricks, const RegionSource& source, const HoldSlices& hold,
                                   const ValueRange& range, bool displacement) {
  std::vector<std::int64_t> mine;
  for (std::int64_t n = ranks.rank(); n < bricks.size(); n += ranks.size()) mine.push_back(n);
  check_rank_memory(ranks, bricks, mine, hold != nullptr, displacement);
  std::vector<BrickErrors> out(mine.size());
  auto run = [&](std::size_t from, std::size_t to) {
    tbb::parallel_for(from, to, [&](std::size_t i) {
      out[i] = bisection_brick_errors(bricks, mine[i], source(bricks.reads(mine[i], displacement)), range, displacement);
    });
  };
  if (!hold) {
    run(0, mine.size());
    return out;
  }
  // Bricks are numbered x fastest, z slowest: a slab's bricks are consecutive.
  for (std::size_t from = 0; from < mine.size();) {
    const std::int64_t slab = bricks.brick(mine[from])[2];
    std::size_t to = from;
    std::int64_t z0 = bricks.dims[2], z1 = -1;
    for (; to < mine.size() && bricks.brick(mine[to])[2] == slab; ++to) {
      const VoxelBox box = bricks.reads(mine[to], displacement);
      z0 = std::min(z0, box.lo[2]), z1 = std::max(z1, box.hi[2]);
    }
    hold(z0, z1);
    run(from, to);
    from = to;
  }
  return out;
}

}  // namespace

nlohmann::json DistributedStats::to_json(int ranks) const {
  nlohmann::json j = {{"ranks", ranks},
                      {"brick_side", brick_side},
                      {"bricks", bricks},
                      {"bricks_per_rank", bricks_per_rank},
                      {"bytes_exchanged", bytes_exchanged},
                      {"peak_bytes_per_rank", peak_bytes_per_rank},
                      {"seconds", {{"rank0_bricks", brick_seconds}, {"combine", combine_seconds}}}};
  if (!ranks_read.empty()) j["ranks_read"] = ranks_read;  // only under mpirun
  return j;
}

BisectionErrors distributed_errors(Ranks& ranks, const Dims& dims, const RegionSource& source, ValueRange range, std::int64_t brick_side,
                                   bool displacement, const Progress& progress, DistributedStats& stats, const HoldSlices& hold) {
  // Rank 0's range on every rank, bit for bit (the codes are relative to it); only rank 0 reads
  // the whole volume.
  range.min = std::bit_cast<double>(ranks.broadcast(std::bit_cast<std::uint64_t>(range.min)));
  range.max = std::bit_cast<double>(ranks.broadcast(std::bit_cast<std::uint64_t>(range.max)));
  const BrickGrid bricks = brick_grid(dims, brick_side);
  stats.brick_side = bricks.side;
  stats.bricks = bricks.size();
  const auto t0 = Clock::now();
  report(progress, "error hierarchy (bricks)", 0);
  std::vector<BrickErrors> results = my_bricks(ranks, bricks, source, hold, range, displacement);
  stats.brick_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  const std::uint64_t sent_before = ranks.bytes_exchanged();
  auto all = ranks.gather(ranks.root() ? std::vector<std::byte>{} : pack(results, peak_resident_bytes()));
  stats.bytes_exchanged = ranks.bytes_exchanged() - sent_before;
  if (!ranks.root()) return {};
  stats.bricks_per_rank.assign(static_cast<std::size_t>(ranks.size()), 0);
  stats.peak_bytes_per_rank.assign(static_cast<std::size_t>(ranks.size()), 0);
  stats.bricks_per_rank[0] = static_cast<std::int64_t>(results.size());
  for (int r = 1; r < ranks.size(); ++r) {
    std::uint64_t peak = 0;
    std::vector<BrickErrors> theirs = unpack(all[static_cast<std::size_t>(r)], peak);
    std::vector<std::byte>().swap(all[static_cast<std::size_t>(r)]);
    stats.bricks_per_rank[static_cast<std::size_t>(r)] = static_cast<std::int64_t>(theirs.size());
    stats.peak_bytes_per_rank[static_cast<std::size_t>(r)] = peak;
    for (auto& b : theirs) results.push_back(std::move(b));
  }
  const auto t1 = Clock::now();
  BisectionErrors errors = bisection_combine_bricks(bricks, std::move(results), range, displacement, progress);
  stats.combine_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  return errors;
}

}  // namespace adaptiso::cli
