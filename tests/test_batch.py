"""Batches of small meshes (warp_subdiv.batch): the union's rows of every member equal the member's own refinement
bitwise (points, limit points, normals, topology) on varied members, schemes and rule sets; members that would
not are refused; the USD writer's batching writes the very layer the unbatched writer writes."""
import itertools
import os

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh
from warp_subdiv.batch import MeshBatch, batch_key, union_mesh
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.refiner import Refiner

NAMES = ["cube", "cube_creased", "grid3x3", "icosahedron", "mixed_prism", "octahedron", "quad_halffan",
         "quad_lshape", "tri_grid3x3", "tri_halffan", "tri_hexfan"]


def tagged_members():
    """Members with every tag a Mesh carries: semi-sharp creases and corners, holes, a concave corner,
    prescribed normals, an n-gon boundary."""
    grid = load_mesh("grid3x3")
    out = [
        ws.Mesh(grid.points, grid.face_vertex_counts, grid.face_vertex_indices, creases=[[5, 6], [6, 10]],
                crease_sharpness=[1.5, 2.0], corners=[0], corner_sharpness=[0.5], holes=[4]),
        ws.Mesh(grid.points, grid.face_vertex_counts, grid.face_vertex_indices, creases=[[5, 6], [5, 9]],
                corners=[5], concave=[[5, 4]]),
    ]
    cube = load_mesh("cube")
    up = np.array([[0.0, 0.0, 1.0]])
    top = int(np.argmax(cube.points[:, 2]))
    out.append(ws.Mesh(cube.points, cube.face_vertex_counts, cube.face_vertex_indices,
                       normals=([top], up / np.linalg.norm(up)), creases=[[0, 1]], crease_sharpness=[3.0]))
    pentagon = np.array([[np.cos(a), np.sin(a), 0.1 * np.sin(3 * a)] for a in np.linspace(0, 2 * np.pi, 6)[:-1]])
    out.append(ws.Mesh(pentagon, [5], [0, 1, 2, 3, 4]))
    return out


def members():
    return [load_mesh(n) for n in NAMES] + tagged_members()


def jitter(mesh, seed):
    rng = np.random.default_rng(seed)
    return mesh.points + rng.normal(scale=0.02, size=mesh.points.shape)


CASES = list(itertools.product(["catmull-clark", "loop"], ["opensubdiv", "piecewise-smooth"], [0, 1, 2, 3]))


@pytest.mark.parametrize("scheme,rules,levels", CASES)
def test_members_refine_bitwise_as_alone(scheme, rules, levels, device):
    """Members grouped by batch_key, each group twice over (repeated members too), refined as one union: every
    member's points, limit points and limit normals equal its own refiner's bitwise (on the CPU, and on CUDA
    where present), and its topology (in its own vertex numbering) equals its own refiner's topology()."""
    options = ws.Options(scheme=scheme, rules=rules)
    own = [(m, Refiner(m, levels, options=options, device=device)) for m in members()
           if rules == "piecewise-smooth" or len(m.normal_vertices) == 0]  # prescribed normals: piecewise-smooth
    groups: dict = {}
    for m, r in own:
        groups.setdefault(batch_key(r), []).append((m, r))
    assert len(groups) >= 2 or scheme == "loop"  # the cases do split into kinds
    for key, group in groups.items():
        group = group + group[::-1]
        batch = MeshBatch([m for m, _ in group], levels, options=options, device=device)
        data = [jitter(m, i) for i, (m, _) in enumerate(group)]
        refined = batch.evaluate(data)
        uv = batch.evaluate([d[:, :2] for d in data], normal_control=False)  # any width
        limits = batch.evaluate_with_limits(data) if levels else [None] * len(group)
        for i, (m, r) in enumerate(group):
            assert np.array_equal(refined[i], r.evaluate(data[i])), (key, i)
            assert np.array_equal(uv[i], r.evaluate(data[i][:, :2], normal_control=False)), (key, i)
            counts, indices = r.topology()
            got_counts, got_indices = batch.topology(i)
            assert np.array_equal(counts, got_counts) and np.array_equal(indices, got_indices), (key, i)
            assert batch.num_vertices(i) == r.num_vertices
            if limits[i] is not None:
                alone = r.evaluate_with_limits(data[i])
                for name in ("points", "limit_points", "limit_normals"):
                    assert np.array_equal(getattr(limits[i], name), getattr(alone, name)), (key, i, name)


