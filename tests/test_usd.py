"""The USD pipeline: round trip on every bundled scene, the output layer, time samples, primvars, subsets,
the reader's tags and errors, orientation, bilinear meshes, failures that leave no file."""
import os

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

import warp_subdiv as ws
from test_usd_support import SCENES_DIR, as_baked, digest, grid, scene_module, write_mesh
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd.order import OrderedRefiner
from warp_subdiv.usd import MemoryGuardError, refine_usd
from warp_subdiv.io.usd_read import read_mesh
from warp_subdiv.io.usd_stage import open_stage

SCENES = scene_module().SCENES
LEVELS = 2
BLOCKED = ("creaseIndices", "creaseLengths", "creaseSharpnesses", "cornerIndices", "cornerSharpnesses",
           "holeIndices", "interpolateBoundary", "faceVaryingLinearInterpolation", "triangleSubdivisionRule")


def expected_refined(spec, points=None, levels=LEVELS, **kw):
    """warp_subdiv.refine on the scene's own data (not on what the reader made of the file), numbered as the
    default bake (vertex_order="auto") writes it: compact for the piecewise-smooth rules, OpenSubdiv's otherwise."""
    mesh = ws.Mesh(spec.points if points is None else points, spec.counts, spec.indices, **spec.tags())
    scheme = "loop" if spec.scheme == "loop" else "catmull-clark"
    return as_baked(ws.refine(mesh, levels, scheme=scheme, rules=spec.rules or "piecewise-smooth", device="cpu",
                              **kw))


@pytest.fixture(scope="module")
def refined_scenes(tmp_path_factory):
    """Every bundled scene refined once (LEVELS levels): {name: (output path, input digest before)}."""
    out = {}
    folder = tmp_path_factory.mktemp("scenes")
    for name in SCENES:
        src = os.path.join(SCENES_DIR, name + ".usda")
        before = digest(src)
        dst = str(folder / f"{name}_L{LEVELS}.usda")
        refine_usd(src, dst, LEVELS, device="cpu")
        out[name] = (dst, before)
    return out


def opened(path):
    """A stage kept alive for the rest of the test (prims do not keep their stage)."""
    stage = Usd.Stage.Open(str(path))
    _OPEN.append(stage)
    return stage


_OPEN = []


@pytest.fixture(autouse=True)
def _close_stages():
    yield
    _OPEN.clear()


@pytest.mark.parametrize("name", sorted(SCENES))
def test_round_trip(refined_scenes, name):
    dst, before = refined_scenes[name]
    assert digest(os.path.join(SCENES_DIR, name + ".usda")) == before  # the input is never modified
    stage = opened(dst)
    src = opened(os.path.join(SCENES_DIR, name + ".usda"))
    for spec in SCENES[name].meshes:
        path = "/World/" + spec.name
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        assert mesh.GetSubdivisionSchemeAttr().Get() == "none"
        for attr in BLOCKED:
            assert mesh.GetPrim().GetAttribute(attr).Get() in (None, "edgeAndCorner", "cornersPlus1", "catmullClark")
            assert not mesh.GetPrim().GetAttribute(attr).HasAuthoredValue()
        for attr in ("subdiv:rules", "subdiv:concave", "subdiv:normalIndices", "subdiv:normals"):
            assert not mesh.GetPrim().GetAttribute(attr).HasAuthoredValue()
        times = sorted(spec.time_points) or [Usd.TimeCode.Default()]
        for t in times:
            points = mesh.GetPointsAttr().Get(t)
            counts = mesh.GetFaceVertexCountsAttr().Get(t)
            indices = mesh.GetFaceVertexIndicesAttr().Get(t)
            ok, why = UsdGeom.Mesh.ValidateTopology(indices, counts, len(points))
            assert ok, why
            expected = expected_refined(spec, spec.time_points.get(t) if spec.time_points else None)
            assert len(counts) == expected.num_faces and len(points) == expected.num_vertices
            np.testing.assert_array_equal(np.asarray(indices), expected.face_vertex_indices)
            np.testing.assert_allclose(np.asarray(points), expected.points, atol=2e-6)
            ext = np.asarray(mesh.GetExtentAttr().Get(t))
            np.testing.assert_allclose(ext, [expected.points.min(0), expected.points.max(0)], atol=2e-6)
        if spec.time_points:
            assert mesh.GetPointsAttr().GetTimeSamples() == sorted(spec.time_points)
        # transforms come from the input untouched
        assert (UsdGeom.Xformable(stage.GetPrimAtPath(path)).ComputeLocalToWorldTransform(1.0)
                == UsdGeom.Xformable(src.GetPrimAtPath(path)).ComputeLocalToWorldTransform(1.0))


def test_output_layer_sublayers_the_input_and_keeps_stage_metadata(refined_scenes):
    dst, _ = refined_scenes["animated"]
    layer = Sdf.Layer.FindOrOpen(dst)
    assert list(layer.subLayerPaths) == [os.path.relpath(os.path.join(SCENES_DIR, "animated.usda"),
                                                         os.path.dirname(dst)).replace(os.sep, "/")]
    assert layer.defaultPrim == "World"
    assert (layer.startTimeCode, layer.endTimeCode, layer.timeCodesPerSecond) == (1, 24, 24)
    assert layer.pseudoRoot.GetInfo("upAxis") == "Z"
    info = layer.customLayerData["warpSubdiv"]
    assert info["levels"] == LEVELS and list(info["prims"]) == ["/World/Animated/Plate"]
    # only overrides: every prim spec of the layer is an over, and the scene's other prims come from the input
    specs = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: specs.append(p) if p.IsPrimPath() else None)
    assert all(layer.GetPrimAtPath(p).specifier == Sdf.SpecifierOver for p in specs)
    stage = opened(dst)
    assert stage.GetPrimAtPath("/World/Looks/Red").IsValid()


