// adaptiso.prepare(…, comm=…) and prepare_file(…, comm=…): the bisection grid's error hierarchy
// shared out over the processes of an mpi4py communicator, as `mpirun adaptiso prepare` shares it
// over MPI ranks (brick_shares.hpp), and the same grid, byte for byte, as one process makes.
//
// The communicator is used through its Python methods alone (Get_rank, Get_size, bcast, gather;
// Bcast, Send and Recv, when it has them, for the selection), so the module links no MPI and
// imports no mpi4py: any object with those methods will do.
//
// Every process calls prepare with its own Volume of the same dimensions (a numpy.memmap, or a
// Volume over one, is read only in the process's bricks) or the same file's path (rank 0 reads it
// whole; the others read their bricks by RegionReader's route, or, where that route would decode
// the file up to their bricks (scattered_route, brick_shares.hpp), rank 0 sends them their regions
// when the communicator has the buffer methods). Rank 0 makes the grid; the others
// compute their bricks, hand them to rank 0 and return None. The protocol always completes, so an
// error on any process (a bad option, a volume of other dimensions, a file it cannot read, memory
// refused) raises on every process, naming the rank, instead of leaving the others waiting:
//   1. rank 0 broadcasts ("go", range min, range max, dims, brick side, displacement, sample type,
//      whether it sends the regions) when its preparation reaches the error hierarchy, or
//      ("failed", message) / ("done",) when it fails or finishes before it;
//   2. every other rank computes its bricks with rank 0's range, side and criterion, and every
//      rank gathers to rank 0 ("ok", bytes, peak resident bytes, how it read) or ("error", message).
//      When rank 0 sends the regions, the ranks first gather ("ready",) or ("error", message) and
//      rank 0 broadcasts whether they go on (bisection_scatter_errors over Send and Recv) before
//      that gather.
//   3. with a communicator that has mpi4py's buffer methods (Bcast, Send, Recv) and a rank 0 that
//      sent "go", the ranks then share the selection's walks (select_shares.hpp) over them, the
//      others whether their bricks succeeded or not: rank 0 selects, or stops them
//      (bisection_select_stop) when it failed before; checks a rank fails within the selection
//      are agreed there.
// A process that dies outright still leaves the others waiting, as with any MPI program: run
// under `python3 -m mpi4py script.py`, which aborts the job on an uncaught exception.
#pragma once
#include <pybind11/pybind11.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "adaptiso/prepare.hpp"
#include "adaptiso/select_shares.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso::python {

// What prepare is given: a volume in memory, or a file's path (rank 0 reads it whole, as
// adaptiso.read does; the other ranks read their bricks from it by RegionReader's route).
struct PrepareInput {
  const Volume* volume = nullptr;
  std::string path;
  PrepareOptions options;
};

// What the bricks did, for the statistics' "bricks" entry (the command line's --json "bricks").
struct BrickStats {
  int ranks = 1;
  std::int64_t brick_side = 0, bricks = 0;
  std::vector<std::int64_t> bricks_per_rank;
  std::vector<std::uint64_t> peak_bytes_per_rank;  // rank 0's when the statistics are read
  std::uint64_t bytes_exchanged = 0;               // handed to rank 0 by the others (one process: across brick faces)
  std::string ranks_read;                          // how rank 1 read its bricks: RegionReader::route() or "volume in memory"
  pybind11::dict to_dict() const;
};

// The shared steps' transport (select_shares.hpp) over an mpi4py communicator's buffer methods
// (Bcast, Send and Recv, in pieces of at most 1 GiB; the GIL taken for each call, so the step runs
// without it): nullptr for None or a communicator of one process. TypeError for an object without
// Get_rank and Get_size, or of several processes without Bcast, Send and Recv (adaptiso.load(comm=...)).
std::unique_ptr<ShareTransport> comm_transport(const pybind11::object& comm);

class CommShare {
public:
  // comm: None or an mpi4py communicator (TypeError for another object); brick_side: None for the
  // default (one process: no bricks; several: brick_shares.hpp's default_share_brick_side).
  CommShare(const pybind11::object& comm, std::optional<std::int64_t> brick_side);

  // Finds the volume and checks the options (Python's arguments; the GIL held).
  using Setup = std::function<PrepareInput()>;
  // This process's part. Rank 0 (or one process): `setup`, then `prepare` with the GIL released,
  // which calls options.error_hierarchy, set here when the hierarchy is bricked or shared; returns
  // its result. Any other rank: its bricks, handed to rank 0 (a throw in `setup` reaches rank 0
  // too); returns nullopt. The protocol completes whether either succeeds or throws.
  template <class R>
  std::optional<R> run(const Setup& setup, const std::function<R(const Volume&, const PrepareOptions&)>& prepare);
  // Rank 0 after run: what the bricks did, when the hierarchy was bricked.
  const std::optional<BrickStats>& stats() const { return stats_; }

private:
  void serve(const Setup& setup);
  static Volume read_file(const std::string& path);  // FileError when it cannot be read
  // `scatter`: rank 0 sends the others their regions of the file it reads whole.
  void share_hierarchy(PrepareOptions& options, bool scatter);
  // Rank 0: whether it will send the others their regions of `in`'s file (over the buffer methods).
  bool scatters(const PrepareInput& in) const;
  // Rank 0 and the others agree before regions are sent: whether every rank is ready.
  bool all_ready(const std::string& own_error);
  void tell_the_others(const pybind11::object& message);
  void stop_the_selection();
  void share_the_selection();
  pybind11::object comm_;
  int rank_ = 0, size_ = 1;
  std::optional<std::int64_t> brick_side_;  // as given
  bool sent_ = false;                       // rank 0 has broadcast its message
  std::optional<BrickStats> stats_;
  std::unique_ptr<ShareTransport> transport_;  // the selection's, over the communicator's buffer methods
};

template <class R>
std::optional<R> CommShare::run(const Setup& setup, const std::function<R(const Volume&, const PrepareOptions&)>& prepare) {
  if (rank_ != 0) {
    serve(setup);
    return std::nullopt;
  }
  std::optional<R> r;
  try {
    PrepareInput in = setup();
    share_hierarchy(in.options, scatters(in));
    pybind11::gil_scoped_release release;
    if (in.volume) {
      r.emplace(prepare(*in.volume, in.options));
    } else {
      const Volume v = read_file(in.path);
      r.emplace(prepare(v, in.options));
    }
  } catch (const std::exception& e) {  // the GIL is held again here (pybind11's errors too)
    if (!sent_)
      tell_the_others(pybind11::make_tuple("failed", std::string(e.what())));
    else
      stop_the_selection();  // the others, having had "go", wait for the selection
    throw;
  }
  if (!sent_) tell_the_others(pybind11::make_tuple("done"));
  return r;
}

}  // namespace adaptiso::python