def test_rows_follow_the_blocks():
    """Level 1 of two quads-only members: each member's rows are its vertex children, then its face children,
    then its edge children, each a range of its block (the rule batch.py follows); a member's rows are not one
    range."""
    cube, grid = load_mesh("cube"), load_mesh("grid3x3")
    batch = MeshBatch([cube, grid], 1, scheme="catmull-clark", device="cpu")
    V, F, E = 8 + 16, 6 + 9, 12 + 24
    expected_cube = np.concatenate([np.arange(8), V + np.arange(6), V + F + np.arange(12)])
    expected_grid = np.concatenate([8 + np.arange(16), V + 6 + np.arange(9), V + F + 12 + np.arange(24)])
    assert np.array_equal(batch.rows(0), expected_cube)
    assert np.array_equal(batch.rows(1), expected_grid)
    assert batch.refiner.num_vertices == V + F + E


def test_union_offsets_every_tag():
    """union_mesh offsets vertex ids of creases, corners, concave tags and prescribed normals, and face ids of
    holes, and keeps sharpness values and normals."""
    a, b, c, _ = tagged_members()
    union, voff, foff = union_mesh([a, b, c])
    assert list(voff) == [0, 16, 32, 40] and list(foff) == [0, 9, 18, 24]
    assert np.array_equal(union.creases, np.concatenate([a.creases, b.creases + 16, c.creases + 32]))
    assert np.array_equal(union.crease_sharpness, [1.5, 2.0, 10.0, 10.0, 3.0])
    assert np.array_equal(union.corners, [0, 21])
    assert np.array_equal(union.corner_sharpness, [0.5, 10.0])
    assert np.array_equal(union.concave, [[21, 20]])
    assert np.array_equal(union.normal_vertices, c.normal_vertices + 32)
    assert np.array_equal(union.normal_vectors, c.normal_vectors)
    assert np.array_equal(union.holes, [4])
    assert np.array_equal(union.face_vertex_indices[-24:], c.face_vertex_indices + 32)


def test_members_that_refine_otherwise_are_refused():
    """A quads-only member and a mixed one under Catmull-Clark (index tables against stencils) differ in the
    last bits of the union (checked here, so the key is needed) and are refused by the check."""
    cube, prism = load_mesh("cube"), load_mesh("mixed_prism")
    options = ws.Options(scheme="catmull-clark", rules="opensubdiv")
    mixed = MeshBatch([cube, prism], 2, options=options, device="cpu", check=False)
    got = mixed.evaluate([cube.points, prism.points])[0]
    alone = Refiner(cube, 2, options=options, device="cpu").evaluate(cube.points)
    assert not np.array_equal(got, alone)
    np.testing.assert_allclose(got, alone, atol=1e-6)
    with pytest.raises(SubdivInputError, match="batch member 1 does not refine like member 0"):
        MeshBatch([cube, prism], 2, options=options, device="cpu")


def test_member_indices_are_sequence_indices():
    """rows, num_vertices and topology take a member index as a Python sequence does: -1 is the last member
    (it used to give -52 vertices and empty rows and faces), out of range is an IndexError naming the index and
    the members, a non-integer a TypeError."""
    cube, grid = load_mesh("cube"), load_mesh("grid3x3")
    batch = MeshBatch([grid, cube], 1, scheme="catmull-clark", device="cpu")
    for i in (-2, -1):
        j = i + 2
        assert batch.num_vertices(i) == batch.num_vertices(j)
        assert np.array_equal(batch.rows(i), batch.rows(j))
        assert all(np.array_equal(a, b) for a, b in zip(batch.topology(i), batch.topology(j)))
    assert batch.num_vertices(-1) == Refiner(cube, 1, scheme="catmull-clark", device="cpu").num_vertices
    for method in (batch.rows, batch.num_vertices, batch.topology):
        for bad in (2, -3, 100):
            with pytest.raises(IndexError, match=f"batch member {bad} .*2 members"):
                method(bad)
        for bad in (1.0, True, "1"):
            with pytest.raises(TypeError, match="member index must be an integer"):
                method(bad)
    assert batch.num_vertices(np.int64(-1)) == batch.num_vertices(1)


