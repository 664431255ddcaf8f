// Marching tetrahedra (Lürig & Ertl §2.4) with shared vertices per cut edge; see
// marching_tetrahedra.hpp. The chunk-parallel march here is also the Extractor's fresh march.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.4.
// - Doi, Koide. An efficient method of triangulating equi-valued surfaces by using tetrahedral
//   cells. IEICE Transactions, 1991.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>

#include "adaptiso/extractor.hpp"
#include "adaptiso/marching_tetrahedra.hpp"
#include "extract/box_clip.hpp"
#include "extract/march_detail.hpp"

namespace adaptiso::detail {
namespace {

// The 16 cases (bit k set = vertex k above), oriented on the reference tetrahedron
// (0,0,0),(1,0,0),(0,1,0),(0,0,1), which is positively oriented like every grid tetrahedron, so the
// orientation carries over to any of them by an affine map of positive determinant.
std::array<Case, 16> make_cases() {
  const double P[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  std::array<Case, 16> cases{};
  for (int code = 1; code < 15; ++code) {
    std::vector<int> A, B;
    for (int k = 0; k < 4; ++k) ((code >> k) & 1 ? A : B).push_back(k);
    std::vector<std::vector<LocalEdge>> tris;
    if (A.size() == 1 || B.size() == 1) {
      std::vector<LocalEdge> t;
      if (A.size() == 1)
        for (int b : B) t.push_back({std::uint8_t(b), std::uint8_t(A[0])});
      else
        for (int a : A) t.push_back({std::uint8_t(B[0]), std::uint8_t(a)});
      tris.push_back(t);
    } else {  // a quad around the cycle a1b1, a1b2, a2b2, a2b1, split along one diagonal
      LocalEdge q[4] = {{std::uint8_t(B[0]), std::uint8_t(A[0])},
                        {std::uint8_t(B[0]), std::uint8_t(A[1])},
                        {std::uint8_t(B[1]), std::uint8_t(A[1])},
                        {std::uint8_t(B[1]), std::uint8_t(A[0])}};
      tris.push_back({q[0], q[1], q[2]});
      tris.push_back({q[0], q[2], q[3]});
    }
    double cb[3] = {0, 0, 0}, ca[3] = {0, 0, 0};
    for (int b : B)
      for (int k = 0; k < 3; ++k) cb[k] += P[b][k] / B.size();
    for (int a : A)
      for (int k = 0; k < 3; ++k) ca[k] += P[a][k] / A.size();
    Case c;
    c.triangles = static_cast<std::uint8_t>(tris.size());
    for (std::size_t t = 0; t < tris.size(); ++t) {
      double m[3][3];
      for (int i = 0; i < 3; ++i)
        for (int k = 0; k < 3; ++k) m[i][k] = 0.5 * (P[tris[t][i].below][k] + P[tris[t][i].above][k]);
      double u[3], v[3];
      for (int k = 0; k < 3; ++k) u[k] = m[1][k] - m[0][k], v[k] = m[2][k] - m[0][k];
      double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
      double d = n[0] * (cb[0] - ca[0]) + n[1] * (cb[1] - ca[1]) + n[2] * (cb[2] - ca[2]);
      if (d < 0) std::swap(tris[t][1], tris[t][2]);  // face the lower values
      for (int i = 0; i < 3; ++i) c.tri[t][i] = tris[t][i];
    }
    cases[code] = c;
  }
  return cases;
}

}  // namespace

const std::array<Case, 16> kCases = make_cases();

void interpolate_vertices(const TetGrid& grid, const std::vector<std::uint64_t>& order, double iso, Mesh& mesh,
                          const std::atomic<bool>* cancel, std::vector<EdgeEnds>* gathered) {
  const std::size_t V = order.size();
  resize_for_overwrite(mesh.positions, V);
  resize_for_overwrite(mesh.normals, V);
  if (gathered) resize_for_overwrite(*gathered, V);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, V, 4096), [&](const auto& r) {
    if (cancel && cancel->load(std::memory_order_relaxed)) return;  // the caller throws
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      if (i + 8 < r.end()) prefetch_edge(grid, order[i + 8]);
      const EdgeEnds e = gather_edge(grid, order[i]);
      if (gathered) (*gathered)[i] = e;
      interpolate_edge(e, iso, mesh.positions[i], mesh.normals[i]);
    }
  });
}

