"""Levels from a camera: what choosing them costs, with the prediction (levels 0 and 1 measured, the level
extrapolated, then checked at it and the one below) against measuring every level from 0 up until the bound is
met, and against the bake itself.

    python bench/bench_camera_levels.py              # 40 props of 96 quads from 3 to 120 units, 1920x1080, 1 px, L6
    python bench/bench_camera_levels.py --quick      # 8 props (smoke test)

One process, the least process CPU time of ``--reps``: ``plan(camera=...)`` (reads, analyses and chooses),
the same plan with the chosen levels given (``mesh_levels``: reading and analysing only; the difference is the
choice), the climb that measures every level (the same measurement, :meth:`CameraLevels.longest_edge`), and
the bake with the camera and with the chosen levels given. Checks that the prediction chose the climb's
levels. Prints a Markdown table.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from benchutil import quiet_warp  # noqa: E402
from fuzz import box_quads  # noqa: E402


def make_scene(path: str, count: int) -> None:
    """``count`` props (a 4 x 4-cut box, 96 quads, 1 unit wide) from z = -3 to z = -120 in front of a camera at
    the origin (35 mm lens on a 36 x 20.25 mm gate: 16:9)."""
    from pxr import Gf, Usd, UsdGeom, Vt

    pts, quads = box_quads(4)
    pts = np.asarray(pts, dtype=np.float64) / 4.0 - 0.5
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Cam")
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(20.25)
    for k, z in enumerate(np.geomspace(3.0, 120.0, count)):
        xform = UsdGeom.Xform.Define(stage, f"/World/P{k}")
        xform.AddTranslateOp().Set(Gf.Vec3d(0.3 * np.sin(k), 0.2 * np.cos(k), -float(z)))
        mesh = UsdGeom.Mesh.Define(stage, f"/World/P{k}/Mesh")
        mesh.CreateSubdivisionSchemeAttr("catmullClark")
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(quads)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for q in quads for i in q]))
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy((pts * (1 + 0.01 * k)).astype(np.float32)))
    stage.Save()


def climb(p, cam, cap):
    """The levels found by measuring every level from 0 up (the reference the prediction is checked against)."""
    levels = {}
    for sp, options in zip(p.prims, p.options):
        placements, _ = cam.placements(sp.prim, sp)
        level = 0
        while level < cap and cam.longest_edge(sp.prim, sp, options, level, placements) > cam.pixel_error:
            level += 1
        levels[sp.path] = level
    return levels


def best(fn, reps):
    """(the least process CPU time of ``reps`` calls, in seconds: every thread's, steadier than the wall clock on
    a shared machine; the last result)."""
    times, out = [], None
    for _ in range(reps):
        t = time.process_time()
        out = fn()
        times.append(time.process_time() - t)
    return min(times), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--props", type=int, default=40)
    parser.add_argument("--levels", type=int, default=6)
    parser.add_argument("--pixel-error", type=float, default=1.0)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.props, args.reps, args.levels = 8, 1, 4
    quiet_warp()
    from warp_subdiv.usd import plan, refine_usd
    from warp_subdiv.usd.levels import CameraLevels

    folder = tempfile.mkdtemp(prefix="bench_camera_")
    src = os.path.join(folder, "props.usda")
    make_scene(src, args.props)
    kw = dict(camera="/World/Cam", pixel_error=args.pixel_error, resolution=(1920, 1080))
    t_cam, p = best(lambda: plan(src, args.levels, device="cpu", **kw), args.reps)
    chosen = {path: level for path, (level, _) in p.level_sources.items()}
    t_given, _ = best(lambda: plan(src, args.levels, device="cpu", mesh_levels=chosen), args.reps)
    cam = CameraLevels(p.stage, "/World/Cam", args.pixel_error, resolution=(1920, 1080), device="cpu")
    t_climb, climbed = best(lambda: climb(p, cam, args.levels), args.reps)
    assert climbed == chosen, (climbed, chosen)
    t_bake, result = best(lambda: refine_usd(src, os.path.join(folder, "out.usdc"), args.levels, device="cpu",
                                             **kw), args.reps)
    t_given_bake, _ = best(lambda: refine_usd(src, os.path.join(folder, "given.usdc"), args.levels, device="cpu",
                                              mesh_levels=chosen), args.reps)
    hist = np.bincount(list(chosen.values()), minlength=args.levels + 1)
    print(f"{args.props} props of 96 quads, 1920x1080, {args.pixel_error:g} px, cap {args.levels}; levels chosen "
          f"(count per level 0..{args.levels}): {hist.tolist()}, equal to the climb's")
    print("| step | CPU seconds |")
    print("|---|---|")
    print(f"| plan with the camera (read, analyse, choose) | {t_cam:.2f} |")
    print(f"| plan with the levels given (read, analyse) | {t_given:.2f} |")
    print(f"| choosing: the difference | {t_cam - t_given:.2f} |")
    ratio = t_climb / max(t_cam - t_given, 1e-9)
    print(f"| choosing by measuring every level from 0 (the climb) | {t_climb:.2f} ({ratio:.2f}x) |")
    print(f"| the bake with the camera (refine_usd, all of it) | {t_bake:.2f} |")
    print(f"| the bake with the levels given (mesh_levels) | {t_given_bake:.2f} |")


if __name__ == "__main__":
    main()
