"""tessellate on USD: primvars evaluated on the tessellation, time samples (issue 13)."""
import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: E402

import warp_subdiv as ws  # noqa: E402
from warp_subdiv.tessellate import corner_weights, tessellate_file  # noqa: E402

CUBE_P = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1],
                   [-1, 1, 1]], float)
CUBE_F = [0, 3, 2, 1, 4, 5, 6, 7, 0, 1, 5, 4, 1, 2, 6, 5, 2, 3, 7, 6, 3, 0, 4, 7]


def _scene(path, fvar_mode=None):
    """The cube with time-sampled points, vertex, varying and face-varying (indexed st) primvars; returns (the
    varying values, st per face corner, st values, st indices). ``fvar_mode``: faceVaryingLinearInterpolation
    to author (None: USD's fallback cornersPlus1)."""
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Cube")
    if fvar_mode is not None:
        mesh.CreateFaceVaryingLinearInterpolationAttr(fvar_mode)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(CUBE_P.astype(np.float32)))
    pts = mesh.GetPointsAttr()
    pts.Set(Vt.Vec3fArray.FromNumpy(CUBE_P.astype(np.float32)), 1.0)
    pts.Set(Vt.Vec3fArray.FromNumpy((2 * CUBE_P).astype(np.float32)), 2.0)
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr(CUBE_F)
    mesh.CreateSubdivisionSchemeAttr("catmullClark")
    api = UsdGeom.PrimvarsAPI(mesh)
    api.CreatePrimvar("pref", Sdf.ValueTypeNames.Point3fArray, UsdGeom.Tokens.vertex).Set(
        Vt.Vec3fArray.FromNumpy(CUBE_P.astype(np.float32)))
    api.CreatePrimvar("heat", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray.FromNumpy((2 * CUBE_P[:, 0] + 1).astype(np.float32)))
    rng = np.random.default_rng(3)
    var = rng.random((8, 3)).astype(np.float32)
    api.CreatePrimvar("tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.varying).Set(
        Vt.Vec3fArray.FromNumpy(var))
    st = rng.random((4, 2)).astype(np.float32)
    st_idx = rng.integers(0, 4, 24).astype(np.int32)
    pv = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray.FromNumpy(st))
    pv.SetIndices(Vt.IntArray.FromNumpy(st_idx))
    stage.GetRootLayer().Save()
    return var, st[st_idx], st, st_idx


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    d = tmp_path_factory.mktemp("tess")
    var, st, _, _ = _scene(d / "in.usda", fvar_mode="all")
    result = tessellate_file(str(d / "in.usda"), str(d / "out.usda"), rate=3, rules="opensubdiv")
    stage = Usd.Stage.Open(str(d / "out.usda"))
    surface = ws.LimitSurface(ws.Mesh(CUBE_P, [4] * 6, CUBE_F), rules="opensubdiv")
    t = surface.tessellate(rate=3)
    return stage, result, t, var, st


def _get(stage, name, time=Usd.TimeCode.Default()):
    return np.asarray(stage.GetPrimAtPath("/Cube").GetAttribute(name).Get(time), dtype=np.float64)


def test_no_primvar_blocked(baked):
    _, result, _, _, _ = baked
    assert not [w for w in result.warnings if "primvar" in w], result.warnings


def test_vertex_primvars_follow_the_limit_surface(baked):
    stage, _, t, _, _ = baked
    points = _get(stage, "points")
    np.testing.assert_allclose(points, t.points, atol=1e-5)
    np.testing.assert_allclose(_get(stage, "primvars:pref"), points, atol=1e-5)  # a Pref equal to the points
    np.testing.assert_allclose(_get(stage, "primvars:heat"), 2 * points[:, 0] + 1, atol=1e-5)  # affine data


