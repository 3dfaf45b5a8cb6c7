"""tessellate on USD: primvars evaluated on the tessellation, time samples, instances, PointInstancer prototypes,
shared meshes and variants written as refine writes them."""
import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: E402

import warp_subdiv as ws  # noqa: E402
from warp_subdiv.limit.parameterisation import corner_weights  # noqa: E402
from warp_subdiv.usd.tessellate import tessellate_file  # noqa: E402

from test_usd_production import (assert_instancing_kept, new_stage, place, validation_errors,  # noqa: E402
                                 with_selections)

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


def _write_asset(path):
    """/Asset: a Catmull-Clark cube /Asset/Geo/Mesh with a vertex primvar, an indexed face-varying st, a face
    GeomSubset and a variant set crease = smooth (default) | sharp (the top square creased)."""
    stage = new_stage(path, "Asset")
    UsdGeom.Xform.Define(stage, "/Asset/Geo")
    mesh = UsdGeom.Mesh.Define(stage, "/Asset/Geo/Mesh")
    mesh.CreateSubdivisionSchemeAttr("catmullClark")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(CUBE_P.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr(CUBE_F)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.array([[-1, -1, -1], [1, 1, 1]], np.float32)))
    api = UsdGeom.PrimvarsAPI(mesh)
    api.CreatePrimvar("heat", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray.FromNumpy((2 * CUBE_P[:, 0] + CUBE_P[:, 2]).astype(np.float32)))
    rng = np.random.default_rng(5)
    pv = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray.FromNumpy(rng.random((4, 2)).astype(np.float32)))
    pv.SetIndices(Vt.IntArray.FromNumpy(rng.integers(0, 4, 24).astype(np.int32)))
    UsdGeom.Subset.CreateGeomSubset(mesh, "top", UsdGeom.Tokens.face, Vt.IntArray([1, 4]), "materialBind")
    UsdGeom.Subset.SetFamilyType(mesh, "materialBind", UsdGeom.Tokens.nonOverlapping)
    vset = stage.GetPrimAtPath("/Asset").GetVariantSets().AddVariantSet("crease")
    for name in ("smooth", "sharp"):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        if name == "sharp":
            with vset.GetVariantEditContext():
                mesh.CreateCreaseIndicesAttr(Vt.IntArray([4, 5, 6, 7, 4]))
                mesh.CreateCreaseLengthsAttr(Vt.IntArray([5]))
                mesh.CreateCreaseSharpnessesAttr(Vt.FloatArray([10.0]))
    vset.SetVariantSelection("smooth")
    stage.Save()
    return str(path)


def _instanced_scene(folder, instanceable):
    """Three references to the asset (two smooth, one sharp), instanceable or not, and a PointInstancer whose
    prototypes are a mesh defined under it and an instanceable reference to the asset."""
    folder.mkdir(exist_ok=True)
    asset = _write_asset(folder / "cube.usda")
    path = folder / f"scene_{int(instanceable)}.usda"
    stage = new_stage(path)
    place(stage, "/World/I1", asset, instanceable=instanceable, x=0.0)
    place(stage, "/World/I2", asset, instanceable=instanceable, x=3.0)
    place(stage, "/World/I3", asset, instanceable=instanceable, x=6.0, variants={"crease": "sharp"})
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    UsdGeom.Scope.Define(stage, "/World/Scatter/Prototypes")
    plate = UsdGeom.Mesh.Define(stage, "/World/Scatter/Prototypes/Plate")
    plate.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.array([(x, y, 0.0) for y in (0.0, 1.0) for x in (0.0, 1.0, 2.0)],
                                                              np.float32)))
    plate.CreateFaceVertexCountsAttr([4, 4])
    plate.CreateFaceVertexIndicesAttr([0, 1, 4, 3, 1, 2, 5, 4])
    place(stage, "/World/Scatter/Prototypes/Cube", asset, instanceable=instanceable)
    pi.CreatePrototypesRel().SetTargets(["/World/Scatter/Prototypes/Plate", "/World/Scatter/Prototypes/Cube"])
    pi.CreateProtoIndicesAttr(Vt.IntArray([0, 1, 1, 0]))
    pi.CreatePositionsAttr(Vt.Vec3fArray([(0, 5, 0), (3, 5, 0), (6, 5, 0), (9, 5, 0)]))
    stage.Save()
    return path


