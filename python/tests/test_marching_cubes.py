"""adaptiso.marching_cubes as a drop-in for skimage.measure.marching_cubes (issues 39 and 41):
every argument, the same results, dtypes and exceptions, and scikit-image's own test module."""
import inspect
import os
import shutil
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest

import adaptiso

skimage_measure = pytest.importorskip("skimage.measure")
sk_marching_cubes = skimage_measure.marching_cubes
SKIMAGE_TESTS = os.path.join(os.path.dirname(skimage_measure.__file__), "tests", "test_marching_cubes.py")


def sphere(shape=(20, 21, 22), centre=(10.1, 9.8, 10.3)):
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]]
    return np.sqrt((z - centre[0]) ** 2 + (y - centre[1]) ** 2 + (x - centre[2]) ** 2).astype(np.float32)


def noise(shape=(9, 10, 11), seed=5):
    return np.random.default_rng(seed).uniform(0, 1, shape).astype(np.float32)


def oriented_triangles(verts, faces):
    """Each triangle as its corners (rounded) rotated to start at the smallest: equal lists mean the
    same triangles wound the same way, whatever the vertex and face order."""
    out = []
    for tri in np.round(np.asarray(verts, dtype=np.float64)[np.asarray(faces)], 4).tolist():
        tri = [tuple(p) for p in tri]
        i = tri.index(min(tri))
        out.append(tuple(tri[i:] + tri[:i]))
    return sorted(out)


def by_position(mesh):
    """verts, normals, values sorted by vertex position."""
    order = np.lexsort(np.asarray(mesh[0]).T)
    return np.asarray(mesh[0])[order], np.asarray(mesh[2])[order], np.asarray(mesh[3])[order]


def test_marching_cubes_takes_every_argument_of_scikit_images_signature():
    ours = inspect.signature(adaptiso.marching_cubes).parameters
    theirs = inspect.signature(sk_marching_cubes).parameters
    assert list(ours) == list(theirs)
    assert [p.kind for p in ours.values()] == [p.kind for p in theirs.values()]
    a = sphere()
    mask = np.ones(a.shape, dtype=bool)
    m = adaptiso.marching_cubes(a, 6.5, spacing=(1.0, 2.0, 0.5), gradient_direction="ascent", step_size=2, allow_degenerate=False,
                                method="lorensen", mask=mask)
    t = sk_marching_cubes(a, 6.5, spacing=(1.0, 2.0, 0.5), gradient_direction="ascent", step_size=2, allow_degenerate=False,
                          method="lorensen", mask=mask)
    assert oriented_triangles(m[0], m[1]) == oriented_triangles(t[0], t[1])


@pytest.mark.parametrize("gradient_direction", ["descent", "ascent"])
@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (2.0, 0.5, 1.0)])
@pytest.mark.parametrize("volume", [noise(), sphere()], ids=["noise", "sphere"])
def test_lorensen_gives_scikit_images_triangles_wound_the_same_way(volume, spacing, gradient_direction):
    # Issue 41: every face was wound the other way. The classic table here is scikit-image's, so
    # the oriented triangles must be the same set, for both gradient directions.
    level = 0.5 if volume.max() <= 1 else 6.5
    ours = adaptiso.marching_cubes(volume, level, spacing=spacing, gradient_direction=gradient_direction, method="lorensen")
    theirs = sk_marching_cubes(volume, level, spacing=spacing, gradient_direction=gradient_direction, method="lorensen")
    assert oriented_triangles(ours[0], ours[1]) == oriented_triangles(theirs[0], theirs[1])
    vo, no, valo = by_position(ours)
    vt, nt, valt = by_position(theirs)
    assert np.array_equal(vo, vt)
    # values: the largest value range of the cubes around each vertex, as theirs.
    assert np.allclose(valo, valt, rtol=1e-6)
    # Normals towards lower values whichever the gradient direction (theirs do not flip either).
    agree = np.mean(np.sum(no * nt, axis=1) > 0)
    assert agree > (0.99 if volume.max() > 1 else 0.85), agree


@pytest.mark.parametrize("gradient_direction", ["descent", "ascent"])
def test_lewiner_winds_faces_and_orients_normals_as_scikit_image(gradient_direction):
    # Issue 41: 'ascent' flipped our normals where scikit-image's stay, and the faces were wound the
    # other way. Our 'lewiner' triangulates some pieces differently, so compare the relation
    # between each face's winding and the outward direction of a sphere.
    a = sphere()
    centre = np.array([10.1, 9.8, 10.3])
    for mesh in (adaptiso.marching_cubes(a, 6.5, gradient_direction=gradient_direction), sk_marching_cubes(a, 6.5, gradient_direction=gradient_direction)):
        v, f, n = mesh[0], mesh[1], mesh[2]
        face_normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        outward_faces = np.mean(np.sum(face_normal * (v[f[:, 0]] - centre), axis=1) > 0)
        assert outward_faces == (1.0 if gradient_direction == "descent" else 0.0)
        assert np.all(np.sum(n * (v - centre), axis=1) < 0)  # towards the lower values inside


