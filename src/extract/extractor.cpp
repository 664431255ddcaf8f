// The Extractor: sweeping simplices plus marching tetrahedra with an incremental update of the
// mesh for small changes of iso-value (see extract.hpp).
//
// After a step from c0 to c1 a tetrahedron keeps its triangles, and every corner keeps its cut
// edge, unless one of its vertices lies between c0 and c1 (its case code changes). Such tetrahedra,
// and those that became active, are marched again; an edge they cut that was already cut is
// found among the same tetrahedron's old corners (a tetrahedron inactive before had no cut edge),
// so only edges cut for the first time need a hash map. Vertices are then renumbered by first use
// in parallel, which reproduces the fresh numbering exactly, and all positions are interpolated.
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>

#include "adaptiso/extract.hpp"
#include "extract/march_internal.hpp"

namespace adaptiso {
namespace {
constexpr std::uint32_t kNone = ~std::uint32_t{0};
}

void Extractor::fresh(double iso) {
  march_tetrahedra(grid_, active_, iso, mesh_, &scratch_);
  codes_.swap(scratch_.codes);
  first_tri_.swap(scratch_.first_triangle);
  order_.swap(scratch_.order);
}

bool Extractor::update(double iso) {
  const TetGrid& g = grid_;
  const std::size_t n = active_.size(), n_old = prev_active_.size();
  // Match every active tetrahedron with its previous entry (both lists ascending).
  old_index_.resize(n);
  for (std::size_t i = 0, j = 0; i < n; ++i) {
    while (j < n_old && prev_active_[j] < active_[i]) ++j;
    old_index_[i] = (j < n_old && prev_active_[j] == active_[i]) ? static_cast<std::uint32_t>(j) : kNone;
  }
  codes_.resize(n);
  // New codes; the entries to march again (new, or case changed) collected per block, in order.
  const std::size_t blocks = std::max<std::size_t>(1, std::min<std::size_t>(256, n / 16384));
  changed_.resize(blocks);
  tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
    auto& list = changed_[b];
    list.clear();
    for (std::size_t i = n * b / blocks; i < n * (b + 1) / blocks; ++i) {
      codes_[i] = tet_code(g, active_[i], iso);
      if (old_index_[i] == kNone || prev_codes_[old_index_[i]] != codes_[i]) list.push_back(static_cast<std::uint32_t>(i));
    }
  });
  std::size_t changed = 0;
  for (const auto& l : changed_) changed += l.size();
  if (static_cast<double>(changed) > max_changed_fraction * static_cast<double>(n)) return false;
  first_tri_.resize(n + 1);
  first_tri_[0] = 0;
  for (std::size_t i = 0; i < n; ++i) first_tri_[i + 1] = first_tri_[i] + kCases[codes_[i]].triangles;
  const std::size_t T = first_tri_[n];
  const std::uint32_t V_old = static_cast<std::uint32_t>(prev_order_.size());
  // Provisional corner ids: old vertex ids, or V_old + k for the k-th edge cut for the first time.
  prov_.resize(T);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8192), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const std::uint32_t j = old_index_[i];
      if (j != kNone && prev_codes_[j] == codes_[i])
        std::copy(prev_tris_.begin() + static_cast<std::ptrdiff_t>(prev_first_tri_[j]),
                  prev_tris_.begin() + static_cast<std::ptrdiff_t>(prev_first_tri_[j + 1]),
                  prov_.begin() + static_cast<std::ptrdiff_t>(first_tri_[i]));
    }
  });
  new_keys_.clear();
  {
    // Changed tetrahedra, sequentially (few for a small step): look up old corners, hash new edges.
    std::vector<std::uint64_t> slots;
    std::vector<std::uint32_t> ids;
    EdgeMap fresh_edges(64, slots, ids);
    for (const auto& list : changed_)
      for (std::uint32_t i : list) {
      const std::uint32_t j = old_index_[i];
      const auto& t = g.tets[active_[i]];
      const Case& c = kCases[codes_[i]];
      for (int q = 0; q < c.triangles; ++q)
        for (int e = 0; e < 3; ++e) {
          const std::uint64_t key = edge_key(t[c.tri[q][e].below], t[c.tri[q][e].above]);
          std::uint32_t id = kNone;
          if (j != kNone)
            for (std::uint64_t k = prev_first_tri_[j]; k < prev_first_tri_[j + 1] && id == kNone; ++k)
              for (std::uint32_t old : prev_tris_[k])
                if (prev_order_[old] == key) id = old;
          if (id == kNone) id = V_old + fresh_edges.find_or_add(key, new_keys_);
          prov_[first_tri_[i] + q][e] = id;
        }
      }
  }
  // Renumber by first use, in parallel: an id belongs to the first chunk of triangles using it;
  // owned ids are numbered chunk by chunk in local first-use order (= the sequential order).
  const std::size_t P = V_old + new_keys_.size();
  const std::size_t C = T < scratch_.parallel_min_triangles ? 1 : static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  first_chunk_.assign(P, static_cast<std::uint32_t>(C));
  rank_.assign(P, kNone);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    for (std::size_t i = T * c / C; i < T * (c + 1) / C; ++i)
      for (std::uint32_t p : prov_[i]) {
        std::atomic_ref<std::uint32_t> f(first_chunk_[p]);
        std::uint32_t cur = f.load(std::memory_order_relaxed);
        while (cur > c && !f.compare_exchange_weak(cur, static_cast<std::uint32_t>(c), std::memory_order_relaxed)) {
        }
      }
  });
  std::vector<std::size_t> owned(C + 1, 0);
  tbb::parallel_for(std::size_t{0}, C, [&](std::size_t c) {
    std::uint32_t next = 0;
    for (std::size_t i = T * c / C; i < T * (c + 1) / C; ++i)
      for (std::uint32_t p : prov_[i])
        if (first_chunk_[p] == c && rank_[p] == kNone) rank_[p] = next++;
    owned[c + 1] = next;
  });
  for (std::size_t c = 0; c < C; ++c) owned[c + 1] += owned[c];
  order_.resize(owned[C]);
  mesh_.triangles.resize(T);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, P, 16384), [&](const auto& r) {
    for (std::size_t p = r.begin(); p < r.end(); ++p)
      if (first_chunk_[p] < C) {
        rank_[p] += static_cast<std::uint32_t>(owned[first_chunk_[p]]);
        order_[rank_[p]] = p < V_old ? prev_order_[p] : new_keys_[p - V_old];
      }
  });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 16384), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i)
      for (int e = 0; e < 3; ++e) mesh_.triangles[i][e] = rank_[prov_[i][e]];
  });
  interpolate_vertices(g, order_, iso, mesh_);
  return true;
}

