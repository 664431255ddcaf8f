// The Extractor: sweeping simplices plus marching tetrahedra, with an incremental update of the
// mesh for small changes of iso-value (see extractor.hpp).
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.4 (browsing iso-values: sweep, then march).
// - Shen, Johnson. Sweeping simplices: a fast iso-surface extraction algorithm for unstructured
//   grids. IEEE Visualization 1995.
//
// After a step from c0 to c1 a tetrahedron keeps its triangles, and every corner keeps its cut
// edge, unless one of its vertices lies in [min(c0,c1), max(c0,c1)): its case code changes. Every
// active tetrahedron owns a slot that carries its case, the interval of iso-values keeping that
// case and the places of its 1 or 2 triangles in the mesh, so a step is one read-only pass over
// the case intervals plus work proportional to what changed: the slots, triangles and vertices of
// unchanged tetrahedra stay where they are. Tetrahedra that entered come from the entries the sweep
// walked; an edge a re-marched tetrahedron cut before is found among its old corners, so only edges
// cut for the first time need a hash map. A vertex dies exactly when its edge stops being cut that
// way, which the changed tetrahedra around it see in their tables (no use counts). Freed slots,
// triangle places and vertices are reused in ascending order, then the arrays grow; when more
// were freed than filled, entries from the end move into the remaining holes (Compaction).
// Everything is decided in block order (not by thread timing), so the mesh depends only on the
// history of iso-values.
#include "adaptiso/extractor.hpp"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <limits>
#include <nlohmann/json.hpp>
#include <numeric>
#include <stdexcept>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/marching_tetrahedra.hpp"
#include "extract/extractor_state.hpp"
#include "util/radix_sort.hpp"

namespace adaptiso::detail {
namespace {
constexpr std::uint32_t kNone = ~std::uint32_t{0};
constexpr std::uint32_t kNewBit = std::uint32_t{1} << 31;  // marks a chunk's index of a first-cut edge corner

// Work split into this many blocks for the streaming passes (a multiple of the thread count keeps
// the cores busy; few enough that per-block bookkeeping stays negligible).
std::size_t block_count(std::size_t n) { return std::max<std::size_t>(1, std::min<std::size_t>(256, n / 16384)); }
// Block b of n items: [begin, end).
std::size_t block_begin(std::size_t n, std::size_t blocks, std::size_t b) { return n * b / blocks; }

bool cut(std::uint8_t code) { return code != 0 && code != 15; }

// Runs f(from, to) for every move of a compaction, in parallel (each place is moved from and to once).
template <class F>
void apply_moves(const Compaction& c, F&& f) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, c.moves.size(), 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) f(c.moves[i].first, c.moves[i].second);
  });
}

// Concatenates per-block lists in block order.
template <class T>
void concatenate(const std::vector<std::vector<T>>& parts, std::vector<T>& out) {
  out.clear();
  for (const auto& part : parts) out.insert(out.end(), part.begin(), part.end());
}
}  // namespace

void Compaction::plan(const std::vector<std::uint32_t>& freed_places, std::size_t fill, std::size_t old_n) {
  freed = &freed_places;
  old_count = old_n;
  moves.clear();
  count = old_n + fill - freed_places.size();
  if (fill >= freed_places.size()) return;
  const auto& f = freed_places;
  std::size_t hole = fill;  // freed places below `fill` are taken by new entries
  std::size_t skip = static_cast<std::size_t>(std::lower_bound(f.begin(), f.end(), count) - f.begin());
  for (std::size_t from = count; from < old_n; ++from) {
    if (skip < f.size() && f[skip] == from) {  // freed itself: nothing to move
      ++skip;
      continue;
    }
    if (hole >= f.size() || f[hole] >= count) throw std::logic_error("extractor: slots out of balance");
    moves.emplace_back(static_cast<std::uint32_t>(from), f[hole++]);
  }
}

