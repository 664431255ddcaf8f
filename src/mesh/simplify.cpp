// Mesh simplification to a distance (see simplify.hpp), with meshoptimizer's simplifier.
//
// This work is based on:
// - Garland, Heckbert. Surface simplification using quadric error metrics. SIGGRAPH 1997 (the
//   error metric of meshoptimizer's simplifier, used here).
//
// meshoptimizer's simplifier runs on one thread and its time grows with the mesh, so a large mesh
// is cut into spatial chunks (a k-d split of the triangles' centroids at the median of the longest
// side, until a chunk holds at most `chunk_triangles`), and the chunks are simplified in parallel.
// A chunk's cut edges are borders to meshoptimizer, and borders are locked, so the chunks still
// fit together exactly and a closed surface stays closed. The vertices along the cuts stay in that
// pass (16 chunks of the bunny at 0.5 voxels left 1.8× the triangles of one pass), so a second,
// serial pass simplifies the seam band: the triangles that touch a cut vertex, with the band's own
// border locked. The cuts depend on the mesh alone, never on the thread count, so the output is
// the same for any number of threads.
#include "adaptiso/simplify.hpp"

#include <fmt/format.h>
#include <meshoptimizer.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <vector>

#include "adaptiso/error.hpp"

namespace adaptiso {
namespace {

// Triangle indices, split recursively at the median centroid along the longest side of their
// bounding box, until every part holds at most `most` triangles; parts in a fixed order.
void split_chunks(const Mesh& m, std::vector<std::uint32_t>& tris, std::size_t begin, std::size_t end, std::size_t most,
                  std::vector<std::pair<std::size_t, std::size_t>>& parts) {
  if (end - begin <= most) {
    parts.emplace_back(begin, end);
    return;
  }
  auto centroid = [&](std::uint32_t t, int a) {
    const auto& tri = m.triangles[t];
    return m.positions[tri[0]][a] + m.positions[tri[1]][a] + m.positions[tri[2]][a];
  };
  float lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = centroid(tris[begin], a);
  for (std::size_t i = begin; i < end; ++i)
    for (int a = 0; a < 3; ++a) {
      const float c = centroid(tris[i], a);
      lo[a] = std::min(lo[a], c), hi[a] = std::max(hi[a], c);
    }
  int axis = 0;
  for (int a = 1; a < 3; ++a)
    if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
  const std::size_t mid = begin + (end - begin) / 2;
  // Ties broken by the triangle index, so the split is the same however nth_element proceeds.
  std::nth_element(tris.begin() + static_cast<std::ptrdiff_t>(begin), tris.begin() + static_cast<std::ptrdiff_t>(mid),
                   tris.begin() + static_cast<std::ptrdiff_t>(end), [&](std::uint32_t a, std::uint32_t b) {
                     const float ca = centroid(a, axis), cb = centroid(b, axis);
                     return ca < cb || (ca == cb && a < b);
                   });
  split_chunks(m, tris, begin, mid, most, parts);
  split_chunks(m, tris, mid, end, most, parts);
}

struct ChunkResult {
  std::vector<std::uint32_t> indices;  // kept triangles, global vertex numbers
  float relative_error = 0, scale = 0;
};

// Triangles given by global vertex numbers (3 per triangle), simplified in their own vertex
// numbering with their border locked.
ChunkResult simplify_part(const Mesh& m, std::vector<std::uint32_t> in, double distance) {
  std::vector<std::uint32_t> global(in);  // local → global vertex
  std::sort(global.begin(), global.end());
  global.erase(std::unique(global.begin(), global.end()), global.end());
  for (auto& v : in) v = static_cast<std::uint32_t>(std::lower_bound(global.begin(), global.end(), v) - global.begin());
  std::vector<std::array<float, 3>> positions(global.size());
  for (std::size_t i = 0; i < global.size(); ++i) positions[i] = m.positions[global[i]];
  std::vector<std::uint32_t> out(in.size());
  ChunkResult r;
  // meshoptimizer measures errors relative to the mesh's extent.
  r.scale = meshopt_simplifyScale(positions[0].data(), positions.size(), sizeof(positions[0]));
  const std::size_t kept = meshopt_simplify(out.data(), in.data(), in.size(), positions[0].data(), positions.size(), sizeof(positions[0]),
                                            0, static_cast<float>(distance / r.scale), meshopt_SimplifyLockBorder, &r.relative_error);
  out.resize(kept);
  for (auto& v : out) v = global[v];
  r.indices = std::move(out);
  return r;
}

// The second pass: the triangles touching a vertex that two chunks share (the cuts, locked in the
// first pass) simplified together, the rest kept as it is.
std::vector<std::uint32_t> simplify_seams(const Mesh& m, const std::vector<std::uint32_t>& tris,
                                          const std::vector<std::pair<std::size_t, std::size_t>>& parts, std::vector<std::uint32_t> indices,
                                          double distance, double& error) {
  constexpr std::uint32_t kNone = ~0u, kShared = ~0u - 1;
  std::vector<std::uint32_t> owner(m.vertex_count(), kNone);
  for (std::size_t c = 0; c < parts.size(); ++c)
    for (std::size_t i = parts[c].first; i < parts[c].second; ++i)
      for (std::uint32_t v : m.triangles[tris[i]]) owner[v] = owner[v] == kNone || owner[v] == c ? static_cast<std::uint32_t>(c) : kShared;
  std::vector<std::uint32_t> band, rest;
  for (std::size_t t = 0; t < indices.size(); t += 3) {
    const bool seam = owner[indices[t]] == kShared || owner[indices[t + 1]] == kShared || owner[indices[t + 2]] == kShared;
    (seam ? band : rest)
        .insert((seam ? band : rest).end(), indices.begin() + static_cast<std::ptrdiff_t>(t),
                indices.begin() + static_cast<std::ptrdiff_t>(t + 3));
  }
  if (band.empty()) return indices;
  // The band's triangles went through the first pass already, and the two passes' errors add up:
  // half the distance here keeps the band's estimate within 1.5 times the distance.
  const ChunkResult r = simplify_part(m, std::move(band), 0.5 * distance);
  error += static_cast<double>(r.relative_error) * r.scale;
  rest.insert(rest.end(), r.indices.begin(), r.indices.end());
  return rest;
}

}  // namespace

Mesh simplify_mesh(const Mesh& m, double distance, SimplifyStats* stats, std::size_t chunk_triangles) {
  if (!(distance >= 0) || !std::isfinite(distance))
    throw OptionError("simplify", fmt::format("must be a non-negative distance, got {}", distance));
  const auto t0 = std::chrono::steady_clock::now();
  SimplifyStats st;
  st.triangles_before = st.triangles_after = m.triangle_count();
  if (distance == 0 || m.triangle_count() == 0) {
    if (stats) *stats = st;
    return m;
  }
  const std::size_t V = m.vertex_count();
  std::vector<std::uint32_t> tris(m.triangle_count());
  std::iota(tris.begin(), tris.end(), 0u);
  std::vector<std::pair<std::size_t, std::size_t>> parts;
  split_chunks(m, tris, 0, tris.size(), std::max<std::size_t>(chunk_triangles, 1), parts);
  auto corners = [&](std::size_t begin, std::size_t end) {
    std::vector<std::uint32_t> in;
    in.reserve(3 * (end - begin));
    for (std::size_t i = begin; i < end; ++i) in.insert(in.end(), m.triangles[tris[i]].begin(), m.triangles[tris[i]].end());
    return in;
  };
  std::vector<ChunkResult> done(parts.size());
  tbb::parallel_for(std::size_t{0}, parts.size(),
                    [&](std::size_t c) { done[c] = simplify_part(m, corners(parts[c].first, parts[c].second), distance); });
  std::vector<std::uint32_t> indices;
  for (const auto& c : done) {
    indices.insert(indices.end(), c.indices.begin(), c.indices.end());
    st.error = std::max(st.error, static_cast<double>(c.relative_error) * c.scale);
  }
  st.chunks = parts.size();
  if (parts.size() > 1) indices = simplify_seams(m, tris, parts, std::move(indices), distance, st.error);
  // The kept vertices, unmoved, in first-use order.
  std::vector<unsigned int> remap(V);
  const std::size_t used = meshopt_optimizeVertexFetchRemap(remap.data(), indices.data(), indices.size(), V);
  Mesh out;
  out.positions.resize(used);
  if (m.normals.size() == V) out.normals.resize(used);
  for (std::size_t v = 0; v < V; ++v) {
    if (remap[v] == ~0u) continue;
    out.positions[remap[v]] = m.positions[v];
    if (!out.normals.empty()) out.normals[remap[v]] = m.normals[v];
  }
  out.triangles.resize(indices.size() / 3);
  for (std::size_t i = 0; i < indices.size(); ++i) out.triangles[i / 3][i % 3] = remap[indices[i]];
  st.triangles_after = out.triangle_count();
  st.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (stats) *stats = st;
  return out;
}

}  // namespace adaptiso
