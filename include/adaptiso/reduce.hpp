// adaptiso/reduce.hpp — vertex reduction of the uniform grid (Lürig & Ertl §2.1).
//
// Two criteria, alone or combined (union); the 8 corners of the volume are always kept.
//
// Structural analysis: the gradient by central differences (one-sided at the border) or by the 3D
// Canny operator (separable convolution with derivatives of a Gaussian, border values replicated);
// a voxel is kept when |gradient| > threshold and |gradient| is a local maximum along the gradient:
// the two neighbours v ± d, d = the gradient direction rounded to one of the 26 neighbour
// directions, have |gradient| ≤ |gradient(v)| and at least one is strictly lower (a neighbour
// outside the volume counts as lower-or-equal but not strictly lower). Gradients are in data units
// per voxel step.
//
// Reconstruction analysis: an implicit octree over the volume extended to a power-of-two cube of
// edge S ≥ max(dims) − 1; atomic cubes span 3³ voxels. A cube is merged when all its sub-cubes are
// merged and trilinear interpolation from its corners reproduces every voxel of the cube within
// max_error (max norm). Outside the volume there are no voxels: a cube that crosses the volume's far
// border is clipped to it, interpolates from the corners of the clipped box (real voxels), and
// those clipped corners are kept when the cube is a leaf; cubes wholly outside never need testing.
// A shared vertex (an edge, face or centre midpoint of its cubes) is dropped only when every cube
// that holds it merged: 4/2/1 cubes inside the volume, 2/1/1 on a side, 1/1/1 on an edge (the
// paper's Tables 1–3; the count is derived from the vertex position).
// Guarantee: every voxel is reproduced within max_error by trilinear interpolation from the kept
// corners of the leaf (maximal merged) cube that contains it (verify_reconstruction checks it).
//
// Error and threshold are in data units; with `relative`, max_error is a fraction of the value
// range and threshold a fraction of the largest gradient magnitude.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "adaptiso/progress.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso {

enum class ReduceMethod { reconstruction, structural, both };
enum class GradientOperator { central, canny };

struct ReduceOptions {
  ReduceMethod method = ReduceMethod::reconstruction;
  double max_error = 0.0;
  double threshold = 0.0;
  GradientOperator gradient = GradientOperator::central;
  double sigma = 1.0;  // Canny: standard deviation of the Gaussian, in voxels
  int kernel = 0;      // Canny: kernel size (odd); 0 = 2·ceil(3σ)+1
  bool relative = false;
};

// Merge state of the implicit octree, kept for verification.
struct OctreeMerges {
  int levels = 0;         // m, with S = 2^m
  std::int64_t size = 0;  // S
  Dims dims{};
  std::vector<Dims> counts;                       // [l-1]: cubes per axis at level l (those meeting the volume)
  std::vector<std::vector<std::uint8_t>> merged;  // [l-1]: 1 if the cube merged
  bool is_merged(int level, std::int64_t cx, std::int64_t cy, std::int64_t cz) const {
    const Dims& n = counts[static_cast<std::size_t>(level - 1)];
    return merged[static_cast<std::size_t>(level - 1)][static_cast<std::size_t>(cx + n[0] * (cy + n[1] * cz))] != 0;
  }
};

struct ReduceResult {
  std::vector<std::int64_t> kept;  // sorted linear voxel indices (x fastest)
  double max_error = 0;            // absolute bound used
  double threshold = 0;            // absolute gradient threshold used
  std::int64_t kept_reconstruction = 0, kept_structural = 0;
  OctreeMerges octree;  // empty for the structural method
};

// Throws OptionError for bad options (negative error, even kernel, …), named as in ReduceOptions.
ReduceResult reduce(const Volume& v, const ReduceOptions& options, const Progress& progress = {});
// The same with the value range already known (it is scanned once otherwise).
ReduceResult reduce(const Volume& v, const ValueRange& range, const ReduceOptions& options, const Progress& progress = {});

// The two criteria on their own (sorted voxel indices; corners not added).
std::vector<std::int64_t> structural_analysis(const Volume& v, const ReduceOptions& options, double* threshold_used,
                                              const Progress& progress = {});
std::vector<std::int64_t> reconstruction_analysis(const Volume& v, double max_error, OctreeMerges* merges, const Progress& progress = {});
std::vector<std::int64_t> reconstruction_analysis(const Volume& v, const ValueRange& range, double max_error, OctreeMerges* merges,
                                                  const Progress& progress = {});

// Checks the guarantee voxel by voxel: returns the largest |value − trilinear reconstruction| over
// all voxels, each taken in every leaf cube that contains it. Throws std::logic_error if a leaf
// corner is missing from `kept`. Needs the octree of a reconstruction or both-method result.
double verify_reconstruction(const Volume& v, const ReduceResult& r);

// Voxel indices of the 8 corners of the volume (fewer when a dimension is 1).
std::vector<std::int64_t> volume_corners(const Volume& v);

}  // namespace adaptiso