ExtractorState::ExtractorState(std::shared_ptr<const PreparedGrid> p, const ExtractorOptions& o)
    : prepared(std::move(p)), grid(prepared->grid), tree(prepared->index), options(o) {
  scratch.parallel_min_tetrahedra = o.parallel_min_tetrahedra;
}

void ExtractorState::fresh(double iso) {
  active.clear();
  active_tetrahedra(tree, sweep, active);
  checkpoint();
  sort_ids(active, grid.tet_count(), bitmap_);
  checkpoint();
  // Edge ends (64 bytes per vertex, about 0.7 vertices per active tetrahedron) are kept only up to
  // edge_cache_max_tetrahedra; larger surfaces are re-interpolated from the grid, a little slower.
  cache_ends = active.size() <= options.edge_cache_max_tetrahedra;
  march_tetrahedra_into(grid, active, iso, mesh, scratch, &gaps, cache_ends ? &ends : nullptr);
  if (!cache_ends) std::vector<EdgeEnds>().swap(ends);
  checkpoint();
  marched = active.size();
  codes.swap(scratch.codes);
  keys.swap(scratch.order);
  // Slots in active order: each owns the triangles the march wrote for it.
  const auto& first = scratch.first_triangle;
  const std::size_t n = active.size();
  resize_for_overwrite(slot_tris, n);
  resize_for_overwrite(owner, mesh.triangles.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384), [&](const auto& r) {
    for (std::size_t s = r.begin(); s < r.end(); ++s) {
      const auto f = static_cast<std::uint32_t>(first[s]);
      slot_tris[s] = {f, first[s + 1] > f + 1 ? f + 1 : kNone};
      for (std::uint64_t k = first[s]; k < first[s + 1]; ++k) owner[k] = static_cast<std::uint32_t>(s);
    }
  });
}

bool ExtractorState::step(double iso) {
  if (!sweep.entering_complete) return false;
  old_slots_ = active.size();
  old_triangles_ = mesh.triangles.size();
  old_vertices_ = static_cast<std::uint32_t>(keys.size());
  if (old_vertices_ >= kNewBit || old_triangles_ >= kNone || old_slots_ + sweep.entering.size() >= kNone)
    throw std::length_error("extractor: too many mesh elements");
  // Give up as soon as more would change than a fresh march is worth.
  const double limit = options.max_changed_fraction < 1
                           ? options.max_changed_fraction * static_cast<double>(std::max<std::size_t>(old_slots_, 1))
                           : std::numeric_limits<double>::infinity();
  if (!collect_entered(iso, limit)) return false;
  checkpoint();
  if (!find_changed(iso, limit)) return false;  // codes and gaps are rebuilt by the fresh march
  checkpoint();
  release_changed();
  split_work();
  march_work();
  checkpoint();
  place_vertices();
  place_slots();
  place_triangles();
  finish_vertices(iso);
  return true;
}

// The sweep's entering entries that are active now (they were not at the previous iso-value;
// those active at both changed case and are found by find_changed), with their case at iso while
// their values are at hand. Each comes once, in tree order (deterministic).
bool ExtractorState::collect_entered(double iso, double limit) {
  const auto& entering = sweep.entering;
  const std::size_t blocks = block_count(entering.size());
  entered_parts_.resize(blocks);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& part = entered_parts_[b];
    part.clear();
    const std::size_t end = block_begin(entering.size(), blocks, b + 1);
    for (std::size_t i = block_begin(entering.size(), blocks, b); i < end; ++i) {
      if (i + 16 < end) {
        prefetch(&grid.tets[entering[i + 16]]);
        prefetch(&sweep.flags[entering[i + 16]]);
      }
      if (i + 8 < end) prefetch_values(grid, entering[i + 8]);
      if (const std::uint32_t t = entering[i]; sweep.flags[t] == 3) {
        Entered e{t, 0, {}};
        e.code = code_and_gap(grid, t, iso, e.gap);
        part.push_back(e);
      }
    }
  });
  concatenate(entered_parts_, entered_);
  return static_cast<double>(entered_.size()) <= limit;
}

