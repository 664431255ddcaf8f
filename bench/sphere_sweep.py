#!/usr/bin/env python3
"""The paper's sphere (issue "The paper's figures"): why Lürig & Ertl keep 198 vertices and make 542
triangles (50³, relative error 0.15, iso 0.7) where `adaptiso run --grid delaunay` keeps 659 and
makes 1,404. Sweeps, on the paper's grid (reconstruction analysis + Delaunay, through the Python
module):

1. radius × extension of the volume to the power-of-two cube the octree covers (65³ = 2^6 + 1
   lattice points): `clip` (adaptiso: cubes are clipped at the far faces and their clipped
   corners kept), `clamp` (the border value repeated into the cube), `formula` (the field computed
   on the whole cube). Kept vertices are counted in all and inside the 50³ volume;
2. the fall-off of the field outside the sphere (ours: 1000·R/r, as `adaptiso generate sphere`)
   against others, with the volume clipped.

The bound and the iso-value are always fractions of the 50³ volume's own value range.
Usage: bench/sphere_sweep.py --build BUILD    (prints Markdown tables)
"""
import argparse
import os
import sys

import numpy as np

N, CUBE = 50, 65
C = (N - 1) / 2


def radius_grid(n):
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    return np.sqrt((x - C) ** 2 + (y - C) ** 2 + (z - C) ** 2)


FALLOFFS = {  # value at distance r from the centre; R the sphere's radius
    "1000·R/r (ours)": lambda r, R: np.where(r <= R, 1000.0, 1000.0 * R / np.maximum(r, 1e-9)),
    "1000·(R/r)²": lambda r, R: np.where(r <= R, 1000.0, 1000.0 * (R / np.maximum(r, 1e-9)) ** 2),
    "1000·exp(−(r/R)²)": lambda r, R: 1000.0 * np.exp(-((r / R) ** 2)),
    "max(0, 1000·(1 − r/2R)) (cone)": lambda r, R: np.clip(1000.0 - 1000.0 * r / (2 * R), 0, 1000),
}


def volume(falloff, R, n=N):
    return np.rint(FALLOFFS[falloff](radius_grid(n), R)).astype(np.int16)


def reduced(adaptiso, a, lo, hi):
    """Kept vertices ([z, y, x]) and triangles at iso 0.7 on the paper's grid, bound 0.15 of [lo, hi]."""
    v = adaptiso.Volume(np.ascontiguousarray(a))
    bound = 0.15 * (hi - lo)
    kept = adaptiso.reduce(v, max_error=bound)
    grid = adaptiso.prepare(v, grid="delaunay", max_error=bound)
    return kept, grid.extract(lo + 0.7 * (hi - lo))[1].shape[0]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", required=True, help="build folder holding python/adaptiso*.so")
    args = ap.parse_args()
    sys.path.insert(0, os.path.join(args.build, "python"))
    import adaptiso

    radii = (6.25, 8.0, 10.0, 12.5, 16.0, 20.0)
    print("| R (voxels) | clip: kept, triangles | clamp: kept (inside 50³), triangles | formula: kept (inside 50³), triangles |")
    print("|---:|---|---|---|")
    for R in radii:
        base = volume("1000·R/r (ours)", R)
        lo, hi = float(base.min()), float(base.max())
        cells = []
        for ext in ("clip", "clamp", "formula"):
            if ext == "clip":
                a = base
            elif ext == "clamp":
                a = np.pad(base, ((0, CUBE - N),) * 3, mode="edge")
            else:
                a = volume("1000·R/r (ours)", R, CUBE)
            kept, tris = reduced(adaptiso, a, lo, hi)
            inside = int((kept < N).all(axis=1).sum())
            cells.append(f"{len(kept)}, {tris}" if ext == "clip" else f"{len(kept)} ({inside}), {tris}")
        print(f"| {R:g}{' (ours)' if R == N / 4 else ''} | " + " | ".join(cells) + " |", flush=True)
    print()
    print("| fall-off (clip) | " + " | ".join(f"R = {R:g}" for R in radii) + " |")
    print("|---|" + "---|" * len(radii))
    for name in FALLOFFS:
        cells = []
        for R in radii:
            a = volume(name, R)
            kept, tris = reduced(adaptiso, a, float(a.min()), float(a.max()))
            cells.append(f"{len(kept)} / {tris}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    print("\n(kept vertices / triangles; the paper: 198 / 542)")


if __name__ == "__main__":
    main()
