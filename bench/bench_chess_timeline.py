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

``--probes``: afterwards, two probes of what threads can do here. The save probe: usd-core saves a copy of the
bake's output while a pure-Python counter runs on another thread; the counter's rate during the save against
its rate alone (near 0: the save holds the GIL, so nothing in Python overlaps it). The analysis probe: the
refiners of every planned mesh (``make_refiner``, levels as given, one thread each) built twice one after the
other and twice at once on two threads (the speed-up: whether the analysis itself is GIL-bound).
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


def save_probe(path: str) -> None:
    """usd-core's save of a copy of the layer at ``path`` against a Python counter thread (see the docstring)."""
    from pxr import Sdf

    src = Sdf.Layer.FindOrOpen(path)
    count, stop = [0], [False]

    def spin():
        while not stop[0]:
            count[0] += 1

    with tempfile.TemporaryDirectory(prefix="wsprobe_") as folder:
        for rep in range(2):
            layer = Sdf.Layer.CreateNew(os.path.join(folder, f"copy{rep}.usdc"))
            layer.TransferContent(src)
            count[0], stop[0] = 0, False
            thread = threading.Thread(target=spin)
            thread.start()
            time.sleep(0.2)
            alone = count[0] / 0.2
            count[0] = 0
            t0, c0 = time.perf_counter(), time.thread_time()
            layer.Save()
            wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
            during = count[0] / wall
            stop[0] = True
            thread.join()
            print(f"save probe: save {wall:.3f} s (saving thread's CPU {cpu:.3f} s); the Python counter ran at "
                  f"{during / alone:.2f} of its rate alone during it")


def analysis_probe(asset: str, levels: int) -> None:
    """The planned meshes' refiners built twice in a row, then twice at once on two threads."""
    from warp_subdiv.runtime import threads as _threads
    from warp_subdiv.usd.planning import make_refiner, plan

    p = plan(asset, levels, device="cpu")

    def job(out, k):
        t0, c0 = time.perf_counter(), time.thread_time()
        with _threads.inline():
            for i, sp in enumerate(p.prims):
                make_refiner(sp, p.levels[i], options=p.options[i], device="cpu")
        out[k] = (time.perf_counter() - t0, time.thread_time() - c0)

    job({}, 0)
    for _ in range(3):
        serial: dict = {}
        t0 = time.perf_counter()
        job(serial, 0)
        job(serial, 1)
        one = time.perf_counter() - t0
        both: dict = {}
        pair = [threading.Thread(target=job, args=(both, k)) for k in range(2)]
        t0 = time.perf_counter()
        for t in pair:
            t.start()
        for t in pair:
            t.join()
        two = time.perf_counter() - t0
        ratios = ", ".join(f"{c / w:.2f}" for w, c in both.values())
        print(f"analysis probe: {len(p.prims)} meshes' refiners twice, one after the other {one:.3f} s, on two "
              f"threads at once {two:.3f} s (speed-up {one / two:.2f}; each thread's CPU / wall {ratios}); "
              f"load average {os.getloadavg()[0]:.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset")
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--threads", type=int, default=0, help="0: the default workers; 1: one thread")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--min-ms", type=float, default=20.0)
    ap.add_argument("--lib", help="import warp_subdiv from this folder instead")
    ap.add_argument("--probes", action="store_true", help="then the save probe and the analysis probe")
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
        if args.probes:
            save_probe(out)
            analysis_probe(args.asset, args.levels)
    return 0


if __name__ == "__main__":
    sys.exit(main())
