"""Distributed bake: an animated scene refined in one process and on local Dask clusters of 1 and 2 workers.

    python bench/bench_distributed.py                     # 50k control faces, 200 frames, level 2, 1 and 2 workers
    python bench/bench_distributed.py --faces 5000 --frames 40 --workers 1,2 --json out/bench_dist.json
    python bench/bench_distributed.py --commit HEAD       # a commit's library (git archive), not the work tree

The scene (a grid of quads waving over ``--frames`` time samples, written once as .usdc into ``--work``) is
baked by ``warp-subdiv refine`` in one process, then by ``warp_subdiv.usd.distributed.bake`` (what ``refine
--workers N`` runs) with each worker count, each in a fresh process, outputs removed in between. The table
gives wall times (the bake with its cluster's start, and without it), the ratio against one worker from the
same run, and where the time went (the bake's own timings: cluster start, topology task, unit tasks,
stitching, output). A projection for 10 and 100 workers follows from the measured costs (see ``project``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from benchutil import export_commit  # noqa: E402 (the scripts run as files; their folder holds the helpers)

MARK = "BENCH_RESULT "


def make_scene(path: str, faces: int, frames: int) -> None:
    import numpy as np
    from pxr import Usd, UsdGeom, Vt

    n = max(1, int(round(math.sqrt(faces))))
    xs, ys = np.meshgrid(np.arange(n + 1, dtype=np.float64), np.arange(n + 1, dtype=np.float64))
    base = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    i = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    quads = np.stack([i, i + 1, i + n + 2, i + n + 1], axis=1).ravel()
    tmp = path + ".tmp.usdc"
    stage = Usd.Stage.CreateNew(tmp)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    stage.SetTimeCodesPerSecond(24)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/World/Wave")
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(n * n, 4, np.int32)))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(quads.astype(np.int32)))
    mesh.GetSubdivisionSchemeAttr().Set("catmullClark")
    attr = mesh.GetPointsAttr()
    for t in range(1, frames + 1):
        pts = base.copy()
        pts[:, 2] = 2.0 * np.sin(0.15 * base[:, 0] + 0.2 * t) * np.cos(0.1 * base[:, 1] - 0.1 * t)
        attr.Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)), Usd.TimeCode(t))
    stage.GetRootLayer().Save()
    del stage
    os.replace(tmp, path)


def child(args) -> None:
    """In a fresh process: one bake with ``args.workers`` workers; prints its timings."""
    sys.path.insert(0, args.lib_root)
    from warp_subdiv.usd.distributed import bake

    import warp_subdiv

    assert os.path.abspath(warp_subdiv.__file__).startswith(os.path.abspath(args.lib_root)), warp_subdiv.__file__
    t = time.perf_counter()
    res = bake(args.scene, args.output, args.levels, workers=args.workers, chunk_frames=args.chunk_frames)
    wall = time.perf_counter() - t
    timings = dict(res.timings)
    timings["wall_s"] = wall
    print(MARK + json.dumps(timings), flush=True)


def _dir_bytes(path: str) -> int:
    total = 0
    for base, _, files in os.walk(path):
        total += sum(os.path.getsize(os.path.join(base, f)) for f in files)
    return total


def project(runs: dict, frames: int, workers_list=(10, 100), bandwidth=1e9, pickle_bytes=0) -> list:
    """Projected bake time on W workers from two measured runs (different chunk sizes):

    * a unit task costs ``o + f * n`` for n frames: o and f solved from the mean task wall time of the two
      runs (their chunks hold different numbers of frames);
    * stitching costs ``s0 + s1 * C`` for C chunks, solved the same way;
    * W workers get C = min(frames / 4, 3 W) chunks (warp_subdiv.usd.distributed.plan_units), so the tasks take
      ceil(C / W) rounds of ``o + f * frames / C``;
    * the topology task and the output write as measured; each worker fetches the mesh's tables
      (``pickle_bytes``) once, at ``bandwidth`` bytes/s, all fetches from one copy one after the other
      (the worst case); the cluster is already running (``--scheduler``), so no start cost.
    Storage is assumed to keep up (the chunks of a 200-frame level-2 bake are about 2 GB)."""
    (n1, r1), (n2, r2) = sorted(runs.items())[:2]

    def per_task(run):
        units = [u for u in run["units"] if u["kind"] == "frames"]
        nf = frames / max(1, len(units))
        return nf, sum(u["wall"] for u in units) / max(1, len(units)), len(units)

    a_n, a_w, a_c = per_task(r1)
    b_n, b_w, b_c = per_task(r2)
    f = (a_w - b_w) / (a_n - b_n) if a_n != b_n else 0.0
    if f <= 0:  # noise swamped the difference: all of a task's time per frame, no fixed part
        f = a_w / a_n
    o = max(0.0, a_w - f * a_n)
    s1 = (r1["stitch_s"] - r2["stitch_s"]) / (a_c - b_c) if a_c != b_c else r1["stitch_s"] / a_c
    s1 = max(0.0, s1)
    s0 = max(0.0, r1["stitch_s"] - s1 * a_c)
    topo = max(r1.get("topology_s") or [0.0])
    commit = (r1["commit_s"] + r2["commit_s"]) / 2
    out = []
    for w in workers_list:
        c = max(1, min(frames // 4, 3 * w))
        rounds = math.ceil(c / w)
        tasks = rounds * (o + f * frames / c)
        fetch = w * pickle_bytes / bandwidth
        stitch = s0 + s1 * c
        total = topo + fetch + tasks + stitch + commit
        out.append({"workers": w, "chunks": c, "topology_s": topo, "fetch_s": fetch, "tasks_s": tasks,
                    "stitch_s": stitch, "commit_s": commit, "total_s": total,
                    "model": {"task_fixed_s": o, "per_frame_s": f, "stitch_fixed_s": s0, "stitch_per_chunk_s": s1}})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=50000)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--chunk-frames", type=int, default=None)
    ap.add_argument("--work", default=os.path.join(ROOT, "out", "bench_distributed"))
    ap.add_argument("--no-single", action="store_true", help="skip the single-process bake")
    ap.add_argument("--json", default=None)
    ap.add_argument("--commit", default=None, help="measure this commit's library (git archive)")
    ap.add_argument("--lib-root", default=ROOT, help=argparse.SUPPRESS)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--scene", help=argparse.SUPPRESS)
    ap.add_argument("--output", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        args.workers = int(args.workers)
        child(args)
        return 0

    sha = None
    if args.commit:
        args.lib_root, sha = export_commit(args.commit)
    os.makedirs(args.work, exist_ok=True)
    scene = os.path.join(args.work, f"wave_{args.faces}f_{args.frames}t.usdc")
    if not os.path.exists(scene):
        t = time.perf_counter()
        make_scene(scene, args.faces, args.frames)
        print(f"wrote {scene} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    load0 = os.getloadavg()[0]
    start = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=args.lib_root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = {"commit": sha, "faces": args.faces, "frames": args.frames, "levels": args.levels, "runs": {}}
    out_dir = os.path.join(args.work, "run")
    if not args.no_single:
        shutil.rmtree(out_dir, ignore_errors=True)
        os.makedirs(out_dir)
        cmd = [sys.executable, "-m", "warp_subdiv", "refine", scene, "-o", os.path.join(out_dir, "single.usdc"),
               "--levels", str(args.levels), "--quiet", "--progress", "off"]
        t = time.perf_counter()
        subprocess.run(cmd, check=True, env=env)
        result["single_s"] = time.perf_counter() - t
        result["output_bytes"] = _dir_bytes(out_dir)
        print(f"single process: {result['single_s']:.2f} s", file=sys.stderr, flush=True)
    for w in [int(x) for x in args.workers.split(",")]:
        shutil.rmtree(out_dir, ignore_errors=True)
        os.makedirs(out_dir)
        cmd = [sys.executable, os.path.abspath(__file__), "--child", "--scene", scene, "--output",
               os.path.join(out_dir, "dist.usdc"), "--levels", str(args.levels), "--workers", str(w),
               "--lib-root", args.lib_root]
        if args.chunk_frames:
            cmd += ["--chunk-frames", str(args.chunk_frames)]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        line = [x for x in proc.stdout.splitlines() if x.startswith(MARK)]
        if proc.returncode or not line:
            print(proc.stderr[-3000:], file=sys.stderr)
            return 1
        run = json.loads(line[0][len(MARK):])
        run["output_bytes"] = _dir_bytes(out_dir)
        result["runs"][w] = run
        print(f"{w} workers: {run['wall_s']:.2f} s (cluster start {run.get('cluster_s', 0):.2f} s)", file=sys.stderr,
              flush=True)
    shutil.rmtree(out_dir, ignore_errors=True)
    load1 = os.getloadavg()[0]
    result.update(load_start=load0, load_end=load1, seconds=time.perf_counter() - start)

    # the tables a frame task is shipped, pickled (as Dask sends them)
    sys.path.insert(0, args.lib_root)
    import pickle

    import warp as wp

    wp.config.log_level = 30

    from warp_subdiv.tables.hierarchy import Hierarchy
    from warp_subdiv.options import Options
    from warp_subdiv.usd import plan

    p = plan(scene, args.levels)
    h = Hierarchy(p.prims[0].mesh, args.levels, Options(scheme="catmull-clark"), threads=1)
    result["pickle_bytes"] = len(pickle.dumps(h, protocol=5))

    runs = result["runs"]
    base = runs[min(runs)]
    print(f"Library: {'commit ' + sha[:7] if sha else 'working tree'}. "
          f"{args.faces:,}-face grid, {args.frames} frames, level {args.levels}; {result['seconds']:.0f} s; 1-minute "
          f"load average {load0:.2f} at the start, {load1:.2f} at the end.\n")
    if "single_s" in result:
        print(f"single process (`warp-subdiv refine`): {result['single_s']:.2f} s, output "
              f"{result['output_bytes'] / 2**30:.2f} GiB\n")
    print("| workers | bake s | without cluster start s | ratio vs 1 worker (with / without start) | cluster start s "
          "| topology task s | unit tasks s (count) | stitch s | output s |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for w, r in sorted(runs.items()):
        net, bnet = r["wall_s"] - r.get("cluster_s", 0), base["wall_s"] - base.get("cluster_s", 0)
        print(f"| {w} | {r['wall_s']:.2f} | {net:.2f} | {base['wall_s'] / r['wall_s']:.2f}x / {bnet / net:.2f}x | "
              f"{r.get('cluster_s', 0):.2f} | {max(r.get('topology_s') or [0]):.2f} | {r['tasks_s']:.2f} "
              f"({len(r['units'])}) | {r['stitch_s']:.2f} | {r['commit_s']:.2f} |")
    if len(runs) >= 2:
        proj = project(runs, args.frames, pickle_bytes=result["pickle_bytes"])
        result["projection"] = proj
        m = proj[0]["model"]
        print(f"\nProjection (model fitted to the runs above: a task costs {m['task_fixed_s']:.2f} s + "
              f"{1e3 * m['per_frame_s']:.0f} ms per frame, stitching {m['stitch_fixed_s']:.2f} s + "
              f"{1e3 * m['stitch_per_chunk_s']:.0f} ms per chunk; tables of {result['pickle_bytes'] / 2**20:.0f} MiB "
              "fetched by every worker at 1 GB/s one after the other; a running cluster):\n")
        print("| workers | chunks | topology s | table fetches s | unit tasks s | stitch s | output s | total s |")
        print("|---:|---:|---:|---:|---:|---:|---:|---:|")
        for q in proj:
            print(f"| {q['workers']} | {q['chunks']} | {q['topology_s']:.2f} | {q['fetch_s']:.2f} | "
                  f"{q['tasks_s']:.2f} | {q['stitch_s']:.2f} | {q['commit_s']:.2f} | {q['total_s']:.2f} |")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
