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
//
// Checked (simplify.hpp): each part's result is measured against the part by point-to-triangle
// distances (CGAL AABB trees, as surface_distance.cpp measures); a part that fails is cut in two
// and each half simplified again. The check and the cuts depend on the part alone, so the output
// still does not depend on the thread count.
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
#include "mesh/triangle_tree.hpp"

namespace adaptiso {
namespace {

// Reorders ids[begin, end) around their median by centroid (`centroid(id, axis)`: the sum of a
// triangle's corners) along the longest side of their centroids' box, and returns the median's
// place. Ties broken by the id, so the split is the same however nth_element proceeds.
template <class Centroid>
std::size_t median_split(std::vector<std::uint32_t>& ids, std::size_t begin, std::size_t end, const Centroid& centroid) {
  float lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = centroid(ids[begin], a);
  for (std::size_t i = begin; i < end; ++i)
    for (int a = 0; a < 3; ++a) {
      const float c = centroid(ids[i], a);
      lo[a] = std::min(lo[a], c), hi[a] = std::max(hi[a], c);
    }
  int axis = 0;
  for (int a = 1; a < 3; ++a)
    if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
  const std::size_t mid = begin + (end - begin) / 2;
  std::nth_element(ids.begin() + static_cast<std::ptrdiff_t>(begin), ids.begin() + static_cast<std::ptrdiff_t>(mid),
                   ids.begin() + static_cast<std::ptrdiff_t>(end), [&](std::uint32_t a, std::uint32_t b) {
                     const float ca = centroid(a, axis), cb = centroid(b, axis);
                     return ca < cb || (ca == cb && a < b);
                   });
  return mid;
}

// Triangle indices, split recursively at the median centroid along the longest side of their
// bounding box, until every part holds at most `most` triangles; parts in a fixed order.
void split_chunks(const Mesh& m, std::vector<std::uint32_t>& tris, std::size_t begin, std::size_t end, std::size_t most,
                  std::vector<std::pair<std::size_t, std::size_t>>& parts) {
  if (end - begin <= most) {
    parts.emplace_back(begin, end);
    return;
  }
  const std::size_t mid = median_split(tris, begin, end, [&](std::uint32_t t, int a) {
    const auto& tri = m.triangles[t];
    return m.positions[tri[0]][a] + m.positions[tri[1]][a] + m.positions[tri[2]][a];
  });
  split_chunks(m, tris, begin, mid, most, parts);
  split_chunks(m, tris, mid, end, most, parts);
}

struct ChunkResult {
  std::vector<std::uint32_t> indices;  // kept triangles, global vertex numbers
  float relative_error = 0, scale = 0;
  std::size_t retried = 0, kept = 0;  // checked: parts cut in two and simplified again; left as they were
};

// A tree over triangles given by global vertex numbers (degenerate ones left out).
struct PartTree {
  std::vector<detail::TreeTriangle> triangles;
  detail::TriangleTree tree;
  PartTree(const Mesh& m, const std::vector<std::uint32_t>& indices) {
    triangles.reserve(indices.size() / 3);
    for (std::size_t t = 0; t < indices.size(); t += 3) {
      detail::TreeTriangle tri(detail::tree_point(m.positions[indices[t]]), detail::tree_point(m.positions[indices[t + 1]]),
                               detail::tree_point(m.positions[indices[t + 2]]));
      if (!tri.is_degenerate()) triangles.push_back(tri);
    }
    if (triangles.empty()) return;  // within() is false for every point
    tree.insert(triangles.begin(), triangles.end());
    tree.accelerate_distance_queries();
  }
  bool within(const detail::TreeKernel::Point_3& p, double limit2) const {
    return !triangles.empty() && tree.squared_distance(p) <= limit2;
  }
};

// The vertices of `in` (sorted, unique) whose connected piece `out` dropped whole and that spans
// at most `limit` (its bounding box's diagonal): a noise speck smaller than the distance may go,
// as the distance query leaves out surfaces smaller than the distance that hide in a cell.
std::vector<bool> small_dropped_pieces(const Mesh& m, const std::vector<std::uint32_t>& in, const std::vector<std::uint32_t>& vertices,
                                       const std::vector<std::uint32_t>& kept, double limit) {
  auto local = [&](std::uint32_t v) {
    return static_cast<std::size_t>(std::lower_bound(vertices.begin(), vertices.end(), v) - vertices.begin());
  };
  std::vector<std::size_t> parent(vertices.size());
  std::iota(parent.begin(), parent.end(), std::size_t{0});
  auto find = [&](std::size_t v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  for (std::size_t t = 0; t < in.size(); t += 3)
    for (int k = 1; k < 3; ++k) parent[find(local(in[t + static_cast<std::size_t>(k)]))] = find(local(in[t]));
  struct Piece {
    float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f};
    bool kept = false;
  };
  std::vector<Piece> pieces(vertices.size());
  for (std::size_t v = 0; v < vertices.size(); ++v) {
    Piece& p = pieces[find(v)];
    p.kept |= std::binary_search(kept.begin(), kept.end(), vertices[v]);
    for (std::size_t a = 0; a < 3; ++a)
      p.lo[a] = std::min(p.lo[a], m.positions[vertices[v]][a]), p.hi[a] = std::max(p.hi[a], m.positions[vertices[v]][a]);
  }
  std::vector<bool> may_go(vertices.size());
  for (std::size_t v = 0; v < vertices.size(); ++v) {
    const Piece& p = pieces[find(v)];
    double d2 = 0;
    for (int a = 0; a < 3; ++a) d2 += double(p.hi[a] - p.lo[a]) * double(p.hi[a] - p.lo[a]);
    may_go[v] = !p.kept && d2 <= limit * limit;
  }
  return may_go;
}

// Does the simplified part `out` stay within `limit` of the part `in`, both ways, at in's
// vertices (but those of small pieces dropped whole) and out's triangle centres?
bool within_limit(const Mesh& m, const std::vector<std::uint32_t>& in, const std::vector<std::uint32_t>& out, double limit) {
  std::vector<std::uint32_t> vertices(in), kept(out);  // in's vertices that out keeps are at distance 0
  std::sort(vertices.begin(), vertices.end());
  vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());
  std::sort(kept.begin(), kept.end());
  const std::vector<bool> may_go = small_dropped_pieces(m, in, vertices, kept, limit);
  const double limit2 = limit * limit;
  const PartTree to_out(m, out);
  for (std::size_t v = 0; v < vertices.size(); ++v)
    if (!may_go[v] && !std::binary_search(kept.begin(), kept.end(), vertices[v]) &&
        !to_out.within(detail::tree_point(m.positions[vertices[v]]), limit2))
      return false;
  const PartTree to_in(m, in);
  for (std::size_t t = 0; t < out.size(); t += 3) {
    double c[3] = {0, 0, 0};
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) c[a] += m.positions[out[t + static_cast<std::size_t>(k)]][static_cast<std::size_t>(a)] / 3.0;
    if (!to_in.within({c[0], c[1], c[2]}, limit2)) return false;
  }
  return true;
}

