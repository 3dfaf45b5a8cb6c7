"""Where a bake's threads spend their time: every phase interval of every thread, wall and thread CPU.

    python bench/bench_chess_timeline.py PATH/TO/chess_set.usda [--levels 2] [--threads 0] [--reps 2]
                                         [--lib EXPORTED_CHECKOUT]

One warm-up bake, then ``--reps`` bakes (``--threads 0``: the default workers; 1: one thread, no workers).
Each :func:`warp_subdiv.runtime.phases.phase` interval is recorded with its thread, its wall-clock span and the
thread's CPU time in it (``time.thread_time``). Printed per bake: the wall time and the process's CPU time
(CPU / wall near 1 on a 2-core machine with workers means the threads take turns, not cores); per thread
and phase, wall and CPU summed over the intervals (inclusive of nested phases) and their ratio (a worker's
CPU / wall well below 1 while the machine has an idle core: it waits for the GIL); and the timeline of the
phase intervals longer than ``--min-ms``, to see what overlaps what (the writer's ``waiting`` against the
workers' ``analyse`` / ``refine`` / ``face-varying``, the layer's save at the end).
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import os
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (ROOT, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)


def traced_phases(events: list):
    """Make every Phases.phase interval append (thread, name, start, end, thread CPU) to ``events``; returns
    a function that undoes it."""
    from warp_subdiv.runtime import phases as _phases

    original = _phases.Phases.phase

    @contextlib.contextmanager
    def phase(self, name):
        t0, c0 = time.perf_counter(), time.thread_time()
        with original(self, name):
            yield
        events.append((threading.current_thread().name, name, t0, time.perf_counter(), time.thread_time() - c0))

    _phases.Phases.phase = phase
    return lambda: setattr(_phases.Phases, "phase", original)


def report(events: list, t0: float, min_ms: float) -> None:
    totals: dict = {}
    for thread, name, a, b, cpu in events:
        key = (thread.rsplit("_", 1)[0], name)
        wall, c, n = totals.get(key, (0.0, 0.0, 0))
        totals[key] = (wall + b - a, c + cpu, n + 1)
    print("| thread | phase | intervals | wall (incl.) | thread CPU | CPU / wall |\n|---|---|---:|---:|---:|---:|")
    for (thread, name), (wall, cpu, n) in sorted(totals.items()):
        print(f"| {thread} | {name} | {n} | {wall:.3f} | {cpu:.3f} | {cpu / max(wall, 1e-9):.2f} |")
    print("\ntimeline (s from the bake's start; intervals over", min_ms, "ms):")
    for thread, name, a, b, cpu in sorted(events, key=lambda e: e[2]):
        if name != "other" and (b - a) * 1e3 >= min_ms:
            print(f"  {a - t0:6.3f} - {b - t0:6.3f}  {thread:24s} {name:13s} CPU {cpu:.3f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset")
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--threads", type=int, default=0, help="0: the default workers; 1: one thread")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--min-ms", type=float, default=20.0)
    ap.add_argument("--lib", help="import warp_subdiv from this folder instead")
    args = ap.parse_args(argv)
    if args.lib:
        sys.path.insert(0, os.path.abspath(args.lib))
    import warnings

    warnings.simplefilter("ignore")
    from warp_subdiv.runtime.allocator import retain_freed_memory

    retain_freed_memory()
    import warp as wp

    wp.config.quiet = True
    from bench_bake import bake
    from pxr import Tf

    Tf.Debug.SetDebugSymbolsByName("*", False)
    events: list = []
    undo = traced_phases(events)
    threads = None if args.threads == 0 else args.threads
    with tempfile.TemporaryDirectory(prefix="wstimeline_") as folder:
        out = os.path.join(folder, "baked.usdc")
        bake(args.asset, out, 1)  # warm-up
        for _ in range(args.reps):
            events.clear()
            gc.collect()
            t0, c0 = time.perf_counter(), time.process_time()
            r = bake(args.asset, out, args.levels, "auto", threads)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            print(f"\n## bake, threads={args.threads or 'default'}: wall {wall:.3f} s, process CPU {cpu:.3f} s "
                  f"(CPU / wall {cpu / wall:.2f}); load average {os.getloadavg()[0]:.2f}; phases "
                  + ", ".join(f"{k} {v:.2f}" for k, v in r["phases"].items()) + "\n")
            report(events, t0, args.min_ms)
    undo()
    return 0


if __name__ == "__main__":
    sys.exit(main())
