// MPI ranks or one process (ranks.hpp). A gather's payload above 2 GiB per rank is refused rather
// than split: the brick results a rank hands up are its share of one byte per voxel plus the
// seams. The other transfers go in pieces.
#include "ranks.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cstdlib>
#include <limits>
#include <string>

#include "adaptiso/error.hpp"

#ifdef ADAPTISO_HAVE_MPI
#include <mpi.h>
#endif

namespace adaptiso::cli {

int launched_processes() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS"}) {
    const char* v = std::getenv(name);
    if (v && *v) {
      const long n = std::strtol(v, nullptr, 10);
      if (n > 0 && n < std::numeric_limits<int>::max()) return static_cast<int>(n);
    }
  }
  return 1;
}

Ranks& Ranks::world() {
  static Ranks ranks;
  return ranks;
}

Ranks::Ranks() {
  const int launched = launched_processes();
#ifdef ADAPTISO_HAVE_MPI
  if (launched > 1) {
    int provided = 0;
    // Serialized: the viewer's connection threads on rank 0 hand surfaces to the other ranks
    // (view_ranks.cpp), one MPI call at a time.
    MPI_Init_thread(nullptr, nullptr, MPI_THREAD_SERIALIZED, &provided);
    serialized_ = provided >= MPI_THREAD_SERIALIZED;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
    MPI_Comm_size(MPI_COMM_WORLD, &size_);
    mpi_ = true;
  }
#else
  if (launched > 1)
    throw InputError(
        fmt::format("started by mpirun with {} processes, but this adaptiso was built without MPI (each would do the whole "
                    "job alone): run it without mpirun, or rebuild with libopenmpi-dev installed",
                    launched));
#endif
  started_ = this;
}

Ranks::~Ranks() {
#ifdef ADAPTISO_HAVE_MPI
  if (mpi_) MPI_Finalize();
#endif
}

void Ranks::abort_if_distributed(int code) {
#ifdef ADAPTISO_HAVE_MPI
  if (started_ && started_->mpi_ && started_->size_ > 1) MPI_Abort(MPI_COMM_WORLD, code);
#endif
  (void)code;
}

