"""Limit evaluation speed: warp_subdiv.LimitSurface against OpenSubdiv's Bfr, in the same run.

    python bench/bench_limit.py [--points N] [--reps R] [--seed S] [--quick] [--json OUT]

For each mesh (``bench/meshes/cube64_noisy.obj``: Catmull-Clark, 24,576 quads; ``icosphere5_noisy.obj``: Loop,
20,480 triangles), ``rules="opensubdiv"``:

* build: ``LimitSurface(mesh)`` (patch tree, local refinement to the default depth 8) against Bfr's set-up
  (``Far::TopologyRefiner`` + ``Bfr::RefinerSurfaceFactory``);
* evaluation of N random (face, u, v) in random order (points, first derivatives, normals), on Warp's CPU
  device (one thread), against ``peers/osd/bfr_peer.cpp``'s two ways of using Bfr (one thread, float64, its
  factory cache on): "grouped" sorts the points by face and makes one ``Bfr::Surface`` per face
  (``InitVertexSurface`` + ``PreparePatchPoints``, then ``Evaluate`` per point) and "per point" makes the
  Surface for every point in the given order.

Times are the best of R repetitions, wall clock and CPU time of the process (``time.process_time`` here,
``std::clock`` in the peer): on a shared machine the CPU time is the fair figure. Repetitions of the two
libraries alternate, so both see the same load. The maximum difference of the two results is printed as a
sanity check (the surfaces agree to 1e-15 where Bfr is exact; Bfr approximates near extraordinary vertices).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

from benchutil import quiet_warp  # noqa: E402

MESHES = [("cube64_noisy.obj", "catmull-clark"), ("icosphere5_noisy.obj", "loop")]


def queries(surface, n, rng):
    """n random (face, u, v) over the whole parameter domain of every face."""
    f = rng.integers(0, surface.num_faces, n)
    u, v = rng.random(n), rng.random(n)
    if surface.tree.triangles:
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    return f, u, v


def run(points: int, reps: int, seed: int) -> list:
    quiet_warp()
    import warp_subdiv as ws
    from peers import osd_peer
    from warp_subdiv.io.obj import read_obj

    have_bfr = osd_peer.bfr_available()
    rows = []
    for name, scheme in MESHES:
        mesh = read_obj(os.path.join(HERE, "meshes", name)).mesh
        t0 = time.perf_counter()
        surface = ws.LimitSurface(mesh, scheme=scheme, rules="opensubdiv", device="cpu")
        build = time.perf_counter() - t0
        rng = np.random.default_rng(seed)
        f, u, v = queries(surface, points, rng)
        surface.evaluate(f[:16], u[:16], v[:16])  # compile / load the kernel outside the timings
        ours_wall, ours_cpu, bfr = [], [], []
        rec = osd_peer.mesh_request(mesh, 0, scheme="catmark" if scheme == "catmull-clark" else "loop")
        for _ in range(reps):
            w, c = time.perf_counter(), time.process_time()
            ev = surface.evaluate(f, u, v)
            ours_cpu.append(time.process_time() - c)
            ours_wall.append(time.perf_counter() - w)
            if have_bfr:
                bfr.append(osd_peer.bfr_bench(rec, f, np.c_[u, v], reps=1))
        row = {"mesh": name, "scheme": scheme, "faces": int(len(mesh.face_vertex_counts)), "points": points,
               "build_s": build, "patches": int(surface.tree.num_patches),
               "ours_wall_s": min(ours_wall), "ours_cpu_s": min(ours_cpu)}
        if bfr:
            row.update({
                "bfr_setup_s": min(b["setup_s"] for b in bfr),
                "bfr_grouped_wall_s": min(b["grouped"]["seconds"] for b in bfr),
                "bfr_grouped_cpu_s": min(b["grouped"]["cpu_seconds"] for b in bfr),
                "bfr_per_point_wall_s": min(b["per_point"]["seconds"] for b in bfr),
                "bfr_per_point_cpu_s": min(b["per_point"]["cpu_seconds"] for b in bfr),
            })
            m = min(points, 20000)
            check = osd_peer.bfr_evaluate(rec, f[:m], np.c_[u[:m], v[:m]])
            scale = np.abs(mesh.points).max()
            row["max_diff_vs_bfr"] = float(np.abs(ev.points[:m] - check["points"]).max() / scale)
            row["median_diff_vs_bfr"] = float(np.median(np.abs(ev.points[:m] - check["points"]).max(axis=1)) / scale)
        rows.append(row)
    return rows


def table(rows) -> str:
    out = ["| mesh | build (ours / Bfr set-up) | ours: wall, CPU | Bfr grouped: wall, CPU | Bfr per point: wall, CPU "
           "| ours / Bfr best (CPU) |",
           "|---|---|---|---|---|---|"]
    for r in rows:
        n = r["points"]

        def rate(seconds):
            return f"{n / seconds / 1e6:.2f} M/s"

        if "bfr_grouped_cpu_s" in r:
            best = min(r["bfr_grouped_cpu_s"], r["bfr_per_point_cpu_s"])
            out.append(f"| {r['mesh']} ({r['faces']:,} faces, {n:,} points) | {r['build_s']:.2f} s / "
                       f"{r['bfr_setup_s']:.3f} s | {rate(r['ours_wall_s'])}, {rate(r['ours_cpu_s'])} | "
                       f"{rate(r['bfr_grouped_wall_s'])}, {rate(r['bfr_grouped_cpu_s'])} | "
                       f"{rate(r['bfr_per_point_wall_s'])}, {rate(r['bfr_per_point_cpu_s'])} | "
                       f"{best / r['ours_cpu_s']:.2f}x |")
        else:
            out.append(f"| {r['mesh']} | {r['build_s']:.2f} s / - | {rate(r['ours_wall_s'])}, {rate(r['ours_cpu_s'])}"
                       " | - | - | - |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--points", type=int, default=1_000_000)
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="100,000 points, one repetition")
    p.add_argument("--json", default=None, help="also write the rows as JSON")
    args = p.parse_args(argv)
    if args.quick:
        args.points, args.reps = 100_000, 1
    rows = run(args.points, args.reps, args.seed)
    print(table(rows))
    for r in rows:
        if "max_diff_vs_bfr" in r:
            print(f"{r['mesh']}: |ours - Bfr| / size: max {r['max_diff_vs_bfr']:.1e} (Bfr's end caps), median "
                  f"{r['median_diff_vs_bfr']:.1e}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
