// The Extractor's state (see extractor.hpp): the sweep position, the mesh, one slot per active
// tetrahedron, and the scratch of the incremental step, kept between steps so they do not fault in
// fresh pages. Internal to src/extract/.
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "adaptiso/extractor.hpp"
#include "adaptiso/interval_tree.hpp"
#include "extract/box_clip.hpp"
#include "extract/march_detail.hpp"

namespace adaptiso::detail {

// Reuse of freed places in one of the Extractor's arrays (vertices, slots, triangles): of
// [0, old_count), `freed` (ascending) are released and `fill` new entries arrive. The k-th new
// entry goes to freed[k] or, past the freed ones, to the end; when fewer arrive than were freed,
// the live entries from the end move into the remaining holes below the new count (`moves`, as
// (from, to) pairs, each from and to once, so they can be applied in parallel).
struct Compaction {
  const std::vector<std::uint32_t>* freed = nullptr;
  std::size_t old_count = 0, count = 0;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> moves;

  void plan(const std::vector<std::uint32_t>& freed_places, std::size_t fill, std::size_t old_n);
  std::uint32_t place_of_new(std::size_t k) const {
    const auto& f = *freed;
    return k < f.size() ? f[k] : static_cast<std::uint32_t>(old_count + (k - f.size()));
  }
};

// A tetrahedron that became active in a step, with its case and case interval.
struct Entered {
  std::uint32_t tet;
  std::uint8_t code;
  Gap gap;
};

struct ExtractorState {
  ExtractorState(std::shared_ptr<const PreparedGrid> p, const ExtractorOptions& o);

  std::shared_ptr<const PreparedGrid> prepared;  // kept alive as long as the state refers to it
  const TetGrid& grid;
  const IntervalTree& tree;
  ExtractorOptions options;
  SweepState sweep;
  Mesh mesh;
  // incremental: the last extract stepped, so the triangles are not in a fresh march's order.
  bool valid = false, incremental = false;
  // Extractor::triangles_in_march_order's answer and its sort's buffers, kept between calls.
  std::vector<std::uint32_t> march_order;
  std::vector<std::uint64_t> march_order_keys, march_order_scratch;
  std::size_t marched = 0;
  // On a padded lattice, the mesh clipped to the volume's box (box_clip.hpp) when it reaches past
  // it: what Extractor::mesh() then gives. `mesh` stays whole for the next step.
  bool clipped_valid = false;
  Mesh clipped;
  ClipMap clip;
  std::vector<std::uint32_t> clipped_order;
  std::vector<std::uint64_t> clipped_keys;

  // Per slot (one per active tetrahedron): its id, case, case interval and triangle places.
  std::vector<std::uint32_t> active;
  std::vector<std::uint8_t> codes;
  std::vector<Gap> gaps;
  std::vector<std::array<std::uint32_t, 2>> slot_tris;
  std::vector<std::uint32_t> owner;  // per triangle, its slot
  std::vector<std::uint64_t> keys;   // per vertex, its cut edge
  std::vector<EdgeEnds> ends;        // per vertex, for re-interpolation (when cache_ends)
  bool cache_ends = false;
  MarchScratch scratch;  // its cancel flag is the extract's under way, read by the march too

  // Between stages: throws ExtractCancelled once the flag is raised (the caller has marked the
  // state invalid, so the next extract starts afresh).
  void checkpoint() const {
    if (scratch.cancelled()) throw ExtractCancelled();
  }

  void fresh(double iso);
  bool step(double iso);  // the incremental path; false when a fresh march is cheaper

private:
  // The steps of an incremental update, in order, each over the scratch below.
  bool collect_entered(double iso, double limit);
  bool find_changed(double iso, double limit);
  void release_changed();
  void split_work();
  void march_work();
  void place_vertices();
  void place_slots();
  void place_triangles();
  void finish_vertices(double iso);
  std::uint32_t final_vertex(std::uint32_t provisional) const;

  // Scratch of the incremental step.
  std::size_t old_slots_ = 0, old_triangles_ = 0;
  std::uint32_t old_vertices_ = 0;
  std::vector<Entered> entered_;
  std::vector<std::vector<Entered>> entered_parts_;
  // Per block of slots (in slot order): the slots whose case changed, their old cases, how many
  // are still cut, the triangle places they free and the vertices they release.
  std::vector<std::vector<std::uint32_t>> changed_, freed_triangle_parts_, released_parts_;
  std::vector<std::vector<std::uint8_t>> changed_old_;
  std::vector<std::size_t> block_cut_;
  // The work: changed slots still cut (with their old case), then the entered tetrahedra.
  std::vector<std::uint32_t> work_, leaving_, entered_slot_;
  std::vector<std::uint8_t> work_old_;
  std::vector<MarchChunk> chunks_;
  std::vector<std::vector<std::array<std::uint32_t, 3>>> chunk_tris_;
  std::vector<std::size_t> chunk_tri_offset_;
  std::vector<std::uint64_t> new_keys_, bitmap_;
  std::vector<std::uint32_t> dead_, freed_triangles_;
  Compaction vertex_places_, slot_places_, triangle_places_;
  std::vector<std::uint32_t> vertex_moved_to_, slot_moved_to_;  // where an entry from the end went
};

}  // namespace adaptiso::detail