ExtractStats Extractor::extract(double iso) {
  using Clock = std::chrono::steady_clock;
  ExtractStats st;
  st.iso = iso;
  st.in_range = iso >= grid_.source.min && iso <= grid_.source.max;
  auto t0 = Clock::now();
  scratch_.parallel_min_triangles = parallel_min_triangles;
  sweep_to(tree_, grid_, state_, iso);
  // Keep the previous extraction for the incremental update. Should anything below throw, the
  // buffers are half swapped: the next call then starts afresh.
  const bool had_previous = valid_;
  valid_ = false;
  active_.swap(prev_active_);
  codes_.swap(prev_codes_);
  first_tri_.swap(prev_first_tri_);
  order_.swap(prev_order_);
  mesh_.triangles.swap(prev_tris_);
  active_.clear();
  active_tetrahedra(tree_, state_, active_);
  sort_tetrahedra(active_, grid_.tet_count(), bitmap_);
  auto t1 = Clock::now();
  incremental_ = had_previous && update(iso);
  if (!incremental_) fresh(iso);
  valid_ = true;
  auto t2 = Clock::now();
  st.walked = state_.walked;
  st.active = active_.size();
  st.triangles = mesh_.triangle_count();
  st.vertices = mesh_.vertex_count();
  st.sweep_seconds = std::chrono::duration<double>(t1 - t0).count();
  st.march_seconds = std::chrono::duration<double>(t2 - t1).count();
  return st;
}

}  // namespace adaptiso
