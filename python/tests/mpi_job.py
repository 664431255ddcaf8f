"""One rank's part of test_over_ranks.py, run as `mpiexec -n N python -m mpi4py mpi_job.py ARGS.json`.

Every rank prepares from a memmap of the same .npy file, or from the same volume file's path (a
rank given "other_shape" a different volume, one given "bad_option" a bad gradients name, to check
that errors reach every rank) and rank 0 saves the grid; or (route "load") every rank loads the same
grid file with comm (one rank given another file or other lazy=, to check that all refuse alike)
and extracts a surface at a distance into OUTPUT.rank-R.npz (and with "together", the same
surface made by all ranks with comm, into OUTPUT.rank-R.together.npz). Each rank writes one line to OUTPUT.rank-R ("rank R: ok" or "rank R:
ErrorType: message"): mpiexec may interleave the ranks' standard outputs within a line.
"""
import json
import sys

import numpy as np
from mpi4py import MPI

import adaptiso

comm = MPI.COMM_WORLD
rank = comm.Get_rank()
job = json.load(open(sys.argv[1], encoding="utf-8"))


def report(outcome):
    with open(f"{job['output']}.rank-{rank}", "w", encoding="utf-8") as f:
        f.write(f"rank {rank}: {outcome}\n")


if job["route"] == "load":  # every rank loads a grid (rank "other_grid_rank" another) and extracts
    try:
        path = job["other_grid"] if rank == job.get("other_grid_rank", -1) else job["grid"]
        lazy = job["lazy"] != (rank == job.get("other_lazy_rank", -1))
        grid = adaptiso.load(path, lazy=lazy, comm=comm)
        mesh = grid.extract(job["iso"], distance=job["distance"])
        np.savez(f"{job['output']}.rank-{rank}.npz", vertices=mesh.vertices, faces=mesh.faces)
        if job.get("together"):  # the same surface made by all the ranks together
            iso = job["iso"] + (0.01 if rank == job.get("other_iso_rank", -1) else 0)
            made = grid.extract(iso, distance=job["distance"], comm=comm)
            np.savez(f"{job['output']}.rank-{rank}.together.npz", vertices=made.vertices, faces=made.faces, normals=made.normals)
        if job.get("full"):  # the tetrahedra too (read later by a lazy load, each rank alone)
            full = grid.extract(job["iso"])
            np.savez(f"{job['output']}.rank-{rank}.full.npz", vertices=full.vertices, faces=full.faces)
        report("ok")
    except Exception as e:  # reported for the test to read; the job itself ends normally
        report(f"{type(e).__name__}: {e}")
    sys.exit(0)

options = dict(job["options"])
if rank == job.get("bad_option_rank", -1):
    options["gradients"] = "no such method"
if "path" in job:  # the file's path on every rank: rank 0 reads it whole, the others their bricks
    volume = job["path"]
else:
    array = np.load(job["npy"], mmap_mode="r")
    if rank == job.get("other_shape_rank", -1):
        array = np.zeros((3, 4, 5), dtype=array.dtype)
        array[1, 1, 1] = 1
    volume = adaptiso.Volume(array, spacing=tuple(job["spacing"]))
try:
    if job["route"] == "prepare_file":
        stats = adaptiso.prepare_file(volume, job["output"], brick_side=job.get("brick_side"), comm=comm, **options)
        assert (stats is None) == (rank != 0), stats
    else:
        grid = adaptiso.prepare(volume, brick_side=job.get("brick_side"), comm=comm, **options)
        assert (grid is None) == (rank != 0), grid
        stats = None
        if grid is not None:
            grid.save(job["output"])
            stats = grid.stats
    if stats is not None:
        with open(job["output"] + ".bricks.json", "w", encoding="utf-8") as f:
            json.dump(stats["bricks"], f)
    outcome = "ok"
except Exception as e:  # reported for the test to read; the job itself ends normally
    outcome = f"{type(e).__name__}: {e}"
report(outcome)