def _composed(prim):
    """Every attribute value of a composed mesh and of its children (subsets), by relative name."""
    out = {}
    for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies()):
        for attr in p.GetAttributes():
            value = attr.Get()
            if value is not None:
                where = "" if p == prim else str(p.GetPath().MakeRelativePath(prim.GetPath())) + "."
                name = where + attr.GetName()
                out[name] = (np.asarray(value), [(t, np.asarray(attr.Get(t))) for t in attr.GetTimeSamples()])
    return out


MESHES = ["/World/I1/Geo/Mesh", "/World/I2/Geo/Mesh", "/World/I3/Geo/Mesh", "/World/Scatter/Prototypes/Plate",
          "/World/Scatter/Prototypes/Cube/Geo/Mesh"]


@pytest.fixture(scope="module")
def instanced(tmp_path_factory):
    d = tmp_path_factory.mktemp("instanced")
    src, plain = _instanced_scene(d / "in", True), _instanced_scene(d / "in", False)
    result = tessellate_file(str(src), str(d / "out.usda"), rate=3)
    plain_result = tessellate_file(str(plain), str(d / "plain.usda"), rate=3)
    return src, d / "out.usda", result, plain, d / "plain.usda", plain_result


def test_instances_tessellated_once_per_prototype_and_stay_instances(instanced):
    """Meshes inside scene-graph instances (and an instanceable PointInstancer prototype) are tessellated as
    refine refines them: once per distinct prototype (two: smooth and sharp), written once each under
    /__warpSubdiv/Prototype_<n> and referenced by the instances, which stay instances sharing the same
    prototypes; the PointInstancer's own mesh prototype is tessellated in place; no warning."""
    src, dst, result, _, _, _ = instanced
    assert not result.warnings, result.warnings
    assert sorted(r.path for r in result.reports) == ["/World/I1/Geo/Mesh", "/World/I3/Geo/Mesh",
                                                      "/World/Scatter/Prototypes/Plate"]
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    assert_instancing_kept(before, after)
    for path in MESHES:
        prim = after.GetPrimAtPath(path)
        assert prim.IsInstanceProxy() == (path != "/World/Scatter/Prototypes/Plate"), path
        assert prim.GetAttribute("subdivisionScheme").Get() == "none", path
    layer = Sdf.Layer.FindOrOpen(str(dst))
    with_points = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: with_points.append(str(p.GetPrimPath()))
                   if p.IsPropertyPath() and p.name == "points" else None)
    assert sorted(with_points) == ["/World/Scatter/Prototypes/Plate", "/__warpSubdiv/Prototype_1/Geo/Mesh",
                                   "/__warpSubdiv/Prototype_2/Geo/Mesh"]
    for inst, proto in (("I1", 1), ("I2", 1), ("I3", 2)):
        refs = layer.GetPrimAtPath(f"/World/{inst}").referenceList.prependedItems
        assert [str(r.primPath) for r in refs] == [f"/__warpSubdiv/Prototype_{proto}"]
    pi = UsdGeom.PointInstancer(after.GetPrimAtPath("/World/Scatter"))
    assert [str(t) for t in pi.GetPrototypesRel().GetTargets()] == ["/World/Scatter/Prototypes/Plate",
                                                                    "/World/Scatter/Prototypes/Cube"]
    assert list(pi.GetProtoIndicesAttr().Get()) == [0, 1, 1, 0]


def test_instanced_output_composes_to_the_uninstanced_tessellation(instanced):
    """Every mesh of the instanced scene composes to exactly the values (points, topology, normals, extent,
    primvars, subset indices, blocked tags) of the same scene with nothing instanceable, and the smooth cube to
    LimitSurface.tessellate of its control mesh."""
    _, dst, _, _, plain_dst, plain_result = instanced
    assert not plain_result.warnings
    after, plain = Usd.Stage.Open(str(dst)), Usd.Stage.Open(str(plain_dst))
    for path in MESHES:
        got, want = _composed(after.GetPrimAtPath(path)), _composed(plain.GetPrimAtPath(path))
        assert sorted(got) == sorted(want), path
        for name in want:
            np.testing.assert_array_equal(got[name][0], want[name][0], err_msg=f"{path}.{name}")
            assert len(got[name][1]) == len(want[name][1])
    top = after.GetPrimAtPath("/World/I2/Geo/Mesh/top")
    assert top.IsInstanceProxy() and len(top.GetAttribute("indices").Get()) == 2 * 9
    t = ws.LimitSurface(ws.Mesh(CUBE_P, [4] * 6, CUBE_F)).tessellate(rate=3)
    mesh = after.GetPrimAtPath("/World/I2/Geo/Mesh")
    np.testing.assert_array_equal(np.asarray(mesh.GetAttribute("faceVertexIndices").Get()), t.face_vertex_indices)
    np.testing.assert_allclose(np.asarray(mesh.GetAttribute("points").Get()), t.points, atol=1e-6)
    sharp = np.asarray(after.GetPrimAtPath("/World/I3/Geo/Mesh").GetAttribute("points").Get())
    assert np.abs(sharp - t.points).max() > 0.1  # the crease variant's own tessellation