def test_member_data_from_any_iterable_and_of_one_width():
    """Member data may come as any iterable (a generator is read once: two arrays used to be reported as "got 1");
    members of different widths are refused naming the member and both widths (it used to fail inside numpy)."""
    cube = load_mesh("cube")
    batch = MeshBatch([cube, cube], 1, device="cpu")
    want = batch.evaluate([cube.points, 2 * cube.points])
    got = batch.evaluate(p for p in [cube.points, 2 * cube.points])
    assert all(np.array_equal(a, b) for a, b in zip(want, got))
    res = batch.evaluate_with_limits(iter([cube.points, 2 * cube.points]))
    assert np.array_equal(res[1].points, want[1])
    with pytest.raises(SubdivInputError, match="takes 2 arrays, got 3"):
        batch.evaluate(p for p in [cube.points] * 3)
    with pytest.raises(SubdivInputError, match="member 1 has data of width 2, member 0 of width 3") as err:
        batch.evaluate([cube.points, cube.points[:, :2]])
    assert err.value.index == 1 and err.value.element == "data"
    ones = batch.evaluate([cube.points[:, 0], cube.points[:, :1]])  # (n,) and (n, 1): one column each
    assert np.array_equal(ones[0], ones[1])

def test_bad_input():
    """Empty batches, non-meshes, per-vertex flatness, wrong data counts and shapes are SubdivInputError."""
    cube = load_mesh("cube")
    with pytest.raises(SubdivInputError, match="at least one mesh"):
        MeshBatch([], 1)
    with pytest.raises(SubdivInputError, match="member 1 must be a warp_subdiv.Mesh"):
        MeshBatch([cube, "cube"], 1)
    with pytest.raises(SubdivInputError, match="per-vertex flatness"):
        MeshBatch([cube], 1, flatness=np.zeros(8))
    with pytest.raises(SubdivInputError, match="levels must be an integer"):
        MeshBatch([cube], -1)
    batch = MeshBatch([cube, cube], 1, device="cpu")
    with pytest.raises(SubdivInputError, match="takes 2 arrays, got 1"):
        batch.evaluate([cube.points])
    with pytest.raises(SubdivInputError, match="member 1 has 8 vertices"):
        batch.evaluate([cube.points, cube.points[:5]])
    with pytest.raises(SubdivInputError, match="refined rows"):
        batch.split(np.zeros((3, 3)))
    with pytest.raises(SubdivInputError, match="not finite"):
        batch.evaluate([cube.points, np.full((8, 3), np.nan)])