// Slots whose iso-value left their case interval get their new case (in parallel, per block in
// slot order). Their old triangles stay in place until place_triangles reuses the places.
bool ExtractorState::find_changed(double iso, double limit) {
  const std::size_t blocks = block_count(old_slots_);
  changed_.resize(blocks);
  changed_old_.resize(blocks);
  block_cut_.resize(blocks);
  std::atomic<std::size_t> changed_so_far{entered_.size()};
  std::atomic<bool> too_many{false};
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& list = changed_[b];
    auto& old_codes = changed_old_[b];
    list.clear();
    old_codes.clear();
    if (too_many.load(std::memory_order_relaxed)) return;
    const Gap* gap = gaps.data();
    for (std::size_t s = block_begin(old_slots_, blocks, b); s < block_begin(old_slots_, blocks, b + 1); ++s)
      if (!(gap[s].below < iso && iso <= gap[s].above)) list.push_back(static_cast<std::uint32_t>(s));
    if (static_cast<double>(changed_so_far.fetch_add(list.size()) + list.size()) > limit) {
      too_many = true;
      return;
    }
    // The grid reads are scattered: prefetch the slot's tetrahedron, then its values, ahead.
    const std::size_t m = list.size();
    std::size_t cuts = 0;
    for (std::size_t i = 0; i < m; ++i) {
      if (i + 32 < m) prefetch(&active[list[i + 32]]);
      if (i + 16 < m) prefetch(&grid.tets[active[list[i + 16]]]);
      if (i + 8 < m) prefetch_values(grid, active[list[i + 8]]);
      old_codes.push_back(codes[list[i]]);
      codes[list[i]] = code_and_gap(grid, active[list[i]], iso, gaps[list[i]]);
      cuts += cut(codes[list[i]]);
    }
    block_cut_[b] = cuts;
  });
  return !too_many;
}

// The old triangles of the changed slots free their places, and every corner whose local edge
// the new case does not cut the same way (below, above) is released. Such a vertex is dead: one of
// its edge's ends crossed the iso-value, so every tetrahedron around the edge changed case and
// none keeps it; a corner whose edge is still cut that way lives on in every tetrahedron around
// it. Several changed tetrahedra report a dead vertex; sort_ids drops the repeats.
void ExtractorState::release_changed() {
  const std::size_t blocks = changed_.size();
  freed_triangle_parts_.resize(blocks);
  released_parts_.resize(blocks);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& freed = freed_triangle_parts_[b];
    auto& dead = released_parts_[b];
    freed.clear();
    dead.clear();
    const auto& list = changed_[b];
    for (std::size_t i = 0; i < list.size(); ++i) {
      if (i + 16 < list.size()) prefetch(&slot_tris[list[i + 16]]);
      if (i + 8 < list.size())
        for (std::uint32_t k : slot_tris[list[i + 8]])
          if (k != kNone) prefetch(&mesh.triangles[k]);
      const Case& was = kCases[changed_old_[b][i]];
      const unsigned now = codes[list[i]];
      for (int q = 0; q < was.triangles; ++q) {
        const std::uint32_t k = slot_tris[list[i]][q];
        freed.push_back(k);
        for (int e = 0; e < 3; ++e)
          if (const LocalEdge le = was.tri[q][e]; ((now >> le.below) & 1) || !((now >> le.above) & 1)) dead.push_back(mesh.triangles[k][e]);
      }
    }
  });
  concatenate(released_parts_, dead_);
  sort_ids(dead_, old_vertices_, bitmap_);
}

// The changed slots split into those still cut (to re-march, block order, with their old case)
// and those that left.
void ExtractorState::split_work() {
  const std::size_t blocks = changed_.size();
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
      if (cut(codes[s])) {
        work_old_[w] = changed_old_[b][i];
        work_[w++] = s;
      } else {
        leaving_[l++] = s;
      }
    }
  });
}

