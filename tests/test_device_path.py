"""Data that stays on the device, recorded launches, limits without round trips, 32-bit and device
memory guards, smaller tables. Every test runs on the CPU (and on CUDA where present, through ``device``)."""
import types

import numpy as np
import pytest
import warp as wp

import warp_subdiv as ws
from warp_subdiv.runtime import estimate
from warp_subdiv.evaluator import interop
from warp_subdiv import evaluator as ev
from warp_subdiv.runtime import threads as wthreads

from conftest import load_mesh

# quad steps (closed, and creased: explicit rows), triangle steps, a first step of stencils, flatness on every
# level with limits read one level deeper (quad_lshape)
MESHES = [("cube", "catmull-clark"), ("cube_creased", "catmull-clark"), ("icosahedron", "loop"),
          ("tri_hexfan", "loop"), ("mixed_prism", "catmull-clark"), ("quad_lshape", "catmull-clark")]


def with_normals():
    """The cube with a prescribed normal (normal-control tables on every level)."""
    base = load_mesh("cube")
    return ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, normals=([0], [[0.6, 0.48, 0.64]]))


def direct(refiner, data, normal_control):
    """The evaluation as it was before plans: every step launched directly (one thread), fresh numpy out."""
    e = refiner.evaluator
    records = e.records()
    levels, scratch = e.level_views(data.shape[1])
    levels[0].numpy()[...] = data if levels[0].ndim == 2 else data.reshape(-1, 3)
    for step, src, dst, tmp in zip(records, levels[:-1], levels[1:], scratch):
        ev.refine_step(step, src, dst, tmp, normal_control, ev.Launcher(refiner.device, 1))
    return np.array(levels[-1].numpy()).reshape(refiner.num_vertices, -1)


class DLPackOnly:
    """A producer that offers only the DLPack protocol (as a torch or JAX CPU tensor does)."""

    def __init__(self, array):
        self.array = array

    def __dlpack__(self, stream=None, **kwargs):
        return self.array.__dlpack__()

    def __dlpack_device__(self):
        return self.array.__dlpack_device__()


class CudaInterfaceOnly:
    """A producer that offers only ``__cuda_array_interface__`` (as CuPy or Numba arrays do)."""

    def __init__(self, array: wp.array):
        self.array = array
        self.__cuda_array_interface__ = array.__cuda_array_interface__


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_device_arrays_in_and_out(precision, device):
    """evaluate_device and evaluate take Warp arrays on the refiner's device -- vec3 rows, (n, 3) of the other
    precision, a strided column view -- and give bitwise what numpy input gives; ``out=`` receives the
    result in another precision or layout and is returned."""
    mesh = load_mesh("cube_creased")
    r = ws.Refiner(mesh, 3, precision=precision, device=device)
    expected = r.evaluate(mesh.points)
    pts64 = np.asarray(mesh.points, np.float64)
    wide = np.zeros((len(pts64), 6))
    wide[:, 2:5] = pts64
    inputs = [wp.array(pts64, dtype=wp.vec3d, device=device),
              wp.array(pts64.astype(np.float32), dtype=wp.float32, device=device),
              wp.array(wide, dtype=wp.float64, device=device)[:, 2:5]]
    for arr in inputs:
        got = r.evaluate_device(arr)
        assert got.device == wp.get_device(device) and got.shape == (r.num_vertices,)
        np.testing.assert_array_equal(got.numpy(), r.evaluate(pts64.astype(arr.dtype._wp_scalar_type_._type_
                                                                           if hasattr(arr.dtype, "_wp_scalar_type_")
                                                                           else arr.dtype._type_)))
        np.testing.assert_array_equal(r.evaluate(arr), got.numpy())
    got = r.evaluate_device(inputs[0])
    np.testing.assert_array_equal(got.numpy(), expected)
    out64 = wp.zeros((r.num_vertices, 3), dtype=wp.float64, device=device)
    assert r.evaluate_device(mesh.points, out=out64) is out64
    np.testing.assert_array_equal(out64.numpy(), expected.astype(np.float64))
    out_vec = wp.zeros(r.num_vertices, dtype=r.evaluator._vec, device=device)
    r.evaluate_device(inputs[0], out=out_vec)
    np.testing.assert_array_equal(out_vec.numpy(), expected)


