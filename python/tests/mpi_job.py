"""One rank's part of test_over_ranks.py, run as `mpiexec -n N python -m mpi4py mpi_job.py ARGS.json`.

Every rank prepares from a memmap of the same .npy file, or from the same volume file's path (a
rank given "other_shape" a different volume, one given "bad_option" a bad gradients name, to check
that errors reach every rank) and rank 0 saves the grid. Each rank writes one line to OUTPUT.rank-R ("rank R: ok" or "rank R:
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
with open(f"{job['output']}.rank-{rank}", "w", encoding="utf-8") as f:
    f.write(f"rank {rank}: {outcome}\n")