def test_instanced_output_validates(instanced):
    """The tessellated layer over an instanced scene (a valid input) has no validation error (usd-core's
    validators, every registered one)."""
    src, dst, _, _, _, _ = instanced
    assert not validation_errors(src)
    assert not validation_errors(dst)


def test_identical_meshes_written_once_and_referenced(tmp_path):
    """Two references to the same asset (not instanced): one tessellation, written once at
    /__warpSubdiv/Mesh_1 and referenced from both meshes, each composing to it."""
    asset = _write_asset(tmp_path / "cube.usda")
    stage = new_stage(tmp_path / "in.usda")
    place(stage, "/World/A", asset)
    place(stage, "/World/B", asset, x=3.0)
    stage.Save()
    result = tessellate_file(str(tmp_path / "in.usda"), str(tmp_path / "out.usda"), rate=2)
    assert len(result.reports) == 1
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "out.usda"))
    for name in ("A", "B"):
        refs = layer.GetPrimAtPath(f"/World/{name}/Geo/Mesh").referenceList.prependedItems
        assert [str(r.primPath) for r in refs] == ["/__warpSubdiv/Mesh_1"]
    out = Usd.Stage.Open(str(tmp_path / "out.usda"))
    t = ws.LimitSurface(ws.Mesh(CUBE_P, [4] * 6, CUBE_F)).tessellate(rate=2)
    for name in ("A", "B"):
        mesh = out.GetPrimAtPath(f"/World/{name}/Geo/Mesh")
        assert len(mesh.GetAttribute("faceVertexCounts").Get()) == t.num_faces
        np.testing.assert_allclose(np.asarray(mesh.GetAttribute("points").Get()), t.points, atol=1e-6)
        assert len(out.GetPrimAtPath(f"/World/{name}/Geo/Mesh/top").GetAttribute("indices").Get()) == 2 * 4


def test_all_variants_tessellates_every_variant(instanced, tmp_path):
    """`tessellate --all-variants`: both crease variants of the instanced asset are tessellated into one
    prototype holding the variant set; each instance composes, in each variant, to that variant's
    tessellation (the un-instanced scene's in the same variant), and instancing is kept."""
    from warp_subdiv.cli import main

    src, _, _, plain_src, _, _ = instanced
    dst = tmp_path / "all.usda"
    assert main(["tessellate", str(src), "-o", str(dst), "--rate", "3", "--all-variants", "--quiet"]) == 0
    layer = Sdf.Layer.FindOrOpen(str(dst))
    proto = layer.GetPrimAtPath("/__warpSubdiv/Prototype_1")
    assert sorted(proto.variantSets["crease"].variants.keys()) == ["sharp", "smooth"]
    assert_instancing_kept(Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst)))
    plain_out = tmp_path / "plain_all.usda"
    tessellate_file(str(plain_src), str(plain_out), rate=3, all_variants=True)
    for inst in ("/World/I1", "/World/I3"):
        for variant in ("smooth", "sharp"):
            out, ref = (with_selections(path, {inst: {"crease": variant}}) for path in (dst, plain_out))
            got = np.asarray(out.GetPrimAtPath(inst + "/Geo/Mesh").GetAttribute("points").Get())
            want = np.asarray(ref.GetPrimAtPath(inst + "/Geo/Mesh").GetAttribute("points").Get())
            assert out.GetPrimAtPath(inst).IsInstance()
            np.testing.assert_array_equal(got, want)
    assert validation_errors(dst) <= validation_errors(src)


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


def test_flatten_with_all_variants_is_refused_before_any_work(tmp_path, capsys):
    """As refine does: a flattened layer holds the selected variants only, so the two options together would
    drop every other variant tessellated; the command refuses them (exit 2, both flags named) and writes nothing."""
    from warp_subdiv import cli

    scene = tmp_path / "in.usda"
    _scene(str(scene))
    out = tmp_path / "out.usda"
    code = cli.main(["tessellate", str(scene), "-o", str(out), "--rate", "2", "--all-variants", "--flatten"])
    err = capsys.readouterr().err
    assert code == 2 and "--all-variants and --flatten cannot be combined" in err
    assert not out.exists()
