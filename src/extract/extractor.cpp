// The Extractor: sweeping simplices plus marching tetrahedra with an incremental update of the
// mesh for small changes of iso-value (see extract.hpp).
//
// After a step from c0 to c1 a tetrahedron keeps its triangles, and every corner keeps its cut
// edge, unless one of its vertices lies in [min(c0,c1), max(c0,c1)): its case code changes. Every
// active tetrahedron owns a slot that carries its case, the interval of iso-values keeping that
// case and the positions of its 1 or 2 triangles in the mesh, so a step is one read-only pass over
// the case intervals plus work proportional to what changed: the slots, triangles and vertices of
// unchanged tetrahedra stay where they are. Tetrahedra that entered come from the entries the sweep
// walked; an edge a re-marched tetrahedron cut before is found among its old corners, so only edges
// cut for the first time need a hash map. A vertex dies exactly when its edge stops being cut that
// way, which the changed tetrahedra around it see in their tables (no use counts). Freed slots,
// triangle positions and vertices are reused in ascending order, then the arrays grow; when more
// were freed than filled, entries from the end move into the remaining holes. Everything is decided
// in block order (not by thread timing), so the mesh depends only on the history of iso-values.
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <limits>
#include <stdexcept>

#include "adaptiso/extract.hpp"
#include "extract/march_internal.hpp"

namespace adaptiso {
namespace {
constexpr std::uint32_t kNone = ~std::uint32_t{0};
constexpr std::uint32_t kNewBit = std::uint32_t{1} << 31;  // marks a chunk's index of a first-cut edge corner

// Work split into this many blocks for the streaming passes (a multiple of the thread count keeps
// the cores busy; few enough that per-block bookkeeping stays negligible).
std::size_t block_count(std::size_t n) { return std::max<std::size_t>(1, std::min<std::size_t>(256, n / 16384)); }

bool cut(std::uint8_t code) { return code != 0 && code != 15; }

// The incremental step reads the grid and its own arrays at scattered places (the tetrahedra that
// changed are few and far between); prefetching a few iterations ahead overlaps those misses.
inline void prefetch(const void* p) { __builtin_prefetch(p); }

// Where new entry k goes when `freed` (ascending) of [0, old_n) were released: freed[k] or, past
// the freed ones, the end.
std::uint32_t placed(const std::vector<std::uint32_t>& freed, std::size_t old_n, std::size_t k) {
  return k < freed.size() ? freed[k] : static_cast<std::uint32_t>(old_n + (k - freed.size()));
}

// Slots [0, old_n) of which `freed` (ascending) are released and `fill` new entries arrive, placed
// as by placed(). Returns the new count and, when fewer arrive than were freed, the live entries
// from the end that move into the remaining holes below the new count, as (from, to) pairs.
std::size_t place(const std::vector<std::uint32_t>& freed, std::size_t fill, std::size_t old_n,
                  std::vector<std::pair<std::uint32_t, std::uint32_t>>& moves) {
  moves.clear();
  const std::size_t n = old_n + fill - freed.size();
  if (fill >= freed.size()) return n;
  std::size_t h = fill, f = static_cast<std::size_t>(std::lower_bound(freed.begin(), freed.end(), n) - freed.begin());
  for (std::size_t from = n; from < old_n; ++from) {
    if (f < freed.size() && freed[f] == from) {
      ++f;
      continue;
    }
    if (h >= freed.size() || freed[h] >= n) throw std::logic_error("extractor: slots out of balance");
    moves.emplace_back(static_cast<std::uint32_t>(from), freed[h++]);
  }
  return n;
}
}  // namespace

Extractor::Extractor(const TetGrid& grid, const IntervalTree& tree) : grid_(grid), tree_(tree) {}
Extractor::~Extractor() = default;

void Extractor::fresh(double iso) {
  active_.clear();
  active_tetrahedra(tree_, state_, active_);
  sort_ids(active_, grid_.tet_count(), bitmap_);
  // Edge ends (64 bytes per vertex, about 0.7 vertices per active tetrahedron) are kept only up to
  // edge_cache_max_tetrahedra; larger surfaces are re-interpolated from the grid, a little slower.
  cache_ends_ = active_.size() <= edge_cache_max_tetrahedra;
  march_tetrahedra_into(grid_, active_, iso, mesh_, scratch_, &gaps_, cache_ends_ ? &ends_ : nullptr);
  if (!cache_ends_) std::vector<EdgeEnds>().swap(ends_);
  marched_ = active_.size();
  codes_.swap(scratch_.codes);
  keys_.swap(scratch_.order);
  // Slots in active order: each owns the triangles the march wrote for it.
  const auto& first = scratch_.first_triangle;
  const std::size_t n = active_.size();
  resize_for_overwrite(slot_tris_, n);
  resize_for_overwrite(owner_, mesh_.triangles.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384), [&](const auto& r) {
    for (std::size_t s = r.begin(); s < r.end(); ++s) {
      const auto f = static_cast<std::uint32_t>(first[s]);
      slot_tris_[s] = {f, first[s + 1] > f + 1 ? f + 1 : kNone};
      for (std::uint64_t k = first[s]; k < first[s + 1]; ++k) owner_[k] = static_cast<std::uint32_t>(s);
    }
  });
}

