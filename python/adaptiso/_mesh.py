"""adaptiso.Mesh: a surface that still unpacks as the tuple scikit-image-like code expects, with the
hand-offs to the libraries its users go on in (VTK/PyVista, meshio, napari) and to files."""
import numpy as np


class Mesh(tuple):
    """A triangle mesh: vertices (N, 3), faces (M, 3), normals (N, 3) and, from marching_cubes,
    values (N,).

    It is a tuple of those arrays, so code written for tuples keeps working::

        verts, faces, normals = grid.extract(300.0)
        verts, faces, normals, values = adaptiso.marching_cubes(array, 300.0)
        verts, faces = adaptiso.marching_cubes(array, 300.0)[:2]

    and it carries:

    - ``stats``: the figures the command line prints for this surface (triangles, vertices,
      seconds, ...) as a dict;
    - ``axes``: the order of the coordinate columns, ``"xyz"`` (meshes from grids: world
      coordinates) or ``"zyx"`` (marching_cubes on an array[z, y, x]: the array's index order, as
      scikit-image returns them).

    ``to_vtk()``, ``to_meshio()`` and ``save()`` give (x, y, z) coordinates whatever ``axes`` is;
    ``to_napari()`` gives (z, y, x), the order of napari's layers over the same array. Reordering
    the columns mirrors the mesh, so the faces are rewound with it: seen from the side the normals
    point to, a face turns the same way before and after.
    """

    def __new__(cls, vertices, faces, normals=None, values=None, *, stats=None, axes="xyz"):
        """Mesh(vertices, faces, normals=None, values=None, *, stats=None, axes="xyz")."""
        if axes not in ("xyz", "zyx"):
            raise ValueError(f"axes: must be 'xyz' or 'zyx', got {axes!r}")
        items = (vertices, faces, normals) if values is None else (vertices, faces, normals, values)
        self = super().__new__(cls, items)
        self.stats = {} if stats is None else dict(stats)
        self.axes = axes
        return self

    def __getnewargs__(self):
        # Pickling: the arrays as Mesh's own arguments (a tuple's default passes itself as one).
        return tuple(self)

    @property
    def vertices(self):
        """Vertex positions (N, 3), columns in ``axes`` order."""
        return self[0]

    @property
    def faces(self):
        """Triangles (M, 3) as indices into vertices."""
        return self[1]

    @property
    def normals(self):
        """Unit normals (N, 3) pointing towards lower values, columns in ``axes`` order (or None)."""
        return self[2]

    @property
    def values(self):
        """marching_cubes: per vertex, the largest value range of the cubes around it; else None."""
        return self[3] if len(self) > 3 else None

    def __repr__(self):
        return f"<adaptiso.Mesh: {len(self[0])} vertices, {len(self[1])} triangles, axes {self.axes}>"

    def _ordered(self, axes):
        """(vertices, faces, normals) with columns in the given order, faces rewound when mirrored."""
        vertices, faces, normals = self[0], self[1], self[2]
        if axes == self.axes:
            return vertices, faces, normals
        vertices = vertices[:, ::-1]
        normals = None if normals is None else normals[:, ::-1]
        faces = faces[:, [0, 2, 1]]
        return vertices, faces, normals

    def _point_values(self):
        """Per-vertex values for viewers: marching_cubes' values, else the iso-value everywhere."""
        if self.values is not None:
            return np.asarray(self.values)
        return np.full(len(self[0]), self.stats.get("iso", 0.0), dtype=np.float32)

    def to_vtk(self):
        """The mesh as a vtkPolyData (x, y, z): points, triangles, point normals ("Normals") and, from
        marching_cubes, point scalars ("values"). PyVista wraps it: pyvista.wrap(mesh.to_vtk()).

        ImportError when VTK's Python module is missing (Debian: python3-vtk9; pip: vtk).
        """
        try:
            from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
            from vtkmodules.vtkCommonCore import vtkPoints
            from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
        except ImportError as e:
            raise ImportError("Mesh.to_vtk needs VTK's Python module (Debian: python3-vtk9; pip: vtk)") from e
        vertices, faces, normals = self._ordered("xyz")
        points = vtkPoints()
        points.SetData(numpy_to_vtk(np.ascontiguousarray(vertices, dtype=np.float32), deep=True))
        ids = np.dtype(f"int{8 * np.dtype(np.intp).itemsize}")  # vtkIdType is 64-bit in Debian's VTK
        connectivity = numpy_to_vtkIdTypeArray(np.ascontiguousarray(faces, dtype=ids).ravel(), deep=True)
        offsets = numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(faces) + 1, 3, dtype=ids), deep=True)
        cells = vtkCellArray()
        cells.SetData(offsets, connectivity)
        poly = vtkPolyData()
        poly.SetPoints(points)
        poly.SetPolys(cells)
        if normals is not None:
            n = numpy_to_vtk(np.ascontiguousarray(normals, dtype=np.float32), deep=True)
            n.SetName("Normals")
            poly.GetPointData().SetNormals(n)
        if self.values is not None:
            v = numpy_to_vtk(np.ascontiguousarray(self.values, dtype=np.float32), deep=True)
            v.SetName("values")
            poly.GetPointData().SetScalars(v)
        return poly

    def to_meshio(self):
        """The mesh as a meshio.Mesh (x, y, z) with one "triangle" cell block and point data
        "normals" (and "values" from marching_cubes); meshio.write() then writes any of its formats.

        ImportError when meshio is missing (Debian: python3-meshio; pip: meshio).
        """
        try:
            import meshio
        except ImportError as e:
            raise ImportError("Mesh.to_meshio needs meshio (Debian: python3-meshio; pip: meshio)") from e
        vertices, faces, normals = self._ordered("xyz")
        point_data = {}
        if normals is not None:
            point_data["normals"] = np.ascontiguousarray(normals)
        if self.values is not None:
            point_data["values"] = np.asarray(self.values)
        return meshio.Mesh(np.ascontiguousarray(vertices), [("triangle", np.ascontiguousarray(faces))], point_data=point_data)

    def save(self, path):
        """Writes the mesh by its extension, (x, y, z): .ply, .obj, .stl or .glb (adaptiso.write_mesh).

        path: str, bytes or os.PathLike. OSError when it cannot be written, ValueError for another
        extension (meshio's formats: mesh.to_meshio().write(path)).
        """
        from . import _core

        vertices, faces, normals = self._ordered("xyz")
        _core.write_mesh(path, vertices, faces, normals)

    def to_napari(self):
        """(vertices, faces, values) in the layout napari's ``viewer.add_surface`` takes: vertices
        (N, 3) in (z, y, x) order, the order of an image layer of the array[z, y, x] (give the layer
        scale=spacing[::-1] and translate=origin[::-1] for a grid's world coordinates), faces (M, 3)
        and one value per vertex (marching_cubes' values, else the iso-value).
        """
        vertices, faces, _ = self._ordered("zyx")
        return np.ascontiguousarray(vertices), np.ascontiguousarray(faces), self._point_values()