def test_output_layer_keeps_the_input_custom_layer_data(tmp_path):
    """The output becomes the stage's root layer: the input root layer's customLayerData (render settings,
    studio tags) is kept in it, beside the bake's own entries under warpSubdiv, which replace those of an
    input that was itself baked. A flattened output keeps them too."""
    pts, counts, idx = grid(1, 1)

    def tags(stage, mesh):
        stage.GetRootLayer().customLayerData = {
            "renderSettings": {"samples": 64, "camera": "/World/Cam"}, "studio": "shot_010",
            "warpSubdiv": {"levels": 9}}

    src = write_mesh(tmp_path / "in.usda", pts, counts, idx, setup=tags)
    for flatten in (False, True):
        dst = tmp_path / f"out_{flatten}.usda"
        refine_usd(src, str(dst), 1, device="cpu", flatten=flatten)
        data = Sdf.Layer.FindOrOpen(str(dst)).customLayerData
        assert data["renderSettings"] == {"samples": 64, "camera": "/World/Cam"}, data
        assert data["studio"] == "shot_010"
        assert data["warpSubdiv"]["levels"] == 1 and data["warpSubdiv"]["flattened"] == flatten
        assert dict(opened(str(dst)).GetRootLayer().customLayerData)["studio"] == "shot_010"


@pytest.mark.parametrize("ext,binary", [(".usdc", True), (".usd", True), (".usda", False)])
def test_output_formats(tmp_path, ext, binary):
    dst = tmp_path / ("out" + ext)
    refine_usd(os.path.join(SCENES_DIR, "twisted_boundary.usda"), str(dst), 1, device="cpu")
    head = dst.read_bytes()[:8]
    assert head.startswith(b"PXR-USDC") == binary and head.startswith(b"#usda") != binary
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(dst).st_mode & 0o777 == 0o666 & ~umask  # readable like any new file, not 0600
    stage = opened(str(dst))
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/World/OpenSubdiv/Fan")).GetSubdivisionSchemeAttr().Get() == "none"


def test_flatten_writes_a_self_contained_layer(tmp_path):
    dst = tmp_path / "flat.usda"
    refine_usd(os.path.join(SCENES_DIR, "concave_corner.usda"), str(dst), 1, device="cpu", flatten=True)
    layer = Sdf.Layer.FindOrOpen(str(dst))
    assert list(layer.subLayerPaths) == []
    prim = layer.GetPrimAtPath("/World/PiecewiseSmooth/LPlate")
    assert prim.specifier == Sdf.SpecifierDef and prim.attributes["subdivisionScheme"].default == "none"
    composed = opened(str(dst)).GetPrimAtPath("/World/PiecewiseSmooth/LPlate")
    assert composed.GetAttribute("cornerIndices").Get() is None  # still blocked


def test_flatten_with_all_variants_is_refused(tmp_path):
    """A flattened layer is the composed stage: it holds the selected variant of each variant set only, so
    flatten would drop every variant that all_variants refined. The combination is refused before anything is
    read or written, naming both options (tessellate too, which checks when it writes)."""
    from test_usd_production import new_stage, place, write_asset
    from warp_subdiv.usd.tessellate import tessellate_file

    asset = write_asset(tmp_path / "cube.usda")
    src = tmp_path / "scene.usda"
    stage = new_stage(src)
    place(stage, "/World/A", asset)
    stage.Save()
    before = digest(str(src))
    dst = tmp_path / "flat.usda"
    with pytest.raises(SubdivInputError, match="all_variants and flatten cannot be combined") as err:
        refine_usd(str(src), str(dst), 1, device="cpu", all_variants=True, flatten=True)
    assert err.value.option == ("all_variants", "flatten")
    with pytest.raises(SubdivInputError, match="all_variants and flatten cannot be combined"):
        tessellate_file(str(src), str(dst), rate=2, device="cpu", all_variants=True, flatten=True)
    assert not dst.exists() and not [f for f in os.listdir(tmp_path) if f.startswith(".warp-subdiv-")]
    assert digest(str(src)) == before
    # either alone works: the variants are kept in an override layer, or the selected one flattened
    refine_usd(str(src), str(tmp_path / "variants.usda"), 1, device="cpu", all_variants=True)
    refine_usd(str(src), str(dst), 1, device="cpu", flatten=True)
    assert list(Sdf.Layer.FindOrOpen(str(dst)).subLayerPaths) == []