std::vector<std::vector<std::byte>> Ranks::gather(const std::vector<std::byte>& mine) {
  std::vector<std::vector<std::byte>> all;
  if (!distributed()) {
    all.push_back(mine);
    return all;
  }
#ifdef ADAPTISO_HAVE_MPI
  if (mine.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()))
    throw InputError(
        fmt::format("rank {} would send {} bytes at once (at most 2 GiB): use more ranks or smaller bricks", rank_, mine.size()));
  const int n = static_cast<int>(mine.size());
  std::vector<int> sizes(root() ? static_cast<std::size_t>(size_) : 0);
  MPI_Gather(&n, 1, MPI_INT, sizes.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  if (!root()) {
    MPI_Send(mine.data(), n, MPI_BYTE, 0, 1, MPI_COMM_WORLD);
    exchanged_ += mine.size();
    return all;
  }
  all.resize(static_cast<std::size_t>(size_));
  all[0] = mine;
  for (int r = 1; r < size_; ++r) {
    auto& got = all[static_cast<std::size_t>(r)];
    got.resize(static_cast<std::size_t>(sizes[static_cast<std::size_t>(r)]));
    MPI_Recv(got.data(), sizes[static_cast<std::size_t>(r)], MPI_BYTE, r, 1, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
    exchanged_ += got.size();
  }
#endif
  return all;
}

namespace {

// MPI counts are ints: a message goes in pieces of at most 1 GiB, f(offset, count) for each.
template <class F>
void each_piece(std::size_t bytes, F f, std::size_t piece = std::size_t{1} << 30) {
  for (std::size_t at = 0; at < bytes; at += piece) f(at, static_cast<int>(std::min(piece, bytes - at)));
}

// send_message's pieces: a receiver short of memory drains them through one buffer of this size,
// held from its first message on (allocated when memory has just run out, it could fail too, and
// the pieces left behind would then be taken for the next message's).
constexpr std::size_t kMessagePiece = std::size_t{1} << 20;

}  // namespace

void Ranks::broadcast(std::span<std::byte> bytes) {
#ifdef ADAPTISO_HAVE_MPI
  if (!distributed()) return;
  each_piece(bytes.size(), [&](std::size_t at, int n) { MPI_Bcast(bytes.data() + at, n, MPI_BYTE, 0, MPI_COMM_WORLD); });
  exchanged_ += bytes.size();
#else
  (void)bytes;
#endif
}

void Ranks::send(std::span<const std::byte> bytes) { send_to(0, bytes); }

void Ranks::send_to(int to, std::span<const std::byte> bytes) {
#ifdef ADAPTISO_HAVE_MPI
  each_piece(bytes.size(), [&](std::size_t at, int n) { MPI_Send(bytes.data() + at, n, MPI_BYTE, to, 2, MPI_COMM_WORLD); });
  exchanged_ += bytes.size();
#else
  (void)to, (void)bytes;
#endif
}

void Ranks::receive(int from, std::span<std::byte> into) {
#ifdef ADAPTISO_HAVE_MPI
  each_piece(into.size(),
             [&](std::size_t at, int n) { MPI_Recv(into.data() + at, n, MPI_BYTE, from, 2, MPI_COMM_WORLD, MPI_STATUS_IGNORE); });
  exchanged_ += into.size();
#else
  (void)from, (void)into;
#endif
}

// The pieces of a message after its header (send_message): a tag of their own, received right
// after the header from the same rank (MPI keeps one sender's messages of one tag in order).
constexpr int kMessagePieceTag = 30000;

void Ranks::send_message(int to, int tag, std::span<const std::byte> bytes) {
#ifdef ADAPTISO_HAVE_MPI
  const std::uint64_t size = bytes.size();
  MPI_Send(&size, 1, MPI_UINT64_T, to, tag, MPI_COMM_WORLD);
  each_piece(
      bytes.size(), [&](std::size_t at, int n) { MPI_Send(bytes.data() + at, n, MPI_BYTE, to, kMessagePieceTag, MPI_COMM_WORLD); },
      kMessagePiece);
  exchanged_ += sizeof size + bytes.size();
#else
  (void)to, (void)tag, (void)bytes;
#endif
}

int Ranks::poll_message(int from, int tag, std::vector<std::byte>& into) {
#ifdef ADAPTISO_HAVE_MPI
  if (!distributed()) return -1;
  int arrived = 0;
  MPI_Status status;
  MPI_Iprobe(from, tag < 0 ? MPI_ANY_TAG : tag, MPI_COMM_WORLD, &arrived, &status);
  if (!arrived) return -1;
  drain_.resize(kMessagePiece);
  std::uint64_t size = 0;
  MPI_Recv(&size, 1, MPI_UINT64_T, status.MPI_SOURCE, status.MPI_TAG, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  // An allocation that fails drains the pieces and throws: the message is lost to the caller,
  // and the next one arrives whole.
  try {
    into.resize(size);
  } catch (const std::bad_alloc&) {
    each_piece(
        size,
        [&](std::size_t, int n) {
          MPI_Recv(drain_.data(), n, MPI_BYTE, status.MPI_SOURCE, kMessagePieceTag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
        },
        kMessagePiece);
    exchanged_ += sizeof size + size;
    throw;
  }
  each_piece(
      size,
      [&](std::size_t at, int n) {
        MPI_Recv(into.data() + at, n, MPI_BYTE, status.MPI_SOURCE, kMessagePieceTag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      },
      kMessagePiece);
  exchanged_ += sizeof size + size;
  return status.MPI_TAG;
#else
  (void)from, (void)tag, (void)into;
  return -1;
#endif
}

std::uint64_t Ranks::broadcast(std::uint64_t x) {
#ifdef ADAPTISO_HAVE_MPI
  if (distributed()) {
    MPI_Bcast(&x, 1, MPI_UINT64_T, 0, MPI_COMM_WORLD);
    exchanged_ += sizeof x;
  }
#endif
  return x;
}

}  // namespace adaptiso::cli