bool Extractor::update(double iso) {
  const TetGrid& g = grid_;
  if (!state_.entering_complete) return false;
  const std::size_t n_old = active_.size();
  const std::size_t T_old = mesh_.triangles.size();
  const std::uint32_t V_old = static_cast<std::uint32_t>(keys_.size());
  if (V_old >= kNewBit || T_old >= kNone || n_old + state_.entering.size() >= kNone)
    throw std::length_error("extractor: too many mesh elements");
  // Give up as soon as more would change than a fresh march is worth.
  const double limit = max_changed_fraction < 1 ? max_changed_fraction * static_cast<double>(std::max<std::size_t>(n_old, 1))
                                                : std::numeric_limits<double>::infinity();

  // 1. Entered: the sweep's entering entries that are active now (they were not at c0; those active
  // at both changed case and are found by the pass below), with their case at iso while their
  // values are at hand. Each comes once, in tree order (deterministic).
  const auto& entering = state_.entering;
  const std::size_t tb = block_count(entering.size());
  entered_parts_.resize(tb);
  tbb::parallel_for(std::size_t{0}, tb, [&](std::size_t b) {
    auto& part = entered_parts_[b];
    part.clear();
    const std::size_t end = entering.size() * (b + 1) / tb;
    for (std::size_t i = entering.size() * b / tb; i < end; ++i) {
      if (i + 16 < end) {
        prefetch(&g.tets[entering[i + 16]]);
        prefetch(&state_.flags[entering[i + 16]]);
      }
      if (i + 8 < end) prefetch_values(g, entering[i + 8]);
      if (const std::uint32_t t = entering[i]; state_.flags[t] == 3) {
        Entered e{t, 0, {}};
        e.code = code_and_gap(g, t, iso, e.gap);
        part.push_back(e);
      }
    }
  });
  entered_.clear();
  for (const auto& part : entered_parts_) entered_.insert(entered_.end(), part.begin(), part.end());
  const std::size_t E = entered_.size();
  if (static_cast<double>(E) > limit) return false;

  // 2. Slots whose iso-value left their case interval get their new case (in parallel, per block
  // in slot order). The old triangles stay in place until step 7 reuses their places.
  const std::size_t blocks = block_count(n_old);
  changed_.resize(blocks);
  changed_old_.resize(blocks);
  block_cut_.resize(blocks);
  std::atomic<std::size_t> changed_so_far{E};
  std::atomic<bool> too_many{false};
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& list = changed_[b];
    auto& old_codes = changed_old_[b];
    list.clear();
    old_codes.clear();
    if (too_many.load(std::memory_order_relaxed)) return;
    const Gap* gap = gaps_.data();
    for (std::size_t s = n_old * b / blocks; s < n_old * (b + 1) / blocks; ++s)
      if (!(gap[s].below < iso && iso <= gap[s].above)) list.push_back(static_cast<std::uint32_t>(s));
    if (static_cast<double>(changed_so_far.fetch_add(list.size()) + list.size()) > limit) {
      too_many = true;
      return;
    }
    // The grid reads are scattered: prefetch the slot's tetrahedron, then its values, ahead.
    const std::size_t m = list.size();
    std::size_t cuts = 0;
    for (std::size_t i = 0; i < m; ++i) {
      if (i + 32 < m) prefetch(&active_[list[i + 32]]);
      if (i + 16 < m) prefetch(&g.tets[active_[list[i + 16]]]);
      if (i + 8 < m) prefetch_values(g, active_[list[i + 8]]);
      old_codes.push_back(codes_[list[i]]);
      codes_[list[i]] = code_and_gap(g, active_[list[i]], iso, gaps_[list[i]]);
      cuts += cut(codes_[list[i]]);
    }
    block_cut_[b] = cuts;
  });
  if (too_many) return false;  // codes_ and gaps_ are rebuilt by the fresh march

  // 3. Release the old triangles of the changed slots: their positions become free, and so does
  // every corner whose local edge the new case does not cut the same way (below, above). Such a
  // vertex is dead: one of its edge's ends crossed the iso-value, so every tetrahedron around the
  // edge changed case and none keeps it; a corner whose edge is still cut that way lives on in
  // every tetrahedron around it. Several of them report it; sort_ids drops the repeats.
  tbb::enumerable_thread_specific<std::vector<std::uint32_t>> released;
  free_parts_.resize(blocks);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& dead = released.local();
    auto& freed = free_parts_[b];
    freed.clear();
    const auto& list = changed_[b];
    for (std::size_t i = 0; i < list.size(); ++i) {
      if (i + 16 < list.size()) prefetch(&slot_tris_[list[i + 16]]);
      if (i + 8 < list.size())
        for (std::uint32_t k : slot_tris_[list[i + 8]])
          if (k != kNone) prefetch(&mesh_.triangles[k]);
      const Case& was = kCases[changed_old_[b][i]];
      const unsigned now = codes_[list[i]];
      for (int q = 0; q < was.triangles; ++q) {
        const std::uint32_t k = slot_tris_[list[i]][q];
        freed.push_back(k);
        for (int e = 0; e < 3; ++e)
          if (const LocalEdge le = was.tri[q][e]; ((now >> le.below) & 1) || !((now >> le.above) & 1)) dead.push_back(mesh_.triangles[k][e]);
      }
    }
  });

  // 4. The work: changed slots still cut (block order), then the entered tetrahedra (tree order).
  std::vector<std::size_t> work_at(blocks + 1, 0), leave_at(blocks + 1, 0);
  for (std::size_t b = 0; b < blocks; ++b) {
    work_at[b + 1] = work_at[b] + block_cut_[b];
    leave_at[b + 1] = leave_at[b] + (changed_[b].size() - block_cut_[b]);
  }
  work_.resize(work_at[blocks]);
  work_old_.resize(work_at[blocks]);
  leaving_.resize(leave_at[blocks]);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    std::size_t w = work_at[b], l = leave_at[b];
    for (std::size_t i = 0; i < changed_[b].size(); ++i) {
      const std::uint32_t s = changed_[b][i];
      if (cut(codes_[s])) {
        work_old_[w] = changed_old_[b][i];
        work_[w++] = s;
      } else {
        leaving_[l++] = s;
      }
    }
  });
  const std::size_t R = work_.size();
  const std::size_t W = R + E;
  if (6 * W >= kNewBit) throw std::length_error("extractor: too many mesh elements");
  marched_ = W;
  auto work_tet = [&](std::size_t w) { return w < R ? active_[work_[w]] : entered_[w - R].tet; };
  auto work_code = [&](std::size_t w) { return w < R ? codes_[work_[w]] : entered_[w - R].code; };

  // New triangles, by chunks of consecutive work: a corner on an edge the tetrahedron cut before
  // (the same local edge, cut the same way, in the old case's table) keeps that vertex, read from
  // the old triangle's corner (corners lie in table order); edges cut for the first time are
  // numbered as one sequential pass would (number_chunk_edges, as in march_tetrahedra): V_old + k
  // for the k-th.
  const std::size_t C = 16 * W < parallel_min_triangles ? 1 : static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  chunks_.resize(C);
  chunk_tris_.resize(C);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = chunks_[c];
    auto& tris = chunk_tris_[c];
    ch.order.clear();
    ch.pending.clear();
    tris.clear();
    ch.map = std::make_shared<EdgeMap>((W * (c + 1) / C - W * c / C) / 2 + 16, ch.slots);
    const std::size_t w_end = W * (c + 1) / C;
    for (std::size_t w = W * c / C; w < w_end; ++w) {
      if (w + 32 < std::min(w_end, R)) {
        prefetch(&active_[work_[w + 32]]);
        prefetch(&codes_[work_[w + 32]]);
        prefetch(&slot_tris_[work_[w + 32]]);
      }
      if (w + 16 < w_end) {
        prefetch(&g.tets[work_tet(w + 16)]);
        if (w + 16 < R)
          for (std::uint32_t k : slot_tris_[work_[w + 16]])
            if (k != kNone) prefetch(&mesh_.triangles[k]);
      }
      const auto& t = g.tets[work_tet(w)];
      const Case& cs = kCases[work_code(w)];
      // The old corners: local edge (below, above) and vertex, one per corner of the old triangles.
      LocalEdge old_edge[6];
      std::uint32_t old_vertex[6];
      int olds = 0;
      if (w < R) {
        const Case& was = kCases[work_old_[w]];
        for (int q = 0; q < was.triangles; ++q)
          for (int e = 0; e < 3; ++e) {
            old_edge[olds] = was.tri[q][e];
            old_vertex[olds++] = mesh_.triangles[slot_tris_[work_[w]][q]][e];
          }
      }
      for (int q = 0; q < cs.triangles; ++q) {
        std::array<std::uint32_t, 3> tri;
        for (int e = 0; e < 3; ++e) {
          const LocalEdge le = cs.tri[q][e];
          std::uint32_t id = kNone;
          for (int i = 0; i < olds; ++i)
            if (old_edge[i].below == le.below && old_edge[i].above == le.above) id = old_vertex[i];
          if (id == kNone) {  // hashed below, in a pass that knows its keys ahead
            id = kNewBit | static_cast<std::uint32_t>(ch.pending.size());
            ch.pending.push_back(edge_key(t[le.below], t[le.above]));
          }
          tri[e] = id;
        }
        tris.push_back(tri);
      }
    }
    // Edges cut for the first time, numbered by first use in the chunk (prefetching the probes:
    // on large steps the map outgrows the caches, and each probe would otherwise stall).
    const std::size_t m = ch.pending.size();
    ch.local.resize(m);
    for (std::size_t i = 0; i < m; ++i) {
      if (i + 16 < m) ch.map->prefetch(ch.pending[i + 16]);
      ch.local[i] = ch.map->find_or_add(ch.pending[i], ch.order);
    }
  });
  number_chunk_edges(chunks_, new_keys_);
  std::vector<std::size_t> tri_offset(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) tri_offset[c + 1] = tri_offset[c] + chunk_tris_[c].size();
  const std::size_t new_tri_count = tri_offset[C];
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {  // provisional ids: new ones after V_old
    const auto& ch = chunks_[c];
    for (auto& tri : chunk_tris_[c])
      for (auto& v : tri)
        if (v & kNewBit) v = V_old + ch.global[ch.local[v & ~kNewBit]];
  });
  dead_.clear();
  for (const auto& d : released) dead_.insert(dead_.end(), d.begin(), d.end());
  sort_ids(dead_, V_old, bitmap_);

  // 5. Vertex slots: new vertices take the lowest freed slots, then the end; live vertices from
  // the end fill the holes that remain below the new count (tail_ maps them).
  const bool cached = cache_ends_;
  const std::size_t N = new_keys_.size();
  const auto V = static_cast<std::uint32_t>(place(dead_, N, V_old, moves_));
  tail_.assign(V_old > V ? V_old - V : 0, kNone);
  // Moves go from [V, V_old) to holes below V, each from and to once: safe in parallel.
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, moves_.size(), 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const auto [from, to] = moves_[i];
      tail_[from - V] = to;
      keys_[to] = keys_[from];
      if (cached) ends_[to] = ends_[from];
    }
  });
  auto new_slot = [&](std::size_t k) { return placed(dead_, V_old, k); };
  keys_.resize(V);
  if (cached) ends_.resize(V);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, N, 1024), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      if (cached && k + 8 < r.end()) prefetch_edge(g, new_keys_[k + 8]);
      keys_[new_slot(k)] = new_keys_[k];
      if (cached) ends_[new_slot(k)] = gather_edge(g, new_keys_[k]);
    }
  });
  auto final_vertex = [&](std::uint32_t p) {
    if (p >= V_old) return new_slot(p - V_old);
    return p >= V ? tail_[p - V] : p;
  };

  // 6. Active slots: the entered tetrahedra take the slots of those that left, then the end; live
  // slots from the end fill the remaining holes (their triangles learn their new owner).
  const std::size_t n = place(leaving_, E, n_old, moves_);
  entered_slot_.resize(E);
  if (n > n_old) {
    active_.resize(n);
    codes_.resize(n);
    gaps_.resize(n);
    slot_tris_.resize(n);
  }
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, E, 4096), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      const std::uint32_t s = placed(leaving_, n_old, k);
      active_[s] = entered_[k].tet;
      codes_[s] = entered_[k].code;
      gaps_[s] = entered_[k].gap;
      entered_slot_[k] = s;
    }
  });
  if (!moves_.empty()) slot_tail_.assign(n_old - n, kNone);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, moves_.size(), 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const auto [from, to] = moves_[i];
      active_[to] = active_[from];
      codes_[to] = codes_[from];
      gaps_[to] = gaps_[from];
      slot_tris_[to] = slot_tris_[from];
      slot_tail_[from - n] = to;
      for (std::uint32_t k : slot_tris_[to])
        if (k != kNone) owner_[k] = to;  // only unchanged slots keep their old triangles; the others are rewritten
    }
  });
  if (!moves_.empty())  // re-marched slots that moved
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, work_.size(), 16384), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i)
        if (work_[i] >= n) work_[i] = slot_tail_[work_[i] - n];
    });
  active_.resize(n);
  codes_.resize(n);
  gaps_.resize(n);
  slot_tris_.resize(n);

  // 7. Triangle positions: the new triangles (in work order) take the freed positions ascending,
  // then the end; live triangles from the end fill the remaining holes.
  free_.clear();
  for (const auto& part : free_parts_) free_.insert(free_.end(), part.begin(), part.end());
  sort_ids(free_, T_old, bitmap_);  // no repeats: each triangle had one owner
  const std::size_t T = place(free_, new_tri_count, T_old, moves_);
  if (T > T_old) {
    mesh_.triangles.resize(T);
    owner_.resize(T);
  }
  // Two moves may belong to one slot (its two triangles): its entries are touched atomically.
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, moves_.size(), 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const auto [from, to] = moves_[i];
      mesh_.triangles[to] = mesh_.triangles[from];
      const std::uint32_t s = owner_[from];
      owner_[to] = s;
      for (auto& k : slot_tris_[s])
        if (std::atomic_ref<std::uint32_t> a(k); a.load(std::memory_order_relaxed) == from) a.store(to, std::memory_order_relaxed);
    }
  });
  auto tri_pos = [&](std::size_t j) { return placed(free_, T_old, j); };
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    std::size_t j = tri_offset[c];
    for (std::size_t w = W * c / C; w < W * (c + 1) / C; ++w) {
      const std::uint32_t s = w < R ? work_[w] : entered_slot_[w - R];
      auto& mine = slot_tris_[s];
      mine = {kNone, kNone};
      for (int q = 0; q < kCases[codes_[s]].triangles; ++q, ++j) {
        const std::uint32_t p = tri_pos(j);
        const auto& tri = chunk_tris_[c][j - tri_offset[c]];
        mesh_.triangles[p] = {final_vertex(tri[0]), final_vertex(tri[1]), final_vertex(tri[2])};
        owner_[p] = s;
        mine[q] = p;
      }
    }
  });
  mesh_.triangles.resize(T);
  owner_.resize(T);
  // Unchanged triangles that use a vertex moved in step 5.
  if (!tail_.empty())
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 16384), [&](const auto& r) {
      for (std::size_t k = r.begin(); k < r.end(); ++k)
        for (auto& v : mesh_.triangles[k])
          if (v >= V) v = tail_[v - V];
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
  // Above this many entering entries a fresh march is cheaper than a step.
  state_.entering_limit = max_changed_fraction >= 1 ? ~std::size_t{0}
                                                   : static_cast<std::size_t>(max_changed_fraction * static_cast<double>(active_.size())) + 1024;
  sweep_to(tree_, grid_, state_, iso);
  auto t1 = Clock::now();
  // Should anything below throw, the state is half updated: the next call then starts afresh.
  const bool had_previous = valid_;
  valid_ = false;
  incremental_ = had_previous && update(iso);
  if (!incremental_) fresh(iso);
  iso_ = iso;
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
