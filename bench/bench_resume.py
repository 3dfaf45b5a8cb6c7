"""Resumable bakes: a full bake, the same bake killed at about 80% of its meshes, and the rerun that resumes it.

    python bench/bench_resume.py [--faces 300000] [--meshes 40] [--levels 2] [--kill-at 0.8] [--reps 1]
                                 [--json OUT] [--out DIR] [--quick]

The scene is bench_bake.py's (``make_scene``: ``--meshes`` distinct tori of quads with face-varying UVs, and
one torus asset referenced twice, about ``--faces`` control faces in all). Each bake runs in its own process
(``warp_subdiv.usd.refine_usd`` on the CPU, every core), rep by rep, in this order:

* **no keeping**: ``resume=False`` (the bake as it was: nothing kept next to the output);
* **full**: the default, every refined mesh kept in ``OUT.resume/`` as it is written and the folder removed
  at the end: its time against "no keeping" is the cost of being resumable;
* **killed**: the same bake killed (SIGKILL, the library's test hook ``WARP_SUBDIV_TEST_KILL_AFTER``) right
  after ``--kill-at`` of its meshes were kept; the time until the kill and the kept folder's size;
* **resumed**: the same bake again: it copies the kept meshes and refines the rest. Its output is checked
  against the full bake's (every attribute's default and time samples, arrays equal).

Times are wall-clock seconds of each process (start-up and Warp's initialisation included, the same for
every run) and, where the process finished, the bake's own ``Result.seconds``. Prints a Markdown table;
``--json`` writes every figure.
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

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from bench_bake import layer_arrays, make_scene  # noqa: E402 (the scripts run as files; their folder holds the helpers)


def child(scene: str, out: str, levels: int, resume: bool) -> None:
    """One bake in this process: prints its figures as JSON."""
    import warp as wp

    wp.config.quiet = True
    from warp_subdiv.usd import refine_usd

    result = refine_usd(scene, out, levels, device="cpu", resume=resume)
    print("RESULT " + json.dumps({"seconds": result.seconds, "reused": len(result.reused),
                                  "meshes": len(result.reports)}))


def run(scene: str, out: str, levels: int, resume: bool = True, kill_after: int | None = None) -> dict:
    """One bake in a fresh process: its wall time, return code and (when it finished) its figures."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if kill_after is not None:
        from warp_subdiv.usd.resume import KILL_ENV

        env[KILL_ENV] = str(kill_after)
    cmd = [sys.executable, os.path.abspath(__file__), "--child", scene, out, str(levels), str(int(resume))]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    wall = time.perf_counter() - t0
    entry = {"wall": wall, "returncode": res.returncode}
    for line in res.stdout.splitlines():
        if line.startswith("RESULT "):
            entry.update(json.loads(line[len("RESULT "):]))
    if res.returncode not in (0, -9):
        entry["error"] = res.stderr[-2000:]
    return entry


def folder_bytes(folder: str) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(folder) for f in files)


