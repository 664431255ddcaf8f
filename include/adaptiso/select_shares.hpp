// adaptiso/select_shares.hpp — the bisection grid's selection (bisection_select, bisection.hpp)
// shared out over processes (issue 38), after its error hierarchy (brick_shares.hpp). The
// transport is the caller's (the command line's MPI ranks; an mpi4py communicator in Python), so
// the library itself speaks no MPI.
//
// The selection walks the hierarchy twice, cut into the same subtrees on every process (12 splits
// below the roots): once to count each subtree's leaves, once to write them as tetrahedra with
// their final vertex numbers. Process 0 sends the others the codes (a byte a voxel, two with the
// displacement criterion); each counts the subtrees whose numbers are ≡ its own (mod processes),
// and the counts are summed on every process. The tetrahedra are then cut into as many runs of
// consecutive subtrees as there are processes, of about as many leaves each; every process numbers
// the vertices alike (the split diamonds' centres), receives the vertices' values from process 0,
// writes its run and sends it to process 0 with the value spans it found, which lands the run in
// place in the grid's tetrahedra and merges the spans (min and max: any order gives the same).
// The grid is byte for byte the one a single process selects.
//
// Every process holds the codes (a byte a voxel), the vertex numbers (a quarter byte a voxel), the
// vertices' values and spans (16 bytes a vertex) and its run (16 bytes a tetrahedron); process 0
// the grid besides. On the CT bunny rank 1 peaked at 0.8–0.9 GB (0.3 GB for its bricks alone).
// Sending each process only the codes of its subtrees' region would take the codes off the others;
// numbering the vertices per run, the values.
//
// Bytes move between processes of one build on one kind of machine: no byte order is converted.
//
// Failures: what each process checks before it takes memory (process 0's message and its copy of
// the codes; the grid or its run once the counts are known, and the 32-bit indices) is agreed
// between the processes: the one that fails throws its error, the others an InputError naming it,
// so no process waits for a message that will not come. Other failures (the transport's, an
// allocation that fails past its check) leave the others waiting: the caller stops them (the
// command line: MPI_Abort).
//
// Throws: what bisection_select throws (on process 0), InputError on another process when process
// 0's message is not one it can use or another process failed its checks, and whatever the
// transport throws.
#pragma once
#include <cstddef>
#include <span>

namespace adaptiso {

// How the processes of a shared step move bytes. Sizes are agreed beforehand: a receiver knows
// how many bytes it expects.
class ShareTransport {
public:
  virtual ~ShareTransport() = default;
  virtual int process() const = 0;    // this one's number, 0 … processes() − 1
  virtual int processes() const = 0;  // how many share the step
  // Process 0's `bytes` into every other process's (of the same size). Collective.
  virtual void broadcast(std::span<std::byte> bytes) = 0;
  // Bytes from this process (not 0) to process 0, which receives them with receive(this, …);
  // messages between two processes arrive in the order they were sent.
  virtual void send(std::span<const std::byte> bytes) = 0;
  // Bytes from process 0 to process `to` (not 0), which receives them with receive(0, …): the
  // regions of a volume only process 0 reads (brick_shares.hpp: bisection_scatter_errors).
  virtual void send_to(int to, std::span<const std::byte> bytes) = 0;
  // On this process, the bytes process `from` sent it (send, or send_to from process 0).
  virtual void receive(int from, std::span<std::byte> into) = 0;
};

// A process other than 0: its part of the selection process 0 runs with
// BisectionOptions::share (bisection.hpp), until that is done; false, having done nothing, when
// process 0 called bisection_select_stop instead. Collective with it.
bool bisection_select_share(ShareTransport& transport);

// Process 0 that will not select after all (it failed after the others began to wait for the
// selection): tells them, so that bisection_select_share returns false.
void bisection_select_stop(ShareTransport& transport);

}  // namespace adaptiso
