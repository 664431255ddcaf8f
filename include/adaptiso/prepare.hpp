// adaptiso/prepare.hpp — the preprocessing pipeline as one call: volume → grid (reduction and
// Delaunay, §2.1–2.2) → vertex gradients (§2.3) → reconstruction error → extraction index (§2.4).
// The command line, the viewer, the Python module, the tests and the benches all prepare grids
// through prepare().
//
// Units: max_error in data units, or a fraction of the value range with `relative`; threshold
// likewise (a fraction of the largest gradient magnitude with `relative`).
// Throws OptionError for a bad option (named as in PrepareOptions), InputError when the volume
// cannot be prepared (flat, too many vertices for 32-bit indices, more memory than the machine has).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

enum class GradientMethod {
  automatic,      // least squares
  least_squares,  // the paper's fit over each vertex's ring (gradients.hpp)
  central,        // central differences of the volume
};

struct PrepareOptions {
  // The error bound of the grid (max norm).
  double max_error = 0;
  bool relative = false;  // max_error and threshold relative to the value range / largest gradient
  // The paper's reduction (§2.1).
  ReduceMethod method = ReduceMethod::reconstruction;
  double threshold = 0;
  GradientOperator structural_gradient = GradientOperator::central;
  double sigma = 1.0;
  int kernel = 0;
  bool parallel_delaunay = true;
  GradientMethod gradients = GradientMethod::automatic;
  std::uint32_t tree_depth = kDefaultTreeDepth;
  bool measure_error = true;  // the piecewise-linear error, voxel by voxel (pl_max_error)
  std::string source_name;    // informational: the source's file name (folders are dropped)
};

// The reduction options that PrepareOptions implies (absolute or relative as given).
ReduceOptions reduce_options(const PrepareOptions& options);

struct StageStats {
  std::string name;  // "reduce", "tetrahedralize", "gradients", "pl_error", "index", ...
  double seconds = 0;
  std::uint64_t peak_bytes = 0;  // resident memory peak of the process during the stage (Linux; 0 elsewhere)
};

struct PrepareStats {
  std::int64_t voxels = 0;
  std::uint64_t kept = 0, tetrahedra = 0;
  double max_error = 0;                         // the absolute bound asked for
  double threshold = 0;                         // the absolute structural threshold used
  double pl_max_error = -1, pl_rms_error = -1;  // measured (< 0: not measured)
  std::uint32_t index_depth = 0;
  double grid_bytes_per_vertex = 0;
  std::vector<StageStats> stages;
  double seconds(const std::string& stage) const;  // 0 when the stage did not run
};

// One JSON object: voxels, kept, ratio, tetrahedra, max_error, pl_max_error, pl_rms_error,
// index_depth, grid_bytes_per_vertex, seconds{stage}, peak_bytes{stage}; and back (fields that
// are missing keep their defaults, so older grid files load).
std::string to_json(const PrepareStats& stats);
PrepareStats prepare_stats_from_json(const std::string& json);

// A grid ready for extraction: the tetrahedra, the index over them and how they were made.
struct PreparedGrid {
  TetGrid grid;
  IntervalTree index;
  PrepareStats stats;
};

PreparedGrid prepare(const Volume& v, const PrepareOptions& options, const Progress& progress = {});
// The same with the value range already known (it is scanned once otherwise).
PreparedGrid prepare(const Volume& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress = {});

}  // namespace adaptiso
