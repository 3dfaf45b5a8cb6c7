"""Fuzzing: random valid and malformed meshes never raise anything but SubdivInputError, never hang, never crash.

The cases come from ``bench/fuzz.py`` (``random_case``: random polygon and triangle soups with repeated
vertices, doubled faces and non-manifold edges and vertices; grids and boxes with collapsed, doubled, flipped and
dropped faces; indices out of range, negative or far out of range; counts that do not add up and faces of fewer
than 3 vertices; NaN, infinite, huge and collapsed coordinates; wrong shapes and dtypes; random crease, corner,
hole, concave and normal tags with sharpness that may be negative, NaN or huge; both schemes and rule sets,
the three boundary modes, both crease methods, both precisions, levels 0-2). They run in worker processes of
a child process with a timeout, so a crash or a hang fails the test instead of the test run. The larger run
(10,000 cases) is ``python bench/fuzz.py --count 10000``; its result is in BENCHMARKS.md.
"""
import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FUZZ = os.path.join(ROOT, "bench", "fuzz.py")


def run_fuzz(tmp_path, count, seed, paths, timeout):
    out = tmp_path / f"fuzz_{paths}.json"
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, FUZZ, "--count", str(count), "--seed", str(seed), "--workers", "2",
                          "--timeout", "30", "--paths", paths, "--json", str(out)],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=timeout)
    assert out.exists(), res.stdout[-3000:] + res.stderr[-3000:]
    return res, json.loads(out.read_text())


def test_fuzz_mesh_and_refine(tmp_path):
    """2,000 random cases through Mesh and refine (both schemes and rule sets, levels 0-2): every one either
    refines to finite points with valid face indices or raises SubdivInputError with a message; no other
    exception, hang or crash; and both outcomes occur often (the generator reaches both the refiner and the
    checks)."""
    res, summary = run_fuzz(tmp_path, 2000, 0, "refine", timeout=240)
    failures = summary["failures"]
    assert not failures, "\n\n".join(f"seed {f['seed']} ({f['kind']}): {f['outcome']}\n{f['message']}"
                                     for f in failures[:5])
    assert res.returncode == 0
    outcomes = summary["outcomes"]
    assert summary["cases"] == 2000
    assert outcomes.get("ok", 0) > 800 and outcomes.get("refused", 0) > 300, outcomes
    # the soups and damaged meshes (repeated vertices, doubled faces, non-manifold input) are mostly refined
    soup = summary["by_kind"]["soup"]
    assert soup.get("ok", 0) > 2 * soup.get("refused", 0), soup


def test_fuzz_every_path(tmp_path):
    """500 further cases through every path: Mesh, refine, Refiner.evaluate of random (sometimes NaN) data,
    limit points and normals, a face-varying channel with random (sometimes out-of-range) indices (evaluate and
    limit), and every 8th case through the USD reader: again only successes with finite output or
    SubdivInputError."""
    pytest.importorskip("pxr")
    res, summary = run_fuzz(tmp_path, 500, 100_000, "all", timeout=240)
    failures = summary["failures"]
    assert not failures, "\n\n".join(f"seed {f['seed']} ({f['kind']}): {f['outcome']}\n{f['message']}"
                                     for f in failures[:5])
    assert res.returncode == 0 and summary["cases"] == 500