# ------------------------------------------------------------------------------------------------ USD writer
def _props_scene(path, count=30, frames=4):
    """A USD scene of ``count`` small animated props of mixed kinds: cubes, creased cubes, triangle meshes
    (Loop), n-gon prisms, grids with a hole, left-handed ones, opensubdiv rules, a bilinear one, one with a
    vertex primvar, UVs and a face subset, one with velocities, a bigger grid (not batched), one whose
    topology changes over time, and a few with other time samples."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    shapes = {n: load_mesh(n) for n in ("cube", "cube_creased", "icosahedron", "mixed_prism", "tri_hexfan",
                                        "grid3x3", "quad_lshape")}
    rng = np.random.default_rng(7)

    def define(name, mesh, *, scheme="catmullClark", times=range(1, frames + 1), offset=0.0):
        m = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        m.CreateSubdivisionSchemeAttr(scheme)
        m.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in mesh.face_vertex_counts]))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray([int(c) for c in mesh.face_vertex_indices]))
        pts = m.CreatePointsAttr()
        pts.Set(Vt.Vec3fArray.FromNumpy(mesh.points.astype(np.float32) + offset))
        for t in times:
            moved = mesh.points + offset + rng.normal(scale=0.05, size=mesh.points.shape)
            pts.Set(Vt.Vec3fArray.FromNumpy(moved.astype(np.float32)), float(t))
        if len(mesh.creases):
            m.CreateCreaseIndicesAttr(Vt.IntArray([int(v) for v in mesh.creases.reshape(-1)]))
            m.CreateCreaseLengthsAttr(Vt.IntArray([2] * len(mesh.creases)))
            m.CreateCreaseSharpnessesAttr(Vt.FloatArray([float(s) for s in mesh.crease_sharpness]))
        return m

    kinds = ["cube", "cube_creased", "icosahedron", "mixed_prism", "tri_hexfan", "grid3x3", "quad_lshape"]
    for i in range(count):
        kind = kinds[i % len(kinds)]
        scheme = "loop" if kind in ("icosahedron", "tri_hexfan") else "catmullClark"
        m = define(f"Prop_{i}", shapes[kind], scheme=scheme, offset=float(i))
        if i % 5 == 3:
            m.CreateOrientationAttr("leftHanded")
        if i % 6 == 4:
            m.GetPrim().CreateAttribute("subdiv:rules", Sdf.ValueTypeNames.Token, custom=True).Set("opensubdiv")
        if kind == "grid3x3" and i % 2:
            m.CreateHoleIndicesAttr(Vt.IntArray([4]))
        if i == 2:
            n = len(shapes[kind].points)
            pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("w", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
            pv.Set(Vt.FloatArray([float(x) for x in range(n)]))
            st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                      UsdGeom.Tokens.faceVarying)
            corners = len(shapes[kind].face_vertex_indices)
            st.Set(Vt.Vec2fArray.FromNumpy(rng.random((corners, 2)).astype(np.float32)))
            UsdGeom.Subset.CreateGeomSubset(m, "top", UsdGeom.Tokens.face, Vt.IntArray([0, 2]))
        if i == 5:
            vel = m.CreateVelocitiesAttr()
            for t in range(1, frames + 1):
                vel.Set(Vt.Vec3fArray.FromNumpy(rng.normal(size=(len(shapes[kind].points), 3)).astype(np.float32)),
                        float(t))
    define("Bilinear", shapes["cube"], scheme="bilinear")
    define("FewSamples", shapes["cube"], times=[1, 3])
    define("FewSamplesToo", shapes["cube_creased"], times=[1, 3])
    define("Static", shapes["cube"], times=[])
    define("StaticToo", shapes["icosahedron"], scheme="loop", times=[])
    xs, ys = np.meshgrid(np.arange(70.0), np.arange(70.0))
    big_pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    q = (np.arange(69)[:, None] * 70 + np.arange(69)[None, :]).ravel()
    big = ws.Mesh(big_pts, np.full(len(q), 4), np.stack([q, q + 1, q + 71, q + 70], axis=1).ravel())
    define("Big", big)
    varying = define("Varying", shapes["cube"])
    varying.GetFaceVertexIndicesAttr().Set(Vt.IntArray([int(c) for c in shapes["cube"].face_vertex_indices[::-1]]),
                                           3.0)
    stage.GetRootLayer().Save()
    return str(path)


def _every_value(layer_path):
    """{(spec path, time or None): value} of every attribute of a layer, time samples included."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(layer_path)
    out = {}

    def visit(path):
        spec = layer.GetObjectAtPath(path)
        if isinstance(spec, Sdf.AttributeSpec):
            out[(str(path), None)] = spec.default
            for t in layer.ListTimeSamplesForPath(path):
                out[(str(path), t)] = layer.QueryTimeSample(path, t)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out, layer.ExportToString()


def _same_layers(a, b):
    values_a, text_a = _every_value(a)
    values_b, text_b = _every_value(b)
    assert values_a.keys() == values_b.keys()
    for key, value in values_a.items():
        other = values_b[key]
        if hasattr(value, "__len__") and not isinstance(value, str):
            x, y = np.asarray(value), np.asarray(other)
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), key
        else:
            assert value == other, key
    assert text_a == text_b


@pytest.fixture(scope="module")
def props_scene(tmp_path_factory):
    return _props_scene(tmp_path_factory.mktemp("props") / "props.usda")


def _evaluations(monkeypatch):
    """Count calls of Refiner.evaluate (through _evaluate_rows, which OrderedRefiner calls directly) and
    evaluate_with_limits (the unions' and the prims' own)."""
    calls = []
    for name in ("_evaluate_rows", "evaluate_with_limits"):
        original = getattr(Refiner, name)

        def counted(self, *args, _original=original, **kwargs):
            calls.append(self.num_vertices)
            return _original(self, *args, **kwargs)

        monkeypatch.setattr(Refiner, name, counted)
    return calls


def _counting(monkeypatch):
    """Count the MeshBatch unions the writer builds and their members."""
    from warp_subdiv.usd import batching

    seen = []

    class Counting(MeshBatch):
        def __init__(self, meshes, *args, **kwargs):
            seen.append(len(meshes))
            super().__init__(meshes, *args, **kwargs)

    monkeypatch.setattr(batching, "MeshBatch", Counting)
    return seen


