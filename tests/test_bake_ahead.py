"""The USD bake's workers (warp_subdiv.usd.ahead.Ahead): meshes refined ahead of the writer on worker threads give
the very layer the one-thread bake writes (every value bitwise, the same text, warnings and errors), the workers
are really used, stop with the bake, and fit the memory limit."""
import threading

import numpy as np
import pytest
from test_batch import _props_scene, _same_layers

import warp_subdiv.usd as usd
from warp_subdiv.usd import ahead
from warp_subdiv.runtime import threads
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.runtime.estimate import total_bytes


@pytest.fixture(scope="module")
def props_scene(tmp_path_factory):
    return _props_scene(tmp_path_factory.mktemp("ahead") / "props.usda", count=12, frames=3)


@pytest.fixture
def every_mesh_ahead(monkeypatch):
    """Every mesh big enough to go ahead; returns the list of (mesh index, worker thread name, context or None,
    results computed ahead) of the workers' jobs."""
    monkeypatch.setattr(ahead, "AHEAD_VERTICES", 1)
    taken = []
    original = ahead.Ahead._refine

    def spied(self, i):
        ctx = original(self, i)
        taken.append((i, threading.current_thread().name, ctx, 0 if ctx is None else len(ctx._ahead)))
        return ctx

    monkeypatch.setattr(ahead.Ahead, "_refine", spied)
    return taken


def _bake(scene, out, threads_, **run):
    threads.set_default_threads(threads_)
    try:
        return usd.refine_usd(scene, out, run.pop("levels", 2), device="cpu", **run)
    finally:
        threads.set_default_threads(None)


@pytest.mark.parametrize("run", [
    dict(),
    dict(limit=True, normals=True, vertex_order="opensubdiv"),
    dict(normals=True, vertex_order="compact", batch=False),
    dict(levels=1, frames=(2, 3), rules="opensubdiv", batch=False),
    dict(samples_only=True, batch=False),
], ids=["default", "limit-normals-osd", "compact-normals-unbatched", "L1-frames-opensubdiv", "samples-only"])
def test_workers_write_the_layer_one_thread_writes(props_scene, tmp_path, every_mesh_ahead, run):
    """With two workers refining ahead, the layer equals the one-thread bake's: every attribute of every prim at
    every time bitwise, the same text, warnings and reports; the meshes went ahead (their contexts built on
    the workers' threads, with results computed ahead, every one of them taken by the writer) and the bake
    reports the writer's waiting time."""
    on = _bake(props_scene, str(tmp_path / "on.usda"), 2, **run)
    went = [(i, name) for i, name, ctx, _ in every_mesh_ahead if ctx is not None]
    assert all(ctx._ahead == {} for _, _, ctx, _ in every_mesh_ahead if ctx is not None)  # every one used
    assert sum(held for _, _, ctx, held in every_mesh_ahead if ctx is not None) >= len(went)
    assert len(went) >= (2 if run.get("batch", True) else 8), every_mesh_ahead
    assert all(name.startswith("warp-subdiv-bake") for _, name in went)
    assert "waiting" in on.phases
    del every_mesh_ahead[:]
    off = _bake(props_scene, str(tmp_path / "off.usda"), 1, **run)
    assert every_mesh_ahead == []  # one thread: no workers
    _same_layers(on.output, off.output)
    assert on.warnings == off.warnings
    assert [(r.path, r.faces_out, r.vertices_out) for r in on.reports] == \
        [(r.path, r.faces_out, r.vertices_out) for r in off.reports]


