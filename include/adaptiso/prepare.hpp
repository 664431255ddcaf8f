// adaptiso/prepare.hpp — the preprocessing pipeline as one call: volume → tetrahedral grid →
// vertex gradients (§2.3) → reconstruction error → extraction index (§2.4). The command line, the
// viewer, the Python module, the tests and the benches all prepare grids through prepare().
//
// Two grid builders, same output (tet_grid.hpp):
// - bisection (bisection.hpp): longest-edge bisection on the voxel lattice; the error bound is a
//   guarantee for the grid's own piecewise-linear reconstruction; linear time; gradients by
//   central differences by default.
// - delaunay (delaunay.hpp): the paper's pipeline, reduction (§2.1: the options method, threshold,
//   structural_gradient, sigma, kernel) then Delaunay tetrahedrization (§2.2); its bound holds for
//   trilinear interpolation in the octree's cubes, not for the tetrahedra, so the grid's error is
//   measured (pl_max_error) and may exceed it; least-squares gradients by default.
//
// Units: max_error in data units, or a fraction of the value range with `relative`; threshold
// likewise (a fraction of the largest gradient magnitude with `relative`); max_displacement in
// voxels. Left unset, max_error is kDefaultRelativeError of the value range: the bound measured
// to serve a first look at any scan (README "Defaults"; bench/defaults.py).
// Throws OptionError for a bad option (named as in PrepareOptions), InputError when the volume
// cannot be prepared (flat, too many vertices for 32-bit indices, more memory than the machine has).
#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/interval_tree.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

enum class GridKind { bisection, delaunay };

// The default error bound, as a fraction of the value range. Measured with bench/defaults.py and
// bench/grids.py on every shared CT, MR and simulation volume at their suggested iso-values
// (docs/RESULTS.md "Defaults"): at 0.02 every surface stays within 0.17 voxels of full-resolution
// marching cubes on average (95 % of it within 0.72), and the 512×512×361 CT bunny prepares in
// well under a minute; 0.05 prepares about 1.6× faster with ~15 % fewer triangles but drifts to
// 0.21 (0.89) voxels, so the default keeps the accuracy.
inline constexpr double kDefaultRelativeError = 0.02;

enum class GradientMethod {
  automatic,      // central differences on the bisection grid, least squares on the Delaunay grid
  least_squares,  // the paper's fit over each vertex's ring (gradients.hpp)
  central,        // central differences of the volume
};

struct PrepareOptions {
  GridKind grid = GridKind::bisection;
  // The error bound of the grid (max norm). Unset: kDefaultRelativeError of the value range,
  // whatever `relative` says, or no error criterion when max_displacement is given (the
  // displacement alone). +∞ (bisection grid): no error criterion.
  std::optional<double> max_error;
  bool relative = false;        // max_error and threshold relative to the value range / largest gradient
  double max_displacement = 0;  // bisection: voxels an iso-surface may move, to first order (0: not used)
  // The paper's reduction (§2.1).
  ReduceMethod method = ReduceMethod::reconstruction;
  double threshold = 0;
  GradientOperator structural_gradient = GradientOperator::central;
  double sigma = 1.0;
  int kernel = 0;
  bool parallel_delaunay = true;
  GradientMethod gradients = GradientMethod::automatic;
  std::uint32_t tree_depth = kDefaultTreeDepth;
  // Measure the piecewise-linear error voxel by voxel (pl_max_error): always for the Delaunay grid,
  // on request for the bisection grid, whose bound is a guarantee (a violation throws logic_error).
  bool verify = false;
  std::string source_name;  // informational: the source's file name (folders are dropped)
};

// The default bound for a volume with this value range, in the unit `relative` implies: a fraction
// of the range, or data units (the reduction alone, in the command line and Python, uses it too).
double default_max_error(const ValueRange& range, bool relative);

// The error bound that PrepareOptions asks for, in data units, for a volume with this value range.
double absolute_max_error(const PrepareOptions& options, const ValueRange& range);

// The reduction options that PrepareOptions implies (the threshold as given, the error bound in
// the same unit: relative to the range with `relative`).
ReduceOptions reduce_options(const PrepareOptions& options, const ValueRange& range);

struct StageStats {
  std::string name;  // "reduce", "tetrahedralize", "gradients", "pl_error", "index", ...
  double seconds = 0;
  std::uint64_t peak_bytes = 0;  // resident memory peak of the process up to the stage's end (Linux; 0 elsewhere)
};

