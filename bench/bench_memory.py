"""Memory estimate against measured peak memory: warp_subdiv.runtime.estimate's prediction beside the peak resident
memory a refinement adds, per configuration, each in a fresh process.

    python bench/bench_memory.py                 # the full table (BENCHMARKS.md, "Memory estimate")
    python bench/bench_memory.py --quick         # the configurations tests/test_memory.py checks

A worker loads its mesh, warms Warp up on a one-face mesh with the same options (so the kernel module is
loaded), resets the peak-RSS counter (Linux: ``/proc/self/clear_refs``), records its RSS, runs the call, and
reports VmHWM minus that RSS: the bytes the call added at its peak. A library call is a refiner evaluated three
times (a CPU refiner expands its quad tables before its third evaluation, and the estimate counts them).
``--retain``: each worker keeps freed memory for reuse first, as the command line does. The estimate is what
the memory guard compares with ``max_memory``: the working set of ``Refiner(...)`` for library calls
(``Estimate.working_bytes``), and everything but Warp's runtime for ``refine_usd`` (``Plan.predicted_bytes -
RUNTIME_BYTES``). Freed C-heap memory is returned to the system before the RSS is recorded (``malloc_trim``),
so that the call cannot reuse it unseen.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchutil import ROOT, proc_status, quiet_warp, run_child

MARK = "MEMORY_RESULT "

#: name -> (mesh, scheme, levels, options); "limit" computes limit points and normals, "usd" runs refine_usd.
CONFIGS = {
    "cc-closed": ("cube64_noisy", "catmull-clark", 3, {}),
    "cc-closed-L4": ("cube64_noisy", "catmull-clark", 4, {}),
    "cc-float64": ("cube64_noisy", "catmull-clark", 3, {"precision": "float64"}),
    "cc-open": ("grid:300", "catmull-clark", 2, {}),
    "cc-open-opensubdiv": ("grid:300", "catmull-clark", 2, {"rules": "opensubdiv"}),
    "cc-large-control": ("grid:700", "catmull-clark", 1, {}),
    "cc-triangles-projecting": ("trigrid:200", "catmull-clark", 2, {}),
    "cc-concave-projecting": ("lshape_concave", "catmull-clark", 8, {}),
    "cc-flatness-projecting": ("grid:300", "catmull-clark", 2, {"flatness": 0.3}),
    "cc-limit": ("cube64_noisy", "catmull-clark", 2, {"limit": True}),
    "cc-limit-deeper": ("grid:150", "catmull-clark", 2, {"flatness": 0.3, "limit": True}),
    "loop-closed": ("icosphere5_noisy", "loop", 3, {}),
    "loop-closed-L4": ("icosphere5_noisy", "loop", 4, {}),
    "loop-open": ("trigrid:300", "loop", 2, {"rules": "opensubdiv"}),
    "loop-large-control": ("trigrid:600", "loop", 1, {}),
    "loop-flatness-projecting": ("trigrid:200", "loop", 2, {"flatness": 0.3}),
    "loop-limit": ("icosphere5_noisy", "loop", 2, {"limit": True}),
    "loop-limit-deeper": ("trigrid:150", "loop", 2, {"limit": True}),
    # the bake's estimate is calibrated on OpenSubdiv's vertex order (its peak is the higher one); the compact
    # order (the default of piecewise-smooth meshes) peaks 25-30% lower, so the estimate bounds it from above
    "usd-cc-open": ("grid:300", "catmull-clark", 2, {"usd": True, "order": "opensubdiv"}),
    "usd-loop-closed": ("icosphere5_noisy", "loop", 3, {"usd": True, "order": "opensubdiv"}),
    "usd-cc-normals": ("cube64_noisy", "catmull-clark", 2, {"usd": True, "normals": True, "order": "opensubdiv"}),
    "usd-cc-uv": ("grid:300", "catmull-clark", 2, {"usd": True, "uv": True, "order": "opensubdiv"}),
    "usd-cc-uv-compact": ("grid:300", "catmull-clark", 2, {"usd": True, "uv": True, "order": "compact"}),
}
QUICK = ["cc-closed", "cc-open", "cc-concave-projecting", "cc-limit", "loop-closed", "loop-flatness-projecting",
         "loop-limit-deeper", "usd-cc-open", "usd-cc-uv", "usd-cc-uv-compact"]


def make_mesh(name: str):
    """A bench mesh, a scene OBJ, or "grid:N" / "trigrid:N": an open N x N vertex height field of quads or
    triangles (a boundary with corners, so the piecewise-smooth rules meet crease and corner sectors)."""
    import numpy as np

    import warp_subdiv as ws
    from warp_subdiv.io.obj import read_obj

    if name.startswith(("grid:", "trigrid:")):
        n = int(name.split(":")[1])
        i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
        points = np.stack([i, j, np.sin(0.3 * i) * np.cos(0.2 * j)], axis=1).astype(np.float64)
        a = (i * n + j).reshape(n, n)[:-1, :-1].ravel()
        b, c, d = a + n, a + n + 1, a + 1
        if name.startswith("grid:"):
            return ws.Mesh(points, np.full(len(a), 4), np.stack([a, b, c, d], axis=1).ravel())
        tris = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
        return ws.Mesh(points, np.full(len(tris), 3), tris.ravel())
    folder = "scenes" if name == "lshape_concave" else os.path.join("bench", "meshes")
    return read_obj(os.path.join(ROOT, folder, name + ".obj")).mesh


def _write_usd(mesh, scheme: str, path: str, uv: bool = False) -> None:
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(path)
    prim = UsdGeom.Mesh.Define(stage, "/mesh")
    prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(mesh.points.astype("float32")))
    prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(mesh.face_vertex_counts.astype("int32")))
    prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh.face_vertex_indices.astype("int32")))
    prim.CreateSubdivisionSchemeAttr("loop" if scheme == "loop" else "catmullClark")
    if uv:  # face-varying texture coordinates, one value per vertex (no seams)
        st = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                      UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(mesh.points[:, :2].astype("float32")))
        st.SetIndices(Vt.IntArray.FromNumpy(mesh.face_vertex_indices.astype("int32")))
    stage.Save()


def worker(name: str) -> dict:
    """Run one configuration in this (fresh) process; returns measured and predicted bytes."""
    import gc

    import numpy as np

    quiet_warp()
    import warp_subdiv as ws
    from warp_subdiv.runtime import estimate as est
    from warp_subdiv.runtime.allocator import release_free_memory

    mesh_name, scheme, levels, options = CONFIGS[name]
    options = dict(options)
    limit, usd = options.pop("limit", False), options.pop("usd", False)
    normals, uv = options.pop("normals", False), options.pop("uv", False)
    order = options.pop("order", "auto")
    mesh = make_mesh(mesh_name)
    tri = scheme == "loop"
    one_face = ws.Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.2], [0, 1, 0]], float), [3, 3] if tri else [4],
                       [0, 1, 2, 0, 2, 3] if tri else [0, 1, 2, 3])
    tmp = tempfile.mkdtemp(prefix="wsbench_mem_")
    if usd:
        from warp_subdiv.usd import plan, refine_usd

        src, warm = os.path.join(tmp, "in.usda"), os.path.join(tmp, "warm.usda")
        _write_usd(mesh, scheme, src, uv)
        _write_usd(one_face, scheme, warm, uv)
        refine_usd(warm, os.path.join(tmp, "warm_out.usdc"), 1, normals=normals)
        predicted = plan(src, levels, normals=normals).predicted_bytes - est.RUNTIME_BYTES
    else:
        warm = ws.refine(one_face, 1, scheme=scheme, device="cpu", **options)
        if limit:
            warm.limit_points(), warm.limit_normals()
        del warm
        control = ws.Refiner(mesh, 0, scheme=scheme, device="cpu", **options)
        predicted = est.estimate(name, mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, levels, scheme,
                                 precision=options.get("precision", "float32"), projecting=control.projects,
                                 limit=limit, limit_deeper=control.limit_reads_deeper(levels)).working_bytes
        del control
    gc.collect()
    release_free_memory()  # freed memory still mapped would be reused by the call without showing in its peak
    with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
        fh.write("5")  # resets VmHWM to the current RSS
    before = proc_status()["VmRSS"]
    if usd:
        refine_usd(src, os.path.join(tmp, "out.usdc"), levels, normals=normals, vertex_order=order)
        vertices = est.level_counts(mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, levels,
                                    scheme)[-1].vertices
    else:
        refiner = ws.Refiner(mesh, levels, scheme=scheme, device="cpu", **options)
        for _ in range(3):  # from its third evaluation a CPU refiner reads expanded quad tables (in the estimate)
            refined = None
            refined = refiner.refine()
        if limit:
            refined.limit_points(), refined.limit_normals()
        vertices = refined.num_vertices
    measured = proc_status()["VmHWM"] - before
    return {"config": name, "mesh": mesh_name, "scheme": scheme, "levels": levels, "options": CONFIGS[name][3],
            "vertices": vertices, "measured": measured, "predicted": predicted, "ratio": predicted / measured}


def run(names, python=sys.executable, retain: bool = False) -> list[dict]:
    pythonpath = ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")
    rows = []
    for name in names:
        res, why = run_child([python, os.path.abspath(__file__), "--worker", name] + (["--retain"] if retain else []),
                             600, None, MARK, {"PYTHONPATH": pythonpath})
        if res is None:
            raise RuntimeError(f"{name}: worker failed: {why}")
        rows.append(res)
    return rows


def table(rows) -> str:
    mib = 2**20
    lines = ["| configuration | mesh | scheme | levels | options | output verts | measured MiB | estimate MiB "
             "| estimate / measured | measured B/vert |", "|---|---|---|---:|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        opts = ", ".join(f"{k}={v}" for k, v in r["options"].items()) or "-"
        lines.append(f"| {r['config']} | {r['mesh']} | {r['scheme']} | {r['levels']} | {opts} | {r['vertices']:,} "
                     f"| {r['measured'] / mib:,.0f} | {r['predicted'] / mib:,.0f} | {r['ratio']:.2f} "
                     f"| {r['measured'] / r['vertices']:.0f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="only the configurations the test suite checks")
    ap.add_argument("--only", nargs="*", choices=sorted(CONFIGS), help="these configurations")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument("--retain", action="store_true",
                    help="each worker keeps freed memory for reuse, as the command line does "
                         "(warp_subdiv.runtime.allocator.retain_freed_memory)")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        if args.retain:
            from warp_subdiv.runtime.allocator import retain_freed_memory

            retain_freed_memory()
        print(MARK + json.dumps(worker(args.worker)))
        return 0
    if not os.path.exists("/proc/self/clear_refs"):
        print("needs Linux's /proc/self/clear_refs to reset the peak-RSS counter", file=sys.stderr)
        return 2
    names = args.only or (QUICK if args.quick else list(CONFIGS))
    rows = run(names, retain=args.retain)
    print(table(rows))
    worst = max(rows, key=lambda r: abs(r["ratio"] - 1))
    print(f"\nworst: {worst['config']} estimate/measured {worst['ratio']:.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