def _scene_with_bad_inputs(path, bad):
    """Four grids with face-varying UVs; the third has a malformed UV primvar ("uv": a value count that does
    not fit) or points that are not finite at time 2 ("points")."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    n = 6
    xs, ys = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0))
    pts = np.stack([xs.ravel(), ys.ravel(), 0.1 * np.sin(xs.ravel() * ys.ravel())], axis=1)
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    quads = np.stack([q, q + 1, q + n + 2, q + n + 1], axis=1).ravel()
    for k in range(4):
        m = UsdGeom.Mesh.Define(stage, f"/World/Grid_{k}")
        m.CreateSubdivisionSchemeAttr("catmullClark")
        m.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(q)))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in quads]))
        attr = m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy((pts + 10 * k).astype(np.float32)))
        for t in (1.0, 2.0):
            moved = pts + 10 * k + 0.01 * t
            if bad == "points" and k == 2 and t == 2.0:
                moved[3, 1] = np.nan
            attr.Set(Vt.Vec3fArray.FromNumpy(moved.astype(np.float32)), t)
        st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                  UsdGeom.Tokens.faceVarying)
        corners = len(quads) - (5 if bad == "uv" and k == 2 else 0)
        st.Set(Vt.Vec2fArray.FromNumpy(np.random.default_rng(k).random((corners, 2)).astype(np.float32)))
    stage.GetRootLayer().Save()
    return str(path)


@pytest.mark.parametrize("bad", ["uv", "points"])
def test_workers_leave_input_errors_to_the_writer(tmp_path, every_mesh_ahead, bad):
    """A mesh whose inputs fail among meshes refined ahead: the bake with workers warns (a dropped primvar) or
    raises (points that are not finite) exactly as the one-thread bake does, and no worker thread outlives it."""
    scene = _scene_with_bad_inputs(tmp_path / "bad.usda", bad)
    outcomes = []
    for n in (2, 1):
        try:
            result = _bake(scene, str(tmp_path / f"out{n}.usda"), n, batch=False)
            outcomes.append(("ok", result.warnings))
        except SubdivInputError as exc:
            outcomes.append(("error", str(exc)))
        assert not [t for t in threading.enumerate() if t.name.startswith("warp-subdiv-bake")]
    assert outcomes[0] == outcomes[1]
    assert outcomes[0][0] == ("ok" if bad == "uv" else "error")
    if bad == "uv":
        assert any("primvars:st" in w for w in outcomes[0][1]), outcomes
        _same_layers(str(tmp_path / "out2.usda"), str(tmp_path / "out1.usda"))
    assert any(ctx is not None for _, _, ctx, _ in every_mesh_ahead)


def test_workers_fit_the_memory_limit(props_scene, tmp_path, every_mesh_ahead):
    """Meshes held at once are counted in the prediction: with max_memory between the one-at-a-time prediction
    and the prediction of two at once, no mesh goes ahead and the result predicts one at a time; with room for
    three, the result predicts three (the writer's and two workers')."""
    p = usd.plan(props_scene, 2, device="cpu")
    eligible = [e for sp, e in zip(p.prims, p.estimates) if not sp.topologies]
    assert len(eligible) >= 3
    one, two, three = (total_bytes(p.estimates, k) for k in (1, 2, 3))
    assert one < two < three
    tight = _bake(props_scene, str(tmp_path / "tight.usda"), 2, batch=False, max_memory=(one + two) // 2)
    assert every_mesh_ahead == [] and tight.predicted_bytes == one
    roomy = _bake(props_scene, str(tmp_path / "roomy.usda"), 2, batch=False, max_memory=three)
    assert every_mesh_ahead and roomy.predicted_bytes == three
    _same_layers(tight.output, roomy.output)


def test_vt_arrays_from_numpy_without_the_gil():
    """The writer's conversion to Vt arrays (one memmove into a new array's storage, the GIL released) gives
    the very array FromNumpy gives, of every numeric class the bake writes and more; input of another layout
    (float64 rows for float3 points) and empty input go through FromNumpy."""
    from pxr import Vt

    from warp_subdiv.io.usd_write import _exports_storage, from_numpy

    rng = np.random.default_rng(3)
    cases = [(Vt.IntArray, rng.integers(-9, 9, 1000).astype(np.int32)),
             (Vt.Vec3fArray, rng.random((300, 3)).astype(np.float32)),
             (Vt.Vec2fArray, rng.random((300, 2)).astype(np.float32)),
             (Vt.FloatArray, np.array([np.nan, np.inf, -0.0, 1.5], np.float32)),
             (Vt.Vec3dArray, rng.random((20, 3))), (Vt.DoubleArray, rng.random(7)),
             (Vt.HalfArray, rng.random(7).astype(np.float16)), (Vt.BoolArray, rng.random(9) > 0.5),
             (Vt.Vec4fArray, rng.random((5, 4)).astype(np.float32)), (Vt.Matrix4dArray, rng.random((3, 4, 4))),
             (Vt.Vec3fArray, rng.random((10, 3))), (Vt.IntArray, np.zeros(0, np.int32))]
    for cls, values in cases:
        got, expected = from_numpy(cls, values), cls.FromNumpy(values)
        assert type(got) is cls and got == expected or np.isnan(values).any(), cls
        assert np.asarray(got).tobytes() == np.asarray(expected).tobytes(), cls
    assert _exports_storage(Vt.IntArray) and _exports_storage(Vt.Vec3fArray)


def test_cli_reports_the_writers_waiting(props_scene, tmp_path, every_mesh_ahead, capsys):
    """`warp-subdiv refine --threads 2` with meshes refined ahead: its phase line gives the writer's waiting
    and says that the workers' time overlaps the writer's; with --threads 1 neither appears."""
    from warp_subdiv.cli import main

    try:
        assert main(["refine", props_scene, "-o", str(tmp_path / "two.usda"), "--levels", "2", "--threads", "2"]) == 0
        two = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("phases:")]
        assert main(["refine", props_scene, "-o", str(tmp_path / "one.usda"), "--levels", "2", "--threads", "1"]) == 0
        one = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("phases:")]
    finally:
        threads.set_default_threads(None)
    assert len(two) == 1 and "waiting" in two[0] and "overlap the writer" in two[0], two
    assert len(one) == 1 and "waiting" not in one[0] and "overlap" not in one[0], one
    assert any(ctx is not None for _, _, ctx, _ in every_mesh_ahead)


def test_small_meshes_go_ahead_within_the_predicted_working_sets(props_scene, tmp_path, every_mesh_ahead,
                                                                 monkeypatch):
    """Beyond the count of meshes in flight (depth), more small meshes go ahead while the working sets held at
    once (the writer's mesh, those in flight or refined and not taken) stay within the largest ``concurrent``
    working sets that the memory prediction counts; the layer is still the one-thread bake's."""
    seen = []
    original = ahead.Ahead._fill

    def spied(self, i):
        original(self, i)
        working = [e.working_bytes for e in self.bake.plan.estimates]
        held = sum(working[j] for j in self.futures) + (working[self.writing] if self.writing is not None else 0)
        budget = sum(sorted(working, reverse=True)[:self.concurrent])
        assert self.budget == budget
        assert len(self.futures) <= self.depth or held <= budget
        seen.append(len(self.futures))

    monkeypatch.setattr(ahead.Ahead, "_fill", spied)
    on = _bake(props_scene, str(tmp_path / "on.usda"), 2, batch=False)
    assert seen and max(seen) > 2  # more than the two workers' depth were in flight at some point
    off = _bake(props_scene, str(tmp_path / "off.usda"), 1, batch=False)
    _same_layers(on.output, off.output)
    assert on.predicted_bytes == total_bytes(usd.plan(props_scene, 2, device="cpu").estimates, 3)
