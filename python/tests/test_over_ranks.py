"""adaptiso.prepare and prepare_file over an mpi4py communicator (issue 38): under mpiexec with 2 and
3 processes, each reading a memmap, the grid file is byte for byte the one a single process writes;
an error on any rank raises on every rank instead of leaving the others waiting. adaptiso.load over
one: every rank's surfaces are one process's, and another file or other parts on one rank are
refused by all alike. The in-process
tests need neither MPI nor mpi4py."""
import gzip
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import adaptiso

HERE = os.path.dirname(os.path.abspath(__file__))
MPIEXEC = shutil.which("mpiexec")


def have_mpi4py():
    return subprocess.run([sys.executable, "-c", "import mpi4py"], capture_output=True).returncode == 0


needs_mpi = pytest.mark.skipif(
    MPIEXEC is None or not have_mpi4py(),
    reason="needs mpiexec (openmpi-bin) and mpi4py (python3-mpi4py) for this interpreter; scripts/deps.sh installs both",
)


def field(shape=(23, 29, 37), seed=5):
    """A smooth field with noise and a flat slab, odd and unequal sizes, array[z, y, x]."""
    rng = np.random.default_rng(seed)
    z, y, x = np.mgrid[0 : shape[0], 0 : shape[1], 0 : shape[2]].astype(np.float32)
    f = np.sin(x / 5.0) * np.cos(y / 7.0) + z / 9.0 + 0.05 * rng.standard_normal(shape).astype(np.float32)
    f[:, :, 20:26] = 0.25  # a brick face (side 8 at x = 24) through a flat region
    return f.astype(np.float32)


def one_process_grid(tmp_path, array, spacing, options):
    path = tmp_path / "one.adg"
    adaptiso.prepare(adaptiso.Volume(array, spacing=spacing), **options).save(path)
    return path.read_bytes()


