// prepare over MPI ranks (ranks.hpp): the bisection grid's error hierarchy shared out brick by
// brick (brick_shares.hpp), brick n to rank n mod size, the results handed to rank 0, which
// combines them and makes the grid exactly as one process would (the same file, byte for byte).
//
// Issue 38, first steps: rank 0 reads the whole volume; the other ranks read only their bricks
// straight from the file where its format allows (volume_regions.hpp: seeking in uncompressed
// samples, slab by slab from a compressed stream or a DICOM series), the whole volume otherwise.
// The error hierarchy and the selection's walks are distributed (select_shares.hpp: Ranks is its
// transport); gradients and saving run on rank 0.
#pragma once
#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>

#include "adaptiso/bisection.hpp"
#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/brick_shares.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/volume.hpp"
#include "ranks.hpp"

namespace adaptiso::cli {

// What the distribution did, for --json.
struct DistributedStats {
  std::string ranks_read;  // how the ranks other than 0 got their bricks: RegionReader::route, or "regions sent by rank 0"
  std::int64_t brick_side = 0, bricks = 0;
  std::vector<std::int64_t> bricks_per_rank;
  std::vector<std::uint64_t> peak_bytes_per_rank;  // each rank's peak at its end (rank 0: filled in last)
  std::uint64_t bytes_exchanged = 0;               // brick results sent to rank 0 by the other ranks
  std::uint64_t regions_sent_bytes = 0;            // the regions rank 0 sent the others (scattered_route)
  std::uint64_t select_bytes_exchanged = 0;        // the selection's: codes, values, counts and runs (rank 0's sent and received)
  double brick_seconds = 0;                        // rank 0's own bricks
  std::vector<double> brick_seconds_per_rank;      // each rank's, reading its bricks included
  double combine_seconds = 0;
  nlohmann::json to_json(int ranks) const;
};

// The error hierarchy of a volume of `dims` over the ranks: each computes its bricks, reading them
// from the source `read` makes (with its hold: slab after slab, front to back), or with `scatter`
// receiving them from rank 0, which sends each rank its regions slab by slab from its own source
// (bisection_scatter_errors, for files a rank could only read by decoding the whole stream or
// volume: scattered_route, brick_shares.hpp); rank 0 receives the others' results and returns the combined hierarchy, the
// others return an empty one. The value range, lattice (`dims`) and sample type are rank 0's (the
// others' are not looked at; `read` is not called on a rank that receives its regions). Brick side
// 0: the default for the lattice and the ranks (default_share_brick_side). Collective: every rank
// calls it with the same side, criterion and `scatter`.
// `read` makes the rank's source of bricks once the range is known (a padded source reflects
// within it).
BisectionErrors distributed_errors(Ranks& ranks, Dims dims, ScalarType type, const std::function<ReaderSource(const ValueRange&)>& read,
                                   ValueRange range, std::int64_t brick_side, bool displacement, bool scatter, const Progress& progress,
                                   DistributedStats& stats);

}  // namespace adaptiso::cli