def test_frames_select_time_samples(tmp_path):
    src = os.path.join(SCENES_DIR, "animated.usda")
    dst = tmp_path / "frames.usda"
    refine_usd(src, str(dst), 1, device="cpu", frames=(5.0, 8.0))
    mesh = UsdGeom.Mesh(opened(str(dst)).GetPrimAtPath("/World/Animated/Plate"))
    assert mesh.GetPointsAttr().GetTimeSamples() == [5.0, 6.0, 7.0, 8.0]
    assert mesh.GetVelocitiesAttr().GetTimeSamples() == [5.0, 6.0, 7.0, 8.0]
    spec = SCENES["animated"].meshes[0]
    src_mesh = UsdGeom.Mesh(opened(src).GetPrimAtPath("/World/Animated/Plate"))
    for t in (5.0, 8.0):
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(t)),
                                   expected_refined(spec, spec.time_points[t], 1).points, atol=2e-6)
        # velocities are derivatives of the points: refined by the same stencils
        vel = np.asarray(src_mesh.GetVelocitiesAttr().Get(t), dtype=np.float64)
        np.testing.assert_allclose(np.asarray(mesh.GetVelocitiesAttr().Get(t)),
                                   expected_refined(spec, vel, 1).points, atol=2e-5)
    # frames after the last sample: the value USD holds there (the last sample's), with a warning
    result = refine_usd(src, str(tmp_path / "late.usda"), 1, device="cpu", frames=(30.0, 40.0))
    assert any("frames 30:40 hold no time sample of points" in w for w in result.warnings)
    late = UsdGeom.Mesh(opened(str(tmp_path / "late.usda")).GetPrimAtPath("/World/Animated/Plate"))
    assert late.GetPointsAttr().GetTimeSamples() == [30.0]
    np.testing.assert_allclose(np.asarray(late.GetPointsAttr().Get(30.0)),
                               expected_refined(spec, spec.time_points[24.0], 1).points, atol=2e-6)


def test_time_varying_topology_is_refined_per_sample(tmp_path):
    """A mesh whose faceVertexIndices change at time 3 is refined with the topology of each sample (time-sampled
    faceVertexCounts / faceVertexIndices in the output); --frames within one topology still works."""
    pts, counts, idx = grid(2, 1)
    swapped = idx[4:] + idx[:4]

    def setup(stage, mesh):
        attr = mesh.GetFaceVertexIndicesAttr()
        attr.Set(Vt.IntArray(idx), 1.0)
        attr.Set(Vt.IntArray(swapped), 3.0)  # faces swapped at time 3

    frames = {t: pts + [0, 0, 0.1 * t] for t in (1.0, 2.0, 3.0, 4.0)}
    src = write_mesh(tmp_path / "topo.usda", pts, counts, idx, time_points=frames, setup=setup)
    refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    mesh = UsdGeom.Mesh(opened(tmp_path / "out.usda").GetPrimAtPath("/World/Mesh"))
    assert mesh.GetFaceVertexIndicesAttr().GetTimeSamples() == [1.0, 3.0]
    for t, p in frames.items():
        expected = as_baked(ws.refine(ws.Mesh(p, counts, idx if t < 3 else swapped), 1, device="cpu"))
        np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get(t)), expected.face_vertex_indices)
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(t)), expected.points, atol=2e-6)
    refine_usd(src, str(tmp_path / "first.usda"), 1, device="cpu", frames=(1.0, 2.0))
    refine_usd(src, str(tmp_path / "last.usda"), 1, device="cpu", frames=(3.0, None))


