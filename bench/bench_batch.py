"""The USD bake of many small animated props with and without batching (one launch per step for many
small meshes, :mod:`warp_subdiv.batch`).

    python bench/bench_batch.py                    # 1,000 cubes x 24 frames and 200 props of 96 quads x 24 frames, L2
    python bench/bench_batch.py --normals --reps 3
    python bench/bench_batch.py --quick            # 50 cubes and 10 props x 3 frames (CI smoke test)

Generates each scene once (a ``.usdc`` layer: ``--cubes`` 8-vertex cubes and ``--props`` props of 96 quads (the
surface of a cube cut 4 x 4 per side), every prop moved and jittered at each of ``--frames`` time samples),
then bakes it with ``refine_usd(..., batch=True)`` and ``batch=False``, each in a fresh process, alternating,
best of ``--reps``; ``--normals`` also writes limit normals (``evaluate_with_limits``). Reports per scene and
mode the bake's wall time (``Result.seconds``: read, analyse, refine, write), its process CPU time (every
thread; steadier than the wall clock on a shared machine) and its ``refine`` phase (``Result.phases``: the
evaluation of points and normals), each with the ratio of unbatched to batched. Prints a
Markdown table; ``--json`` writes every figure.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from benchutil import quiet_warp, run_child  # noqa: E402
from fuzz import box_quads  # noqa: E402

MARK = "BENCH_BATCH_RESULT "


def make_scene(path: str, count: int, cuts: int, frames: int, seed: int = 0) -> dict:
    """``count`` props (the surface of a cube cut ``cuts`` x ``cuts`` per side), each at its own place, with
    ``frames`` time samples of moved and jittered points, written with Sdf (fast for thousands of prims)."""
    from pxr import Sdf, Vt

    pts, quads = box_quads(cuts)
    pts = pts / cuts
    counts = Vt.IntArray([4] * len(quads))
    indices = Vt.IntArray([int(v) for q in quads for v in q])
    rng = np.random.default_rng(seed)
    layer = Sdf.Layer.CreateNew(path)
    T = Sdf.ValueTypeNames
    world = Sdf.CreatePrimInLayer(layer, "/World")
    world.specifier = Sdf.SpecifierDef
    world.typeName = "Xform"
    layer.defaultPrim = "World"
    layer.startTimeCode, layer.endTimeCode = 1, frames
    side = int(np.ceil(np.sqrt(count)))
    for i in range(count):
        prim = Sdf.CreatePrimInLayer(layer, f"/World/Prop_{i}")
        prim.specifier = Sdf.SpecifierDef
        prim.typeName = "Mesh"
        Sdf.AttributeSpec(prim, "subdivisionScheme", T.Token, Sdf.VariabilityUniform).default = "catmullClark"
        Sdf.AttributeSpec(prim, "faceVertexCounts", T.IntArray).default = counts
        Sdf.AttributeSpec(prim, "faceVertexIndices", T.IntArray).default = indices
        spec = Sdf.AttributeSpec(prim, "points", T.Point3fArray)
        base = pts + np.array([2.0 * (i % side), 2.0 * (i // side), 0.0])
        spec.default = Vt.Vec3fArray.FromNumpy(base.astype(np.float32))
        for f in range(1, frames + 1):
            moved = base + 0.05 * f + 0.02 * rng.standard_normal(base.shape)
            layer.SetTimeSample(spec.path, float(f), Vt.Vec3fArray.FromNumpy(moved.astype(np.float32)))
    layer.Save()
    return {"props": count, "faces": len(quads), "vertices": len(pts), "frames": frames}


def worker(args) -> dict:
    quiet_warp()
    from warp_subdiv.usd.refine import refine_usd

    with tempfile.TemporaryDirectory(prefix="wsbatch_") as tmp:
        cpu = time.process_time()
        res = refine_usd(args.scene, os.path.join(tmp, "out.usdc"), args.level, device=args.device,
                         normals=args.normals, batch=args.batch == "on")
        return {"seconds": res.seconds, "cpu_seconds": time.process_time() - cpu, "phases": res.phases}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cubes", type=int, default=1000, help="8-vertex cubes in the first scene (0: none)")
    p.add_argument("--props", type=int, default=200, help="96-quad props in the second scene (0: none)")
    p.add_argument("--frames", type=int, default=24, help="time samples per prop")
    p.add_argument("--levels", type=int, default=2, help="refinement levels")
    p.add_argument("--normals", action="store_true", help="write limit normals too")
    p.add_argument("--device", default="cpu", help="Warp device (default cpu)")
    p.add_argument("--reps", type=int, default=1, help="bakes per mode (best)")
    p.add_argument("--quick", action="store_true", help="50 cubes and 10 props x 3 frames (CI smoke test)")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per bake subprocess")
    p.add_argument("--json", help="also write all measurements to this JSON file")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--scene", help=argparse.SUPPRESS)
    p.add_argument("--level", type=int, help=argparse.SUPPRESS)
    p.add_argument("--batch", choices=["on", "off"], help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        print(MARK + json.dumps(worker(args)), flush=True)
        return 0
    if args.quick:
        args.cubes, args.props, args.frames = min(args.cubes, 50), min(args.props, 10), min(args.frames, 3)
    rows = []
    env = {"PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with tempfile.TemporaryDirectory(prefix="wsbatch_scenes_") as tmp:
        for name, count, cuts in (("cubes", args.cubes, 1), ("props", args.props, 4)):
            if count <= 0:
                continue
            scene = os.path.join(tmp, f"{name}.usdc")
            info = make_scene(scene, count, cuts, args.frames)
            best = {}
            for _ in range(args.reps):
                for mode in ("off", "on"):
                    cmd = [sys.executable, os.path.abspath(__file__), "--worker", "--scene", scene, "--level",
                           str(args.levels), "--batch", mode, "--device", args.device] + \
                        (["--normals"] if args.normals else [])
                    res, why = run_child(cmd, args.timeout, None, MARK, env)
                    if res is None:
                        print(f"{name} batch={mode}: {why}", file=sys.stderr)
                        return 1
                    if mode not in best or res["seconds"] < best[mode]["seconds"]:
                        best[mode] = res
            rows.append(dict(scene=name, levels=args.levels, normals=args.normals, device=args.device, **info,
                             off=best["off"], on=best["on"]))
    print("| scene | props x frames | level | bake off (s) | bake on (s) | ratio | CPU off (s) | CPU on (s) | ratio | "
          "refine off (s) | refine on (s) | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        off, on = r["off"], r["on"]
        ro, rn = off["phases"].get("refine", 0.0), on["phases"].get("refine", 0.0)
        label = f"{r['scene']} ({r['faces']} quads)" + (" + normals" if r["normals"] else "")
        print(f"| {label} | {r['props']} x {r['frames']} | {r['levels']} | {off['seconds']:.2f} | "
              f"{on['seconds']:.2f} | {off['seconds'] / on['seconds']:.2f}x | {off['cpu_seconds']:.2f} | "
              f"{on['cpu_seconds']:.2f} | {off['cpu_seconds'] / on['cpu_seconds']:.2f}x | {ro:.3f} | {rn:.3f} | "
              f"{ro / rn if rn else float('nan'):.2f}x |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