def mpi_run(tmp_path, ranks, job):
    job_path = tmp_path / f"job-{ranks}.json"
    job_path.write_text(json.dumps(job))
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1",
               OMPI_MCA_btl="self,vader", OMPI_MCA_btl_vader_single_copy_mechanism="none")
    # A rank left waiting would hang the job: fail after 300 s instead.
    out = subprocess.run([MPIEXEC, "-n", str(ranks), sys.executable, "-m", "mpi4py", os.path.join(HERE, "mpi_job.py"), str(job_path)],
                         capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    lines = []
    for r in range(ranks):
        path = f"{job['output']}.rank-{r}"
        assert os.path.exists(path), out.stdout + out.stderr
        lines.append(open(path, encoding="utf-8").read().rstrip("\n"))
    return lines


@needs_mpi
@pytest.mark.parametrize("ranks, route, options", [
    (2, "prepare", {"max_error": 0.05}),
    (3, "prepare", {"max_error": 0.05}),
    (2, "prepare", {"max_displacement": 0.5}),
    (3, "prepare_file", {"max_error": 0.02, "relative": True}),
])
def test_prepare_over_mpi_ranks_writes_the_one_process_grid_from_memmaps(tmp_path, ranks, route, options):
    array = field()
    np.save(tmp_path / "f.npy", array)
    spacing = (1.0, 0.8, 1.5)
    expected = one_process_grid(tmp_path, array, spacing, options)
    out = tmp_path / "ranks.adg"
    lines = mpi_run(tmp_path, ranks, {"npy": str(tmp_path / "f.npy"), "spacing": spacing, "options": options, "route": route,
                                      "brick_side": 8, "output": str(out)})
    assert lines == [f"rank {r}: ok" for r in range(ranks)]
    assert out.read_bytes() == expected
    bricks = json.loads((tmp_path / "ranks.adg.bricks.json").read_text())
    assert bricks["ranks"] == ranks and bricks["brick_side"] == 8 and bricks["bricks"] == 5 * 4 * 3
    assert bricks["bricks_per_rank"] == [len(range(r, 60, ranks)) for r in range(ranks)]
    assert bricks["bytes_exchanged"] > 0 and all(p > 10_000_000 for p in bricks["peak_bytes_per_rank"]), bricks
    assert bricks["ranks_read"] == "volume in memory"


@needs_mpi
def test_prepare_over_mpi_ranks_without_a_brick_side_takes_the_default_for_the_lattice(tmp_path):
    # The 41×29×25 lattice of field(): at 16 a side 12 bricks, at least 4 for each of 2 ranks; at 32, 4.
    array = field()
    np.save(tmp_path / "f.npy", array)
    options = {"max_error": 0.05}
    expected = one_process_grid(tmp_path, array, (1.0, 1.0, 1.0), options)
    out = tmp_path / "ranks.adg"
    lines = mpi_run(tmp_path, 2, {"npy": str(tmp_path / "f.npy"), "spacing": (1.0, 1.0, 1.0), "options": options, "route": "prepare",
                                  "output": str(out)})
    assert lines == [f"rank {r}: ok" for r in range(2)]
    assert out.read_bytes() == expected
    bricks = json.loads((tmp_path / "ranks.adg.bricks.json").read_text())
    assert bricks["brick_side"] == 16 and bricks["bricks"] == 12 and bricks["bricks_per_rank"] == [6, 6], bricks


def write_nrrd(path, array, encoding):
    """array[z, y, x] float32 as an attached NRRD, raw or gzip."""
    z, y, x = array.shape
    data = array.astype("<f4").tobytes()
    if encoding == "gzip":
        data = gzip.compress(data)
    header = f"NRRD0004\ntype: float\ndimension: 3\nsizes: {x} {y} {z}\nspacings: 1 0.8 1.5\nencoding: {encoding}\nendian: little\n\n"
    with open(path, "wb") as f:
        f.write(header.encode() + data)


@needs_mpi
@pytest.mark.parametrize("encoding", ["raw", "gzip"])
def test_prepare_over_mpi_ranks_from_a_path_writes_the_one_process_grid(tmp_path, encoding):
    # Raw: the other ranks seek their bricks; gzip: rank 0, which decodes the stream, sends them theirs.
    path = tmp_path / "f.nrrd"
    write_nrrd(path, field(), encoding)
    one = tmp_path / "one.adg"
    adaptiso.prepare(str(path), max_error=0.05).save(one)
    out = tmp_path / "ranks.adg"
    lines = mpi_run(tmp_path, 3, {"path": str(path), "options": {"max_error": 0.05}, "route": "prepare_file", "brick_side": 8,
                                  "output": str(out)})
    assert lines == [f"rank {r}: ok" for r in range(3)]
    assert out.read_bytes() == one.read_bytes()
    bricks = json.loads((tmp_path / "ranks.adg.bricks.json").read_text())
    assert bricks["ranks_read"] == ("regions" if encoding == "raw" else "regions sent by rank 0")


@needs_mpi
@pytest.mark.parametrize("bad", [1, 2])
def test_a_bad_option_on_a_rank_rank_0_sends_regions_to_raises_there_and_on_rank_0(tmp_path, bad):
    # The ranks agree they are ready before rank 0 sends a region: none waits for a message, and
    # rank 0 reports the rank that was not (whether a ready rank's empty answer comes before it).
    path = tmp_path / "f.nrrd"
    write_nrrd(path, field(), "gzip")
    out = tmp_path / "ranks.adg"
    lines = mpi_run(tmp_path, 3, {"path": str(path), "options": {}, "route": "prepare_file", "brick_side": 8, "output": str(out),
                                  "bad_option_rank": bad})
    assert lines[0].startswith(f"rank 0: ValueError: comm: rank {bad}: gradients: must be"), lines
    assert lines[bad].startswith(f"rank {bad}: ValueError: gradients: must be"), lines
    assert lines[3 - bad] == f"rank {3 - bad}: ok", lines  # its part done; rank 0 reports the failure
    assert not out.exists()


@needs_mpi
def test_a_volume_of_other_dimensions_on_one_rank_raises_on_every_rank(tmp_path):
    np.save(tmp_path / "f.npy", field())
    out = tmp_path / "ranks.adg"
    lines = mpi_run(tmp_path, 3, {"npy": str(tmp_path / "f.npy"), "spacing": (1, 1, 1), "options": {}, "route": "prepare",
                                  "brick_side": 8, "output": str(out), "other_shape_rank": 2})
    assert lines[0] == "rank 0: ValueError: comm: rank 2: the volume has 5×4×3 voxels on rank 2, a lattice of 41×29×25 on rank 0", lines
    assert lines[2] == "rank 2: ValueError: the volume has 5×4×3 voxels on rank 2, a lattice of 41×29×25 on rank 0", lines
    assert lines[1] == "rank 1: ok"  # its part done; rank 0 reports the failure
    assert not out.exists()


@needs_mpi
def test_a_bad_option_on_rank_0_raises_on_every_rank(tmp_path):
    np.save(tmp_path / "f.npy", field())
    out = tmp_path / "ranks.adg"
    lines = mpi_run(tmp_path, 2, {"npy": str(tmp_path / "f.npy"), "spacing": (1, 1, 1), "options": {}, "route": "prepare_file",
                                  "brick_side": 8, "output": str(out), "bad_option_rank": 0})
    assert lines[0].startswith("rank 0: ValueError: gradients: must be"), lines
    assert lines[1].startswith("rank 1: ValueError: comm: rank 0: gradients: must be"), lines
    assert not out.exists()


def distance_grids(tmp_path):
    """Two bisection grid files of the same size but other values (the second's field shifted)."""
    paths = []
    for i, shift in enumerate([0.0, 0.125]):
        path = tmp_path / f"g{i}.adg"
        adaptiso.prepare(adaptiso.Volume(field() + np.float32(shift), spacing=(1.0, 0.8, 1.5)), max_error=0.05).save(path)
        paths.append(path)
    return paths


@needs_mpi
@pytest.mark.parametrize("ranks, lazy", [(2, True), (3, True), (2, False), (3, False)])
def test_load_over_mpi_ranks_gives_every_rank_the_one_process_grid(tmp_path, ranks, lazy):
    grid, _ = distance_grids(tmp_path)
    one = adaptiso.load(grid)
    expected, expected_full = one.extract(0.6, distance=0.5), one.extract(0.6)
    out = tmp_path / "load"
    lines = mpi_run(tmp_path, ranks, {"route": "load", "grid": str(grid), "lazy": lazy, "iso": 0.6, "distance": 0.5, "full": True,
                                      "together": True, "output": str(out)})
    assert lines == [f"rank {r}: ok" for r in range(ranks)]
    for r in range(ranks):
        for got, want in [(np.load(f"{out}.rank-{r}.npz"), expected), (np.load(f"{out}.rank-{r}.full.npz"), expected_full),
                          (np.load(f"{out}.rank-{r}.together.npz"), expected)]:
            assert np.array_equal(got["vertices"], want.vertices) and np.array_equal(got["faces"], want.faces), r
        # extract(distance=, comm=): the surface the ranks made together is one process's, normals too
        assert np.array_equal(np.load(f"{out}.rank-{r}.together.npz")["normals"], expected.normals), r


@needs_mpi
def test_a_rank_asking_for_another_surface_to_make_together_raises_on_every_rank(tmp_path):
    grid, _ = distance_grids(tmp_path)
    out = tmp_path / "other-iso"
    lines = mpi_run(tmp_path, 3, {"route": "load", "grid": str(grid), "lazy": True, "iso": 0.6, "distance": 0.5, "together": True,
                                  "other_iso_rank": 1, "output": str(out)})
    assert lines[1].startswith("rank 1: ValueError: process 1 asked for another surface than process 0"), lines
    for r in (0, 2):
        assert lines[r].startswith(f"rank {r}: ValueError: process 1 cannot take its share of the surface made together"), lines


@needs_mpi
@pytest.mark.parametrize("other, key, value, lazy", [
    ("grid", "other_grid_rank", 1, True), ("grid", "other_grid_rank", 0, False), (None, "other_lazy_rank", 2, True),
    ("absent", "other_grid_rank", 2, True), ("absent", "other_grid_rank", 1, False), ("noise", "other_grid_rank", 1, True),
])
def test_load_over_mpi_ranks_of_another_or_unreadable_file_on_one_rank_raises_alike_on_every_rank(tmp_path, other, key, value, lazy):
    # Regression: a rank that could not open its file, or read it as a grid file, raised alone and
    # left the others waiting.
    grid, other_grid = distance_grids(tmp_path)
    paths = {"grid": other_grid, "absent": tmp_path / "absent.adg", "noise": tmp_path / "noise.adg", None: other_grid}
    (tmp_path / "noise.adg").write_bytes(bytes(range(256)) * 16)
    out = tmp_path / "load"
    lines = mpi_run(tmp_path, 3, {"route": "load", "grid": str(grid), "other_grid": str(paths[other]), "lazy": lazy, "iso": 0.6,
                                  "distance": 0.5, "output": str(out), key: value})
    messages = {line.split(": ", 1)[1].replace(str(other_grid), str(grid)) for line in lines}
    assert len(messages) == 1, lines  # the same words on every rank (each names its own file when they differ)
    message = messages.pop()
    assert message.startswith("OSError: "), lines
    if other in ("grid", None):
        assert "every process must load the same parts of the same grid file" in message, lines
    else:
        assert str(paths[other]) in message and f"(process {value})" in message, lines
        assert ("no such file" if other == "absent" else "bad magic") in message, lines


class OneProcess:
    """What mpi4py's COMM_SELF answers, for the tests that need no MPI."""

    def Get_rank(self):
        return 0

    def Get_size(self):
        return 1

    def bcast(self, obj, root=0):
        return obj

    def gather(self, obj, root=0):
        return [obj]


def test_bricks_in_one_process_and_a_communicator_of_one_make_the_same_grid(tmp_path):
    array = field((17, 20, 33))
    expected = one_process_grid(tmp_path, array, (1, 1, 1), {})
    for i, kwargs in enumerate([{"brick_side": 4}, {"brick_side": 16}, {"comm": OneProcess()}, {"comm": OneProcess(), "brick_side": 2}]):
        path = tmp_path / f"b{i}.adg"
        adaptiso.prepare(adaptiso.Volume(array), **kwargs).save(path)
        assert path.read_bytes() == expected, kwargs
    stats = adaptiso.prepare_file(adaptiso.Volume(array), tmp_path / "f.adg", brick_side=8, comm=OneProcess())
    assert stats["tetrahedra"] > 0
    assert (tmp_path / "f.adg").read_bytes() == expected
    assert stats["bricks"]["ranks"] == 1 and stats["bricks"]["bricks"] == 4 * 3 * 2 and stats["bricks"]["bricks_per_rank"] == [24]
    assert stats["bricks"]["bytes_exchanged"] > 0  # across the brick faces
    assert "bricks" not in adaptiso.prepare(adaptiso.Volume(array)).stats
    assert adaptiso.prepare(adaptiso.Volume(array), brick_side=64).stats["bricks"]["bricks"] == 1


def test_a_path_is_read_as_adaptiso_read_reads_it(tmp_path):
    path = tmp_path / "f.nrrd"
    write_nrrd(path, field((9, 10, 11)), "gzip")
    a, b = tmp_path / "a.adg", tmp_path / "b.adg"
    grid = adaptiso.prepare(path, brick_side=4)  # os.PathLike
    grid.save(a)
    other = adaptiso.prepare(adaptiso.read(str(path)))
    other.save(b)
    # The same grid; its file also records the source's name, as the command line's does.
    assert grid.stats["bricks"]["bricks"] == 3 * 3 * 2
    assert b'"file":"f.nrrd"' in a.read_bytes() and b'"file":"f.nrrd"' not in b.read_bytes()
    assert (grid.vertex_count, grid.tetrahedron_count) == (other.vertex_count, other.tetrahedron_count)
    for x, y in zip(grid.extract(0.3), other.extract(0.3)):
        assert np.array_equal(x, y)
    with pytest.raises(OSError, match="no_such.nrrd"):
        adaptiso.prepare(str(tmp_path / "no_such.nrrd"))
    with pytest.raises(OSError, match="no_such.nrrd"):
        adaptiso.prepare_file(tmp_path / "no_such.nrrd", tmp_path / "c.adg", comm=OneProcess())
    assert not (tmp_path / "c.adg").exists()


def test_bad_bricks_and_communicators_are_refused():
    v = adaptiso.Volume(field((9, 10, 11)))
    with pytest.raises(ValueError, match="brick_side"):
        adaptiso.prepare(v, brick_side=6)
    with pytest.raises(ValueError, match="brick_side: applies to the bisection grid only"):
        adaptiso.prepare(v, grid="delaunay", brick_side=8)
    with pytest.raises(TypeError, match="comm: must be an mpi4py communicator"):
        adaptiso.prepare(v, comm=object())


def test_extract_with_a_communicator_needs_a_distance_and_with_one_process_is_a_plain_extract(tmp_path):
    grid, _ = distance_grids(tmp_path)
    g = adaptiso.load(grid)
    with pytest.raises(ValueError, match="comm needs distance"):
        g.extract(0.6, comm=OneProcess())
    alone, made = g.extract(0.6, distance=0.5), g.extract(0.6, distance=0.5, comm=OneProcess())
    assert np.array_equal(alone.vertices, made.vertices) and np.array_equal(alone.faces, made.faces)
    with pytest.raises(TypeError):
        g.extract(0.6, distance=0.5, comm=object())


def test_load_with_a_communicator_of_one_is_a_plain_load_and_another_object_is_refused(tmp_path):
    grid, _ = distance_grids(tmp_path)
    expected = adaptiso.load(grid).extract(0.6, distance=0.5)
    for lazy in [True, False]:
        got = adaptiso.load(grid, lazy=lazy, comm=OneProcess()).extract(0.6, distance=0.5)
        assert np.array_equal(got.vertices, expected.vertices) and np.array_equal(got.faces, expected.faces)
    with pytest.raises(TypeError, match="comm: must be an mpi4py communicator"):
        adaptiso.load(grid, comm=object())

    class Several(OneProcess):  # two processes, but none of the buffer methods a shared load sends by
        def Get_size(self):
            return 2

    with pytest.raises(TypeError, match=r"it has no Bcast\(\)"):
        adaptiso.load(grid, comm=Several())
