// adaptiso/marching_cubes.hpp — classic marching cubes on the full grid: the paper's baseline and
// the full-resolution reference that adaptiso's surfaces are measured against.
//
// Same conventions as the tetrahedral extraction (extract.hpp): a voxel equal to the iso-value
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
#include "adaptiso/mesh.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso {

struct MarchingCubesStats {
  std::size_t cubes_cut = 0;
  std::size_t ambiguous_faces = 0;  // cube faces with two diagonal corners above (counted per cube)
};

// Parallel over slabs of cube layers; the output is the same for any number of threads.
Mesh marching_cubes(const Volume& v, double iso, MarchingCubesStats* stats = nullptr);

}  // namespace adaptiso
