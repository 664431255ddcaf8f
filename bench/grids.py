#!/usr/bin/env python3
"""Both grids side by side (issue "Bisection grid"): for each volume and relative error, the
Delaunay grid (the paper's reduction + Delaunay) and the bisection grid, prepared by the command
line as a user would, then the bisection grid asked for the error the Delaunay grid actually
reached (its measured pl_max_error), so the two are compared at the same achieved error.

Per grid: preparation wall seconds and peak resident memory of the whole process (wait4), the
saved grid's bytes, vertices, tetrahedra, the requested and the achieved max-norm error (the
bisection grid's is its guaranteed bound; --verify measures it voxel by voxel when asked), and at
the sidecar's suggested iso-values the triangle count and the symmetric mean / 95th percentile
distance to full-resolution marching cubes (`adaptiso compare`, voxels of the smallest spacing).

Usage: bench/grids.py --build BUILD [--data DIR] [--work DIR] [--errors 0.02,0.05] [--verify]
                      [--out RECORDS.json] [DATASET...]
Prints a Markdown table on stdout.
"""
import argparse
import json
import os
import subprocess
import sys
import time

from defaults import distance, run, volumes


def timed(cmd):
    """Runs cmd; returns (stdout, wall seconds, peak resident bytes of the process)."""
    t0 = time.monotonic()
    with open(os.devnull, "w") as null:
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=null, text=True)
        out = p.stdout.read()
        _, status, usage = os.wait4(p.pid, 0)
    wall = time.monotonic() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: exit {p.returncode}")
    return out, wall, usage.ru_maxrss * 1024


def prepare(exe, src, grid_path, args):
    out, wall, peak = timed([exe, "prepare", src, *args, "-o", grid_path, "--json", "--quiet"])
    j = json.loads(out)
    return {"seconds": wall, "peak_bytes": peak, "grid_bytes": os.path.getsize(grid_path), "vertices": j["kept"],
            "tetrahedra": j["tetrahedra"], "max_error": j["max_error"],
            "achieved": j.get("pl_max_error", j.get("error_bound")), "error_bound": j.get("error_bound"),
            "stages": j["seconds"]}


def surfaces(exe, grid_path, isos, work, tag, mc_paths, voxel):
    rows = []
    for iso, ref in zip(isos, mc_paths):
        mesh = os.path.join(work, f"{tag}-{iso:g}.ply")
        run([exe, "extract", grid_path, "--iso", f"{iso:.9g}", "-o", mesh, "--quiet"])
        mean, p95, tris = distance(exe, mesh, ref, voxel)
        rows.append({"iso": iso, "triangles": tris, "mean": mean, "p95": p95})
        os.remove(mesh)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--data", default=os.environ.get("ADAPTISO_DATA", "../shared/data"))
    ap.add_argument("--work", default="build/grids-work")
    ap.add_argument("--errors", default="0.02,0.05")
    ap.add_argument("--verify", action="store_true", help="measure the bisection grid's error voxel by voxel")
    ap.add_argument("--out")
    ap.add_argument("datasets", nargs="*")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bin", "adaptiso")
    os.makedirs(a.work, exist_ok=True)
    names = a.datasets or ["ct_bunny_stanford", "ct_chest_lidc2", "dicom_mr_head_t1_vsseg"]
    records = []
    print("| volume (volume MB) | rel. error | grid | asked | achieved | prepare s | peak MB | grid MB | tetrahedra | iso: triangles, mean / p95 distance |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---|")
    for name, src, isos in volumes(a.data, names, a.work):
        info = json.loads(run([exe, "info", src, "--json"]))
        voxel = min(info["spacing"])
        volume_mb = info.get("bytes", 0) / 1e6
        mc_paths = []
        for iso in isos:
            ref = os.path.join(a.work, f"{name}-mc-{iso:g}.ply")
            run([exe, "mc", src, "--iso", f"{iso:.9g}", "-o", ref, "--quiet"])
            mc_paths.append(ref)
        span = info["max"] - info["min"]
        for e in [float(x) for x in a.errors.split(",")]:
            grid_path = os.path.join(a.work, f"{name}.adg")
            runs = []
            d = prepare(exe, src, grid_path, ["--grid", "delaunay", "--relative", "--max-error", f"{e:g}"])
            d["surfaces"] = surfaces(exe, grid_path, isos, a.work, name, mc_paths, voxel)
            runs.append(("delaunay", d))
            extra = ["--verify"] if a.verify else []
            b = prepare(exe, src, grid_path, ["--grid", "bisection", "--relative", "--max-error", f"{e:g}", *extra])
            b["surfaces"] = surfaces(exe, grid_path, isos, a.work, name, mc_paths, voxel)
            runs.append(("bisection", b))
            # The bisection grid asked for what the Delaunay grid reached.
            bd = prepare(exe, src, grid_path, ["--grid", "bisection", "--max-error", f"{d['achieved']:.9g}", *extra])
            bd["surfaces"] = surfaces(exe, grid_path, isos, a.work, name, mc_paths, voxel)
            runs.append(("bisection at Delaunay's achieved error", bd))
            os.remove(grid_path)
            for label, r in runs:
                r.update({"dataset": name, "relative_error": e, "grid": label, "volume_bytes": info.get("bytes", 0)})
                records.append(r)
                surf = "; ".join(f"{s['iso']:g}: {s['triangles']:,}, {s['mean']:.3f} / {s['p95']:.3f}" for s in r["surfaces"])
                print(f"| {name} ({volume_mb:.0f}) | {e:g} | {label} | {r['max_error'] / span:.4f} | {r['achieved'] / span:.4f} "
                      f"| {r['seconds']:.1f} | {r['peak_bytes'] / 1e6:.0f} | {r['grid_bytes'] / 1e6:.0f} | {r['tetrahedra']:,} | {surf} |",
                      flush=True)
        for p in mc_paths:
            os.remove(p)
    if a.out:
        with open(a.out, "w") as f:
            json.dump(records, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
