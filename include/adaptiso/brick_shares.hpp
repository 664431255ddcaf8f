// adaptiso/brick_shares.hpp — the bisection grid's error hierarchy shared out over processes
// (issue 38): which bricks (bisection_bricks.hpp) a process computes, and their results as bytes
// to hand to the one that combines them. The transport is the caller's: the command line's MPI
// ranks (`mpirun adaptiso prepare`), or mpi4py in Python (`adaptiso.prepare(…, comm=…)`), so the
// library itself speaks no MPI.
//
// Process r of n computes the bricks whose numbers are ≡ r (mod n), on its threads; process 0
// receives the others' bytes, unpacks them beside its own results and calls
// bisection_combine_bricks with the value range every process used (bit for bit: the codes are
// relative to it). The grid is then byte for byte the one a single process makes.
//
// The bytes are the machine's own (every process runs one build on one kind of machine): per
// brick its number and its arrays, each as a length and its elements.
//
// Throws: what bisection_brick_errors and the region source throw; InputError when bytes to
// unpack are truncated or have bytes left over; InputError (via require_memory) when a process's
// share will not fit in its memory, before any brick is read; and for bisection_scatter_errors,
// what the transport throws.
#pragma once
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string_view>
#include <vector>

#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/volume_regions.hpp"

namespace adaptiso {

class ShareTransport;  // select_shares.hpp

// The brick side when shared over `processes` and none is given: the largest power of two up to
// 256 that leaves at least 4 bricks a process (2 at least), so the bricks balance and the combine
// step's seams stay few. Seams cost: on the CT bunny (a lattice of 513²×361), 2 ranks, one thread
// each, the combine step took 4.5 s at 64, 1.9 s at 128 (48 bricks) and 0.7 s at 256 (8 bricks),
// its error hierarchy 8.6, 5.4 and 4.2 s (one process unbricked: 4.2 s). Up to 256: a rank reading
// a compressed stream holds a slab of that many slices, and each thread a brick.
std::int64_t default_share_brick_side(const Dims& lattice, int processes);

// Told the slices [z0, z1] the next slab of bricks will read (VolumeStream::hold: a compressed
// stream read front to back).
using HoldSlices = std::function<void(std::int64_t z0, std::int64_t z1)>;

// The brick step for process `process` of `processes`: its bricks (n ≡ process mod processes),
// in parallel, each read from `source`. With `hold`, slab after slab of bricks, each slab's slices
// announced before its bricks are read. Refuses up front what will not fit (memory.hpp): a code
// per owned voxel until they are handed up, and per thread one brick at work.
std::vector<BrickErrors> bisection_share_errors(const BrickGrid& bricks, int process, int processes, const RegionSource& source,
                                                const ValueRange& range, bool displacement = false, const HoldSlices& hold = {});

// Bricks read from a file by `reader`'s route: the source, and with a stream the hold that reads
// it slab by slab (both refer to `reader`, which must outlive them). With `lattice` (the padded
// lattice prepare builds a bisection grid on, bisection_lattice_dims), regions of the volume
// padded to it within the whole volume's value range (padded_source, bisection_bricks.hpp).
struct ReaderSource {
  RegionSource source;
  HoldSlices hold;
};
ReaderSource reader_source(RegionReader& reader);
ReaderSource reader_source(RegionReader& reader, const Dims& lattice, const ValueRange& range);

// Whether a file read by this route (RegionReader::route()) is one a process other than 0 could
// only read by decoding it up to its bricks (a compressed stream) or whole (text encodings, one
// file per slice, a multi-frame DICOM file, VTK): then process 0, which reads it anyway, sends the
// others their regions (bisection_scatter_errors). On the gzip CT bunny over 2 ranks rank 1's
// bricks took 3.4 s decoding the stream itself, 2.7-2.9 s sent their regions.
bool scattered_route(std::string_view route);

// The brick step with process 0 sending each other process its bricks' regions, slab after slab
// (bricks are numbered x fastest, z slowest; brick n is process n mod N's): a slab's regions go out
// before process 0 computes its own bricks of it, so the processes work on a slab at once.
// `source` is process 0's (the others' is not read) and `type` the samples' on every process.
// Collective over `transport`. Each process refuses up front what it cannot hold (a code per owned
// voxel until handed up, one slab's regions, a brick at work per thread), agreed between the
// processes (select_shares.hpp); a region process 0 cannot read ends every process's step, the
// others with an InputError naming process 0, and a process whose brick fails still takes its
// regions, so process 0 never waits.
std::vector<BrickErrors> bisection_scatter_errors(ShareTransport& transport, const BrickGrid& bricks, ScalarType type,
                                                  const RegionSource& source, const ValueRange& range, bool displacement = false);

// A process's results as one flat message, and back.
std::vector<std::byte> pack_brick_errors(const std::vector<BrickErrors>& bricks);
std::vector<BrickErrors> unpack_brick_errors(std::span<const std::byte> bytes);

}  // namespace adaptiso
