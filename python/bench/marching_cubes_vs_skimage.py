"""adaptiso.marching_cubes against skimage.measure.marching_cubes, same arguments, in one run,
alternating (the machine is shared and noisy: ratios of interleaved medians, not absolute times).

    /usr/bin/python3 python/bench/marching_cubes_vs_skimage.py [--data ../shared/data] [--repeats 5]

Volumes: the CT bunny (512x512x361 int16, read with adaptiso.read; iso 1600.5, its spacing) and a
256^3 float32 sphere-like field. Prints one JSON line per case.
"""
import argparse
import json
import os
import statistics
import time

import numpy as np
import skimage.measure

import adaptiso


def timed(call):
    t0 = time.perf_counter()
    out = call()
    return time.perf_counter() - t0, out


def case(name, array, level, spacing, method, repeats):
    ours_t, theirs_t = [], []
    ours = theirs = None
    for _ in range(repeats):
        t, ours = timed(lambda: adaptiso.marching_cubes(array, level, spacing=spacing, method=method))
        ours_t.append(t)
        t, theirs = timed(lambda: skimage.measure.marching_cubes(array, level, spacing=spacing, method=method))
        theirs_t.append(t)
    o, s = statistics.median(ours_t), statistics.median(theirs_t)
    print(json.dumps({"case": name, "method": method, "triangles": [len(ours[1]), len(theirs[1])], "adaptiso_s": round(o, 3),
                      "skimage_s": round(s, 3), "speedup": round(s / o, 2), "adaptiso_all": [round(x, 3) for x in ours_t],
                      "skimage_all": [round(x, 3) for x in theirs_t]}), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data"))
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    bunny = adaptiso.read(os.path.join(args.data, "ct_bunny_stanford.nhdr"))
    spacing = tuple(bunny.spacing[::-1])  # [z, y, x], as the array
    n = 256
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float32)
    field = np.sqrt((x - 127.3) ** 2 + (y - 128.6) ** 2 + (z - 126.9) ** 2) + 4 * np.sin(x / 9) * np.cos(y / 11)
    field = field.astype(np.float32)
    for method in ("lewiner", "lorensen"):
        case("ct_bunny_stanford iso 1600.5", bunny.array, 1600.5, spacing, method, args.repeats)
        case("float32 256^3 iso 90.5", field, 90.5, (1.0, 1.0, 1.0), method, args.repeats)


if __name__ == "__main__":
    main()