def test_dlpack_and_cuda_interface_producers_are_read_in_place(device):
    """A DLPack producer (JAX where installed, and a minimal one) is wrapped without a copy -- the Warp view
    has the producer's address -- and refines to the numpy result; on CUDA so is a
    ``__cuda_array_interface__`` producer, which the CPU device cannot read."""
    mesh = load_mesh("cube")
    r = ws.Refiner(mesh, 2, device=device)
    host = np.ascontiguousarray(mesh.points, np.float32)
    expected = r.evaluate(host)
    source = wp.array(host, dtype=wp.float32, device=device)
    producers = [DLPackOnly(source)]
    if device == "cpu":
        producers.append(DLPackOnly(host))
        view = interop.wrap(producers[-1], r.device)
        assert view.ptr == host.ctypes.data  # zero-copy
    try:
        import jax.numpy as jnp

        if device == "cpu":
            producers.append(jnp.asarray(host))
    except ImportError:
        pass
    if wp.get_device(device).is_cuda:
        producers.append(CudaInterfaceOnly(source))
        assert interop.wrap(producers[-1], r.device).ptr == source.ptr
    for p in producers:
        np.testing.assert_array_equal(r.evaluate_device(p).numpy(), expected)
        np.testing.assert_array_equal(r.evaluate(p), expected)
    if wp.get_cuda_device_count() == 0:
        fake = types.SimpleNamespace(__cuda_array_interface__={"shape": (8, 3), "typestr": "<f4", "data": (0, False),
                                                               "version": 3})
        with pytest.raises(ws.SubdivInputError, match="CUDA"):
            r.evaluate_device(fake)


def test_device_data_is_checked(device):
    """Device data of the wrong row count, an integer dtype, or an ``out`` of the wrong shape is refused with
    SubdivInputError naming the data, before anything runs."""
    mesh = load_mesh("cube")
    r = ws.Refiner(mesh, 1, device=device)
    with pytest.raises(ws.SubdivInputError, match=r"\(8, d\)"):
        r.evaluate_device(wp.zeros(7, dtype=wp.vec3f, device=device))
    with pytest.raises(ws.SubdivInputError, match="float32 or float64"):
        r.evaluate_device(wp.zeros((8, 3), dtype=wp.int32, device=device))
    with pytest.raises(ws.SubdivInputError, match="positions"):
        r.evaluate_device(wp.zeros((8, 2), dtype=wp.float32, device=device))
    with pytest.raises(ws.SubdivInputError, match="out"):
        r.evaluate_device(mesh.points, out=wp.zeros((r.num_vertices, 2), dtype=wp.float32, device=device))
    with pytest.raises(ws.SubdivInputError, match="out"):
        r.evaluate_device(mesh.points, out=np.zeros((r.num_vertices, 3), np.float32))


