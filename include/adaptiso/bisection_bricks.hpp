// adaptiso/bisection_bricks.hpp — the bisection grid's error hierarchy (bisection_errors,
// bisection.hpp) computed brick by brick, byte for byte the same, so a volume need never be in
// memory at once (later: one brick per MPI rank).
//
// Bricks: cubes of side B = 2^b voxel steps (B ≥ 2) aligned to multiples of B in index space, on
// the whole volume's lattice (its root cube S and its box [0, dims−1]). Brick (i, j, k) covers the
// voxels [iB, (i+1)B] per axis, clipped to the box, so neighbours share their face plane; it owns
// the voxels [iB, (i+1)B) (the last brick along an axis also its far face). A brick side ≥ S is
// one brick. Bricks are numbered x fastest.
//
// Two steps. The brick step runs the hierarchy of the scales h < B on one brick's voxels, except
// for its *seam* diamonds, and hands up what the combine step needs of those (BrickErrors). The
// combine step takes every brick's result, in any order, evaluates the seam diamonds scale by
// scale and then the coarse scales h ≥ B over the whole box, and returns what bisection_errors
// returns for the whole volume, byte for byte.
//
// Why the seams: a diamond's bound covers its children's whole diamonds, and a child may reach
// across a brick's face plane. A diamond of scale h whose centre lies on a face plane, or h from
// one (across which its children reach), is a seam diamond, and so is every cube centre of scale
// B/2 and every diamond of scale ≥ B; a diamond that is no seam diamond has no seam diamond among
// its descendants, so a brick evaluates it exactly from its own voxels. A seam diamond's children
// that are no seam diamonds all lie in the brick that owns its centre, which hands up their
// bounds united (unite is min/max, exact in any order), the diamond's δ and, with the
// displacement criterion, the gradient at its centre; the combine step then applies the same
// operations in the same precision as the whole-volume run (including the float rounding of
// stored bounds), and the displacement codes are computed from complete bounds only. The coarse
// scales need the voxels at multiples of B (and their gradients), handed up by their owners.
//
// Units: voxel index space; bounds in data units. The value range must be the whole volume's
// (value_range), as for bisection_errors. With the displacement criterion a brick also reads the
// voxel plane below its near faces (central differences at its seam planes).
//
// Throws OptionError("brick_side") for a brick side that is not a power of two ≥ 2, InputError
// for a flat volume (as bisection_errors) or a region whose dimensions are not the brick's, and
// InputError when the results handed to the combine step are not one per brick.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "adaptiso/bisection.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso {

// The bricks of a volume.
struct BrickGrid {
  Dims dims{0, 0, 0};     // the volume's
  std::int64_t side = 0;  // B, at most the root cube's side
  Dims count{0, 0, 0};    // bricks per axis
  std::int64_t size() const { return count[0] * count[1] * count[2]; }
  Dims brick(std::int64_t n) const { return {n % count[0], n / count[0] % count[1], n / (count[0] * count[1])}; }
  VoxelBox covers(std::int64_t n) const;                    // [iB, (i+1)B] clipped
  VoxelBox owns(std::int64_t n) const;                      // the voxels whose codes it writes
  VoxelBox reads(std::int64_t n, bool displacement) const;  // what its brick step reads
};
BrickGrid brick_grid(const Dims& dims, std::int64_t brick_side);
// The brick side's check alone (brick_grid makes it too): before a volume is read.
void check_brick_side(std::int64_t brick_side);

// What one brick hands up: its own codes, and flat arrays for the combine step.
struct BrickErrors {
  std::int64_t brick = 0;  // its number in the BrickGrid
  // Per owned voxel (x fastest over BrickGrid::owns): the saturated codes of the diamonds centred
  // there, except at seam diamonds (0; the combine step writes those).
  std::vector<std::uint8_t> code, displacement_code;
  // Per seam diamond centred in an owned voxel: its global voxel index (x fastest over the
  // volume), the union of the bounds of its children computed here (lo ≤ 0 ≤ hi, data units), its
  // δ (data units) and, with the displacement criterion, the smallest gradient magnitude beneath
  // those children and at its centre (data units per voxel step).
  std::vector<std::int64_t> seam_voxel;
  std::vector<double> seam_lo, seam_hi, seam_delta, seam_g, seam_gradient;
  // Per owned voxel whose coordinates are all multiples of B (x fastest): its value and, with the
  // displacement criterion, its gradient magnitude. The coarse scales need only these.
  std::vector<std::int64_t> coarse_voxel;
  std::vector<double> coarse_value, coarse_gradient;

  // The bytes handed to the combine step beyond the brick's own codes (the seams and the coarse
  // points): what crosses brick faces.
  std::uint64_t bytes_exchanged() const;
};

// The brick step on the voxels `region` (dims of BrickGrid::reads(brick, displacement); its
// spacing and origin are ignored). Runs on the calling thread's TBB arena.
BrickErrors bisection_brick_errors(const BrickGrid& bricks, std::int64_t brick, const Volume& region, const ValueRange& range,
                                   bool displacement = false);

// The combine step: every brick's result exactly once, in any order (consumed).
BisectionErrors bisection_combine_bricks(const BrickGrid& bricks, std::vector<BrickErrors> results, const ValueRange& range,
                                         bool displacement = false, const Progress& progress = {});

// The voxels of a box, as a volume of the box's dims (a reader can serve them from a file).
using RegionSource = std::function<Volume(const VoxelBox&)>;
// Regions copied out of a volume in memory (which must outlive the source).
RegionSource region_source(const Volume& v);
// Regions of the volume padded past its far faces (pad_volume, volume.hpp: the lattice prepare
// builds a bisection grid on) from a source of the volume's own, of dims `volume` and value range
// `range` (the whole volume's): a region reaching past a far face reads what its reflection needs
// inside and pads it, the same values pad_volume gives the whole volume.
RegionSource padded_source(RegionSource source, const Dims& volume, const ValueRange& range);

// Both steps: the bricks in parallel, each reading its region from `source`. The same bytes as
// bisection_errors(volume, range, displacement). bytes_exchanged, when given, receives the sum
// over the bricks.
BisectionErrors bisection_errors_bricked(const Dims& dims, const ValueRange& range, std::int64_t brick_side, const RegionSource& source,
                                         bool displacement = false, const Progress& progress = {},
                                         std::uint64_t* bytes_exchanged = nullptr);

}  // namespace adaptiso
