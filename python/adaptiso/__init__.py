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
    prepare,
    prepare_file,
    read,
    reduce,
    write_mesh,
)
from ._marching_cubes import marching_cubes
from ._mesh import Mesh

__all__ = [
    "DEFAULT_RELATIVE_ERROR",
    "Extractor",
    "Grid",
    "Mesh",
    "Volume",
    "__version__",
    "load",
    "marching_cubes",
    "prepare",
    "prepare_file",
    "read",
    "reduce",
    "write_mesh",
]