@pytest.mark.parametrize("name,scheme", MESHES)
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_recorded_plans_equal_direct_launches(name, scheme, precision, device, monkeypatch):
    """The recorded plans -- one launch per kernel, or row ranges on two threads, or (where Warp captures)
    graphs; compact or expanded quad tables -- give bitwise what launching every step directly gives, for
    data of width 1, 3 and 5."""
    monkeypatch.setattr(wthreads, "MIN_ROWS", 16)  # small meshes split into ranges too
    rng = np.random.default_rng(5)
    for threads, graphs, expand in ((1, False, None), (2, False, False), (1, True, True)):
        r = ws.Refiner(load_mesh(name), 3, scheme=scheme, precision=precision, device=device, threads=threads)
        r.evaluator.graphs, r.evaluator.expand_tables = graphs, expand
        for width in (1, 3, 5):
            data = rng.standard_normal((r.base_num_vertices, width))
            got = r.evaluate(data, normal_control=False)
            assert got.shape == (r.num_vertices, width)
            np.testing.assert_array_equal(got, direct(r, data, False))
        if threads == 2 and r.num_vertices >= 32:
            plans = list(r.evaluator._plans.values())
            assert any(kind == "ranges" for p in plans for kind, _ in p.segments)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_compact_and_expanded_quad_tables_agree(precision, device):
    """Quad steps read from the compact tables (corners; CUDA's default) and from the expanded ones (endpoints,
    ring vertices and faces; the CPU's default) give bitwise the same points, for every quad test mesh, data
    of width 1, 3 and 4, and the limit points read from them."""
    rng = np.random.default_rng(11)
    for name in ("cube", "cube_creased", "grid3x3", "quad_lshape", "quad_halffan", "mixed_prism"):
        mesh = load_mesh(name)
        runs = []
        for expand in (False, True):
            r = ws.Refiner(mesh, 3, precision=precision, device=device)
            r.evaluator.expand_tables = expand
            runs.append(r)
        quads = [rec.rows for rec in runs[1].evaluator.records() if isinstance(rec.rows, ev.QuadStep)]
        assert quads and all(q.edge_ends is not None for q in quads)
        assert all(rec.rows.edge_ends is None for rec in runs[0].evaluator.records()
                   if isinstance(rec.rows, ev.QuadStep))
        for width in (1, 3, 4):
            data = rng.standard_normal((mesh.num_vertices, width))
            compact, expanded = (r.evaluate(data, normal_control=False) for r in runs)
            np.testing.assert_array_equal(compact, expanded)
        np.testing.assert_array_equal(*(r.evaluate_with_limits(mesh.points).limit_points for r in runs))


@pytest.mark.parametrize("graphs", [False, True])
def test_normal_control_through_plans(graphs, device):
    """Normal control (projection tables on every level) through recorded plans and graphs equals the direct
    launches bitwise, and differs from the result without it."""
    mesh = with_normals()
    r = ws.Refiner(mesh, 3, device=device, precision="float64")
    r.evaluator.graphs = graphs
    got = r.evaluate(mesh.points)
    np.testing.assert_array_equal(got, direct(r, mesh.points, True))
    assert np.abs(got - r.evaluate(mesh.points, normal_control=False)).max() > 1e-6


def test_replays_make_no_launch_calls(device, monkeypatch):
    """Once a call has recorded its plan (on the CPU, after the third evaluation, which moves the quad steps to
    their expanded tables), later evaluate_device calls issue no ``wp.launch`` (the recorded launches are
    replayed) and record nothing new; on CUDA the step loop is one captured graph."""
    mesh = load_mesh("cube")
    r = ws.Refiner(mesh, 2, device=device, threads=1)
    for _ in range(3):
        first = r.evaluate_device(mesh.points).numpy().copy()
    plans = dict(r.evaluator._plans)
    assert len(plans) == 1
    plan = next(iter(plans.values()))
    assert plan.num_launches == 6  # face, edge and vertex points of two steps
    if wp.get_device(device).is_cuda:
        assert plan.graphs == 1

    def no_launch(*args, **kwargs):
        raise AssertionError("wp.launch called on a replay")

    monkeypatch.setattr(wp, "launch", no_launch)
    for _ in range(3):
        np.testing.assert_array_equal(r.evaluate_device(mesh.points).numpy(), first)
    assert r.evaluator._plans == plans


def test_cpu_graph_capture_replays_the_plan():
    """With graphs on the CPU (opt-in) the plan is captured as Warp graphs where Warp can capture on the CPU,
    and gives the same results as without."""
    mesh = load_mesh("cube_creased")
    a = ws.Refiner(mesh, 3, device="cpu", threads=1)
    b = ws.Refiner(mesh, 3, device="cpu", threads=1)
    b.evaluator.graphs = True
    np.testing.assert_array_equal(a.evaluate(mesh.points), b.evaluate(mesh.points))
    plan = next(iter(b.evaluator._plans.values()))
    assert plan.graphs in (0, 1) and plan.num_launches >= 6