// Triangles given by global vertex numbers (3 per triangle), simplified in their own vertex
// numbering with their border locked.
ChunkResult simplify_raw(const Mesh& m, std::vector<std::uint32_t> in, double distance) {
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

// Triangles (3 global vertex numbers each) cut in two as split_chunks cuts, each half in list order:
// the same for any thread count.
std::pair<std::vector<std::uint32_t>, std::vector<std::uint32_t>> halves(const Mesh& m, const std::vector<std::uint32_t>& in) {
  std::vector<std::uint32_t> order(in.size() / 3);
  std::iota(order.begin(), order.end(), 0u);
  const auto mid = order.begin() + static_cast<std::ptrdiff_t>(median_split(order, 0, order.size(), [&](std::uint32_t t, int a) {
                     return m.positions[in[3 * t]][a] + m.positions[in[3 * t + 1]][a] + m.positions[in[3 * t + 2]][a];
                   }));
  std::sort(order.begin(), mid), std::sort(mid, order.end());
  std::pair<std::vector<std::uint32_t>, std::vector<std::uint32_t>> r;
  for (auto it = order.begin(); it != order.end(); ++it)
    (it < mid ? r.first : r.second).insert((it < mid ? r.first : r.second).end(), in.begin() + 3 * *it, in.begin() + 3 * *it + 3);
  return r;
}

// A failing part smaller than this is kept as it was (a few voxels of surface).
constexpr std::size_t kSmallestCheckedPart = 256;
// Checked, meshoptimizer aims below the distance checked: its quadric error averages over a
// vertex's planes, so it overshoots. Measured (CT bunny and chest, 0.5 voxels, extract --distance
// 0.5 then the checked simplification): 0.7 left 56 k and 472 k triangles, 1.0 left 97 k and
// 592 k (more parts failed and were cut), 0.5 left 67 k and 440 k.
constexpr double kCheckedTarget = 0.7;

// One part simplified to `distance`; checked, a part that fails is cut in two and each half
// simplified on its own (the cut locked like a border), down to kSmallestCheckedPart triangles,
// which are kept as they were: what meshoptimizer gets wrong costs a small region, not the part.
ChunkResult simplify_part(const Mesh& m, const std::vector<std::uint32_t>& in, double distance, bool checked) {
  ChunkResult r = simplify_raw(m, in, checked ? kCheckedTarget * distance : distance);
  if (!checked || within_limit(m, in, r.indices, distance)) return r;
  if (in.size() / 3 <= kSmallestCheckedPart) {
    r.indices = in;
    r.relative_error = 0, r.retried = 0, r.kept = 1;
    return r;
  }
  const auto [a, b] = halves(m, in);
  ChunkResult ra = simplify_part(m, a, distance, true), rb = simplify_part(m, b, distance, true);
  ra.indices.insert(ra.indices.end(), rb.indices.begin(), rb.indices.end());
  ra.relative_error = std::max(ra.relative_error * ra.scale, rb.relative_error * rb.scale), ra.scale = 1;
  ra.retried += rb.retried + 1, ra.kept += rb.kept;
  return ra;
}

// The second pass: the triangles touching a vertex that two chunks share (the cuts, locked in the
// first pass) simplified together, the rest kept as it is.
std::vector<std::uint32_t> simplify_seams(const Mesh& m, const std::vector<std::uint32_t>& tris,
                                          const std::vector<std::pair<std::size_t, std::size_t>>& parts, std::vector<std::uint32_t> indices,
                                          double distance, bool checked, SimplifyStats& st) {
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
  // the band gets half of the first pass's distance.
  const ChunkResult r = simplify_part(m, band, 0.5 * distance, checked);
  st.error += static_cast<double>(r.relative_error) * r.scale;
  st.chunks_retried += r.retried, st.chunks_kept += r.kept;
  rest.insert(rest.end(), r.indices.begin(), r.indices.end());
  return rest;
}

}  // namespace