def bilinear_grid_scene(path, scheme="bilinear"):
    """A 3x2 grid with primvars of every interpolation (values that are linear in x and y), a hole-free
    face subset and authored normals."""
    pts, counts, idx = grid(3, 2)

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        api.CreatePrimvar("f", Sdf.ValueTypeNames.FloatArray, "varying").Set(
            Vt.FloatArray([float(p[0] * p[1] + 2 * p[0]) for p in pts]))
        st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "faceVarying")
        st.Set(Vt.Vec2fArray.FromNumpy(pts[:, :2].astype(np.float32)))
        st.SetIndices(Vt.IntArray(idx))
        api.CreatePrimvar("col", Sdf.ValueTypeNames.Color3fArray, "vertex").Set(
            Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        api.CreatePrimvar("face", Sdf.ValueTypeNames.IntArray, "uniform").Set(Vt.IntArray(list(range(6))))
        tag = api.CreatePrimvar("tag", Sdf.ValueTypeNames.TokenArray, "uniform")
        tag.Set(Vt.TokenArray(["a", "b"]))
        tag.SetIndices(Vt.IntArray([0, 1, 0, 1, 0, 1]))
        api.CreatePrimvar("name", Sdf.ValueTypeNames.String, "constant").Set("grid")
        api.CreatePrimvar("rot", Sdf.ValueTypeNames.QuatfArray, "vertex").Set(Vt.QuatfArray(len(pts)))
        api.CreatePrimvar("short", Sdf.ValueTypeNames.FloatArray, "vertex").Set(Vt.FloatArray([1.0, 2.0]))
        mesh.CreateNormalsAttr(Vt.Vec3fArray([(0, 0, 1)] * len(pts)))
        UsdGeom.Subset.CreateGeomSubset(mesh, "right", "face", Vt.IntArray([2, 5]), "materialBind")

    return write_mesh(path, pts, counts, idx, scheme=scheme, setup=setup), pts


def test_primvars_subsets_and_normals(tmp_path):
    src, pts = bilinear_grid_scene(tmp_path / "grid.usda")
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 2, device="cpu")
    prim = opened(str(dst)).GetPrimAtPath("/World/Mesh")
    mesh = UsdGeom.Mesh(prim)
    api = UsdGeom.PrimvarsAPI(prim)
    p = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    assert len(counts) == 6 * 16
    # bilinear points stay in the plane, on the control grid's bilinear map
    assert np.all(p[:, 2] == 0) and p[:, 0].max() == 3 and p[:, 1].max() == 2
    # varying: linear per face -> f(x, y) of the refined positions (f is bilinear in x, y)
    f = np.asarray(api.GetPrimvar("f").ComputeFlattened())
    np.testing.assert_allclose(f, p[:, 0] * p[:, 1] + 2 * p[:, 0], atol=1e-5)
    # face-varying st (was indexed): per corner, equal to the corner's (x, y); no indices left
    st = api.GetPrimvar("st")
    assert not st.IsIndexed()
    np.testing.assert_allclose(np.asarray(st.Get()), p[idx, :2], atol=1e-6)
    # vertex colour on a bilinear mesh: bilinear too
    np.testing.assert_allclose(np.asarray(api.GetPrimvar("col").Get()), p, atol=1e-5)
    # uniform: every refined face carries its control face's value; the control face is the grid cell
    centroid = np.add.reduceat(p[idx], np.concatenate([[0], np.cumsum(counts)[:-1]])) / 4
    cell = np.floor(centroid[:, 0]).astype(int) + 3 * np.floor(centroid[:, 1]).astype(int)
    np.testing.assert_array_equal(np.asarray(api.GetPrimvar("face").Get()), cell)
    tags = np.asarray(api.GetPrimvar("tag").ComputeFlattened())  # indexed uniform: values kept, indices remapped
    np.testing.assert_array_equal(tags, np.where(cell % 2 == 0, "a", "b"))
    assert api.GetPrimvar("tag").IsIndexed() and len(api.GetPrimvar("tag").Get()) == 2
    assert api.GetPrimvar("name").Get() == "grid"  # constant: inherited
    # what cannot be refined is reported and blocked
    assert not api.GetPrimvar("rot").HasAuthoredValue() and not api.GetPrimvar("short").HasAuthoredValue()
    dropped = " ".join(result.warnings)
    assert "primvars:rot dropped" in dropped and "primvars:short dropped" in dropped
    # authored normals belong to the control mesh: blocked (no --normals)
    assert not mesh.GetNormalsAttr().HasAuthoredValue()
    # the face subset follows its faces
    subset = UsdGeom.Subset(prim.GetChild("right"))
    np.testing.assert_array_equal(np.asarray(subset.GetIndicesAttr().Get()), np.flatnonzero(np.isin(cell, [2, 5])))
    ok, why = UsdGeom.Subset.ValidateSubsets([subset], len(counts), "face")
    assert ok, why


def test_a_primvar_that_goes_bad_at_a_later_time_is_dropped_entirely(tmp_path):
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", Sdf.ValueTypeNames.FloatArray, "vertex")
        pv.Set(Vt.FloatArray([1.0] * len(pts)), 1.0)
        pv.Set(Vt.FloatArray([1.0] * (len(pts) - 1)), 2.0)  # one value short at time 2

    src = write_mesh(tmp_path / "w.usda", pts, counts, idx, setup=setup)
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    pv = UsdGeom.PrimvarsAPI(opened(tmp_path / "out.usda").GetPrimAtPath("/World/Mesh")).GetPrimvar("w")
    assert pv.Get(1.0) is None and pv.Get(2.0) is None and pv.GetAttr().GetTimeSamples() == []
    assert any("primvars:w dropped" in w and "5 vertex values, the mesh needs 6" in w for w in result.warnings)


