// prepare over MPI ranks (ranks.hpp): the bisection grid's error hierarchy shared out brick by
// brick (bisection_bricks.hpp), brick n to rank n mod size, the results handed to rank 0, which
// combines them and makes the grid exactly as one process would (the same file, byte for byte).
//
// First step of issue 38: every rank still reads the whole volume (region reads straight from the
// file are the next step), and only the error hierarchy is distributed; selection, gradients and
// the index run on rank 0.
#pragma once
#include <cstdint>
#include <nlohmann/json.hpp>

#include "adaptiso/bisection.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/volume.hpp"
#include "ranks.hpp"

namespace adaptiso::cli {

// What the distribution did, for --json.
struct DistributedStats {
  std::int64_t brick_side = 0, bricks = 0;
  std::vector<std::int64_t> bricks_per_rank;
  std::vector<std::uint64_t> peak_bytes_per_rank;  // at the time each rank handed up its bricks (rank 0: filled in at the end)
  std::uint64_t bytes_exchanged = 0;               // brick results sent to rank 0 by the other ranks
  double brick_seconds = 0;                        // rank 0's own bricks
  double combine_seconds = 0;
  nlohmann::json to_json(int ranks) const;
};

// The error hierarchy of `v` over the ranks: each computes its bricks; rank 0 receives the others'
// and returns the combined hierarchy, the others return an empty one. Collective: every rank calls
// it with the same volume, range, side and criterion.
BisectionErrors distributed_errors(Ranks& ranks, const Volume& v, const ValueRange& range, std::int64_t brick_side, bool displacement,
                                   const Progress& progress, DistributedStats& stats);

}  // namespace adaptiso::cli