Mesh simplify_mesh(const Mesh& m, double distance, SimplifyStats* stats, const SimplifyOptions& options) {
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
  const std::size_t most = options.checked ? std::min(options.chunk_triangles, kCheckedChunkTriangles) : options.chunk_triangles;
  split_chunks(m, tris, 0, tris.size(), std::max<std::size_t>(most, 1), parts);
  // Checked, the two passes' distances add up to the one asked for: 2/3 here, 1/3 in the band.
  const double first = options.checked && parts.size() > 1 ? distance * 2 / 3 : distance;
  auto corners = [&](std::size_t begin, std::size_t end) {
    std::vector<std::uint32_t> in;
    in.reserve(3 * (end - begin));
    for (std::size_t i = begin; i < end; ++i) in.insert(in.end(), m.triangles[tris[i]].begin(), m.triangles[tris[i]].end());
    return in;
  };
  std::vector<ChunkResult> done(parts.size());
  tbb::parallel_for(std::size_t{0}, parts.size(),
                    [&](std::size_t c) { done[c] = simplify_part(m, corners(parts[c].first, parts[c].second), first, options.checked); });
  std::vector<std::uint32_t> indices;
  for (const auto& c : done) {
    indices.insert(indices.end(), c.indices.begin(), c.indices.end());
    st.error = std::max(st.error, static_cast<double>(c.relative_error) * c.scale);
    st.chunks_retried += c.retried, st.chunks_kept += c.kept;
  }
  st.chunks = parts.size();
  if (parts.size() > 1) indices = simplify_seams(m, tris, parts, std::move(indices), first, options.checked, st);
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
