// The error hierarchy over an mpi4py communicator (prepare_over_comm.hpp).
#include "prepare_over_comm.hpp"

#include <fmt/format.h>
#include <pybind11/stl.h>

#include <bit>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "adaptiso/brick_shares.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"
#include "adaptiso/volume_io.hpp"
#include "adaptiso/volume_regions.hpp"
#include "file_errors.hpp"

namespace py = pybind11;

namespace adaptiso::python {
namespace {

constexpr const char* kBisectionOnly = "only the bisection grid is prepared over several processes (drop grid=\"delaunay\" or comm)";

// mpi4py's lowercase collectives count bytes in a C int.
void check_message_size(std::size_t bytes, int rank) {
  if (bytes > static_cast<std::size_t>(std::numeric_limits<int>::max()))
    throw InputError(
        fmt::format("rank {} would hand up {} bytes at once (at most 2 GiB): use more ranks or a smaller brick_side", rank, bytes));
}

// The selection's transport (select_shares.hpp) over mpi4py's buffer methods, in pieces of at most
// 1 GiB (counts are C ints); the GIL is taken for each call (the selection runs without it).
class CommTransport final : public ShareTransport {
public:
  CommTransport(py::object comm, int rank, int size) : comm_(std::move(comm)), rank_(rank), size_(size) {}
  ~CommTransport() override {
    py::gil_scoped_acquire gil;
    comm_ = py::object();
  }
  int process() const override { return rank_; }
  int processes() const override { return size_; }
  void broadcast(std::span<std::byte> bytes) override {
    started_ = true;
    each_piece(bytes.data(), bytes.size(),
               [&](std::byte* p, std::size_t n) { comm_.attr("Bcast")(view(p, n, false), py::arg("root") = 0); });
  }
  void send(std::span<const std::byte> bytes) override {
    each_piece(const_cast<std::byte*>(bytes.data()), bytes.size(),
               [&](std::byte* p, std::size_t n) { comm_.attr("Send")(view(p, n, true), py::arg("dest") = 0, py::arg("tag") = kTag); });
  }
  void send_to(int to, std::span<const std::byte> bytes) override {
    each_piece(const_cast<std::byte*>(bytes.data()), bytes.size(),
               [&](std::byte* p, std::size_t n) { comm_.attr("Send")(view(p, n, true), py::arg("dest") = to, py::arg("tag") = kTag); });
  }
  void receive(int from, std::span<std::byte> into) override {
    each_piece(into.data(), into.size(), [&](std::byte* p, std::size_t n) {
      comm_.attr("Recv")(view(p, n, false), py::arg("source") = from, py::arg("tag") = kTag);
    });
  }
  // Whether rank 0 has sent the selection's first message (its head) yet.
  bool started() const { return started_; }

private:
  static constexpr int kTag = 38;
  template <class F>
  static void each_piece(std::byte* p, std::size_t n, F f) {
    py::gil_scoped_acquire gil;
    constexpr std::size_t piece = std::size_t{1} << 30;
    for (std::size_t at = 0; at < n; at += piece) f(p + at, std::min(piece, n - at));
  }
  static py::memoryview view(std::byte* p, std::size_t n, bool readonly) {
    return py::memoryview::from_memory(static_cast<void*>(p), static_cast<py::ssize_t>(n), readonly);
  }
  py::object comm_;
  int rank_, size_;
  bool started_ = false;
};

// Rank 0's range travels as Python floats: the same bits on every rank.
py::tuple go_message(const ValueRange& range, const Dims& dims, std::int64_t side, bool displacement, ScalarType type, bool scatter) {
  return py::make_tuple("go", range.min, range.max, py::make_tuple(dims[0], dims[1], dims[2]), side, displacement, static_cast<int>(type),
                        scatter);
}

RegionReader open_file(const std::string& path) {
  return file_errors([&] { return RegionReader(path); });
}

}  // namespace

std::unique_ptr<ShareTransport> comm_transport(const py::object& comm) {
  if (comm.is_none()) return nullptr;
  auto need = [&](std::initializer_list<const char*> methods) {
    for (const char* method : methods)
      if (!py::hasattr(comm, method)) throw py::type_error(fmt::format("comm: must be an mpi4py communicator (it has no {}())", method));
  };
  need({"Get_rank", "Get_size"});
  const int rank = comm.attr("Get_rank")().cast<int>(), size = comm.attr("Get_size")().cast<int>();
  if (size <= 1) return nullptr;
  need({"Bcast", "Send", "Recv"});
  return std::make_unique<CommTransport>(comm, rank, size);
}

Volume CommShare::read_file(const std::string& path) {
  return file_errors([&] { return read_volume(path); });
}

py::dict BrickStats::to_dict() const {
  py::dict d;
  d["ranks"] = ranks, d["brick_side"] = brick_side, d["bricks"] = bricks, d["bricks_per_rank"] = bricks_per_rank;
  d["bytes_exchanged"] = bytes_exchanged;
  if (!ranks_read.empty()) d["ranks_read"] = ranks_read;
  std::vector<std::uint64_t> peaks = peak_bytes_per_rank;
  peaks.resize(static_cast<std::size_t>(ranks), 0);
  peaks[0] = peak_resident_bytes();
  d["peak_bytes_per_rank"] = peaks;
  return d;
}

CommShare::CommShare(const py::object& comm, std::optional<std::int64_t> brick_side) : brick_side_(brick_side) {
  if (!comm.is_none()) {
    for (const char* method : {"Get_rank", "Get_size", "bcast", "gather"})
      if (!py::hasattr(comm, method)) throw py::type_error(fmt::format("comm: must be an mpi4py communicator (it has no {}())", method));
    comm_ = comm;
    rank_ = comm.attr("Get_rank")().cast<int>();
    size_ = comm.attr("Get_size")().cast<int>();
    if (size_ > 1 && py::hasattr(comm, "Bcast") && py::hasattr(comm, "Send") && py::hasattr(comm, "Recv"))
      transport_ = std::make_unique<CommTransport>(comm, rank_, size_);
  }
}

bool CommShare::scatters(const PrepareInput& in) const {
  return size_ > 1 && !in.volume && transport_ && scattered_route(RegionReader::route_of(in.path));
}

bool CommShare::all_ready(const std::string& own_error) {
  const py::object mine = own_error.empty() ? py::object(py::make_tuple("ready")) : py::object(py::make_tuple("error", own_error));
  const py::object all = comm_.attr("gather")(mine, py::arg("root") = 0);
  bool ready = own_error.empty();
  if (rank_ == 0)
    for (const auto& m : all.cast<py::list>()) ready = ready && m.cast<py::tuple>()[0].cast<std::string>() == "ready";
  return comm_.attr("bcast")(ready, py::arg("root") = 0).cast<bool>();
}

void CommShare::stop_the_selection() {
  if (!transport_ || static_cast<CommTransport&>(*transport_).started()) return;  // none, or rank 0 began it
  bisection_select_stop(*transport_);
}

// The others' part of the selection after their bricks (whether those succeeded or not): rank 0
// selects with them, or stops them.
void CommShare::share_the_selection() {
  if (!transport_) return;
  py::gil_scoped_release release;
  bisection_select_share(*transport_);
}

void CommShare::tell_the_others(const py::object& message) {
  if (size_ <= 1) return;
  sent_ = true;
  comm_.attr("bcast")(message, py::arg("root") = 0);
}

// Rank 0's hook: its own bricks and the others', combined as one process would.
void CommShare::share_hierarchy(PrepareOptions& options, bool scatter) {
  if (!brick_side_ && size_ <= 1) return;
  const std::int64_t side = brick_side_.value_or(0);  // 0: the default, once the lattice is known
  if (brick_side_) check_brick_side(side);
  if (options.grid != GridKind::bisection)
    throw size_ > 1 ? OptionError("comm", kBisectionOnly) : OptionError("brick_side", "applies to the bisection grid only");
  stats_.emplace();
  stats_->ranks = size_;
  stats_->brick_side = side;
  if (size_ <= 1) {
    options.error_hierarchy = [this, side](const Volume& v, const ValueRange& range, bool displacement, const Progress& progress) {
      stats_->bricks = brick_grid(v.dims, side).size();
      stats_->bricks_per_rank = {stats_->bricks};
      return bisection_errors_bricked(v.dims, range, side, region_source(v), displacement, progress, &stats_->bytes_exchanged);
    };
    return;
  }
  options.select_share = transport_.get();
  options.error_hierarchy = [this, given = side, scatter](const Volume& v, const ValueRange& range, bool displacement,
                                                          const Progress& progress) {
    const std::int64_t side = given > 0 ? given : default_share_brick_side(v.dims, size_);
    stats_->brick_side = side;
    const BrickGrid bricks = brick_grid(v.dims, side);
    stats_->bricks = bricks.size();
    stats_->bricks_per_rank.assign(static_cast<std::size_t>(size_), 0);
    stats_->peak_bytes_per_rank.assign(static_cast<std::size_t>(size_), 0);
    {
      py::gil_scoped_acquire gil;
      tell_the_others(go_message(range, v.dims, side, displacement, v.type, scatter));
    }
    // The others wait in the gather below: rank 0 reaches it whatever happens to its own bricks.
    std::vector<BrickErrors> results;
    std::exception_ptr failed;
    bool ready = true;  // sending the regions: every rank said it was (the others' bytes are empty otherwise)
    try {
      if (!scatter) {
        results = bisection_share_errors(bricks, 0, size_, region_source(v), range, displacement);
      } else {
        {
          py::gil_scoped_acquire gil;
          ready = all_ready("");
        }
        // A rank that is not ready says why in the gather below.
        if (ready) results = bisection_scatter_errors(*transport_, bricks, v.type, region_source(v), range, displacement);
      }
    } catch (...) {
      failed = std::current_exception();
    }
    stats_->bricks_per_rank[0] = static_cast<std::int64_t>(results.size());
    std::vector<std::string> errors;
    {
      py::gil_scoped_acquire gil;
      py::list all = comm_.attr("gather")(py::make_tuple("ok", py::bytes(), 0), py::arg("root") = 0);
      for (int r = 1; r < size_; ++r) {
        const auto at = static_cast<std::size_t>(r);
        const py::tuple m = all[at].cast<py::tuple>();
        if (m[0].cast<std::string>() != "ok") {
          errors.push_back(fmt::format("rank {}: {}", r, m[1].cast<std::string>()));
          continue;
        }
        if (failed || !errors.empty() || !ready) continue;
        const std::string_view bytes = m[1].cast<std::string_view>();
        std::vector<BrickErrors> theirs = unpack_brick_errors(std::as_bytes(std::span(bytes.data(), bytes.size())));
        stats_->bricks_per_rank[at] = static_cast<std::int64_t>(theirs.size());
        stats_->peak_bytes_per_rank[at] = m[2].cast<std::uint64_t>();
        if (r == 1) stats_->ranks_read = m[3].cast<std::string>();
        stats_->bytes_exchanged += bytes.size();
        for (auto& b : theirs) results.push_back(std::move(b));
        all[at] = py::none();  // its bytes go as soon as they are unpacked
      }
    }
    if (failed) std::rethrow_exception(failed);
    if (!errors.empty()) throw OptionError("comm", errors.front());  // ValueError, whatever the call
    return bisection_combine_bricks(bricks, std::move(results), range, displacement, progress);
  };
}

void CommShare::serve(const Setup& setup) {
  const py::object message = comm_.attr("bcast")(py::none(), py::arg("root") = 0);
  const py::tuple m = message.cast<py::tuple>();
  const std::string what = m[0].cast<std::string>();
  if (what == "done") return;
  if (what == "failed") throw OptionError("comm", "rank 0: " + m[1].cast<std::string>());
  const bool scatter = m[7].cast<bool>();  // rank 0 sends the regions: first agreed whether every rank is ready
  bool agreed = false;
  py::tuple reply;
  try {
    const ValueRange range{m[1].cast<double>(), m[2].cast<double>()};
    const auto d = m[3].cast<py::tuple>();
    const Dims dims{d[0].cast<std::int64_t>(), d[1].cast<std::int64_t>(), d[2].cast<std::int64_t>()};
    const std::int64_t side = m[4].cast<std::int64_t>();
    const bool displacement = m[5].cast<bool>();
    const auto type = static_cast<ScalarType>(m[6].cast<int>());
    const PrepareInput in = setup();
    if (in.options.grid != GridKind::bisection) throw OptionError("comm", kBisectionOnly);
    if (scatter && !transport_)
      throw OptionError("comm", "rank 0 sends the regions over Send and Recv, which this rank's communicator lacks");
    std::vector<std::byte> bytes;
    std::string route = "volume in memory";
    std::optional<RegionReader> reader;
    {
      py::gil_scoped_release release;
      if (!in.volume) route = reader.emplace(open_file(in.path)).route();
      // Rank 0 sends the padded lattice it builds on (prepare.hpp: pad_lattice); every rank pads alike.
      const Dims& v = in.volume ? in.volume->dims : reader->header().dims;
      if (bisection_lattice_dims(v) != dims)
        throw InputError(fmt::format("the volume has {}×{}×{} voxels on rank {}, a lattice of {}×{}×{} on rank 0", v[0], v[1], v[2], rank_,
                                     dims[0], dims[1], dims[2]));
    }
    if (scatter) {
      agreed = true;
      if (!all_ready("")) {  // another rank said why: rank 0 reports it
        comm_.attr("gather")(py::make_tuple("ok", py::bytes(), peak_resident_bytes(), route), py::arg("root") = 0);
        share_the_selection();
        return;
      }
    }
    {
      py::gil_scoped_release release;
      const BrickGrid bricks = brick_grid(dims, side);
      if (scatter) {
        route = "regions sent by rank 0";
        bytes = pack_brick_errors(bisection_scatter_errors(*transport_, bricks, type, {}, range, displacement));
      } else {
        const Dims& v = in.volume ? in.volume->dims : reader->header().dims;
        const ReaderSource read =
            reader ? reader_source(*reader, dims, range) : ReaderSource{padded_source(region_source(*in.volume), v, range), {}};
        bytes = pack_brick_errors(bisection_share_errors(bricks, rank_, size_, read.source, range, displacement, read.hold));
      }
    }
    check_message_size(bytes.size(), rank_);
    reply = py::make_tuple("ok", py::bytes(reinterpret_cast<const char*>(bytes.data()), bytes.size()), peak_resident_bytes(), route);
  } catch (const std::exception& e) {             // the GIL is held again here
    if (scatter && !agreed) all_ready(e.what());  // rank 0 waits to hear whether every rank is ready
    comm_.attr("gather")(py::make_tuple("error", std::string(e.what())), py::arg("root") = 0);
    share_the_selection();  // rank 0, told of the error, stops it
    throw;
  }
  comm_.attr("gather")(reply, py::arg("root") = 0);
  share_the_selection();
}

}  // namespace adaptiso::python
