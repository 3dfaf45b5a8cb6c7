"""The face-varying channel of a real asset's meshes, piece by piece: where the bake's face-varying phase goes.

    python bench/bench_chess_channel.py PATH/TO/chess_set.usda [--levels 2] [--reps 5] [--lib EXPORTED_CHECKOUT]

One bake (no resume folder) records every mesh's face-varying call as the writer makes it (the compact order's
refiner, the UVs and their indices, the mode); then, in this warm process, for each of those meshes rep by
rep: the value mesh's tags and islands (``_ValueTags``, ``islands()``), the islands' set-up (``_Islands``),
the compact order's seam fast path giving up (``_fast_parts``), the islands' evaluation, and the vertex
evaluation for scale. Set-up pieces are this thread's CPU time (``time.thread_time``: numpy on one thread, so a
loaded machine inflates them less than wall time); evaluations are wall time (Warp may use several threads).
Each figure is the sum over the meshes, the best rep and every rep printed. Single-face refiners are built
(and cached) by the recording bake, as from a bake's second mesh on. The SHA-1 of every mesh's refined UVs and
indices (the channel's, and the compact order's as written) is printed: equal digests from two checkouts
(``--lib``: an exported older commit) mean the same bits.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def record_calls(asset: str, levels: int) -> list:
    """Bake ``asset`` once and return every face-varying call of the writer: (compact refiner, values, indices,
    mode)."""
    from warp_subdiv.usd import order
    from warp_subdiv.usd.refine import refine_usd

    calls = []
    original = order.OrderedRefiner.evaluate_face_varying

    def recording(self, values, indices, mode="corners-plus1"):
        calls.append((self, np.array(values), np.array(indices), mode))
        return original(self, values, indices, mode)

    order.OrderedRefiner.evaluate_face_varying = recording
    try:
        with tempfile.TemporaryDirectory(prefix="wschannel_") as folder:
            refine_usd(asset, os.path.join(folder, "out.usdc"), levels, device="cpu", resume=False)
    finally:
        order.OrderedRefiner.evaluate_face_varying = original
    return calls


def one_rep(calls) -> dict:
    """Seconds of each piece, summed over the meshes."""
    from warp_subdiv.tables import facevarying as fv
    from warp_subdiv.usd.order import _fast_parts

    t = dict.fromkeys(("tags and islands", "islands set-up", "seam fast path", "islands evaluation",
                       "vertex evaluation"), 0.0)
    for ordered, values, indices, mode in calls:
        r = ordered.refiner
        c0 = time.thread_time()
        tags = fv._ValueTags(r.mesh, indices, mode, r.boundary, r.scheme, fv._control_level(r))
        island = tags.islands()
        c1 = time.thread_time()
        channel = r.face_varying_channel(indices, mode)  # (built by the recording bake: its options, factory)
        islands = fv._Islands(channel, tags, island)
        c2 = time.thread_time()
        _fast_parts(r, values, indices, mode, None, rows=ordered.old_id)
        c3 = time.thread_time()
        w0 = time.perf_counter()
        islands.evaluate(channel._checked(values))
        w1 = time.perf_counter()
        r.evaluate(r.mesh.points)
        w2 = time.perf_counter()
        t["tags and islands"] += c1 - c0
        t["islands set-up"] += c2 - c1
        t["seam fast path"] += c3 - c2
        t["islands evaluation"] += w1 - w0
        t["vertex evaluation"] += w2 - w1
    return t


def digest(calls) -> str:
    """SHA-1 of every mesh's refined UVs and indices: the channel's and the compact order's."""
    h = hashlib.sha1()
    for ordered, values, indices, mode in calls:
        channel = ordered.refiner.face_varying_channel(indices, mode)
        for a in (*channel.evaluate(values), *ordered.evaluate_face_varying(values, indices, mode)):
            a = np.ascontiguousarray(a)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(a.view(np.uint8).reshape(-1))
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset")
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--lib", help="import warp_subdiv from this folder (an exported older commit)")
    args = ap.parse_args(argv)
    sys.path.insert(0, os.path.abspath(args.lib) if args.lib else os.path.dirname(HERE))
    import warp as wp

    import warp_subdiv

    wp.config.quiet = True
    print(f"warp_subdiv from {os.path.dirname(os.path.abspath(warp_subdiv.__file__))}")
    calls = record_calls(args.asset, args.levels)
    reps = [one_rep(calls) for _ in range(args.reps)]
    faces = sum(len(c[0].refiner.mesh.face_vertex_counts) for c in calls)
    print(f"{len(calls)} meshes, {faces:,} control faces, level {args.levels}")
    for name in reps[0]:
        xs = [r[name] for r in reps]
        print(f"{name:20s} best {min(xs):.3f} s   reps " + " ".join(f"{x:.3f}" for x in xs))
    print(f"refined UVs and indices: sha1 {digest(calls)}")
    print(f"load average {', '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
