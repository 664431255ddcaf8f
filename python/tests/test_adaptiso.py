"""Tests of the Python module against an installed copy (scripts/test.sh runs them against a staging
prefix on PYTHONPATH, then against pip's install in a venv), the command line and scikit-image."""
import json
import os
import resource
import subprocess
import tempfile
import threading

import numpy as np
import pytest

import adaptiso

DATA = os.environ.get("ADAPTISO_DATA", os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data"))
CLI = os.environ.get("ADAPTISO_CLI")  # the command line of the same build, when given


def sphere_distance(shape=(30, 31, 32), centre=(14.5, 15.0, 15.5)):
    """Distance to a centre, as array[z, y, x]."""
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]]
    return np.sqrt((x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2).astype(np.float32)


def area(verts, faces):
    t = verts[faces.astype(np.int64)]
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()


def test_version_is_the_projects():
    assert adaptiso.__version__.count(".") == 2
    if CLI:
        out = subprocess.run([CLI, "--version"], capture_output=True, text=True, check=True).stdout
        assert out.strip() == "adaptiso " + adaptiso.__version__


def test_axis_order_array_zyx_is_volume_xyz():
    a = np.arange(2 * 3 * 4, dtype=np.int16).reshape(2, 3, 4)  # [z, y, x]
    v = adaptiso.Volume(a, spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3))
    assert v.dims == [4, 3, 2]
    assert v.shape == (2, 3, 4)
    assert v.spacing == [0.5, 1.0, 2.0]
    assert v.is_view
    assert np.shares_memory(v.array, a)
    assert np.array_equal(v.array, a)
    assert v.range() == (0.0, 23.0)
    # The other way round: a Fortran-ordered array of the same values is copied into C order.
    f = np.asfortranarray(a)
    vf = adaptiso.Volume(f)
    assert not np.shares_memory(vf.array, f)
    assert np.array_equal(vf.array, a)


def test_volume_of_a_large_array_is_not_copied():
    # Every page written before measuring: on kernels that back even a read of np.zeros' untouched
    # pages with memory (Linux 6.18 with numpy's huge-page advice: +123 MB for a.sum()), reading
    # would look like a copy.
    a = np.empty((256, 256, 512), dtype=np.float32)  # 128 MiB
    a.fill(0)
    a[100:150, 100:150, 100:150] = 1
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    v = adaptiso.Volume(a)
    assert v.range() == (0.0, 1.0)
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    assert v.is_view
    assert after - before < a.nbytes // 4, f"resident memory grew by {after - before} bytes"


def test_round_trip_numpy_volume_mesh():
    a = sphere_distance()
    v = adaptiso.Volume(a)
    grid = adaptiso.prepare(v, max_error=0.01, relative=True)
    assert grid.error_bound is not None and grid.error_bound <= 0.01 * (a.max() - a.min()) + 1e-9
    verts, faces, normals = grid.extract(iso=10.0)
    assert verts.dtype == np.float32 and faces.dtype == np.uint32 and normals.dtype == np.float32
    assert verts.shape[1] == 3 and faces.shape[1] == 3 and normals.shape == verts.shape
    assert verts.flags.owndata or verts.base is not None
    # A sphere of radius 10 around the centre, in (x, y, z).
    r = np.linalg.norm(verts - np.array([14.5, 15.0, 15.5], dtype=np.float32), axis=1)
    assert abs(r.mean() - 10) < 0.05
    assert abs(area(verts, faces) / (4 * np.pi * 100) - 1) < 0.01
    # Normals point towards lower values: inwards for a distance field.
    assert np.mean(np.sum(normals * (verts - np.array([14.5, 15.0, 15.5])), axis=1)) < 0
    # Every edge is shared by exactly two triangles (closed), in opposite directions (oriented).
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    assert len({tuple(x) for x in e.tolist()}) == len(e)
    assert {tuple(x) for x in e.tolist()} == {(b, a_) for a_, b in e.tolist()}