def test_vertex_primvars_follow_the_stencils_and_not_the_normal_projection(refined_scenes):
    """Vertex primvars of a Catmull-Clark mesh: the refiner's stencils (no prescribed-normal projection), in the
    default bake's (compact) vertex order."""
    dst, _ = refined_scenes["animated"]
    spec = SCENES["animated"].meshes[0]
    prim = opened(dst).GetPrimAtPath("/World/Animated/Plate")
    src = opened(os.path.join(SCENES_DIR, "animated.usda")).GetPrimAtPath("/World/Animated/Plate")
    col = np.asarray(UsdGeom.PrimvarsAPI(src).GetPrimvar("displayColor").Get(), dtype=np.float64)
    mesh = ws.Mesh(spec.points, spec.counts, spec.indices, **spec.tags())
    refiner = OrderedRefiner(ws.Refiner(mesh, LEVELS, device="cpu"))  # piecewise-smooth: the compact order
    expected = refiner.evaluate(col, normal_control=False)
    np.testing.assert_allclose(np.asarray(UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor").Get()), expected,
                               atol=1e-6)
    # face-varying st: the refiner's face-varying channel with the mesh's mode (USD's default cornersPlus1),
    # written indexed
    st_in = UsdGeom.PrimvarsAPI(src).GetPrimvar("st")
    st_out = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    values, indices = refiner.evaluate_face_varying(
        np.asarray(st_in.Get(), dtype=np.float64), np.asarray(st_in.GetIndices()), mode="corners-plus1")
    assert st_out.IsIndexed()
    np.testing.assert_allclose(np.asarray(st_out.Get()), values, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(st_out.GetIndices()), indices)
    assert len(st_out.ComputeFlattened()) == 4 * len(spec.counts) * 4 ** LEVELS
    # time-sampled varying primvar keeps its samples
    assert UsdGeom.PrimvarsAPI(prim).GetPrimvar("weight").GetAttr().GetTimeSamples() == [1.0, 12.0, 24.0]
    # the material subset is remapped: 4 control faces -> 4 * 16 refined faces
    subset = UsdGeom.Subset(prim.GetChild("FirstRow"))
    assert len(subset.GetIndicesAttr().Get()) == 4 * 4 ** LEVELS


def test_reader_reads_every_tag(tmp_path):
    pts, counts, idx = grid(3, 3)
    src = write_mesh(tmp_path / "tags.usda", pts, counts, idx, attrs={
        "creaseIndices": Vt.IntArray([0, 1, 2, 5, 6]), "creaseLengths": Vt.IntArray([3, 2]),
        "creaseSharpnesses": Vt.FloatArray([10.0, 2.5]),  # one per crease; the second is semi-sharp
        "cornerIndices": Vt.IntArray([5, 15]), "cornerSharpnesses": Vt.FloatArray([10.0, 0.0]),
        "holeIndices": Vt.IntArray([4]), "interpolateBoundary": "edgeOnly",
    }, custom={
        "subdiv:rules": ("Token", "opensubdiv"),
        "subdiv:concave": ("Int2Array", Vt.Vec2iArray([(5, 6)])),
        "subdiv:normalIndices": ("IntArray", Vt.IntArray([9])),
        "subdiv:normals": ("Normal3fArray", Vt.Vec3fArray([(0, 0.6, 0.8)])),
        "subdiv:flatness": ("Float", 0.25), "subdiv:normalStrength": ("Float", 0.5),
    })
    stage = open_stage(src)
    prim = stage.GetPrimAtPath("/World/Mesh")
    sp = read_mesh(prim)
    m = sp.mesh
    np.testing.assert_array_equal(m.creases, [[0, 1], [1, 2], [5, 6]])
    np.testing.assert_array_equal(m.crease_sharpness, [10, 10, 2.5])
    np.testing.assert_array_equal(m.corners, [5])  # sharpness 0 means not tagged
    np.testing.assert_array_equal(m.holes, [4])
    np.testing.assert_array_equal(m.concave, [[5, 6]])
    np.testing.assert_array_equal(m.normal_vertices, [9])
    np.testing.assert_allclose(m.normal_vectors, [[0, 0.6, 0.8]], atol=1e-6)
    assert (sp.boundary, sp.rules, sp.flatness, sp.normal_strength) == ("edge-only", "opensubdiv", 0.25, 0.5)
    assert sp.semi_sharp == 1
    # per-edge sharpness and the override of semi-sharp tags
    sharp = read_mesh(prim, semi_sharp="sharp")
    np.testing.assert_array_equal(sharp.mesh.crease_sharpness, [10, 10, 10])
    assert any("treated as infinitely sharp" in w for w in sharp.warnings)


@pytest.mark.parametrize("token,mode", [(None, "corners-plus1"), ("none", "none"), ("cornersOnly", "corners-only"),
                                        ("cornersPlus2", "corners-plus2"), ("boundaries", "boundaries"),
                                        ("all", "all")])
def test_face_varying_interpolation_reads_as_the_refiners_mode(tmp_path, token, mode):
    """faceVaryingLinearInterpolation (cornersPlus1 when unset, as in USD) maps onto FaceVaryingMode."""
    pts, counts, idx = grid(1, 1)
    attrs = {} if token is None else {"faceVaryingLinearInterpolation": token}
    stage = open_stage(write_mesh(tmp_path / "fv.usda", pts, counts, idx, attrs=attrs))
    sp = read_mesh(stage.GetPrimAtPath("/World/Mesh"))
    assert isinstance(sp.face_varying_mode, ws.FaceVaryingMode) and sp.face_varying_mode == mode


def test_semi_sharp_creases_refine_as_semi_sharp_or_are_made_sharp(tmp_path):
    pts, counts, idx = grid(2, 2)
    pts = np.array(pts, dtype=float)
    pts[4, 2] = 0.5  # lift the centre, on the crease
    src = write_mesh(tmp_path / "semi.usda", pts, counts, idx, attrs={
        "creaseIndices": Vt.IntArray([1, 4, 7]), "creaseLengths": Vt.IntArray([3]),
        "creaseSharpnesses": Vt.FloatArray([0.5, 10.0])})  # one per crease edge
    refine_usd(src, str(tmp_path / "a.usda"), 2, device="cpu")
    stage_a = Usd.Stage.Open(str(tmp_path / "a.usda"))
    got = np.asarray(stage_a.GetPrimAtPath("/World/Mesh").GetAttribute("points").Get())
    mesh = ws.Mesh(pts, counts, idx, creases=[[1, 4], [4, 7]], crease_sharpness=[0.5, 10.0])
    np.testing.assert_allclose(got, as_baked(ws.refine(mesh, 2, device="cpu")).points, atol=1e-5)
    result = refine_usd(src, str(tmp_path / "b.usda"), 2, device="cpu", semi_sharp="sharp")
    assert any("semi-sharp" in w for w in result.warnings)
    stage_b = Usd.Stage.Open(str(tmp_path / "b.usda"))
    sharp = np.asarray(stage_b.GetPrimAtPath("/World/Mesh").GetAttribute("points").Get())
    assert np.abs(sharp - got).max() > 1e-4  # sharpness 0.5 blends at once; infinite does not


@pytest.mark.parametrize("attrs,custom,needle", [
    ({"faceVertexIndices": Vt.IntArray([0, 1, 3, 9])}, {}, "/World/Mesh: faceVertexIndices: face 0 corner 3 refers to vertex 9"),
    ({"faceVertexCounts": Vt.IntArray([3])}, {}, "/World/Mesh: faceVertexCounts"),
    ({"creaseIndices": Vt.IntArray([0, 3]), "creaseLengths": Vt.IntArray([2]), "creaseSharpnesses": Vt.FloatArray([10])},
     {}, "/World/Mesh: creaseIndices: crease 0 edge (0, 3) is not an edge of the mesh"),
    ({"creaseIndices": Vt.IntArray([0, 4]), "creaseLengths": Vt.IntArray([2]), "creaseSharpnesses": Vt.FloatArray([10])}, {},
     "/World/Mesh: creaseIndices[1] = 4 is not a vertex of the mesh"),
    ({"creaseIndices": Vt.IntArray([0, 1]), "creaseLengths": Vt.IntArray([3])}, {}, "creaseLengths add up to 3"),
    ({"creaseIndices": Vt.IntArray([0, 1]), "creaseLengths": Vt.IntArray([2]), "creaseSharpnesses": Vt.FloatArray([1, 2, 3])},
     {}, "creaseSharpnesses has 3 values; expected 1 (one per crease)"),
    ({"creaseIndices": Vt.IntArray([0, 1, 3]), "creaseLengths": Vt.IntArray([3]), "creaseSharpnesses": Vt.FloatArray([1, 2, 3])},
     {}, "creaseSharpnesses has 3 values; expected 1 (one per crease) or 2 (one per crease edge)"),
    ({"holeIndices": Vt.IntArray([7])}, {}, "/World/Mesh: holeIndices[0] = 7 is not a face of the mesh"),
    ({"subdivisionScheme": "catmark"}, {}, "subdivisionScheme 'catmark' is not one of"),
    ({"faceVaryingLinearInterpolation": "sometimes"}, {}, "/World/Mesh: faceVaryingLinearInterpolation 'sometimes' "
     "is not one of none, cornersOnly, cornersPlus1, cornersPlus2, boundaries, all"),
    ({}, {"subdiv:concave": ("FloatArray", Vt.FloatArray([1.0]))}, "subdiv:concave must be int2[], got float[]"),
    ({}, {"subdiv:rules": ("Token", "hoppe")}, "subdiv:rules 'hoppe' is not"),
    ({}, {"subdiv:normalIndices": ("IntArray", Vt.IntArray([0]))}, "must be given together"),
    ({}, {"subdiv:flatness": ("Float", 1.5)}, "subdiv:flatness = 1.5 is not in [0, 1]"),
])
def test_reader_errors_name_the_prim_and_attribute(tmp_path, attrs, custom, needle):
    pts, counts, idx = grid(1, 1)
    src = write_mesh(tmp_path / "bad.usda", pts, counts, idx, attrs=attrs, custom=custom)
    with pytest.raises(SubdivInputError) as info:
        refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert needle in str(info.value)
    assert not (tmp_path / "out.usda").exists() and sorted(os.listdir(tmp_path)) == ["bad.usda"]


def test_library_errors_are_put_in_usd_terms_from_their_fields():
    """usd_error names the USD attribute from an error's structured fields (the Mesh argument or refiner option,
    else the element), never from its text, keeps the fields, and turns a crease edge into its USD crease."""
    from warp_subdiv.io.usd_read import usd_error

    cases = [
        (SubdivInputError("flatness must lie in [0, 1], got 2", option="flatness", value=2),
         "/W: subdiv:flatness: flatness must lie in [0, 1], got 2"),
        (SubdivInputError("normal_strength must lie in [0, 1]", option="normal_strength"),
         "/W: subdiv:normalStrength: normal_strength"),
        (SubdivInputError("face 3 is odd", element="face", index=3), "/W: faceVertexIndices: face 3 is odd"),
        (SubdivInputError("face 3 has 2 vertices", option="face_vertex_counts", element="face", index=3),
         "/W: faceVertexCounts: face 3 has 2 vertices"),
        (SubdivInputError("prescribed normal for vertex 4 has length 2", option="normals", element="normal", index=0),
         "/W: subdiv:normals: prescribed normal"),
        (SubdivInputError("concave tag 0 (10, 6): vertex 10 is not a corner", option="concave", element="vertex",
                          index=10), "/W: subdiv:concave: concave tag 0"),
        (SubdivInputError("crease 2 (4, 5) is not an edge of the mesh", option="creases", element="crease", index=2),
         "/W: creaseIndices: crease 1 edge (4, 5) is not an edge of the mesh"),
        (SubdivInputError("precision must be one of 'float32', 'float64'", option="precision"),
         "/W: precision must be one of"),
    ]
    for exc, text in cases:
        out = usd_error("/W", exc, np.array([0, 0, 1]))
        assert str(out) == text or str(out).startswith(text), (str(out), text)
        assert (out.option, out.element, out.index, out.value) == (exc.option, exc.element, exc.index, exc.value)


def test_options_a_mesh_asks_for_are_checked_with_the_run_rules(tmp_path):
    """subdiv:flatness under --rules opensubdiv is refused, naming the prim and the attribute."""
    pts, counts, idx = grid(2, 2)
    src = write_mesh(tmp_path / "flat.usda", pts, counts, idx, custom={"subdiv:flatness": ("Float", 0.5)})
    with pytest.raises(SubdivInputError, match=r"^/World/Mesh: subdiv:flatness: flatness is a piecewise-smooth rule"):
        refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu", rules="opensubdiv")
    with pytest.raises(SubdivInputError, match=r"^precision must be one of") as info:
        refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu", precision="float16")
    assert info.value.option == "precision"
    assert sorted(os.listdir(tmp_path)) == ["flat.usda"]


def test_smooth_triangle_rule(tmp_path):
    """triangleSubdivisionRule = smooth reaches the refiner (OpenSubdiv's TRI_SUB_SMOOTH)."""
    spec = SCENES["icosahedron_normals"].meshes[0]
    src = write_mesh(tmp_path / "tri.usda", spec.points, spec.counts, spec.indices,
                     attrs={"triangleSubdivisionRule": "smooth"})
    result = refine_usd(src, str(tmp_path / "out.usda"), 2, device="cpu")
    points = np.asarray(opened(tmp_path / "out.usda").GetPrimAtPath("/World/Mesh").GetAttribute("points").Get())
    mesh = ws.Mesh(spec.points, spec.counts, spec.indices)
    expected = as_baked(ws.refine(mesh, 2, device="cpu", triangle_subdivision="smooth")).points
    assert not any("triangleSubdivisionRule" in w for w in result.warnings)
    assert np.abs(expected - as_baked(ws.refine(mesh, 2, device="cpu")).points).max() > 1e-3  # it makes a difference
    np.testing.assert_allclose(points, expected, atol=2e-6)


def test_unknown_subdiv_attribute_is_a_warning(tmp_path):
    pts, counts, idx = grid(1, 1)
    src = write_mesh(tmp_path / "typo.usda", pts, counts, idx, custom={"subdiv:flattness": ("Float", 0.5)})
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert any("unknown attribute subdiv:flattness" in w for w in result.warnings)


def test_left_handed_meshes_refine_to_the_same_surface(tmp_path):
    """Subdivision stencils do not depend on the winding: a left-handed copy (every face reversed) refines to
    the same points; its faces keep their winding and the orientation attribute stays leftHanded."""
    spec = SCENES["concave_corner"].meshes[0]
    counts = np.asarray(spec.counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    flipped = np.concatenate([np.asarray(spec.indices)[s:s + c][::-1] for s, c in zip(starts, counts)])
    concave = {"subdiv:concave": ("Int2Array", Vt.Vec2iArray([tuple(map(int, p)) for p in spec.concave]))}
    corners = {"cornerIndices": Vt.IntArray(spec.corners), "cornerSharpnesses": Vt.FloatArray([10.0])}
    right = write_mesh(tmp_path / "right.usda", spec.points, counts, spec.indices, attrs=corners, custom=concave)
    left = write_mesh(tmp_path / "left.usda", spec.points, counts, flipped, custom=concave,
                      attrs=dict(corners, orientation="leftHanded"))
    kw = dict(device="cpu", normals=True)
    refine_usd(right, str(tmp_path / "r.usda"), 2, **kw)
    refine_usd(left, str(tmp_path / "l.usda"), 2, **kw)
    r = UsdGeom.Mesh(opened(str(tmp_path / "r.usda")).GetPrimAtPath("/World/Mesh"))
    lm = UsdGeom.Mesh(opened(str(tmp_path / "l.usda")).GetPrimAtPath("/World/Mesh"))
    assert lm.GetOrientationAttr().Get() == "leftHanded"
    rp, lp = np.asarray(r.GetPointsAttr().Get()), np.asarray(lm.GetPointsAttr().Get())
    assert len(rp) == len(lp)
    nearest = np.argmin(np.linalg.norm(rp[:, None] - lp[None], axis=2), axis=1)  # the same point in the other
    np.testing.assert_allclose(rp, lp[nearest], atol=1e-6)
    assert len(set(nearest.tolist())) == len(rp)
    # normals point to the same side: the left-handed mesh's front is its clockwise side
    rn, ln = np.asarray(r.GetNormalsAttr().Get()), np.asarray(lm.GetNormalsAttr().Get())
    np.testing.assert_allclose(rn, ln[nearest], atol=1e-4)
    assert np.mean(rn[:, 2]) > 0.5  # faces wound counter-clockwise seen from +z: up


def test_limit_points_and_normals(tmp_path):
    src = os.path.join(SCENES_DIR, "animated.usda")
    dst = tmp_path / "limit.usda"
    refine_usd(src, str(dst), 2, device="cpu", limit=True, normals=True, frames=(3.0, 4.0))
    mesh = UsdGeom.Mesh(opened(str(dst)).GetPrimAtPath("/World/Animated/Plate"))
    spec = SCENES["animated"].meshes[0]
    for t in (3.0, 4.0):
        expected = expected_refined(spec, spec.time_points[t])
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(t)), expected.limit_points(), atol=2e-6)
        normals = np.asarray(mesh.GetNormalsAttr().Get(t))
        np.testing.assert_allclose(normals, expected.limit_normals(), atol=2e-6)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert mesh.GetNormalsInterpolation() == "vertex"