void interpolate_vertices(const std::vector<EdgeEnds>& ends, double iso, Mesh& mesh) {
  const std::size_t V = ends.size();
  resize_for_overwrite(mesh.positions, V);
  resize_for_overwrite(mesh.normals, V);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, V, 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) interpolate_edge(ends[i], iso, mesh.positions[i], mesh.normals[i]);
  });
}

void number_chunk_edges(std::vector<MarchChunk>& chunks, std::vector<std::uint64_t>& order) {
  const std::size_t C = chunks.size();
  // Ownership: is the edge in an earlier chunk? The last chunk asks the most maps, so the lookups
  // are split within each chunk too.
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = chunks[c];
    ch.owner.assign(ch.order.size(), static_cast<std::uint32_t>(c));
    ch.owner_id.resize(ch.order.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, ch.order.size(), 4096), [&](const auto& r) {
      for (std::size_t j = r.begin(); j < r.end(); ++j) {
        if (j + 16 < r.end())
          for (std::size_t q = 0; q < c; ++q) chunks[q].map->prefetch(ch.order[j + 16]);
        ch.owner_id[j] = static_cast<std::uint32_t>(j);
        for (std::size_t q = 0; q < c; ++q)
          if (std::uint32_t id = chunks[q].map->find(ch.order[j]); id != EdgeMap::kNone) {
            ch.owner[j] = static_cast<std::uint32_t>(q);
            ch.owner_id[j] = id;
            break;
          }
      }
    });
    ch.owned = static_cast<std::size_t>(std::count(ch.owner.begin(), ch.owner.end(), static_cast<std::uint32_t>(c)));
  });
  std::vector<std::size_t> offset(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) offset[c + 1] = offset[c] + chunks[c].owned;
  resize_for_overwrite(order, offset[C]);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {  // global ids of owned edges
    auto& ch = chunks[c];
    ch.global.resize(ch.order.size());
    std::size_t next = offset[c];
    for (std::size_t j = 0; j < ch.order.size(); ++j)
      if (ch.owner[j] == c) {
        order[next] = ch.order[j];
        ch.global[j] = static_cast<std::uint32_t>(next++);
      }
  });
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {  // borrowed edges
    auto& ch = chunks[c];
    for (std::size_t j = 0; j < ch.order.size(); ++j)
      if (ch.owner[j] != c) ch.global[j] = chunks[ch.owner[j]].global[ch.owner_id[j]];
  });
}

template <class Tets>
void march_into(const TetGrid& grid, const Tets& tets, double iso, Mesh& mesh, MarchScratch& sc, std::vector<Gap>* gaps,
                std::vector<EdgeEnds>* ends) {
  const std::size_t n = tets.size();
  auto& codes = sc.codes;
  auto& first_tri = sc.first_triangle;
  resize_for_overwrite(codes, n);
  first_tri.resize(n + 1);
  if (gaps) resize_for_overwrite(*gaps, n);
  // 1. Chunks of consecutive tetrahedra (in parallel) find their cases and corners and number the
  // edges locally by first use; an edge belongs to the first chunk that uses it, and owned edges
  // are numbered chunk by chunk in local first-use order: exactly the sequential first-use
  // numbering, whatever the number of chunks. Tetrahedra are taken in batches: the batch's corner
  // keys go to a small buffer first, so the map probes (scattered misses once the map outgrows the
  // caches) can be prefetched ahead without a corner array for the whole surface.
  const std::size_t C = n < sc.parallel_min_tetrahedra ? 1 : static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  sc.chunks.resize(C);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = sc.chunks[c];
    const std::size_t b = n * c / C, e = n * (c + 1) / C;
    ch.order.clear();
    ch.local.clear();  // 3 local vertex ids per triangle
    ch.map = std::make_shared<EdgeMap>((e - b) * 3 / 4 + 16, ch.slots);
    constexpr std::size_t kBatch = 256;
    auto& keys = ch.pending;
    for (std::size_t i0 = b; i0 < e; i0 += kBatch) {
      if (sc.cancelled()) return;
      const std::size_t i1 = std::min(e, i0 + kBatch);
      keys.clear();
      for (std::size_t i = i0; i < i1; ++i) {
        if (i + 8 < e) tets.prefetch(i + 8);
        const Quad& t = tets[i];
        codes[i] = gaps ? code_and_gap(grid, t, iso, (*gaps)[i]) : tet_code(grid, t, iso);
        const Case& cs = kCases[codes[i]];
        for (int q = 0; q < cs.triangles; ++q)
          for (int k = 0; k < 3; ++k) keys.push_back(edge_key(t[cs.tri[q][k].below], t[cs.tri[q][k].above]));
      }
      const std::size_t m = keys.size();
      for (std::size_t j = 0; j < std::min<std::size_t>(16, m); ++j) ch.map->prefetch(keys[j]);
      for (std::size_t j = 0; j < m; ++j) {
        if (j + 16 < m) ch.map->prefetch(keys[j + 16]);
        ch.local.push_back(ch.map->find_or_add(keys[j], ch.order));
      }
    }
  });
  if (sc.cancelled()) throw ExtractCancelled();  // the chunks may be incomplete
  auto& order = sc.order;
  number_chunk_edges(sc.chunks, order);
  if (sc.cancelled()) throw ExtractCancelled();
  // 2. Triangles in the order of the tetrahedra, with their global vertex ids (in parallel).
  std::vector<std::size_t> tri_at(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) tri_at[c + 1] = tri_at[c] + sc.chunks[c].local.size() / 3;
  const std::size_t T = tri_at[C];
  resize_for_overwrite(mesh.triangles, T);
  first_tri[n] = T;
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    const auto& ch = sc.chunks[c];
    std::uint64_t f = tri_at[c];
    for (std::size_t i = n * c / C; i < n * (c + 1) / C; ++i) {
      first_tri[i] = f;
      f += kCases[codes[i]].triangles;
    }
    for (std::size_t j = 0; j < ch.local.size() / 3; ++j)
      for (int k = 0; k < 3; ++k) mesh.triangles[tri_at[c] + j][k] = ch.global[ch.local[3 * j + k]];
  });
  if (sc.cancelled()) throw ExtractCancelled();
  if (sc.remap)
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, order.size(), 1024), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) order[i] = sc.remap->fine(order[i]);
    });
  interpolate_vertices(grid, order, iso, mesh, sc.cancel, ends);
  if (sc.cancelled()) throw ExtractCancelled();
}

