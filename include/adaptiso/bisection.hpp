// adaptiso/bisection.hpp — a grid that keeps its error bound: longest-edge bisection on the voxel
// lattice (Maubach's bisection of the Kuhn cube; the diamond hierarchy of Gregorski, Duchaineau,
// Lindstrom, Pascucci and Joy, "Interactive view-dependent rendering of large isosurfaces", 2002).
// The alternative to the paper's reduction and Delaunay grid (§2.1–2.2), with the same output.
//
// The hierarchy: the cube of side S = 2^k ≥ max(dims) − 1 that covers the volume from its first
// voxel is split into 6 tetrahedra around its main diagonal, and every tetrahedron at the midpoint
// of its longest edge, recursively, down to the Kuhn tetrahedra of the unit cubes. Every vertex is
// a voxel: no new points, no geometric predicates, no degenerate configurations. A tetrahedron is
// split together with all tetrahedra around its refinement edge (its *diamond*), and those need
// their own parents split, so the selected mesh is conforming: no hanging vertex.
//
// Volumes whose dimensions are not 2^k + 1: the grid tiles exactly the volume's box [0, dims−1]
// (index units) and no tetrahedron reaches outside it. Diamonds whose cubes cross the box's far
// faces are always split, so the far faces are reached by the finest tetrahedra that fit (where a
// far face lies at an odd index, tetrahedra of unit size line it); cubes wholly outside the box are
// never visited. Near faces lie at index 0, on every cube's boundary. prepare() therefore builds
// the grid on a padded lattice (bisection_lattice_dims, below): each far face moved out to a
// multiple of 8 voxels with copies of the volume's last slices, where tetrahedra 8 voxels across
// meet it; its surfaces are clipped back to the volume's box (GridSource::volume_dims). A smooth
// 64³ volume then costs what its 65³ neighbour does, not 7.6× as much. Anisotropic spacing changes
// nothing here: the hierarchy lives in index space, and the grid frame scales it. A dimension of 1
// leaves no volume to tile and is refused (InputError).
//
// Bricks: the hierarchy is that of the volume's own box (its root cube starts at its voxel 0), so
// grids built from bricks of a larger volume are separate hierarchies. The global lattice keys
// (tet_grid.hpp) name the vertices and edges of a face two bricks share alike, but nothing here
// makes their triangulations of that face agree: a brick's far faces are lined with its finest
// tetrahedra, its near faces follow its own selection.
// (bisection_bricks.hpp computes one volume's error hierarchy brick by brick, on the whole
// volume's lattice: that is one hierarchy, the same as bisection_errors'.)
//
// The error guarantee (max norm, data units): every voxel is reproduced within max_error by the
// linear interpolant of the tetrahedron that holds it (each tetrahedron holding it, on shared
// faces). Per diamond a conservative signed bound of value − interpolant over every voxel beneath
// it is computed bottom-up in time linear in the voxels: on each half of a split tetrahedron the
// difference between the parent's interpolant and the half's is linear, zero at the shared
// vertices and δ = (f(p) + f(q))/2 − f(m) at the midpoint m of the refinement edge pq, so the
// parent's bound is the halves' bound widened by δ on one side. Bounds are saturated over the
// hierarchy (a diamond's error is at least its descendants'), so selecting every diamond above a
// bound is closed under the conformity dependencies, and quantized conservatively to one byte per
// lattice vertex (16 steps per octave, 2^-15.8 of the value range to the range, rounded up).
//
// The displacement criterion (max_displacement D, in voxels): a tetrahedron is also split when
// its error bound exceeds D·max(g_min, g0), g_min the smallest gradient magnitude (central
// differences, one-sided at the border; data units per voxel step) at the voxels beneath it and
// g0 = 1 % of the value range per voxel, the floor below which an iso-surface's position is set by
// noise, not by the data. To first order no iso-surface of any iso-value then moves more than D
// voxels (measured in the benchmark).
//
// Throws InputError for a flat volume (a dimension of 1), OptionError("max_error" /
// "max_displacement") for a negative or non-finite bound, InputError when the grid would exceed
// 32-bit vertex indices.
#pragma once
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

class ShareTransport;  // select_shares.hpp
struct BisectionGrid;
class TetrahedraSink;

// A tetrahedron is split when either criterion asks for it.
struct BisectionOptions {
  double max_error = 0;         // data units; +∞: no error criterion
  double max_displacement = 0;  // voxels; 0: not used
  // bisection_coarsen only: no diamond is split below cubes of side 2^cell_floor voxels (0: no
  // floor), except where the volume's box forces it. The grid then no longer keeps max_error:
  // its bounds are measured, the largest codes among the diamonds the floor left whole.
  int cell_floor = 0;
  // bisection_select only: the processes that share its walks (select_shares.hpp), this one being
  // their process 0 (the others call bisection_select_share); null: this process alone.
  ShareTransport* share = nullptr;
  // bisection_select only: where its tetrahedra go, in order, instead of into the grid it returns
  // (whose tets stay empty); null: kept. prepare_to_file writes them straight into the file.
  TetrahedraSink* sink = nullptr;
  // bisection_select only: how many tetrahedra go to the sink at once (a larger subtree goes
  // whole), and from one process to another at once (the others take process 0's); 64 MB of them.
  std::uint64_t piece = std::uint64_t{1} << 22;
};