// New triangles for the work (re-marched slots, then entered tetrahedra), by chunks of consecutive
// work: a corner on an edge the tetrahedron cut before (the same local edge, cut the same way, in
// the old case's table) keeps that vertex, read from the old triangle's corner (corners lie in
// table order); edges cut for the first time are numbered as one sequential pass would
// (number_chunk_edges, as in the fresh march): provisionally old_vertices_ + k for the k-th.
void ExtractorState::march_work() {
  const std::size_t R = work_.size(), E = entered_.size(), W = R + E;
  if (6 * W >= kNewBit) throw std::length_error("extractor: too many mesh elements");
  marched = W;
  auto work_tet = [&](std::size_t w) { return w < R ? active[work_[w]] : entered_[w - R].tet; };
  auto work_code = [&](std::size_t w) { return w < R ? codes[work_[w]] : entered_[w - R].code; };
  const std::size_t C =
      16 * W < options.parallel_min_tetrahedra ? 1 : static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  chunks_.resize(C);
  chunk_tris_.resize(C);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    auto& ch = chunks_[c];
    auto& tris = chunk_tris_[c];
    ch.order.clear();
    ch.pending.clear();
    tris.clear();
    const std::size_t w_end = block_begin(W, C, c + 1);
    ch.map = std::make_shared<EdgeMap>((w_end - block_begin(W, C, c)) / 2 + 16, ch.slots);
    for (std::size_t w = block_begin(W, C, c); w < w_end; ++w) {
      if (w + 32 < std::min(w_end, R)) {
        prefetch(&active[work_[w + 32]]);
        prefetch(&codes[work_[w + 32]]);
        prefetch(&slot_tris[work_[w + 32]]);
      }
      if (w + 16 < w_end) {
        prefetch(&grid.tets[work_tet(w + 16)]);
        if (w + 16 < R)
          for (std::uint32_t k : slot_tris[work_[w + 16]])
            if (k != kNone) prefetch(&mesh.triangles[k]);
      }
      const auto& t = grid.tets[work_tet(w)];
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
            old_vertex[olds++] = mesh.triangles[slot_tris[work_[w]][q]][e];
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
  chunk_tri_offset_.assign(C + 1, 0);
  for (std::size_t c = 0; c < C; ++c) chunk_tri_offset_[c + 1] = chunk_tri_offset_[c] + chunk_tris_[c].size();
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {  // provisional ids: new ones after the old vertices
    const auto& ch = chunks_[c];
    for (auto& tri : chunk_tris_[c])
      for (auto& v : tri)
        if (v & kNewBit) v = old_vertices_ + ch.global[ch.local[v & ~kNewBit]];
  });
}

// Vertex places: new vertices take the lowest places of dead ones, then the end; live vertices
// from the end fill the holes that remain below the new count.
void ExtractorState::place_vertices() {
  const std::size_t N = new_keys_.size();
  vertex_places_.plan(dead_, N, old_vertices_);
  const std::size_t V = vertex_places_.count;
  vertex_moved_to_.assign(old_vertices_ > V ? old_vertices_ - V : 0, kNone);
  apply_moves(vertex_places_, [&](std::uint32_t from, std::uint32_t to) {
    vertex_moved_to_[from - V] = to;
    keys[to] = keys[from];
    if (cache_ends) ends[to] = ends[from];
  });
  keys.resize(V);
  if (cache_ends) ends.resize(V);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, N, 1024), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      if (cache_ends && k + 8 < r.end()) prefetch_edge(grid, new_keys_[k + 8]);
      const std::uint32_t v = vertex_places_.place_of_new(k);
      keys[v] = new_keys_[k];
      if (cache_ends) ends[v] = gather_edge(grid, new_keys_[k]);
    }
  });
}

