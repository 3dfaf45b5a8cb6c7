"""When the CPU evaluator's expanded quad tables pay: first and later evaluations of fresh refiners, with the
compact tables, the expanded ones, and the default (compact for the first two evaluations, expanded from the
third: ``Evaluator.expand_tables`` None).

    python bench/bench_expand.py [--levels 2,3,4] [--refiners 6]

A torus of 125 x 104 quads (the bake benchmark's mesh) refined ``--levels``; for each setting, ``--refiners``
fresh refiners (one thread) each evaluate the control points four times; per evaluation the median over the
refiners, in milliseconds. The settings take turns refiner by refiner, so a change in the machine's speed
touches each alike. Results are bitwise the same for every setting (checked).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchutil import ROOT, parse_levels, quiet_warp

if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", default="2,3,4")
    ap.add_argument("--refiners", type=int, default=6)
    args = ap.parse_args(argv)
    quiet_warp()
    import warp_subdiv as ws
    from bench_bake import torus

    pts, counts, idx, _, _ = torus(125, 104)
    mesh = ws.Mesh(pts, counts, idx)
    ws.Refiner(mesh, 1, device="cpu", threads=1).evaluate(pts)  # loads the kernels
    settings = {"compact": False, "expanded": True, "default": None}
    print("| level | tables | 1st evaluation (ms) | 2nd | 3rd | 4th | four in all |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for level in parse_levels(args.levels):
        times = {name: [] for name in settings}
        expected = None
        for _ in range(args.refiners):
            for name, expand in settings.items():
                r = ws.Refiner(mesh, level, device="cpu", threads=1)
                r.evaluator.expand_tables = expand
                row = []
                for _ in range(4):
                    t0 = time.perf_counter()
                    out = r.evaluate(pts)
                    row.append(time.perf_counter() - t0)
                    if expected is None:
                        expected = out
                    elif not np.array_equal(out, expected):
                        raise SystemExit(f"level {level} {name}: results differ")
                times[name].append(row)
                del r, out
        for name, rows in times.items():
            med = np.median(np.array(rows), axis=0) * 1e3
            print(f"| {level} | {name} | {med[0]:.1f} | {med[1]:.1f} | {med[2]:.1f} | {med[3]:.1f} | {med.sum():.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
