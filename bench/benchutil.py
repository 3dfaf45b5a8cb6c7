"""Helpers shared by the benchmark scripts: memory readings, Warp quieting, commit export, level lists."""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile

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
