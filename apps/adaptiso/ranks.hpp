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
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <thread>
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
  // Bytes this rank sent to or received from others so far.
  std::uint64_t bytes_exchanged() const { return exchanged_; }
  // Stops every rank with this exit code (after this rank's message) when the ranks were started
  // and there are several; returns otherwise.
  static void abort_if_distributed(int code);
  // The ranks once started (nullptr before, or when starting them failed).
  static const Ranks* started() { return started_; }
  // MPI lets a thread of rank 0 serve the others while its main thread computes (Handout).
  bool serves_from_a_thread() const { return serialized_; }
  ~Ranks() override;

private:
  friend class Handout;
  Ranks();
  static inline Ranks* started_ = nullptr;
  int rank_ = 0, size_ = 1;
  bool mpi_ = false, serialized_ = false;
  std::uint64_t exchanged_ = 0;
};

// The numbers 0, 1, …, n − 1 handed out to the ranks one at a time, in order, as each asks for
// its next, so that a rank whose work went faster takes more (the costs of a distance query's
// iso-values differ 7-fold on the CT bunny and follow no cheap estimate). Rank 0 serves the
// others from a thread while its main thread takes its own from the same counter; that thread is
// the only one of rank 0 to call MPI until next() has returned nothing there (MPI_THREAD_SERIALIZED),
// so rank 0 must call no other MPI until then. Without such threads, or on one process, rank r
// takes r, r + N, r + 2N, … (in turn), as it does when `as_asked` is false. Every rank builds one
// alike and calls next() until it returns nothing; a failing rank stops the job (main.cpp: MPI_Abort), and rank 0's destructor stops its
// thread first.
class Handout {
public:
  Handout(Ranks& ranks, std::size_t n, bool as_asked = true);
  ~Handout();
  Handout(const Handout&) = delete;
  Handout& operator=(const Handout&) = delete;
  std::optional<std::size_t> next();
  // Handed out as ranks ask (false: in turn).
  bool as_ranks_ask() const { return as_asked_; }

private:
  void serve();
  void stop_serving();
  Ranks& ranks_;
  std::size_t n_;
  bool as_asked_;
  std::size_t in_turn_;  // the next in turn (not as asked)
  std::atomic<std::size_t> counter_{0};
  std::atomic<bool> stop_{false};
  std::thread server_;
};

}  // namespace adaptiso::cli