def test_save_load_and_incremental_extractor(tmp_path):
    v = adaptiso.Volume(sphere_distance())
    grid = adaptiso.prepare(v, max_error=0.02, relative=True)
    path = str(tmp_path / "s.adg")
    grid.save(path)
    loaded = adaptiso.load(path)
    assert loaded.tetrahedron_count == grid.tetrahedron_count
    assert loaded.stats["grid"] == "bisection"
    ex = loaded.extractor()
    ex.extract(9.0)
    v1, f1, n1 = ex.extract(9.1)
    assert ex.last_stats["incremental"]
    v2, f2, n2 = loaded.extract(9.1)
    assert sorted(map(tuple, v1[f1].reshape(-1, 9).tolist())) == sorted(map(tuple, v2[f2].reshape(-1, 9).tolist()))


def faces_as_points(mesh):
    v, f, _ = mesh
    return sorted(map(tuple, v[f].reshape(-1, 9).tolist()))


def test_load_reads_the_tetrahedra_from_the_file_it_opened(tmp_path):
    # load keeps a bisection grid's vertices and hierarchy; extract(iso) reads the tetrahedra later,
    # from the file as loaded: one renamed over and then deleted still gives the first grid.
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    other = adaptiso.prepare(adaptiso.Volume(sphere_distance(centre=(10.5, 12.0, 13.5))), max_error=0.02, relative=True)
    path = tmp_path / "s.adg"
    grid.save(path)
    loaded = adaptiso.load(path)
    assert loaded.tetrahedron_count == grid.tetrahedron_count
    assert faces_as_points(loaded.extract(9.1, distance=1.0)) == faces_as_points(grid.extract(9.1, distance=1.0))
    other.save(tmp_path / "o.adg")
    os.replace(tmp_path / "o.adg", path)
    os.remove(path)
    assert faces_as_points(loaded.extract(9.1)) == faces_as_points(grid.extract(9.1))
    assert faces_as_points(loaded.extract(9.1, distance=1.0)) == faces_as_points(grid.extract(9.1, distance=1.0))
    assert faces_as_points(loaded.extractor().extract(9.1)) == faces_as_points(grid.extract(9.1))
    assert loaded.coarsen(1.0).tetrahedron_count == grid.coarsen(1.0).tetrahedron_count
    loaded.save(tmp_path / "again.adg")
    assert (tmp_path / "again.adg").stat().st_size > 0


def test_save_after_a_load_in_part_writes_the_file_it_loaded(tmp_path):
    # save reads the tetrahedra from the open file for the write alone (no index built), and the
    # grid stays loaded in part: later routes still read the file as it was loaded.
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    grid.save(tmp_path / "s.adg")
    loaded = adaptiso.load(tmp_path / "s.adg")
    loaded.save(tmp_path / "again.adg")
    assert (tmp_path / "again.adg").read_bytes() == (tmp_path / "s.adg").read_bytes()
    loaded.save(tmp_path / "s.adg")  # over the file it loaded, which it holds open
    assert (tmp_path / "s.adg").read_bytes() == (tmp_path / "again.adg").read_bytes()
    assert faces_as_points(loaded.extract(9.1)) == faces_as_points(grid.extract(9.1))


def test_a_whole_surface_of_a_grid_loaded_in_part_is_found_without_the_index(tmp_path):
    # extract(iso) reads the tetrahedra once, without building the index, and scans them for the
    # surface's (as the command line's extract does for up to 4 iso-values): the same arrays, in the
    # same order, as an extraction over the whole grid with its index.
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    grid.save(tmp_path / "s.adg")
    loaded = adaptiso.load(tmp_path / "s.adg")
    first, second = loaded.extract(9.1), loaded.extract(9.2)
    assert first.stats["scanned"] and second.stats["scanned"]
    indexed = grid.extractor().extract(9.1)  # the index's route
    assert "scanned" not in indexed.stats
    assert all(np.array_equal(a, b) for a, b in zip(first, indexed))
    assert first.stats["triangles"] == indexed.stats["triangles"] and first.stats["active_tetrahedra"] == indexed.stats["active_tetrahedra"]
    incremental = loaded.extractor().extract(9.2)  # reads the whole grid, with its index
    assert all(np.array_equal(a, b) for a, b in zip(second, incremental))
    assert "scanned" not in loaded.extract(9.2).stats


