"""adaptiso: adaptive iso-surface extraction from 3D scalar volumes (after Lürig & Ertl).

    import adaptiso
    vol = adaptiso.read("scan.nii.gz")   # or adaptiso.Volume(array[z, y, x], spacing=(sx, sy, sz))
    grid = adaptiso.prepare(vol, max_error=0.02, relative=True)
    mesh = grid.extract(iso=300.0)       # an adaptiso.Mesh: unpacks as vertices, faces, normals
    mesh.save("out.glb")                 # or mesh.to_vtk(), mesh.to_meshio(), mesh.to_napari()
    verts, faces, normals, values = adaptiso.marching_cubes(array, 300.0)  # scikit-image's

Volumes are indexed array[z, y, x]; spacing and origin are (x, y, z); meshes from grids are in world
coordinates (x, y, z): vertices float32 (N, 3), faces uint32 (M, 3), normals float32 (N, 3).
marching_cubes alone follows scikit-image: spacing and vertices in the array's index order.
"""
from ._core import (
    DEFAULT_RELATIVE_ERROR,
    Extractor,
    Grid,
    Volume,
    __version__,
    load,
    memory_limit,
    prepare,
    prepare_file,
    read,
    reduce,
    set_memory_limit,
    write_mesh,
)
from . import _core
from ._marching_cubes import marching_cubes
from ._mesh import Mesh


def simplify(mesh, distance, *, checked=False):
    """simplify(mesh, distance, *, checked=False) -> Mesh

    The mesh with fewer triangles, moved about `distance` (the mesh's units: world units for
    meshes from grids) by meshoptimizer's simplifier, borders locked and kept vertices unmoved
    (the command line's --simplify, which takes voxels). checked=True checks each region's result
    both ways (every vertex within the distance of the simplified surface, but closed pieces
    smaller than it; every simplified triangle's centre within it of the mesh) and simplifies
    smaller regions where it fails: slower, more triangles on noisy surfaces. mesh: an
    adaptiso.Mesh or a (vertices, faces[, normals, ...]) tuple; the result keeps its axes and
    carries the figures in ``stats``. ValueError on a bad mesh or distance."""
    items = tuple(mesh)
    if len(items) < 2:
        raise ValueError("mesh: must hold vertices and faces")
    normals = items[2] if len(items) > 2 else None
    vertices, faces, normals, stats = _core._simplify(items[0], items[1], normals, float(distance), bool(checked))
    return Mesh(vertices, faces, normals, stats=stats, axes=getattr(mesh, "axes", "xyz"))


__all__ = [
    "DEFAULT_RELATIVE_ERROR",
    "Extractor",
    "Grid",
    "Mesh",
    "Volume",
    "__version__",
    "load",
    "marching_cubes",
    "memory_limit",
    "prepare",
    "prepare_file",
    "read",
    "reduce",
    "set_memory_limit",
    "simplify",
    "write_mesh",
]
