// adaptiso/surface_distance.hpp — how far apart are two surfaces? Symmetric surface distance by
// point-to-triangle distance (CGAL AABB tree), from dense area-uniform samples of each surface
// (plus its vertices) to the other surface.
#pragma once
#include <cstdint>

#include "adaptiso/mesh.hpp"

namespace adaptiso {

struct DistanceStats {
  std::size_t samples = 0;
  double mean = 0, rms = 0, p95 = 0, max = 0;
};

struct SurfaceDistance {
  DistanceStats a_to_b, b_to_a;
  double hausdorff() const { return a_to_b.max > b_to_a.max ? a_to_b.max : b_to_a.max; }
};

struct DistanceOptions {
  std::size_t min_samples = 200'000;  // per direction; at least 4 per triangle as well
  std::size_t max_samples = 4'000'000;
  std::uint64_t seed = 1;  // fixed: the same meshes give the same figures
};

// Throws InputError when either mesh has no triangles. Parallel.
SurfaceDistance surface_distance(const Mesh& a, const Mesh& b, const DistanceOptions& options = {});

}  // namespace adaptiso
