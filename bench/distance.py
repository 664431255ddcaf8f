#!/usr/bin/env python3
"""Surface-adaptive extraction against the peers (issue "Surface-adaptive extraction"), all in one
run. For each volume and iso-value, on the bisection grid `prepare` makes by default:

- adaptiso --distance D --collapse R: `extract GRID --iso V --distance D --collapse R` for each D and
  each R of --collapse (rounds of edge collapses after the march; 0: every triangle inside its
  tetrahedron; 8: the default), and the grid's own surface (D = "grid");
- flying edges: VTK's vtkFlyingEdges3D (SMP, `peer_bench fe`), the reference for time and triangles;
- flying edges + meshoptimizer at D: that surface simplified with the same distance as target
  (`bench_simplify MESH D·voxel 0`), its time added to flying edges';
- adaptiso --distance D/2 --simplify D/2 [--checked]: the query at half the distance, its surface
  simplified by the other half (meshoptimizer's estimate, or checked: simplify.hpp);
- adaptiso mc --simplify D: full-resolution marching cubes and our chunked simplification;
- OpenVDB volumeToMesh at adaptivity 0.25 and 0.5 (`peer_bench vdb`).

Per row: triangles and their ratio to flying edges', mean / p95 / max symmetric distance to the
full-resolution surface (`adaptiso mc`, voxels of the smallest spacing), for adaptiso's rows also
mean / p95 against the grid's own surface (what --distance bounds), with the p95 each way in
brackets (to the grid: what --distance promises; from the grid: also the pieces under --min-piece
dropped, as far as they lay from the rest), and seconds (the tools' own
timings, fastest of --repeat, no file I/O) with their ratio to flying edges'. A new iso-value on a
loaded grid costs adaptiso the query alone; the query's one-time set-up per loaded grid is printed
beside the grid. The peers need `peer_bench` and `bench_simplify` (scripts/bench.sh builds them into
build/peers, -DADAPTISO_BUILD_PEERS=ON); without them their rows are left out with a message.

Usage: bench/distance.py --build BUILD [--data DIR] [--work DIR] [--distances 0.5,1,2] [--collapse 0,8] [--query-only]
                         [--repeat 3] [--out RECORDS.json] [DATASET[:ISO,...] ...]
"""
import argparse
import json
import os
import subprocess
import sys

from defaults import compare, last_json, main_input, run

DEFAULT = ["ct_bunny_stanford:1600.5", "dicom_mr_head_t1_vsseg:120.5", "ct_chest_lidc2:100.5", "mr_brain_flair:90.5",
           "ct_head_headsq_quarter:1000.5", "sci_neghip:50.5"]


def fastest(cmd, repeat, seconds):
    """The record of the fastest of `repeat` runs; `seconds(record)` reads its time."""
    best = None
    for _ in range(repeat):
        r = json.loads(run(cmd))
        if best is None or seconds(r) < seconds(best):
            best = r
    return best