def reference_limits(refiner, points):
    """Limit points and normals as before the device path: masks applied by direct launches to fresh device
    arrays of the given host points (through the deeper refiner's last step where masks are read deeper)."""
    src_refiner = refiner.limit_source()[0]
    e = src_refiner.evaluator
    run = ev.Launcher(refiner.device, 1)
    pts = wp.array(np.ascontiguousarray(points, e._scalar_np), dtype=e._vec, device=refiner.device)
    if src_refiner is not refiner:
        records = e.records()
        out = wp.empty(src_refiner.num_vertices, dtype=e._vec, device=refiner.device)
        scratch = wp.empty(max(1, records[-1].num_moved), dtype=e._vec, device=refiner.device)
        ev.refine_step(records[-1], pts, out, scratch, True, run)
        pts = out
    masks = e.limit_masks()
    lp = wp.empty(masks.num_vertices, dtype=e._vec, device=refiner.device)
    ev.limit_positions(masks, pts, lp, run)
    tu = wp.empty(masks.num_tangents, dtype=e._vec, device=refiner.device)
    tv = wp.empty(masks.num_tangents, dtype=e._vec, device=refiner.device)
    ln = wp.empty(masks.num_vertices, dtype=e._vec, device=refiner.device)
    ev.limit_normals(masks, pts, tu, tv, ln, run)
    ids, normals = src_refiner._prescribed()
    ln = ln.numpy()
    ln[ids] = normals
    n = refiner.num_vertices
    return lp.numpy()[:n], ln[:n]


@pytest.mark.parametrize("name,scheme", [m for m in MESHES if m[0] != "mixed_prism"] + [("normals", "catmull-clark")])
def test_limits_without_round_trips_equal_the_old_path(name, scheme, device, monkeypatch):
    """evaluate_with_limits (one pass), and limit_points / limit_normals of evaluate_device's own result (read
    where it lies) or of host points, equal bitwise the old path (host points uploaded, masks by direct
    launches); the device result is not copied again."""
    mesh = with_normals() if name == "normals" else load_mesh(name)
    r = ws.Refiner(mesh, 2, scheme=scheme, device=device, precision="float64")
    points = r.evaluate(mesh.points)
    lp, ln = reference_limits(r, points)
    res = r.evaluate_with_limits(mesh.points)
    np.testing.assert_array_equal(res.points, points)
    np.testing.assert_array_equal(res.limit_points, lp)
    np.testing.assert_array_equal(res.limit_normals, ln)
    np.testing.assert_array_equal(r.limit_points(points), lp)
    np.testing.assert_array_equal(r.limit_normals(points), ln)
    on = r.evaluate_with_limits(mesh.points, on_device=True)
    assert all(isinstance(a, wp.array) for a in (on.points, on.limit_points, on.limit_normals))
    np.testing.assert_array_equal(on.limit_normals.numpy(), ln)
    if not r.limit_reads_deeper():
        loads = []
        original = ev.Evaluator._load
        monkeypatch.setattr(ev.Evaluator, "_load", lambda self, *a: (loads.append(a[0]), original(self, *a)))
        d = r.evaluate_device(mesh.points)
        np.testing.assert_array_equal(r.limit_points(d, on_device=True).numpy(), lp)
        np.testing.assert_array_equal(r.limit_normals(d), ln)
        assert loads == [0]  # only the control points went in: the limits read the device result in place


def test_limit_values_of_any_width_in_one_pass(device):
    """evaluate_with_limits of (n, d) data gives evaluate's points and limit_points' values per column, without
    normals; a (n,) column keeps its shape."""
    r = ws.Refiner(load_mesh("quad_lshape"), 2, device=device, precision="float64")
    data = np.random.default_rng(2).standard_normal((r.base_num_vertices, 4))
    res = r.evaluate_with_limits(data, limit_normals=False)
    np.testing.assert_array_equal(res.points, r.evaluate(data))
    np.testing.assert_array_equal(res.limit_points, r.limit_points(res.points))
    assert res.limit_normals is None
    one = r.evaluate_with_limits(data[:, 1], limit_normals=False)
    assert one.points.shape == (r.num_vertices,)
    np.testing.assert_array_equal(one.limit_points, res.limit_points[:, 1])
    with pytest.raises(ws.SubdivInputError):
        r.evaluate_with_limits(data)  # normals need positions


