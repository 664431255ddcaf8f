#!/usr/bin/env python3
"""Simplified exports against the peers (issue "Meshes worth exporting"), all in one run. For each
volume and iso-value:
- adaptiso: the surface of a grid prepared at --error, extracted with `--simplify D`;
- flying edges + meshoptimizer at the same triangle count: VTK's vtkFlyingEdges3D (SMP), then
  meshopt_simplify down to adaptiso's triangle count at that D (`peer_bench fe` + `peer_bench
  simplify`, best of 3 after a warm-up each);
- flying edges + meshoptimizer at D: the flying-edges surface simplified in one pass with the same
  error target as adaptiso (`bench_simplify MESH D 0`, median of 3);
- adaptiso mc --simplify D: full-resolution marching cubes and our chunked simplification;
- OpenVDB volumeToMesh at adaptivity 0.25 and 0.5 (`peer_bench vdb`, best of 3).
Per row: triangles, mean / 95th percentile symmetric distance to the full-resolution surface
(`adaptiso mc`, voxels of the smallest spacing, `adaptiso compare`), and the seconds of extraction +
simplification (the tools' own timings, no file I/O). The peers need `peer_bench` (scripts/bench.sh
builds it and bench_simplify into build/peers, -DADAPTISO_BUILD_PEERS=ON); without it their columns
are left out with a message.

Usage: bench/simplify.py --build BUILD [--data DIR] [--work DIR] [--distances 0.1,0.25,0.5]
                         [--error 0.02] [--repeat 3] [--out RECORDS.json] [--plot PNG] [DATASET[:ISO,...] ...]
"""
import argparse
import json
import os
import sys

from defaults import distance, last_json, main_input, run

DEFAULT = ["ct_bunny_stanford:500,1600", "ct_chest_lidc2:100", "mr_brain_flair:90"]
ADAPTISO = "adaptiso"
FE_SAME_TRIANGLES = "flying edges + meshoptimizer, same triangles"
FE_SAME_D = "flying edges + meshoptimizer, same D"
MC_CHUNKED = "adaptiso mc --simplify"