def test_varying_primvar_bilinear_in_the_base_face(baked):
    stage, _, t, var, _ = baked
    fvi = np.asarray(CUBE_F).reshape(6, 4)
    c = var[fvi[t.base_face]].astype(np.float64)  # (n, 4, 3)
    u, v = t.uv[:, :1], t.uv[:, 1:]
    want = (1 - u) * (1 - v) * c[:, 0] + u * (1 - v) * c[:, 1] + u * v * c[:, 2] + (1 - u) * v * c[:, 3]
    got = _get(stage, "primvars:tint")
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_face_varying_primvar_bilinear_per_corner(baked):
    """Under faceVaryingLinearInterpolation "all" a face-varying primvar is bilinear in each control face from
    its corner values, one value per output corner."""
    stage, _, t, _, st = baked
    prim = stage.GetPrimAtPath("/Cube")
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    assert pv.GetInterpolation() == UsdGeom.Tokens.faceVarying
    got = np.asarray(pv.ComputeFlattened(), dtype=np.float64)
    face = np.repeat(t.face_base_face, t.face_vertex_counts)
    c = st.reshape(6, 4, 2)[face].astype(np.float64)
    u, v = t.face_uv[:, :1], t.face_uv[:, 1:]
    want = (1 - u) * (1 - v) * c[:, 0] + u * (1 - v) * c[:, 1] + u * v * c[:, 2] + (1 - u) * v * c[:, 3]
    assert len(got) == len(t.face_vertex_indices)
    np.testing.assert_allclose(got, want, atol=1e-6)


@pytest.mark.parametrize("fvar_mode,mode", [(None, "corners-plus1"), ("none", "none"), ("boundaries", "boundaries")])
def test_face_varying_primvar_on_the_limit_surface(tmp_path, fvar_mode, mode):
    """Other faceVaryingLinearInterpolation modes (and USD's fallback cornersPlus1): the face-varying primvar is
    the limit surface of its value mesh under that mode (LimitSurface.evaluate_face_varying) at every output
    corner, which differs from bilinear interpolation."""
    _, st_corner, st, st_idx = _scene(tmp_path / "in.usda", fvar_mode=fvar_mode)
    result = tessellate_file(str(tmp_path / "in.usda"), str(tmp_path / "out.usda"), rate=3, rules="opensubdiv")
    assert not [w for w in result.warnings if "primvar" in w], result.warnings
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    got = np.asarray(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Cube")).GetPrimvar("st").ComputeFlattened(),
                     dtype=np.float64)
    surface = ws.LimitSurface(ws.Mesh(CUBE_P, [4] * 6, CUBE_F), rules="opensubdiv")
    t = surface.tessellate(rate=3)
    face = np.repeat(t.face_base_face, t.face_vertex_counts)
    want = surface.evaluate_face_varying(st.astype(np.float64), st_idx, face, t.face_uv[:, 0], t.face_uv[:, 1],
                                         mode=mode).values
    np.testing.assert_allclose(got, want, atol=1e-6)
    corners, w = corner_weights(surface, face, t.face_uv)
    bilinear = np.einsum("nm,nmk->nk", w, st_corner.astype(np.float64)[np.maximum(corners, 0)])
    assert np.abs(got - bilinear).max() > 1e-3