def test_level_equal_to_the_maximum_raises_as_scikit_image():
    # Issue 41: gave triangles where scikit-image raises (a voxel equal to the level is outside).
    a = np.zeros((5, 5, 5), np.float32)
    a[2, 2, 2] = 1
    for mc in (adaptiso.marching_cubes, sk_marching_cubes):
        with pytest.raises(RuntimeError, match="No surface found"):
            mc(a, 1.0)
    # And the minimum does give a surface, for both.
    assert len(adaptiso.marching_cubes(a, 0.0)[1]) == len(sk_marching_cubes(a, 0.0, method="lorensen")[1]) > 0


BAD_CALLS = {
    "a 2x2x1 volume (was an empty mesh)": (lambda mc: mc(np.zeros((2, 2, 1)), 0), ValueError),
    "a 2x2x1 volume, level 1": (lambda mc: mc(np.zeros((2, 2, 1)), 1), ValueError),
    "a spacing of the wrong length (was TypeError)": (lambda mc: mc(np.ones((3, 3, 3)), 1, spacing=(1, 2)), ValueError),
    "a 2D volume": (lambda mc: mc(np.zeros((20, 20)), 0), ValueError),
    "a level below the data": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), -1), ValueError),
    "a level above the data": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 27), ValueError),
    "an empty mask": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 13, mask=np.array([])), ValueError),
    "a mask of another shape": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 13, mask=np.ones((3, 3, 2), bool)), ValueError),
    "an all-False mask": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 13, mask=np.zeros((3, 3, 3), bool)), RuntimeError),
    "step_size 0": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 13, step_size=0), ValueError),
    "an unknown method": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 13, method="dual"), ValueError),
    "an unknown gradient direction": (lambda mc: mc(np.arange(27.0).reshape(3, 3, 3), 13, gradient_direction="up"), ValueError),
    "a constant volume": (lambda mc: mc(np.ones((3, 3, 3)), 1), RuntimeError),
}


@pytest.mark.parametrize("case", list(BAD_CALLS))
def test_the_same_exception_as_scikit_image_for_the_same_mistake(case):
    call, expected = BAD_CALLS[case]
    with pytest.raises(expected):
        call(sk_marching_cubes)
    with pytest.raises(expected):
        call(adaptiso.marching_cubes)


@pytest.mark.parametrize("step", [2, 3])
def test_step_size_marches_every_step_th_voxel_as_scikit_image(step):
    a = noise((13, 14, 15), seed=2)
    ours = adaptiso.marching_cubes(a, 0.5, step_size=step, method="lorensen")
    theirs = sk_marching_cubes(a, 0.5, step_size=step, method="lorensen")
    assert oriented_triangles(ours[0], ours[1]) == oriented_triangles(theirs[0], theirs[1])
    assert np.allclose(by_position(ours)[2], by_position(theirs)[2], rtol=1e-6)


def test_mask_marches_the_cubes_whose_far_corner_is_true_as_scikit_image():
    # scikit-image gates a cube on mask[z+1, y+1, x+1] (its issue 8202 discusses all eight
    # corners; until it changes, the same cubes here).
    a = noise((10, 11, 12), seed=3)
    mask = np.random.default_rng(4).uniform(size=a.shape) > 0.4
    ours = adaptiso.marching_cubes(a, 0.5, mask=mask, method="lorensen")
    theirs = sk_marching_cubes(a, 0.5, mask=mask, method="lorensen")
    assert oriented_triangles(ours[0], ours[1]) == oriented_triangles(theirs[0], theirs[1])
    # Masked slabs leave vertices on the planes between the library's slabs to one slab only.
    big = sphere((64, 40, 40), (31.7, 19.6, 20.2))
    mask = np.zeros(big.shape, bool)
    mask[::2] = True
    ours = adaptiso.marching_cubes(big, 15.5, mask=mask, method="lorensen")
    theirs = sk_marching_cubes(big, 15.5, mask=mask, method="lorensen")
    assert oriented_triangles(ours[0], ours[1]) == oriented_triangles(theirs[0], theirs[1])
    assert len(ours[0]) == len(theirs[0])
    assert len(set(map(tuple, ours[0].tolist()))) == len(ours[0])  # one vertex per cut edge


