// The Extractor: sweeping simplices plus marching tetrahedra with an incremental update of the
// mesh for small changes of iso-value (see extract.hpp).
//
// After a step from c0 to c1 a tetrahedron keeps its triangles, and every corner keeps its cut
// edge, unless one of its vertices lies in [min(c0,c1), max(c0,c1)): its case code changes. The
// active list is the previous one merged with the entries the sweep walked (those that entered or
// left), and each active tetrahedron carries the interval of iso-values that keep its case, so
// finding the ones to march again is one streaming pass. An edge they cut that was already cut
// is found among the same tetrahedron's old corners (a tetrahedron inactive before had no cut
// edge), so only edges cut for the first time need a hash map. Vertices carry reference counts:
// those no triangle uses any more free their slots, new ones fill them, and vertices from the end
// fill what is left, so the unchanged triangles are copied with at most a small tail remap.
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <limits>
#include <stdexcept>

#include "adaptiso/extract.hpp"
#include "extract/march_internal.hpp"

namespace adaptiso {
namespace {
constexpr std::uint32_t kNone = ~std::uint32_t{0};
constexpr std::uint32_t kNewBit = std::uint32_t{1} << 31;  // marks a chunk-local id of a first-cut edge

// Work split into this many blocks for the streaming passes (a multiple of the thread count keeps
// the cores busy; few enough that per-block bookkeeping stays negligible).
std::size_t block_count(std::size_t n) { return std::max<std::size_t>(1, std::min<std::size_t>(256, n / 16384)); }
}  // namespace

Extractor::Extractor(const TetGrid& grid, const IntervalTree& tree) : grid_(grid), tree_(tree) {}
Extractor::~Extractor() = default;

void Extractor::fresh(double iso) {
  active_.clear();
  active_tetrahedra(tree_, state_, active_);
  sort_tetrahedra(active_, grid_.tet_count(), bitmap_);
  // Edge ends (80 bytes per vertex, about 0.7 vertices per active tetrahedron) are kept only up to
  // edge_cache_max_tetrahedra; larger surfaces are re-interpolated from the grid, a little slower.
  cache_ends_ = active_.size() <= edge_cache_max_tetrahedra;
  march_tetrahedra_into(grid_, active_, iso, mesh_, scratch_, &gaps_, cache_ends_ ? &ends_ : nullptr);
  if (!cache_ends_) std::vector<EdgeEnds>().swap(ends_);
  marched_ = active_.size();
  codes_.swap(scratch_.codes);
  first_tri_.swap(scratch_.first_triangle);
  keys_.swap(scratch_.order);
  // The march kept edge ends and case intervals for the incremental path; count vertex uses.
  refs_.assign(keys_.size(), 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh_.triangles.size(), 16384), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i)
      for (std::uint32_t v : mesh_.triangles[i]) std::atomic_ref<std::uint32_t>(refs_[v]).fetch_add(1, std::memory_order_relaxed);
  });
}