def test_prepare_leaves_the_index_until_an_extractor_needs_it(tmp_path):
    # prepare builds no extraction index (1.0-1.5 s and 0.8 GB of the CT bunny's): extract(iso)
    # scans, coarsen and save read none; extractor() builds it, once, as loading the file does.
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    assert "index" not in grid.stats["seconds"]
    grid.save(tmp_path / "s.adg")
    loaded = adaptiso.load(tmp_path / "s.adg")
    whole = loaded.extractor().extract(9.1)  # the loaded grid's own index
    for key in ("index_depth", "grid_bytes_per_vertex", "tree_depth"):
        assert grid.stats[key] == loaded.stats[key], key  # the figures the index will have
    first = grid.extract(9.1)
    assert first.stats["scanned"]
    coarse = grid.coarsen(0.2 * (grid.value_range[1] - grid.value_range[0]))
    assert coarse.stats["tree_depth"] == loaded.coarsen(0.2 * (grid.value_range[1] - grid.value_range[0])).stats["tree_depth"]
    near = grid.extract(9.1, distance=1)  # the hierarchy's query, made before the index
    incremental = grid.extractor().extract(9.1)
    assert all(np.array_equal(a, b) for a, b in zip(first, incremental))
    assert all(np.array_equal(a, b) for a, b in zip(whole, incremental))
    assert "scanned" not in grid.extract(9.1).stats  # the index, once built, serves the next ones
    assert all(np.array_equal(a, b) for a, b in zip(near, grid.extract(9.1, distance=1)))
    grid.save(tmp_path / "again.adg")
    assert (tmp_path / "s.adg").read_bytes() == (tmp_path / "again.adg").read_bytes()


def test_an_extractor_asked_while_another_thread_holds_the_grid_gets_the_index_too():
    # The index goes into a copy when another call holds the grid (here a distance query, running
    # while extractor() is asked): both answer, and the copy serves what follows.
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance((60, 61, 62), (29.5, 30.0, 30.5))), max_error=0.01, relative=True)
    results, errors = {}, []

    def query():
        try:
            for _ in range(20):
                results["near"] = grid.extract(20.1, distance=0.25, collapse=0)
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    t = threading.Thread(target=query)
    t.start()
    extractor = grid.extractor()
    t.join()
    assert not errors
    assert all(np.array_equal(a, b) for a, b in zip(extractor.extract(20.1), grid.extract(20.1)))
    assert all(np.array_equal(a, b) for a, b in zip(results["near"], grid.extract(20.1, distance=0.25, collapse=0)))


def test_load_in_part_reads_the_rest_once_for_two_threads(tmp_path):
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    grid.save(tmp_path / "s.adg")
    loaded = adaptiso.load(tmp_path / "s.adg")
    out = [None, None]

    def run(k):
        out[k] = faces_as_points(loaded.extract(9.1 + 0.1 * k))

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert out == [faces_as_points(grid.extract(9.1)), faces_as_points(grid.extract(9.2))]


def test_load_in_part_names_the_file_when_its_tetrahedra_lie(tmp_path):
    # Tetrahedra that lie (two corners swapped, the checksum made good) pass the partial load, which
    # reads them for the checksum only, and are refused when a route reads them, naming the file.
    import struct
    import zlib
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance()), max_error=0.02, relative=True)
    path = tmp_path / "lie.adg"
    grid.save(path)
    data = bytearray(path.read_bytes())
    m, n = struct.unpack_from("<QQ", data, 24)
    tets = 64 + m + n * (12 + 8 + 12)
    a, b = struct.unpack_from("<II", data, tets)
    struct.pack_into("<II", data, tets, b, a)
    struct.pack_into("<I", data, len(data) - 4, zlib.crc32(bytes(data[:-4])))
    path.write_bytes(bytes(data))
    loaded = adaptiso.load(path)
    assert loaded.extract(9.1, distance=1.0).faces.shape[0] > 0
    with pytest.raises(OSError, match="lie.adg") as e:
        loaded.extract(9.1)
    assert "/proc/" not in str(e.value)
    with pytest.raises(OSError):
        adaptiso.load(path).extractor()
    with pytest.raises(OSError, match="lie.adg"):
        adaptiso.load(path, lazy=False)


