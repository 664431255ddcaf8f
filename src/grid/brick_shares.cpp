// The error hierarchy shared out over processes (brick_shares.hpp).
#include "adaptiso/brick_shares.hpp"

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstring>

#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"

namespace adaptiso {
namespace {

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
    if (n > (bytes_.size() - at_) / sizeof(T)) truncated();
    v.resize(n);
    if (n > 0) std::memcpy(v.data(), bytes_.data() + at_, n * sizeof(T));  // an empty vector's data() may be null
    at_ += n * sizeof(T);
  }
  bool done() const { return at_ == bytes_.size(); }

private:
  void need(std::size_t n) const {
    if (bytes_.size() - at_ < n) truncated();
  }
  [[noreturn]] static void truncated() { throw InputError("a process's brick results are truncated"); }
  std::span<const std::byte> bytes_;
  std::size_t at_ = 0;
};

template <class IO, class B>
void each_array(IO& io, B& b) {
  io(b.code), io(b.displacement_code), io(b.seam_voxel), io(b.seam_lo), io(b.seam_hi), io(b.seam_delta), io(b.seam_g), io(b.seam_gradient),
      io(b.coarse_voxel), io(b.coarse_value), io(b.coarse_gradient);
}

// What this process's bricks hold at once: a code per owned voxel (two with the displacement
// criterion) until they are handed up, and per thread one brick at work: its region (at most 8
// bytes a sample), codes and the hierarchy's state (as bisection_errors counts it: 14 bytes per 8
// voxels); from a stream, one slab of slices.
void check_share_memory(const BrickGrid& bricks, int process, const std::vector<std::int64_t>& mine, bool slabs, bool displacement) {
  if (mine.empty()) return;
  const std::uint64_t per_code = displacement ? 2 : 1;
  std::uint64_t owned = 0, brick = 0;
  for (const std::int64_t n : mine) {
    owned += static_cast<std::uint64_t>(bricks.owns(n).voxel_count());
    brick = std::max(brick, static_cast<std::uint64_t>(bricks.reads(n, displacement).voxel_count()));
  }
  const auto threads = static_cast<std::uint64_t>(std::min<std::size_t>(tbb::this_task_arena::max_concurrency(), mine.size()));
  const std::uint64_t slab =
      slabs ? static_cast<std::uint64_t>(bricks.side + 2) * static_cast<std::uint64_t>(bricks.dims[0] * bricks.dims[1]) * 8 : 0;
  const std::uint64_t bytes = owned * per_code + threads * brick * (8 + per_code + 2) + slab;
  require_memory(bytes,
                 fmt::format("the error hierarchy of rank {}'s {} bricks of side {} ({} at a time{})", process, mine.size(), bricks.side,
                             threads, slabs ? ", from a slab of the stream" : ""),
                 "brick_side", "more ranks, or a smaller brick side");
}

}  // namespace

std::int64_t default_share_brick_side(const Dims& lattice, int processes) {
  const std::int64_t wanted = 4 * std::int64_t{std::max(processes, 1)};
  std::int64_t side = 256;
  while (side > 2 && brick_grid(lattice, side).size() < wanted) side /= 2;
  return side;
}

std::vector<BrickErrors> bisection_share_errors(const BrickGrid& bricks, int process, int processes, const RegionSource& source,
                                                const ValueRange& range, bool displacement, const HoldSlices& hold) {
  if (processes < 1 || process < 0 || process >= processes)
    throw InputError(fmt::format("process {} of {}: not a process of the job", process, processes));
  std::vector<std::int64_t> mine;
  for (std::int64_t n = process; n < bricks.size(); n += processes) mine.push_back(n);
  check_share_memory(bricks, process, mine, hold != nullptr, displacement);
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

ReaderSource reader_source(RegionReader& reader) {
  ReaderSource r{[&reader](const VoxelBox& box) { return reader.read(box); }, {}};
  if (reader.streams()) r.hold = [&reader](std::int64_t z0, std::int64_t z1) { reader.hold(z0, z1); };
  return r;
}

ReaderSource reader_source(RegionReader& reader, const Dims& lattice, const ValueRange& range) {
  ReaderSource r = reader_source(reader);
  const Dims volume = reader.header().dims;
  if (lattice == volume) return r;
  r.source = padded_source(std::move(r.source), volume, range);
  // A slab reaching past the far z face reads, for its reflection, as far below the face as it
  // reaches past it (padded_source): those slices are held too.
  if (r.hold)
    r.hold = [hold = std::move(r.hold), last = volume[2] - 1](std::int64_t z0, std::int64_t z1) {
      if (z1 > last) z0 = std::max<std::int64_t>(0, std::min(z0, 2 * last - z1));
      hold(std::min(z0, last), std::min(z1, last));
    };
  return r;
}

std::vector<std::byte> pack_brick_errors(const std::vector<BrickErrors>& bricks) {
  Writer w;
  w.put(static_cast<std::uint64_t>(bricks.size()));
  for (const BrickErrors& b : bricks) {
    w.put(b.brick);
    auto put = [&](const auto& v) { w.put(v); };
    each_array(put, b);
  }
  return w.take();
}

std::vector<BrickErrors> unpack_brick_errors(std::span<const std::byte> bytes) {
  Reader r(bytes);
  std::uint64_t n = 0;
  r.get(n);
  std::vector<BrickErrors> bricks;
  for (std::uint64_t i = 0; i < n; ++i) {
    BrickErrors& b = bricks.emplace_back();
    r.get(b.brick);
    auto get = [&](auto& v) { r.get(v); };
    each_array(get, b);
  }
  if (!r.done()) throw InputError("a process's brick results have bytes left over");
  return bricks;
}

}  // namespace adaptiso
