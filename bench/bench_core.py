"""Benchmark of the core engine: topology + stencil-table build, Warp evaluation, end-to-end refine, memory.

    python bench/bench_core.py                    # both bench meshes, levels 1-5, Markdown table on stdout
    python bench/bench_core.py --quick            # levels 1-2 only (CI smoke test, about 10 s)
    python bench/bench_core.py --levels 3-4 --frames 9 --device cpu --json out/bench.json
    python bench/bench_core.py --profile catmull-clark:4   # cProfile of one Refiner build (top functions)
    python bench/bench_core.py --commit HEAD      # measure a commit's library (git archive), not the work tree
    python bench/bench_core.py --baseline cf72af6  # before/after in one run: each case on both, back to back

Exit status 1 when a worker crashed (a library error); a level stopped by the timeout or memory guard is
reported in the output but is not a failure.

Every (mesh, level) runs in a fresh subprocess so that its peak memory is its own: the worker reads VmHWM
(peak resident set) from /proc/self/status after imports + mesh load (baseline) and again at the end, and
reports both (``getrusage(RUSAGE_SELF).ru_maxrss`` where /proc is absent). The parent guards every worker
with a timeout and a resident-memory limit (it polls the child's VmRSS and kills it when over the limit) and
stops a mesh at the highest level that worked, saying why in the output. Within a worker:

* build      ``Refiner(mesh, L, ...)``: topology of all levels + CSR stencil tables (numpy, CPU);
* warm-up    the first ``evaluate``: table upload, buffer allocation, Warp module load (compiled once into
             Warp's kernel cache; the compile from an empty cache is timed once, separately);
* eval       median over ``--frames`` further ``evaluate`` calls (each with different points), numpy in and out
             (the JSON also holds the median process CPU time per frame, steadier on a busy machine);
* refine     ``ws.refine(mesh, L, ...)`` end to end (build + topology + first evaluate), after the Refiner
             above was freed.
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from benchutil import (  # noqa: E402 (the scripts run as files; their folder holds the shared helpers)
    proc_status, export_commit, mem_available_bytes, parse_levels, peak_rss_bytes, quiet_warp, run_child)
MESH_DIR = os.path.join(HERE, "meshes")
MESHES = {
    # name: (file, scheme)
    "cube64_noisy": ("cube64_noisy.obj", "catmull-clark"),
    "icosphere5_noisy": ("icosphere5_noisy.obj", "loop"),
    # open meshes (a boundary: explicit stencil rows on every level); not in the default set
    "grid64_open": ("grid64_open.obj", "catmull-clark"),
    "trigrid64_open": ("trigrid64_open.obj", "loop"),
}
DEFAULT_MESHES = ("cube64_noisy", "icosphere5_noisy")
MARK = "BENCH_RESULT "


# ------------------------------------------------------------------------------------------------ memory
# ------------------------------------------------------------------------------------------------ worker
def worker(args) -> dict:
    """One (mesh, level) configuration; returns a dict of measurements (printed as JSON by main)."""
    import numpy as np

    wp = quiet_warp()
    import warp_subdiv as ws
    read_obj = obj_reader()

    wp.init()
    file, scheme = MESHES[args.mesh]
    mesh = read_obj(os.path.join(MESH_DIR, file)).mesh
    level = args.level
    opts = dict(scheme=scheme, rules=args.rules, device=args.device, precision=args.precision)
    rng = np.random.default_rng(0)
    base = np.asarray(mesh.points, dtype=np.float64)
    # different points every frame (an animation); made before the baseline so they are not counted
    frames = [base + 1e-3 * rng.standard_normal(base.shape) for _ in range(args.frames)]
    gc.collect()
    res = {"mesh": args.mesh, "scheme": scheme, "level": level, "device": args.device,
           "base_vertices": int(len(base)), "base_faces": int(len(mesh.face_vertex_counts)),
           "baseline_peak_rss": peak_rss_bytes(), "baseline_rss": proc_status().get("VmRSS")}

    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    t = time.perf_counter()
    r = ws.Refiner(mesh, level, **opts)
    res["build_s"] = time.perf_counter() - t
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    # kernel time of the build: mostly page faults (zeroing fresh pages) of numpy temporaries
    res["build_user_s"] = ru1.ru_utime - ru0.ru_utime
    res["build_sys_s"] = ru1.ru_stime - ru0.ru_stime
    res["num_vertices"] = int(r.num_vertices)
    res["table_bytes"] = int(r.table_bytes())
    t = time.perf_counter()
    counts, _ = r.topology()
    res["topology_s"] = time.perf_counter() - t
    res["num_faces"] = int(len(counts))
    del counts, _

    t = time.perf_counter()
    out = r.evaluate(base)
    res["warmup_s"] = time.perf_counter() - t
    assert out.shape == (r.num_vertices, 3) and np.all(np.isfinite(out))
    times, cpu = [], []
    for pts in frames:
        c = time.process_time()
        t = time.perf_counter()
        r.evaluate(pts)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    res["eval_s"] = statistics.median(times)
    res["eval_s_all"] = times
    # CPU time of this process per frame: less sensitive than wall time to other jobs on a shared machine
    # (on the CPU device; with CUDA it leaves out the GPU's time)
    res["eval_cpu_s"] = statistics.median(cpu)
    res["peak_rss_refiner"] = peak_rss_bytes()
    del r, out
    gc.collect()

    if not args.skip_refine:
        t = time.perf_counter()
        refined = ws.refine(mesh, level, **opts)
        res["refine_s"] = time.perf_counter() - t
        assert refined.num_vertices == res["num_vertices"]
        del refined
    res["peak_rss"] = peak_rss_bytes()
    return res


def compile_worker(args) -> dict:
    """Time the Warp module build from an empty kernel cache (one tiny evaluate)."""
    import numpy as np

    wp = quiet_warp()
    cache = tempfile.mkdtemp(prefix="wsbench_kcache_")
    wp.config.kernel_cache_dir = cache
    import warp_subdiv as ws

    try:
        wp.init()
        mesh = ws.Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), [4], [0, 1, 2, 3])
        r = ws.Refiner(mesh, 1, device=args.device, precision=args.precision)
        t = time.perf_counter()
        r.evaluate(mesh.points)
        res = {"compile_s": time.perf_counter() - t}
        t = time.perf_counter()
        r.evaluate(mesh.points)
        res["second_s"] = time.perf_counter() - t
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    return res


def profile_build(args):
    import cProfile
    import pstats

    quiet_warp()
    import warp_subdiv as ws
    read_obj = obj_reader()

    scheme, _, level = args.profile.partition(":")
    names = [n for n, (_, s) in MESHES.items() if s == scheme]
    if not names or not level.isdigit():
        sys.exit(f"--profile wants SCHEME:LEVEL with SCHEME one of "
                 f"{', '.join(s for _, s in MESHES.values())}, got {args.profile!r}")
    name = names[0]
    mesh = read_obj(os.path.join(MESH_DIR, MESHES[name][0])).mesh
    prof = cProfile.Profile()
    t = time.perf_counter()
    prof.enable()
    ws.Refiner(mesh, int(level), scheme=scheme, rules=args.rules, device=args.device, precision=args.precision)
    prof.disable()
    print(f"Refiner build of {name} ({scheme}) level {level}: {time.perf_counter() - t:.2f} s wall "
          f"(profiled), peak RSS {peak_rss_bytes() / 2**20:.0f} MiB")
    stats = pstats.Stats(prof).strip_dirs()
    stats.sort_stats("tottime").print_stats(25)
    stats.sort_stats("cumulative").print_stats(25)


# ------------------------------------------------------------------------------------------------ parent
def run_worker(cmd, timeout_s, mem_limit, lib_root=ROOT):
    """run_child for this script's workers, with the measured library first on their path."""
    pythonpath = lib_root + (os.pathsep + os.environ["PYTHONPATH"] if os.environ.get("PYTHONPATH") else "")
    return run_child(cmd + ["--lib-root", lib_root], timeout_s, mem_limit, MARK, {"PYTHONPATH": pythonpath})


