"""The memory estimate (what ``max_memory`` and ``--max-memory`` compare with) is within 20% of the measured peak.

Each configuration of ``bench/bench_memory.py --quick`` runs in a fresh process: the peak resident memory the
call adds (``/proc/self/clear_refs`` resets the peak counter) beside the estimate the memory guard computes
before any refined level is allocated. The configurations cover both schemes, closed and open meshes, the
projecting piecewise-smooth rules (concave corner, explicit flatness), limit masks on the last level and one
level deeper, and ``refine_usd`` with and without a face-varying primvar, at 0.35 to 1.6 million output
vertices, where refined data dominates the process's fixed costs.
"""
import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"),
                                reason="needs Linux's /proc/self/clear_refs to reset the peak-RSS counter")


def _measure(out, *names):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for name in [k for k in env if k.startswith("MALLOC_")]:  # glibc tunables (set by Dask, for one) change peaks
        del env[name]
    select = ["--only", *names] if names else ["--quick"]
    res = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "bench_memory.py"), *select, "--json",
                          str(out)], capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    return {r["config"]: r for r in json.loads(out.read_text())}


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    folder = tmp_path_factory.mktemp("memory")
    return _measure(folder / "rows.json")


def _bounding(row) -> bool:
    """A configuration the estimate bounds from above rather than predicts: the USD bake in the compact vertex
    order (the estimate is calibrated on OpenSubdiv's order, whose peak is higher)."""
    return row["options"].get("order") == "compact"


def test_estimate_within_20_percent_of_measured_peak(rows):
    """estimate / measured peak in [0.8, 1.2] for every configuration (measured in a fresh process with the
    allocator's defaults: glibc MALLOC_* tunables, which Dask sets in its parent process, are removed)."""
    off = {name: round(r["ratio"], 3) for name, r in rows.items() if not _bounding(r) and not 0.8 <= r["ratio"] <= 1.2}
    assert not off, f"estimate / measured peak outside [0.8, 1.2]: {off}"


def test_estimate_bounds_the_compact_bake(rows):
    """The bake in the compact vertex order (the default for piecewise-smooth meshes) peaks lower than in
    OpenSubdiv's order; the same estimate stays above its measured peak, by at most 50%."""
    bounded = {name: round(r["ratio"], 3) for name, r in rows.items() if _bounding(r)}
    assert bounded, "no compact-order configuration measured"
    off = {name: ratio for name, ratio in bounded.items() if not 1.0 <= ratio <= 1.5}
    assert not off, f"estimate / measured peak outside [1.0, 1.5]: {off}"


def test_configurations_are_large_and_distinct(rows):
    """The check means something: outputs large enough that refined data dominates, and the projecting and
    limit configurations really cost more per vertex than plain refinement (the model must tell them apart)."""
    assert len(rows) >= 8
    assert min(r["vertices"] for r in rows.values()) > 300_000
    per_vertex = {name: r["measured"] / r["vertices"] for name, r in rows.items()}
    assert per_vertex["cc-concave-projecting"] > 1.5 * per_vertex["cc-open"]
    assert per_vertex["cc-limit"] > 5 * per_vertex["cc-closed"]
    assert per_vertex["loop-closed"] > 1.15 * per_vertex["cc-closed"]