def test_delaunay_grid_loads_whole(tmp_path):
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance((16, 17, 18), (7.5, 8.0, 8.5))), grid="delaunay", max_error=0.05,
                            relative=True)
    grid.save(tmp_path / "d.adg")
    loaded = adaptiso.load(tmp_path / "d.adg")
    eager = adaptiso.load(tmp_path / "d.adg", lazy=False)
    os.remove(tmp_path / "d.adg")
    assert faces_as_points(eager.extract(5.0)) == faces_as_points(grid.extract(5.0))
    assert loaded.tetrahedron_count == grid.tetrahedron_count
    assert faces_as_points(loaded.extract(5.0)) == faces_as_points(grid.extract(5.0))


def test_coarser_error_from_the_hierarchy():
    v = adaptiso.Volume(sphere_distance())
    grid = adaptiso.prepare(v, max_error=0.005, relative=True)
    fine = grid.extract(10.0)[1].shape[0]
    coarse = grid.extract(10.0, max_error=0.05, relative=True)[1].shape[0]
    assert coarse < fine
    assert grid.coarsen(1.0).tetrahedron_count < grid.tetrahedron_count


def test_min_piece_keeps_the_pieces_the_distance_drops():
    rng = np.random.default_rng(7)
    grid = adaptiso.prepare(adaptiso.Volume(rng.random((24, 23, 22)).astype(np.float32)), max_error=0.02, relative=True)
    dropped = grid.extract(0.5, distance=2.0, collapse=0)
    kept = grid.extract(0.5, distance=2.0, collapse=0, min_piece=0)
    assert dropped.stats["specks_dropped"] > 0 and kept.stats["specks_dropped"] == 0  # noise: many small pieces
    assert kept.faces.shape[0] == dropped.faces.shape[0] + dropped.stats["speck_triangles"]
    more = grid.extract(0.5, distance=2.0, collapse=0, min_piece=4.0)
    assert more.stats["specks_dropped"] > dropped.stats["specks_dropped"]


def test_surface_within_a_distance_has_the_full_surfaces_vertices():
    v = adaptiso.Volume(sphere_distance((50, 51, 52), (24.5, 25.0, 25.5)))
    grid = adaptiso.prepare(v, max_error=0.005, relative=True)
    full = grid.extract(15.0)
    near = grid.extract(15.0, distance=1.0)
    assert 0 < near.faces.shape[0] < full.faces.shape[0] / 2
    assert near.stats["distance_voxels"] == 1.0 and near.stats["triangles"] == near.faces.shape[0]
    # Every vertex is one of the full surface's, bit for bit.
    assert set(map(tuple, near.vertices.tolist())) <= set(map(tuple, full.vertices.tolist()))
    # Within the distance of the sphere of radius 15 (the grid's surface lies within its error of it).
    radius = np.linalg.norm(near.vertices[near.faces].mean(axis=1) - [24.5, 25.0, 25.5], axis=1)
    assert np.all(np.abs(radius - 15.0) < 1.0 + 0.2)
    zero = grid.extract(15.0, distance=0)
    assert np.array_equal(zero.faces, full.faces) and np.array_equal(zero.vertices, full.vertices)
    with pytest.raises(ValueError):
        grid.extract(15.0, distance=-1)
    with pytest.raises(ValueError):
        grid.extract(15.0, distance=1.0, max_error=0.1)
    # Rounds of edge collapses: fewer triangles, the same vertices; 0 is the march alone.
    marched = grid.extract(15.0, distance=1.0, collapse=0)
    assert near.faces.shape[0] < marched.faces.shape[0] and near.stats["collapsed_edges"] > 0
    assert marched.stats["collapsed_edges"] == 0
    assert near.stats["specks_dropped"] == 0 and near.stats["speck_triangles"] == 0  # one sphere: no speck
    assert near.stats["min_piece_voxels"] == 1.0  # the distance, by default
    assert grid.extract(15.0, distance=1.0, min_piece=0).stats["min_piece_voxels"] == 0.0
    with pytest.raises(ValueError):
        grid.extract(15.0, min_piece=1.0)  # needs distance
    with pytest.raises(ValueError):
        grid.extract(15.0, distance=1.0, min_piece=-1)
    assert set(map(tuple, near.vertices.tolist())) <= set(map(tuple, marched.vertices.tolist()))
    for bad in (-1, 17):
        with pytest.raises(ValueError):
            grid.extract(15.0, distance=1.0, collapse=bad)
    with pytest.raises(ValueError):
        grid.extract(15.0, collapse=1)