def test_allow_degenerate_false_removes_zero_area_triangles():
    # A sphere whose level passes through voxels: scikit-image's small test volume.
    from skimage.draw import ellipsoid

    s = ellipsoid(1, 1, 1, levelset=True)
    with_degenerate = adaptiso.marching_cubes(s, 0)
    ours = adaptiso.marching_cubes(s, 0, allow_degenerate=False)
    theirs = sk_marching_cubes(s, 0, allow_degenerate=False, method="lorensen")
    t = ours[0][ours[1]]
    areas = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    assert len(with_degenerate[1]) > len(ours[1]) == 8 and np.all(areas > 0)
    assert oriented_triangles(ours[0], ours[1]) == oriented_triangles(theirs[0], theirs[1])
    assert len(ours[0]) == len(theirs[0]) == 6 and ours[1].max() == 5


def test_results_have_scikit_images_dtypes():
    a = sphere()
    for kwargs in ({}, {"spacing": (1.0, 2.0, 3.0)}, {"allow_degenerate": False}, {"spacing": (1.0, 2.0, 3.0), "allow_degenerate": False}):
        ours = adaptiso.marching_cubes(a, 6.5, **kwargs)
        theirs = sk_marching_cubes(a, 6.5, **kwargs)
        assert [x.dtype for x in ours] == [x.dtype for x in theirs], kwargs
        assert len(ours) == 4 and isinstance(ours, tuple)


def test_level_defaults_to_the_middle_of_the_value_range():
    a = noise()
    assert adaptiso.marching_cubes(a).stats["iso"] == pytest.approx(0.5 * (a.min() + a.max()))


def test_other_dtypes_are_converted_as_scikit_image_converts_them():
    a = sphere() < 6.5  # bool
    ours = adaptiso.marching_cubes(a, 0.5, method="lorensen")
    theirs = sk_marching_cubes(a, 0.5, method="lorensen")
    assert oriented_triangles(ours[0], ours[1]) == oriented_triangles(theirs[0], theirs[1])
    big = (sphere() * 1e6).astype(np.int64)
    assert len(adaptiso.marching_cubes(big, 6.5e6)[1]) == len(sk_marching_cubes(big, 6.5e6, method="lorensen")[1])


def peak_traced_bytes(call):
    """numpy's allocations (traced by tracemalloc) at their peak during call()."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        call()
        return tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()


def test_a_c_contiguous_volume_is_never_copied():
    a = np.zeros((128, 256, 256), np.float32)  # 32 MiB
    a[40:90, 60:200, 60:200] = 1
    copy_size = a.nbytes
    assert peak_traced_bytes(lambda: adaptiso.marching_cubes(a, 0.5)) < copy_size // 8
    # Fortran order (nibabel's memmaps) goes through the transpose, a view: no copy either, and the
    # same surface in the same index order.
    f = np.asfortranarray(a)
    assert peak_traced_bytes(lambda: adaptiso.marching_cubes(f, 0.5)) < copy_size // 8
    assert oriented_triangles(*adaptiso.marching_cubes(f[:60], 0.5)[:2]) == oriented_triangles(*adaptiso.marching_cubes(a[:60], 0.5)[:2])
    # The measure sees a copy where one is needed (a strided view).
    assert peak_traced_bytes(lambda: adaptiso.marching_cubes(a[:, :, ::2], 0.5)) >= copy_size // 2


def test_volumes_from_the_buffer_protocol_and___array__():
    a = sphere()

    class Wrapped:
        def __array__(self, dtype=None):
            return a

    reference = adaptiso.marching_cubes(a, 6.5)
    for volume in (memoryview(a), Wrapped()):
        m = adaptiso.marching_cubes(volume, 6.5)
        assert np.array_equal(m[0], reference[0]) and np.array_equal(m[1], reference[1])


def test_nan_in_the_volume_is_refused():
    a = sphere()
    a[3, 4, 5] = np.nan
    with pytest.raises(ValueError, match=r"1 voxel\(s\) are NaN or Inf \(first at voxel 5,4,3\)"):
        adaptiso.marching_cubes(a, 6.5)


def test_scikit_images_own_test_module_passes_against_ours(tmp_path):
    if not os.path.exists(SKIMAGE_TESTS):
        pytest.skip(f"{SKIMAGE_TESTS} absent")
    shutil.copy(SKIMAGE_TESTS, tmp_path / "test_marching_cubes.py")
    shutil.copy(os.path.join(os.path.dirname(__file__), "skimage_shim.py"), tmp_path / "conftest.py")
    calls = tmp_path / "calls"
    # Excluded: this test exercises scikit-image's private '_lorensen' function alone (a mask with
    # it must raise NotImplementedError); nothing of adaptiso runs in it.
    excluded = ["test_masked_marching_cubes_old_lewiner"]
    env = dict(os.environ, ADAPTISO_SHIM_CALLS=str(calls), PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rA", "test_marching_cubes.py", "-k",
                        " and ".join(f"not {name}" for name in excluded)],
                       cwd=tmp_path, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    passed = [line for line in r.stdout.splitlines() if line.startswith("PASSED")]
    assert len(passed) == 8 and "1 deselected" in r.stdout, r.stdout
    assert int(calls.read_text()) >= 10  # the calls went to adaptiso
