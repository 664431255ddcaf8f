#!/usr/bin/python3
"""The side-by-side benchmark behind scripts/bench.sh: adaptiso against its peers on the same volumes.

For every dataset and suggested iso-value it runs adaptiso (prepare per stage, fresh extraction,
small iso steps, tree vs scan), full-resolution marching cubes (adaptiso mc, the distance
reference), vtkFlyingEdges3D, vtkMarchingCubes, OpenVDB volumeToMesh (adaptivity 0/0.25/0.5/1),
scikit-image marching_cubes, flying edges + meshoptimizer simplification to adaptiso's triangle
count, and vtkContour3DLinearGrid with vtkSpanSpace on the same adaptiso grid; then the surface
distance of every mesh to the full-resolution surface. Times are ratios to flying edges in the
same run. Writes RESULTS_DIR/<date>.json, <date>.md and two plots.
"""
import argparse
import datetime
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tarfile
import time

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--build", required=True, help="build folder with adaptiso, bench_extract and peer_bench")
ap.add_argument("--data", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--work", required=True, help="scratch folder for meshes and grids")
ap.add_argument("--errors", default="0.05", help="relative max errors for every dataset (comma-separated)")
ap.add_argument("--curve-errors", default="0.005,0.01,0.02,0.05,0.1,0.15,0.3",
                help="extra errors on --curve-dataset, for the distance-vs-triangles plot")
ap.add_argument("--curve-dataset", default="ct_head_headsq_quarter")
ap.add_argument("--sweep-dataset", default="ct_bunny_stanford", help="where the iso sweep plot is measured")
ap.add_argument("--repeat", type=int, default=3)
ap.add_argument("--replot", help="only rewrite the report and plots from this results JSON")
ap.add_argument("--append", help="keep this results JSON's records of the datasets not run now")
ap.add_argument("--refresh-extract", help="re-time this results JSON's extraction figures (flying edges, our marching cubes, "
                "bench_extract on the saved grids in --work) without redoing meshes and distances, and write today's report")
ap.add_argument("--max-samples", default="1000000", help="surface distance: most samples per direction")
ap.add_argument("datasets", nargs="*")
args = ap.parse_args()

B = args.build
ADAPTISO = f"{B}/bin/adaptiso"
PEER = f"{B}/bin/peer_bench"
BENCH_EXTRACT = f"{B}/bin/bench_extract"
SKIMAGE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "peers", "skimage_peer.py")
os.makedirs(args.out, exist_ok=True)
os.makedirs(args.work, exist_ok=True)
env = dict(os.environ, PEER_REPEAT=str(args.repeat))
records = []


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def run_json(cmd, lines=False, timeout=7200):
    """Runs a command, returns its JSON output (one object, or a list of JSON lines)."""
    t0 = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])}... failed ({p.returncode}): {p.stderr.strip()[-400:]}")
    log(f"    {os.path.basename(cmd[0])} {cmd[1] if len(cmd) > 1 else ''}: {time.time() - t0:.1f} s")
    if lines:
        return [json.loads(l) for l in p.stdout.splitlines() if l.startswith("{")]
    return json.loads(p.stdout)


def record(**kw):
    records.append(kw)
    return kw


def sidecar_isos(name):
    txt = open(os.path.join(args.data, name + ".txt")).read()
    m = re.search(r"Suggested iso-values:\n((?:[ \t]+.*\n)+)", txt)
    isos = []
    for line in (m.group(1).splitlines() if m else []):
        t = re.match(r"\s+(-?[0-9.]+(?:e-?\d+)?)\s+-", line)
        if t:
            isos.append(float(t.group(1)))
    return isos