// A corner's vertex after place_vertices: provisional new ids map to their places, old vertices
// that moved from the end to their holes, the rest stay.
std::uint32_t ExtractorState::final_vertex(std::uint32_t p) const {
  if (p >= old_vertices_) return vertex_places_.place_of_new(p - old_vertices_);
  return p >= vertex_places_.count ? vertex_moved_to_[p - vertex_places_.count] : p;
}

// Slots: the entered tetrahedra take the slots of those that left, then the end; live slots from
// the end fill the remaining holes (their triangles learn their new owner).
void ExtractorState::place_slots() {
  const std::size_t E = entered_.size();
  slot_places_.plan(leaving_, E, old_slots_);
  const std::size_t n = slot_places_.count;
  entered_slot_.resize(E);
  if (n > old_slots_) {
    active.resize(n);
    codes.resize(n);
    gaps.resize(n);
    slot_tris.resize(n);
  }
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, E, 4096), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      const std::uint32_t s = slot_places_.place_of_new(k);
      active[s] = entered_[k].tet;
      codes[s] = entered_[k].code;
      gaps[s] = entered_[k].gap;
      entered_slot_[k] = s;
    }
  });
  if (!slot_places_.moves.empty()) {
    slot_moved_to_.assign(old_slots_ - n, kNone);
    apply_moves(slot_places_, [&](std::uint32_t from, std::uint32_t to) {
      active[to] = active[from];
      codes[to] = codes[from];
      gaps[to] = gaps[from];
      slot_tris[to] = slot_tris[from];
      slot_moved_to_[from - n] = to;
      for (std::uint32_t k : slot_tris[to])
        if (k != kNone) owner[k] = to;  // only unchanged slots keep their old triangles; the others are rewritten
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, work_.size(), 16384), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i)  // re-marched slots that moved
        if (work_[i] >= n) work_[i] = slot_moved_to_[work_[i] - n];
    });
  }
  active.resize(n);
  codes.resize(n);
  gaps.resize(n);
  slot_tris.resize(n);
}

// Triangle places: the new triangles (in work order) take the freed places ascending, then the
// end; live triangles from the end fill the remaining holes.
void ExtractorState::place_triangles() {
  concatenate(freed_triangle_parts_, freed_triangles_);
  sort_ids(freed_triangles_, old_triangles_, bitmap_);  // no repeats: each triangle had one owner
  const std::size_t C = chunk_tris_.size(), R = work_.size(), W = R + entered_.size();
  triangle_places_.plan(freed_triangles_, chunk_tri_offset_[C], old_triangles_);
  const std::size_t T = triangle_places_.count;
  if (T > old_triangles_) {
    mesh.triangles.resize(T);
    owner.resize(T);
  }
  // Two moves may belong to one slot (its two triangles): its entries are touched atomically.
  apply_moves(triangle_places_, [&](std::uint32_t from, std::uint32_t to) {
    mesh.triangles[to] = mesh.triangles[from];
    const std::uint32_t s = owner[from];
    owner[to] = s;
    for (auto& k : slot_tris[s])
      if (std::atomic_ref<std::uint32_t> a(k); a.load(std::memory_order_relaxed) == from) a.store(to, std::memory_order_relaxed);
  });
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    std::size_t j = chunk_tri_offset_[c];
    for (std::size_t w = block_begin(W, C, c); w < block_begin(W, C, c + 1); ++w) {
      const std::uint32_t s = w < R ? work_[w] : entered_slot_[w - R];
      auto& mine = slot_tris[s];
      mine = {kNone, kNone};
      for (int q = 0; q < kCases[codes[s]].triangles; ++q, ++j) {
        const std::uint32_t p = triangle_places_.place_of_new(j);
        const auto& tri = chunk_tris_[c][j - chunk_tri_offset_[c]];
        mesh.triangles[p] = {final_vertex(tri[0]), final_vertex(tri[1]), final_vertex(tri[2])};
        owner[p] = s;
        mine[q] = p;
      }
    }
  });
  mesh.triangles.resize(T);
  owner.resize(T);
}

