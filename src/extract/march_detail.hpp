// Pieces of marching tetrahedra shared by the fresh march (marching_tetrahedra.cpp) and the
// Extractor's incremental step (extractor.cpp); not part of the public API.
#pragma once
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <span>
#include <vector>

#include "adaptiso/mesh.hpp"
#include "adaptiso/tet_grid.hpp"
#include "extract/edge_point.hpp"
#include "grid/grid_prefetch.hpp"
#include "util/big_array.hpp"
#include "util/prefetch.hpp"

namespace adaptiso::detail {

// A cut edge as local vertex indices: `below` (value < iso) and `above` (value >= iso).
struct LocalEdge {
  std::uint8_t below, above;
};
struct Case {
  std::uint8_t triangles = 0;
  LocalEdge tri[2][3];
};
extern const std::array<Case, 16> kCases;  // by code: bit k set = vertex k at or above the iso-value

using Quad = std::array<std::uint32_t, 4>;  // a tetrahedron's vertices

inline std::uint8_t tet_code(const TetGrid& grid, const Quad& q, double iso) {
  const double* v = grid.values.data();
  return static_cast<std::uint8_t>((v[q[0]] >= iso) | ((v[q[1]] >= iso) << 1) | ((v[q[2]] >= iso) << 2) | ((v[q[3]] >= iso) << 3));
}

// Keep (below, above) order in the key: for one iso-value a grid edge is always cut one way.
inline std::uint64_t edge_key(std::uint32_t below, std::uint32_t above) { return (std::uint64_t{below} << 32) | above; }

// The case of a tetrahedron stays the same for iso-values in (below, above]; rounded inwards: a
// value close to the ends only costs a needless re-march.
struct Gap {
  float below, above;
};

// Reusable buffers of a chunk-parallel march (so repeated extractions do not fault in fresh pages).
class EdgeMap;
struct MarchChunk {
  std::vector<std::uint64_t> slots, order, pending;
  std::vector<std::uint32_t> local, owner, owner_id, global;
  std::shared_ptr<EdgeMap> map;
  std::size_t owned = 0;
};
// Where the mesh vertex of a cut edge really lies: the distance query (distance_query.cpp) marches
// coarse tetrahedra but places each vertex on the grid's own cut edge inside the coarse one.
struct EdgeRemap {
  virtual ~EdgeRemap() = default;
  virtual std::uint64_t fine(std::uint64_t coarse_key) const = 0;  // edge keys (below << 32 | above)
};

struct MarchScratch {
  const EdgeRemap* remap = nullptr;  // set: vertices on the remapped edges (vertex_edges are those)
  std::vector<std::uint8_t> codes;
  std::vector<std::uint64_t> first_triangle, order;
  std::vector<MarchChunk> chunks;
  std::size_t parallel_min_tetrahedra = 65536;  // below this many tetrahedra (about as many triangles), one chunk
  // A cancel flag (Extractor::extract, HierarchyQuery::extract): the march's first, longest phase
  // stops at its next batch once it is raised, and the march throws ExtractCancelled before
  // anything reads its output; its later phases (numbering, triangles, vertices: over half of a
  // fresh march, whose arrays are first touched there) look again between and within them.
  const std::atomic<bool>* cancel = nullptr;
  bool cancelled() const { return cancel && cancel->load(std::memory_order_relaxed); }
};

// Open-addressing map from edge key to mesh vertex, numbering vertices by first use. A slot is
// the key and its id side by side (two words of `slots`), so a probe touches one cache line.
class EdgeMap {
public:
  EdgeMap(std::size_t expected, std::vector<std::uint64_t>& slots) : slots_(slots) {
    rehash(std::bit_ceil(std::max<std::size_t>(64, expected * 2)));
  }
  std::uint32_t find_or_add(std::uint64_t key, std::vector<std::uint64_t>& order) {
    if (order.size() * 10 >= cap_ * 7) grow(order);
    for (std::size_t h = hash(key);; h = (h + 1) & (cap_ - 1)) {
      std::uint64_t* slot = &slots_[2 * h];
      if (slot[0] == kEmpty) {
        slot[0] = key;
        slot[1] = order.size();
        order.push_back(key);
        return static_cast<std::uint32_t>(slot[1]);
      }
      if (slot[0] == key) return static_cast<std::uint32_t>(slot[1]);
    }
  }
  // Probes are scattered misses; callers that know their keys ahead prefetch their home slots.
  void prefetch(std::uint64_t key) const { __builtin_prefetch(&slots_[2 * hash(key)]); }
  // The id of key, or kNone.
  std::uint32_t find(std::uint64_t key) const {
    for (std::size_t h = hash(key);; h = (h + 1) & (cap_ - 1)) {
      const std::uint64_t* slot = &slots_[2 * h];
      if (slot[0] == kEmpty) return kNone;
      if (slot[0] == key) return static_cast<std::uint32_t>(slot[1]);
    }
  }
  static constexpr std::uint32_t kNone = ~std::uint32_t{0};

private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  std::size_t hash(std::uint64_t k) const { return static_cast<std::size_t>((k * 0x9E3779B97F4A7C15ull) >> shift_); }
  void rehash(std::size_t cap) {
    cap_ = cap;
    shift_ = 64 - std::countr_zero(cap);
    assign_big(slots_, 2 * cap, kEmpty);
  }
  void grow(const std::vector<std::uint64_t>& order) {
    rehash(cap_ * 2);
    for (std::uint32_t i = 0; i < order.size(); ++i) {
      std::size_t h = hash(order[i]);
      while (slots_[2 * h] != kEmpty) h = (h + 1) & (cap_ - 1);
      slots_[2 * h] = order[i];
      slots_[2 * h + 1] = i;
    }
  }
  std::size_t cap_ = 0;
  int shift_ = 0;
  std::vector<std::uint64_t>& slots_;
};

// Resizes v, whose contents are about to be overwritten. Incremental steps grow the Extractor's
// arrays a little at a time: a quarter of headroom, reserved before filling (address space only,
// no pages touched), spares the first step that grows them a copy of every array (about 0.1 s on
// a 2.7-million-vertex surface).
template <class Vec>
void resize_for_overwrite(Vec& v, std::size_t n) {
  if (n > v.capacity()) {
    v.clear();
    v.reserve(n + n / 4);
    populate(v.data(), (n + n / 4) * sizeof(v[0]));  // big_array.hpp: faulted in at once, on huge pages
  }
  v.resize(n);
}

// A cut edge's two ends, gathered once from the grid: values, world positions and world-frame
// gradients. Re-interpolating at another iso-value then streams through one record per vertex
// instead of reading six scattered grid arrays (the Extractor keeps these between steps).
struct EdgeEnds {
  double va, vb;                       // a below, b at or above the iso-value
  std::array<float, 3> wa, d, ga, gb;  // world position of a, b - a; gradients (world frame)
};                                     // 64 bytes: re-interpolation streams these, so every byte counts

// gather_edge's reads are scattered over the grid: callers prefetch them a few edges ahead.
inline void prefetch_edge(const TetGrid& grid, std::uint64_t key) {
  for (std::uint32_t v : {static_cast<std::uint32_t>(key >> 32), static_cast<std::uint32_t>(key)}) {
    __builtin_prefetch(&grid.values[v]);
    __builtin_prefetch(&grid.ijk[v]);
    __builtin_prefetch(&grid.gradients[v]);
  }
}

inline EdgeEnds gather_edge(const TetGrid& grid, std::uint64_t key) {
  const std::uint32_t a = static_cast<std::uint32_t>(key >> 32), b = static_cast<std::uint32_t>(key);
  const auto& D = grid.source.direction;
  auto rotate = [&](const std::array<float, 3>& v) {  // a direction: no origin
    const Vec3 m = grid_to_world({0, 0, 0}, D, {v[0], v[1], v[2]});
    return std::array<float, 3>{float(m[0]), float(m[1]), float(m[2])};
  };
  const Vec3 wa = grid.world_position(a), wb = grid.world_position(b);
  const std::array<float, 3> d{float(wb[0] - wa[0]), float(wb[1] - wa[1]), float(wb[2] - wa[2])};
  return {grid.values[a],           grid.values[b], {float(wa[0]), float(wa[1]), float(wa[2])}, d, rotate(grid.gradients[a]),
          rotate(grid.gradients[b])};
}

// The mesh vertex on a cut edge: linear interpolation of position and gradient (§2.4); the normal
// is the negated, normalised gradient (towards lower values), or the edge direction towards the
// lower end where the gradients cancel.
inline void interpolate_edge(const EdgeEnds& e, double iso, std::array<float, 3>& p, std::array<float, 3>& n) {
  const double t = std::clamp((iso - e.va) / (e.vb - e.va), kEdgeMargin, 1 - kEdgeMargin);
  double m[3];
  for (int k = 0; k < 3; ++k) {
    p[k] = static_cast<float>(double(e.wa[k]) + t * e.d[k]);
    m[k] = -((1 - t) * e.ga[k] + t * e.gb[k]);
  }
  double len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
  if (!(len > 0)) {
    for (int k = 0; k < 3; ++k) m[k] = -e.d[k];
    len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
  }
  const double inv = 1 / len;
  for (int k = 0; k < 3; ++k) n[k] = static_cast<float>(m[k] * inv);
}

// Positions and normals of the mesh vertices, one per cut edge key in `order` (parallel; left
// incomplete once `cancel` is raised, for the caller to throw). With `gathered`, each edge's ends
// are kept there too, for later steps (interpolate_vertices below).
void interpolate_vertices(const TetGrid& grid, const std::vector<std::uint64_t>& order, double iso, Mesh& mesh,
                          const std::atomic<bool>* cancel = nullptr, std::vector<EdgeEnds>* gathered = nullptr);
// The same from gathered edge ends (bit-identical results).
void interpolate_vertices(const std::vector<EdgeEnds>& ends, double iso, Mesh& mesh);

// The case of tetrahedron t at iso and the interval of iso-values with the same case: a vertex is
// above iff value >= iso, so the case holds while the largest value below iso stays below and the
// smallest value at or above iso stays at or above. Stored as floats rounded inwards (half the
// bytes to stream per step): the float interval lies inside the exact one.
inline std::uint8_t code_and_gap(const TetGrid& grid, const Quad& q, double iso, Gap& gap) {
  std::uint8_t code = 0;
  double below = -std::numeric_limits<double>::infinity(), above = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 4; ++k) {
    const double v = grid.values[q[k]];
    if (v >= iso) {
      code |= static_cast<std::uint8_t>(1 << k);
      above = std::min(above, v);
    } else {
      below = std::max(below, v);
    }
  }
  gap.below = static_cast<float>(below);
  if (gap.below < below) gap.below = std::nextafter(gap.below, std::numeric_limits<float>::infinity());
  gap.above = static_cast<float>(above);
  if (gap.above > above) gap.above = std::nextafter(gap.above, -std::numeric_limits<float>::infinity());
  return code;
}
inline std::uint8_t code_and_gap(const TetGrid& grid, std::uint32_t t, double iso, Gap& gap) {
  return code_and_gap(grid, grid.tets[t], iso, gap);
}

