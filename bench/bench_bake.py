"""The USD bake against its write floor and against Blender's round trip.

    python bench/bench_bake.py [--faces 300000] [--meshes 22] [--levels 2] [--reps 1] [--json OUT]
                               [--blender /path/to/python-with-bpy] [--out DIR]

Generates a scene (``make_scene``): ``--meshes`` distinct tori of quads with face-varying UVs (indexed, with
the u and v seams of a torus) in one ``.usdc`` layer, plus one more torus asset in its own ``.usdc`` file
referenced by two prims (the same asset twice), about ``--faces`` control faces in all (the asset counted
once). Then, in one run:

* **bake**: ``warp_subdiv.usd.refine_usd(scene, out.usdc, levels)`` end to end (read, analyse, refine,
  face-varying, write; its phase times from ``Result.phases``), best of ``--reps``, three ways: the default
  (vertex order "auto": compact for these piecewise-smooth meshes; workers on every core), OpenSubdiv's vertex
  order (``vertex_order="opensubdiv"``), and the default on one thread (``WARP_SUBDIV_THREADS=1``: no workers);
* **floor**: usd-core writing a new ``.usdc`` layer holding the same arrays a bake wrote (every attribute of
  the bake's output layer, read back into numpy first; Vt arrays made as the writer makes them,
  ``warp_subdiv.io.usd_write.from_numpy``, 15x faster than ``FromNumpy``; ``Sdf`` specs, ``Save``), best of
  ``--reps``, for the OpenSubdiv-order arrays and for the compact ones, each rep right after that rep's bakes,
  and again in a fresh process whose C allocator is the system's (the faster counts); the bake's ratio to the
  floor is the figure of merit (target: at most 1.3x), best against best and rep by rep (the median of the
  reps' ratios: a change in the machine's speed between reps touches bake and floor alike);
* **face-varying vs vertex**: the face-varying phase against the vertex refinement of the same meshes
  (target: no more);
* **Blender** (when ``--blender`` names a Python with ``bpy``, e.g. a venv made with ``pip install bpy``):
  ``bpy.ops.wm.usd_import(import_subdivision=True)``, every Subdivision Surface modifier set to the level,
  ``bpy.ops.wm.usd_export(export_subdivision="TESSELLATE")``, timed in that Python, best of ``--reps`` (target:
  the bake at least 2x faster).

The process keeps freed memory for reuse first, as the ``warp-subdiv`` command does
(``warp_subdiv.runtime.allocator.retain_freed_memory``); the floor is measured in the same process, under the same
setting. ``--system-allocator`` leaves the C allocator as it is.

Prints a Markdown table; ``--json`` writes every figure.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


# ------------------------------------------------------------------------------------------------ the scene
def torus(nu: int, nv: int, r_major: float = 1.0, r_minor: float = 0.35, seed: int = 0):
    """A torus of nu x nv quads: (points (nu*nv, 3), counts, indices, uv values ((nu+1)(nv+1), 2), uv indices).

    The UVs are a (nu+1) x (nv+1) grid: the same value at a vertex everywhere but on the two seams."""
    rng = np.random.default_rng(seed)
    u = np.arange(nu) * 2 * np.pi / nu
    v = np.arange(nv) * 2 * np.pi / nv
    uu, vv = np.meshgrid(u, v, indexing="ij")
    pts = np.stack([(r_major + r_minor * np.cos(vv)) * np.cos(uu), (r_major + r_minor * np.cos(vv)) * np.sin(uu),
                    r_minor * np.sin(vv)], axis=-1).reshape(-1, 3)
    pts += 0.002 * rng.standard_normal(pts.shape)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.reshape(-1), j.reshape(-1)
    vid = lambda a, b: (a % nu) * nv + (b % nv)  # noqa: E731
    quads = np.stack([vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)], axis=1)
    uid = lambda a, b: a * (nv + 1) + b  # noqa: E731
    uvq = np.stack([uid(i, j), uid(i + 1, j), uid(i + 1, j + 1), uid(i, j + 1)], axis=1)
    gu, gv = np.meshgrid(np.arange(nu + 1) / nu, np.arange(nv + 1) / nv, indexing="ij")
    uv = np.stack([gu.reshape(-1), gv.reshape(-1)], axis=1)
    return pts, np.full(nu * nv, 4, np.int32), quads.reshape(-1).astype(np.int32), uv, uvq.reshape(-1).astype(np.int32)


def _define_mesh(layer, path: str, mesh, offset):
    from pxr import Gf, Sdf, Vt

    T = Sdf.ValueTypeNames
    pts, counts, idx, uv, uvi = mesh
    prim = Sdf.CreatePrimInLayer(layer, path)
    prim.specifier = Sdf.SpecifierDef
    prim.typeName = "Mesh"
    Sdf.AttributeSpec(prim, "points", T.Point3fArray).default = Vt.Vec3fArray.FromNumpy(
        (pts + offset).astype(np.float32))
    Sdf.AttributeSpec(prim, "faceVertexCounts", T.IntArray).default = Vt.IntArray.FromNumpy(counts)
    Sdf.AttributeSpec(prim, "faceVertexIndices", T.IntArray).default = Vt.IntArray.FromNumpy(idx)
    Sdf.AttributeSpec(prim, "subdivisionScheme", T.Token, Sdf.VariabilityUniform).default = "catmullClark"
    lo, hi = (pts + offset).min(0), (pts + offset).max(0)
    Sdf.AttributeSpec(prim, "extent", T.Float3Array).default = Vt.Vec3fArray([Gf.Vec3f(*lo), Gf.Vec3f(*hi)])
    st = Sdf.AttributeSpec(prim, "primvars:st", T.TexCoord2fArray)
    st.default = Vt.Vec2fArray.FromNumpy(uv.astype(np.float32))
    st.SetInfo("interpolation", "faceVarying")
    Sdf.AttributeSpec(prim, "primvars:st:indices", T.IntArray).default = Vt.IntArray.FromNumpy(uvi)
    return prim


def make_scene(folder: str, faces: int = 300_000, meshes: int = 22) -> dict:
    """Write ``scene.usdc`` (and ``asset.usdc``) into ``folder``; returns a description."""
    from pxr import Sdf

    per = max(16, faces // (meshes + 1))
    nu = max(4, int(round(np.sqrt(per * 1.2))))
    nv = max(4, per // nu)
    asset = Sdf.Layer.CreateNew(os.path.join(folder, "asset.usdc"))
    root = Sdf.CreatePrimInLayer(asset, "/Asset")
    root.specifier = Sdf.SpecifierDef
    root.typeName = "Xform"
    asset.defaultPrim = "Asset"
    _define_mesh(asset, "/Asset/Body", torus(nu, nv, seed=999), np.zeros(3))
    asset.Save()
    layer = Sdf.Layer.CreateNew(os.path.join(folder, "scene.usdc"))
    layer.defaultPrim = "World"
    world = Sdf.CreatePrimInLayer(layer, "/World")
    world.specifier = Sdf.SpecifierDef
    world.typeName = "Xform"
    for k in range(meshes):
        _define_mesh(layer, f"/World/Torus_{k:02d}", torus(nu, nv, seed=k), np.array([3.0 * k, 0, 0]))
    for name in ("AssetA", "AssetB"):
        prim = Sdf.CreatePrimInLayer(layer, f"/World/{name}")
        prim.specifier = Sdf.SpecifierDef
        prim.typeName = "Xform"
        prim.referenceList.Prepend(Sdf.Reference("./asset.usdc"))
    layer.Save()
    return {"scene": os.path.join(folder, "scene.usdc"), "mesh_prims": meshes + 2, "distinct_meshes": meshes + 1,
            "faces_per_mesh": nu * nv, "control_faces": (meshes + 2) * nu * nv,
            "distinct_control_faces": (meshes + 1) * nu * nv}


# ------------------------------------------------------------------------------------------------ the floor
def layer_arrays(path: str) -> list:
    """Every attribute default and time sample of the layer at ``path``, with array values as numpy:
    [(prim path, prim specifier, type name, attribute name, type name, variability, info, default, samples)]."""
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(path)
    out = []

    def visit(spec_path):
        spec = layer.GetObjectAtPath(spec_path)
        if isinstance(spec, Sdf.PrimSpec) and spec_path != Sdf.Path.absoluteRootPath:
            attrs = []
            for attr in spec.attributes:
                default = attr.default if attr.HasDefaultValue() else None
                if hasattr(default, "__len__") and not isinstance(default, str) and hasattr(type(default), "FromNumpy"):
                    default = (type(default), np.array(default))
                samples = [(t, layer.QueryTimeSample(attr.path, t)) for t in layer.ListTimeSamplesForPath(attr.path)]
                info = {k: attr.GetInfo(k) for k in ("interpolation",) if attr.HasInfo(k)}
                attrs.append((attr.name, attr.typeName, attr.variability, info, default, samples))
            out.append((str(spec.path), spec.specifier, spec.typeName, attrs))

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out


def write_floor(arrays: list, path: str, fast: bool = True) -> float:
    """Seconds to write ``arrays`` (layer_arrays) into a new layer at ``path`` and save it; Vt arrays made with
    ``warp_subdiv.io.usd_write.from_numpy`` (``fast``) or usd-core's ``FromNumpy``."""
    from pxr import Sdf

    from warp_subdiv.io.usd_write import from_numpy

    if not fast:
        def from_numpy(cls, values):
            return cls.FromNumpy(values)

    t0 = time.perf_counter()
    layer = Sdf.Layer.CreateNew(path)
    for prim_path, specifier, type_name, attrs in arrays:
        prim = Sdf.CreatePrimInLayer(layer, prim_path)
        prim.specifier = specifier
        if type_name:
            prim.typeName = type_name
        for name, tname, variability, info, default, samples in attrs:
            spec = Sdf.AttributeSpec(prim, name, tname, variability)
            for k, v in info.items():
                spec.SetInfo(k, v)
            if isinstance(default, tuple):
                spec.default = from_numpy(*default)
            elif default is not None:
                spec.default = default
            for t, v in samples:
                layer.SetTimeSample(spec.path, t, v)
    layer.Save()
    return time.perf_counter() - t0


