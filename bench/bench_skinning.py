"""A skinned bake against UsdSkel's own bake plus our refine of its points, in one run.

    python bench/bench_skinning.py [--rings 64] [--around 32] [--frames 100] [--levels 2] [--reps 3] [--json OUT]
                                   [--quick]

Generates a character (``make_scene``): a Catmull-Clark tube of ``--rings`` x ``--around`` quads (a leg, open at
both ends) bound to a three-joint chain (hip, knee, ankle) with four influences per point (elementSize 4), two
blend shapes, and a SkelAnimation of ``--frames`` frames (every joint and blend-shape weight sampled each frame),
in a ``.usdc``. Then, best of ``--reps``:

* **bake**: ``warp_subdiv.usd.refine_usd(scene, out.usdc, levels)`` (``skinning="bake"``, the default): at every
  frame, UsdSkel's deformed control points, refined and written, end to end;
* **floor**: what a pipeline without the skinning bake does: ``UsdSkel.BakeSkinning`` of the same interval on a
  stage of the scene (into its session layer, which is exported flattened: the baked points as time samples),
  then ``refine_usd(prebaked, out.usdc, levels, skinning="none")`` of those points (the same refinement and
  writing); the two timed together, and each on its own;
* **UsdSkel alone**: the BakeSkinning step of the floor, and the skinning the bake itself runs (its
  ``skinned_points`` over every frame, UsdSkel's blend shapes and ``ComputeSkinnedPoints``), to show where the
  time goes.

The bake's ratio to the floor is the figure of merit (at most 1: no cost for skinning in the bake). Prints a
Markdown table; ``--json`` writes every figure.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def make_scene(path: str, rings: int, around: int, frames: int) -> str:
    """The character (see the module docstring), written to ``path``."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    UsdSkel.Root.Define(stage, "/Character")
    skel = UsdSkel.Skeleton.Define(stage, "/Character/Skel")
    joints = ["hip", "hip/knee", "hip/knee/ankle"]
    skel.CreateJointsAttr(joints)
    heights = [0.0, 1.0, 2.0]
    bind = [Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, h)) for h in heights]
    rest = [Gf.Matrix4d(1)] + [Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 1))] * 2
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray(bind))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray(rest))
    anim = UsdSkel.Animation.Define(stage, "/Character/Skel/Anim")
    anim.CreateJointsAttr(joints)
    anim.CreateBlendShapesAttr(["bulge", "twist"])
    tr, ro, wt = anim.CreateTranslationsAttr(), anim.CreateRotationsAttr(), anim.CreateBlendShapeWeightsAttr()
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * 3))
    for f in range(1, frames + 1):
        u = (f - 1) / max(1, frames - 1)
        a = [0.3 * math.sin(2 * math.pi * u), math.radians(80) * u, math.radians(40) * math.sin(math.pi * u)]
        tr.Set(Vt.Vec3fArray([Gf.Vec3f(0.02 * f, 0, 0), Gf.Vec3f(0, 0, 1), Gf.Vec3f(0, 0, 1)]), f)
        ro.Set(Vt.QuatfArray([Gf.Quatf(math.cos(a[0] / 2), Gf.Vec3f(0, 0, math.sin(a[0] / 2))),
                              Gf.Quatf(math.cos(a[1] / 2), Gf.Vec3f(math.sin(a[1] / 2), 0, 0)),
                              Gf.Quatf(math.cos(a[2] / 2), Gf.Vec3f(0, math.sin(a[2] / 2), 0))]), f)
        wt.Set(Vt.FloatArray([u, 1.0 - u]), f)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])

    ang = np.arange(around) * 2 * np.pi / around
    z = np.linspace(0.0, 3.0, rings + 1)
    pts = np.stack([np.tile(0.25 * np.cos(ang), rings + 1), np.tile(0.25 * np.sin(ang), rings + 1),
                    np.repeat(z, around)], axis=1)
    r, k = np.meshgrid(np.arange(rings), np.arange(around), indexing="ij")
    a, b = r * around + k, r * around + (k + 1) % around
    quads = np.stack([a, b, b + around, a + around], axis=-1).reshape(-1, 4)
    mesh = UsdGeom.Mesh.Define(stage, "/Character/Leg")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.reshape(-1).astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr("catmullClark")
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    h = pts[:, 2]
    w = np.stack([np.clip(1.5 - h, 0, 1), np.clip(1 - np.abs(h - 1.5), 0, 1), np.clip(h - 1.5, 0, 1),
                  np.zeros_like(h)], axis=1) + 1e-3
    w /= w.sum(axis=1, keepdims=True)
    idx = np.tile(np.array([0, 1, 2, 0], dtype=np.int32), (len(pts), 1))
    binding.CreateJointIndicesPrimvar(False, 4).Set(Vt.IntArray.FromNumpy(idx.reshape(-1)))
    binding.CreateJointWeightsPrimvar(False, 4).Set(Vt.FloatArray.FromNumpy(w.reshape(-1).astype(np.float32)))
    shapes = []
    for name, sel, offset in (("bulge", np.abs(h - 1.0) < 0.3, lambda p: p * [0.3, 0.3, 0.0]),
                              ("twist", h > 2.0, lambda p: np.stack([-p[:, 1], p[:, 0], 0 * p[:, 2]], 1) * 0.2)):
        shape = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(name))
        ids = np.flatnonzero(sel)
        shape.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(ids.astype(np.int32)))
        shape.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(offset(pts[ids]).astype(np.float32)))
        shapes.append(shape.GetPath())
    binding.CreateBlendShapesAttr(["bulge", "twist"])
    binding.CreateBlendShapeTargetsRel().SetTargets(shapes)
    layer.Export(path)
    return path