def test_simplify_keeps_vertices_and_the_distance_checked():
    v = adaptiso.Volume(sphere_distance((40, 40, 40), (19.5, 19.5, 19.5)))
    grid = adaptiso.prepare(v, max_error=0.005, relative=True)
    full = grid.extract(12.0)
    for checked in (False, True):
        s = adaptiso.simplify(full, 0.5, checked=checked)
        assert isinstance(s, adaptiso.Mesh) and s.axes == full.axes
        assert 0 < s.faces.shape[0] < full.faces.shape[0] / 2
        assert s.stats["checked"] is checked and s.stats["triangles_after"] == s.faces.shape[0]
        # Kept vertices are the full surface's, unmoved, with their normals.
        assert set(map(tuple, s.vertices.tolist())) <= set(map(tuple, full.vertices.tolist()))
        assert s.normals.shape == s.vertices.shape
        radius = np.linalg.norm(s.vertices[s.faces].mean(axis=1) - [19.5, 19.5, 19.5], axis=1)
        assert np.all(np.abs(radius - 12.0) < 0.5 + 0.3)
    # A plain tuple works; bad input is a ValueError.
    assert adaptiso.simplify((full.vertices, full.faces), 0).faces.shape == full.faces.shape
    with pytest.raises(ValueError):
        adaptiso.simplify(full, -1)
    with pytest.raises(ValueError):
        adaptiso.simplify((full.vertices, full.faces + full.vertices.shape[0]), 0.5)


def test_cell_floor_gives_fewer_tetrahedra_at_a_measured_error():
    rng = np.random.default_rng(3)
    a = sphere_distance() + rng.uniform(0, 5, size=sphere_distance().shape).astype(np.float32)
    grid = adaptiso.prepare(adaptiso.Volume(a), max_error=0.01, relative=True)
    e0 = grid.stats["error_bound"]
    floored = grid.coarsen(e0, cell_floor=2)
    assert floored.tetrahedron_count < grid.coarsen(e0).tetrahedron_count
    assert floored.stats["error_bound"] > e0
    assert floored.extract(10.0)[1].shape[0] < grid.extract(10.0)[1].shape[0]
    with pytest.raises(ValueError):
        grid.coarsen(e0, cell_floor=-1)


def test_same_mesh_as_the_command_line(tmp_path):
    if not CLI:
        pytest.skip("ADAPTISO_CLI not set")
    a = sphere_distance()
    v = adaptiso.Volume(a)
    grid = adaptiso.prepare(v, max_error=0.02, relative=True)
    grid.save(str(tmp_path / "py.adg"))
    verts, faces, normals = grid.extract(iso=8.0)
    adaptiso.write_mesh(str(tmp_path / "py.ply"), verts, faces, normals)
    subprocess.run([CLI, "extract", str(tmp_path / "py.adg"), "--iso", "8", "-o", str(tmp_path / "cli.ply"), "--quiet"], check=True)
    assert (tmp_path / "py.ply").read_bytes() == (tmp_path / "cli.ply").read_bytes()