// Conservative one-byte codes for error bounds relative to a scale (the value range): code 0 is
// an error of 0 (up to rounding), 255 "always split" (across the volume's boundary), 1…254 are
// scale·2^((code − 254)/16), rounded up.
struct ErrorCodes {
  double scale = 1;  // the value range (1 for a constant volume)
  double zero = 0;   // errors up to this count as 0 (rounding of the data's magnitude)
  static constexpr std::uint8_t kForced = 255;
  std::uint8_t code(double error) const;       // the smallest code whose error is ≥ error
  double error(std::uint8_t code) const;       // the error a code stands for
  std::uint8_t threshold(double bound) const;  // the largest code whose error is ≤ bound
};

// The scale of the displacement codes (voxels): they span 0.0045 … 256 voxels.
inline constexpr double kDisplacementCodeScale = 256;

// What a coarser query needs of the hierarchy: the selection of the grid is every diamond whose
// code exceeds the threshold; a coarser error raises the threshold (hierarchy_query.hpp).
struct BisectionHierarchy {
  std::int32_t root_size = 0;  // S
  ErrorCodes codes;
  std::uint8_t error_threshold = 0;      // of the grid's max_error
  std::vector<std::uint8_t> error_code;  // per grid vertex: the saturated code of its diamond
  // Per grid vertex whose diamond the grid splits: the smallest and largest value of the grid's
  // vertices beneath it (floats rounded outwards; an empty span, +∞ … −∞, for the others).
  std::vector<std::array<float, 2>> value_span;
  // With the displacement criterion (voxels; empty otherwise).
  ErrorCodes displacement_codes;
  std::uint8_t displacement_threshold = 0;
  std::vector<std::uint8_t> displacement_code;
};

struct BisectionGrid {
  TetGrid grid;  // values filled, gradients left empty (gradients.hpp)
  BisectionHierarchy hierarchy;
  double error_bound = 0;          // guaranteed max-norm error of the grid's piecewise-linear reconstruction
  double displacement_bound = -1;  // voxels, when the displacement criterion is used
  // Under a cell floor: per tetrahedron, the code of its own bound (the diamond it would split
  // at; 0 for a unit tetrahedron), so a surface's error can be that of the tetrahedra it cuts.
  std::vector<std::uint8_t> tet_code;
};

// The receiver of a selection's tetrahedra (BisectionOptions::sink): with it no process holds them
// all (the CT bunny's 54 M are 0.87 GB, half of prepare's peak, and faulting that memory in was a
// fifth of two MPI ranks' time). Called on the calling thread.
class TetrahedraSink {
public:
  virtual ~TetrahedraSink() = default;
  // Before the first tetrahedra: the grid's vertices (ijk, values), its hierarchy's codes,
  // thresholds and error bounds are final; `tets` tetrahedra will follow. The value spans are
  // not: they are complete when bisection_select returns.
  virtual void begin(BisectionGrid& grid, std::uint64_t tets) = 0;
  // The next tetrahedra, in the grid's order (four vertex numbers each); valid for the call only.
  virtual void write(std::span<const std::array<std::uint32_t, 4>> tets) = 0;
};

// The error hierarchy alone: a saturated code per voxel (1 byte each), then the selection at a
// bound; bisection_grid runs both.
struct BisectionErrors {
  std::int32_t root_size = 0;
  ErrorCodes codes;
  std::vector<std::uint8_t> code;  // per voxel (x fastest): the code of the diamond centred there
  ErrorCodes displacement_codes;   // with the displacement criterion: its codes, likewise
  std::vector<std::uint8_t> displacement_code;
};
BisectionErrors bisection_errors(const Volume& v, const ValueRange& range, bool displacement = false, const Progress& progress = {});
BisectionGrid bisection_select(const Volume& v, const ValueRange& range, const BisectionErrors& errors, const BisectionOptions& options,
                               const Progress& progress = {});

BisectionGrid bisection_grid(const Volume& v, const ValueRange& range, const BisectionOptions& options, const Progress& progress = {});

// The lattice prepare() builds a volume's bisection grid on: per axis, dims − 1 rounded up to a
// multiple of a step, 8 voxels or less on small volumes (the largest power of two ≤ (dims − 1)/4,
// so a small volume is padded by at most a quarter), plus one. The root cube never grows: it
// covers dims − 1 rounded up to a power of two ≥ the step. Pad the volume with pad_volume
// (volume.hpp).
Dims bisection_lattice_dims(const Dims& volume);

// The grid at a coarser bound from a bisection grid and its hierarchy, without the volume: the
// same grid bisection_grid gives at that bound (vertices, tetrahedra and their order), gradients
// copied. Bounds below the fine grid's give the fine grid. Throws InputError when the hierarchy
// is not the grid's, OptionError for a bad bound or floor.
//
// With a cell floor the triangle count of its surfaces falls about 4× a step of the floor
// whatever the data, where a coarser bound alone may not reduce it at all (on a noisy scan the
// surface follows noise up to errors of a large part of the range): the viewer's coarse levels.
// The floor follows the dependencies (a diamond's parents are at its scale or above), so the grid
// stays conforming; its hierarchy describes no single bound and must not be coarsened again.
BisectionGrid bisection_coarsen(const TetGrid& fine, const BisectionHierarchy& hierarchy, const BisectionOptions& options,
                                const Progress& progress = {});

}  // namespace adaptiso