def test_writer_takes_points_limits_and_normals_in_one_pass(tmp_path, monkeypatch):
    """The writer refines each time sample of the points once (Refiner.evaluate_with_limits) and never asks for
    their limit points or normals separately (that would move the last level twice); in the compact
    vertex order too, whose output equals the OpenSubdiv order's renumbered."""
    from warp_subdiv.refiner import Refiner

    calls = []
    # (_evaluate_rows: every evaluate goes through it, and OrderedRefiner calls it directly)
    for name in ("_evaluate_rows", "limit_points", "limit_normals", "evaluate_with_limits"):
        original = getattr(Refiner, name)

        def spy(self, *a, _name=name, _original=original, **kw):
            calls.append(_name)
            return _original(self, *a, **kw)

        monkeypatch.setattr(Refiner, name, spy)
    src = os.path.join(SCENES_DIR, "animated.usda")
    outs = {}
    for order in ("opensubdiv", "compact"):
        calls.clear()
        dst = tmp_path / f"{order}.usda"
        refine_usd(src, str(dst), 2, device="cpu", limit=True, normals=True, frames=(3.0, 4.0), vertex_order=order)
        assert calls.count("evaluate_with_limits") == 3  # the default and two time samples
        assert "limit_normals" not in calls  # (limit_points is still called for the primvars' own data)
        assert calls.count("limit_points") == calls.count("_evaluate_rows")
        mesh = UsdGeom.Mesh(opened(str(dst)).GetPrimAtPath("/World/Animated/Plate"))
        outs[order] = [np.asarray(a.Get(4.0)) for a in (mesh.GetPointsAttr(), mesh.GetNormalsAttr())] + [
            np.asarray(mesh.GetFaceVertexIndicesAttr().Get())]
    (p_osd, n_osd, i_osd), (p_cmp, n_cmp, i_cmp) = outs["opensubdiv"], outs["compact"]
    np.testing.assert_array_equal(p_osd[i_osd], p_cmp[i_cmp])  # the same corners, renumbered
    np.testing.assert_array_equal(n_osd[i_osd], n_cmp[i_cmp])


