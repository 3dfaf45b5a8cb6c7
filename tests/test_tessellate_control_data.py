"""tessellate on USD leaves nothing sized for the control mesh: every primvar, subset and point array of a
tessellated mesh is rewritten for the tessellation (as refine rewrites them for the refined mesh) or blocked
with a warning, so no attribute keeps control-sized data that a renderer would misread."""
import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, Vt  # noqa: E402

from warp_subdiv.usd.tessellate import tessellate_file  # noqa: E402

from test_usd_production import new_stage  # noqa: E402

GRID = np.array([[x, y, 0.0] for y in range(3) for x in range(3)])  # 2 x 2 quads, 9 points
GRID_FACES = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]]


def _mesh(stage, path, points, faces, scheme="catmullClark"):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(scheme)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in faces]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([i for f in faces for i in f]))
    return mesh


def _tessellate(tmp_path, build, **kw):
    """Write a stage (``build(stage)`` adds to it), tessellate it; (result, the composed output stage)."""
    stage = new_stage(tmp_path / "in.usda")
    build(stage)
    stage.Save()
    result = tessellate_file(str(tmp_path / "in.usda"), str(tmp_path / "out.usda"), **kw)
    return result, Usd.Stage.Open(str(tmp_path / "out.usda"))


def test_values_that_cannot_be_interpolated_are_blocked_with_a_warning(tmp_path):
    """Vertex, varying and face-varying primvars of ints, bools, strings and matrices have no value between
    control vertices: they are blocked with a warning (as refine does), not left at the control mesh's size."""
    def build(stage):
        mesh = _mesh(stage, "/World/Grid", GRID, GRID_FACES)
        api = UsdGeom.PrimvarsAPI(mesh)
        T = Sdf.ValueTypeNames
        api.CreatePrimvar("objectId", T.IntArray, UsdGeom.Tokens.vertex).Set(Vt.IntArray(list(range(9))))
        api.CreatePrimvar("label", T.StringArray, UsdGeom.Tokens.vertex).Set(Vt.StringArray(["a"] * 9))
        api.CreatePrimvar("frame", T.Matrix4dArray, UsdGeom.Tokens.varying).Set(
            Vt.Matrix4dArray([Gf.Matrix4d(1.0)] * 9))
        api.CreatePrimvar("seam", T.BoolArray, UsdGeom.Tokens.faceVarying).Set(Vt.BoolArray([True] * 16))
        api.CreatePrimvar("part", T.IntArray, UsdGeom.Tokens.uniform).Set(Vt.IntArray([1, 2, 3, 4]))

    result, out = _tessellate(tmp_path, build, rate=2)
    prim = out.GetPrimAtPath("/World/Grid")
    assert len(prim.GetAttribute("points").Get()) == 25
    for name in ("objectId", "label", "frame", "seam"):
        assert prim.GetAttribute("primvars:" + name).Get() is None, name
        assert [w for w in result.warnings if f"primvars:{name} dropped" in w], (name, result.warnings)
    part = np.asarray(prim.GetAttribute("primvars:part").Get())  # uniform: follows the control faces
    base = np.asarray(prim.GetAttribute("primvars:tessellation:baseFace").Get())
    np.testing.assert_array_equal(part, np.array([1, 2, 3, 4])[base])


