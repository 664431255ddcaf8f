#!/usr/bin/env python3
"""Simplified exports against the peer (issue "Meshes worth exporting"): for each volume and
iso-value, adaptiso's surface from a prepared grid simplified with --simplify D (chunks in
parallel, simplify.hpp), against full-resolution marching cubes (the surface flying edges gives, up
to how 4- to 7-edge pieces are triangulated) simplified by meshoptimizer in one pass over the whole
mesh, as the peer "flying edges + meshoptimizer" does (`bench_simplify MESH D 0`, median of 3),
and against `adaptiso mc --simplify D` (the same surface, our chunked simplification), in one run.
Per row: triangles, mean / 95th percentile symmetric distance to the full-resolution surface
(voxels of the smallest spacing, `adaptiso compare`), and the seconds of extraction +
simplification (the tools' own timings, no file I/O).

Usage: bench/simplify.py --build BUILD [--data DIR] [--work DIR] [--distances 0.1,0.25,0.5]
                         [--error 0.02] [--out RECORDS.json] [--plot PNG] [DATASET[:ISO,...] ...]
"""
import argparse
import json
import os
import sys

from defaults import distance, main_input, run

DEFAULT = ["ct_bunny_stanford:500,1600", "ct_chest_lidc2:100", "mr_brain_flair:90"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--data", default=os.environ.get("ADAPTISO_DATA", "../shared/data"))
    ap.add_argument("--work", default="build/simplify-work")
    ap.add_argument("--distances", default="0.1,0.25,0.5")
    ap.add_argument("--error", type=float, default=0.02, help="the grid's relative error bound")
    ap.add_argument("--out")
    ap.add_argument("--plot", help="PNG: mean distance against triangles, one panel per volume and iso-value")
    ap.add_argument("datasets", nargs="*")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bin", "adaptiso")
    bench = os.path.join(a.build, "bin", "bench_simplify")
    os.makedirs(a.work, exist_ok=True)
    distances = [float(x) for x in a.distances.split(",")]
    records = []
    print("| volume | iso | method | D | triangles | mean / p95 distance | seconds (extract + simplify) |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for spec in a.datasets or DEFAULT:
        name, _, isos = spec.partition(":")
        src = main_input(a.data, name, a.work)
        if not src:
            print(f"skipping {name}: not in {a.data}", file=sys.stderr)
            continue
        voxel = min(json.loads(run([exe, "info", src, "--json"]))["spacing"])
        grid = os.path.join(a.work, name + ".adg")
        run([exe, "prepare", src, "--relative", "--max-error", f"{a.error:g}", "-o", grid, "--quiet"])
        for iso in [float(x) for x in isos.split(",")]:
            ref = os.path.join(a.work, f"{name}-{iso:g}-mc.ply")
            mc = json.loads(run([exe, "mc", src, "--iso", f"{iso:g}", "-o", ref, "--json"]))["surfaces"][0]
            mesh = os.path.join(a.work, f"{name}-{iso:g}.ply")
            for d in [0.0] + distances:
                for method in ("adaptiso", "mc + meshoptimizer (one pass)", "mc + adaptiso's chunked simplify"):
                    if method == "adaptiso":
                        cmd = [exe, "extract", grid, "--iso", f"{iso:g}", "-o", mesh, "--json"]
                    else:
                        if d == 0:
                            continue
                        cmd = [exe, "mc", src, "--iso", f"{iso:g}", "-o", mesh, "--json"]
                    if d > 0 and method != "mc + meshoptimizer (one pass)":
                        cmd += ["--simplify", f"{d:g}"]
                    s = json.loads(run(cmd))["surfaces"][0]
                    simp = s.get("simplify", {})
                    if method == "mc + meshoptimizer (one pass)":
                        one = json.loads(run([bench, ref, repr(d * voxel), "0", mesh]).splitlines()[-1])
                        simp = {"seconds": one["seconds"], "triangles_after": one["triangles_after"],
                                "triangles_before": one["triangles_before"]}
                    seconds = s["seconds"] + simp.get("seconds", 0)
                    triangles = simp.get("triangles_after", s["triangles"])
                    mean, p95, _ = distance(exe, mesh, ref, voxel)
                    rec = {"dataset": name, "iso": iso, "method": method, "distance": d, "triangles": triangles, "mean": mean,
                           "p95": p95, "seconds": seconds, "extract_seconds": s["seconds"], "simplify_seconds": simp.get("seconds", 0),
                           "triangles_before": simp.get("triangles_before", s["triangles"]), "mc_triangles": mc["triangles"]}
                    records.append(rec)
                    print(f"| {name} | {iso:g} | {method} | {d:g} | {triangles:,} | {mean:.3f} / {p95:.3f} | {seconds:.3f} "
                          f"({s['seconds']:.3f} + {simp.get('seconds', 0):.3f}) |", flush=True)
            for p in (ref, mesh):
                if os.path.exists(p):
                    os.remove(p)
        os.remove(grid)
    if a.out:
        with open(a.out, "w") as f:
            json.dump(records, f, indent=1)
    if a.plot and records:
        plot(records, a.plot)


def plot(records, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cases = sorted({(r["dataset"], r["iso"]) for r in records}, key=lambda c: (c[0], c[1]))
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 4), squeeze=False)
    for ax, (name, iso) in zip(axes[0], cases):
        rows = [r for r in records if r["dataset"] == name and r["iso"] == iso]
        for method, style in (("adaptiso", "s-"), ("mc + meshoptimizer (one pass)", "o-"), ("mc + adaptiso's chunked simplify", "^--")):
            pts = sorted((r["triangles"], max(r["mean"], 1e-3), r["distance"]) for r in rows if r["method"] == method)
            if not pts:
                continue
            ax.plot([p[0] for p in pts], [p[1] for p in pts], style, label=method)
            for t, m, d in pts:
                ax.annotate(f"D={d:g}", (t, m), fontsize=6, textcoords="offset points", xytext=(3, 3))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("triangles")
        ax.set_ylabel("mean distance to full resolution (voxels)")
        ax.set_title(f"{name}, iso {iso:g}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
