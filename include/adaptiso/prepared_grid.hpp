// adaptiso/prepared_grid.hpp — what preparation makes and extraction takes: the tetrahedral grid,
// the extraction index over it, the bisection hierarchy (bisection grids) and the statistics of how
// it was made, with their JSON. prepare.hpp makes one, grid_file.hpp stores and loads one; the
// Extractor, the hierarchy's queries and the levels of detail read one, and need nothing else of
// the pipeline.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/interval_tree.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

struct StageStats {
  std::string name;  // "reduce", "tetrahedralize", "gradients", "pl_error", "index", ...
  double seconds = 0;
  std::uint64_t peak_bytes = 0;  // resident memory peak of the process up to the stage's end (Linux; 0 elsewhere)
};

struct PrepareStats {
  std::string grid;  // "bisection" or "delaunay"
  std::int64_t voxels = 0;
  std::uint64_t kept = 0;      // the volume's voxels the grid keeps as vertices
  std::uint64_t vertices = 0;  // all its vertices: kept and, on a padded lattice, the copies past the far faces
  std::uint64_t tetrahedra = 0;
  double max_error = 0;                          // the absolute bound asked for
  double threshold = 0;                          // the absolute structural threshold used
  double error_bound = -1;                       // bisection: the guaranteed max-norm error (< 0: no guarantee)
  double max_displacement = 0;                   // bisection: the displacement criterion used (voxels; 0: none)
  double pl_max_error = -1, pl_rms_error = -1;   // measured (< 0: not measured)
  std::uint32_t index_depth = 0;                 // the index's, reduced from tree_depth where there are fewer tetrahedra than leaves
  std::uint32_t tree_depth = kDefaultTreeDepth;  // the index's depth asked for (PrepareOptions::tree_depth)
  double grid_bytes_per_vertex = 0;
  std::vector<StageStats> stages;
  double seconds(const std::string& stage) const;  // 0 when the stage did not run
};

// One JSON object: grid, voxels, kept, ratio (kept / voxels), vertices (when counted), tetrahedra,
// max_error, pl_max_error, pl_rms_error, error_bound, index_depth, tree_depth, grid_bytes_per_vertex,
// seconds{stage}, peak_bytes{stage}; and back (fields that are missing keep their defaults, so older
// grid files load).
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

// Bytes the grid and its index occupy in memory (= the grid file without header and metadata), per
// vertex.
double grid_bytes_per_vertex(const TetGrid& grid, const IntervalTree& index);

namespace detail {
// The statistics' index figures (index_depth, grid_bytes_per_vertex as loaded, with the index) for
// an index of that shape over stats.vertices and stats.tetrahedra, not built (loading builds it:
// prepare_to_file, and the command line's run).
void set_index_figures(PrepareStats& stats, const IntervalTreeShape& shape);
}  // namespace detail

}  // namespace adaptiso
