"""First run against second run of the quick start after ``pip install .`` into a fresh virtual environment.

    python bench/bench_first_run.py [--venv /tmp/fresh] [--reps 3] [--compile-reps 1] [--install-without]
                                    [--json out.json]

Creates a new virtual environment, installs this checkout into it (``pip install -q .``: the wheel build compiles
the kernels ahead of time, warp_subdiv.kernels.prebuilt), then runs the README's quick-start command
(``warp-subdiv refine scenes/concave_corner.usda -o ... --levels 4``) as separate processes, each pair with a new
empty Warp kernel cache (``WARP_CACHE_PATH``):

* **shipped binaries**: first run, then second run (the target: first at most 1.5x the second);
* **compile on first use** (``WARP_SUBDIV_PREBUILT=0``: the shipped binaries ignored, as before they existed):
  first run (Warp compiles the modules, now several at once), then second run (from Warp's cache).

Prints the wall times of each run, the ratios, the install time and whether the kernel cache stayed empty.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, "scenes", "concave_corner.usda")


def timed(cmd, env=None, cwd=None) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, env=env, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return time.perf_counter() - start


def cached_modules(cache: str) -> int:
    """Kernel modules Warp compiled into ``cache`` (folders named wp_*)."""
    return sum(1 for _, dirs, _ in os.walk(cache) for d in dirs if d.startswith("wp_"))


def pair(venv: str, work: str, prebuilt: bool) -> dict:
    """First and second quick-start run with a new empty kernel cache."""
    cache = tempfile.mkdtemp(prefix="wsbench_cache_", dir=work)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "WARP_SUBDIV_PREBUILT")}
    env["WARP_CACHE_PATH"] = cache
    if not prebuilt:
        env["WARP_SUBDIV_PREBUILT"] = "0"
    cmd = [os.path.join(venv, "bin", "warp-subdiv"), "refine", SCENE, "-o", os.path.join(work, "out.usda"),
           "--levels", "4"]
    first = timed(cmd, env=env, cwd=work)
    compiled = cached_modules(cache)
    second = timed(cmd, env=env, cwd=work)
    shutil.rmtree(cache, ignore_errors=True)
    return {"first_s": first, "second_s": second, "ratio": first / second, "modules_compiled": compiled}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--venv", help="where to create the virtual environment (default: a new temporary folder)")
    ap.add_argument("--reps", type=int, default=3, help="pairs of runs with shipped binaries (default 3)")
    ap.add_argument("--compile-reps", type=int, default=1, help="pairs of runs compiling on first use (default 1)")
    ap.add_argument("--install-without", action="store_true",
                    help="also time the install without the compile (WARP_SUBDIV_PREBUILD=0) into a second venv")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args(argv)

    work = tempfile.mkdtemp(prefix="wsbench_first_run_")
    venv = args.venv or os.path.join(work, "venv")
    shutil.rmtree(venv, ignore_errors=True)
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    pip_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    install_s = timed([os.path.join(venv, "bin", "pip"), "install", "-q", ROOT], env=pip_env, cwd=work)
    plain_install_s = None
    if args.install_without:
        plain = os.path.join(work, "venv_plain")
        subprocess.run([sys.executable, "-m", "venv", plain], check=True)
        plain_install_s = timed([os.path.join(plain, "bin", "pip"), "install", "-q", ROOT],
                                env=dict(pip_env, WARP_SUBDIV_PREBUILD="0"), cwd=work)
    site = subprocess.run([os.path.join(venv, "bin", "python"), "-c",
                           "import warp, warp_subdiv.kernels.prebuilt as p, json; "
                           "print(json.dumps([warp.config.version, (p.SHIPPED / p.MANIFEST).exists()]))"],
                          env=pip_env, cwd=work, capture_output=True, text=True, check=True)
    warp_version, shipped = json.loads(site.stdout.strip().splitlines()[-1])

    rows = [("shipped binaries", pair(venv, work, True)) for _ in range(args.reps)]
    rows += [("compile on first use", pair(venv, work, False)) for _ in range(args.compile_reps)]

    print(f"pip install -q . into a new venv: {install_s:.1f} s (Warp {warp_version}; "
          f"binaries shipped: {'yes' if shipped else 'no'})")
    if plain_install_s is not None:
        print(f"the same install without the compile (WARP_SUBDIV_PREBUILD=0): {plain_install_s:.1f} s")
    print("\n| kernels | first run s | second run s | first / second | modules compiled by the first run |")
    print("|---|---:|---:|---:|---:|")
    for name, r in rows:
        print(f"| {name} | {r['first_s']:.2f} | {r['second_s']:.2f} | {r['ratio']:.2f} | {r['modules_compiled']} |")
    for name in ("shipped binaries", "compile on first use"):
        ratios = [r["ratio"] for n, r in rows if n == name]
        if ratios:
            print(f"\n{name}: first / second median {statistics.median(ratios):.2f} "
                  f"({min(ratios):.2f}-{max(ratios):.2f}, {len(ratios)} pairs)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"install_s": install_s, "install_without_compile_s": plain_install_s, "warp": warp_version,
                       "shipped": shipped, "runs": [{"kernels": n, **r} for n, r in rows]}, fh, indent=1)
    shutil.rmtree(work, ignore_errors=True)  # the caches, the output and the default venv
    return 0


if __name__ == "__main__":
    sys.exit(main())