def test_marching_cubes_matches_scikit_image_on_a_smooth_field():
    skimage = pytest.importorskip("skimage.measure")
    a = sphere_distance((40, 41, 42), (20.3, 19.7, 21.1))
    for spacing in ((1.0, 1.0, 1.0), (2.0, 0.5, 1.0)):
        ours = adaptiso.marching_cubes(a, 12.5, spacing=spacing)
        theirs = skimage.marching_cubes(a, 12.5, spacing=spacing, method="lorensen")
        assert ours[1].shape == theirs[1].shape
        assert abs(area(ours[0], ours[1]) / area(theirs[0], theirs[1]) - 1) < 1e-3
        # The same vertices, in the array's index order scaled by spacing.
        assert np.allclose(np.sort(ours[0], axis=0), np.sort(theirs[0], axis=0), atol=1e-4)
        assert len(ours) == 4 and ours[3].shape == (ours[0].shape[0],)


def surface_pieces(verts, faces):
    """The surface's connected pieces, each as the sorted tuple of its vertices' rounded positions."""
    parent = list(range(len(verts)))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b, c in faces.astype(np.int64):
        parent[find(b)] = find(a)
        parent[find(c)] = find(a)
    pieces = {}
    for i, p in enumerate(np.round(verts * 2) / 2):
        pieces.setdefault(find(i), []).append(tuple(p))
    return sorted(tuple(sorted(p)) for p in pieces.values())


def test_marching_cubes_connects_every_cube_configuration_as_scikit_image():
    # All 254 cut configurations of one cube, corners 0 or 1 at level 0.5: the same triangle count
    # and the same cut edges grouped into the same surface pieces as the classic table (ambiguous
    # faces included). Only the triangulation of a piece with 4 to 7 cut edges may differ.
    skimage = pytest.importorskip("skimage.measure")
    for mask in range(1, 255):
        a = np.array([(mask >> c) & 1 for c in range(8)], dtype=np.float32).reshape(2, 2, 2)
        ours = adaptiso.marching_cubes(a, 0.5)
        theirs = skimage.marching_cubes(a, 0.5, method="lorensen")
        assert ours[1].shape == theirs[1].shape, mask
        assert surface_pieces(ours[0], ours[1]) == surface_pieces(theirs[0], theirs[1]), mask


def flying_edges(a, level):
    """vtkFlyingEdges3D's surface of array a[z, y, x], vertices in the array's index order."""
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy
    image = vtk.vtkImageData()
    image.SetDimensions(a.shape[2], a.shape[1], a.shape[0])
    image.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(a, dtype=np.float32).ravel(), deep=1))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, level)
    fe.ComputeNormalsOff()
    fe.Update()
    out = fe.GetOutput()
    verts = vtk_to_numpy(out.GetPoints().GetData())[:, ::-1].astype(np.float64)
    return verts, vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)