def same_arrays(a: str, b: str) -> bool:
    """Whether two layers hold the same prims, attributes, defaults and time samples (arrays equal)."""
    la, lb = layer_arrays(a), layer_arrays(b)
    if [(p, s, t, [x[:4] for x in at]) for p, s, t, at in la] != [(p, s, t, [x[:4] for x in at]) for p, s, t, at in lb]:
        return False

    def same(x, y):
        if isinstance(x, tuple) and isinstance(y, tuple):
            return x[0] == y[0] and np.array_equal(x[1], y[1])
        if hasattr(x, "__len__") and not isinstance(x, str):
            return np.array_equal(np.asarray(x), np.asarray(y))
        return x == y

    for (_, _, _, at), (_, _, _, bt) in zip(la, lb):
        for x, y in zip(at, bt):
            if not same(x[4], y[4]) or len(x[5]) != len(y[5]):
                return False
            if not all(tx == ty and same(vx, vy) for (tx, vx), (ty, vy) in zip(x[5], y[5])):
                return False
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=300_000)
    ap.add_argument("--meshes", type=int, default=40)
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--kill-at", type=float, default=0.8, help="fraction of the meshes kept before the kill")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="a small scene (a smoke test of the script)")
    ap.add_argument("--out", help="folder for the scene and outputs (default: a temporary one, removed)")
    ap.add_argument("--json")
    ap.add_argument("--child", nargs=4, metavar=("SCENE", "OUT", "LEVELS", "RESUME"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        scene, out, levels, resume = args.child
        child(scene, out, int(levels), bool(int(resume)))
        return 0
    if args.quick:
        args.faces, args.meshes, args.levels = 4000, 8, 1
    folder = args.out or tempfile.mkdtemp(prefix="wsresume_")
    os.makedirs(folder, exist_ok=True)
    try:
        scene = make_scene(folder, args.faces, args.meshes)
        n = scene["distinct_meshes"]  # the shared asset is refined once
        kill_after = max(1, min(n - 1, round(args.kill_at * n)))
        full_out, out = os.path.join(folder, "full.usdc"), os.path.join(folder, "resumed.usdc")
        reps = []
        for _ in range(args.reps):
            rep = {"no_keeping": run(scene["scene"], os.path.join(folder, "plain.usdc"), args.levels, resume=False),
                   "full": run(scene["scene"], full_out, args.levels)}
            for name in ("resumed.usdc", "resumed.usdc.resume"):
                path = os.path.join(folder, name)
                shutil.rmtree(path, ignore_errors=True) if os.path.isdir(path) else None
            rep["killed"] = run(scene["scene"], out, args.levels, kill_after=kill_after)
            rep["killed"]["kept_bytes"] = folder_bytes(out + ".resume")
            rep["resumed"] = run(scene["scene"], out, args.levels)
            rep["identical"] = same_arrays(full_out, out)
            reps.append(rep)
        result = {"scene": scene, "levels": args.levels, "kill_after": kill_after, "reps": reps,
                  "cores": os.cpu_count(), "load_average": os.getloadavg()}
        _report(result)
        if args.json:
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump(result, fh, indent=1)
        return 0 if all(r["identical"] and "error" not in r["resumed"] for r in reps) else 1
    finally:
        if not args.out:
            shutil.rmtree(folder, ignore_errors=True)


def _report(r: dict) -> None:
    s = r["scene"]
    print(f"\n{s['mesh_prims']} mesh prims ({s['distinct_meshes']} distinct), {s['control_faces']:,} control faces, "
          f"level {r['levels']}; killed after {r['kill_after']} meshes kept; {r['cores']} cores, load "
          f"{', '.join(f'{x:.2f}' for x in r['load_average'])}\n")
    print("| rep | no keeping (s) | full, keeping (s) | keeping's cost | killed at (s) | kept (MiB) | resumed (s) | "
          "meshes reused | killed + resumed / full | resumed / full | bakes' own s: no keeping, full, resumed | "
          "output identical |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for k, rep in enumerate(r["reps"], 1):
        plain, full, killed, resumed = rep["no_keeping"], rep["full"], rep["killed"], rep["resumed"]
        print(f"| {k} | {plain['wall']:.2f} | {full['wall']:.2f} | {full['wall'] / plain['wall']:.2f}x | "
              f"{killed['wall']:.2f} ({killed['wall'] / full['wall']:.0%}) | {killed['kept_bytes'] / 2**20:.1f} | "
              f"{resumed['wall']:.2f} | {resumed.get('reused', '?')}/{resumed.get('meshes', '?')} | "
              f"{(killed['wall'] + resumed['wall']) / full['wall']:.2f} | {resumed['wall'] / full['wall']:.2f} | "
              f"{plain.get('seconds', float('nan')):.2f}, {full.get('seconds', float('nan')):.2f}, "
              f"{resumed.get('seconds', float('nan')):.2f} | "
              f"{'yes' if rep['identical'] else 'NO'} |")


if __name__ == "__main__":
    sys.exit(main())
