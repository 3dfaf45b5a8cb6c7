"""Threaded CPU evaluation: a launch split into row ranges on several threads gives, bitwise, one thread's
result; ``threads`` is checked; one threaded evaluator still serves several Python threads."""
import threading

import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv.runtime import threads as th

from conftest import load_mesh


@pytest.fixture
def small_ranges(monkeypatch):
    """Split launches of a few rows too, so that the small test meshes exercise every kernel's ranges."""
    monkeypatch.setattr(th, "MIN_ROWS", 3)


def test_ranges_cover_rows_in_order():
    """ranges() covers 0..n with at most `parts` contiguous, non-empty, ordered ranges, none shorter than
    min_rows (one range for small n)."""
    assert th.ranges(10, 4, min_rows=100) == [(0, 10)]
    for n, parts, m in [(100, 3, 1), (7, 8, 1), (1000, 4, 200), (65536, 2, 32768)]:
        r = th.ranges(n, parts, m)
        assert r[0][0] == 0 and r[-1][1] == n and len(r) <= parts
        assert all(a < b and (b - a >= m or len(r) == 1) for a, b in r)
        assert all(r[i][1] == r[i + 1][0] for i in range(len(r) - 1))


def test_chunks_cover_rows_several_per_thread():
    """chunks() covers 0..n in order with up to CHUNKS_PER_THREAD contiguous ranges per thread, none shorter
    than min_rows; one range for one thread or small n."""
    assert th.chunks(10**6, 1) == [(0, 10**6)] and th.chunks(100, 2, min_rows=64) == [(0, 100)]
    assert th.chunks(0, 2) == []
    r = th.chunks(10**6, 2, min_rows=1000)
    assert len(r) == 2 * th.CHUNKS_PER_THREAD and r[0][0] == 0 and r[-1][1] == 10**6
    assert all(r[i][1] == r[i + 1][0] for i in range(len(r) - 1))
    assert len(th.chunks(5000, 2, min_rows=1000)) == 5


def test_run_shared_runs_every_job_once_on_several_threads():
    """run_shared() runs each job exactly once, the calling thread and the pool taking jobs from one queue
    (a job that waits does not hold back the others), and raises a job's exception after the others stop."""
    done, names, lock = [], set(), threading.Lock()
    started = threading.Event()

    def job(k):
        def f():
            if k == 0:  # the first job waits until another thread has run one: two threads take jobs
                started.wait(10)
            with lock:
                done.append(k)
                names.add(threading.current_thread().name)
                started.set()
        return f

    th.run_shared([job(k) for k in range(20)], 2)
    assert sorted(done) == list(range(20)) and len(names) == 2

    def fail():
        raise ValueError("boom")

    with pytest.raises(ValueError, match="boom"):
        th.run_shared([fail] + [job(k) for k in range(5)], 2)


@pytest.mark.parametrize("name,scheme,normals", [
    ("cube_creased", "catmull-clark", False), ("quad_lshape", "catmull-clark", True),
    ("tri_hexfan", "loop", False), ("mixed_prism", "loop", True), ("mixed_prism", "catmull-clark", False)])
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_threaded_evaluation_is_bitwise_one_thread(small_ranges, name, scheme, normals, precision):
    """Refined points (width 3 with normal control, width 5), limit points and limit normals with 1, 2 and 3
    threads are bitwise equal: quad and triangle steps, explicit rows, stencil steps, flatness and
    normal-control displacements, limit masks."""
    base = load_mesh(name)
    mesh = base
    if normals:
        mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices,
                       creases=base.creases if len(base.creases) else None, normals=([1], [[0.0, 0.6, 0.8]]))
    rng = np.random.default_rng(3)
    wide = rng.standard_normal((mesh.num_vertices, 5))
    results = []
    for threads in (1, 2, 3):
        r = ws.Refiner(mesh, 3, scheme=scheme, precision=precision, device="cpu", threads=threads)
        assert r.evaluator.launcher.threads == threads
        pts = r.evaluate(mesh.points)
        results.append((pts, r.evaluate(wide), r.limit_points(pts), r.limit_normals(pts)))
    for other in results[1:]:
        for a, b in zip(results[0], other):
            np.testing.assert_array_equal(a, b)


def test_large_level_splits_without_patching():
    """With the real range size, a level of 393K vertices (cube64 at level 2) is split over 2 threads and
    matches one thread bitwise."""
    import os

    from warp_subdiv.io.obj import read_obj

    mesh = read_obj(os.path.join(os.path.dirname(__file__), "..", "bench", "meshes", "cube64_noisy.obj")).mesh
    one = ws.Refiner(mesh, 2, device="cpu", threads=1)
    two = ws.Refiner(mesh, 2, device="cpu", threads=2)
    assert len(th.ranges(one.num_vertices, 2)) == 2
    np.testing.assert_array_equal(one.evaluate(mesh.points), two.evaluate(mesh.points))


def test_threads_is_checked_and_defaults_to_the_affinity(monkeypatch):
    """threads must be an integer >= 1; None means the cores this process may use, or the process default
    that set_default_threads (the CLI's --threads) or WARP_SUBDIV_THREADS sets."""
    mesh = load_mesh("cube")
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ws.SubdivInputError, match="threads"):
            ws.Refiner(mesh, 1, device="cpu", threads=bad)
    monkeypatch.delenv("WARP_SUBDIV_THREADS", raising=False)
    assert ws.Refiner(mesh, 1, device="cpu").threads == th.available_cores()
    monkeypatch.setenv("WARP_SUBDIV_THREADS", "3")
    assert ws.Refiner(mesh, 1, device="cpu").threads == 3
    th.set_default_threads(2)
    try:
        assert ws.Refiner(mesh, 1, device="cpu").threads == 2
    finally:
        th.set_default_threads(None)
    assert ws.refine(mesh, 1, device="cpu", threads=2).num_vertices == 26


