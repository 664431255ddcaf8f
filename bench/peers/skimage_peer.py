#!/usr/bin/python3
"""scikit-image marching_cubes (Lewiner) on a float32 raw volume written by `peer_bench dump`.

usage: skimage_peer.py RAW NX NY NZ SX SY SZ ISO OUT.ply [REPEAT]
Prints one JSON line; writes the mesh (world = spacing * index, like the other peers) as PLY.
"""
import json
import sys
import time

import numpy as np
from skimage import measure

raw, nx, ny, nz, sx, sy, sz, iso, out = sys.argv[1:10]
repeat = int(sys.argv[10]) if len(sys.argv) > 10 else 3
nx, ny, nz = int(nx), int(ny), int(nz)
vol = np.fromfile(raw, dtype="<f4").reshape(nz, ny, nx)  # x fastest on disk
spacing = (float(sz), float(sy), float(sx))
level = float(iso)
best = float("inf")
result = None
for r in range(repeat + 1):  # the first run is a warm-up
    t0 = time.perf_counter()
    result = measure.marching_cubes(vol, level=level, spacing=spacing, method="lewiner")
    if r:
        best = min(best, time.perf_counter() - t0)
verts, faces = result[0][:, ::-1].astype("<f4"), result[1].astype("<u4")  # (z,y,x) -> (x,y,z)
with open(out, "wb") as f:
    f.write(f"ply\nformat binary_little_endian 1.0\nelement vertex {len(verts)}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {len(faces)}\nproperty list uchar uint vertex_indices\nend_header\n".encode())
    f.write(np.ascontiguousarray(verts).tobytes())
    rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<u4", 3)])
    rec["n"] = 3
    rec["i"] = faces
    f.write(rec.tobytes())
print(json.dumps({"method": "skimage.marching_cubes", "triangles": int(len(faces)), "seconds": best, "threads": 1}))