def test_32_bit_limits_are_computed_and_refused():
    """The size checks compute the entries first and refuse what 32-bit offsets cannot hold: limit tables of
    a level of 240M Catmull-Clark vertices, a level buffer of 2^31 values; smaller ones pass."""
    with pytest.raises(estimate.MemoryGuardError, match="limit masks of level 7"):
        estimate.check_limit_tables(240_000_000, 960_000_000, "catmull-clark", 7)
    estimate.check_limit_tables(200_000_000, 800_000_000, "catmull-clark", 7)
    assert estimate.limit_entries(10, 40, "catmull-clark") == 90
    assert estimate.limit_entries(10, 60, "loop") == 70
    with pytest.raises(estimate.MemoryGuardError) as err:
        estimate.check_buffer_elements(2**31, "data of width 8")
    assert err.value.option == "data" and err.value.value == 2**31
    estimate.check_buffer_elements(2**31 - 1, "data of width 8")


def test_32_bit_refusals_come_before_allocating(monkeypatch):
    """With the 32-bit limit lowered, a refiner refuses limit masks before building them and data too wide
    for its level buffers before allocating them (SubdivInputError, nothing allocated); the exact check at
    the table build refuses too."""
    mesh = load_mesh("cube")
    r = ws.Refiner(mesh, 2, device="cpu")
    monkeypatch.setattr(estimate, "INT32_MAX", 200)
    built = []
    monkeypatch.setattr(r.hierarchy, "limit_tables", lambda: built.append(1))
    with pytest.raises(ws.SubdivInputError, match="limit masks of level 2"):
        r.limit_points(np.zeros((r.num_vertices, 3)))
    assert not built
    monkeypatch.setattr(wp, "empty", lambda *a, **k: pytest.fail("allocated"))
    with pytest.raises(ws.SubdivInputError, match="width 3"):
        r.evaluate(mesh.points)
    monkeypatch.undo()
    monkeypatch.setattr(estimate, "INT32_MAX", 100)
    from warp_subdiv.tables import projections
    from warp_subdiv.topology import refinement as topology

    level = r.hierarchy.final
    if level.edge_verts is None:  # built faces-only: the full last level
        level = topology.refine_level(r.hierarchy.penultimate)
    with pytest.raises(ws.SubdivInputError, match="limit mask table"):
        projections.limit_tables(level, np.zeros(level.num_sectors), "loop")


def test_device_memory_guard(monkeypatch):
    """On CUDA the guard compares the predicted device bytes with Warp's free memory and refuses before any
    work (MemoryGuardError, option "device"); the CPU is left to the host guard. A refiner and a wider
    evaluation are refused when the device reports too little free memory."""
    gpu = types.SimpleNamespace(is_cuda=True, free_memory=2**30, total_memory=2**31, alias="cuda:0")
    with pytest.raises(estimate.MemoryGuardError, match="cuda:0") as err:
        estimate.check_device_memory(2**30, gpu, "refining to level 6")
    assert err.value.option == "device"
    estimate.check_device_memory(2**29, gpu, "refining to level 6")
    estimate.check_device_memory(2**60, wp.get_device("cpu"), "anything")
    mesh = load_mesh("cube")
    counts = estimate.level_counts(8, mesh.face_vertex_counts, 12, 5, "catmull-clark")
    items = estimate.device_bytes(counts, "catmull-clark", limit=True)
    assert items["level buffers"] == 12 * sum(c.vertices for c in counts)
    assert set(items) == {"step tables", "level buffers", "limit masks", "limit outputs"}
    monkeypatch.setattr(estimate, "device_free_memory", lambda device: (estimate.DEVICE_RESERVE + 1000, 2**40))
    with pytest.raises(estimate.MemoryGuardError, match="memory on cpu"):
        ws.Refiner(mesh, 5, device="cpu")
    monkeypatch.setattr(estimate, "device_free_memory", lambda device: None)
    r = ws.Refiner(mesh, 3, device="cpu")
    r.evaluate(mesh.points)
    monkeypatch.setattr(estimate, "device_free_memory", lambda device: (estimate.DEVICE_RESERVE + 1000, 2**40))
    with pytest.raises(estimate.MemoryGuardError, match="width 7"):
        r.evaluate(np.zeros((8, 7)))


