"""Helpers shared by the benchmark scripts: memory readings, guarded worker processes, Warp quieting, commit
export, level lists."""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def proc_status(pid="self") -> dict:
    out = {}
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(("VmHWM", "VmRSS")):
                    key, value = line.split(":", 1)
                    out[key] = int(value.split()[0]) * 1024  # kB -> bytes
    except OSError:
        pass
    return out


def peak_rss_bytes() -> int:
    """Peak resident set of this process so far (VmHWM; ru_maxrss where /proc is absent)."""
    hwm = proc_status().get("VmHWM")
    if hwm is not None:
        return hwm
    scale = 1 if sys.platform == "darwin" else 1024  # ru_maxrss is bytes on macOS, kB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale


def mem_available_bytes() -> int | None:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def quiet_warp():
    """Import Warp with its start-up banner and module-load lines off."""
    import warp as wp

    wp.config.log_level = 30
    wp.config.quiet = True
    return wp


def export_commit(rev: str, prefix: str = "wsbench_lib_") -> tuple[str, str]:
    """Extract warp_subdiv/ and kernels/ of commit ``rev`` into a temporary folder; (folder, full sha)."""
    sha = subprocess.run(["git", "rev-parse", "--verify", rev + "^{commit}"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.strip()
    dest = tempfile.mkdtemp(prefix=prefix)
    archive = subprocess.run(["git", "archive", sha, "warp_subdiv", "kernels"], cwd=ROOT, capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", dest], input=archive, check=True)
    return dest, sha


def parse_levels(text: str) -> list[int]:
    """"3-5" or "3,5" as a list of levels; "" as none."""
    if not text:
        return []
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(x) for x in text.split(",")]


def _tree_rss(pid: int) -> int:
    """Resident bytes of a process and all its descendants (the OpenSubdiv worker runs a C++ child)."""
    total, todo, seen = 0, [pid], set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        total += proc_status(p).get("VmRSS", 0)
        try:
            for tid in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{tid}/children", encoding="ascii") as fh:
                    todo.extend(int(c) for c in fh.read().split())
        except OSError:
            pass
    return total


def run_child(cmd, timeout_s, mem_limit, mark, env_extra=None):
    """Run a worker that prints its result as one JSON line after ``mark``; (result dict | None, reason).

    Kills it on timeout or when its process tree is over mem_limit; reports the largest tree RSS seen
    (sampled every 0.1 s) as ``sampled_peak_tree_rss`` and its wall time as ``subprocess_wall_s``."""
    env = dict(os.environ)
    env.update(env_extra or {})
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    killed, max_rss = {}, [0]

    def kill():
        try:
            os.killpg(proc.pid, 9)  # the worker and its children (osd_peer) only: its own session
        except OSError:
            proc.kill()

    def watch():
        while proc.poll() is None:
            rss = _tree_rss(proc.pid)
            max_rss[0] = max(max_rss[0], rss)
            if mem_limit and rss > mem_limit:
                killed["why"] = (f"killed at {rss / 2**30:.1f} GiB resident (limit {mem_limit / 2**30:.1f} GiB)")
                killed["rss"] = rss
                kill()
                return
            time.sleep(0.1)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    t = time.perf_counter()
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        kill()
        out, err = proc.communicate()
        killed.setdefault("why", f"timed out after {timeout_s:.0f} s")
    wall = time.perf_counter() - t
    watcher.join()
    if "why" in killed:
        return None, killed["why"] + f" (largest resident size seen {max_rss[0] / 2**30:.1f} GiB, {wall:.0f} s)"
    for line in out.splitlines():
        if line.startswith(mark):
            res = json.loads(line[len(mark):])
            res["subprocess_wall_s"] = wall
            res["sampled_peak_tree_rss"] = max_rss[0]
            return res, ""
    tail = (err or out).strip().splitlines()[-3:]
    return None, f"exit code {proc.returncode}: " + " | ".join(tail)