bool Extractor::update(double iso) {
  const TetGrid& g = grid_;
  if (!state_.touched_complete) return false;
  // 1. The new active list: the previous one (ascending) merged with the walked entries.
  candidates_ = state_.touched;
  if (candidates_.size() * 64 > g.tet_count()) {  // many: a bitmap pass beats sorting
    sort_tetrahedra(candidates_, g.tet_count(), bitmap_);
  } else {
    tbb::parallel_sort(candidates_.begin(), candidates_.end());
    candidates_.erase(std::unique(candidates_.begin(), candidates_.end()), candidates_.end());
  }
  const std::size_t n_old = prev_active_.size();
  active_.resize(n_old + candidates_.size());
  old_index_.resize(n_old + candidates_.size());
  left_.clear();
  std::size_t n = 0, j = 0;
  auto copy_run = [&](std::size_t end) {  // previous entries j..end-1 stay active
    std::copy(prev_active_.begin() + static_cast<std::ptrdiff_t>(j), prev_active_.begin() + static_cast<std::ptrdiff_t>(end),
              active_.begin() + static_cast<std::ptrdiff_t>(n));
    for (; j < end; ++j) old_index_[n++] = static_cast<std::uint32_t>(j);
  };
  for (std::uint32_t t : candidates_) {
    copy_run(static_cast<std::size_t>(std::lower_bound(prev_active_.begin() + static_cast<std::ptrdiff_t>(j), prev_active_.end(), t) -
                                      prev_active_.begin()));
    const bool was = j < n_old && prev_active_[j] == t;
    if (state_.flags[t] == 3) {
      active_[n] = t;
      old_index_[n++] = was ? static_cast<std::uint32_t>(j) : kNone;
    } else if (was) {
      left_.push_back(static_cast<std::uint32_t>(j));
    }
    j += was;
  }
  copy_run(n_old);
  active_.resize(n);
  old_index_.resize(n);
  // 2. Codes and case intervals: reused unless the iso-value left the interval (in parallel); the
  // entries to march again are collected per block, in order.
  codes_.resize(n);
  gaps_.resize(n);
  const std::size_t blocks = block_count(n);
  changed_.resize(blocks);
  block_tris_.assign(blocks + 1, 0);
  // Give up as soon as more would change than a fresh march is worth.
  const double limit = max_changed_fraction < 1 ? max_changed_fraction * static_cast<double>(std::max(n, n_old))
                                                : std::numeric_limits<double>::infinity();
  if (static_cast<double>(left_.size()) > limit) return false;
  std::atomic<std::size_t> changed_so_far{left_.size()};
  std::atomic<bool> too_many{false};
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& list = changed_[b];
    list.clear();
    if (too_many.load(std::memory_order_relaxed)) return;
    std::uint64_t tris = 0;
    const std::size_t end = n * (b + 1) / blocks;
    for (std::size_t i = n * b / blocks; i < end;) {
      const std::uint32_t o = old_index_[i];
      if (o == kNone) {  // entered
        codes_[i] = code_and_gap(g, active_[i], iso, gaps_[i]);
        list.push_back(static_cast<std::uint32_t>(i));
        tris += kCases[codes_[i]].triangles;
        ++i;
        continue;
      }
      std::size_t r = i + 1;  // the run i..r-1 had consecutive entries o.. before: copy, then check
      while (r < end && old_index_[r] == o + (r - i)) ++r;
      std::memcpy(codes_.data() + i, prev_codes_.data() + o, r - i);
      std::memcpy(gaps_.data() + i, prev_gaps_.data() + o, (r - i) * sizeof(Gap));
      tris += prev_first_tri_[o + (r - i)] - prev_first_tri_[o];
      for (std::size_t k = i; k < r; ++k)
        if (!(gaps_[k].below < iso && iso <= gaps_[k].above)) {
          tris -= kCases[codes_[k]].triangles;
          codes_[k] = code_and_gap(g, active_[k], iso, gaps_[k]);
          tris += kCases[codes_[k]].triangles;
          list.push_back(static_cast<std::uint32_t>(k));
        }
      i = r;
    }
    block_tris_[b + 1] = tris;
    if (static_cast<double>(changed_so_far.fetch_add(list.size()) + list.size()) > limit) too_many = true;
  });
  if (too_many) return false;
  const std::size_t changed = changed_so_far;
  for (std::size_t b = 0; b < blocks; ++b) block_tris_[b + 1] += block_tris_[b];
  first_tri_.resize(n + 1);
  first_tri_[n] = block_tris_[blocks];
  const std::size_t T = first_tri_[n];

  // 3. Vertex bookkeeping, O(changed), in parallel. Release the old triangles of the tetrahedra
  // that left or changed case (atomic use counts; a vertex whose count drops to zero may be dead).
  const std::uint32_t V_old = static_cast<std::uint32_t>(keys_.size());
  const bool cached = cache_ends_;
  if (V_old >= kNewBit) throw std::length_error("extractor: too many mesh vertices");
  tbb::enumerable_thread_specific<std::vector<std::uint32_t>> released;
  auto release = [&](std::uint32_t o, std::vector<std::uint32_t>& dead) {
    for (std::uint64_t k = prev_first_tri_[o]; k < prev_first_tri_[o + 1]; ++k)
      for (std::uint32_t v : prev_tris_[k])
        if (std::atomic_ref<std::uint32_t>(refs_[v]).fetch_sub(1, std::memory_order_relaxed) == 1) dead.push_back(v);
  };
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, left_.size(), 1024), [&](const auto& r) {
    auto& dead = released.local();
    for (std::size_t x = r.begin(); x < r.end(); ++x) release(left_[x], dead);
  });
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& dead = released.local();
    for (std::uint32_t i : changed_[b])
      if (old_index_[i] != kNone) release(old_index_[i], dead);
  });
  // New triangles, by chunks of consecutive blocks: a corner on an edge the tetrahedron cut before
  // keeps that vertex; edges cut for the first time are numbered as one sequential pass would
  // (number_chunk_edges, as in march_tetrahedra): V_old + k for the k-th.
  const std::size_t re_marched = changed - left_.size();
  marched_ = re_marched;
  const std::size_t C = 16 * re_marched < parallel_min_triangles ? 1 : std::min<std::size_t>(blocks, std::max(1, tbb::this_task_arena::max_concurrency()));
  std::vector<std::size_t> chunk_block(C + 1, blocks);
  for (std::size_t b = 0, c = 0, seen = 0; b < blocks && c <= C; seen += changed_[b++].size())
    while (c <= C && seen >= re_marched * c / C) chunk_block[c++] = b;
  chunk_block[0] = 0;
  chunks_.resize(C);
  chunk_tris_.resize(C);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = chunks_[c];
    auto& tris = chunk_tris_[c];
    ch.order.clear();
    tris.clear();
    ch.map = std::make_shared<EdgeMap>(64, ch.slots, ch.ids);
    for (std::size_t b = chunk_block[c]; b < chunk_block[c + 1]; ++b)
      for (std::uint32_t i : changed_[b]) {
        const std::uint32_t o = old_index_[i];
        const auto& t = g.tets[active_[i]];
        const Case& cs = kCases[codes_[i]];
        for (int q = 0; q < cs.triangles; ++q) {
          std::array<std::uint32_t, 3> tri;
          for (int e = 0; e < 3; ++e) {
            const std::uint64_t key = edge_key(t[cs.tri[q][e].below], t[cs.tri[q][e].above]);
            std::uint32_t id = kNone;
            if (o != kNone)
              for (std::uint64_t k = prev_first_tri_[o]; k < prev_first_tri_[o + 1] && id == kNone; ++k)
                for (std::uint32_t v : prev_tris_[k])
                  if (keys_[v] == key) id = v;
            tri[e] = id != kNone ? id : kNewBit | ch.map->find_or_add(key, ch.order);
          }
          tris.push_back(tri);
        }
      }
  });
  number_chunk_edges(chunks_, new_keys_);
  std::vector<std::size_t> tri_offset(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) tri_offset[c + 1] = tri_offset[c] + chunk_tris_[c].size();
  new_tris_.resize(tri_offset[C]);
  new_refs_.assign(new_keys_.size(), 0);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {  // final provisional ids, uses
    const auto& ch = chunks_[c];
    auto* out = new_tris_.data() + tri_offset[c];
    for (const auto& tri : chunk_tris_[c]) {
      for (int e = 0; e < 3; ++e) {
        const std::uint32_t v = tri[e] & kNewBit ? V_old + ch.global[tri[e] & ~kNewBit] : tri[e];
        (*out)[e] = v;
        std::atomic_ref<std::uint32_t>(v < V_old ? refs_[v] : new_refs_[v - V_old]).fetch_add(1, std::memory_order_relaxed);
      }
      ++out;
    }
  });
  // A vertex released to zero may have been used again by a new triangle.
  dead_.clear();
  for (const auto& d : released)
    for (std::uint32_t v : d)
      if (refs_[v] == 0) dead_.push_back(v);
  std::sort(dead_.begin(), dead_.end());

  // 4. Slots: new vertices take the lowest freed slots, then the end; when more slots were freed
  // than filled, live vertices from the end move into the holes below the new vertex count.
  const std::size_t D = dead_.size(), N = new_keys_.size();
  const std::uint32_t V = static_cast<std::uint32_t>(V_old + N - D);
  auto new_slot = [&](std::size_t k) { return k < D ? dead_[k] : static_cast<std::uint32_t>(V_old + (k - D)); };
  tail_.clear();  // tail_[v - V]: the slot of live vertex v >= V
  if (V < V_old) {
    tail_.assign(V_old - V, kNone);
    std::size_t h = N;  // holes dead_[N..D) below V, ascending, paired with live tail vertices
    for (std::uint32_t v = V; v < V_old; ++v) {
      if (refs_[v] == 0) continue;
      // Holes below V (the first of dead_[N..D), ascending) are as many as live vertices >= V.
      if (h >= D || dead_[h] >= V) throw std::logic_error("extractor: vertex slots out of balance");
      const std::uint32_t slot = dead_[h++];
      tail_[v - V] = slot;
      keys_[slot] = keys_[v];
      refs_[slot] = refs_[v];
      if (cached) ends_[slot] = ends_[v];
    }
  }
  keys_.resize(V);
  refs_.resize(V);
  if (cached) ends_.resize(V);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, N, 1024), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      keys_[new_slot(k)] = new_keys_[k];
      refs_[new_slot(k)] = new_refs_[k];
      if (cached) ends_[new_slot(k)] = gather_edge(g, new_keys_[k]);
    }
  });
  auto final_id = [&](std::uint32_t p) {
    if (p >= V_old) return new_slot(p - V_old);
    return p >= V ? tail_[p - V] : p;
  };

  // 5. Triangles in active order, with the offsets per tetrahedron: unchanged tetrahedra copy
  // theirs (in parallel, by runs that were consecutive before too), the re-marched ones take their
  // new triangles.
  mesh_.triangles.resize(T);
  for (std::size_t b = 0; b < blocks; ++b)
    for (std::uint32_t i : changed_[b]) old_index_[i] = kNone;
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    const std::size_t end = n * (b + 1) / blocks;
    std::uint64_t f = block_tris_[b];
    for (std::size_t i = n * b / blocks; i < end;) {
      const std::uint32_t o = old_index_[i];
      if (o == kNone) {  // re-marched: its triangles are written below
        first_tri_[i] = f;
        f += kCases[codes_[i]].triangles;
        ++i;
        continue;
      }
      std::size_t r = i;  // the run i..r-1 had consecutive entries o.. before
      for (; r < end && old_index_[r] == o + (r - i); ++r) {
        first_tri_[r] = f + (prev_first_tri_[o + (r - i)] - prev_first_tri_[o]);
      }
      const std::uint64_t from = prev_first_tri_[o], to = prev_first_tri_[o + (r - i)];
      auto* dst = mesh_.triangles.data() + f;
      std::copy(prev_tris_.begin() + static_cast<std::ptrdiff_t>(from), prev_tris_.begin() + static_cast<std::ptrdiff_t>(to), dst);
      if (!tail_.empty())
        for (std::uint64_t k = 0; k < to - from; ++k)
          for (auto& v : dst[k]) v = v >= V ? tail_[v - V] : v;
      f += to - from;
      i = r;
    }
  });
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    std::size_t next = tri_offset[c];
    for (std::size_t b = chunk_block[c]; b < chunk_block[c + 1]; ++b)
      for (std::uint32_t i : changed_[b])
        for (std::uint64_t k = first_tri_[i]; k < first_tri_[i + 1]; ++k, ++next)
          for (int e = 0; e < 3; ++e) mesh_.triangles[k][e] = final_id(new_tris_[next][e]);
  });
  if (cached) {
    interpolate_vertices(ends_, iso, mesh_);
  } else {
    interpolate_vertices(g, keys_, iso, mesh_);
  }
  return true;
}