def test_time_sampled_face_subsets_follow_their_control_faces(tmp_path):
    """A face subset whose indices are time-sampled (a material moving between faces) holds, at every sample
    and at the default time, the output faces of its control faces, not control face ids."""
    def build(stage):
        mesh = _mesh(stage, "/World/Grid", GRID, GRID_FACES)
        subset = UsdGeom.Subset.CreateGeomSubset(mesh, "left", UsdGeom.Tokens.face, Vt.IntArray([3]),
                                                 "materialBind")
        subset.GetIndicesAttr().Set(Vt.IntArray([0, 2]), 1.0)
        subset.GetIndicesAttr().Set(Vt.IntArray([1, 3]), 2.0)

    result, out = _tessellate(tmp_path, build, rate=3)
    base = np.asarray(out.GetPrimAtPath("/World/Grid").GetAttribute("primvars:tessellation:baseFace").Get())
    indices = out.GetPrimAtPath("/World/Grid/left").GetAttribute("indices")
    assert indices.GetTimeSamples() == [1.0, 2.0]
    for time, faces in ((1.0, [0, 2]), (2.0, [1, 3]), (Usd.TimeCode.Default(), [3])):
        np.testing.assert_array_equal(np.asarray(indices.Get(time)), np.flatnonzero(np.isin(base, faces)))


PENTAGON_AND_QUAD = (np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [1, 2, 0], [0, 1, 0], [3, 0, 0], [3, 1, 0]], float),
                     [[0, 1, 2, 3, 4], [1, 5, 6, 2]])


@pytest.mark.parametrize("scheme,points,faces,edges", [
    ("catmullClark", GRID, GRID_FACES, [[1, 4], [4, 7], [0, 3]]),  # the middle line and a boundary edge
    ("catmullClark", *PENTAGON_AND_QUAD, [[2, 1], [3, 4]]),  # an n-gon's edges (in quad sub-faces)
    ("loop", *PENTAGON_AND_QUAD, [[1, 2], [4, 3], [5, 6]]),  # a Loop polygon's edges (in fan triangles)
    ("bilinear", *PENTAGON_AND_QUAD, [[1, 2], [0, 4]]),
])
def test_edge_subsets_hold_the_output_edges_on_their_control_edges(tmp_path, scheme, points, faces, edges):
    """An edge subset (pairs of point indices) holds the output edges that lie on its control edges, as many
    on each as its rate: a valid subset of the tessellated mesh (usd-core's validators), not the control
    mesh's point pairs."""
    import warp_subdiv as ws
    from test_usd_production import validation_errors

    def build(stage):
        mesh = _mesh(stage, "/World/M", points, faces, scheme)
        UsdGeom.Subset.CreateGeomSubset(mesh, "seam", "edge", Vt.IntArray(np.ravel(edges).tolist()), "seams")

    result, out = _tessellate(tmp_path, build, rate=3)
    assert not validation_errors(tmp_path / "in.usda")
    assert not validation_errors(tmp_path / "out.usda")
    got = np.asarray(out.GetPrimAtPath("/World/M/seam").GetAttribute("indices").Get()).reshape(-1, 2)
    counts = np.asarray(out.GetPrimAtPath("/World/M").GetAttribute("faceVertexCounts").Get())
    fvi = np.asarray(out.GetPrimAtPath("/World/M").GetAttribute("faceVertexIndices").Get())
    offsets = np.concatenate([[0], np.cumsum(counts)])
    nxt = np.arange(1, len(fvi) + 1)
    nxt[offsets[1:] - 1] = offsets[:-1]
    output_edges = {tuple(sorted(e)) for e in zip(fvi.tolist(), fvi[nxt].tolist())}
    assert {tuple(sorted(e)) for e in got.tolist()} <= output_edges
    control = ws.Mesh(points, [len(f) for f in faces], [i for f in faces for i in f])
    rates = ws.LimitSurface(control, scheme={"catmullClark": "catmull-clark", "loop": "loop",
                                             "bilinear": "catmull-clark"}[scheme]).tessellate(rate=3).edge_rates
    assert len(got) == int(rates[control.edges.find(np.asarray(edges), len(points))].sum())
    if faces is GRID_FACES:  # the grid is flat and symmetric: its control lines' limit curves are straight
        x = np.asarray(out.GetPrimAtPath("/World/M").GetAttribute("points").Get())[got][:, :, 0]  # (k, 2)
        assert np.sum(np.all(np.isclose(x, 1.0), axis=1)) == 2 * 3 and np.sum(np.all(np.isclose(x, 0.0), axis=1)) == 3


