// adaptiso/extract.hpp — iso-surfaces from the tetrahedral grid: marching tetrahedra (Lürig &
// Ertl §2.4) over the active tetrahedra found by sweeping simplices.
//
// Rule for ties: a vertex whose value equals the iso-value counts as above it, so a tetrahedron
// is cut iff min < iso <= max, and each cut edge joins a vertex below and one at or above. Each cut
// grid edge gives exactly one mesh vertex (shared by every triangle using it), so a closed surface
// is watertight and 2-manifold. Cut points are kept at least 1/1024 of the edge length away from
// the edge's ends, so no triangle collapses when vertices lie exactly on the iso-value (the surface
// then passes within that distance of them, as if the iso-value were lowered infinitesimally).
// Normals are the linearly interpolated vertex gradients, normalised and negated: they point
// towards lower values (outward for a bright object); triangles are counter-clockwise seen from
// that side. Output order of march_tetrahedra: triangles in the order of the given tetrahedra,
// vertices by first use. An Extractor's first extraction is that order over the active tetrahedra
// sorted by id; after incremental steps its triangle order and vertex numbering depend on the
// history of iso-values (deterministically, whatever the thread count; see Extractor).
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/mesh.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

// Reusable buffers of march_tetrahedra (so repeated extractions do not fault in fresh pages).
class EdgeMap;
struct MarchScratch {
  struct Chunk {
    std::vector<std::uint64_t> slots, order, pending;
    std::vector<std::uint32_t> local, owner, owner_id, global;
    std::shared_ptr<EdgeMap> map;
    std::size_t owned = 0;
  };
  std::vector<std::uint8_t> codes;
  std::vector<std::uint64_t> first_triangle, order;
  std::vector<Chunk> chunks;
  std::size_t parallel_min_triangles = 65536;  // below this many tetrahedra (about as many triangles), one chunk (tests lower it)
};

// Marching tetrahedra over the given tetrahedra (each must be active at iso). Replaces mesh.
void march_tetrahedra(const TetGrid& grid, const std::vector<std::uint32_t>& active, double iso, Mesh& mesh,
                      MarchScratch* scratch = nullptr);

// Sorts ids (tetrahedra, triangles or vertices, all below `bound`) ascending through a bitmap,
// dropping repeats (O(bound/64 + n), parallel): much cheaper than a comparison sort.
void sort_ids(std::vector<std::uint32_t>& ids, std::size_t bound, std::vector<std::uint64_t>& bitmap);

struct ExtractStats {
  double iso = 0;
  std::size_t active = 0, triangles = 0, vertices = 0;
  std::uint64_t walked = 0;  // list entries the sweep visited
  std::size_t marched = 0;   // tetrahedra marched: all active ones afresh, the entered or changed ones in a step
  double sweep_seconds = 0, march_seconds = 0;
  bool in_range = true;      // false when iso lies outside [min, max] of the grid (empty mesh)
};

// One client's extraction. It keeps its sweep state and its last mesh: after a small change of
// iso-value only the tetrahedra that entered, left or changed case are marched again (found from
// the entries the sweep walked and a per-tetrahedron interval of iso-values that keep its case),
// the rest of the mesh stays in place and only the vertex positions are interpolated anew. Every
// vertex has the same position and normal, bit for bit, and the mesh the same triangles, as a
// fresh march of the same iso-value; the order is first use after a fresh march and then stable:
// an incremental step leaves unchanged triangles and vertices where they are, puts new ones into
// freed places and moves entries from the end into the remaining holes (deterministic for a given
// history of iso-values, whatever the thread count).
struct EdgeEnds;  // a cut edge's gathered ends (internal)
class Extractor {
public:
  Extractor(const TetGrid& grid, const IntervalTree& tree);
  ~Extractor();
  Extractor(const Extractor&) = delete;
  Extractor& operator=(const Extractor&) = delete;
  ExtractStats extract(double iso);
  const Mesh& mesh() const { return mesh_; }
  // The active tetrahedra of the last extract, in slot order (ascending after a fresh march).
  const std::vector<std::uint32_t>& active() const { return active_; }
  // Per mesh vertex, its cut edge as (below vertex << 32 | above vertex), grid vertex ids.
  const std::vector<std::uint64_t>& vertex_edges() const { return keys_; }
  const SweepState& state() const { return state_; }
  bool last_was_incremental() const { return incremental_; }
  double max_changed_fraction = 0.25;  // above this share of re-marched tetrahedra, march afresh
  std::size_t parallel_min_triangles = 65536;  // below this, number vertices in one chunk (tests lower it)
  // Up to this many active tetrahedra the mesh vertices' edge ends are kept (64 bytes per vertex)
  // so a step re-interpolates from one record each; larger surfaces read the grid instead.
  std::size_t edge_cache_max_tetrahedra = 6'000'000;

  struct Gap {  // the case of a tetrahedron stays the same for iso-values in (below, above]
    float below, above;  // rounded inwards: a value close to the ends only costs a needless re-march
  };

private:
  bool update(double iso);  // the incremental path; false when a fresh march is cheaper
  std::size_t marched_ = 0;
  void fresh(double iso);

  const TetGrid& grid_;
  const IntervalTree& tree_;
  SweepState state_;
  Mesh mesh_;
  double iso_ = 0;  // of the last extraction
  bool valid_ = false, incremental_ = false;
  // Per slot (one per active tetrahedron): its id, case, case interval and triangle positions.
  std::vector<std::uint32_t> active_;
  std::vector<std::uint8_t> codes_;
  std::vector<Gap> gaps_;
  std::vector<std::array<std::uint32_t, 2>> slot_tris_;
  std::vector<std::uint32_t> owner_;  // per triangle, its slot
  std::vector<std::uint64_t> keys_;   // per vertex, its cut edge
  std::vector<EdgeEnds> ends_;        // per vertex, for re-interpolation (when cache_ends_)
  bool cache_ends_ = false;
  // Scratch of the incremental step, kept to avoid faulting in fresh pages every step.
  struct Entered {
    std::uint32_t tet;
    std::uint8_t code;
    Gap gap;
  };
  std::vector<Entered> entered_;
  std::vector<std::uint32_t> entered_slot_, work_, leaving_, free_, dead_, tail_, slot_tail_;
  std::vector<std::uint64_t> bitmap_, new_keys_;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> moves_;
  std::vector<std::vector<std::uint32_t>> changed_, free_parts_;
  std::vector<std::vector<std::uint8_t>> changed_old_;  // per changed slot, its case before the step
  std::vector<std::uint8_t> work_old_;
  std::vector<std::vector<Entered>> entered_parts_;
  std::vector<std::size_t> block_cut_;
  std::vector<MarchScratch::Chunk> chunks_;
  std::vector<std::vector<std::array<std::uint32_t, 3>>> chunk_tris_;
  MarchScratch scratch_;
};

}  // namespace adaptiso