def test_memory_guard_refuses_before_any_work(tmp_path):
    with pytest.raises(MemoryGuardError, match=r"would need about .* more than max_memory 1\.0 MiB"):
        refine_usd(os.path.join(SCENES_DIR, "complex_corner.usda"), str(tmp_path / "x.usda"), 5, device="cpu",
                   max_memory=2**20)
    with pytest.raises(MemoryGuardError, match="more than 32-bit tables can index"):
        refine_usd(os.path.join(SCENES_DIR, "complex_corner.usda"), str(tmp_path / "x.usda"), 14, device="cpu")
    assert os.listdir(tmp_path) == []


def test_a_failure_while_writing_leaves_no_file(tmp_path, monkeypatch):
    from warp_subdiv.usd import subsets

    def boom(*args, **kw):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(subsets, "write_subset", boom)
    dst = tmp_path / "out.usda"
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(OSError):
        refine_usd(os.path.join(SCENES_DIR, "animated.usda"), str(dst), 1, device="cpu")
    assert sorted(os.listdir(tmp_path)) == ["keep.txt"]


def test_output_may_not_overwrite_the_input(tmp_path):
    src = tmp_path / "in.usda"
    src.write_bytes(open(os.path.join(SCENES_DIR, "twisted_boundary.usda"), "rb").read())
    before = digest(src)
    with pytest.raises(SubdivInputError, match="the input reads this file"):
        refine_usd(str(src), str(src), 1, device="cpu")
    assert digest(src) == before and sorted(os.listdir(tmp_path)) == ["in.usda"]


