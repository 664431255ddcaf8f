// adaptiso/hierarchy_query.hpp — iso-surfaces of a bisection grid at any error at or above the one
// it was prepared with, without preparing again (query-time error).
//
// A bisection grid keeps its hierarchy (bisection.hpp): per vertex the saturated error code of the
// diamond centred there and the values beneath it. A query (iso-value c, error E) walks the
// hierarchy top-down from the 6 root tetrahedra, splits exactly the diamonds a grid prepared at E
// would split (the same codes against E's threshold, the same splits forced by the volume's box),
// descends only into tetrahedra whose values beneath straddle c, and marches the leaves the
// surface cuts. So the surface is the one that preparing at E and extracting at c gives (the same
// triangles; their order and numbering follow the walk), with the same guarantee: every voxel in
// a tetrahedron used is within the reported error of its linear interpolation. The cost is
// proportional to what the walk meets near the surface, not to the grid; subtrees run in parallel
// and the result is the same for any thread count.
//
// Errors below the prepared one cannot be had (the finer diamonds were not kept): the query then
// answers at the prepared error. The displacement criterion, when the grid was prepared with it,
// applies at its prepared bound or any larger one asked for.
#pragma once
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "adaptiso/mesh.hpp"
#include "adaptiso/prepared_grid.hpp"
#include "adaptiso/progress.hpp"

namespace adaptiso {

struct HierarchyQueryStats {
  double iso = 0;
  double max_error = 0;        // asked for (raised to the prepared bound when below it)
  double error_bound = 0;      // guaranteed for the tetrahedra used: the largest of their bounds
  std::size_t tetrahedra = 0;  // leaves cut by the surface (marched)
  std::size_t visited = 0;     // tetrahedra the walk met
  std::size_t triangles = 0, vertices = 0;
  bool in_range = true;
  double walk_seconds = 0, march_seconds = 0;
};

// A surface within a distance of the grid's own (extract_within).
struct DistanceQueryStats {
  double iso = 0;
  double distance = 0;         // asked for, voxels of the smallest spacing
  std::size_t tetrahedra = 0;  // leaves marched
  std::size_t tested = 0;      // tetrahedra the refinement tested
  std::size_t refined = 0;     // diamonds split by the tests, and by the closure that keeps the mesh conforming
  std::size_t closure = 0;     // of those, split only to keep it conforming
  std::size_t visited = 0;     // tetrahedra the final walk met
  std::size_t triangles = 0, vertices = 0;
  bool in_range = true;
  // Pieces smaller than min_piece voxels dropped (after the march and after the collapses), and their triangles.
  double min_piece = 0;  // voxels: the distance unless asked otherwise
  std::size_t specks = 0, speck_triangles = 0;
  std::size_t collapsed = 0;         // edges collapsed after the march (each removes two triangles)
  std::size_t collapse_rounds = 0;   // rounds run (a round removing under a sixteenth is the last)
  std::size_t collapses_probed = 0;  // collapses chosen and probed, over the rounds
  std::size_t collapses_failed = 0;  // of those, not applied (own tests failed, or the ring's held vertices: below)
  double refine_seconds = 0, walk_seconds = 0, march_seconds = 0, collapse_seconds = 0;
};

// Rounds of edge collapses after the distance query's march (extract_within). Each round removes
// a fifth to a quarter of the triangles, on a smaller mesh than the last, so eight cost 1.4-1.8×
// the time of two for a third to a quarter of their triangles, still within the distance (the CT
// bunny at iso 1600.5 and 0.5 voxels: 91 k → 32 k triangles, p95 from the grid's surface 0.37 →
// 0.45 voxels; at 2 voxels 55 k → 14 k, 0.94 → 1.55; 2026-12-07). 2 or 0 for speed.
inline constexpr int kDefaultCollapseRounds = 8;
inline constexpr int kMaxCollapseRounds = 16;

class ShareTransport;  // select_shares.hpp
namespace detail {
struct HierarchyIndex;
}

class HierarchyQuery {
public:
  // Throws InputError when the grid has no hierarchy (a Delaunay grid, or a file without one).
  // Neither query reads the grid's tetrahedra or index: a grid loaded with GridParts::hierarchy
  // (grid_file.hpp) serves both.
  explicit HierarchyQuery(std::shared_ptr<const PreparedGrid> grid);
  ~HierarchyQuery();
  HierarchyQuery(HierarchyQuery&&) noexcept;
  HierarchyQuery& operator=(HierarchyQuery&&) noexcept;