def test_marching_cubes_differs_from_flying_edges_only_where_a_piece_has_four_or_more_cut_edges():
    # Why `mc` gives VTK's triangle count but less area on integer volumes (issue "The paper's
    # figures"): over all 254 configurations of one cube, with corner values off the midpoints,
    # vtkFlyingEdges3D and scikit-image's classic table give the same area, and ours has the same
    # vertices and triangle count; the area differs only where a surface piece has 4 to 7 cut
    # edges, which the classic table splits by a per-case pattern and ours fans from one edge.
    skimage = pytest.importorskip("skimage.measure")
    rng = np.random.default_rng(7)
    differ = {}
    for mask in range(1, 255):
        above = np.array([(mask >> c) & 1 for c in range(8)]).reshape(2, 2, 2)  # corner c = x + 2y + 4z
        a = np.where(above == 1, rng.uniform(0.6, 1.0, above.shape), rng.uniform(0.0, 0.4, above.shape)).astype(np.float32)
        ours = adaptiso.marching_cubes(a, 0.5)
        fe = flying_edges(a, 0.5)
        classic = skimage.marching_cubes(a, 0.5, method="lorensen")
        assert ours[1].shape == fe[1].shape == classic[1].shape, mask
        assert np.allclose(np.sort(ours[0], axis=0), np.sort(fe[0], axis=0), atol=1e-5), mask
        assert area(*fe) == pytest.approx(area(classic[0], classic[1]), rel=1e-6), mask
        largest = max(len(p) for p in surface_pieces(np.round(ours[0] * 2) / 2, ours[1]))
        if abs(area(ours[0], ours[1]) - area(*fe)) > 1e-6 * area(*fe):
            differ[mask] = largest
    assert differ and min(differ.values()) >= 4  # never a configuration made of triangles alone
    # A small constructed volume: one cube with the corners 0, 1, 2 and 4 above 0.5 (0x17), i.e.
    # one hexagon, made non-planar by its values. Same six vertices, four triangles each, and the
    # classic table's zigzag has more area than our fan.
    # (1.398 against 1.422 voxels², 1.7 %).
    a = np.array([1.0, 0.55, 0.55, 0.45, 1.0, 0.0, 0.0, 0.4], dtype=np.float32).reshape(2, 2, 2)
    ours, fe = adaptiso.marching_cubes(a, 0.5), flying_edges(a, 0.5)
    assert ours[1].shape == fe[1].shape == (4, 3)
    assert area(ours[0], ours[1]) < area(*fe) - 0.02


@pytest.mark.skipif(not os.path.isdir(DATA), reason=f"no shared data at {DATA}")
def test_marching_cubes_matches_scikit_image_on_a_real_volume():
    skimage = pytest.importorskip("skimage.measure")
    path = os.path.join(DATA, "ct_chest_lidc2.nhdr")
    if not os.path.exists(path):
        pytest.skip(f"{path} absent")
    v = adaptiso.read(path)
    spacing = tuple(v.spacing[::-1])
    ours = adaptiso.marching_cubes(v.array, 200.5, spacing=spacing)
    theirs = skimage.marching_cubes(v.array, 200.5, spacing=spacing, method="lorensen")
    # The same triangle count and the same vertices (the same interpolation, no margin off the
    # voxels, as scikit-image).
    assert ours[1].shape == theirs[1].shape
    o, t = ours[0][np.lexsort(ours[0].T)], theirs[0][np.lexsort(theirs[0].T)]
    assert o.shape == t.shape and np.array_equal(o, t)
    # Pieces with 4 to 7 cut edges are fanned from one edge here and triangulated per case by the
    # classic table there, which moves the area of this noisy surface by about 0.4 % (both lie 2.5 to
    # 3 % above the area of the trilinear interpolant's surface: bench/results/HISTORY.md).
    assert abs(area(ours[0], ours[1]) / area(theirs[0], theirs[1]) - 1) < 0.01
    # method="lorensen" is their table: the same triangles, wound the same way.
    classic = adaptiso.marching_cubes(v.array, 200.5, spacing=spacing, method="lorensen")
    tri_o = np.round(classic[0].astype(np.float64), 4)[classic[1]]
    tri_t = np.round(theirs[0].astype(np.float64), 4)[theirs[1]]
    assert sorted(rotated(x) for x in tri_o.tolist()) == sorted(rotated(x) for x in tri_t.tolist())


def rotated(tri):
    """A triangle's corners rotated to start at the smallest: the same tuple for the same winding."""
    tri = [tuple(p) for p in tri]
    i = tri.index(min(tri))
    return tuple(tri[i:] + tri[:i])


def test_reduce_gives_voxel_indices_in_array_order():
    a = sphere_distance()
    kept = adaptiso.reduce(adaptiso.Volume(a), max_error=0.05, relative=True)
    assert kept.dtype == np.int64 and kept.shape[1] == 3
    assert [0, 0, 0] in kept.tolist() and [29, 30, 31] in kept.tolist()  # the corners, [z, y, x]
    assert (kept.max(axis=0) <= np.array(a.shape) - 1).all()