def test_meshes_with_scheme_none_are_left_alone(tmp_path):
    pts, counts, idx = grid(1, 1)
    src = write_mesh(tmp_path / "none.usda", pts, counts, idx, scheme="none")
    with pytest.raises(SubdivInputError, match=r"no subdivision meshes in the file: /World/Mesh \(subdivisionScheme none\)"):
        refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")


def test_the_scenes_are_what_make_scenes_writes(tmp_path):
    """scenes/*.usda are generated: regenerating them gives the same files."""
    for name, scene in SCENES.items():
        path = tmp_path / (name + ".usda")
        scene_module().write_scene(scene, str(path))
        assert path.read_text() == open(os.path.join(SCENES_DIR, name + ".usda")).read(), name


def test_shared_boundary_has_no_gap(refined_scenes):
    """Fig. 10a: the two meshes' refined boundaries along x = 0 coincide, with both rule sets."""
    stage = opened(refined_scenes["shared_boundary"][0])
    for variant in ("PiecewiseSmooth", "OpenSubdiv"):
        sides = []
        for part in ("Left", "Right"):
            p = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath(f"/World/{variant}/{part}")).GetPointsAttr().Get())
            on = p[np.abs(p[:, 0]) < 1e-6]
            sides.append(on[np.argsort(on[:, 1])])
        assert len(sides[0]) == len(sides[1]) == 2 ** LEVELS * 2 + 1
        np.testing.assert_allclose(sides[0], sides[1], atol=1e-6)

