// adaptiso/prepare.hpp — the preprocessing pipeline as one call: volume → tetrahedral grid →
// vertex gradients (§2.3) → reconstruction error → extraction index (§2.4). The command line, the
// viewer, the Python module, the tests and the benches all prepare grids through prepare(); what
// it makes is a PreparedGrid (prepared_grid.hpp); prepare_to_file.hpp writes it to a grid file as
// it is made.
//
// Two grid builders, same output (tet_grid.hpp):
// - bisection (bisection.hpp): longest-edge bisection on the voxel lattice; the error bound is a
//   guarantee for the grid's own piecewise-linear reconstruction; linear time; gradients by
//   central differences by default.
// - delaunay (delaunay.hpp): the paper's pipeline, reduction (§2.1: PrepareOptions::reduce, its
//   method, threshold, gradient, sigma, kernel) then Delaunay tetrahedrization (§2.2); its bound holds for
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
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/prepared_grid.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/reduce.hpp"

namespace adaptiso {

enum class GridKind { bisection, delaunay };

// The default error bound, as a fraction of the value range. Measured with bench/defaults.py and
// bench/grids.py on every shared CT, MR and simulation volume at their suggested iso-values
// (docs/RESULTS.md; bench/results/HISTORY.md "Defaults"): at 0.02 every surface stays within 0.17 voxels of full-resolution
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
  // The error bound of the grid (max norm), for either builder. Unset: kDefaultRelativeError of
  // the value range, whatever `relative` says, or no error criterion when max_displacement is given
  // (the displacement alone). +∞ (bisection grid): no error criterion.
  std::optional<double> max_error;
  bool relative = false;        // max_error and reduce.threshold relative to the value range / largest gradient
  double max_displacement = 0;  // bisection: voxels an iso-surface may move, to first order (0: not used)
  // The Delaunay grid's reduction (§2.1, reduce.hpp): method, threshold, gradient operator, sigma,
  // kernel. Its max_error and relative are not read: the two fields above are the bound of either
  // grid, and prepare hands them to reduce() as they are (converted to data units once, there).
  ReduceOptions reduce;
  bool parallel_delaunay = true;
  GradientMethod gradients = GradientMethod::automatic;
  std::uint32_t tree_depth = kDefaultTreeDepth;
  // Measure the piecewise-linear error voxel by voxel (pl_max_error): always for the Delaunay grid,
  // on request for the bisection grid, whose bound is a guarantee (a violation throws logic_error).
  bool verify = false;
  std::string source_name;  // informational: the source's file name (folders are dropped)
  // Bisection grid: computes its error hierarchy (bisection.hpp) in place of bisection_errors on
  // this process, e.g. brick by brick or over MPI ranks (bisection_bricks.hpp); it must return the
  // same bytes. Unset: bisection_errors. It is handed the padded volume (below): bricks read from
  // a file are padded alike (padded_source, bisection_bricks.hpp).
  std::function<BisectionErrors(const Volume&, const ValueRange&, bool displacement, const Progress&)> error_hierarchy;
  // Bisection grid: the processes its selection is shared with (select_shares.hpp), this one being
  // their process 0; null: selected here alone.
  ShareTransport* select_share = nullptr;
  // Bisection grid: built on the padded lattice (bisection_lattice_dims, bisection.hpp), its
  // surfaces clipped to the volume's box. false: on the volume's own box, its far faces lined with
  // the finest tetrahedra that fit (what tests that compare a grid with its volume voxel by voxel
  // use).
  bool pad_lattice = true;
};

// The default bound for a volume with this value range, in the unit `relative` implies: a fraction
// of the range, or data units (the reduction alone, in the command line and Python, uses it too).
double default_max_error(const ValueRange& range, bool relative);

// The error bound that PrepareOptions asks for, in data units, for a volume with this value range
// (volume.hpp: from_fraction). Throws InputError when a relative bound overflows.
double absolute_max_error(const PrepareOptions& options, const ValueRange& range);

PreparedGrid prepare(const Volume& v, const PrepareOptions& options, const Progress& progress = {});