def best_cli(cmd, repeat):
    """The CLI's --json surface record of the fastest of `repeat` runs (extraction + simplification)."""
    best = None
    for _ in range(repeat):
        s = json.loads(run(cmd))["surfaces"][0]
        total = s["seconds"] + s.get("simplify", {}).get("seconds", 0)
        if best is None or total < best[0]:
            best = (total, s)
    return best[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--data", default=os.environ.get("ADAPTISO_DATA", "../shared/data"))
    ap.add_argument("--work", default="build/simplify-work")
    ap.add_argument("--distances", default="0.1,0.25,0.5")
    ap.add_argument("--error", type=float, default=0.02, help="the grid's relative error bound")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing (fastest kept)")
    ap.add_argument("--out")
    ap.add_argument("--plot", help="PNG: mean distance against triangles, one panel per volume and iso-value")
    ap.add_argument("datasets", nargs="*")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bin", "adaptiso")
    bench = os.path.join(a.build, "bin", "bench_simplify")
    peer = os.path.join(a.build, "bin", "peer_bench")
    if not os.path.exists(peer):
        print(f"{peer} not built: the flying-edges and OpenVDB columns are left out (scripts/bench.sh builds it)", file=sys.stderr)
        peer = None
    os.environ["PEER_REPEAT"] = str(a.repeat)
    os.makedirs(a.work, exist_ok=True)
    distances = [float(x) for x in a.distances.split(",")]
    records = []

    def record(name, iso, method, d, mesh, ref, voxel, seconds, extract_seconds, simplify_seconds, triangles, before, **extra):
        mean, p95, _ = distance(exe, mesh, ref, voxel)
        rec = {"dataset": name, "iso": iso, "method": method, "distance": d, "triangles": triangles, "mean": mean, "p95": p95,
               "seconds": seconds, "extract_seconds": extract_seconds, "simplify_seconds": simplify_seconds,
               "triangles_before": before, **extra}
        records.append(rec)
        label = f"adaptivity {extra['adaptivity']:g}" if "adaptivity" in extra else f"{d:g}"
        print(f"| {name} | {iso:g} | {method} | {label} | {triangles:,} | {mean:.3f} / {p95:.3f} | {seconds:.3f} "
              f"({extract_seconds:.3f} + {simplify_seconds:.3f}) |", flush=True)
        os.remove(mesh)

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
            tag = os.path.join(a.work, f"{name}-{iso:g}")
            ref = tag + "-mc.ply"
            run([exe, "mc", src, "--iso", f"{iso:g}", "-o", ref, "--json", "--quiet"])
            fe, fe_seconds = tag + "-fe.ply", 0.0
            if peer:
                fe_seconds = last_json(run([peer, "fe", src, f"{iso:g}", fe]))["seconds"]
            mesh = tag + ".ply"
            for d in [0.0] + distances:
                simplify = ["--simplify", f"{d:g}"] if d > 0 else []
                s = best_cli([exe, "extract", grid, "--iso", f"{iso:g}", "-o", mesh, "--json", "--quiet"] + simplify, a.repeat)
                simp = s.get("simplify", {})
                ours = simp.get("triangles_after", s["triangles"])
                record(name, iso, ADAPTISO, d, mesh, ref, voxel, s["seconds"] + simp.get("seconds", 0), s["seconds"],
                       simp.get("seconds", 0), ours, simp.get("triangles_before", s["triangles"]))
                if d == 0:
                    continue
                if peer:
                    p = last_json(run([peer, "simplify", fe, str(ours), mesh]))
                    record(name, iso, FE_SAME_TRIANGLES, d, mesh, ref, voxel, fe_seconds + p["seconds"], fe_seconds, p["seconds"],
                           p["triangles"], None)
                    one = last_json(run([bench, fe, repr(d * voxel), "0", mesh]))
                    record(name, iso, FE_SAME_D, d, mesh, ref, voxel, fe_seconds + one["seconds"], fe_seconds, one["seconds"],
                           one["triangles_after"], one["triangles_before"])
                s = best_cli([exe, "mc", src, "--iso", f"{iso:g}", "-o", mesh, "--json", "--quiet"] + simplify, a.repeat)
                simp = s["simplify"]
                record(name, iso, MC_CHUNKED, d, mesh, ref, voxel, s["seconds"] + simp["seconds"], s["seconds"], simp["seconds"],
                       simp["triangles_after"], simp["triangles_before"])
            if peer:
                for line in run([peer, "vdb", src, f"{iso:g}", tag + "-"]).strip().splitlines():
                    v = json.loads(line)
                    vdb = f"{tag}-openvdb_{v['adaptivity']:.2f}.ply"
                    if v["adaptivity"] in (0.25, 0.5):
                        record(name, iso, "OpenVDB volumeToMesh", 0.0, vdb, ref, voxel, v["seconds"], v["seconds"], 0.0, v["triangles"],
                               None, adaptivity=v["adaptivity"])
                    elif os.path.exists(vdb):
                        os.remove(vdb)
            for p in (ref, fe):
                if os.path.exists(p):
                    os.remove(p)
        os.remove(grid)
    print()
    print(summary(records))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(records, f, indent=1)
    if a.plot and records:
        plot(records, a.plot)

def summary(records):
    """One row per volume, iso-value and D: the methods side by side, and the ratios of adaptiso
    against flying edges + meshoptimizer at the same triangle count (mean distance, seconds)."""
    def cell(r, with_triangles=True):
        if r is None:
            return "–"
        t = f"{r['triangles']:,}, " if with_triangles else ""
        return f"{t}{r['mean']:.3f} / {r['p95']:.3f}, {r['seconds']:.2f} s"

    def find(name, iso, method, d):
        return next((r for r in records if (r["dataset"], r["iso"], r["method"], r["distance"]) == (name, iso, method, d)), None)

    out = ["| volume, iso | D | adaptiso: triangles, mean / p95, s | FE + meshoptimizer, same triangles: mean / p95, s | "
           "adaptiso ÷ it: mean, time | FE + meshoptimizer, same D | adaptiso mc --simplify | OpenVDB 0.25 / 0.5: triangles, mean |",
           "|---|---:|---|---|---|---|---|---|"]
    cases = sorted({(r["dataset"], r["iso"]) for r in records}, key=lambda c: (c[0], c[1]))
    for name, iso in cases:
        vdb = [r for r in records if (r["dataset"], r["iso"], r["method"]) == (name, iso, "OpenVDB volumeToMesh")]
        vdb_cell = " / ".join(f"{r['triangles']:,}, {r['mean']:.3f}" for r in sorted(vdb, key=lambda r: r["adaptivity"])) or "–"
        for d in sorted({r["distance"] for r in records if (r["dataset"], r["iso"], r["method"]) == (name, iso, ADAPTISO)}):
            if d == 0:
                continue
            ours, same = find(name, iso, ADAPTISO, d), find(name, iso, FE_SAME_TRIANGLES, d)
            ratio = f"{ours['mean'] / same['mean']:.2f}×, {ours['seconds'] / same['seconds']:.2f}×" if ours and same else "–"
            out.append(f"| {name}, {iso:g} | {d:g} | {cell(ours)} | {cell(same, False)} | {ratio} | {cell(find(name, iso, FE_SAME_D, d))} | "
                       f"{cell(find(name, iso, MC_CHUNKED, d))} | {vdb_cell} |")
            vdb_cell = ""
    return "\n".join(out)


def plot(records, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cases = sorted({(r["dataset"], r["iso"]) for r in records}, key=lambda c: (c[0], c[1]))
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 4), squeeze=False)
    for ax, (name, iso) in zip(axes[0], cases):
        rows = [r for r in records if r["dataset"] == name and r["iso"] == iso]
        for method, style in ((ADAPTISO, "s-"), (FE_SAME_TRIANGLES, "o-"), (FE_SAME_D, "o--"), (MC_CHUNKED, "^--"),
                              ("OpenVDB volumeToMesh", "D:")):
            pts = sorted((r["triangles"], max(r["mean"], 1e-3), r.get("adaptivity", r["distance"])) for r in rows if r["method"] == method)
            if not pts:
                continue
            ax.plot([p[0] for p in pts], [p[1] for p in pts], style, label=method)
            for t, m, d in pts:
                ax.annotate(f"{'a' if method.startswith('OpenVDB') else 'D'}={d:g}", (t, m), fontsize=6, textcoords="offset points", xytext=(3, 3))
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
