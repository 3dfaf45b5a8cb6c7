"""Tiled tessellation under a memory limit against the in-core tessellation: peak resident memory and time, each
in a fresh process, in one run; and the calibration of the tessellation's memory prediction.

    python bench/bench_tiled_tessellate.py                              # torus 5000 quads, rate 24, tiled under 1G
    python bench/bench_tiled_tessellate.py --rate 48 --max-memory 2G
    python bench/bench_tiled_tessellate.py --calibrate --rates 4,8,16,32   # measured peak against predict()

The in-core worker runs ``LimitSurface(mesh).tessellate(rate=...)``; the tiled worker iterates
``tessellate_tiled(mesh, rate=..., max_memory=...)`` and drops each tile after summing its points. Each reports
its peak resident memory (VmHWM, the whole process), its resident memory before the call (after the mesh is read
and Warp's kernels are loaded) and its wall time. ``--calibrate`` runs the in-core worker at each rate and prints
the measured peak above the baseline beside :func:`warp_subdiv.tiled_tessellation.predict` of its counts.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchutil import ROOT, proc_status, quiet_warp, run_child

MARK = "TESS_RESULT "
MESH = os.path.join("/work/shared/meshes/bench", "torus_100x50_5000quad.obj")


def worker(args) -> None:
    sys.path.insert(0, ROOT)
    quiet_warp()
    import numpy as np
    import warp_subdiv as ws
    from warp_subdiv.io.obj import read_obj
    from warp_subdiv.tiled_tessellation import _Numbering, _SurfacePlan, predict
    from warp_subdiv.limit.tessellation import segment_rates

    mesh = read_obj(args.mesh).mesh
    small = ws.Mesh(mesh.points[:4], [4], [0, 1, 2, 3])
    ws.LimitSurface(small, device="cpu").tessellate(rate=2)  # load the kernels
    options = ws.Options(scheme=args.scheme)
    plan = _SurfacePlan(mesh, options)
    numbering = _Numbering(plan, *segment_rates(type("M", (), {"mesh": mesh})(), args.rate, None), True)
    emitted, faces = numbering.size_of(np.arange(len(plan.counts)))
    corners = int(plan.counts.sum())
    irregular = int(plan.counts[plan.irregular].sum())
    del plan, numbering
    baseline = proc_status().get("VmRSS", 0)
    start = time.perf_counter()
    if args.worker == "in-core":
        t = ws.LimitSurface(mesh, device="cpu", options=options).tessellate(rate=args.rate)
        result = {"vertices": t.num_vertices, "faces": t.num_faces, "tiles": 1}
        del t
    else:
        vertices, out_faces, count = 0, 0, 0
        for tile in ws.tessellate_tiled(mesh, rate=args.rate, max_memory=args.max_memory, device="cpu",
                                        options=options):
            count += 1
            vertices += int(np.count_nonzero(~tile.border))
            out_faces += tile.num_faces
        result = {"unshared_vertices": vertices, "faces": out_faces, "tiles": count}
    result["seconds"] = time.perf_counter() - start
    result["peak_rss"] = proc_status().get("VmHWM", 0)
    result["baseline_rss"] = baseline
    result["predicted"] = predict(corners, irregular, emitted, faces)
    print(MARK + json.dumps(result), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", default=MESH)
    parser.add_argument("--rate", type=int, default=24)
    parser.add_argument("--scheme", default="catmull-clark", choices=["catmull-clark", "loop"])
    parser.add_argument("--rates", default="4,8,16,32", help="--calibrate: the rates")
    parser.add_argument("--max-memory", default="1G")
    parser.add_argument("--calibrate", action="store_true")
    parser.add_argument("--no-in-core", action="store_true", help="skip the in-core run")
    parser.add_argument("--kill-above", default="20G", help="kill a worker whose process tree is above this")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker(args)
    from warp_subdiv.runtime.estimate import format_bytes, parse_size

    kill = parse_size(args.kill_above)
    print(f"{os.path.basename(args.mesh)}, load average {os.getloadavg()[0]:.2f}")
    if args.calibrate:
        runs = [("in-core", int(r)) for r in args.rates.split(",")]
    else:
        runs = ([] if args.no_in_core else [("in-core", args.rate)]) + [("tiled", args.rate)]
        print(f"rate {args.rate}; tiled under --max-memory {args.max_memory}")
    rows = {}
    for name, rate in runs:
        cmd = [sys.executable, os.path.abspath(__file__), "--worker", name, "--mesh", args.mesh, "--rate",
               str(rate), "--max-memory", args.max_memory, "--scheme", args.scheme]
        result, reason = run_child(cmd, 7200, kill, MARK, {"PYTHONPATH": ROOT})
        if result is None:
            print(f"  {name:8s} rate {rate} failed: {reason}")
            continue
        rows[name] = result
        added = result["peak_rss"] - result["baseline_rss"]
        print(f"  {name:8s} rate {rate:3d}: peak RSS {format_bytes(result['peak_rss']):>10s} (before the call "
              f"{format_bytes(result['baseline_rss'])}, added {format_bytes(added)}; predicted in core "
              f"{format_bytes(result['predicted'])})  {result['seconds']:8.1f} s  {result['tiles']} tile(s), "
              f"{result['faces']:,} faces")
    if len(rows) == 2 and not args.calibrate:
        a, b = rows["in-core"], rows["tiled"]
        print(f"  tiled / in-core: peak {b['peak_rss'] / a['peak_rss']:.2f}x, time {b['seconds'] / a['seconds']:.2f}x")


if __name__ == "__main__":
    main()