// The same with the value range already known (it is scanned once otherwise).
PreparedGrid prepare(const Volume& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress = {});

// The same, taking the volume: its voxels are released once the grid no longer needs them (after
// the gradients and the check of --verify, before the index), so the process's peak does not hold
// the volume and the index's build at once (the CT bunny at 0.02: 189 MB of a 2.1 GB peak). v keeps its
// geometry and type, with no voxels.
PreparedGrid prepare(Volume&& v, const PrepareOptions& options, const Progress& progress = {});
PreparedGrid prepare(Volume&& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress = {});

// prepare without the extraction index (PreparedGrid::index left empty; the statistics' index
// figures, index_depth and grid_bytes_per_vertex, as the index would give them, and no stage
// "index"): for a caller that asks only for whole surfaces by a scan (extract_scanned,
// extractor.hpp) or for the hierarchy's queries (hierarchy_query.hpp), none of which reads it. On
// the CT bunny (Python's prepare, 2026-12-01) 5.0-5.3 s peaking at 1.78 GB against 7.8-8.8 s and
// 2.52 GB with the index. add_index builds it when an Extractor is wanted after all. Throws what
// prepare throws.
PreparedGrid prepare_without_index(const Volume& v, const PrepareOptions& options, const Progress& progress = {});

// Builds the extraction index of a grid that has its tetrahedra but no index (prepare_without_index)
// at the depth it was prepared for (stats.tree_depth), as loading a grid file does; its figures in
// the statistics come from the index. Does nothing to a grid that has one, or no tetrahedra.
void add_index(PreparedGrid& grid, const Progress& progress = {});

// A bisection grid at a coarser bound (data units; +∞: the coarsest) from a prepared one, without
// the volume: what prepare would give at that bound, with its own index (the viewer's levels of
// detail). Throws InputError for a grid without a hierarchy.
PreparedGrid coarsen(const PreparedGrid& grid, double max_error, double max_displacement = 0, const Progress& progress = {});

// The same under a cell floor (bisection.hpp: BisectionOptions::cell_floor): no tetrahedron finer
// than cubes of 2^cell_floor voxels but where the volume's box forces it, for surfaces some 4×
// smaller a step of the floor on any data. Its error bound (stats.error_bound, guaranteed) is
// measured, not asked for; it has no hierarchy, being no selection at one bound.
PreparedGrid coarsen_floored(const PreparedGrid& grid, double max_error, int cell_floor, const Progress& progress = {});

// The steps prepare() combines, for the callers that combine them otherwise (prepare_to_file.hpp:
// the grid file without its index).
namespace detail {

// Where prepare_unindexed hands a bisection grid as it is made, instead of keeping its tetrahedra
// (prepare_to_file: straight into the file). Called on the calling thread.
class PreparedGridSink {
public:
  virtual ~PreparedGridSink() = default;
  // The vertices with their gradients, the hierarchy's codes and the statistics (stages but the
  // last, tetrahedra counted) are final; stats.tetrahedra tetrahedra follow.
  virtual void begin(const PrepareStats& stats, const TetGrid& vertices, const BisectionHierarchy& hierarchy) = 0;
  virtual void write(std::span<const std::array<std::uint32_t, 4>> tets) = 0;
};

// Whether prepare_unindexed can hand these options' grid to a sink: a bisection grid whose
// gradients come from the volume and whose tetrahedra nothing after the selection reads.
bool can_sink(const PrepareOptions& options);

// Every stage before the index (the grid, its gradients, the check of `verify`), timed into the
// grid's stats. `release`, when not null, is v itself, whose voxels go once nothing reads them.
// With `sink` (can_sink), the grid's tetrahedra go there and the grid returned has none; the time
// spent in the sink is the stage "save". Throws what prepare throws.
PreparedGrid prepare_unindexed(const Volume& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress,
                               Volume* release, PreparedGridSink* sink = nullptr);

// Records a stage that took `seconds` in stats, with the process's peak memory so far.
void record_stage(PrepareStats& stats, const std::string& name, double seconds);

}  // namespace detail

}  // namespace adaptiso