// Chunk-parallel first-use numbering: each chunk numbered its edges locally by first use (ch.map,
// ch.order); an edge belongs to the first chunk using it, and owned edges are numbered chunk by
// chunk, which is exactly the sequential first-use order whatever the number of chunks. Fills
// order (edge keys by global id) and ch.global (global id per local id).
void number_chunk_edges(std::vector<MarchChunk>& chunks, std::vector<std::uint64_t>& order);

// Sorts ids (tetrahedra, triangles or vertices, all below `bound`) ascending through a bitmap,
// dropping repeats (O(bound/64 + n), parallel): much cheaper than a comparison sort.
void sort_ids(std::vector<std::uint32_t>& ids, std::size_t bound, std::vector<std::uint64_t>& bitmap);

// The tetrahedra a march visits, in order: the grid's own by id, or ad hoc ones over the grid's
// vertices (a bisection grid's query at a coarser error, hierarchy_query.hpp).
struct GridTets {
  const TetGrid& grid;
  std::span<const std::uint32_t> ids;
  std::size_t size() const { return ids.size(); }
  const Quad& operator[](std::size_t i) const { return grid.tets[ids[i]]; }
  void prefetch(std::size_t i) const { prefetch_values(grid, ids[i]); }
};
struct QuadTets {
  const TetGrid& grid;
  std::span<const Quad> quads;
  std::size_t size() const { return quads.size(); }
  const Quad& operator[](std::size_t i) const { return quads[i]; }
  void prefetch(std::size_t i) const {
    for (std::uint32_t v : quads[i]) __builtin_prefetch(&grid.values[v]);
  }
};

// march_tetrahedra that also keeps, when asked, each active tetrahedron's case interval and each
// vertex's edge ends (what the Extractor's incremental steps need), without reading them twice.
template <class Tets>
void march_into(const TetGrid& grid, const Tets& tets, double iso, Mesh& mesh, MarchScratch& sc, std::vector<Gap>* gaps,
                std::vector<EdgeEnds>* ends);
inline void march_tetrahedra_into(const TetGrid& grid, std::span<const std::uint32_t> active, double iso, Mesh& mesh, MarchScratch& sc,
                                  std::vector<Gap>* gaps, std::vector<EdgeEnds>* ends) {
  march_into(grid, GridTets{grid, active}, iso, mesh, sc, gaps, ends);
}

}  // namespace adaptiso::detail
