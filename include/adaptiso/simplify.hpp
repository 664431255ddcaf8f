// adaptiso/simplify.hpp — an extracted mesh simplified to a stated distance, for export.
//
// A grid-based surface needs voxel-sized cells wherever the surface bends sharply, so even an
// adaptive grid gives more triangles than the shape needs; an edge-collapse simplifier then
// removes what the distance allows. This wraps meshoptimizer's simplifier (Garland & Heckbert
// quadrics, collapses that keep the topology and the triangles' orientation) with:
// - the target error set to `distance` (world units): meshoptimizer estimates, by its quadrics,
//   how far the simplified surface moves from the original and stops there; on smooth surfaces
//   the mean symmetric distance stays below it (measured with surface_distance.hpp in the tests
//   and by `--measure`), but the estimate is no bound: the largest deviation reached 1.4× the
//   distance on the tests' sphere and torus, and the mean 1.3× on a noisy CT;
// - the mesh's border vertices locked (meshopt_SimplifyLockBorder), so an open surface keeps its
//   border on the volume's box and a closed one stays closed;
// - the kept vertices keep their positions and normals exactly (the interpolated gradients of the
//   grid: simplification only removes vertices, it never moves one), renumbered in first-use order.
// - a large mesh cut into spatial chunks of at most `chunk_triangles` triangles, simplified in
//   parallel (meshoptimizer's simplifier runs on one thread), with the cuts locked like borders;
//   then the band of triangles around the cuts is simplified once more (its errors add to the
//   first pass's). The chunks depend on the mesh alone: the output is the same for any thread
//   count. A chunk size of at least the triangle count gives one pass.
// - checked (SimplifyOptions::checked; CLI --checked): meshoptimizer's estimate is no bound, and on
//   noisy surfaces it drops whole pieces (thin vessels, noise specks: on a chest CT at 0.5 voxels,
//   5 % of the surface ended up 6 voxels or more from the simplified one). Checked, each part's
//   result is measured against the part: every vertex of the part within the distance of the
//   simplified part (but those of closed pieces no larger than the distance, which may go, as the
//   distance query leaves such pieces out), every simplified triangle's centre within it of the
//   part (point-to-triangle distances, exact in double). A part that fails is cut in two and each
//   half simplified on its own, down to parts of 256 triangles, kept as they were when they fail:
//   where meshoptimizer errs costs a small region its simplification, not the mesh. The band pass
//   is checked the same way against its input, the first pass getting 2/3 of the distance and the
//   band 1/3, so the checked points of each pass are within its share (points between them are
//   not checked: measure with surface_distance.hpp). The price, measured on the CT bunny at 0.5
//   voxels from marching cubes: 152 k triangles in 7.6 s against meshoptimizer's 22 k in 1–2 s, and
//   a largest distance of 0.47 voxels against 6.3.
// A distance of 0 returns the mesh unchanged. Throws OptionError("simplify") for a negative or
// non-finite distance.
#pragma once
#include "adaptiso/mesh.hpp"

namespace adaptiso {

struct SimplifyStats {
  std::size_t triangles_before = 0, triangles_after = 0;
  double error = 0;  // meshoptimizer's estimate of the largest deviation, world units (both passes)
  double seconds = 0;
  std::size_t chunks = 0;          // simplified in parallel
  std::size_t chunks_retried = 0;  // checked: parts that failed and were cut in two
  std::size_t chunks_kept = 0;     // checked: parts of 256 triangles or fewer left as they were
};

// Chunks of this many triangles keep 2 cores busy on a 512³ scan's surface (the CT bunny's 3.7 to
// 4.5 M triangles make 4 to 8 chunks) and cost few triangles along the cuts; a smaller mesh is
// simplified in one pass. Smaller chunks moved the mean distance on the noisy chest CT by up to
// 24 % against one pass (bench_simplify).
inline constexpr std::size_t kSimplifyChunkTriangles = 1000000;
// Checked, the first pass's parts hold at most this many triangles, so the checks share the cores.
inline constexpr std::size_t kCheckedChunkTriangles = 50000;

struct SimplifyOptions {
  std::size_t chunk_triangles = kSimplifyChunkTriangles;
  bool checked = false;  // true: each part's result checked (above); slower, more triangles
};

Mesh simplify_mesh(const Mesh& mesh, double distance, SimplifyStats* stats = nullptr, const SimplifyOptions& options = {});

}  // namespace adaptiso