def test_bilinear_mesh_tessellated_as_bilinear_patches(tmp_path):
    """A bilinear mesh is tessellated as bilinear patches (not left alone): its points lie on the control faces
    (the cube's faces), one normal per face corner (faceVarying: the faces meet at creases), the face's own
    normal; a face-varying primvar is interpolated linearly whatever the interpolation mode says."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "in.usda"))
    mesh = UsdGeom.Mesh.Define(stage, "/Box")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(CUBE_P.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr(CUBE_F)
    mesh.CreateSubdivisionSchemeAttr("bilinear")
    st = np.random.default_rng(4).random((24, 2)).astype(np.float32)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                            UsdGeom.Tokens.faceVarying).Set(Vt.Vec2fArray.FromNumpy(st))
    stage.GetRootLayer().Save()
    result = tessellate_file(str(tmp_path / "in.usda"), str(tmp_path / "out.usda"), rate=3)
    assert not result.warnings, result.warnings
    out_stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    out = out_stage.GetPrimAtPath("/Box")
    points = np.asarray(out.GetAttribute("points").Get(), dtype=np.float64)
    np.testing.assert_allclose(np.abs(points).max(axis=1), 1.0, atol=1e-6)  # on the cube's faces
    assert len(points) == 6 * 16 - 12 * 4 + 8  # a 3 x 3 grid per face, shared edges and corners
    normals = UsdGeom.Mesh(out).GetNormalsAttr()
    assert UsdGeom.Mesh(out).GetNormalsInterpolation() == UsdGeom.Tokens.faceVarying
    n = np.asarray(normals.Get(), dtype=np.float64)
    counts = np.asarray(out.GetAttribute("faceVertexCounts").Get())
    assert len(n) == counts.sum()
    corner_points = points[np.asarray(out.GetAttribute("faceVertexIndices").Get())]
    # the outward unit normal of the corner's face: an axis, with n . p = 1 on the cube's face
    np.testing.assert_allclose(np.abs(n).max(axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.einsum("nk,nk->n", n, corner_points), 1.0, atol=1e-6)
    got = np.asarray(UsdGeom.PrimvarsAPI(out).GetPrimvar("st").ComputeFlattened(), dtype=np.float64)
    surface = ws.LimitSurface(ws.Mesh(CUBE_P, [4] * 6, CUBE_F), linear=True)
    t = surface.tessellate(rate=3)
    face = np.repeat(t.face_base_face, t.face_vertex_counts)
    corners, w = corner_weights(surface, face, t.face_uv)
    np.testing.assert_allclose(got, np.einsum("nm,nmk->nk", w, st.astype(np.float64)[corners]), atol=1e-6)


def test_instanced_meshes_warned_precisely(tmp_path):
    """A mesh inside a scene-graph instance is left alone with a warning that names the instance and says how
    to tessellate it; the same mesh made uninstanceable is tessellated."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "in.usda"))
    proto = UsdGeom.Xform.Define(stage, "/Proto")
    mesh = UsdGeom.Mesh.Define(stage, "/Proto/Cube")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(CUBE_P.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr(CUBE_F)
    proto.GetPrim().SetSpecifier(Sdf.SpecifierClass)
    for name, instanceable in (("A", True), ("B", False)):
        prim = stage.DefinePrim(f"/{name}", "Xform")
        prim.GetReferences().AddInternalReference("/Proto")
        prim.SetInstanceable(instanceable)
    stage.GetRootLayer().Save()
    result = tessellate_file(str(tmp_path / "in.usda"), str(tmp_path / "out.usda"), rate=2)
    assert [r.path for r in result.reports] == ["/B/Cube"]
    assert len(result.warnings) == 1
    assert result.warnings[0].startswith("/A/Cube: inside the instance /A,") and "instanceable = false" in \
        result.warnings[0]


def test_time_samples_tessellated(baked):
    stage, _, t, _, _ = baked
    attr = stage.GetPrimAtPath("/Cube").GetAttribute("points")
    assert attr.GetTimeSamples() == [1.0, 2.0]
    np.testing.assert_allclose(_get(stage, "points", 1.0), t.points, atol=1e-5)
    np.testing.assert_allclose(_get(stage, "points", 2.0), 2 * t.points, atol=1e-5)  # the same topology, scaled
    assert len(_get(stage, "normals", 2.0)) == len(t.points)


def test_corner_weights_ngon_and_loop_polygon():
    pent = np.array([[np.cos(a), np.sin(a), 0] for a in np.linspace(0, 2 * np.pi, 6)[:-1]])
    for scheme in ("catmull-clark", "loop"):
        s = ws.LimitSurface(ws.Mesh(pent, [5], [0, 1, 2, 3, 4]), scheme=scheme)
        t = s.tessellate(rate=4)
        corners, w = corner_weights(s, t.base_face, t.uv)
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
        at_corner = corner_weights(s, np.zeros(5, int), s.vertex_uv(np.zeros(5, int), np.arange(5)))[1]
        np.testing.assert_allclose(at_corner, np.eye(5), atol=1e-12)
        # linear data: interpolated positions of a planar polygon stay inside it and on its edges' lines
        p = np.einsum("nm,nmk->nk", w, pent[np.maximum(corners, 0)])
        assert np.all(np.abs(p[:, 2]) < 1e-12) and np.all(np.linalg.norm(p, axis=1) <= 1 + 1e-12)


def test_cli_frames(tmp_path):
    from warp_subdiv.cli import main

    _scene(tmp_path / "in.usda")
    assert main(["tessellate", str(tmp_path / "in.usda"), "-o", str(tmp_path / "out.usda"), "--rate", "2",
                 "--frames", "2:2", "--quiet"]) == 0
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    assert stage.GetPrimAtPath("/Cube").GetAttribute("points").GetTimeSamples() == [2.0]