ExtractStats Extractor::extract(double iso) {
  using Clock = std::chrono::steady_clock;
  ExtractStats st;
  st.iso = iso;
  st.in_range = iso >= grid_.source.min && iso <= grid_.source.max;
  auto t0 = Clock::now();
  // Above this many walked entries a fresh march is cheaper than merging.
  state_.touched_limit = max_changed_fraction >= 1 ? ~std::size_t{0}
                                                   : static_cast<std::size_t>(max_changed_fraction * static_cast<double>(active_.size())) + 1024;
  sweep_to(tree_, grid_, state_, iso);
  auto t1 = Clock::now();
  // Keep the previous extraction for the incremental update. Should anything below throw, the
  // buffers are half swapped: the next call then starts afresh.
  const bool had_previous = valid_;
  valid_ = false;
  active_.swap(prev_active_);
  codes_.swap(prev_codes_);
  gaps_.swap(prev_gaps_);
  first_tri_.swap(prev_first_tri_);
  mesh_.triangles.swap(prev_tris_);
  incremental_ = had_previous && update(iso);
  if (!incremental_) fresh(iso);
  valid_ = true;
  auto t2 = Clock::now();
  st.walked = state_.walked;
  st.active = active_.size();
  st.marched = marched_;
  st.triangles = mesh_.triangle_count();
  st.vertices = mesh_.vertex_count();
  st.sweep_seconds = std::chrono::duration<double>(t1 - t0).count();
  st.march_seconds = std::chrono::duration<double>(t2 - t1).count();
  return st;
}

}  // namespace adaptiso