def test_an_edge_subset_naming_no_edge_is_blocked_with_a_warning(tmp_path):
    def build(stage):
        mesh = _mesh(stage, "/World/Grid", GRID, GRID_FACES)
        UsdGeom.Subset.CreateGeomSubset(mesh, "seam", "edge", Vt.IntArray([1, 4, 0, 4]))  # (0, 4): a diagonal

    result, out = _tessellate(tmp_path, build, rate=2)
    assert out.GetPrimAtPath("/World/Grid/seam").GetAttribute("indices").Get() is None
    assert [w for w in result.warnings if "seam" in w and "(0, 4) is not an edge" in w], result.warnings


@pytest.mark.parametrize("scheme,moving", [("catmullClark", False), ("catmullClark", True), ("bilinear", True)])
def test_velocities_and_accelerations_are_tessellated_like_the_points(tmp_path, scheme, moving):
    """Velocities and accelerations are the derivatives of the points: evaluated on the tessellation with the
    points' weights at the default time and every sample (as refine refines them), not blocked. Affine
    functions of the points stay the same functions of the tessellated points."""
    def affine(p, k):
        return np.stack([p[:, 1], 2 * p[:, 0], np.ones(len(p))], axis=1) * k

    def build(stage):
        mesh = _mesh(stage, "/World/Grid", GRID, GRID_FACES, scheme)
        if moving:  # points sampled where the velocities are: each sample's own surface
            for time in (1.0, 2.0):
                mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((GRID * time ** 2).astype(np.float32)), time)
        vel = mesh.CreateVelocitiesAttr(Vt.Vec3fArray.FromNumpy(affine(GRID, 1).astype(np.float32)))
        vel.Set(Vt.Vec3fArray.FromNumpy(affine(GRID, 2).astype(np.float32)), 1.0)
        vel.Set(Vt.Vec3fArray.FromNumpy(affine(GRID, 3).astype(np.float32)), 2.0)
        mesh.CreateAccelerationsAttr(Vt.Vec3fArray.FromNumpy(np.tile([[0, 0, -9.8]], (9, 1)).astype(np.float32)))

    result, out = _tessellate(tmp_path, build, rate=3)
    assert not result.warnings
    prim = out.GetPrimAtPath("/World/Grid")
    points = np.asarray(prim.GetAttribute("points").Get(), dtype=np.float64)  # where the grid's values land
    vel = prim.GetAttribute("velocities")
    assert vel.GetTimeSamples() == [1.0, 2.0]
    for time, k in ((Usd.TimeCode.Default(), 1), (1.0, 2), (2.0, 3)):
        np.testing.assert_allclose(np.asarray(vel.Get(time)), affine(points, k), atol=1e-5)
    acc = np.asarray(prim.GetAttribute("accelerations").Get())
    np.testing.assert_allclose(acc, np.tile([[0, 0, -9.8]], (len(points), 1)), atol=1e-5)


def test_indexed_authored_normals_are_blocked_with_their_indices(tmp_path):
    """Authored primvars:normals belong to the control mesh (the limit normals are written as ``normals``): an
    indexed one is blocked with its indices, which would otherwise index the control points."""
    def build(stage):
        mesh = _mesh(stage, "/World/Grid", GRID, GRID_FACES)
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray,
                                                     UsdGeom.Tokens.vertex)
        pv.Set(Vt.Vec3fArray([(0, 0, 1)]))
        pv.SetIndices(Vt.IntArray([0] * 9))

    _, out = _tessellate(tmp_path, build, rate=2)
    prim = out.GetPrimAtPath("/World/Grid")
    assert prim.GetAttribute("primvars:normals").Get() is None
    assert prim.GetAttribute("primvars:normals:indices").Get() is None
    assert len(prim.GetAttribute("normals").Get()) == 25