def floor_child(baked: str, path: str, reps: int) -> list:
    """:func:`write_floor` of the arrays of the layer ``baked``, ``reps`` times, in a fresh Python process
    whose C allocator is left as it is (this process's keeps freed memory, which changes how fast usd-core
    saves); the seconds of each, or [] where the child failed."""
    res = subprocess.run([sys.executable, os.path.abspath(__file__), "--floor-of", baked, path, str(reps)],
                         capture_output=True, text=True, timeout=3600)
    for line in res.stdout.splitlines()[::-1]:
        if line.startswith("FLOOR "):
            return json.loads(line[6:])
    return []


# ------------------------------------------------------------------------------------------------ the bake
def bake(scene: str, out: str, levels: int, vertex_order: str = "auto", threads: int | None = None) -> dict:
    """One bake (``threads``: the workers' thread count, None for every core)."""
    from warp_subdiv.runtime import threads as _threads
    from warp_subdiv.usd.refine import refine_usd

    _threads.set_default_threads(threads)
    try:
        t0 = time.perf_counter()
        result = refine_usd(scene, out, levels, device="cpu", vertex_order=vertex_order)
        wall = time.perf_counter() - t0
    finally:
        _threads.set_default_threads(None)
    phases = dict(getattr(result, "phases", {}) or {})
    faces_out = sum(r.faces_out for r in result.reports)
    return {"seconds": wall, "phases": phases, "faces_out": faces_out,
            "vertices_out": sum(r.vertices_out for r in result.reports), "meshes": len(result.reports),
            "bytes": os.path.getsize(out)}