@pytest.mark.parametrize("run", [
    dict(),
    dict(limit=True, normals=True),
    dict(normals=True, vertex_order="compact"),
    dict(levels=1, frames=(2, 3), rules="opensubdiv"),
], ids=["points", "limit-normals", "compact-normals", "L1-frames-opensubdiv"])
def test_usd_batched_layer_is_identical(props_scene, tmp_path, monkeypatch, run):
    """The writer with batching (the default) and with batch=False writes the same layer: every attribute of
    every prim at every time bitwise, and the same text; small meshes were batched (unions built, and their
    results used: far fewer evaluator calls), the big, bilinear and time-varying ones were not."""
    from warp_subdiv.usd.refine import refine_usd

    run = dict(run)
    levels = run.pop("levels", 2)
    seen = _counting(monkeypatch)
    calls = _evaluations(monkeypatch)
    on = refine_usd(props_scene, str(tmp_path / "on.usda"), levels, device="cpu", **run)
    assert seen and sum(seen) >= 25, seen
    unions, calls_on = len(seen), len(calls)
    off = refine_usd(props_scene, str(tmp_path / "off.usda"), levels, device="cpu", batch=False, **run)
    assert len(seen) == unions  # the unbatched run builds none
    assert 0 < calls_on < (len(calls) - calls_on) / 2, (calls_on, len(calls) - calls_on)
    _same_layers(on.output, off.output)
    assert on.warnings == off.warnings
    assert [(r.path, r.faces_out, r.vertices_out) for r in on.reports] == \
        [(r.path, r.faces_out, r.vertices_out) for r in off.reports]


def test_usd_batch_memory_cap_splits_chunks(props_scene, tmp_path, monkeypatch):
    """With a small cap on rows x samples, batches are smaller and more numerous, and the layer is the same;
    batch=False builds no union."""
    from warp_subdiv.usd import batching, refine_usd

    seen = _counting(monkeypatch)
    refine_usd(props_scene, str(tmp_path / "off.usda"), 2, device="cpu", batch=False)
    assert seen == []
    monkeypatch.setattr(batching, "BATCH_ROWS", 2000)
    refine_usd(props_scene, str(tmp_path / "on.usda"), 2, device="cpu")
    assert len(seen) >= 4 and max(seen) <= 5, seen
    _same_layers(str(tmp_path / "on.usda"), str(tmp_path / "off.usda"))


def test_usd_batch_bound_depends_on_what_is_written(props_scene, tmp_path, monkeypatch):
    """A prim is batched up to BATCH_VERTICES refined vertices where limit points or normals are written, and only
    up to BATCH_VERTICES_POINTS where only points are (its own evaluation is then cheap): with the points-only
    bound below every prop, nothing is batched for points, and the same props are batched with normals."""
    from warp_subdiv.usd import batching, refine_usd

    seen = _counting(monkeypatch)
    monkeypatch.setattr(batching, "BATCH_VERTICES_POINTS", 1)
    refine_usd(props_scene, str(tmp_path / "points.usda"), 2, device="cpu")
    assert seen == []
    refine_usd(props_scene, str(tmp_path / "normals.usda"), 2, device="cpu", normals=True)
    assert seen and sum(seen) >= 25, seen


@pytest.mark.parametrize("bad", ["count", "nan"])
def test_usd_batch_input_errors_as_unbatched(tmp_path, bad):
    """A small prim whose points at one time do not fit its mesh (or are not finite) among batched ones: the
    batched writer raises the very error the unbatched one raises (the batch leaves that time to the prim)."""
    from pxr import Usd, UsdGeom, Vt

    from warp_subdiv.usd.refine import refine_usd

    cube = load_mesh("cube")
    path = str(tmp_path / "bad.usda")
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.Xform.Define(stage, "/World")
    for i in range(4):
        m = UsdGeom.Mesh.Define(stage, f"/World/Cube_{i}")
        m.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in cube.face_vertex_counts]))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray([int(c) for c in cube.face_vertex_indices]))
        for t in (1.0, 2.0, 3.0):
            pts = cube.points + t + i
            if i == 2 and t == 2.0:
                pts = pts[:7] if bad == "count" else np.where(np.arange(8)[:, None] == 3, np.nan, pts)
            m.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)), t)
    stage.GetRootLayer().Save()
    messages = []
    for batch in (True, False):
        with pytest.raises(SubdivInputError) as info:
            refine_usd(path, str(tmp_path / f"out_{batch}.usda"), 2, device="cpu", batch=batch)
        messages.append(str(info.value))
    assert messages[0] == messages[1] and "/World/Cube_2" in messages[0], messages
    assert not os.path.exists(tmp_path / "out_True.usda")