// Unchanged triangles that use a vertex moved in place_vertices learn its new place; then every
// vertex is interpolated at the new iso-value.
void ExtractorState::finish_vertices(double iso) {
  const std::size_t V = vertex_places_.count, T = mesh.triangles.size();
  if (!vertex_moved_to_.empty())
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 16384), [&](const auto& r) {
      for (std::size_t k = r.begin(); k < r.end(); ++k)
        for (auto& v : mesh.triangles[k])
          if (v >= V) v = vertex_moved_to_[v - V];
    });
  if (cache_ends)
    interpolate_vertices(ends, iso, mesh);
  else
    interpolate_vertices(grid, keys, iso, mesh);
}

}  // namespace adaptiso::detail

namespace adaptiso {

Extractor::Extractor(std::shared_ptr<const PreparedGrid> grid, const ExtractorOptions& options) {
  if (!grid) throw std::invalid_argument("Extractor: no grid");
  // Vertices without tetrahedra: loaded with GridParts::hierarchy, whose surfaces would come out empty.
  if (grid->grid.tet_count() == 0 && grid->grid.vertex_count() > 0)
    throw std::invalid_argument("Extractor: the grid was loaded without its tetrahedra (GridParts::hierarchy): use HierarchyQuery");
  // Tetrahedra without an index (GridParts::tetrahedra): every tree, even one of no entries, has a root.
  if (grid->grid.tet_count() > 0 && grid->index.nodes.empty())
    throw std::invalid_argument("Extractor: the grid was loaded without its index (GridParts::tetrahedra): load it whole");
  state_ = std::make_unique<detail::ExtractorState>(std::move(grid), options);
}
Extractor::~Extractor() = default;
Extractor::Extractor(Extractor&&) noexcept = default;
Extractor& Extractor::operator=(Extractor&&) noexcept = default;

const Mesh& Extractor::mesh() const { return state_->clipped_valid ? state_->clipped : state_->mesh; }
const std::vector<std::uint32_t>& Extractor::active() const { return state_->active; }

namespace {

// The unclipped mesh's march order (see triangles_in_march_order).
const std::vector<std::uint32_t>& march_order(detail::ExtractorState& s) {
  const std::size_t T = s.mesh.triangle_count();
  auto& order = s.march_order;
  detail::resize_big(order, T);
  // After a fresh march the triangles are in its order (a cancelled extraction leaves no surface).
  if (!s.incremental || !s.valid) {
    std::iota(order.begin(), order.end(), std::uint32_t{0});
    return order;
  }
  // By tetrahedron: a stable sort on the id in the high half of (tet << 32 | triangle); then each
  // tetrahedron's first triangle before its second, as the march wrote them (a step's compaction
  // can move a second triangle from past the new end into a hole before its first).
  auto& keys = s.march_order_keys;
  detail::resize_big(keys, T);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 1 << 16), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) keys[k] = std::uint64_t{s.active[s.owner[k]]} << 32 | k;
  });
  detail::radix_sort(keys, s.march_order_scratch, 32);
  for (std::size_t i = 0; i < T; ++i) order[i] = static_cast<std::uint32_t>(keys[i]);
  for (std::size_t i = 0; i + 1 < T; ++i)
    if (const std::uint32_t slot = s.owner[order[i]]; s.owner[order[i + 1]] == slot && s.slot_tris[slot][0] == order[i + 1])
      std::swap(order[i], order[i + 1]);
  return order;
}

}  // namespace

const std::vector<std::uint32_t>& Extractor::triangles_in_march_order() const {
  auto& s = *state_;  // the answer and the sort's buffers are scratch of the state
  const auto& order = march_order(s);
  if (!s.clipped_valid) return order;
  // A clipped triangle's pieces are consecutive: each triangle in order gives its pieces.
  auto& clipped = s.clipped_order;
  clipped.clear();
  clipped.reserve(s.clipped.triangle_count());
  for (std::uint32_t t : order)
    for (std::uint32_t k = s.clip.first[t]; k < s.clip.first[t + 1]; ++k) clipped.push_back(k);
  return clipped;
}

