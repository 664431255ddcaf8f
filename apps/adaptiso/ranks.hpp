// The processes one command runs on: MPI ranks when adaptiso was built with MPI (ADAPTISO_HAVE_MPI)
// and started by mpirun, one process otherwise. Only the command line speaks MPI; the library
// stays free of it and offers the steps the ranks share out (bisection_bricks.hpp).
//
// A failure on any rank stops every rank (MPI_Abort after the message), so no rank waits forever in
// a collective and no output reaches its final name (outputs are renamed into place at the end).
// A failure every rank meets alike is told by rank 0 alone; a rank still running 3 s after meeting
// one (it met it alone) tells it with its number before stopping the others (main.cpp).
// A build without MPI started by mpirun with several processes refuses to run (exit 2): each process
// would do the whole job alone and write the same files.
#pragma once
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "adaptiso/error.hpp"
#include "adaptiso/select_shares.hpp"

namespace adaptiso::cli {

// The size of the job mpirun (OpenMPI, MPICH, PMIx launchers) started this process in; 1 when it
// was not started by one.
int launched_processes();

// An input error of one rank's own share of the work (its outputs, say), which the other ranks do
// not meet: told with the rank's number, where an InputError every rank meets alike is told once,
// by rank 0. Exit 2 as for any InputError.
class RankInputError : public InputError {
public:
  using InputError::InputError;
};

// Also the transport of the shared selection (select_shares.hpp).
class Ranks final : public ShareTransport {
public:
  // The ranks of this job; MPI is initialised on first use when launched by mpirun.
  static Ranks& world();
  int rank() const { return rank_; }
  int size() const { return size_; }
  bool root() const { return rank_ == 0; }
  bool distributed() const { return size_ > 1; }

  // Every rank's bytes at rank 0, in rank order (empty elsewhere). Collective.
  std::vector<std::vector<std::byte>> gather(const std::vector<std::byte>& mine);
  // Rank 0's value of x on every rank. Collective.
  std::uint64_t broadcast(std::uint64_t x);
  // ShareTransport: messages of any size (sent in pieces of at most 1 GiB).
  int process() const override { return rank_; }
  int processes() const override { return size_; }
  void broadcast(std::span<std::byte> bytes) override;
  void send(std::span<const std::byte> bytes) override;
  void receive(int from, std::span<std::byte> into) override;
  // Bytes from rank 0 to rank `to` (which receives them with receive(0, …)), in pieces likewise.
  void send_to(int to, std::span<const std::byte> bytes) override;
  // Tagged point-to-point messages of any size, for work handed out while rank 0 serves
  // (view_ranks.hpp): a header with the size, then pieces of at most 1 MiB. With
  // serialized_threads() any thread may call these, one at a time (the caller serialises).
  void send_message(int to, int tag, std::span<const std::byte> bytes);
  // The first message from `from` with `tag` (any tag: -1) if one has arrived, its tag returned;
  // -1 when none has. Never blocks: OpenMPI's blocking receive spins, and an idle viewer's ranks
  // would each keep a core busy.
  int poll_message(int from, int tag, std::vector<std::byte>& into);
  // Whether MPI lets several threads of this rank call it one at a time (MPI_THREAD_SERIALIZED,
  // asked for; prepare and extract need only the main thread's).
  bool serialized_threads() const { return serialized_; }
  // Bytes this rank sent to or received from others so far.
  std::uint64_t bytes_exchanged() const { return exchanged_; }
  // Stops every rank with this exit code (after this rank's message) when the ranks were started
  // and there are several; returns otherwise.
  static void abort_if_distributed(int code);
  // The ranks once started (nullptr before, or when starting them failed).
  static const Ranks* started() { return started_; }
  ~Ranks() override;

private:
  Ranks();
  static inline Ranks* started_ = nullptr;
  int rank_ = 0, size_ = 1;
  bool mpi_ = false, serialized_ = true;
  std::uint64_t exchanged_ = 0;
  std::vector<std::byte> drain_;  // poll_message's: a message it cannot hold is received through it
};

}  // namespace adaptiso::cli
