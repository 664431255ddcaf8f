// The error hierarchy shared out over processes (brick_shares.hpp).
#include "adaptiso/brick_shares.hpp"

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstring>
#include <exception>

#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"
#include "adaptiso/select_shares.hpp"
#include "grid/share_agree.hpp"

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

// What a process's bricks hold at once: a code per owned voxel (two with the displacement
// criterion) until they are handed up, and per thread one brick at work: its region (at most 8
// bytes a sample), codes and the hierarchy's state (as bisection_errors counts it: 14 bytes per 8
// voxels); and `slab` bytes of one slab (of a stream's slices, or of the regions sent).
void check_share_memory(const BrickGrid& bricks, int process, const std::vector<std::int64_t>& mine, std::uint64_t slab, bool displacement,
                        const char* how) {
  if (mine.empty()) return;
  const std::uint64_t per_code = displacement ? 2 : 1;
  std::uint64_t owned = 0, brick = 0;
  for (const std::int64_t n : mine) {
    owned += static_cast<std::uint64_t>(bricks.owns(n).voxel_count());
    brick = std::max(brick, static_cast<std::uint64_t>(bricks.reads(n, displacement).voxel_count()));
  }
  const auto threads = static_cast<std::uint64_t>(std::min<std::size_t>(tbb::this_task_arena::max_concurrency(), mine.size()));
  const std::uint64_t bytes = owned * per_code + threads * brick * (8 + per_code + 2) + slab;
  require_memory(bytes,
                 fmt::format("the error hierarchy of rank {}'s {} bricks of side {} ({} at a time{})", process, mine.size(), bricks.side,
                             threads, how),
                 "brick_side", "more ranks, or a smaller brick side");
}

std::vector<std::int64_t> bricks_of(const BrickGrid& bricks, int process, int processes) {
  std::vector<std::int64_t> mine;
  for (std::int64_t n = process; n < bricks.size(); n += processes) mine.push_back(n);
  return mine;
}

// Process p's bricks of slab z: consecutive numbers, x fastest.
std::vector<std::int64_t> slab_bricks(const BrickGrid& bricks, std::int64_t z, int p, int processes) {
  std::vector<std::int64_t> out;
  const std::int64_t per = bricks.count[0] * bricks.count[1];
  for (std::int64_t n = z * per; n < (z + 1) * per; ++n)
    if (n % processes == p) out.push_back(n);
  return out;
}

// Process 0's word before each region it sends: the region follows, or it failed and no more will.
enum class RegionWord : std::uint8_t { region = 1, failed = 2 };

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
  const std::vector<std::int64_t> mine = bricks_of(bricks, process, processes);
  const std::uint64_t slab =
      hold ? static_cast<std::uint64_t>(bricks.side + 2) * static_cast<std::uint64_t>(bricks.dims[0] * bricks.dims[1]) * 8 : 0;
  check_share_memory(bricks, process, mine, slab, displacement, hold ? ", from a slab of the stream" : "");
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

bool scattered_route(std::string_view route) { return route == "slabs of the stream" || route == "whole volume"; }

std::vector<BrickErrors> bisection_scatter_errors(ShareTransport& t, const BrickGrid& bricks, ScalarType type, const RegionSource& source,
                                                  const ValueRange& range, bool displacement) {
  const int me = t.process(), processes = t.processes();
  const std::vector<std::int64_t> mine = bricks_of(bricks, me, processes);
  std::exception_ptr refused;
  try {
    std::uint64_t slab = 0;  // the largest slab's regions of this process
    for (std::int64_t z = 0; z < bricks.count[2]; ++z) {
      std::uint64_t held = 0;
      for (const std::int64_t n : slab_bricks(bricks, z, me, processes))
        held += static_cast<std::uint64_t>(bricks.reads(n, displacement).voxel_count()) * scalar_size(type);
      slab = std::max(slab, held);
    }
    check_share_memory(bricks, me, mine, slab, displacement, ", one slab of them sent by rank 0");
  } catch (...) {
    refused = std::current_exception();
  }
  detail::share::agree(t, refused, "the error hierarchy's bricks");
  // Regions still owed to each process: told when process 0 fails, so that none waits.
  std::vector<std::size_t> owed(static_cast<std::size_t>(processes), 0);
  for (int p = 1; p < processes; ++p) owed[static_cast<std::size_t>(p)] = bricks_of(bricks, p, processes).size();
  auto word = [&](int to, RegionWord w) { t.send_to(to, std::as_bytes(std::span(&w, 1))); };
  auto tell_failed = [&] {  // process 0 failed: the others still owed a region wait for no more
    for (int p = 1; p < processes; ++p)
      if (owed[static_cast<std::size_t>(p)] > 0) word(p, RegionWord::failed);
  };
  std::vector<BrickErrors> out;
  std::exception_ptr failed;  // another process's own failure: it still takes its regions
  for (std::int64_t z = 0; z < bricks.count[2]; ++z) {
    const std::vector<std::int64_t> slab = slab_bricks(bricks, z, me, processes);
    std::vector<Volume> regions;
    if (me == 0) {
      try {
        for (int p = 1; p < processes; ++p)
          for (const std::int64_t n : slab_bricks(bricks, z, p, processes)) {
            const Volume region = source(bricks.reads(n, displacement));
            word(p, RegionWord::region);
            t.send_to(p, std::as_bytes(std::span(region.bytes.data(), region.bytes.size())));
            --owed[static_cast<std::size_t>(p)];
          }
      } catch (...) {
        tell_failed();
        throw;
      }
    } else {
      for (const std::int64_t n : slab) {
        RegionWord w{};
        t.receive(0, std::as_writable_bytes(std::span(&w, 1)));
        if (w != RegionWord::region) throw InputError("process 0 could not read the regions it sends (its own message says why)");
        Volume& region = regions.emplace_back(make_volume(bricks.reads(n, displacement).dims(), type));
        t.receive(0, std::as_writable_bytes(std::span(region.bytes.data(), region.bytes.size())));
      }
    }
    if (failed) continue;
    const std::size_t at = out.size();
    out.resize(at + slab.size());
    try {
      tbb::parallel_for(std::size_t{0}, slab.size(), [&](std::size_t i) {
        out[at + i] = bisection_brick_errors(bricks, slab[i], me == 0 ? source(bricks.reads(slab[i], displacement)) : regions[i], range,
                                             displacement);
      });
    } catch (...) {
      if (me == 0) {  // the others wait for the next slab's regions: told instead
        tell_failed();
        throw;
      }
      failed = std::current_exception();
    }
  }
  if (failed) std::rethrow_exception(failed);
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
