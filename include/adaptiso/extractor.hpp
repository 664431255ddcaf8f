// adaptiso/extractor.hpp — one client's iso-surface browsing over a prepared grid: sweeping
// simplices (the interval tree, §2.4) to find the tetrahedra the surface cuts, marching
// tetrahedra (marching_tetrahedra.hpp, same conventions) to cut them, and incremental updates.
//
// After a small change of iso-value only the tetrahedra that entered, left or changed case are
// marched again (found from the entries the sweep walked and a per-tetrahedron interval of
// iso-values that keep its case); the rest of the mesh stays in place and only the vertex
// positions are interpolated anew. Every vertex has the same position and normal, bit for bit,
// and the mesh the same triangles, as a fresh march of the same iso-value. The first extraction is
// a fresh march of the active tetrahedra sorted by id (triangles in that order, vertices by first
// use); after incremental steps the order is stable: unchanged triangles and vertices stay where
// they are, new ones take freed places and entries from the end move into the remaining holes, so
// triangle order and vertex numbering depend on the history of iso-values (deterministically,
// whatever the thread count).
//
// The Extractor shares ownership of its grid, so the grid outlives every client that uses it.
// One Extractor is used by one thread at a time; any number of Extractors may share a grid.
//
// extract() may be given a cancel flag, read between its stages (sweep, collecting, marching,
// placing): once raised, extract throws ExtractCancelled within one stage, and the Extractor's
// next extract marches afresh. The viewer cancels background work this way when a page asks.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "adaptiso/marching_tetrahedra.hpp"
#include "adaptiso/mesh.hpp"
#include "adaptiso/prepared_grid.hpp"

namespace adaptiso {

namespace detail {
struct ExtractorState;
}

struct ExtractorOptions {
  double max_changed_fraction = 0.25;           // above this share of re-marched tetrahedra, march afresh
  std::size_t parallel_min_tetrahedra = 65536;  // below this, one thread numbers the vertices
  // Up to this many active tetrahedra the mesh vertices' edge ends are kept (64 bytes per vertex)
  // so a step re-interpolates from one record each; larger surfaces read the grid instead.
  std::size_t edge_cache_max_tetrahedra = 6'000'000;
};

struct ExtractStats {
  double iso = 0;
  std::size_t active = 0, triangles = 0, vertices = 0;
  std::uint64_t walked = 0;  // list entries the sweep visited
  std::size_t marched = 0;   // tetrahedra marched: all active ones afresh, the entered or changed ones in a step
  double sweep_seconds = 0, march_seconds = 0;
  bool in_range = true;      // false when iso lies outside [min, max] of the grid (empty mesh)
  bool incremental = false;  // the mesh was updated from the previous one
  bool scanned = false;      // found by a scan of every tetrahedron, without the index (extract_scanned)
};

// One JSON object, the figures the command line's --json and Python's Mesh.stats give: iso,
// in_range, triangles, vertices, active_tetrahedra, walked_entries, marched_tetrahedra,
// incremental, seconds (sweep and march), sweep_seconds, march_seconds; and "scanned": true for
// a surface extract_scanned found.
std::string to_json(const ExtractStats& stats);

// The surface at iso without an index: its tetrahedra found by one scan of them all (scan_active,
// interval_tree.hpp), then marched, the Extractor's fresh march byte for byte. For a few
// iso-values this costs less than building the index (the CT bunny: a scan 0.2 s, the index
// 1.0-1.5 s and 0.8 GB): `adaptiso extract` for up to 4, Python's extract(iso) of a grid loaded in
// part. The figures are an extraction's, the scan as the sweep (every tetrahedron walked). A raised
// `cancel` stops the march (ExtractCancelled), as Extractor::extract's.
ExtractStats extract_scanned(const TetGrid& grid, double iso, Mesh& mesh, const std::atomic<bool>* cancel = nullptr);

struct ExtractCancelled : std::runtime_error {
  ExtractCancelled() : std::runtime_error("extraction cancelled") {}
};

class Extractor {
public:
  // Throws std::invalid_argument for a grid loaded without its tetrahedra (GridParts::hierarchy) or
  // its index (GridParts::tetrahedra).
  explicit Extractor(std::shared_ptr<const PreparedGrid> grid, const ExtractorOptions& options = {});
  ~Extractor();
  Extractor(Extractor&&) noexcept;
  Extractor& operator=(Extractor&&) noexcept;

  ExtractStats extract(double iso, const std::atomic<bool>* cancel = nullptr);
  const Mesh& mesh() const;
  // The mesh's triangles in the order a fresh march of the same iso-value writes them (by
  // tetrahedron id; spatially coherent, which the compact codec compresses best: after
  // incremental steps the mesh's own order depends on the history, see above). A permutation of
  // [0, triangles), valid until the next extract; sorting costs about 2 passes over the
  // triangles, in buffers the Extractor keeps for the next call (fresh memory is costly on
  // virtual machines: util/big_array.hpp).
  const std::vector<std::uint32_t>& triangles_in_march_order() const;
  // The active tetrahedra of the last extract, in slot order (ascending after a fresh march).
  const std::vector<std::uint32_t>& active() const;
  // Per mesh vertex, its cut edge as (below vertex << 32 | above vertex), grid vertex ids; the
  // same edge in every grid of the volume is grid().grid.lattice_edge(key >> 32, key & 0xffffffff)
  // (tet_grid.hpp: global lattice keys). kClippedVertex for a vertex the clip to the volume's box
  // made on one of its far faces (a padded lattice, tet_grid.hpp), which lies on no grid edge.
  const std::vector<std::uint64_t>& vertex_edges() const;
  bool last_was_incremental() const;
  const PreparedGrid& grid() const;

private:
  std::unique_ptr<detail::ExtractorState> state_;
};

}  // namespace adaptiso
