"""The USD bake against its write floor and against Blender's round trip.

    python bench/bench_bake.py [--faces 300000] [--meshes 22] [--levels 2] [--reps 1] [--json OUT]
                               [--blender /path/to/python-with-bpy] [--out DIR]

Generates a scene (``make_scene``): ``--meshes`` distinct tori of quads with face-varying UVs (indexed, with
the u and v seams of a torus) in one ``.usdc`` layer, plus one more torus asset in its own ``.usdc`` file
referenced by two prims (the same asset twice), about ``--faces`` control faces in all (the asset counted
once). Then, in one run:

* **bake**: ``warp_subdiv.usd.refine_usd(scene, out.usdc, levels)`` end to end (read, analyse, refine,
  face-varying, write; its phase times from ``Result.phases``), best of ``--reps``;
* **floor**: usd-core writing a new ``.usdc`` layer holding the same arrays the bake wrote (every attribute of
  the bake's output layer, read back into numpy first: ``Vt.*Array.FromNumpy``, ``Sdf`` specs, ``Save``), best
  of ``--reps``; the bake's ratio to it is the figure of merit (target: at most 1.3x);
* **face-varying vs vertex**: the face-varying phase against the vertex refinement of the same meshes
  (target: no more);
* **Blender** (when ``--blender`` names a Python with ``bpy``, e.g. a venv made with ``pip install bpy``):
  ``bpy.ops.wm.usd_import(import_subdivision=True)``, every Subdivision Surface modifier set to the level,
  ``bpy.ops.wm.usd_export(export_subdivision="TESSELLATE")``, timed in that Python, best of ``--reps`` (target:
  the bake at least 2x faster).

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


def write_floor(arrays: list, path: str) -> float:
    """Seconds to write ``arrays`` (layer_arrays) into a new layer at ``path`` and save it."""
    from pxr import Sdf

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
                spec.default = default[0].FromNumpy(default[1])
            elif default is not None:
                spec.default = default
            for t, v in samples:
                layer.SetTimeSample(spec.path, t, v)
    layer.Save()
    return time.perf_counter() - t0


# ------------------------------------------------------------------------------------------------ the bake
def bake(scene: str, out: str, levels: int, vertex_order: str = "opensubdiv") -> dict:
    from warp_subdiv.usd import refine_usd

    t0 = time.perf_counter()
    result = refine_usd(scene, out, levels, device="cpu", vertex_order=vertex_order)
    wall = time.perf_counter() - t0
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
    args = ap.parse_args(argv)
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
        result = {"scene": scene, "levels": args.levels, "orders": {}}
        for order in ("opensubdiv", "compact"):
            out = os.path.join(folder, f"baked_{order}.usdc")
            bakes = [bake(scene["scene"], out, args.levels, order) for _ in range(args.reps)]
            best = min(bakes, key=lambda b: b["seconds"])
            arrays = layer_arrays(out)
            floor_path = os.path.join(folder, f"floor_{order}.usdc")
            floors = [write_floor(arrays, floor_path) for _ in range(args.reps)]
            result["orders"][order] = {"bake": best, "bakes": [b["seconds"] for b in bakes],
                                       "floor_seconds": min(floors), "floors": floors,
                                       "floor_bytes": os.path.getsize(floor_path)}
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
    o, c = r["orders"]["opensubdiv"], r["orders"]["compact"]
    floor = r["floor_seconds"]
    print(f"scene: {s['mesh_prims']} mesh prims ({s['distinct_meshes']} distinct, one asset referenced twice), "
          f"{s['control_faces']:,} control faces ({s['distinct_control_faces']:,} distinct), UVs face-varying; "
          f"level {r['levels']}: {c['bake']['faces_out']:,} faces, {c['bake']['vertices_out']:,} vertices refined")
    names = list(dict.fromkeys(list(o["bake"]["phases"]) + list(c["bake"]["phases"])))
    print("\n| phase (s) | bake, OpenSubdiv order | bake, compact order |\n|---|---:|---:|")
    for name in names:
        print(f"| {name} | {o['bake']['phases'].get(name, 0):.2f} | {c['bake']['phases'].get(name, 0):.2f} |")
    print(f"| **end to end** | **{o['bake']['seconds']:.2f}** | **{c['bake']['seconds']:.2f}** |")
    print("\n| measure | seconds | / floor |\n|---|---:|---:|")
    print(f"| floor: usd-core saves the OpenSubdiv-order arrays | {floor:.2f} | 1.00 |")
    print(f"| usd-core saves the compact-order arrays | {c['floor_seconds']:.2f} | {c['floor_seconds'] / floor:.2f} |")
    print(f"| bake, OpenSubdiv order | {o['bake']['seconds']:.2f} | {o['bake']['seconds'] / floor:.2f} |")
    print(f"| bake, compact order | {c['bake']['seconds']:.2f} | {c['bake']['seconds'] / floor:.2f} |")
    bl = r.get("blender")
    if bl and "seconds" in bl:
        print(f"| Blender: USD import (subdivision) + subsurf + USD export (tessellate) | {bl['seconds']:.2f} | "
              f"{bl['seconds'] / floor:.2f} |")
        print(f"\nBlender runs: {', '.join(f'{x:.2f}' for x in r.get('blender_runs', []) if x)} s")
        print(f"Blender / bake (compact): {bl['seconds'] / c['bake']['seconds']:.2f}x (import {bl['import']:.2f} s, "
              f"export {bl['export']:.2f} s, {bl['subsurf_modifiers']} subsurf modifiers, "
              f"{bl['bytes'] / 2**20:.1f} MiB)")
    elif bl:
        print(f"\nBlender failed: {bl.get('error', '')[-500:]}")
    for name, b in (("OpenSubdiv order", o["bake"]), ("compact order", c["bake"])):
        ph = b["phases"]
        vertex = ph.get("analyse", 0) + ph.get("refine", 0)
        print(f"{name}: face-varying {ph.get('face-varying', 0):.2f} s vs vertex refinement (analyse + refine) "
              f"{vertex:.2f} s; output {b['bytes'] / 2**20:.1f} MiB")
    print(f"bake runs (compact): {', '.join(f'{x:.2f}' for x in c['bakes'])} s; floor runs: "
          f"{', '.join(f'{x:.2f}' for x in o['floors'])} s")
    print(f"load average at the end: {', '.join(f'{x:.2f}' for x in r['load_average'])}")


if __name__ == "__main__":
    sys.exit(main())