  // The surface at iso with every tetrahedron within max_error (data units; +∞: the coarsest grid)
  // and, with the displacement criterion, max_displacement voxels (0: the prepared bound). With
  // `used`, also the tetrahedra marched (grid vertex ids, positively oriented).
  // Thread-safe: any number of queries may run at once. With `cancel`, once *cancel is raised the
  // query stops within a subtree of the walk or a chunk of the march and throws ExtractCancelled
  // (extractor.hpp), never a partial surface: Python's Ctrl-C.
  Mesh extract(double iso, double max_error, double max_displacement = 0, HierarchyQueryStats* stats = nullptr,
               std::vector<std::array<std::uint32_t, 4>>* used = nullptr, const std::atomic<bool>* cancel = nullptr) const;

  // The surface at iso within about `distance` voxels (of the smallest spacing) of the grid's own
  // surface at iso (the one extract gives at the prepared error), with far fewer triangles.
  // Refinement follows this surface only (distance_query.cpp): from the 6 root tetrahedra, one the
  // surface may cross is split while a test finds it too coarse (a triangle's centre, or for a
  // triangle longer than 3·distance one of its corner quarters' centres, farther than the
  // distance from the grid's surface, or a cut point its split adds farther than the distance
  // from its triangles, or a surface hidden beneath it, or beneath its half whose corners show
  // none, or, when it shows only a speck, beneath it farther than the distance from the speck,
  // while its longest edge exceeds the distance, kept only when the surface shows beneath it);
  // the splits are then closed under their parents, so the mesh stays conforming.
  // Then up to `collapse_rounds` rounds of edge collapses (distance_query.cpp): an edge is collapsed
  // into one of its ends when the same tests pass on the result (every new triangle's centre
  // within the distance of the grid's surface along its normal, unless its edges are within
  // √3·distance; the removed vertex within the distance of the new triangles), no new triangle
  // turns by more than 60°, and the link condition holds; vertices on the surface's border stay.
  // Every removed vertex is held by a vertex that stays (the one it went to), and a collapse keeps
  // every vertex held by v or by v's ring within the distance of the holder's star as it leaves it
  // (whatever the round's other collapses do: one that needs a triangle another collapse changes
  // waits a round if that one passes). A collapse whose own tests failed is not tried again while
  // v's star stays as it was; one that waited or failed what its ring holds, not the next round. A round
  // removing less than a sixteenth of the triangles is the last. Measured (2026-12-07), the first
  // rounds remove a fifth to a quarter: the CT bunny at iso 1600.5 157,114 → 119,784 → 91,552 at
  // 0.5 voxels, 92,796 → 69,934 → 52,330 at 2; the 512×512×120 MR head at iso 120.5 (slices 3.7
  // voxels apart) 7,268,646 → 5,757,276 → 4,661,426 at 0.5. The probes are made in the grid's
  // frame (the mesh's world positions taken back through the volume's origin and direction).
  // Guaranteed: every mesh vertex is a vertex of the grid's own surface, bit for bit (the cut of a
  // coarse edge is placed on the grid's cut edge inside it); the surface is watertight and
  // 2-manifold where the grid's is, oriented, and the same for any thread count; no piece of it
  // is smaller than `min_piece` voxels, by default the distance (a piece whose bounding box, in the
  // grid's frame, has a diagonal under it is dropped after the march, and again after the
  // collapses, which shrink pieces: a speck of noise, or a lesion a reader wants kept, which 0
  // keeps; stats->specks counts them); every vertex of the march (each a vertex of the
  // grid's surface) outside a dropped piece lies within the distance of the collapsed
  // surface (the vertices that stay are on it, each removed one near its holder's star); the centre (and
  // when longer than 3·distance the corner quarters' centres) of every triangle of a tetrahedron
  // whose longest edge exceeds the distance, and the centre of every triangle a collapse made,
  // was found within it of the grid's surface along the triangle's normal (most
  // triangles: those of tetrahedra split only to stay conforming are not tested). Without
  // collapses (collapse_rounds 0) each triangle lies in its tetrahedron, so the surface is free
  // of self-intersections; collapses move triangles out of their tetrahedra and, in thin
  // places, do not exclude them. Not guaranteed, and measured (bench/distance.py,
  // docs/RESULTS.md): the distance everywhere, and parts that no corner shows, which are left out
  // (measured on the shared MR heads at 2 voxels: no piece of the grid's surface wider than
  // 2·distance; at 1 voxel a few 2-4 voxels wide, 2 voxels from a larger surface that hid them).
  // distance 0 gives the grid's own surface exactly (no collapses; pieces dropped only under a
  // min_piece given).
  // Thread-safe. With `cancel`, once *cancel is raised the query stops within a stage's part (a
  // subtree of the refinement, a chunk of probes) and throws ExtractCancelled (extractor.hpp):
  // the viewer drops a surface the page no longer wants (a rest surface the next drag overtook).
  // `progress` hears the stages "refine", "march" and "collapse" (after each round; on the
  // 512×512×120 MR head at 0.5 voxels eight rounds take 8 s).
  // The other direction is not guaranteed where pieces are dropped: the grid's surface of a
  // dropped piece is as far from this one as the piece is from the rest (measured at 2 voxels on
  // the 4 mm HeadMRVolume's ventricles at iso 150.5: 90 pieces, p95 from the grid's surface 1.48
  // → 3.01 voxels; 0.96–1.79 on the other shared scans and iso-values).
  // Throws OptionError for a non-finite iso, a negative or non-finite distance or min_piece, or
  // rounds outside 0..kMaxCollapseRounds.
  Mesh extract_within(double iso, double distance, DistanceQueryStats* stats = nullptr, int collapse_rounds = kDefaultCollapseRounds,
                      const std::atomic<bool>* cancel = nullptr, const Progress& progress = {}, std::optional<double> min_piece = {}) const;

