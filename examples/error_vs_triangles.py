#!/usr/bin/python3
"""Prepares a shared volume once, extracts two iso-values at a range of errors from the bisection
hierarchy (no second preparation), and plots triangles and extraction time against the error.

Usage: examples/error_vs_triangles.py [VOLUME] [ISO1 ISO2] [-o PLOT.png]
Defaults: the CT chest of ../shared/data (ADAPTISO_DATA) at its suggested iso-values 100 and 200.
Needs the installed module (README "Python") and Debian's python3-matplotlib.
"""
import argparse
import os
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import adaptiso  # noqa: E402


def main():
    data = os.environ.get("ADAPTISO_DATA", os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("volume", nargs="?", default=os.path.join(data, "ct_chest_lidc2.nhdr"))
    ap.add_argument("isos", nargs="*", type=float, default=[100.0, 200.0])
    ap.add_argument("-o", "--output", default="error_vs_triangles.png")
    a = ap.parse_args()

    volume = adaptiso.read(a.volume)
    t0 = time.perf_counter()
    grid = adaptiso.prepare(volume, max_error=0.005, relative=True)
    print(f"prepared {grid} in {time.perf_counter() - t0:.2f} s (guaranteed error {grid.error_bound:.4g})")
    lo, hi = grid.value_range
    errors = [0.005 * 2 ** (k / 2) for k in range(0, 13)]  # fractions of the value range
    fig, (ax_t, ax_s) = plt.subplots(1, 2, figsize=(10, 4))
    for iso in a.isos:
        triangles, seconds = [], []
        for e in errors:
            t0 = time.perf_counter()
            _, faces, _ = grid.extract(iso, max_error=e * (hi - lo))
            seconds.append(time.perf_counter() - t0)
            triangles.append(len(faces))
        print(f"iso {iso:g}: " + ", ".join(f"{e:.3g}→{n:,}" for e, n in zip(errors, triangles)))
        ax_t.loglog(errors, triangles, "o-", label=f"iso {iso:g}")
        ax_s.loglog(errors, [1000 * s for s in seconds], "o-", label=f"iso {iso:g}")
    ax_t.set(xlabel="max error (fraction of the value range)", ylabel="triangles", title=os.path.basename(a.volume))
    ax_s.set(xlabel="max error (fraction of the value range)", ylabel="extraction ms")
    for ax in (ax_t, ax_s):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(a.output, dpi=100)
    print(f"wrote {a.output}")


if __name__ == "__main__":
    main()