def library_state(lib_root: str = ROOT, commit: str | None = None) -> str:
    """Which library code is measured: git commit, whether warp_subdiv/ or kernels/ differ from it, and a
    digest of their sources (compared at the start and the end of a run to catch edits made meanwhile)."""
    import hashlib

    digest = hashlib.sha1()
    for folder in ("warp_subdiv", "kernels"):
        for dirpath, dirnames, files in sorted(os.walk(os.path.join(lib_root, folder))):
            dirnames.sort()
            for name in sorted(files):
                if name.endswith(".py"):
                    with open(os.path.join(dirpath, name), "rb") as fh:
                        digest.update(name.encode() + fh.read())
    if commit:
        return f"git {commit[:7]}, exported snapshot of that commit (sources {digest.hexdigest()[:10]})"
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "warp_subdiv", "kernels"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
        head = f"git {sha}" + (" + uncommitted changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        head = "not a git checkout"
    return f"{head} (sources {digest.hexdigest()[:10]})"


def machine_info() -> dict:
    import numpy
    import warp

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    ram = None
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        pass
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count()
    return {"cpu": cpu, "cores": cores, "ram_bytes": ram, "os": platform.platform(),
            "python": platform.python_version(), "numpy": numpy.__version__, "warp": warp.__version__}


def obj_reader():
    """The library's OBJ reader, wherever the library under test keeps it (``--commit`` / ``--baseline`` may
    measure a commit from before the package was layered)."""
    try:
        from warp_subdiv.io.obj import read_obj
    except ImportError:
        from warp_subdiv.objio import read_obj
    return read_obj


def fmt_comparison(pairs) -> str:
    """Before/after table: one row per (mesh, level) measured with both libraries, ratios after / before."""
    head = ["mesh (scheme)", "level", "build s before", "after", "ratio", "eval ms before", "after", "ratio",
            "refine s before", "after", "ratio", "peak RSS ratio"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for b, a in pairs:
        def trio(key, scale=1.0, fmt="{:.3f}"):
            if key not in b or key not in a:
                return ["–", "–", "–"]
            return [fmt.format(b[key] * scale), fmt.format(a[key] * scale), f"{a[key] / max(b[key], 1e-12):.2f}"]
        lines.append("| " + " | ".join([f"{a['mesh']} ({a['scheme']})", str(a["level"])] + trio("build_s")
                                       + trio("eval_s", 1e3, "{:.2f}") + trio("refine_s")
                                       + [f"{a['peak_rss'] / max(b['peak_rss'], 1):.2f}"]) + " |")
    return "\n".join(lines)


def fmt_table(rows) -> str:
    head = ["mesh (scheme)", "level", "output verts", "build s", "build sys %", "warm-up s", "eval ms/frame",
            "refine s", "table B/vert", "eval Mverts/s", "peak RSS MiB", "Δ peak MiB"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    mib = 2**20
    for r in rows:
        refine = f"{r['refine_s']:.3f}" if "refine_s" in r else "–"
        lines.append("| " + " | ".join([
            f"{r['mesh']} ({r['scheme']})", str(r["level"]), f"{r['num_vertices']:,}", f"{r['build_s']:.3f}",
            f"{100 * r['build_sys_s'] / max(r['build_user_s'] + r['build_sys_s'], 1e-9):.0f}",
            f"{r['warmup_s']:.3f}", f"{r['eval_s'] * 1e3:.2f}", refine,
            f"{r['table_bytes'] / r['num_vertices']:.1f}", f"{r['num_vertices'] / r['eval_s'] / 1e6:.1f}",
            f"{r['peak_rss'] / mib:,.0f}", f"{(r['peak_rss'] - r['baseline_peak_rss']) / mib:,.0f}",
        ]) + " |")
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--levels", default="1-5", help="e.g. 1-5 or 1,3 (default 1-5)")
    p.add_argument("--quick", action="store_true", help="levels 1-2, 3 frames (CI smoke test)")
    p.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda")
    p.add_argument("--precision", default="float32", choices=["float32", "float64"])
    p.add_argument("--rules", default="piecewise-smooth", choices=["piecewise-smooth", "opensubdiv"])
    p.add_argument("--meshes", default=",".join(DEFAULT_MESHES),
                   help=f"comma-separated subset of {','.join(MESHES)} (default: {','.join(DEFAULT_MESHES)})")
    p.add_argument("--frames", type=int, default=5, help="timed evaluate calls after warm-up (median)")
    p.add_argument("--timeout", type=float, default=300.0, help="seconds per (mesh, level) subprocess")
    p.add_argument("--mem-limit-gib", type=float, default=None,
                   help="kill a worker above this resident size (default: 90%% of MemAvailable at start)")
    p.add_argument("--skip-refine", action="store_true", help="do not time ws.refine end to end")
    p.add_argument("--json", help="also write all measurements to this JSON file")
    p.add_argument("--profile", metavar="SCHEME:LEVEL", help="cProfile one Refiner build and exit")
    p.add_argument("--baseline", metavar="REV",
                   help="also measure this commit's library, each (mesh, level) right before the working tree's "
                        "(before/after in one run, a table of ratios after / before)")
    p.add_argument("--commit", metavar="REV",
                   help="benchmark warp_subdiv/ and kernels/ of this git commit (exported to a temporary folder) "
                        "instead of the working tree")
    # internal
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--compile-worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--mesh", help=argparse.SUPPRESS)
    p.add_argument("--level", type=int, help=argparse.SUPPRESS)
    p.add_argument("--lib-root", default=ROOT, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)

    commit = None
    if args.commit and not (args.worker or args.compile_worker):
        args.lib_root, commit = export_commit(args.commit)
    if args.worker or args.compile_worker or args.profile:
        sys.path.insert(0, args.lib_root)
        quiet_warp()
        import warp_subdiv

        assert os.path.abspath(warp_subdiv.__file__).startswith(os.path.abspath(args.lib_root)), \
            f"imported {warp_subdiv.__file__}, not the library under {args.lib_root}"
    if args.worker:
        print(MARK + json.dumps(worker(args)), flush=True)
        return 0
    if args.compile_worker:
        print(MARK + json.dumps(compile_worker(args)), flush=True)
        return 0
    if args.profile:
        try:
            profile_build(args)
        finally:
            if commit:
                shutil.rmtree(args.lib_root, ignore_errors=True)
        return 0
    args.baseline_root = None
    if args.baseline:
        args.baseline_root, _ = export_commit(args.baseline)
    try:
        return run_benchmark(p, args, commit)
    finally:
        if commit:
            shutil.rmtree(args.lib_root, ignore_errors=True)
        if args.baseline_root:
            shutil.rmtree(args.baseline_root, ignore_errors=True)


def run_benchmark(p, args, commit) -> int:

    levels = [1, 2] if args.quick else parse_levels(args.levels)
    if args.quick:
        args.frames = min(args.frames, 3)
    meshes = [m.strip() for m in args.meshes.split(",") if m.strip()]
    for m in meshes:
        if m not in MESHES:
            p.error(f"unknown mesh {m!r}; choose from {', '.join(MESHES)}")
    avail = mem_available_bytes()
    mem_limit = int(args.mem_limit_gib * 2**30) if args.mem_limit_gib else (int(0.9 * avail) if avail else None)

    info = machine_info()
    lib = library_state(args.lib_root, commit)
    started = time.perf_counter()
    cmdline = "python bench/bench_core.py" + "".join(" " + a for a in args.argv)
    print(f"# warp-subdiv core benchmark\n\ncommand: `{cmdline}`\n")
    ram = f"{info['ram_bytes'] / 2**30:.1f} GiB" if info["ram_bytes"] else "?"
    print(f"machine: {info['cpu']}, {info['cores']} cores, {ram} RAM; {info['os']}; "
          f"Python {info['python']}, numpy {info['numpy']}, warp {info['warp']}; Warp device {args.device}, "
          f"{args.precision}, rules {args.rules}")
    print(f"library: warp_subdiv {lib}")
    load0 = os.getloadavg() if hasattr(os, "getloadavg") else None
    if mem_limit:
        print(f"guards: {args.timeout:.0f} s and {mem_limit / 2**30:.1f} GiB resident per (mesh, level) subprocess")
    sys.stdout.flush()

    common = ["--device", args.device, "--precision", args.precision, "--rules", args.rules]
    comp, why = run_worker([sys.executable, os.path.abspath(__file__), "--compile-worker"] + common,
                           args.timeout, mem_limit, args.lib_root)
    compile_note = (f"Warp module build from an empty kernel cache (first evaluate of a 1-quad mesh): "
                    f"{comp['compile_s']:.2f} s; the rows below load it from Warp's kernel cache."
                    if comp else f"Warp module compile could not be timed: {why}")

    rows, notes, crashed, pairs = [], [], False, []
    for m in meshes:
        for lv in levels:
            cmd = [sys.executable, os.path.abspath(__file__), "--worker", "--mesh", m, "--level", str(lv),
                   "--frames", str(args.frames)] + common + (["--skip-refine"] if args.skip_refine else [])
            before = None
            if args.baseline_root:  # the baseline right before, so both see the machine in the same state
                before, why = run_worker(cmd, args.timeout, mem_limit, args.baseline_root)
                if before is None:
                    notes.append(f"{m} level {lv}: baseline {args.baseline} stopped ({why})")
            t = time.perf_counter()
            res, why = run_worker(cmd, args.timeout, mem_limit, args.lib_root)
            wall = time.perf_counter() - t
            if res is None:
                crashed = crashed or why.startswith("exit code")
                higher = [x for x in levels if x > lv]
                msg = f"{m} level {lv}: stopped ({why}); highest level that worked: " \
                      f"{max([r['level'] for r in rows if r['mesh'] == m], default='none')}"
                if higher:
                    msg += f"; levels {', '.join(map(str, higher))} not run"
                notes.append(msg)
                print(f"  {msg}", file=sys.stderr, flush=True)
                break
            res["subprocess_wall_s"] = wall
            rows.append(res)
            if before is not None:
                pairs.append((before, res))
            print(f"  {m} level {lv}: {res['num_vertices']:,} verts, build {res['build_s']:.2f} s, "
                  f"eval {res['eval_s'] * 1e3:.1f} ms, subprocess {wall:.1f} s", file=sys.stderr, flush=True)

    total = time.perf_counter() - started
    lib_end = library_state(args.lib_root, commit)
    load1 = os.getloadavg() if hasattr(os, "getloadavg") else None
    if lib_end != lib:
        notes.append(f"the library changed during this run (start: {lib}; end: {lib_end}): rerun")
    print()
    print(fmt_table(rows))
    print()
    if pairs:
        print(f"Before ({args.baseline}) and after (this library), each pair measured back to back:\n")
        print(fmt_comparison(pairs))
        print()
    print("build = Refiner(): topology + stencil tables of all levels (numpy, CPU); build sys % = kernel share "
          "of the build's CPU time (getrusage; page faults of fresh memory); warm-up = first evaluate "
          "(table upload + Warp module load); eval = median of "
          f"{args.frames} further evaluate calls (numpy in, numpy out); refine = ws.refine end to end; "
          "table B/vert = Refiner.table_bytes() / output vertices; peak RSS = VmHWM of the fresh subprocess "
          "at its end, Δ = minus its VmHWM after imports + mesh load.")
    print()
    print(compile_note)
    for n in notes:
        print(f"\n**{n}**")
    if len(rows) == len(meshes) * len(levels):
        print(f"\nAll requested levels ({', '.join(map(str, levels))}) completed for every mesh.")
    load = (f" (1-minute load average {load0[0]:.2f} at the start, {load1[0]:.2f} at the end, on "
            f"{info['cores']} cores: other work on the machine slows the timings)") if load0 and load1 else ""
    print(f"\nTotal benchmark wall time: {total:.1f} s{load}")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"command": cmdline, "machine": info, "library": lib, "rows": rows, "notes": notes,
                       "baseline": args.baseline, "baseline_rows": [b for b, _ in pairs],
                       "compile": comp, "total_s": total,
                       "loadavg_start": load0, "loadavg_end": load1}, fh, indent=1)
    return 1 if crashed else 0


if __name__ == "__main__":
    sys.exit(main())