const std::vector<std::uint64_t>& Extractor::vertex_edges() const {
  auto& s = *state_;
  if (!s.clipped_valid) return s.keys;
  detail::carry_vertex_keys(s.clip, s.keys, kClippedVertex, s.clipped_keys);
  return s.clipped_keys;
}
bool Extractor::last_was_incremental() const { return state_->incremental; }
const PreparedGrid& Extractor::grid() const { return *state_->prepared; }

ExtractStats Extractor::extract(double iso, const std::atomic<bool>* cancel) {
  using Clock = std::chrono::steady_clock;
  auto& s = *state_;
  ExtractStats st;
  st.iso = iso;
  st.in_range = iso >= s.grid.source.min && iso <= s.grid.source.max;
  const auto t0 = Clock::now();
  // Above this many entering entries a fresh march is cheaper than a step.
  s.sweep.entering_limit = s.options.max_changed_fraction >= 1
                               ? ~std::size_t{0}
                               : static_cast<std::size_t>(s.options.max_changed_fraction * static_cast<double>(s.active.size())) + 1024;
  sweep_to(s.tree, s.grid, s.sweep, iso);
  const auto t1 = Clock::now();
  // Should anything below throw, the state is half updated: the next call then starts afresh.
  const bool had_previous = s.valid;
  s.valid = false;
  s.clipped_valid = false;
  s.scratch.cancel = cancel;
  s.checkpoint();
  s.incremental = had_previous && s.step(iso);
  if (!s.incremental) s.fresh(iso);
  s.checkpoint();  // a step's last stage, or a fresh march's slots
  s.valid = true;
  s.scratch.cancel = nullptr;
  s.clipped_valid = detail::clip_to_volume_box(s.mesh, s.grid.source, s.clipped, &s.clip);
  const auto t2 = Clock::now();
  st.walked = s.sweep.walked;
  st.active = s.active.size();
  st.marched = s.marched;
  st.triangles = mesh().triangle_count();
  st.vertices = mesh().vertex_count();
  st.incremental = s.incremental;
  st.sweep_seconds = std::chrono::duration<double>(t1 - t0).count();
  st.march_seconds = std::chrono::duration<double>(t2 - t1).count();
  return st;
}

std::string to_json(const ExtractStats& s) {
  nlohmann::json j = {{"iso", s.iso},
                      {"in_range", s.in_range},
                      {"triangles", s.triangles},
                      {"vertices", s.vertices},
                      {"active_tetrahedra", s.active},
                      {"walked_entries", s.walked},
                      {"marched_tetrahedra", s.marched},
                      {"incremental", s.incremental},
                      {"seconds", s.sweep_seconds + s.march_seconds},
                      {"sweep_seconds", s.sweep_seconds},
                      {"march_seconds", s.march_seconds}};
  if (s.scanned) j["scanned"] = true;
  return j.dump();
}

ExtractStats extract_scanned(const TetGrid& grid, double iso, Mesh& mesh, const std::atomic<bool>* cancel) {
  using Clock = std::chrono::steady_clock;
  ExtractStats st;
  st.iso = iso;
  st.in_range = iso >= grid.source.min && iso <= grid.source.max;
  st.scanned = true;
  const auto t0 = Clock::now();
  std::vector<std::uint32_t> active;
  scan_active(grid, iso, active);
  const auto t1 = Clock::now();
  MarchOptions o;
  o.cancel = cancel;
  mesh = march_tetrahedra(grid, active, iso, o);
  st.active = st.marched = active.size();
  st.walked = grid.tet_count();
  st.triangles = mesh.triangle_count();
  st.vertices = mesh.vertex_count();
  st.sweep_seconds = std::chrono::duration<double>(t1 - t0).count();
  st.march_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  return st;
}

}  // namespace adaptiso