def query_setup_seconds(build, grid, iso):
    """bench_distance's one-time HierarchyQuery construction on a loaded grid (None when not built)."""
    bench = os.path.join(build, "bin", "bench_distance")
    if not os.path.exists(bench):
        return None
    return last_json(run([bench, grid, f"{iso:g}", "1", "1"]))["setup_seconds"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--data", default=os.environ.get("ADAPTISO_DATA", "../shared/data"))
    ap.add_argument("--work", default="build/distance-work")
    ap.add_argument("--distances", default="0.5,1,2")
    ap.add_argument("--collapse", default="0,8", help="rounds of edge collapses after the query, one row each (8: the default)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing (fastest kept)")
    ap.add_argument("--query-only", action="store_true",
                    help="the grid's surface, the query at each D and the peers (flying edges, flying edges + meshoptimizer at each D, OpenVDB); "
                         "no rows of our simplification (the tandem, mc --simplify): minutes less on large volumes")
    ap.add_argument("--out")
    ap.add_argument("datasets", nargs="*")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bin", "adaptiso")
    peer = os.path.join(a.build, "bin", "peer_bench")
    simplify = os.path.join(a.build, "bin", "bench_simplify")
    if not (os.path.exists(peer) and os.path.exists(simplify)):
        print(f"{peer} or {simplify} not built: the flying-edges and OpenVDB rows are left out (scripts/bench.sh builds them)",
              file=sys.stderr)
        peer = None
    os.environ["PEER_REPEAT"] = str(a.repeat)
    os.makedirs(a.work, exist_ok=True)
    distances = [float(x) for x in a.distances.split(",")]
    records = []

    print("| volume | iso | method | D | triangles | ÷ FE | mean / p95 / max to mc | mean / p95 to grid (to / from) | seconds | ÷ FE |")
    print("|---|---:|---|---:|---:|---:|---|---|---:|---:|")
    for spec in a.datasets or DEFAULT:
        name, _, isos = spec.partition(":")
        src = main_input(a.data, name, a.work)
        if not src:
            print(f"skipping {name}: not in {a.data}", file=sys.stderr)
            continue
        voxel = min(json.loads(run([exe, "info", src, "--json"]))["spacing"])
        grid = os.path.join(a.work, name + ".adg")
        prep = json.loads(run([exe, "prepare", src, "-o", grid, "--json", "--quiet"]))
        print(f"<!-- {name}: default grid, {prep.get('tetrahedra', '?')} tetrahedra, prepared in "
              f"{prep.get('seconds', {}).get('total', float('nan')) if isinstance(prep.get('seconds'), dict) else prep.get('seconds')} s -->",
              flush=True)
        for iso in [float(x) for x in isos.split(",")]:
            tag = os.path.join(a.work, f"{name}-{iso:g}")
            ref, own, mesh, fe = tag + "-mc.ply", tag + "-grid.ply", tag + ".ply", tag + "-fe.ply"
            run([exe, "mc", src, "--iso", f"{iso:g}", "-o", ref, "--quiet"])
            fe_rec = None
            if peer:
                fe_rec = last_json(run([peer, "fe", src, f"{iso:g}", fe]))

            def record(method, d, path, triangles, seconds, against_grid, **extra):
                mean, p95, worst = compare(exe, path, ref, voxel)[:3]
                rec = {"dataset": name, "iso": iso, "method": method, "distance": d, "triangles": triangles, "mean": mean, "p95": p95,
                       "max": worst, "seconds": seconds, **extra}
                grid_cell = "–"
                if against_grid:
                    c = compare(exe, path, own, voxel)
                    rec["grid_mean"], rec["grid_p95"], rec["grid_max"], rec["grid_p95_to"], rec["grid_p95_from"] = c.mean, c.p95, c.max, c.p95_to, c.p95_from
                    grid_cell = f"{rec['grid_mean']:.3f} / {rec['grid_p95']:.3f} ({rec['grid_p95_to']:.2f} / {rec['grid_p95_from']:.2f})"
                tri_ratio = f"{triangles / fe_rec['triangles']:.3f}" if fe_rec else "–"
                time_ratio = f"{seconds / fe_rec['seconds']:.2f}" if fe_rec else "–"
                label = extra.get("label", "–" if d is None else f"{d:g}")
                print(f"| {name} | {iso:g} | {method} | {label} | {triangles:,} | {tri_ratio} | {mean:.3f} / {p95:.3f} / {worst:.2f} | "
                      f"{grid_cell} | {seconds:.3f} | {time_ratio} |", flush=True)
                records.append(rec)

            if fe_rec:
                record("flying edges (VTK)", None, fe, fe_rec["triangles"], fe_rec["seconds"], False)
            s = fastest([exe, "extract", grid, "--iso", f"{iso:g}", "-o", own, "--json", "--quiet"], a.repeat,
                        lambda r: r["surfaces"][0]["seconds"])["surfaces"][0]
            record("adaptiso, the grid's surface", None, own, s["triangles"], s["seconds"], False, label="grid")
            for d in distances:
                for rounds in [int(r) for r in a.collapse.split(",")]:
                    s = fastest([exe, "extract", grid, "--iso", f"{iso:g}", "--distance", f"{d:g}", "--collapse", str(rounds), "-o", mesh,
                                 "--json", "--quiet"], a.repeat, lambda r: r["surfaces"][0]["seconds"])["surfaces"][0]
                    record(f"adaptiso --distance --collapse {rounds}", d, mesh, s["triangles"], s["seconds"], True)
                if fe_rec:
                    one = last_json(run([simplify, fe, repr(d * voxel), "0", mesh]))
                    record("flying edges + meshoptimizer", d, mesh, one["triangles_after"], fe_rec["seconds"] + one["seconds"], False)
                if a.query_only:
                    continue
                # Tandem: half the distance to the query, half to a simplification of its surface,
                # meshoptimizer's estimate alone and checked (simplify.hpp).
                for checked in ([], ["--checked"]):
                    t = fastest([exe, "extract", grid, "--iso", f"{iso:g}", "--distance", f"{d / 2:g}", "--simplify", f"{d / 2:g}", *checked,
                                 "-o", mesh, "--json", "--quiet"], a.repeat,
                                lambda r: r["surfaces"][0]["seconds"] + r["surfaces"][0]["simplify"]["seconds"])["surfaces"][0]
                    record("adaptiso --distance D/2 --simplify D/2" + (" --checked" if checked else ""), d, mesh,
                           t["simplify"]["triangles_after"], t["seconds"] + t["simplify"]["seconds"], True)
                m = fastest([exe, "mc", src, "--iso", f"{iso:g}", "-o", mesh, "--json", "--quiet", "--simplify", f"{d:g}"], a.repeat,
                            lambda r: r["surfaces"][0]["seconds"] + r["surfaces"][0]["simplify"]["seconds"])["surfaces"][0]
                record("adaptiso mc --simplify", d, mesh, m["simplify"]["triangles_after"], m["seconds"] + m["simplify"]["seconds"], False)
            if peer:
                for line in run([peer, "vdb", src, f"{iso:g}", tag + "-"]).strip().splitlines():
                    v = json.loads(line)
                    vdb = f"{tag}-openvdb_{v['adaptivity']:.2f}.ply"
                    if v["adaptivity"] in (0.25, 0.5):
                        record("OpenVDB volumeToMesh", None, vdb, v["triangles"], v["seconds"], False, label=f"a={v['adaptivity']:g}")
                    if os.path.exists(vdb):
                        os.remove(vdb)
            setup = query_setup_seconds(a.build, grid, iso)
            if setup is not None:
                print(f"<!-- {name}: the distance query's one-time set-up on a loaded grid: {setup:.3f} s -->", flush=True)
            for p in (ref, own, mesh, fe):
                if os.path.exists(p):
                    os.remove(p)
        os.remove(grid)
    if a.out:
        with open(a.out, "w") as f:
            json.dump(records, f, indent=1)


if __name__ == "__main__":
    try:
        main()
    except (RuntimeError, subprocess.SubprocessError) as e:
        sys.exit(f"distance.py: {e}")
