// adaptiso/synthetic.hpp — built-in volumes that need no files.
//
// sphere (the test volume of Lürig & Ertl §3): N³ voxels of `type` (default int16). With the
// centre c = (N-1)/2 and radius R = N/4 (voxels), the value is 1000 inside the sphere (r ≤ R) and
// 1000·R/r outside, i.e. it falls off with the inverse distance to the centre towards the borders.
// The value range is [1000·R/r_corner, 1000] ≈ [289, 1000]; the paper's relative iso 0.7 is the
// sphere r ≈ 1.27 R. Integer types round to nearest.
// marschner-lobb: the Marschner–Lobb test signal (fM = 6, α = 0.25) on [-1,1]³, values in [0,1]
// (scaled ×255 for uint8/int8, ×1000 for wider integer types).
// linear: 1·i + 2·j + 3·k (a field trilinear interpolation reproduces exactly).
// noise: uniform white noise in [0, 1000) from a fixed seed (deterministic).
// torus: signed distance-like field of a torus (major radius N/4, minor N/10), values 0..1000.
#pragma once
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"

namespace adaptiso {

std::vector<std::string> synthetic_names();
// Throws InputError for an unknown name or a size < 2.
Volume make_synthetic(const std::string& name, std::int64_t size, ScalarType type);
// Default element type of each built-in volume (int16 for sphere, float32 otherwise).
ScalarType synthetic_default_type(const std::string& name);

}  // namespace adaptiso
