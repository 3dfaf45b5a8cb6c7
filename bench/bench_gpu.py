"""Benchmark of evaluation on the device: evaluate_device time, bytes moved, copy bandwidth.

    python bench/bench_gpu.py                     # both bench meshes, levels 4-6, on CUDA where present
    python bench/bench_gpu.py --device cpu --levels 2-4 --frames 10
    python bench/bench_gpu.py --quick             # levels 1-2, 3 frames (CI smoke test, any device)
    python bench/bench_gpu.py --overhead-only --commit 7fd7d44   # the call overhead of a commit's library

Every (mesh, level) runs in a fresh subprocess (bench_core's guards: a timeout and a resident-memory limit).
Within a worker, for ``bench/meshes/cube64_noisy.obj`` (Catmull-Clark) and ``icosphere5_noisy.obj`` (Loop):

* topology   ``Refiner(mesh, L)``: topology and step tables of every level (numpy, host);
* upload     the step tables to the device (``Evaluator.records()``, synchronised);
* first      the first ``evaluate_device``: level buffers, the recorded plan (and on CUDA its graph
             capture), the control points' copy and one evaluation (synchronised);
* eval       ``evaluate_device`` of control points already on the device (a new Warp array per frame), median
             over ``--frames`` calls: by CUDA events around the call (on CUDA; the device time) and by the wall
             clock to the end of a ``wp.synchronize_device`` (host overhead included), and the process CPU
             time of the call (every thread; steadier than the wall clock on a shared CPU);
* numpy      ``evaluate`` with numpy in and out (one transfer each way on CUDA), median wall time;
* bytes      what one evaluation must move at least: every level's points read once and written once (the
             control points and the last level included) and every table array its kernels take read once
             (on CUDA the compact tables, ``Refiner.table_bytes()``; on the CPU the expanded quad tables
             the CPU kernels read instead); ``GB/s`` = bytes / eval time (events on CUDA, else wall);
* copy       the device's copy bandwidth measured in the same worker: ``wp.copy`` of a buffer as large as the
             last level's points (at least 64 MiB), read + written bytes / time, best of 5 (events on CUDA);
* fraction   GB/s / copy GB/s: the share of the copy bandwidth the evaluation reaches.

A row for the 8-vertex cube (``tests/data/meshes/cube.obj``) at levels 2 and 4 gives the host overhead of one
``evaluate_device`` call (median and best of 300 calls, wall clock, synchronised): launch overhead, not data.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from benchutil import export_commit, mem_available_bytes, parse_levels, quiet_warp, run_child  # noqa: E402

MESH_DIR = os.path.join(HERE, "meshes")
MESHES = {"cube64_noisy": ("cube64_noisy.obj", "catmull-clark"), "icosphere5_noisy": ("icosphere5_noisy.obj", "loop")}
SMALL_CUBE = os.path.join(ROOT, "tests", "data", "meshes", "cube.obj")
MARK = "BENCH_GPU_RESULT "


class Clock:
    """Times a callable on ``device``: CUDA events around it on the current stream (device time) and the wall
    clock to the end of a device synchronisation."""

    def __init__(self, wp, device):
        self.wp, self.device = wp, device
        self.cuda = device.is_cuda

    def __call__(self, fn) -> tuple[float | None, float]:
        wp = self.wp
        wp.synchronize_device(self.device)
        if self.cuda:
            stream = wp.get_stream(self.device)
            start, stop = wp.Event(self.device, enable_timing=True), wp.Event(self.device, enable_timing=True)
            t = time.perf_counter()
            stream.record_event(start)
            fn()
            stream.record_event(stop)
            wp.synchronize_device(self.device)
            wall = time.perf_counter() - t
            return wp.get_event_elapsed_time(start, stop) / 1e3, wall
        t = time.perf_counter()
        fn()
        wp.synchronize_device(self.device)
        return None, time.perf_counter() - t


def copy_bandwidth(wp, device, nbytes: int, clock: Clock) -> float:
    """Bytes per second of ``wp.copy`` on the device (read + written), best of 5."""
    n = max(nbytes, 64 * 2**20) // 4
    src = wp.zeros(n, dtype=wp.float32, device=device)
    dst = wp.empty(n, dtype=wp.float32, device=device)
    wp.copy(dst, src)
    best = min((e if e is not None else w) for e, w in (clock(lambda: wp.copy(dst, src)) for _ in range(5)))
    return 2 * 4 * n / best


def bytes_moved(refiner) -> tuple[int, int]:
    """(point bytes, table bytes) one evaluation moves at least: every level read once and written once, every
    table array its kernels take read once (the expanded quad tables where the evaluator reads those: on the
    CPU; the compact ones, ``Refiner.table_bytes()``, on CUDA)."""
    import dataclasses

    import warp as wp
    from warp_subdiv import evaluator as ev

    e = refiner.evaluator
    real = 8 if refiner.precision.value == "float64" else 4
    rows = e.level_rows()
    points = sum(3 * real * (a + b) for a, b in zip(rows[:-1], rows[1:]))

    def table(obj) -> int:
        if obj is None:
            return 0
        if isinstance(obj, wp.array):
            return obj.size * wp.types.type_size_in_bytes(obj.dtype)
        if not dataclasses.is_dataclass(obj):
            return 0
        skip = {"edge_neighbours", "ring"} if isinstance(obj, ev.QuadStep) and obj.edge_ends is not None else set()
        return sum(table(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.name not in skip)

    return points, sum(table(rec) for rec in e.records())


def worker(args) -> dict:
    import numpy as np

    wp = quiet_warp()
    import warp_subdiv as ws
    from warp_subdiv.io.obj import read_obj

    wp.init()
    device = wp.get_device(args.device)
    clock = Clock(wp, device)
    if args.mesh == "overhead":
        return overhead(args, wp, ws, read_obj, device)
    file, scheme = MESHES[args.mesh]
    mesh = read_obj(os.path.join(MESH_DIR, file)).mesh
    base = np.asarray(mesh.points, dtype=np.float64)
    rng = np.random.default_rng(0)
    frames = [base + 1e-3 * rng.standard_normal(base.shape) for _ in range(args.frames)]
    res = {"mesh": args.mesh, "scheme": scheme, "level": args.level, "device": str(device)}

    t = time.perf_counter()
    r = ws.Refiner(mesh, args.level, scheme=scheme, device=device, precision=args.precision)
    res["topology_s"] = time.perf_counter() - t
    r.evaluator.expand_tables = {"auto": None, "compact": False, "expanded": True}[args.tables]
    res["tables"] = args.tables
    res["num_vertices"] = int(r.num_vertices)
    _, res["upload_s"] = clock(r.evaluator.records)
    scalar = wp.float64 if args.precision == "float64" else wp.float32
    dev_frames = [wp.array(f.astype(np.float64 if args.precision == "float64" else np.float32), dtype=scalar,
                           device=device) for f in frames]
    _, res["first_s"] = clock(lambda: r.evaluate_device(dev_frames[0]))
    ev, wall, cpu = [], [], []
    for f in dev_frames:
        c = time.process_time()
        e, w = clock(lambda f=f: r.evaluate_device(f))
        cpu.append(time.process_time() - c)
        wall.append(w)
        if e is not None:
            ev.append(e)
    res["eval_cpu_s"] = statistics.median(cpu)  # process CPU time (every thread): steadier on a shared CPU
    res["eval_wall_s"] = statistics.median(wall)
    res["eval_event_s"] = statistics.median(ev) if ev else None
    res["eval_wall_all"] = wall
    plan = next(iter(r.evaluator._plans.values()))
    res["launches"], res["graphs"] = plan.num_launches, plan.graphs
    host = [clock(lambda f=f: r.evaluate(f))[1] for f in frames[: max(1, args.frames // 2)]]
    res["numpy_s"] = statistics.median(host)
    res["points_bytes"], res["table_bytes"] = bytes_moved(r)
    eval_s = res["eval_event_s"] or res["eval_wall_s"]
    res["gbps"] = (res["points_bytes"] + res["table_bytes"]) / eval_s / 1e9
    res["copy_gbps"] = copy_bandwidth(wp, device, 12 * r.num_vertices, clock) / 1e9
    res["fraction"] = res["gbps"] / res["copy_gbps"]
    out = r.evaluate_device(dev_frames[-1]).numpy()
    np.testing.assert_array_equal(out, r.evaluate(frames[-1]))  # device input, numpy input: the same result
    return res


def overhead(args, wp, ws, read_obj, device) -> dict:
    """Host overhead of evaluate_device on the 8-vertex cube at levels 2 and 4 (median and best of 300)."""
    import numpy as np

    mesh = read_obj(SMALL_CUBE).mesh
    res = {"mesh": "overhead", "device": str(device)}
    for level in (2, 4):
        r = ws.Refiner(mesh, level, device=device, threads=1)
        pts = np.asarray(mesh.points, np.float64)
        r.evaluate_device(pts)
        wp.synchronize_device(device)
        times = []
        for _ in range(30 if args.quick else 300):
            t = time.perf_counter()
            r.evaluate_device(pts)
            wp.synchronize_device(device)
            times.append(time.perf_counter() - t)
        res[f"L{level}_median_us"] = 1e6 * statistics.median(times)
        res[f"L{level}_best_us"] = 1e6 * min(times)
        res[f"L{level}_vertices"] = int(r.num_vertices)
    return res


def fmt_table(rows) -> str:
    head = ["mesh (scheme)", "level", "output verts", "topology s", "upload s", "first s", "eval ms (events)",
            "eval ms (wall)", "eval CPU ms", "evaluate numpy ms", "points MB", "tables MB", "GB/s", "copy GB/s",
            "fraction", "launches / graphs"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for r in rows:
        ev = "–" if r["eval_event_s"] is None else f"{1e3 * r['eval_event_s']:.3f}"
        lines.append("| " + " | ".join([
            f"{r['mesh']} ({r['scheme']})", str(r["level"]), f"{r['num_vertices']:,}", f"{r['topology_s']:.3f}",
            f"{r['upload_s']:.4f}", f"{r['first_s']:.4f}", ev, f"{1e3 * r['eval_wall_s']:.3f}",
            f"{1e3 * r['eval_cpu_s']:.2f}",
            f"{1e3 * r['numpy_s']:.2f}", f"{r['points_bytes'] / 1e6:.1f}", f"{r['table_bytes'] / 1e6:.1f}",
            f"{r['gbps']:.2f}", f"{r['copy_gbps']:.1f}", f"{r['fraction']:.3f}", f"{r['launches']} / {r['graphs']}",
        ]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--levels", default="4-6", help="e.g. 4-6 or 4,6 (default 4-6)")
    p.add_argument("--quick", action="store_true", help="levels 1-2, 3 frames (CI smoke test)")
    p.add_argument("--device", default=None, help="Warp device (default: cuda where present, else cpu)")
    p.add_argument("--precision", default="float32", choices=["float32", "float64"])
    p.add_argument("--meshes", default=",".join(MESHES), help="comma-separated subset of " + ",".join(MESHES))
    p.add_argument("--frames", type=int, default=20, help="timed evaluate_device calls (median)")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds per (mesh, level) subprocess")
    p.add_argument("--json", help="also write all measurements to this JSON file")
    p.add_argument("--overhead-only", action="store_true", help="only the 8-vertex cube's call overhead")
    p.add_argument("--tables", default="auto", choices=["auto", "compact", "expanded"],
                   help="quad tables the kernels read (auto: expanded on the CPU, compact on CUDA)")
    p.add_argument("--commit", metavar="REV", help="measure warp_subdiv/ and kernels/ of this git commit (exported "
                   "to a temporary folder); libraries without device input take host data only: use --overhead-only")
    p.add_argument("--lib-root", default=ROOT, help=argparse.SUPPRESS)
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--mesh", help=argparse.SUPPRESS)
    p.add_argument("--level", type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.device is None:
        wp = quiet_warp()
        args.device = "cuda" if wp.get_cuda_device_count() > 0 else "cpu"
    if args.quick:
        args.frames = min(args.frames, 3)
    if args.worker:
        sys.path.insert(0, args.lib_root)
        print(MARK + json.dumps(worker(args)), flush=True)
        return 0
    if args.commit:
        import shutil

        args.lib_root, sha = export_commit(args.commit)
        try:
            return run(p, args, argv, f"git {sha[:7]} (exported)")
        finally:
            shutil.rmtree(args.lib_root, ignore_errors=True)
    return run(p, args, argv, "working tree")


def run(p, args, argv, library: str) -> int:

    levels = [] if args.overhead_only else [1, 2] if args.quick else parse_levels(args.levels)
    meshes = [m.strip() for m in args.meshes.split(",") if m.strip()]
    for m in meshes:
        if m not in MESHES:
            p.error(f"unknown mesh {m!r}; choose from {', '.join(MESHES)}")
    avail = mem_available_bytes()
    mem_limit = int(0.9 * avail) if avail else None
    env = {"PYTHONPATH": args.lib_root + (os.pathsep + os.environ["PYTHONPATH"] if os.environ.get("PYTHONPATH")
                                          else "")}
    common = ["--device", args.device, "--precision", args.precision, "--frames", str(args.frames),
              "--lib-root", args.lib_root, "--tables", args.tables] + (["--quick"] if args.quick else [])
    me = [sys.executable, os.path.abspath(__file__), "--worker"]
    started = time.perf_counter()
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    cmdline = "python bench/bench_gpu.py" + "".join(" " + a for a in (sys.argv[1:] if argv is None else argv))
    print(f"# warp-subdiv device benchmark\n\ncommand: `{cmdline}`; Warp device {args.device}, {args.precision}, "
          f"quad tables {args.tables}; library: {library}\n")
    sys.stdout.flush()

    rows, notes, crashed = [], [], False
    small, why = run_child(me + ["--mesh", "overhead"] + common, args.timeout, mem_limit, MARK, env)
    if small is None:
        crashed = why.startswith("exit code")
        notes.append(f"overhead run failed: {why}")
    for m in meshes:
        for lv in levels:
            res, why = run_child(me + ["--mesh", m, "--level", str(lv)] + common, args.timeout, mem_limit, MARK, env)
            if res is None:
                crashed = crashed or why.startswith("exit code")
                notes.append(f"{m} level {lv}: stopped ({why})")
                print(f"  {notes[-1]}", file=sys.stderr, flush=True)
                break
            rows.append(res)
            print(f"  {m} level {lv}: {res['num_vertices']:,} verts, evaluate_device {1e3 * res['eval_wall_s']:.2f} ms",
                  file=sys.stderr, flush=True)
    if rows:
        print(fmt_table(rows))
    if small:
        print(f"\nHost overhead of one evaluate_device call, 8-vertex cube (Catmull-Clark): level 2 "
              f"({small['L2_vertices']} vertices) median {small['L2_median_us']:.1f} us, best "
              f"{small['L2_best_us']:.1f} us; level 4 ({small['L4_vertices']:,} vertices) median "
              f"{small['L4_median_us']:.1f} us, best {small['L4_best_us']:.1f} us.")
    for n in notes:
        print(f"\n**{n}**")
    total = time.perf_counter() - started
    load1 = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    load = f" (1-minute load average {load0:.2f} at the start, {load1:.2f} at the end)" if load0 is not None else ""
    print(f"\nTotal wall time: {total:.1f} s{load}")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"command": cmdline, "rows": rows, "overhead": small, "notes": notes, "total_s": total,
                       "loadavg_start": load0, "loadavg_end": load1}, fh, indent=1)
    return 1 if crashed else 0


if __name__ == "__main__":
    sys.exit(main())
