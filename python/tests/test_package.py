"""The package as a Python user meets it (issue 39): pip's installed copy, its version, Mesh and its
hand-offs to VTK, meshio, napari and files, volumes from memmaps, buffers and nibabel images,
type hints and help()."""
import ast
import importlib.metadata
import inspect
import os
import pickle
import re
import sys
import tracemalloc

import numpy as np
import pytest

import adaptiso

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
# scripts/test.sh sets this when it runs the suite against the pip-installed package.
EXPECT_PIP = os.environ.get("ADAPTISO_EXPECT_PIP") == "1"


def sphere_distance(shape=(30, 31, 32), centre=(14.5, 15.0, 15.5)):
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]]
    return np.sqrt((x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2).astype(np.float32)


def cmake_version():
    with open(os.path.join(ROOT, "CMakeLists.txt"), encoding="utf-8") as f:
        return re.search(r"project\(\s*adaptiso\s+VERSION\s+([0-9.]+)", f.read()).group(1)


def test_version_is_cmakelists_project_version():
    assert adaptiso.__version__ == cmake_version()


@pytest.mark.skipif(not EXPECT_PIP, reason="not run against a pip install (scripts/test.sh does)")
def test_the_pip_installed_package_is_the_one_imported():
    assert importlib.metadata.version("adaptiso") == adaptiso.__version__ == cmake_version()
    here = os.path.realpath(adaptiso.__file__)
    assert here.startswith(os.path.realpath(sys.prefix) + os.sep), here  # the venv's, not a build tree's
    files = {str(f) for f in importlib.metadata.files("adaptiso")}
    assert {"adaptiso/__init__.py", "adaptiso/__init__.pyi", "adaptiso/py.typed"} <= files
    assert any(f.startswith("adaptiso/_core.") for f in files)


def extracted_sphere():
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    return grid.extract(10.0)


def test_extract_gives_a_mesh_that_still_unpacks_as_a_tuple():
    mesh = extracted_sphere()
    verts, faces, normals = mesh
    assert isinstance(mesh, adaptiso.Mesh) and isinstance(mesh, tuple) and len(mesh) == 3
    assert mesh.vertices is verts and mesh.faces is faces and mesh.normals is normals and mesh.values is None
    assert mesh.axes == "xyz"
    assert mesh.stats["triangles"] == len(faces) and mesh.stats["vertices"] == len(verts) and mesh.stats["iso"] == 10.0
    assert {"active_tetrahedra", "seconds", "incremental"} <= set(mesh.stats)
    coarse = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.005, relative=True).extract(10.0, max_error=0.05, relative=True)
    assert {"error_bound", "max_error", "visited_tetrahedra"} <= set(coarse.stats)
    v2, f2, n2 = pickle.loads(pickle.dumps(mesh))
    assert np.array_equal(v2, verts) and pickle.loads(pickle.dumps(mesh)).stats == mesh.stats


def test_mesh_to_vtk_is_a_polydata_of_the_same_surface():
    pytest.importorskip("vtkmodules")
    mesh = extracted_sphere()
    poly = mesh.to_vtk()
    from vtkmodules.util.numpy_support import vtk_to_numpy

    assert poly.GetNumberOfPoints() == len(mesh.vertices) and poly.GetNumberOfPolys() == len(mesh.faces)
    assert np.array_equal(vtk_to_numpy(poly.GetPoints().GetData()), mesh.vertices)
    assert np.array_equal(vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3), mesh.faces)
    assert np.array_equal(vtk_to_numpy(poly.GetPointData().GetNormals()), mesh.normals)
    # From marching_cubes (z, y, x): VTK gets (x, y, z), the faces rewound with the mirror.
    a = sphere_distance()
    mc = adaptiso.marching_cubes(a, 10.0)
    poly = mc.to_vtk()
    assert np.array_equal(vtk_to_numpy(poly.GetPoints().GetData()), mc.vertices[:, ::-1])
    assert np.array_equal(vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3), mc.faces[:, [0, 2, 1]])
    assert np.array_equal(vtk_to_numpy(poly.GetPointData().GetScalars()), mc.values)


def test_mesh_to_meshio_and_save_in_every_format(tmp_path):
    meshio = pytest.importorskip("meshio")
    a = sphere_distance()
    mc = adaptiso.marching_cubes(a, 10.0, spacing=(2.0, 1.0, 0.5))
    m = mc.to_meshio()
    assert np.allclose(m.points, mc.vertices[:, ::-1]) and np.array_equal(m.cells_dict["triangle"], mc.faces[:, [0, 2, 1]])
    assert np.array_equal(m.point_data["values"], mc.values)
    for ext in ("ply", "obj", "stl", "glb"):
        path = tmp_path / f"s.{ext}"
        mc.save(path)  # os.PathLike
        assert path.stat().st_size > 0
        if ext in ("ply", "obj"):
            back = meshio.read(path)
            assert np.allclose(back.points, mc.vertices[:, ::-1], atol=1e-5)  # written in (x, y, z)
    with pytest.raises(ValueError, match="unknown mesh type|extension"):
        mc.save(tmp_path / "s.vtu")