def test_threaded_evaluator_serves_several_python_threads(small_ranges):
    """Several Python threads evaluating different points on one 2-thread refiner each get their own
    result, equal to a one-thread refiner's (the evaluator's lock spans every range of a call)."""
    mesh = load_mesh("cube_creased")
    ref = ws.Refiner(mesh, 3, device="cpu", threads=1)
    r = ws.Refiner(mesh, 3, device="cpu", threads=2)
    inputs = [mesh.points + 0.01 * k for k in range(6)]
    out = [None] * len(inputs)

    def work(k):
        for _ in range(5):
            out[k] = r.evaluate(inputs[k])

    ts = [threading.Thread(target=work, args=(k,)) for k in range(len(inputs))]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    for k, pts in enumerate(inputs):
        np.testing.assert_array_equal(out[k], ref.evaluate(pts))


def _arrays(obj, prefix="", seen=None) -> dict:
    """Every array and scalar reachable from ``obj`` (attributes, list items), by access path."""
    seen = set() if seen is None else seen
    if obj is None or id(obj) in seen:
        return {}
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return {prefix: obj}
    if isinstance(obj, (list, tuple)):
        out = {}
        for i, x in enumerate(obj):
            out.update(_arrays(x, f"{prefix}[{i}]", seen))
        return out
    if hasattr(obj, "__dict__"):
        out = {}
        for k, v in vars(obj).items():
            out.update(_arrays(v, f"{prefix}.{k}", seen))
        return out
    return {prefix: obj} if isinstance(obj, (int, float, str, bool)) else {}


@pytest.mark.parametrize("name,scheme", [("cube_creased", "catmull-clark"), ("quad_lshape", "catmull-clark"),
                                         ("tri_hexfan", "loop"), ("mixed_prism", "loop")])
def test_threaded_build_is_bitwise_one_thread(name, scheme):
    """The hierarchy built with 2 threads (step tables and the next level at once) has, array for array,
    the tables, displacements and final topology of the one-thread build."""
    from warp_subdiv.tables.hierarchy import Hierarchy
    from warp_subdiv.options import Options

    mesh = load_mesh(name)
    one, two = (Hierarchy(mesh, 3, Options(scheme=scheme), threads=t, concurrent_build=t > 1) for t in (1, 2))

    for what in ("steps", "flatness_tables", "normal_tables", "final"):
        a, b = _arrays(getattr(one, what)), _arrays(getattr(two, what))
        assert a.keys() == b.keys() and (len(a) > 10 or what != "steps")
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"{what}{key}")
    for x, y in zip(one.topology(), two.topology()):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("rules", ["opensubdiv", "piecewise-smooth"])
@pytest.mark.parametrize("name,scheme", [("cube_creased", "catmull-clark"), ("quad_halffan", "catmull-clark"),
                                         ("mixed_prism", "catmull-clark"), ("tri_hexfan", "loop"),
                                         ("mixed_prism", "loop"), ("icosahedron", "loop")])
def test_threaded_topology_is_bitwise_one_thread(monkeypatch, small_ranges, name, scheme, rules):
    """Refinement steps whose per-face tables are written in blocks split over 2 threads (blocks of 2 faces,
    so that these small meshes split), child edges filled and step tables gathered in ranges of a few rows on
    2 threads, give, array for array, the levels, step tables and topology of a one-thread build in one
    block."""
    from warp_subdiv.topology import refinement as topology
    from warp_subdiv.tables.hierarchy import Hierarchy
    from warp_subdiv.options import Options

    mesh = load_mesh(name)
    options = Options(scheme=scheme, rules=rules)
    one = Hierarchy(mesh, 3, options, threads=1)
    levels_one = [topology.refine_level(one.penultimate, faces_only=fo) for fo in (False, True)]
    monkeypatch.setattr(topology, "BLOCK_FACES", 2)
    calls = []
    monkeypatch.setattr(th, "map_ranges", lambda fn, n, threads, min_rows=th.MIN_ROWS, real=th.map_ranges:
                        calls.append(len(th.ranges(n, threads, min_rows))) or real(fn, n, threads, min_rows))
    two = Hierarchy(mesh, 3, options, threads=2)
    levels_two = [topology.refine_level(two.penultimate, faces_only=fo, threads=2) for fo in (False, True)]
    assert max(calls) == 2  # the blocks were split over the two threads
    for what in ("steps", "flatness_tables", "normal_tables", "final", "penultimate"):
        a, b = _arrays(getattr(one, what)), _arrays(getattr(two, what))
        assert a.keys() == b.keys() and (len(a) > 1 or what.endswith("_tables"))
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"{what}{key}")
    for x, y in zip(levels_one, levels_two):
        a, b = _arrays(x), _arrays(y)
        assert a.keys() == b.keys()
        for key in a:
            assert type(a[key]) is type(b[key]) and getattr(a[key], "dtype", None) == getattr(b[key], "dtype", None)
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    for x, y in zip(one.topology(), two.topology()):
        np.testing.assert_array_equal(x, y)


def test_nested_runs_do_not_deadlock():
    """Work that itself runs jobs on the pool, started from a job of the pool, runs its jobs inline (a pool
    of one worker would otherwise wait for itself)."""
    def inner(k):
        return th.run([lambda: k, lambda: k + 1], 2)

    assert th.run([lambda: inner(0), lambda: inner(10)], 2) == [[0, 1], [10, 11]]
