"""Forward evaluation vs backward pass (warp_subdiv.gradients) at levels 3-5, Catmull-Clark and Loop.

For each (mesh, level): build the refiner, time the one-off build of the transposed tables (``prepare``), then
time ``evaluate_device`` (control points on the host -> last level on the device) and the backward pass (a
last-level gradient on the device -> control-point gradient on the device) alternately, ``--repeats`` times
each, and report the minimum and median of each (CPU time of this process: steadier than wall time on a
shared machine; ``--wall`` for wall time) and their ratio. The backward pass includes normal control where the
mesh has prescribed normals (none here) and flatness where it has tables.

    .venv/bin/python bench/bench_gradients.py                 # levels 3-5, both meshes
    .venv/bin/python bench/bench_gradients.py --levels 3,4 --threads 2
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from benchutil import parse_levels, quiet_warp  # noqa: E402

MESHES = {
    "torus_5000quad": ("torus_100x50_5000quad.obj", "catmull-clark"),
    "icosphere_5120tri": ("icosphere_5120tri.obj", "loop"),
}


def measure(name: str, level: int, repeats: int, threads: int, wall: bool, device: str) -> dict:
    import numpy as np

    wp = quiet_warp()
    import warp_subdiv as ws
    from warp_subdiv import gradients
    from warp_subdiv.io.obj import read_obj

    wp.init()
    file, scheme = MESHES[name]
    mesh = read_obj(os.path.join(HERE, "meshes", file)).mesh
    clock = time.perf_counter if wall else time.process_time
    t = time.perf_counter()
    r = ws.Refiner(mesh, level, scheme=scheme, device=device, threads=threads)
    build = time.perf_counter() - t
    adj = gradients.adjoint(r)
    t = time.perf_counter()
    adj.prepare()
    prepare = time.perf_counter() - t
    grad = adj.to_device(np.random.default_rng(0).standard_normal((r.num_vertices, 3)))
    out = adj.empty(r.base_num_vertices, 3)
    points = np.asarray(mesh.points, np.float64)

    def forward():
        r.evaluate_device(points)
        wp.synchronize_device(r.device)

    def backward():
        adj.backward(grad, True, out=out)
        wp.synchronize_device(r.device)

    forward(), backward()
    fwd, bwd = [], []
    for _ in range(repeats):
        for fn, acc in ((forward, fwd), (backward, bwd)):
            t = clock()
            fn()
            acc.append(clock() - t)
    return {"mesh": name, "scheme": scheme, "level": level, "vertices": r.num_vertices, "build_s": build,
            "prepare_s": prepare, "forward_min": min(fwd), "forward_median": statistics.median(fwd),
            "backward_min": min(bwd), "backward_median": statistics.median(bwd)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--levels", default="3-5", help="e.g. 3-5 or 3,4 (default 3-5)")
    p.add_argument("--meshes", default=",".join(MESHES), help="comma-separated subset of " + ",".join(MESHES))
    p.add_argument("--repeats", type=int, default=20, help="timed calls of each (default 20)")
    p.add_argument("--threads", type=int, default=1, help="CPU threads (default 1)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--wall", action="store_true", help="wall time instead of this process's CPU time")
    args = p.parse_args(argv)
    rows = []
    print("| mesh | level | vertices | forward ms (min / median) | backward ms (min / median) | backward / forward "
          "(min, median) | transposed tables built once, s |")
    print("|---|---|---|---|---|---|---|")
    for name in args.meshes.split(","):
        for level in parse_levels(args.levels):
            m = measure(name, level, args.repeats, args.threads, args.wall, args.device)
            rows.append(m)
            print(f"| {m['mesh']} ({m['scheme']}) | {level} | {m['vertices']:,} | {1e3 * m['forward_min']:.1f} / "
                  f"{1e3 * m['forward_median']:.1f} | {1e3 * m['backward_min']:.1f} / {1e3 * m['backward_median']:.1f}"
                  f" | {m['backward_min'] / m['forward_min']:.2f}, {m['backward_median'] / m['forward_median']:.2f}"
                  f" | {m['prepare_s']:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