template void march_into(const TetGrid&, const GridTets&, double, Mesh&, MarchScratch&, std::vector<Gap>*, std::vector<EdgeEnds>*);
template void march_into(const TetGrid&, const QuadTets&, double, Mesh&, MarchScratch&, std::vector<Gap>*, std::vector<EdgeEnds>*);

void sort_ids(std::vector<std::uint32_t>& ids, std::size_t bound, std::vector<std::uint64_t>& bitmap) {
  const std::size_t words = (bound + 63) / 64;
  bitmap.assign(words, 0);
  for (std::uint32_t t : ids) bitmap[t >> 6] |= std::uint64_t{1} << (t & 63);
  const std::size_t chunks = std::max<std::size_t>(1, std::min<std::size_t>(64, words / 4096));
  std::vector<std::size_t> start(chunks + 1, 0);
  tbb::parallel_for(std::size_t{0}, chunks, [&](std::size_t c) {
    std::size_t cnt = 0;
    for (std::size_t w = words * c / chunks; w < words * (c + 1) / chunks; ++w) cnt += std::popcount(bitmap[w]);
    start[c + 1] = cnt;
  });
  for (std::size_t c = 0; c < chunks; ++c) start[c + 1] += start[c];
  ids.resize(start[chunks]);  // repeated ids counted once
  tbb::parallel_for(std::size_t{0}, chunks, [&](std::size_t c) {
    std::uint32_t* out = ids.data() + start[c];
    for (std::size_t w = words * c / chunks; w < words * (c + 1) / chunks; ++w)
      for (std::uint64_t b = bitmap[w]; b; b &= b - 1) *out++ = static_cast<std::uint32_t>(w * 64 + std::countr_zero(b));
  });
}

}  // namespace adaptiso::detail

namespace adaptiso {

Mesh march_tetrahedra(const TetGrid& grid, std::span<const std::uint32_t> active, double iso, const MarchOptions& options,
                      std::vector<std::uint64_t>* vertex_edges) {
  detail::MarchScratch scratch;
  scratch.parallel_min_tetrahedra = options.parallel_min_tetrahedra;
  scratch.cancel = options.cancel;  // the march throws ExtractCancelled itself
  Mesh mesh;
  detail::march_tetrahedra_into(grid, active, iso, mesh, scratch, nullptr, nullptr);
  Mesh clipped;
  detail::ClipMap map;
  if (!detail::clip_to_volume_box(mesh, grid.source, clipped, &map)) {
    if (vertex_edges) *vertex_edges = std::move(scratch.order);
    return mesh;
  }
  if (vertex_edges) detail::carry_vertex_keys(map, scratch.order, kClippedVertex, *vertex_edges);
  return clipped;
}

}  // namespace adaptiso
