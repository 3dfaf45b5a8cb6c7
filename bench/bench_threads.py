"""Threaded CPU evaluation and build: threads 1 against all cores, per mesh and level, in one run.

    python bench/bench_threads.py                         # both bench meshes, levels 4-5, 1 vs all cores
    python bench/bench_threads.py --levels 4-6 --frames 5 --json out/bench_threads.json
    python bench/bench_threads.py --quick                 # level 2 only (smoke test)
    python bench/bench_threads.py --commit HEAD           # a commit's library (git archive), not the work tree
    python bench/bench_threads.py --probe                 # how plain Warp CPU kernels scale here (no library)
    python bench/bench_threads.py --levels 4-6 --reps 3 --commit main   # main's library, same probe beside it
    python bench/bench_threads.py --levels 4-5 --baseline main    # main and the work tree interleaved, one probe

Every (mesh, level, threads) runs in a fresh subprocess (its memory is its own, nothing is warm from the
other thread count): ``Refiner(mesh, L, threads=T)`` (build), a first ``evaluate`` (warm-up), the median of
``--frames`` further ``evaluate`` calls with different points (numpy in and out), and ``ws.refine(mesh, L,
threads=T)`` end to end after the refiner is freed. Each thread count runs ``--reps`` times, the counts
interleaved (1, all, 1, all, ...), and each figure is the best of its repetitions (on a shared machine the
best is the run least disturbed by other jobs). The table gives each figure for 1 thread and for all cores,
and their ratio (1-thread time / all-cores time) from the same run; the 1-minute load average at the start
and end tells how busy the machine was.

Beside every (mesh, level), in the same run and interleaved with its repetitions, a fresh process times the
plain Warp gather kernel of :func:`probe` (4 vec3 per row, local indices: one launch against two half launches
from two Python threads, best of its repetitions): the speed-up the machine gives a kernel with no library
around it at that moment. The columns "eval / probe" and "refine / probe" divide the library's 2-thread
speed-ups by the probe's (1.00: as good as the plain kernel).
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from benchutil import (  # noqa: E402 (the scripts run as files; their folder holds the shared helpers)
    export_commit, mem_available_bytes, parse_levels, peak_rss_bytes, quiet_warp, run_child)

MESHES = {"cube64_noisy": ("cube64_noisy.obj", "catmull-clark"),
          "icosphere5_noisy": ("icosphere5_noisy.obj", "loop")}
MARK = "BENCH_RESULT "


def worker(args) -> dict:
    import numpy as np

    quiet_warp()
    sys.path.insert(0, args.lib_root)
    import warp_subdiv as ws

    assert os.path.abspath(ws.__file__).startswith(os.path.abspath(args.lib_root)), ws.__file__
    from warp_subdiv.io.obj import read_obj

    file, scheme = MESHES[args.mesh]
    mesh = read_obj(os.path.join(HERE, "meshes", file)).mesh
    rng = np.random.default_rng(0)
    frames = [mesh.points + 1e-3 * rng.standard_normal(mesh.points.shape) for _ in range(args.frames)]
    ws.refine(mesh, 1, scheme=scheme, device="cpu", threads=args.threads)  # Warp's module loaded, pool made
    gc.collect()
    res = {"mesh": args.mesh, "scheme": scheme, "level": args.level, "threads": args.threads}
    t = time.perf_counter()
    r = ws.Refiner(mesh, args.level, scheme=scheme, device="cpu", threads=args.threads)
    res["build_s"] = time.perf_counter() - t
    res["vertices"] = int(r.num_vertices)
    t = time.perf_counter()
    r.evaluate(mesh.points)
    res["warmup_s"] = time.perf_counter() - t
    times = []
    for pts in frames:
        t = time.perf_counter()
        r.evaluate(pts)
        times.append(time.perf_counter() - t)
    res["eval_s"] = statistics.median(times)
    del r
    gc.collect()
    t = time.perf_counter()
    out = ws.refine(mesh, args.level, scheme=scheme, device="cpu", threads=args.threads)
    res["refine_s"] = time.perf_counter() - t
    del out
    res["peak_rss"] = peak_rss_bytes()
    return res


def probe(reps: int = 3, only: str | None = None) -> list:
    """How plain Warp CPU launches scale on this machine when split into two row ranges on two Python
    threads (as the evaluator does): a compute-bound kernel, a streaming gather with local indices (what
    the subdivision kernels' reads look like) and a gather with random indices; best of ``reps``."""
    import threading

    import numpy as np

    wp = quiet_warp()
    wp.init()

    @wp.kernel
    def compute(a: wp.array(dtype=float), b: wp.array(dtype=float), row0: int):
        i = wp.tid() + row0
        s = float(0.0)
        for j in range(200):
            s += wp.sin(a[i] + float(j))
        b[i] = s

    @wp.kernel
    def gather(idx: wp.array(dtype=wp.int32), a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3), row0: int):
        i = wp.tid() + row0
        b[i] = a[idx[4 * i]] + a[idx[4 * i + 1]] + a[idx[4 * i + 2]] + a[idx[4 * i + 3]]

    rng = np.random.default_rng(0)
    n, m = 20_000_000, 6_000_000
    cases = [("compute-bound (200 sin per row, 2M rows)", compute, 2_000_000,
              lambda: [wp.array(rng.random(2_000_000).astype(np.float32), device="cpu"),
                       wp.zeros(2_000_000, dtype=float, device="cpu")])]
    for name, idx in (("local", (np.arange(4 * n) // 13).astype(np.int32) % m),
                      ("random", rng.integers(0, m, 4 * n).astype(np.int32))):
        cases.append((f"gather of 4 vec3 per row, {name} indices (20M rows from 6M)", gather, n,
                       lambda idx=idx: [wp.array(idx, device="cpu"),
                                        wp.array(rng.random((m, 3)).astype(np.float32), dtype=wp.vec3, device="cpu"),
                                        wp.zeros(n, dtype=wp.vec3, device="cpu")]))
    out = []
    for name, kernel, rows, make in cases:
        if only is not None and only not in name:
            continue
        arrays = make()
        wp.launch(kernel, dim=rows, inputs=arrays + [0], device="cpu")
        one, two = [], []
        for _ in range(reps):
            t = time.perf_counter()
            wp.launch(kernel, dim=rows, inputs=arrays + [0], device="cpu")
            one.append(time.perf_counter() - t)

            def part(lo, hi, arrays=arrays, kernel=kernel):
                wp.launch(kernel, dim=hi - lo, inputs=arrays + [lo], device="cpu")

            t = time.perf_counter()
            th = threading.Thread(target=part, args=(rows // 2, rows))
            th.start()
            part(0, rows // 2)
            th.join()
            two.append(time.perf_counter() - t)
        out.append({"kernel": name, "one_s": min(one), "two_s": min(two)})
    if only is not None:
        return out
    # the memory bandwidth itself: numpy copies of 1 GiB, whole or in two halves on two threads
    a = np.ones(256 * 2**20, np.float32)
    b = np.zeros_like(a)
    one, two = [], []
    for _ in range(reps):
        t = time.perf_counter()
        np.copyto(b, a)
        one.append(time.perf_counter() - t)
        half = len(a) // 2
        t = time.perf_counter()
        th = threading.Thread(target=np.copyto, args=(b[half:], a[half:]))
        th.start()
        np.copyto(b[:half], a[:half])
        th.join()
        two.append(time.perf_counter() - t)
    gbs = 2 * a.nbytes / 1e9
    out.append({"kernel": f"np.copyto of 1 GiB ({gbs / min(one):.1f} / {gbs / min(two):.1f} GB/s read + write)",
                "one_s": min(one), "two_s": min(two)})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default=",".join(MESHES))
    ap.add_argument("--levels", default="4-5")
    ap.add_argument("--threads", default=None, help="comma-separated thread counts (default: 1 and all cores)")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--reps", type=int, default=3, help="fresh processes per thread count, best taken")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--timeout", type=float, default=600)
    ap.add_argument("--json", default=None)
    ap.add_argument("--commit", default=None, help="measure this commit's library (git archive)")
    ap.add_argument("--baseline", default=None,
                    help="also measure this commit's library, interleaved with the other in every repetition")
    ap.add_argument("--lib-root", default=ROOT, help=argparse.SUPPRESS)
    ap.add_argument("--probe", action="store_true", help="only time plain Warp kernels split over 2 threads")
    ap.add_argument("--no-probe", action="store_true", help="no probe process beside each (mesh, level)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--probe-worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--mesh", help=argparse.SUPPRESS)
    ap.add_argument("--level", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.probe_worker:
        print(MARK + json.dumps(probe(2, only="local")[0]), flush=True)
        return 0
    if args.worker:
        args.threads = int(args.threads)
        print(MARK + json.dumps(worker(args)), flush=True)
        return 0
    if args.probe:
        load0 = os.getloadavg()[0]
        rows = probe(args.reps)
        print(f"Plain Warp CPU kernels, one launch against two half launches on two threads (best of {args.reps}); "
              f"1-minute load average {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end.\n")
        print("| kernel | 1 thread s | 2 threads s | ratio |")
        print("|---|---:|---:|---:|")
        for r in rows:
            print(f"| {r['kernel']} | {r['one_s']:.3f} | {r['two_s']:.3f} | {r['one_s'] / r['two_s']:.2f}x |")
        return 0

    sha = None
    if args.commit:
        args.lib_root, sha = export_commit(args.commit)
    sys.path.insert(0, args.lib_root)
    from warp_subdiv.runtime.threads import available_cores

    cores = available_cores()
    counts = [int(x) for x in args.threads.split(",")] if args.threads else sorted({1, cores})
    levels = [2] if args.quick else parse_levels(args.levels)
    load0 = os.getloadavg()[0]
    start = time.perf_counter()
    libs = [("working tree" if not sha else sha[:7], args.lib_root)]
    if args.baseline:
        base_root, base_sha = export_commit(args.baseline)
        libs.insert(0, (base_sha[:7], base_root))  # the baseline first in every repetition
    rows, failed = [], False
    for name in args.meshes.split(","):
        for level in levels:
            group = [{"mesh": name, "scheme": MESHES[name][1], "level": level, "library": label, "runs": {},
                      "reps": {}} for label, _ in libs]
            probe_reps: list = []
            for rep in range(args.reps):
                for t in counts:
                    for row, (label, root) in zip(group, libs):
                        if "error" in row["runs"].get(t, {}):
                            continue
                        cmd = [sys.executable, os.path.abspath(__file__), "--worker", "--mesh", name, "--level",
                               str(level), "--threads", str(t), "--frames", str(args.frames), "--lib-root", root]
                        avail = mem_available_bytes()
                        res, why = run_child(cmd, args.timeout, int(0.9 * avail) if avail else None, MARK)
                        if res is None:
                            row["runs"][t] = {"error": why}
                            failed = failed or why.startswith("exit code")
                        else:
                            row["reps"].setdefault(t, []).append(res)
                            best = dict(res)
                            for key in ("build_s", "warmup_s", "eval_s", "refine_s"):
                                best[key] = min(r[key] for r in row["reps"][t])
                            row["runs"][t] = best
                        print(f"{name} L{level} {label} threads {t} (repetition {rep + 1}): " + (
                              why if res is None else f"build {res['build_s']:.3f} s, eval "
                              f"{1e3 * res['eval_s']:.1f} ms, refine {res['refine_s']:.3f} s"),
                              file=sys.stderr, flush=True)
                if args.no_probe:
                    continue
                cmd = [sys.executable, os.path.abspath(__file__), "--probe-worker"]
                res, why = run_child(cmd, args.timeout, None, MARK)
                if res is not None:
                    probe_reps.append(res)
                    best = {k: min(r[k] for r in probe_reps) for k in ("one_s", "two_s")}
                    for row in group:
                        row["probe_reps"] = probe_reps
                        row["probe"] = dict(best, ratio=best["one_s"] / best["two_s"])
                print(f"{name} L{level} probe (repetition {rep + 1}): " + (why if res is None else
                      f"{res['one_s']:.3f} / {res['two_s']:.3f} s"), file=sys.stderr, flush=True)
            rows.extend(group)
    load1 = os.getloadavg()[0]
    seconds = time.perf_counter() - start
    lo, hi = counts[0], counts[-1]
    print(f"Library: {' against '.join(label for label, _ in libs)} (interleaved in every repetition). "
          f"Threads {lo} against {hi} ({cores} cores available), best of {args.reps}; {seconds:.1f} s; "
          f"1-minute load average "
          f"{load0:.2f} at the start, {load1:.2f} at the end.\n")
    print(f"| mesh (scheme) | level | library | output verts | build s ({lo} / {hi}) | ratio "
          f"| eval ms ({lo} / {hi}) | ratio "
          f"| refine s ({lo} / {hi}) | ratio | probe ratio | eval / probe | refine / probe |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        a, b = row["runs"].get(lo, {}), row["runs"].get(hi, {})
        if "error" in a or "error" in b:
            print(f"| {row['mesh']} ({row['scheme']}) | {row['level']} | {row['library']} | – | "
                  f"{a.get('error') or b.get('error')} "
                  "| | | | | | | | |")
            continue
        p = row.get("probe", {}).get("ratio")
        eval_ratio, refine_ratio = a["eval_s"] / b["eval_s"], a["refine_s"] / b["refine_s"]
        versus = (f"{p:.2f}x | {eval_ratio / p:.2f} | {refine_ratio / p:.2f}" if p else "– | – | –")
        print(f"| {row['mesh']} ({row['scheme']}) | {row['level']} | {row['library']} | {a['vertices']:,} | "
              f"{a['build_s']:.3f} / "
              f"{b['build_s']:.3f} | {a['build_s'] / b['build_s']:.2f}x | {1e3 * a['eval_s']:.1f} / "
              f"{1e3 * b['eval_s']:.1f} | {eval_ratio:.2f}x | {a['refine_s']:.3f} / "
              f"{b['refine_s']:.3f} | {refine_ratio:.2f}x | {versus} |")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump({"commit": sha, "baseline": args.baseline,
                       "cores": cores, "threads": counts, "load_start": load0, "load_end": load1,
                       "seconds": seconds, "rows": rows}, f, indent=1)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