def test_mesh_to_napari_layout():
    a = sphere_distance()
    mc = adaptiso.marching_cubes(a, 10.0)
    verts, faces, values = mc.to_napari()
    assert np.array_equal(verts, mc.vertices) and np.array_equal(faces, mc.faces) and np.array_equal(values, mc.values)
    ex = extracted_sphere()
    verts, faces, values = ex.to_napari()
    assert np.array_equal(verts, ex.vertices[:, ::-1])  # napari's layers are (z, y, x)
    assert values.shape == (len(verts),) and np.all(values == 10.0)


def test_missing_optional_packages_give_an_import_error_naming_them(monkeypatch):
    mesh = extracted_sphere()
    monkeypatch.setitem(sys.modules, "vtkmodules", None)
    monkeypatch.setitem(sys.modules, "vtkmodules.util.numpy_support", None)
    monkeypatch.setitem(sys.modules, "meshio", None)
    with pytest.raises(ImportError, match="python3-vtk9"):
        mesh.to_vtk()
    with pytest.raises(ImportError, match="python3-meshio"):
        mesh.to_meshio()


def test_volume_of_a_memmap_reads_nothing_and_copies_nothing(tmp_path):
    path = tmp_path / "big.raw"
    shape = (64, 512, 512)  # 32 MiB of int16, sparse on disk
    with open(path, "wb") as f:
        f.truncate(int(np.prod(shape)) * 2)
    mm = np.memmap(path, dtype=np.int16, mode="r", shape=shape)
    tracemalloc.start()
    try:
        v = adaptiso.Volume(mm, spacing=(0.5, 0.5, 1.0))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert v.is_view and np.shares_memory(v.array, mm) and peak < 1 << 20
    assert v.shape == shape and v.spacing == [0.5, 0.5, 1.0]


def test_volume_from_the_buffer_protocol_and___array__():
    a = sphere_distance()
    v = adaptiso.Volume(memoryview(a))
    assert v.is_view and np.shares_memory(v.array, a)

    class Wrapped:
        def __array__(self, dtype=None):
            return a

    assert np.array_equal(adaptiso.Volume(Wrapped()).array, a)
    with pytest.raises(TypeError, match="numeric array"):
        adaptiso.Volume(object())


def test_nibabel_image_gives_the_readers_geometry_without_a_copy(tmp_path):
    nib = pytest.importorskip("nibabel")
    data = sphere_distance((20, 22, 24))  # [z, y, x]
    ijk = np.asfortranarray(data.T)  # nibabel's order: [i, j, k] = x, y, z
    affine = np.diag([0.5, 0.75, 1.25, 1.0])
    affine[:3, 3] = (-10.0, 20.0, 5.0)
    img = nib.Nifti1Image(ijk, affine)
    path = tmp_path / "s.nii"
    nib.save(img, path)
    loaded = nib.load(path)
    v = adaptiso.Volume(loaded)
    r = adaptiso.read(path)
    assert v.shape == r.shape == data.shape
    assert np.allclose(v.spacing, r.spacing) and np.allclose(v.spacing, loaded.header.get_zooms()[:3])
    assert np.allclose(v.origin, r.origin) and np.allclose(v.direction, r.direction)
    assert np.array_equal(v.array, r.array) and v.is_view  # the file's memmap, transposed in place
    # marching_cubes on the image: its index order (x, y, z) and its zooms, as scikit-image on
    # its data with spacing=zooms.
    skimage_measure = pytest.importorskip("skimage.measure")
    ours = adaptiso.marching_cubes(loaded, 8.5)
    theirs = skimage_measure.marching_cubes(np.asarray(loaded.dataobj), 8.5, spacing=loaded.header.get_zooms()[:3], method="lorensen")
    assert ours.axes == "xyz" and len(ours[1]) == len(theirs[1])
    assert np.allclose(np.sort(ours[0], axis=0), np.sort(theirs[0], axis=0), atol=1e-5)


def public_names():
    return [n for n in adaptiso.__all__ if not n.startswith("__")]


def test_help_shows_a_docstring_for_every_function():
    missing = []
    for name in public_names():
        obj = getattr(adaptiso, name)
        if not (callable(obj) or inspect.isclass(obj)):
            continue
        if not (obj.__doc__ or "").strip():
            missing.append(name)
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if attr.startswith("_") or not (callable(member) or isinstance(member, property) or hasattr(member, "__get__")):
                    continue
                if not (getattr(member, "__doc__", None) or "").strip():
                    missing.append(f"{name}.{attr}")
    assert not missing


def test_the_stub_types_every_public_name():
    stub = os.path.join(os.path.dirname(adaptiso.__file__), "__init__.pyi")
    tree = ast.parse(open(stub, encoding="utf-8").read())
    declared = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    declared |= {t.id for n in tree.body if isinstance(n, ast.AnnAssign) for t in [n.target]}
    assert set(public_names()) <= declared
    for cls in (n for n in tree.body if isinstance(n, ast.ClassDef)):
        obj = getattr(adaptiso, cls.name)
        stubbed = {n.name for n in cls.body if isinstance(n, ast.FunctionDef)}
        public = {a for a in vars(obj) if not a.startswith("_")}
        assert public <= stubbed | {"stats", "axes"}, (cls.name, public - stubbed)