struct PrepareStats {
  std::string grid;  // "bisection" or "delaunay"
  std::int64_t voxels = 0;
  std::uint64_t kept = 0, tetrahedra = 0;
  double max_error = 0;                         // the absolute bound asked for
  double threshold = 0;                         // the absolute structural threshold used
  double error_bound = -1;                      // bisection: the guaranteed max-norm error (< 0: no guarantee)
  double max_displacement = 0;                  // bisection: the displacement criterion used (voxels; 0: none)
  double pl_max_error = -1, pl_rms_error = -1;  // measured (< 0: not measured)
  std::uint32_t index_depth = 0;
  double grid_bytes_per_vertex = 0;
  std::vector<StageStats> stages;
  double seconds(const std::string& stage) const;  // 0 when the stage did not run
};

// One JSON object: grid, voxels, kept, ratio, tetrahedra, max_error, pl_max_error, pl_rms_error,
// error_bound, index_depth, grid_bytes_per_vertex, seconds{stage}, peak_bytes{stage}; and back (fields that
// are missing keep their defaults, so older grid files load).
std::string to_json(const PrepareStats& stats);
PrepareStats prepare_stats_from_json(const std::string& json);

// A grid ready for extraction: the tetrahedra, the index over them and how they were made.
struct PreparedGrid {
  TetGrid grid;
  IntervalTree index;
  PrepareStats stats;
  std::optional<BisectionHierarchy> hierarchy;  // bisection grids: for queries at a coarser error
  // Floored levels (coarsen_floored): per tetrahedron the code of its own guaranteed bound, in
  // tet_codes; empty otherwise.
  std::vector<std::uint8_t> tet_error_code;
  ErrorCodes tet_codes;
};

// The error of a grid's surfaces, data units: guaranteed on a bisection grid, measured on a
// Delaunay grid.
double surface_error(const PrepareStats& stats);

// The error of a surface made of the given tetrahedra of the grid (data units; the Extractor's
// active() after an extract): on a floored level the largest guaranteed bound among them (0 for
// none: a unit tetrahedron holds no voxel but its corners), elsewhere surface_error.
double surface_error_bound(const PreparedGrid& grid, const std::vector<std::uint32_t>& tetrahedra);

PreparedGrid prepare(const Volume& v, const PrepareOptions& options, const Progress& progress = {});

// The same with the value range already known (it is scanned once otherwise).
PreparedGrid prepare(const Volume& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress = {});

// The same, taking the volume: its voxels are released once the grid no longer needs them (after
// the gradients and the check of --verify, before the index), so the process's peak does not hold
// the volume and the index's build at once (the CT bunny at 0.02: 189 MB of a 2.1 GB peak). v keeps its
// geometry and type, with no voxels.
PreparedGrid prepare(Volume&& v, const PrepareOptions& options, const Progress& progress = {});
PreparedGrid prepare(Volume&& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress = {});

// prepare(std::move(v), ...) and save_grid(grid, path) in one, for a caller that wants the file:
// the same bytes, written as they are made. The grid's positions and gradients are on disk and
// freed before the index is built, and the index's sort takes what the file's bytes plus 2.5
// volumes leave, so the peak stays there where the grid and its index in memory at once cannot
// (the 256×256×133 chest CT: 304 MB file, 2.5 volumes 22 MB). Returns the statistics, with the
// writing's time as the stage "save". Throws what prepare and save_grid throw; on any failure no
// file is left at path.
PrepareStats prepare_to_file(Volume&& v, const PrepareOptions& options, const std::string& path, const Progress& progress = {});
PrepareStats prepare_to_file(Volume&& v, const ValueRange& range, const PrepareOptions& options, const std::string& path,
                             const Progress& progress = {});
// The same, lending the volume (it keeps its voxels, which then stay resident: the Python module).
PrepareStats prepare_to_file(const Volume& v, const PrepareOptions& options, const std::string& path, const Progress& progress = {});

// A bisection grid at a coarser bound (data units; +∞: the coarsest) from a prepared one, without
// the volume: what prepare would give at that bound, with its own index (the viewer's levels of
// detail). Throws InputError for a grid without a hierarchy.
PreparedGrid coarsen(const PreparedGrid& grid, double max_error, double max_displacement = 0, const Progress& progress = {});

// The same under a cell floor (bisection.hpp: BisectionOptions::cell_floor): no tetrahedron finer
// than cubes of 2^cell_floor voxels but where the volume's box forces it, for surfaces some 4×
// smaller a step of the floor on any data. Its error bound (stats.error_bound, guaranteed) is
// measured, not asked for; it has no hierarchy, being no selection at one bound.
PreparedGrid coarsen_floored(const PreparedGrid& grid, double max_error, int cell_floor, const Progress& progress = {});

}  // namespace adaptiso