def test_step_table_estimate_matches_the_tables():
    """The device estimate of the step tables is never below the tables a refiner keeps and at most 25% above
    them (closed and open meshes of both schemes)."""
    for name, scheme in (("cube", "catmull-clark"), ("grid3x3", "catmull-clark"), ("icosahedron", "loop"),
                         ("tri_grid3x3", "loop")):
        mesh = load_mesh(name)
        r = ws.Refiner(mesh, 4, scheme=scheme, device="cpu")
        counts = estimate.level_counts(mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, 4,
                                       "loop" if scheme == "loop" else "catmull-clark")
        predicted = estimate.device_bytes(counts, scheme)["step tables"]
        assert r.table_bytes() <= predicted <= 1.25 * r.table_bytes(), (name, predicted, r.table_bytes())


def test_tables_store_nothing_index_arithmetic_gives():
    """Quad steps keep an edge as its two corners and a vertex ring as its corners (no ring faces, no edge
    endpoints), Loop steps no corner table, closed smooth levels no row masks; table bytes per output vertex
    of level 3: below 18 for Catmull-Clark (29 before), below 26 for Loop (35 before)."""
    cube = ws.Refiner(load_mesh("cube"), 3, device="cpu")
    quad = cube.steps[-1]
    assert quad.edge_neighbours.shape[1] == 2 and not hasattr(quad, "ring_faces")
    assert quad.vertex_regular.size == 0 and quad.edge_regular.size == 0
    assert cube.table_bytes() / cube.num_vertices < 18
    ico = ws.Refiner(load_mesh("icosahedron"), 3, scheme="loop", device="cpu")
    assert ico.steps[-1].corner_vert.size == 0
    assert ico.table_bytes() / ico.num_vertices < 26
    creased = ws.Refiner(load_mesh("cube_creased"), 2, device="cpu")
    assert creased.steps[-1].edge_regular.size > 0  # crease edges are explicit rows


def test_cpu_tables_expanded_from_the_third_evaluation(monkeypatch):
    """On the CPU with ``expand_tables`` None, the first two evaluations read the compact quad tables (expanding
    them would cost more than it saves for a mesh evaluated once or twice) and the third and later the expanded
    ones of steps with EXPAND_MIN_ROWS rows or more (smaller steps keep the compact ones: they evaluate as fast);
    every result is bitwise the same, and explicit True or False keeps its tables throughout."""
    from warp_subdiv.evaluator import records

    mesh = load_mesh("cube")
    expected = ws.Refiner(mesh, 3, device="cpu", threads=1).evaluate(mesh.points)

    def expansions(min_rows):
        monkeypatch.setattr(records, "EXPAND_MIN_ROWS", min_rows)
        r = ws.Refiner(mesh, 3, device="cpu", threads=1)
        seen = []
        for _ in range(4):
            np.testing.assert_array_equal(r.evaluate(mesh.points), expected)
            seen.append([getattr(rec.rows, "edge_ends", None) is not None for rec in r.evaluator.records()])
        return seen

    steps = ws.Refiner(mesh, 3, device="cpu").hierarchy.steps
    assert expansions(0) == [[False] * 3, [False] * 3, [True] * 3, [True] * 3]
    last_only = steps[-1].num_rows  # only the last step is that large
    assert expansions(last_only) == [[False] * 3, [False] * 3, [False, False, True], [False, False, True]]
    assert expansions(last_only + 1) == [[False] * 3] * 4
    for fixed in (True, False):
        r = ws.Refiner(mesh, 3, device="cpu", threads=1)
        r.evaluator.expand_tables = fixed
        for _ in range(4):
            np.testing.assert_array_equal(r.evaluate(mesh.points), expected)
            assert (getattr(r.evaluator.records()[-1].rows, "edge_ends", None) is not None) == fixed
