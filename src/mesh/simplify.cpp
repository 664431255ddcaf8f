// Mesh simplification to a distance (see simplify.hpp), with meshoptimizer's simplifier.
#include "adaptiso/simplify.hpp"

#include <fmt/format.h>
#include <meshoptimizer.h>

#include <chrono>
#include <cmath>
#include <vector>

#include "adaptiso/error.hpp"

namespace adaptiso {

Mesh simplify_mesh(const Mesh& m, double distance, SimplifyStats* stats) {
  if (!(distance >= 0) || !std::isfinite(distance))
    throw OptionError("simplify", fmt::format("must be a non-negative distance, got {}", distance));
  const auto t0 = std::chrono::steady_clock::now();
  SimplifyStats st;
  st.triangles_before = st.triangles_after = m.triangle_count();
  if (distance == 0 || m.triangle_count() == 0) {
    if (stats) *stats = st;
    return m;
  }
  const std::size_t V = m.vertex_count(), I = 3 * m.triangle_count();
  const float* positions = m.positions[0].data();
  // meshoptimizer measures errors relative to the mesh's extent.
  const float scale = meshopt_simplifyScale(positions, V, sizeof(m.positions[0]));
  std::vector<unsigned int> indices(I);
  float relative_error = 0;
  const std::size_t kept = meshopt_simplify(indices.data(), m.triangles[0].data(), I, positions, V, sizeof(m.positions[0]), 0,
                                            static_cast<float>(distance / scale), meshopt_SimplifyLockBorder, &relative_error);
  indices.resize(kept);
  // The kept vertices, unmoved, in first-use order.
  std::vector<unsigned int> remap(V);
  const std::size_t used = meshopt_optimizeVertexFetchRemap(remap.data(), indices.data(), kept, V);
  Mesh out;
  out.positions.resize(used);
  if (m.normals.size() == V) out.normals.resize(used);
  for (std::size_t v = 0; v < V; ++v) {
    if (remap[v] == ~0u) continue;
    out.positions[remap[v]] = m.positions[v];
    if (!out.normals.empty()) out.normals[remap[v]] = m.normals[v];
  }
  out.triangles.resize(kept / 3);
  for (std::size_t i = 0; i < kept; ++i) out.triangles[i / 3][i % 3] = remap[indices[i]];
  st.triangles_after = out.triangle_count();
  st.error = static_cast<double>(relative_error) * scale;
  st.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (stats) *stats = st;
  return out;
}

}  // namespace adaptiso