def volume_path(name):
    d = args.data
    for ext in (".nhdr", ".nrrd", ".mha", ".vti", ".vtk"):
        if os.path.exists(f"{d}/{name}{ext}"):
            return f"{d}/{name}{ext}"
    if os.path.isdir(f"{d}/{name}"):
        for f in sorted(os.listdir(f"{d}/{name}")):
            if f.endswith((".nhdr", ".mhd")):
                return f"{d}/{name}/{f}"
        return f"{d}/{name}"
    if os.path.exists(f"{d}/{name}.tar.gz"):
        target = os.path.join(args.work, "unpacked")
        if not os.path.isdir(os.path.join(target, name)):
            with tarfile.open(f"{d}/{name}.tar.gz") as t:
                t.extractall(target)
        return os.path.join(target, name)
    return None


def datasets():
    names = args.datasets
    if not names:
        names = ["sphere"] + sorted(f[:-4] for f in os.listdir(args.data) if f.endswith(".txt") and f != "INDEX.txt") + ["sphere512"]
    out = []
    for n in names:
        if n in ("sphere", "sphere512"):
            size = 50 if n == "sphere" else 512
            path = os.path.join(args.work, f"{n}.nrrd")
            if not os.path.exists(path):
                subprocess.run([ADAPTISO, "generate", "sphere", "--size", str(size), "-o", path, "--quiet"], check=True)
            out.append((n, path, None))  # iso: the paper's relative 0.7
        else:
            p = volume_path(n)
            if p:
                out.append((n, p, sidecar_isos(n)))
            else:
                log(f"skipping {n}: no volume found")
    return out


def distance(mesh, ref, voxel):
    d = run_json([ADAPTISO, "compare", mesh, ref, "--voxel", str(voxel), "--max-samples", args.max_samples, "--json"])
    return {"mean_voxels": max(d["a_to_b"]["mean_voxels"], d["b_to_a"]["mean_voxels"]),
            "rms_voxels": max(d["a_to_b"]["rms_voxels"], d["b_to_a"]["rms_voxels"]),
            "p95_voxels": max(d["a_to_b"]["p95_voxels"], d["b_to_a"]["p95_voxels"]),
            "max_voxels": d["hausdorff_voxels"]}


