#!/usr/bin/env python3
"""How the default error bound was chosen: for every shared volume and each candidate relative
error, the bisection grid's preparation time and size, and the distance of its surfaces at the
sidecar's suggested iso-values to full-resolution marching cubes (mean and 95th percentile, in
voxels of the smallest spacing).

Usage: bench/defaults.py --build BUILD [--data DIR] [--work DIR] [--errors 0.02,0.05,0.1] [DATASET...]
Writes a Markdown table on stdout and the records as JSON to --out (default: stdout only).
"""
import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tarfile
import time


def main_input(data, name, work):
    for ext in (".nhdr", ".nrrd", ".mha", ".vti", ".vtk"):
        p = os.path.join(data, name + ext)
        if os.path.exists(p):
            return p
    d = os.path.join(data, name)
    if os.path.isdir(d):
        for f in sorted(os.listdir(d)):
            if f.endswith((".nhdr", ".mhd")):
                return os.path.join(d, f)
        return d
    t = os.path.join(data, name + ".tar.gz")
    if os.path.exists(t):
        out = os.path.join(work, name)
        if not os.path.isdir(out):
            with tarfile.open(t) as tar:
                tar.extractall(work)
        return out
    return None


def sidecar(path):
    text = open(path).read()
    isos = []
    block = re.search(r"Suggested iso-values:\n(.*?)\n\n", text, re.S)
    if block:
        for line in block.group(1).splitlines():
            m = re.match(r"\s+(-?[\d.]+)\s+-", line)
            if m:
                isos.append(float(m.group(1)))
    return isos


def volumes(data, names, work):
    """(name, input path, suggested iso-values) of each named shared volume that is present."""
    for name in names:
        src = main_input(data, name, work)
        isos = sidecar(os.path.join(data, name + ".txt")) if src else []
        if not isos:
            print(f"skipping {name}: not in {data}", file=sys.stderr)
            continue
        yield name, src, isos


def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {r.stderr.strip()}")
    return r.stdout


Comparison = collections.namedtuple("Comparison", "mean p95 max triangles p95_to p95_from")


def compare(exe, mesh, ref, voxel):
    """Symmetric mean, 95th percentile and largest distance between two meshes in voxels, the first
    mesh's triangles, and the 95th percentile each way (adaptiso compare): a surface within a
    distance bounds the way to the reference; the way back also counts the pieces it dropped."""
    d = json.loads(run([exe, "compare", mesh, ref, "--voxel", f"{voxel:.9g}", "--json"]))
    a, b = d["a_to_b"], d["b_to_a"]
    return Comparison(0.5 * (a["mean_voxels"] + b["mean_voxels"]), max(a["p95_voxels"], b["p95_voxels"]), d["hausdorff_voxels"],
                      d["a_triangles"], a["p95_voxels"], b["p95_voxels"])


def distance(exe, mesh, ref, voxel):
    """Symmetric mean and 95th percentile distance between two meshes in voxels, and the first's triangles."""
    c = compare(exe, mesh, ref, voxel)
    return c.mean, c.p95, c.triangles


def last_json(text):
    """The last line of a tool's output, which holds its JSON record."""
    return json.loads(text.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--data", default=os.environ.get("ADAPTISO_DATA", "../shared/data"))
    ap.add_argument("--work", default="build/defaults-work")
    ap.add_argument("--errors", default="0.02,0.05,0.1")
    ap.add_argument("--out")
    ap.add_argument("datasets", nargs="*")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bin", "adaptiso")
    os.makedirs(a.work, exist_ok=True)
    names = a.datasets or sorted(f[:-4] for f in os.listdir(a.data) if f.endswith(".txt"))
    records = []
    print("| volume | relative error | prepare s | tetrahedra | iso | triangles (MC) | mean distance | p95 | max |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, src, isos in volumes(a.data, names, a.work):
        info = json.loads(run([exe, "info", src, "--json"]))
        voxel = min(info["spacing"])
        iso_arg = ",".join(f"{x:g}" for x in isos)
        mc = os.path.join(a.work, name + "-mc.ply")
        run([exe, "mc", src, "--iso", iso_arg, "-o", mc, "--quiet"])
        for e in [float(x) for x in a.errors.split(",")]:
            grid = os.path.join(a.work, f"{name}-{e:g}.adg")
            mesh = os.path.join(a.work, f"{name}-{e:g}.ply")
            t0 = time.monotonic()
            prep = json.loads(run([exe, "run", src, "--relative", "--max-error", f"{e:g}", "--iso",
                                   ",".join(f"{(x - info['min']) / (info['max'] - info['min']):.9g}" for x in isos),
                                   "-o", mesh, "--json"]))
            wall = time.monotonic() - t0
            for k, iso in enumerate(isos):
                path_a = prep["surfaces"][k]["output"] if len(isos) > 1 else mesh
                path_b = mc.replace(".ply", f"-{iso:g}.ply") if len(isos) > 1 else mc
                d = json.loads(run([exe, "compare", path_a, path_b, "--voxel", f"{voxel:.9g}", "--json"]))
                mean = 0.5 * (d["a_to_b"]["mean_voxels"] + d["b_to_a"]["mean_voxels"])
                p95 = max(d["a_to_b"]["p95_voxels"], d["b_to_a"]["p95_voxels"])
                rec = {"dataset": name, "error": e, "seconds": wall, "tetrahedra": prep["tetrahedra"], "iso": iso,
                       "triangles": d["a_triangles"], "mc_triangles": d["b_triangles"], "mean": mean, "p95": p95,
                       "max": d["hausdorff_voxels"]}
                records.append(rec)
                print(f"| {name} | {e:g} | {wall:.1f} | {prep['tetrahedra']:,} | {iso:g} | {d['a_triangles']:,} ({d['b_triangles']:,}) "
                      f"| {mean:.3f} | {p95:.3f} | {d['hausdorff_voxels']:.2f} |", flush=True)
            os.remove(grid) if os.path.exists(grid) else None
    if a.out:
        with open(a.out, "w") as f:
            json.dump(records, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