def test_errors_are_python_exceptions_with_the_command_lines_messages(tmp_path):
    v = adaptiso.Volume(sphere_distance())
    with pytest.raises(ValueError, match="max_error: must be a non-negative number"):
        adaptiso.prepare(v, max_error=-1)
    with pytest.raises(ValueError, match="grid"):
        adaptiso.prepare(v, grid="voronoi")
    with pytest.raises(ValueError, match="dtype"):
        adaptiso.Volume(np.zeros((2, 2, 2), dtype=np.complex64))
    with pytest.raises(ValueError, match="3 dimensions"):
        adaptiso.Volume(np.zeros((2, 2), dtype=np.float32))
    with pytest.raises(OSError, match="nonexistent"):
        adaptiso.read(str(tmp_path / "nonexistent.nrrd"))
    bad = tmp_path / "bad.adg"
    bad.write_bytes(b"garbage")
    with pytest.raises(OSError, match="bad.adg"):
        adaptiso.load(str(bad))
    with pytest.raises(ValueError, match="faces"):
        adaptiso.write_mesh(str(tmp_path / "m.ply"), np.zeros((3, 3), np.float32), np.array([[0, 1, 5]], np.uint32))
    if CLI:  # the same one line as the command line, without its flag spelling
        r = subprocess.run([CLI, "generate", "sphere", "--size", "8", "-o", str(tmp_path / "s.nrrd")], check=True)
        r = subprocess.run([CLI, "prepare", str(tmp_path / "s.nrrd"), "--max-error", "-1", "-o", str(tmp_path / "x.adg")],
                           capture_output=True, text=True)
        assert r.returncode == 2 and "must be a non-negative number, got -1" in r.stderr


def test_extract_from_two_threads_at_once():
    grid = adaptiso.prepare(adaptiso.Volume(sphere_distance((60, 60, 60), (30, 30, 30))), max_error=0.005, relative=True)
    expected = {iso: grid.extract(iso)[1].shape[0] for iso in (8.0, 12.0, 20.0)}
    results, errors = [], []

    def work(iso):
        try:
            for _ in range(5):
                results.append((iso, grid.extract(iso)[1].shape[0]))
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=work, args=(iso,)) for iso in expected]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(results) == 15 and all(n == expected[iso] for iso, n in results)


def test_the_gil_is_released_while_preparing():
    a = sphere_distance((96, 96, 96), (48, 48, 48))
    v = adaptiso.Volume(a)
    ticks = []
    done = threading.Event()

    def tick():
        while not done.is_set():
            ticks.append(1)
            done.wait(0.001)

    t = threading.Thread(target=tick)
    t.start()
    start = len(ticks)
    adaptiso.prepare(v, max_error=0.001, relative=True, verify=True)
    during = len(ticks) - start
    done.set()
    t.join()
    assert during > 3, "the other thread did not run while prepare() worked"


def test_prepare_file_writes_what_prepare_then_save_writes(tmp_path):
    v = adaptiso.Volume(sphere_distance())
    saved, streamed = str(tmp_path / "saved.adg"), str(tmp_path / "streamed.adg")
    adaptiso.prepare(v, max_error=0.02, relative=True).save(saved)
    stats = adaptiso.prepare_file(v, streamed, max_error=0.02, relative=True)
    assert open(saved, "rb").read() == open(streamed, "rb").read()
    assert stats["tetrahedra"] == adaptiso.load(streamed).tetrahedron_count
    assert "save" in stats["seconds"] and "index" not in stats["seconds"]  # the file leaves it out
    assert v.array.shape == sphere_distance().shape  # lent, not taken
    with pytest.raises(OSError):
        adaptiso.prepare_file(v, str(tmp_path / "missing" / "x.adg"))
    with pytest.raises(ValueError):
        adaptiso.prepare_file(v, streamed, max_error=-1)
