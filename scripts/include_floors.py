#!/usr/bin/env python3
"""The include graph between the folders of src/, floor by floor (README "Where things live").

Counts the upward includes (a file of a lower floor including a header of a higher one) and the
include cycles between folders, and lists them. A public header include/adaptiso/X.hpp belongs to
the folder whose src/<folder>/X.cpp implements it, or to the one OWNER names; a header of neither
is an error, so a new header gets a floor on purpose.

  scripts/include_floors.py [ROOT] [--order util,mesh,...] [--list] [--check]

--check exits 1 when there is an upward include or a cycle (the test includes_flow_one_way).
"""
import argparse
import os
import re
import sys

# The floors, lowest first; folders joined by '/' share a floor (README "Where things live").
FLOORS = "util,mesh,volume,reduce/grid,gradients,index,prepare,extract,io,view"

# Public headers without a .cpp of their name.
OWNER = {
    "atomic_file.hpp": "util", "error.hpp": "util", "number.hpp": "util", "progress.hpp": "util",
    "version.hpp": "util", "mesh.hpp": "mesh", "volume_io.hpp": "volume", "synthetic.hpp": "volume",
    "tet_grid.hpp": "grid", "bisection.hpp": "grid", "select_shares.hpp": "grid", "marching_tetrahedra.hpp": "extract",
    "hierarchy_query.hpp": "extract", "prepare_to_file.hpp": "io", "view_server.hpp": "view",
}

INCLUDE = re.compile(r'^\s*#\s*include\s*"([^"]+)"')


def files_by_folder(root):
    """(folder, path, shown name) of every source and header, public headers with their owner."""
    src = os.path.join(root, "src")
    folders = sorted(d for d in os.listdir(src) if os.path.isdir(os.path.join(src, d)))
    implemented = {}
    out = []
    for d in folders:
        for f in sorted(os.listdir(os.path.join(src, d))):
            if f.endswith(".cpp"):
                implemented.setdefault(f[:-4] + ".hpp", d)
            if f.endswith((".cpp", ".hpp")):
                out.append((d, os.path.join(src, d, f), f"src/{d}/{f}"))
    owner = dict(implemented, **OWNER)
    public = os.path.join(root, "include", "adaptiso")
    for f in sorted(os.listdir(public)):
        if f.endswith(".hpp"):
            if f not in owner:
                sys.exit(f"include_floors.py: no folder owns include/adaptiso/{f} (add it to OWNER)")
            out.append((owner[f], os.path.join(public, f), f"include/adaptiso/{f}"))
    return out, owner, folders


def arrows(root):
    """{(from folder, to folder): [file -> included header, ...]} between different folders."""
    files, owner, folders = files_by_folder(root)
    edges = {}
    for d, path, shown in files:
        with open(path, encoding="utf-8") as text:
            for line in text:
                m = INCLUDE.match(line)
                if not m:
                    continue
                h = m.group(1)
                if h.startswith("adaptiso/"):
                    name = h[len("adaptiso/"):]
                    if name == "version.hpp":
                        target = "util"
                    elif name in owner:
                        target = owner[name]
                    else:
                        sys.exit(f"include_floors.py: {shown} includes {h}, which no folder owns")
                elif "/" in h and h.split("/")[0] in folders:
                    target = h.split("/")[0]
                else:
                    target = d  # a header beside the file
                if target != d:
                    edges.setdefault((d, target), []).append(f"{shown} -> {h}")
    return edges, folders


def cycles(edges):
    """Groups of folders that reach each other (Tarjan's strongly connected components, size > 1)."""
    adj = {}
    for a, b in edges:
        adj.setdefault(a, set()).add(b)
    index, low, stack, on, groups = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(adj.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted({x for e in edges for x in e}):
        if v not in index:
            visit(v)
    return groups


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("root", nargs="?", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    p.add_argument("--order", default=FLOORS, help=f"floors, lowest first (default {FLOORS})")
    p.add_argument("--list", action="store_true", help="list every upward include and every include of a cycle")
    p.add_argument("--check", action="store_true", help="exit 1 on an upward include or a cycle")
    a = p.parse_args()
    floor = {f: i for i, group in enumerate(a.order.split(",")) for f in group.split("/")}
    edges, folders = arrows(a.root)
    missing = sorted(set(folders) - set(floor))
    if missing:
        sys.exit(f"include_floors.py: folders without a floor: {', '.join(missing)}")
    up = sorted((w for (x, y), ws in edges.items() if floor[y] > floor[x] for w in ws))
    groups = cycles(edges)
    print(f"floors {a.order}")
    print(f"{len(edges)} arrows between folders; {len(up)} upward includes; {len(groups)} include cycles")
    if a.list:
        for w in up:
            print(f"  up     {w}")
        for g in groups:
            print(f"  cycle  {' <-> '.join(g)}")
            for (x, y), ws in sorted(edges.items()):
                if x in g and y in g:
                    for w in ws:
                        print(f"           {w}")
    return 1 if a.check and (up or groups) else 0


if __name__ == "__main__":
    sys.exit(main())
