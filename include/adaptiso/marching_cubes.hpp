// adaptiso/marching_cubes.hpp — classic marching cubes on the full grid: the paper's baseline and
// the full-resolution reference that adaptiso's surfaces are measured against.
//
// Same conventions as the tetrahedral extraction (marching_tetrahedra.hpp): a voxel equal to the iso-value
// counts as above it; one mesh vertex per cut grid edge (watertight where the surface stays inside
// the volume); normals are the volume's gradient (central differences, one-sided at the border)
// interpolated along the edge, pointing towards lower values; world coordinates.
//
// The case table is generated, not typed in: on each cube face the contour joins the face's cut
// edges, and on a face with two diagonal corners above the iso-value the contour cuts those two
// corners off (above corners are separated). Both cubes sharing a face decide it the same way, so
// the surface has no cracks. Each closed contour is fanned from its lowest-numbered edge. The
// classic table (scikit-image's method="lorensen") groups the cut edges of all 254 configurations
// into the same pieces (tested), so triangle counts and vertices agree; it triangulates a piece of
// 4 to 7 cut edges per case instead, which moves the area of a noisy surface by about 0.5 %.
#pragma once
#include <cstdint>
#include <vector>

#include "adaptiso/mesh.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso {

struct MarchingCubesStats {
  std::size_t cubes_cut = 0;
  std::size_t ambiguous_faces = 0;  // cube faces with two diagonal corners above (counted per cube)
};

// What scikit-image's marching_cubes does differently (the Python module's front end); the
// defaults are this library's conventions above.
struct MarchingCubesOptions {
  bool strictly_above = false;      // a voxel counts as above only when greater than the iso-value
  double edge_margin = 1.0 / 1024;  // cut points stay this fraction of an edge from its ends (0: exact)
  // Lorensen & Cline's table (scikit-image's method="lorensen"): the same cut edges and pieces,
  // each piece of 4 to 7 edges split into triangles per case rather than fanned.
  bool classic_table = false;
  // nx*ny*nz bytes (the volume's layout) or null: a cube is marched only when its far corner
  // (i+1, j+1, k+1) is nonzero, as scikit-image's mask does.
  const std::uint8_t* mask = nullptr;
  // Out, when not null: per vertex, the largest value range (max − min of its 8 corners) of the
  // marched cubes that use it (scikit-image's "values").
  std::vector<float>* values = nullptr;
};

// Parallel over slabs of cube layers; the output is the same for any number of threads. Each
// voxel decides above/below once (slabs share the plane between them), so values changed by
// another thread during the call give a wrong surface, never an out-of-range index.
Mesh marching_cubes(const Volume& v, double iso, MarchingCubesStats* stats = nullptr);
Mesh marching_cubes(const Volume& v, double iso, const MarchingCubesOptions& options, MarchingCubesStats* stats = nullptr);

}  // namespace adaptiso