def bench_dataset(name, path, isos, errors):
    log(f"== {name}: {path}")
    info = run_json([ADAPTISO, "info", path, "--json"])
    lo, hi = info["min"], info["max"]
    voxel = min(info["spacing"])
    if not isos:
        isos = [lo + 0.7 * (hi - lo)]
    isos = [i for i in isos if lo < i < hi][:2]
    W = os.path.join(args.work, name)
    os.makedirs(W, exist_ok=True)
    record(kind="dataset", dataset=name, dims=info["dims"], spacing=info["spacing"], min=lo, max=hi, voxels=info["voxels"])
    refs = {}
    for iso in isos:
        tag = f"{iso:g}"
        ref = f"{W}/mc_{tag}.ply"
        mc = run_json([ADAPTISO, "mc", path, "--iso", repr(iso), "-o", ref, "--json"])["surfaces"][0]
        refs[iso] = ref
        record(kind="mesh", dataset=name, iso=iso, method="adaptiso mc (full resolution)", triangles=mc["triangles"], seconds=mc["seconds"])
        try:
            for r in run_json([PEER, "vtk", path, repr(iso), f"{W}/{tag}_"], lines=True):
                mesh = f"{W}/{tag}_flying_edges.ply" if r["method"] == "vtkFlyingEdges3D" else f"{W}/{tag}_marching_cubes.ply"
                record(kind="mesh", dataset=name, iso=iso, method=r["method"], triangles=r["triangles"], seconds=r["seconds"],
                       smp=r.get("smp"), distance=distance(mesh, ref, voxel))
                if r["method"] == "vtkFlyingEdges3D":
                    fe_rec = records[-1]
                    for pct in (10, 2):  # the peers' usual decimation points
                        simp = f"{W}/{tag}_meshopt_{pct}pct.ply"
                        s = run_json([PEER, "simplify", mesh, str(r["triangles"] * pct // 100), simp], lines=True)[0]
                        record(kind="mesh", dataset=name, iso=iso, method=f"flying edges + meshoptimizer {pct} %",
                               triangles=s["triangles"], seconds=fe_rec["seconds"] + s["seconds"], distance=distance(simp, ref, voxel))
            for r in run_json([PEER, "vdb", path, repr(iso), f"{W}/{tag}_"], lines=True):
                mesh = f"{W}/{tag}_openvdb_{r['adaptivity']:.2f}.ply"
                record(kind="mesh", dataset=name, iso=iso, method=f"OpenVDB volumeToMesh {r['adaptivity']:g}",
                       triangles=r["triangles"], seconds=r["seconds"], distance=distance(mesh, ref, voxel))
            d = info["dims"]
            if info["voxels"] <= 200_000_000:
                raw = f"{W}/volume.raw"
                if not os.path.exists(raw):
                    subprocess.run([PEER, "dump", path, raw], check=True, capture_output=True)
                sp = info["spacing"]
                r = run_json(["/usr/bin/python3", SKIMAGE, raw, *map(str, d), *map(str, sp), repr(iso), f"{W}/{tag}_skimage.ply",
                              str(args.repeat)])
                subprocess.run([PEER, "world", path, f"{W}/{tag}_skimage.ply"], check=True)
                record(kind="mesh", dataset=name, iso=iso, method="scikit-image marching_cubes", triangles=r["triangles"],
                       seconds=r["seconds"], distance=distance(f"{W}/{tag}_skimage.ply", ref, voxel))
        except Exception as e:  # a failing peer must not hide the others
            log(f"    peer failed: {e}")
            record(kind="error", dataset=name, iso=iso, error=str(e))
    for error in errors:
        grid = f"{W}/grid_{error:g}.adg"
        prep = run_json([ADAPTISO, "prepare", path, "--relative", "--max-error", str(error), "-o", grid, "--json"])
        record(kind="prepare", dataset=name, error=error, kept=prep["kept"], ratio=prep["ratio"], tetrahedra=prep["tetrahedra"],
               pl_max_error=prep["pl_max_error"], pl_rms_error=prep["pl_rms_error"], max_error=prep["max_error"],
               seconds=prep["seconds"], bytes=prep["bytes"])
        for iso in isos:
            tag = f"{iso:g}"
            out = f"{W}/adaptiso_{error:g}_{tag}.ply"
            ex = run_json([ADAPTISO, "extract", grid, "--iso", repr(iso), "-o", out, "--json"])["surfaces"][0]
            be = run_json([BENCH_EXTRACT, grid, repr(iso)], lines=True)[0]
            fe = next((r for r in records if r.get("dataset") == name and r.get("iso") == iso and r.get("method") == "vtkFlyingEdges3D"), None)
            rec = record(kind="mesh", dataset=name, iso=iso, method=f"adaptiso (error {error:g})", error=error, triangles=ex["triangles"],
                         seconds=be["extract_fresh"], first_client_seconds=be["first_extract_with_state"],
                         step_small=be["step_0.1%"], step_large=be["step_1%"], query_tree=be["query_tree"], query_scan=be["query_scan"],
                         active_fraction=be["active_fraction"], distance=distance(out, refs[iso], voxel))
            if fe:  # flying edges + meshoptimizer down to adaptiso's triangle count
                simp = f"{W}/{tag}_meshopt_{error:g}.ply"
                r = run_json([PEER, "simplify", fe and f"{W}/{tag}_flying_edges.ply", str(ex["triangles"]), simp], lines=True)[0]
                record(kind="mesh", dataset=name, iso=iso, method=f"flying edges + meshoptimizer (to adaptiso {error:g})",
                       triangles=r["triangles"], seconds=fe["seconds"] + r["seconds"], distance=distance(simp, refs[iso], voxel))
        if prep["tetrahedra"] <= 40_000_000 and isos:
            vtu = f"{W}/grid_{error:g}.vtu"
            subprocess.run([ADAPTISO, "export", grid, "-o", vtu, "--quiet"], check=True)
            try:
                for r in run_json([PEER, "vtkgrid", vtu, ",".join(repr(i) for i in isos)], lines=True):
                    if r.get("stage") == "setup":
                        record(kind="setup", dataset=name, error=error, method=r["method"], load_seconds=r["load_seconds"],
                               first_seconds=r["first_seconds"])
                    else:
                        record(kind="mesh", dataset=name, iso=r["iso"], method=f"VTK contour of the adaptiso grid (error {error:g})",
                               triangles=r["triangles"], seconds=r["seconds"])
            except Exception as e:
                log(f"    vtkgrid failed: {e}")
            os.remove(vtu)
    if name == args.curve_dataset and isos:  # the triangles-vs-distance curve
        iso = isos[0]
        for error in [float(e) for e in args.curve_errors.split(",") if float(e) not in errors]:
            grid = f"{W}/curve_{error:g}.adg"
            out = f"{W}/curve_{error:g}.ply"
            rel_iso = (iso - lo) / (hi - lo)  # run's --relative applies to the error and the iso-value
            p = run_json([ADAPTISO, "run", path, "--relative", "--max-error", str(error), "--iso", repr(rel_iso), "-o", out, "--json"])
            record(kind="curve", dataset=name, iso=iso, error=error, kept=p["kept"], triangles=p["surfaces"][0]["triangles"],
                   distance=distance(out, refs[iso], voxel))
    if name == args.sweep_dataset:  # extraction time across a sweep of iso-values
        sweep = [lo + (hi - lo) * (0.05 + 0.9 * k / 15) for k in range(16)]
        grid = f"{W}/grid_{errors[0]:g}.adg"
        ex = run_json([ADAPTISO, "extract", grid, "--iso", ",".join(repr(s) for s in sweep), "-o", f"{W}/sweep.ply", "--json"])
        for s in ex["surfaces"]:
            record(kind="sweep", dataset=name, method="adaptiso (one client, consecutive values)", iso=s["iso"], triangles=s["triangles"],
                   seconds=s["seconds"])
        for r in run_json([PEER, "vtksweep", path, ",".join(repr(s) for s in sweep)], lines=True):
            record(kind="sweep", dataset=name, method="vtkFlyingEdges3D", iso=r["iso"], triangles=r["triangles"], seconds=r["seconds"])


def summary_tables():
    """One row per dataset and iso-value: adaptiso beside flying edges and the decimating peers."""
    def find(ds, iso, pred):
        return next((r for r in records if r.get("kind") == "mesh" and r["dataset"] == ds and r.get("iso") == iso and pred(r["method"])), None)
    out = ["## Summary", "",
           "| dataset | iso | FE triangles | adaptiso triangles | adaptiso mean / p95 distance | adaptiso time × FE | VTK grid contour × adaptiso "
           "| adaptiso mc × FE | OpenVDB 0.5: triangles, mean | FE + meshoptimizer 2 %: triangles, mean |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for ds in [r["dataset"] for r in records if r["kind"] == "dataset"]:
        for iso in sorted({r["iso"] for r in records if r.get("kind") == "mesh" and r["dataset"] == ds}):
            fe = find(ds, iso, lambda m: m == "vtkFlyingEdges3D")
            ad = find(ds, iso, lambda m: m.startswith("adaptiso (error"))
            vg = find(ds, iso, lambda m: m.startswith("VTK contour"))
            mc = find(ds, iso, lambda m: m.startswith("adaptiso mc"))
            vdb = find(ds, iso, lambda m: m == "OpenVDB volumeToMesh 0.5")
            mo = find(ds, iso, lambda m: m == "flying edges + meshoptimizer 2 %")
            if not (fe and ad and mc):
                continue
            cell = lambda r: f"{r['triangles']:,}, {r['distance']['mean_voxels']:.3f}" if r and r.get("distance") else ""
            out.append(f"| {ds} | {iso:g} | {fe['triangles']:,} | {ad['triangles']:,} | {ad['distance']['mean_voxels']:.3f} / "
                       f"{ad['distance']['p95_voxels']:.3f} | {ad['seconds'] / fe['seconds']:.3g} | "
                       f"{(vg.get('vs_adaptiso', vg['seconds'] / ad['seconds'])) if vg else float('nan'):.3g} | {mc['seconds'] / fe['seconds']:.3g} | "
                       f"{cell(vdb)} | {cell(mo)} |")
    out += ["", "| dataset | error | kept | % of voxels | tetrahedra | reduce s | tetrahedralize s | gradients s | index s | pl max / bound |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for p in [r for r in records if r["kind"] == "prepare"]:
        t = p["seconds"]
        out.append(f"| {p['dataset']} | {p['error']:g} | {p['kept']:,} | {100 * p['ratio']:.2f} | {p['tetrahedra']:,} | {t['reduce']:.2f} | "
                   f"{t['tetrahedralize']:.2f} | {t['gradients']:.2f} | {t['index']:.2f} | {p['pl_max_error']:g} / {p['max_error']:g} |")
    out += ["", "| dataset | iso | fresh ms | new client ms | step 0.1 % ms (× fresh, × new client) | step 1 % ms (× fresh) "
            "| re-marched 0.1 % / 1 % | tree query ms | scan ms | active % |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in [r for r in records if r["kind"] == "mesh" and r["method"].startswith("adaptiso (error")]:
        marched = f"{r['marched_small']:,} / {r['marched_large']:,}" if "marched_small" in r else ""
        out.append(f"| {r['dataset']} | {r['iso']:g} | {r['seconds'] * 1e3:.1f} | {r['first_client_seconds'] * 1e3:.1f} | "
                   f"{r['step_small'] * 1e3:.1f} ({r['step_small'] / r['seconds']:.2f}, {r['step_small'] / r['first_client_seconds']:.2f}) | "
                   f"{r['step_large'] * 1e3:.1f} ({r['step_large'] / r['seconds']:.2f}) | {marched} | {r['query_tree'] * 1e3:.3f} | "
                   f"{r['query_scan'] * 1e3:.2f} | {100 * r['active_fraction']:.2f} |")
    return out


def write_report(stamp):
    meta = {"date": stamp, "machine": platform.node(), "cpu": platform.processor() or platform.machine(), "threads": os.cpu_count(),
            "python": platform.python_version()}
    with open(os.path.join(args.out, f"{stamp}.json"), "w") as f:
        json.dump({"meta": meta, "records": records}, f, indent=1)
    md = [f"# adaptiso vs peers — {stamp}", "", f"Machine: {meta['cpu']}, {meta['threads']} threads. Times exclude I/O; "
          "`× FE` is the time relative to vtkFlyingEdges3D in the same run; distances are to the full-resolution "
          "marching-cubes surface, in voxels (max of both directions).", ""]
    md += summary_tables() + [""]
    for ds in [r for r in records if r["kind"] == "dataset"]:
        name = ds["dataset"]
        md += [f"## {name} ({'×'.join(map(str, ds['dims']))}, values {ds['min']:g} … {ds['max']:g})", ""]
        for p in [r for r in records if r["kind"] == "prepare" and r["dataset"] == name]:
            s = p["seconds"]
            md.append(f"adaptiso prepare, relative error {p['error']:g}: {p['kept']:,} kept vertices ({100 * p['ratio']:.2f} %), "
                      f"{p['tetrahedra']:,} tetrahedra; reduce {s['reduce']:.2f} s, tetrahedralize {s['tetrahedralize']:.2f} s, "
                      f"gradients {s['gradients']:.2f} s, index {s['index']:.2f} s; piecewise-linear error max {p['pl_max_error']:g} "
                      f"(bound {p['max_error']:g}).")
        for st in [r for r in records if r["kind"] == "setup" and r["dataset"] == name]:
            md.append(f"VTK on the same grid: load {st['load_seconds']:.2f} s, first contour with vtkSpanSpace build {st['first_seconds']:.2f} s.")
        md.append("")
        for iso in sorted({r["iso"] for r in records if r["kind"] == "mesh" and r["dataset"] == name and "iso" in r}):
            rows = [r for r in records if r["kind"] == "mesh" and r["dataset"] == name and r["iso"] == iso]
            fe = next((r["seconds"] for r in rows if r["method"] == "vtkFlyingEdges3D"), None)
            md += [f"### iso {iso:g}", "", "| method | triangles | seconds | × FE | mean dist | p95 | max |", "|---|---:|---:|---:|---:|---:|---:|"]
            for r in rows:
                d = r.get("distance") or {}
                ratio = f"{r['seconds'] / fe:.2f}" if fe else ""
                md.append(f"| {r['method']} | {r['triangles']:,} | {r['seconds']:.4f} | {ratio} | "
                          + " | ".join(f"{d[k]:.3f}" if k in d else "" for k in ("mean_voxels", "p95_voxels", "max_voxels")) + " |")
            for r in rows:
                if r["method"].startswith("adaptiso (error"):
                    md.append(f"\n{r['method']}: new client {r['first_client_seconds']:.4f} s, step 0.1 % {r['step_small']:.4f} s, "
                              f"step 1 % {r['step_large']:.4f} s; tree query {r['query_tree'] * 1e3:.3f} ms vs scan "
                              f"{r['query_scan'] * 1e3:.3f} ms ({r['query_scan'] / max(r['query_tree'], 1e-9):.0f}×); "
                              f"{100 * r['active_fraction']:.2f} % of the tetrahedra active.")
            md.append("")
    for e in [r for r in records if r["kind"] == "error"]:
        md.append(f"- {e['dataset']} iso {e['iso']:g}: {e['error']}")
    md += ["", f"![distance vs triangles]({stamp}-distance.png)", "", f"![iso sweep]({stamp}-sweep.png)", ""]
    with open(os.path.join(args.out, f"{stamp}.md"), "w") as f:
        f.write("\n".join(md))
    # Plot 1: distance to the full-resolution surface vs triangle count, every method.
    curve = [r for r in records if r["kind"] == "curve"]
    ds = curve[0]["dataset"] if curve else next((r["dataset"] for r in records if r["kind"] == "dataset" and r["dataset"] != "sphere"),
                                                next((r["dataset"] for r in records if r["kind"] == "dataset"), None))
    if ds:
        iso = curve[0]["iso"] if curve else None
        fig, ax = plt.subplots(figsize=(7, 5))
        pts = [r for r in records if r["kind"] == "mesh" and r["dataset"] == ds and (iso is None or r["iso"] == iso) and r.get("distance")]
        groups = {}
        for r in pts:
            key = re.sub(r" \(.*\)| [0-9.]+$", "", r["method"])
            groups.setdefault(key, []).append((r["triangles"], max(r["distance"]["mean_voxels"], 1e-3)))
        ad = sorted([(r["triangles"], max(r["distance"]["mean_voxels"], 1e-3)) for r in curve] +
                    [(r["triangles"], max(r["distance"]["mean_voxels"], 1e-3)) for r in pts if r["method"].startswith("adaptiso (error")])
        groups.pop("adaptiso", None)
        for k, v in groups.items():
            v.sort()
            ax.plot([a for a, _ in v], [b for _, b in v], "o-" if len(v) > 1 else "o", label=k)
        if ad:
            ax.plot([a for a, _ in ad], [b for _, b in ad], "s-", color="black", label="adaptiso (relative error sweep)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(bottom=1e-3)
        ax.set_xlabel("triangles")
        ax.set_ylabel("mean distance to full-resolution surface (voxels)")
        ax.set_title(f"{ds}, iso {iso:g}" if iso is not None else ds)
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(os.path.join(args.out, f"{stamp}-distance.png"), dpi=110)
    sweep = [r for r in records if r["kind"] == "sweep"]
    if sweep:
        fig, ax = plt.subplots(figsize=(7, 4))
        for m in sorted({r["method"] for r in sweep}):
            v = sorted((r["iso"], r["seconds"]) for r in sweep if r["method"] == m)
            ax.plot([a for a, _ in v], [1e3 * b for _, b in v], "o-", label=m)
        ax.set_xlabel("iso-value")
        ax.set_ylabel("extraction time (ms)")
        ax.set_title(f"iso sweep on {sweep[0]['dataset']}")
        ax.legend(fontsize=8)
        ax.grid(True, alpha=0.3)
        fig.tight_layout()
        fig.savefig(os.path.join(args.out, f"{stamp}-sweep.png"), dpi=110)


def refresh_extract(saved):
    """New timings in one run per dataset for the rows whose meshes do not change: flying edges and
    VTK marching cubes, our marching cubes, and bench_extract on the grid saved by the full run."""
    global records
    records = saved["records"]
    names = set(args.datasets) if args.datasets else None
    paths = {n: p for n, p, _ in datasets()}
    for ds in [r for r in records if r["kind"] == "dataset" and (names is None or r["dataset"] in names)]:
        name, W = ds["dataset"], os.path.join(args.work, ds["dataset"])
        if name not in paths:
            continue
        log(f"== {name}: re-timing extraction")
        for iso in sorted({r["iso"] for r in records if r["kind"] == "mesh" and r["dataset"] == name}):
            rows = {r["method"]: r for r in records if r["kind"] == "mesh" and r["dataset"] == name and r["iso"] == iso}
            tag = f"{iso:g}"
            fe_old = rows.get("vtkFlyingEdges3D", {}).get("seconds")
            for r in run_json([PEER, "vtk", paths[name], repr(iso), f"{W}/{tag}_"], lines=True):
                if r["method"] in rows:
                    rows[r["method"]]["seconds"] = r["seconds"]
            fe_new = rows.get("vtkFlyingEdges3D", {}).get("seconds")
            for m, r in rows.items():  # decimation rows: flying edges + the (unchanged) simplification time
                if m.startswith("flying edges + meshoptimizer") and fe_old and fe_new:
                    r["seconds"] += fe_new - fe_old
            if "adaptiso mc (full resolution)" in rows:
                mc = run_json([ADAPTISO, "mc", paths[name], "--iso", repr(iso), "-o", f"{W}/mc_{tag}.ply", "--json"])["surfaces"][0]
                rows["adaptiso mc (full resolution)"]["seconds"] = mc["seconds"]
            for m, r in rows.items():
                grid = f"{W}/grid_{r.get('error', 0):g}.adg"
                vg = rows.get(f"VTK contour of the adaptiso grid (error {r.get('error', 0):g})")
                if vg and "vs_adaptiso" not in vg:  # not re-timed here: keep the ratio of the run that timed it
                    vg["vs_adaptiso"] = vg["seconds"] / r["seconds"]
                if m.startswith("adaptiso (error") and os.path.exists(grid):
                    be = run_json([BENCH_EXTRACT, grid, repr(iso)], lines=True)[0]
                    r.update(seconds=be["extract_fresh"], first_client_seconds=be["first_extract_with_state"], step_small=be["step_0.1%"],
                             step_large=be["step_1%"], marched_small=be["marched_0.1%"], marched_large=be["marched_1%"],
                             query_tree=be["query_tree"], query_scan=be["query_scan"], active_fraction=be["active_fraction"])


if args.refresh_extract:
    refresh_extract(json.load(open(args.refresh_extract)))
    write_report(datetime.date.today().isoformat())
    sys.exit(0)
if args.replot:
    saved = json.load(open(args.replot))
    records = saved["records"]
    write_report(os.path.splitext(os.path.basename(args.replot))[0])
    sys.exit(0)
stamp = datetime.date.today().isoformat()
if args.append:
    rerun = {n for n, _, _ in datasets()}
    records = [r for r in json.load(open(args.append))["records"] if r.get("dataset") not in rerun]
errors = [float(e) for e in args.errors.split(",")]
try:
    for name, path, isos in datasets():
        try:
            bench_dataset(name, path, isos, errors)
        except Exception as e:
            log(f"  {name} failed: {e}")
            record(kind="error", dataset=name, iso=0, error=str(e))
        write_report(stamp)  # after every dataset, so an interrupted run still leaves a report
finally:
    write_report(stamp)
log(f"wrote {args.out}/{stamp}.json, .md and plots")