BLENDER_SCRIPT = r"""
import json, sys, time
import bpy
scene, out, levels = sys.argv[-3], sys.argv[-2], int(sys.argv[-1])
bpy.ops.wm.read_factory_settings(use_empty=True)
t0 = time.perf_counter()
bpy.ops.wm.usd_import(filepath=scene, import_subdivision=True)
t1 = time.perf_counter()
mods = 0
for ob in bpy.data.objects:
    for m in ob.modifiers:
        if m.type == "SUBSURF":
            m.levels = levels
            m.render_levels = levels
            mods += 1
t2 = time.perf_counter()
bpy.ops.wm.usd_export(filepath=out, export_subdivision="TESSELLATE")
t3 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "export": t3 - t2, "seconds": t3 - t0, "subsurf_modifiers": mods}))
"""


def blender(python: str, scene: str, out: str, levels: int, timeout: float = 3600) -> dict:
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as fh:
        fh.write(BLENDER_SCRIPT)
        script = fh.name
    try:
        res = subprocess.run([python, script, scene, out, str(levels)], capture_output=True, text=True,
                             timeout=timeout)
    finally:
        os.unlink(script)
    for line in res.stdout.splitlines()[::-1]:
        if line.startswith("{"):
            data = json.loads(line)
            data["bytes"] = os.path.getsize(out) if os.path.exists(out) else 0
            return data
    return {"error": (res.stdout + res.stderr)[-2000:]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=300_000)
    ap.add_argument("--meshes", type=int, default=22)
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--blender", help="a Python interpreter with bpy")
    ap.add_argument("--out", help="folder for the scene and outputs (default: a temporary one, removed)")
    ap.add_argument("--json")
    ap.add_argument("--system-allocator", action="store_true",
                    help="leave the C allocator as it is (default: keep freed memory for reuse, as the "
                         "warp-subdiv command does; warp_subdiv.runtime.allocator)")
    ap.add_argument("--floor-of", nargs=3, metavar=("BAKED", "OUT", "REPS"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.floor_of:  # a floor_child: the system's allocator
        baked, path, reps = args.floor_of
        arrays = layer_arrays(baked)
        print("FLOOR " + json.dumps([write_floor(arrays, path) for _ in range(int(reps))]))
        return 0
    from warp_subdiv.runtime.allocator import retain_freed_memory

    retained = False if args.system_allocator else retain_freed_memory()
    import warp as wp

    wp.config.quiet = True
    import warp_subdiv  # noqa: F401

    folder = args.out or tempfile.mkdtemp(prefix="wsbake_")
    os.makedirs(folder, exist_ok=True)
    try:
        # warm-up: Warp loads its kernel module on the first evaluation (once per process)
        os.makedirs(os.path.join(folder, "warm"), exist_ok=True)
        warm = make_scene(os.path.join(folder, "warm"), 200, 1)
        bake(warm["scene"], os.path.join(folder, "warm", "out.usdc"), 1)
        scene = make_scene(folder, args.faces, args.meshes)
        result = {"scene": scene, "levels": args.levels, "orders": {}, "cores": os.cpu_count(),
                  "retain_freed_memory": retained}
        # the bakes take turns, rep by rep, so that a change in the machine's load touches each alike
        runs = {"default": ("auto", None), "opensubdiv": ("opensubdiv", None), "one-thread": ("auto", 1)}
        # and so do the floors: each rep saves the arrays of both orders right after its bakes (the arrays are the
        # same every rep), so each rep gives a ratio of bake to floor measured a few seconds apart
        bakes: dict = {name: [] for name in runs}
        floor_reps: dict = {"default": [], "opensubdiv": []}
        arrays_of: dict = {}
        for _ in range(args.reps):
            for name, (order, threads) in runs.items():
                bakes[name].append(bake(scene["scene"], os.path.join(folder, f"baked_{name}.usdc"), args.levels,
                                        order, threads))
            for name in floor_reps:
                if name not in arrays_of:
                    arrays_of[name] = layer_arrays(os.path.join(folder, f"baked_{name}.usdc"))
                floor_reps[name].append(write_floor(arrays_of[name], os.path.join(folder, f"floor_{name}.usdc")))
        result["rep_ratios"] = [b["seconds"] / f for b, f in zip(bakes["default"], floor_reps["opensubdiv"])]
        for name in runs:
            best = min(bakes[name], key=lambda b: b["seconds"])
            entry = {"bake": best, "bakes": [b["seconds"] for b in bakes[name]]}
            if name != "one-thread":  # (the same arrays as the default's)
                arrays = arrays_of[name]
                floor_path = os.path.join(folder, f"floor_{name}.usdc")
                floors = floor_reps[name]
                # and in a fresh process with the system's allocator (usd-core may save faster there): the
                # floor is the faster of the two
                system = floor_child(os.path.join(folder, f"baked_{name}.usdc"), floor_path, args.reps)
                entry.update(floor_seconds=min(floors + system), floors=floors, floors_system_allocator=system,
                             floor_bytes=os.path.getsize(floor_path))
                slow = [write_floor(arrays, floor_path, fast=False) for _ in range(args.reps)]
                entry.update(floor_fromnumpy_seconds=min(slow))
            result["orders"][name] = entry
        result["floor_seconds"] = result["orders"]["opensubdiv"]["floor_seconds"]
        if args.blender:
            runs = [blender(args.blender, scene["scene"], os.path.join(folder, "blender.usdc"), args.levels)
                    for _ in range(args.reps)]
            ok = [b for b in runs if "seconds" in b]
            result["blender"] = min(ok, key=lambda b: b["seconds"]) if ok else runs[-1]
            result["blender_runs"] = [b.get("seconds") for b in runs]
        result["load_average"] = os.getloadavg()
        _report(result)
        if args.json:
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump(result, fh, indent=1)
    finally:
        if not args.out:
            shutil.rmtree(folder, ignore_errors=True)
    return 0


def _report(r: dict) -> None:
    s = r["scene"]
    runs = r["orders"]
    d, o, one = runs["default"], runs["opensubdiv"], runs["one-thread"]
    floor, compact_floor = r["floor_seconds"], d["floor_seconds"]
    print(f"scene: {s['mesh_prims']} mesh prims ({s['distinct_meshes']} distinct, one asset referenced twice), "
          f"{s['control_faces']:,} control faces ({s['distinct_control_faces']:,} distinct), UVs face-varying; "
          f"level {r['levels']}: {d['bake']['faces_out']:,} faces, {d['bake']['vertices_out']:,} vertices refined")
    heads = {"default": "default (compact order, workers)", "opensubdiv": "OpenSubdiv order (workers)",
             "one-thread": "default on one thread"}
    names = list(dict.fromkeys(n for run in runs.values() for n in run["bake"]["phases"]))
    print("\n| phase (s; thread time: workers overlap the writer) | " + " | ".join(heads[k] for k in runs)
          + " |\n|---|" + "---:|" * len(runs))
    for name in names:
        print(f"| {name} | " + " | ".join(f"{run['bake']['phases'].get(name, 0):.2f}" for run in runs.values()) + " |")
    print("| **end to end (wall)** | " + " | ".join(f"**{run['bake']['seconds']:.2f}**" for run in runs.values())
          + " |")
    print("\n| measure | seconds | / floor (OpenSubdiv-order arrays) | / floor (compact arrays) |")
    print("|---|---:|---:|---:|")

    def row(label, sec):
        print(f"| {label} | {sec:.2f} | {sec / floor:.2f} | {sec / compact_floor:.2f} |")

    row("floor: usd-core saves the OpenSubdiv-order arrays", floor)
    row("floor: usd-core saves the compact-order arrays", compact_floor)
    row("(floor, OpenSubdiv-order arrays, Vt arrays by usd-core's FromNumpy)", o["floor_fromnumpy_seconds"])
    row("(floor, compact arrays, Vt arrays by usd-core's FromNumpy)", d["floor_fromnumpy_seconds"])
    row("bake, default (compact order, workers)", d["bake"]["seconds"])
    row("bake, OpenSubdiv order (workers)", o["bake"]["seconds"])
    row("bake, default on one thread", one["bake"]["seconds"])
    bl = r.get("blender")
    if bl and "seconds" in bl:
        row("Blender: USD import (subdivision) + subsurf + USD export (tessellate)", bl["seconds"])
        print(f"\nBlender runs: {', '.join(f'{x:.2f}' for x in r.get('blender_runs', []) if x)} s")
        print(f"Blender / bake (default): {bl['seconds'] / d['bake']['seconds']:.2f}x (import {bl['import']:.2f} s, "
              f"export {bl['export']:.2f} s, {bl['subsurf_modifiers']} subsurf modifiers, "
              f"{bl['bytes'] / 2**20:.1f} MiB)")
    elif bl:
        print(f"\nBlender failed: {bl.get('error', '')[-500:]}")
    ratios = sorted(r.get("rep_ratios", []))
    if ratios:
        print(f"bake (default) / floor (OpenSubdiv-order arrays), rep by rep (each rep's bakes, then its floors): "
              f"{', '.join(f'{x:.2f}' for x in r['rep_ratios'])}; median {ratios[len(ratios) // 2]:.2f}")
    for name, run in runs.items():
        ph = run["bake"]["phases"]
        vertex = ph.get("analyse", 0) + ph.get("refine", 0)
        print(f"{heads[name]}: face-varying {ph.get('face-varying', 0):.2f} s vs vertex refinement (analyse + "
              f"refine) {vertex:.2f} s; output {run['bake']['bytes'] / 2**20:.1f} MiB; runs "
              f"{', '.join(f'{x:.2f}' for x in run['bakes'])} s")
    runs_of = lambda xs: ", ".join(f"{x:.2f}" for x in xs) or "-"  # noqa: E731
    print(f"floor runs: OpenSubdiv order {runs_of(o['floors'])} s (a fresh process with the system's allocator: "
          f"{runs_of(o.get('floors_system_allocator', []))} s), compact {runs_of(d['floors'])} s "
          f"({runs_of(d.get('floors_system_allocator', []))} s)")
    print(f"load average at the end: {', '.join(f'{x:.2f}' for x in r['load_average'])} ({r['cores']} cores); "
          f"freed memory kept for reuse (warp_subdiv.runtime.allocator): "
          f"{'yes' if r.get('retain_freed_memory') else 'no'}")


if __name__ == "__main__":
    sys.exit(main())