def usdskel_bake(src: str, prebaked: str, frames: int) -> float:
    """UsdSkel.BakeSkinning of frames 1..frames into a stage's session layer, exported flattened; seconds of the
    bake (the export is not counted)."""
    from pxr import Gf, Usd, UsdSkel

    stage = Usd.Stage.Open(src)
    stage.SetEditTarget(stage.GetSessionLayer())
    t0 = time.perf_counter()
    ok = UsdSkel.BakeSkinning(UsdSkel.Root(stage.GetPrimAtPath("/Character")), Gf.Interval(1, frames))
    seconds = time.perf_counter() - t0
    assert ok
    stage.Export(prebaked)
    return seconds


def skinning_alone(src: str) -> float:
    """The bake's own UsdSkel calls: the skinned control points of every frame (no refinement)."""
    from warp_subdiv.usd.planning import plan
    from warp_subdiv.usd.skinning import skinned_points

    p = plan(src, 0, device="cpu")
    sp = p.prims[0]
    t0 = time.perf_counter()
    for t in sp.point_times:
        skinned_points(sp, t)
    return time.perf_counter() - t0


def same_points(a: str, b: str, frames: int) -> float:
    """The largest difference between the refined points of two outputs over every frame (the bake and the floor
    must write the same surface)."""
    from pxr import Usd

    sa, sb = Usd.Stage.Open(a), Usd.Stage.Open(b)  # held while their prims are used
    pa = sa.GetPrimAtPath("/Character/Leg").GetAttribute("points")
    pb = sb.GetPrimAtPath("/Character/Leg").GetAttribute("points")
    assert pa.GetTimeSamples() == pb.GetTimeSamples() == [float(f) for f in range(1, frames + 1)]
    return max(float(np.abs(np.asarray(pa.Get(t)) - np.asarray(pb.Get(t))).max()) for t in pa.GetTimeSamples())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rings", type=int, default=64)
    ap.add_argument("--around", type=int, default=32)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true", help="a tiny configuration (the smoke test's)")
    args = ap.parse_args(argv)
    if args.quick:
        args.rings, args.around, args.frames, args.levels, args.reps = 8, 8, 5, 1, 1
    from benchutil import quiet_warp

    quiet_warp()
    from warp_subdiv.usd import refine_usd

    folder = tempfile.mkdtemp(prefix="bench_skinning_")
    src = make_scene(os.path.join(folder, "character.usdc"), args.rings, args.around, args.frames)
    prebaked = os.path.join(folder, "prebaked.usdc")
    refine_usd(src, os.path.join(folder, "warm.usdc"), 1, device="cpu")  # kernels loaded, caches warm
    rows = {"bake": [], "floor": [], "usdskel_bake": [], "refine_prebaked": [], "bake_skinning_alone": []}
    for _ in range(args.reps):
        t0 = time.perf_counter()
        result = refine_usd(src, os.path.join(folder, "out.usdc"), args.levels, device="cpu")
        rows["bake"].append(time.perf_counter() - t0)
        skel = usdskel_bake(src, prebaked, args.frames)
        t0 = time.perf_counter()
        refine_usd(prebaked, os.path.join(folder, "floor.usdc"), args.levels, device="cpu", skinning="none")
        refine = time.perf_counter() - t0
        rows["usdskel_bake"].append(skel)
        rows["refine_prebaked"].append(refine)
        rows["floor"].append(skel + refine)
        rows["bake_skinning_alone"].append(skinning_alone(src))
    check = same_points(os.path.join(folder, "out.usdc"), os.path.join(folder, "floor.usdc"), args.frames)
    best = {k: min(v) for k, v in rows.items()}
    ratios = [b / f for b, f in zip(rows["bake"], rows["floor"])]
    report = result.reports[0]
    print(f"character: {report.faces_in} control faces -> {report.faces_out} at level {args.levels}, "
          f"{report.samples} frames, 3 joints x 4 influences, 2 blend shapes; best of {args.reps}")
    print()
    print("| step | seconds (best) |")
    print("|---|---|")
    print(f"| bake: `refine_usd(..., skinning=\"bake\")` | {best['bake']:.2f} |")
    print(f"| floor: UsdSkel.BakeSkinning + `refine_usd(prebaked, skinning=\"none\")` | {best['floor']:.2f} |")
    print(f"| &nbsp; UsdSkel.BakeSkinning of {args.frames} frames | {best['usdskel_bake']:.2f} |")
    print(f"| &nbsp; refine_usd of the prebaked points | {best['refine_prebaked']:.2f} |")
    print(f"| the bake's own UsdSkel skinning of {args.frames} frames | {best['bake_skinning_alone']:.2f} |")
    print()
    print(f"bake / floor: {best['bake'] / best['floor']:.2f} best against best, {float(np.median(ratios)):.2f} "
          f"median of the reps; largest difference between their points over the frames: {check:.2g}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "seconds": rows, "ratios": ratios}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