  // The same surface made by several processes together (issue 38): every process of `share`
  // (select_shares.hpp) calls this with the same arguments on the same grid, and each returns the
  // same mesh, byte for byte the one extract_within makes alone. The refinement's subtrees 12
  // levels below the roots are dealt out by a hash of their place (the levels above are refined
  // on every process, then again on process 0 with the owners' answers), the final walk's units
  // in contiguous chunks (4 a process, in turn), each process numbering its chunks' vertices and
  // placing them; process 0 numbers the chunks' vertices again in chunk order and sends the mesh
  // to the others; each round of collapses has each block of 2^18 vertices chosen on one process
  // (process 0 choosing across the blocks) and each process probing a share of the collapses
  // chosen. `stats` is the same on every process but its timings. Throws what extract_within
  // throws, and whatever the transport throws; a process that fails mid-way (its memory) leaves
  // the others waiting: the caller stops them (the command line: MPI_Abort).
  Mesh extract_within(ShareTransport& share, double iso, double distance, DistanceQueryStats* stats = nullptr,
                      int collapse_rounds = kDefaultCollapseRounds, std::optional<double> min_piece = {}) const;

  double prepared_error() const;  // the smallest error a query can have
  const PreparedGrid& grid() const;

private:
  std::shared_ptr<const PreparedGrid> grid_;
  std::unique_ptr<detail::HierarchyIndex> index_;
  Mesh within(double iso, double distance, DistanceQueryStats* stats, int collapse_rounds, const std::atomic<bool>* cancel,
              ShareTransport* share, const Progress& progress, std::optional<double> min_piece) const;
};

}  // namespace adaptiso
