"""Where `Refiner.evaluate` stands between the points-only memory-traffic floor and what a gather costs on Warp's
CPU backend, in one run (one thread).

    python bench/bench_eval_bound.py                 # icosphere (Loop), torus and cube64 (Catmull-Clark), level 5
    python bench/bench_eval_bound.py --levels 4 --reps 5

Per mesh and level it reports:

* ``evaluate``: the best of ``--reps`` calls of ``Refiner.evaluate`` (numpy float32 in and out, one thread);
* ``floor``: the points-only traffic (each level's parent read once, each level written once, 12 bytes a point)
  over the copy bandwidth measured in the same run (``np.copyto`` of 256 MiB, best of 3), as bench_peers.py;
* ``gathers``: the vec3 reads the smooth rules make per step as the table-free kernels read them
  (Catmull-Clark quads: 4 per face point, 4 per edge point, 1 + 2n per vertex point of valence n, i.e.
  4F + 8E + V; Loop: 4 per edge point, 1 + n per vertex point, i.e. 6E + V), summed over the steps;
* ``probe seq`` / ``probe rand``: a Warp kernel doing that many vec3 gathers per step (k per output row, k the
  step's mean) from a level-sized source, with indices that walk the source in order (the best locality any
  vertex order could give) or at random (none), plus one vec3 write per row.

``evaluate / probe seq`` is what a better vertex order could at most win with these kernels; ``probe seq /
floor`` is the cost of the rules' gathers themselves on this backend even in perfect order.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchutil import ROOT, quiet_warp

MESHES = [("icosphere_5120tri", "loop"), ("torus_100x50_5000quad", "catmull-clark"), ("cube64_noisy", "catmull-clark")]
MESH_DIR = "/work/shared/meshes/bench"


def best(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def bandwidth() -> float:
    import numpy as np

    a = np.ones(64 * 2 ** 20, np.float32)
    b = np.empty_like(a)
    return 2 * a.nbytes / best(lambda: np.copyto(b, a), 3)


def step_counts(mesh, levels: int, scheme: str) -> list[tuple[int, int, int]]:
    """(source vertices, output rows, vec3 gathers) of each step, from the level counts' closed forms (a closed
    control mesh: V' = V + F + E, E' = 2E + corners, F' = corners for Catmull-Clark; V' = V + E, E' = 2E + 3F,
    F' = 4F for Loop)."""
    import numpy as np

    V, E, F = mesh.num_vertices, mesh.num_edges, len(mesh.face_vertex_counts)
    corners = int(np.sum(mesh.face_vertex_counts))
    out = []
    for _ in range(levels):
        source = V
        if scheme == "loop":
            rows, gathers = V + E, 6 * E + V
            V, E, F = rows, 2 * E + 3 * F, 4 * F
        else:
            rows, gathers = V + F + E, 4 * F + 8 * E + V
            V, E, F = rows, 2 * E + corners, corners
            corners = 4 * F
        out.append((source, rows, gathers))
    return out


def make_probe(wp):
    @wp.kernel
    def gather_k(idx: wp.array(dtype=wp.int32), src: wp.array(dtype=wp.vec3), dst: wp.array(dtype=wp.vec3), k: int):
        i = wp.tid()
        acc = wp.vec3()
        for j in range(k):
            acc = acc + src[idx[i * k + j]]
        dst[i] = acc

    return gather_k


def probe(wp, kernel, steps, pattern: str, reps: int) -> float:
    import numpy as np

    rng = np.random.default_rng(7)
    total = 0.0
    for V, rows, gathers in steps:
        k = max(1, round(gathers / rows))
        if pattern == "seq":  # row i reads k neighbours around its place in the source, walking it in order
            base = (np.arange(rows, dtype=np.int64) * V // rows)[:, None] + np.arange(k)[None, :]
            idx = np.minimum(base, V - 1).astype(np.int32).ravel()
        else:
            idx = rng.integers(0, V, rows * k, dtype=np.int32)
        src = wp.array(rng.random((V, 3), dtype=np.float32), dtype=wp.vec3, device="cpu")
        dst = wp.empty(rows, dtype=wp.vec3, device="cpu")
        ia = wp.array(idx, dtype=wp.int32, device="cpu")
        total += best(lambda: wp.launch(kernel, rows, [ia, src, dst, k], device="cpu"), reps)
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--levels", type=int, default=5)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--meshes", default=",".join(m for m, _ in MESHES))
    args = parser.parse_args()
    sys.path.insert(0, ROOT)
    wp = quiet_warp()
    import numpy as np
    import warp_subdiv as ws
    from warp_subdiv.io.obj import read_obj

    kernel = make_probe(wp)
    bw = bandwidth()
    print(f"copy bandwidth {bw / 1e9:.1f} GB/s, load average {os.getloadavg()[0]:.2f}")
    print("| mesh | scheme | level | output verts | evaluate | floor | gathers | probe seq | probe rand | "
          "evaluate / floor | probe seq / floor | evaluate / probe seq |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    schemes = dict(MESHES)
    for name in args.meshes.split(","):
        mesh = read_obj(os.path.join(MESH_DIR, name + ".obj")).mesh
        refiner = ws.Refiner(mesh, args.levels, scheme=schemes.get(name, "catmull-clark"), device="cpu", threads=1)
        points = np.asarray(mesh.points, np.float32)
        t_eval = best(lambda: refiner.evaluate(points), args.reps)
        steps = step_counts(mesh, args.levels, refiner.options.scheme.value)
        counts = [mesh.num_vertices] + [rows for _, rows, _ in steps]
        assert counts[-1] == len(refiner.evaluate(points)), "a closed mesh's level counts"
        floor = sum(12 * (a + b) for a, b in zip(counts[:-1], counts[1:])) / bw
        seq = probe(wp, kernel, steps, "seq", args.reps)
        rand = probe(wp, kernel, steps, "rand", args.reps)
        gathers = sum(g for _, _, g in steps)
        print(f"| {name} | {refiner.options.scheme.value} | {args.levels} | {counts[-1]:,} | {t_eval * 1e3:.1f} ms | "
              f"{floor * 1e3:.1f} ms | {gathers / 1e6:.1f}M | {seq * 1e3:.1f} ms | {rand * 1e3:.1f} ms | "
              f"{t_eval / floor:.1f}x | {seq / floor:.1f}x | {t_eval / seq:.2f}x |", flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
