"""Regressions of the USD bake found by users: time-sampled primvar indices, elementSize of indexed uniform
primvars, what --frames evaluates, empty or wrongly sized defaults, symlinked output folders, stale
extentsHint, render times, --prim on inactive or abstract prims, --limit and vertex primvars, edge subsets,
the flattened layer's doc and the frames parser. Each test builds its own small USD file."""
import os

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

from test_usd_support import grid, write_mesh
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd.refine import refine_usd

T = Sdf.ValueTypeNames
_OPEN = []


def opened(path):
    """A stage kept alive for the rest of the test (prims do not keep their stage)."""
    stage = Usd.Stage.Open(str(path))
    _OPEN.append(stage)
    return stage


@pytest.fixture(autouse=True)
def _close_stages():
    yield
    _OPEN.clear()


def out_prim(path, prim="/World/Mesh"):
    return opened(path).GetPrimAtPath(prim)


# -- item 10 -------------------------------------------------------------------------------------------

def test_indices_authored_only_as_time_samples_are_read(tmp_path):
    """Indexed primvars whose values and indices exist only as time samples (UV sets exported per frame):
    GetIndices(Default) is an empty array, not None, which used to hide the samples; both the face-varying
    st and an indexed uniform primvar must be refined, not blocked."""
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        st = api.CreatePrimvar("st", T.TexCoord2fArray, "faceVarying")
        tag = api.CreatePrimvar("tag", T.FloatArray, "uniform")
        for t in (1.0, 2.0):
            st.Set(Vt.Vec2fArray.FromNumpy((pts[:, :2] * t).astype(np.float32)), t)
            st.SetIndices(Vt.IntArray(idx), t)
            tag.Set(Vt.FloatArray([10.0 * t, 20.0 * t]), t)
            tag.SetIndices(Vt.IntArray([1, 0]), t)

    src = write_mesh(tmp_path / "uv.usda", pts, counts, idx, setup=setup)
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu")
    assert not [w for w in result.warnings if "dropped" in w], result.warnings
    api = UsdGeom.PrimvarsAPI(out_prim(dst))
    mesh = UsdGeom.Mesh(out_prim(dst))
    p = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    for t in (1.0, 2.0):
        st = np.asarray(api.GetPrimvar("st").ComputeFlattened(t))
        np.testing.assert_allclose(st, p[fvi, :2] * t, atol=1e-5)  # a plane: face-varying = positions
        tag = np.asarray(api.GetPrimvar("tag").ComputeFlattened(t))
        np.testing.assert_allclose(tag, np.repeat([20.0 * t, 10.0 * t], 4))
    assert len(api.GetPrimvar("st").ComputeFlattened()) == len(fvi)  # the default: the first sample


# -- item 11 -------------------------------------------------------------------------------------------

def test_indexed_uniform_primvar_with_element_size_two(tmp_path):
    """An indexed uniform primvar with elementSize 2: its indices count elements (one per face), not scalars;
    every refined face gets its control face's element."""
    pts, counts, idx = grid(3, 3)

    def setup(stage, mesh):
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", T.FloatArray, "uniform", 2)
        pv.Set(Vt.FloatArray([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))  # three elements of two floats
        pv.SetIndices(Vt.IntArray([f % 3 for f in range(9)]))

    src = write_mesh(tmp_path / "w.usda", pts, counts, idx, setup=setup)
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu")
    assert not [w for w in result.warnings if "dropped" in w], result.warnings
    pv = UsdGeom.PrimvarsAPI(out_prim(dst)).GetPrimvar("w")
    assert pv.GetElementSize() == 2 and pv.IsIndexed()
    indices = np.asarray(pv.GetIndices())
    assert len(indices) == 36  # one element per refined face
    # the refined faces of control face f: 4f .. 4f + 3 (Catmull-Clark quads)
    np.testing.assert_array_equal(indices, np.repeat([f % 3 for f in range(9)], 4))
    np.testing.assert_allclose(np.asarray(pv.ComputeFlattened()).reshape(-1, 2),
                               np.array([[1, 2], [3, 4], [5, 6]])[indices])


def test_indexed_uniform_primvar_indices_out_of_range_are_reported(tmp_path):
    """Indices of an indexed uniform primvar that point past its elements (elementSize 2) are reported
    and the primvar blocked, never a crash or a wrongly sized array."""
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", T.FloatArray, "uniform", 2)
        pv.Set(Vt.FloatArray([1.0, 2.0, 3.0]))  # 3 floats: not whole elements of 2
        pv.SetIndices(Vt.IntArray([0, 1]))

    src = write_mesh(tmp_path / "w.usda", pts, counts, idx, setup=setup)
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert any("primvars:w dropped" in w and "elementSize 2" in w for w in result.warnings), result.warnings


# -- item 12 -------------------------------------------------------------------------------------------

def refined_plane(dst, t=None):
    """(refined points, faceVertexIndices) of the output mesh at time ``t`` (None: the default)."""
    mesh = UsdGeom.Mesh(out_prim(dst))
    time = Usd.TimeCode.Default() if t is None else t
    return (np.asarray(mesh.GetPointsAttr().Get(time), dtype=np.float64),
            np.asarray(mesh.GetFaceVertexIndicesAttr().Get()))


def test_frames_evaluate_attributes_held_or_interpolated_from_samples_outside_the_range(tmp_path):
    """--frames 2:4 on a plane whose points are sampled at 1..5: attributes whose samples lie outside the range
    (st at 1 and 5, velocities at 1, a vertex primvar at 1, 3, 5, subset indices at 1) are evaluated at the
    range's ends as USD holds or interpolates them; nothing is dropped or emptied, and the output agrees with
    the input at every time in the range."""
    pts, counts, idx = grid(2, 2)
    n = len(pts)

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        st = api.CreatePrimvar("st", T.TexCoord2fArray, "faceVarying")
        st.SetIndices(Vt.IntArray(idx))
        for t in (1.0, 5.0):
            st.Set(Vt.Vec2fArray.FromNumpy((pts[:, :2] * t).astype(np.float32)), t)
        mesh.CreateVelocitiesAttr().Set(Vt.Vec3fArray([(0.0, 0.0, 2.0)] * n), 1.0)
        w = api.CreatePrimvar("w", T.FloatArray, "vertex")
        for t in (1.0, 3.0, 5.0):
            w.Set(Vt.FloatArray([t] * n), t)
        subset = UsdGeom.Subset.CreateGeomSubset(mesh, "left", "face", Vt.IntArray(), "materialBind")
        subset.GetIndicesAttr().Set(Vt.IntArray([0, 2]), 1.0)

    src = write_mesh(tmp_path / "held.usda", pts, counts, idx, setup=setup,
                     time_points={float(t): pts + [0, 0, t] for t in range(1, 6)})
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu", frames=(2.0, 4.0))
    assert not [w for w in result.warnings if "dropped" in w], result.warnings
    prim = out_prim(dst)
    api = UsdGeom.PrimvarsAPI(prim)
    mesh = UsdGeom.Mesh(prim)
    counts_out = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    for t in (2.0, 2.5, 3.0, 4.0):
        p, fvi = refined_plane(dst, t)
        np.testing.assert_allclose(p[:, 2], t, atol=1e-5)
        # st: interpolated between the samples at 1 and 5, as the input reads at t
        np.testing.assert_allclose(np.asarray(api.GetPrimvar("st").ComputeFlattened(t)), p[fvi, :2] * t, atol=1e-5)
        # velocities: the sample at 1, held
        np.testing.assert_allclose(np.asarray(mesh.GetVelocitiesAttr().Get(t)), [[0, 0, 2]] * len(p), atol=1e-6)
        # the vertex primvar reads t (linear between 1, 3 and 5), not 3 at both ends
        np.testing.assert_allclose(np.asarray(api.GetPrimvar("w").Get(t)), t, atol=1e-5)
        # the subset: the refined faces of control faces 0 and 2 (4 children each), held from time 1
        ids = np.asarray(UsdGeom.Subset(prim.GetChild("left")).GetIndicesAttr().Get(t))
        np.testing.assert_array_equal(ids, [0, 1, 2, 3, 8, 9, 10, 11])
        assert len(ids) and ids.max() < len(counts_out)
    assert mesh.GetPointsAttr().GetTimeSamples() == [2.0, 3.0, 4.0]


def test_frames_between_samples_evaluate_the_range_ends(tmp_path):
    """Points sampled at 11.6, 13.2, 14.8, 16.4 refined for --frames 12:16: the output has samples at 12 and
    16 (the interpolated points refined) besides 13.2 and 14.8, so every time in 12..16 reads as in the input;
    a range holding no sample of the points reads the value USD holds there, with a warning."""
    pts, counts, idx = grid(1, 1)
    times = (11.6, 13.2, 14.8, 16.4)
    src = write_mesh(tmp_path / "between.usda", pts, counts, idx, scheme="bilinear",
                     time_points={t: pts + [0, 0, t] for t in times})
    dst = tmp_path / "out.usda"
    refine_usd(src, str(dst), 1, device="cpu", frames=(12.0, 16.0))
    mesh = UsdGeom.Mesh(out_prim(dst))
    assert mesh.GetPointsAttr().GetTimeSamples() == pytest.approx([12.0, 13.2, 14.8, 16.0])
    for t in (12.0, 12.5, 15.0, 16.0):
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(t))[:, 2], t, atol=1e-4)
    late = tmp_path / "late.usda"
    result = refine_usd(src, str(late), 1, device="cpu", frames=(30.0, 40.0))
    assert any("no time sample of points" in w for w in result.warnings), result.warnings
    late_mesh = UsdGeom.Mesh(out_prim(late))
    assert late_mesh.GetPointsAttr().GetTimeSamples() == [30.0]
    np.testing.assert_allclose(np.asarray(late_mesh.GetPointsAttr().Get(35.0))[:, 2], 16.4, atol=1e-4)


# -- item 13 -------------------------------------------------------------------------------------------

def test_an_empty_or_wrongly_sized_default_beside_time_samples_is_stood_in_for(tmp_path):
    """An empty points (and velocities, primvar) default beside time samples: the first selected sample stands
    in for it (the README's rule); a default of another size too, with a warning, with or without --frames."""
    pts, counts, idx = grid(2, 1)
    n = len(pts)

    def setup(stage, mesh, default):
        mesh.GetPointsAttr().Set(default)
        vel = mesh.CreateVelocitiesAttr()
        vel.Set(Vt.Vec3fArray())
        w = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", T.FloatArray, "vertex")
        w.Set(Vt.FloatArray())
        for t in (1.0, 2.0):
            vel.Set(Vt.Vec3fArray([(0.0, 0.0, t)] * n), t)
            w.Set(Vt.FloatArray([t] * n), t)

    timed = {t: pts + [0, 0, t] for t in (1.0, 2.0)}
    for name, default in (("empty", Vt.Vec3fArray()), ("short", Vt.Vec3fArray([(0.0, 0.0, 0.0)] * 2))):
        src = write_mesh(tmp_path / f"{name}.usda", pts, counts, idx, time_points=timed,
                         setup=lambda stage, mesh, d=default: setup(stage, mesh, d))
        for frames in (None, (2.0, 2.0)):
            dst = tmp_path / f"{name}_{frames is None}.usda"
            result = refine_usd(src, str(dst), 1, device="cpu", frames=frames)
            assert not [w for w in result.warnings if "dropped" in w], result.warnings
            first = 1.0 if frames is None else 2.0
            prim = out_prim(dst)
            p = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(), dtype=np.float64)
            np.testing.assert_allclose(p[:, 2], first, atol=1e-6)  # the first selected sample's points
            np.testing.assert_allclose(np.asarray(UsdGeom.Mesh(prim).GetVelocitiesAttr().Get())[:, 2], first)
            np.testing.assert_allclose(np.asarray(UsdGeom.PrimvarsAPI(prim).GetPrimvar("w").Get()), first)
            stood_in = [w for w in result.warnings if "default" in w and "stands in" in w]
            if name == "short":
                assert any("/World/Mesh: points default has 2 entries" in w for w in stood_in), result.warnings
            else:
                assert not stood_in, result.warnings


def test_a_bad_sample_names_prim_attribute_and_time_and_leaves_no_folder(tmp_path):
    """A points sample of the wrong size (empty here) is an error naming the prim, the attribute and the time
    (not numpy's reshape message), and the failed run leaves neither the output nor the folders it made."""
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        mesh.GetPointsAttr().Set(Vt.Vec3fArray(), 2.0)

    src = write_mesh(tmp_path / "bad.usda", pts, counts, idx, time_points={1.0: pts}, setup=setup)
    dst = tmp_path / "made" / "deeper" / "out.usda"
    with pytest.raises(SubdivInputError, match=r"/World/Mesh: points at time 2 has 0 entries, the mesh has 6"):
        refine_usd(src, str(dst), 1, device="cpu")
    assert not (tmp_path / "made").exists()


# -- item 14 -------------------------------------------------------------------------------------------

@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_output_through_a_symlinked_folder_sublayers_the_input(tmp_path):
    """Writing through a symlinked folder: USD anchors the relative sublayer path to the path the layer is
    opened by, so it must be computed from the output path as given, not from the resolved folder."""
    pts, counts, idx = grid(1, 1)
    src = write_mesh(tmp_path / "in.usda", pts, counts, idx)
    deep = tmp_path / "real" / "deep"
    deep.mkdir(parents=True)
    os.symlink(deep, tmp_path / "link")
    dst = tmp_path / "link" / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu")
    assert (deep / "out.usda").exists()
    assert os.path.dirname(result.output) == str(tmp_path / "link")
    stage = opened(dst)
    assert str(tmp_path / "in.usda") in [layer.realPath for layer in stage.GetUsedLayers()]
    prim = stage.GetPrimAtPath("/World/Mesh")
    assert prim.GetTypeName() == "Mesh" and len(UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get()) == 4


# -- item 15 -------------------------------------------------------------------------------------------

def test_ancestors_extents_hint_is_recomputed(tmp_path):
    """A prescribed normal tilts a flat plate out of its plane (the control hull): the extentsHint that
    /World (UsdGeom.ModelAPI) carries for the control mesh is overridden with the refined bounds, at the
    default time and at every time sample of the points, so bounding boxes that use the hint contain the mesh."""
    pts, counts, idx = grid(2, 2)
    tilt = np.array([[0.6, 0.0, 0.8]])

    def setup(stage, mesh):
        world = stage.GetPrimAtPath("/World")
        hint = UsdGeom.ModelAPI.Apply(world)
        hint.SetExtentsHint(Vt.Vec3fArray([(0, 0, 0), (2, 2, 0)]))
        hint.GetExtentsHintAttr().Set(Vt.Vec3fArray([(0, 0, 1), (2, 2, 1)]), 1.0)
        hint.GetExtentsHintAttr().Set(Vt.Vec3fArray([(0, 0, 2), (2, 2, 2)]), 2.0)

    src = write_mesh(tmp_path / "hint.usda", pts, counts, idx, setup=setup,
                     time_points={1.0: pts + [0, 0, 1], 2.0: pts + [0, 0, 2]},
                     custom={"subdiv:normalIndices": ("IntArray", Vt.IntArray([4])),
                             "subdiv:normals": ("Normal3fArray", Vt.Vec3fArray.FromNumpy(tilt.astype(np.float32)))})
    dst = tmp_path / "out.usda"
    refine_usd(src, str(dst), 2, device="cpu")
    stage = opened(dst)
    world = stage.GetPrimAtPath("/World")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh"))
    for t in (Usd.TimeCode.Default(), 1.0, 2.0):
        p = np.asarray(mesh.GetPointsAttr().Get(t), dtype=np.float64)
        assert np.ptp(p[:, 2]) > 0.01  # the surface leaves the control plane
        hint = np.asarray(UsdGeom.ModelAPI(world).GetExtentsHint(t), dtype=np.float64)
        np.testing.assert_allclose(hint[:2], [p.min(axis=0), p.max(axis=0)], atol=1e-5)
        box = UsdGeom.BBoxCache(t, [UsdGeom.Tokens.default_], useExtentsHint=True).ComputeWorldBound(world)
        lo, hi = np.asarray(box.GetRange().GetMin()), np.asarray(box.GetRange().GetMax())
        assert np.all(p >= lo - 1e-5) and np.all(p <= hi + 1e-5)


# -- item 16 -------------------------------------------------------------------------------------------

def test_render_uses_the_first_sample_when_points_are_only_time_sampled(tmp_path):
    """Points authored only as time samples on a stage without a start time: render shows the first sample
    (saying so, and that --time chooses another), instead of 'nothing to render'."""
    from warp_subdiv.render import BACKGROUND_BOTTOM, BACKGROUND_TOP, render_file

    pts, counts, idx = grid(2, 2)
    src = write_mesh(tmp_path / "timed.usda", pts, counts, idx, time_points={3.0: pts, 4.0: pts + [0, 0, 1]})
    assert not opened(src).HasAuthoredTimeCodeRange()
    with pytest.warns(UserWarning, match=r"rendered at 3\b.*the time option"):
        img = render_file(src, str(tmp_path / "timed.png"), size=(40, 30), samples=1, device="cpu")
    rows = np.linspace(0.0, 1.0, img.shape[0])[:, None, None]
    background = 255 * (BACKGROUND_TOP * (1 - rows) + BACKGROUND_BOTTOM * rows)
    assert np.count_nonzero(np.any(np.abs(img - background) > 12, axis=2)) > 100  # the plate is there


def test_render_command_says_which_time_it_rendered(tmp_path, capsys):
    """The command line names the time option by its flag in that warning."""
    from warp_subdiv import cli

    pts, counts, idx = grid(1, 1)
    src = write_mesh(tmp_path / "timed.usda", pts, counts, idx, time_points={5.0: pts})
    assert cli.main(["render", src, "-o", str(tmp_path / "t.png"), "--size", "20x20", "--samples", "1",
                     "--device", "cpu"]) == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "rendered at 5, their first sample (the --time option chooses another)" in err
    assert "start --time" not in err


# -- item 17 -------------------------------------------------------------------------------------------

def test_prim_option_on_inactive_or_abstract_prims_says_so(tmp_path):
    """--prim on an inactive prim (or below one), or on a mesh under a class prim, says inactive / abstract,
    not 'is not a mesh and holds no meshes'."""
    pts, counts, idx = grid(1, 1)

    def setup(stage, mesh):
        off = UsdGeom.Mesh.Define(stage, "/World/Off")
        off.CreateFaceVertexCountsAttr(Vt.IntArray(counts))
        off.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
        off.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        UsdGeom.Xform.Define(stage, "/World/Group/Inner")
        stage.GetPrimAtPath("/World/Group").SetActive(False)
        off.GetPrim().SetActive(False)
        stage.CreateClassPrim("/Template")
        UsdGeom.Mesh.Define(stage, "/Template/Mesh").CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))

    src = write_mesh(tmp_path / "odd.usda", pts, counts, idx, setup=setup)
    for prim, needle in (("/World/Off", "/World/Off is inactive"),
                         ("/World/Group/Inner", "/World/Group/Inner is under the inactive prim /World/Group"),
                         ("/Template/Mesh", "/Template/Mesh is abstract (under the class /Template)"),
                         ("/Template", "/Template is abstract (a class)")):
        with pytest.raises(SubdivInputError) as info:
            refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu", prims=[prim])
        assert needle in str(info.value)
        assert "holds no meshes" not in str(info.value)


# -- item 18 -------------------------------------------------------------------------------------------

def cube():
    pts = np.array([(x, y, z) for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return pts, [4] * 6, [i for f in faces for i in f]


def test_limit_evaluates_vertex_and_face_varying_primvars_at_the_limit(tmp_path):
    """--limit on a cube at level 2: a Pref vertex primvar equal to the points (and a 2-wide one equal to their
    x, y) and a face-varying copy of the points (on the points' indices) come out as the limit points, not
    as refined control values (0.039 apart before)."""
    pts, counts, idx = cube()

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        api.CreatePrimvar("Pref", T.Point3fArray, "vertex").Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        api.CreatePrimvar("xy", T.Float2Array, "vertex").Set(Vt.Vec2fArray.FromNumpy(pts[:, :2].astype(np.float32)))
        fv = api.CreatePrimvar("pos", T.Float3Array, "faceVarying")
        fv.Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        fv.SetIndices(Vt.IntArray(idx))

    src = write_mesh(tmp_path / "cube.usda", pts, counts, idx, setup=setup)
    dst = tmp_path / "limit.usda"
    refine_usd(src, str(dst), 2, device="cpu", limit=True, precision="float64")
    prim = out_prim(dst)
    api = UsdGeom.PrimvarsAPI(prim)
    mesh = UsdGeom.Mesh(prim)
    p = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    np.testing.assert_allclose(np.asarray(api.GetPrimvar("Pref").Get()), p, atol=1e-6)
    np.testing.assert_allclose(np.asarray(api.GetPrimvar("xy").Get()), p[:, :2], atol=1e-6)
    np.testing.assert_allclose(np.asarray(api.GetPrimvar("pos").ComputeFlattened()), p[fvi], atol=1e-6)


def test_limit_primvars_ignore_prescribed_normals(tmp_path):
    """With prescribed normals (normal control moves positions only) a 3-wide vertex primvar is evaluated at
    the limit exactly as the same data 4 wide: no normal control reaches the primvar."""
    pts, counts, idx = cube()
    normal = np.array([[0.0, 0.6, 0.8]])

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        api.CreatePrimvar("a", T.Float3Array, "vertex").Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        wide = np.concatenate([pts, np.ones((len(pts), 1))], axis=1)
        api.CreatePrimvar("b", T.Float4Array, "vertex").Set(Vt.Vec4fArray.FromNumpy(wide.astype(np.float32)))

    src = write_mesh(tmp_path / "cube.usda", pts, counts, idx, setup=setup,
                     custom={"subdiv:normalIndices": ("IntArray", Vt.IntArray([7])),
                             "subdiv:normals": ("Normal3fArray", Vt.Vec3fArray.FromNumpy(normal.astype(np.float32)))})
    dst = tmp_path / "limit.usda"
    refine_usd(src, str(dst), 2, device="cpu", limit=True, precision="float64")
    api = UsdGeom.PrimvarsAPI(out_prim(dst))
    a, b = np.asarray(api.GetPrimvar("a").Get()), np.asarray(api.GetPrimvar("b").Get())
    np.testing.assert_allclose(a, b[:, :3], atol=1e-6)
    np.testing.assert_allclose(b[:, 3], 1.0, atol=1e-6)
    p = np.asarray(UsdGeom.Mesh(out_prim(dst)).GetPointsAttr().Get())
    assert np.abs(a - p).max() > 1e-3  # the positions were moved by the normal, the primvar was not


# -- item 19 -------------------------------------------------------------------------------------------

def chain(pairs, start, end):
    """Whether the edges ``pairs`` (k, 2) form one path from ``start`` to ``end``."""
    links = {}
    for a, b in pairs:
        links.setdefault(int(a), []).append(int(b))
        links.setdefault(int(b), []).append(int(a))
    path, prev, here = [start], None, start
    while here != end:
        nxt = [v for v in links.get(here, []) if v != prev]
        if len(nxt) != 1:
            return False
        prev, here = here, nxt[0]
        path.append(here)
    return len(path) == len(pairs) + 1


@pytest.mark.parametrize("scheme", ["catmullClark", "loop"])
def test_edge_subsets_are_mapped_to_the_child_edges(tmp_path, scheme):
    """An edge GeomSubset (pairs of point indices) is mapped to the child edges of each control edge, so
    UsdGeom.Subset.ValidateFamily accepts it on the refined mesh; edges of hole faces vanish with them."""
    pts, counts, idx = grid(2, 1)  # faces (0 1 4 3) and (1 2 5 4); face 1 is a hole

    def setup(stage, mesh):
        UsdGeom.Subset.CreateGeomSubset(mesh, "seam", "edge", Vt.IntArray([0, 1, 4, 1, 2, 5]), "seams",
                                        UsdGeom.Tokens.nonOverlapping)

    src = write_mesh(tmp_path / "edges.usda", pts, counts, idx, scheme=scheme, setup=setup,
                     attrs={"holeIndices": Vt.IntArray([1])})
    dst = tmp_path / "out.usda"
    levels = 2
    result = refine_usd(src, str(dst), levels, device="cpu")
    prim = out_prim(dst)
    ok, why = UsdGeom.Subset.ValidateFamily(UsdGeom.Mesh(prim), "edge", "seams")
    assert ok, why
    pairs = np.asarray(UsdGeom.Subset(prim.GetChild("seam")).GetIndicesAttr().Get()).reshape(-1, 2)
    n = 2 ** levels  # child edges per control edge
    assert len(pairs) == 2 * n  # (0, 1) and (1, 4); (2, 5) lies only on the hole face
    assert chain(pairs, 0, 4)  # one path from control vertex 0 through 1 to 4
    assert not [w for w in result.warnings if "seam" in w], result.warnings


def test_an_edge_subset_naming_no_edge_is_dropped_with_a_warning(tmp_path):
    """An edge subset whose pair is no edge of the control mesh (a quad's diagonal) cannot be mapped: it is
    blocked on the output, with a warning naming it."""
    pts, counts, idx = grid(1, 1)

    def setup(stage, mesh):
        UsdGeom.Subset.CreateGeomSubset(mesh, "bad", "edge", Vt.IntArray([0, 1, 0, 3]), "seams")

    src = write_mesh(tmp_path / "edges.usda", pts, counts, idx, setup=setup)
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu")
    assert any("/World/Mesh/bad: edge 1 (0, 3) is not an edge of the mesh; the subset is dropped" in w
               for w in result.warnings), result.warnings
    assert UsdGeom.Subset(out_prim(dst).GetChild("bad")).GetIndicesAttr().Get() is None


# -- item 20 -------------------------------------------------------------------------------------------

def test_flattened_layer_doc_names_no_temporary_file(tmp_path):
    """--flatten: the flattened layer's doc names the input it came from, not the deleted temporary file."""
    pts, counts, idx = grid(1, 1)
    src = write_mesh(tmp_path / "in.usda", pts, counts, idx)
    dst = tmp_path / "flat.usda"
    refine_usd(src, str(dst), 1, device="cpu", flatten=True)
    doc = Sdf.Layer.FindOrOpen(str(dst)).documentation
    assert ".warp-subdiv-" not in doc and "in.usda" in doc, doc


@pytest.mark.parametrize("text", ["nan", "1:inf", "-inf:3", "nan:", ":inf"])
def test_frames_must_be_finite(text):
    """--frames nan, 1:inf and the like are refused (time codes are finite)."""
    from warp_subdiv.io.usd_stage import parse_frames

    with pytest.raises(SubdivInputError, match="frames .*finite"):
        parse_frames(text)


# -- time-sampled primvars whose indexing changes ----------------------------------------------------------

#: (time, values, indices as a function of the element number) of the primvars of reindexed_primvars_scene:
#: the indices change at 7 (all 0 -> all 1), 10 (alternating) and 13 (three values: USD holds values of
#: another length), not at 16.
REINDEXED = [(1.0, [0.0, 10.0], lambda i: 0), (7.0, [0.0, 15.0], lambda i: 1), (10.0, [5.0, 15.0], lambda i: i % 2),
             (13.0, [1.0, 2.0, 3.0], lambda i: i % 3), (16.0, [2.0, 3.0, 4.0], lambda i: i % 3)]
#: Times to compare at: samples, sub-frames, just before and after a change, outside the samples.
REINDEXED_TIMES = [0.0, 1.0, 2.5, 4.0, 6.99, 7.0, 8.5, 10.0, 11.5, 12.99, 13.0, 14.5, 16.0, 17.0]


def reindexed_primvars_scene(path, times=REINDEXED):
    """A 2 x 2 grid with indexed vertex, varying, face-varying and uniform primvars whose values and indices are
    time-sampled together (``times``)."""
    pts, counts, idx = grid(2, 2)

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        for name, interp, n in (("v", "vertex", 9), ("vy", "varying", 9), ("fv", "faceVarying", 16),
                                ("u", "uniform", 4)):
            pv = api.CreatePrimvar(name, T.FloatArray, interp)
            for t, values, index in times:
                pv.Set(Vt.FloatArray(values), t)
                pv.SetIndices(Vt.IntArray([index(i) for i in range(n)]), t)

    return write_mesh(path, pts, counts, idx, setup=setup)


def test_primvars_read_as_the_input_where_their_indices_change(tmp_path):
    """USD interpolates a primvar's values between samples but holds its indices (and holds values of another
    length): where the indices change, the input reads the earlier indices with interpolated values until the
    next sample (at 4 it reads 0 everywhere). The refined primvars, flattened or re-indexed per sample, read as
    the input at every time, sub-frames included: as the refinement of the input's values at that time."""
    src = reindexed_primvars_scene(tmp_path / "in.usda")
    dst = tmp_path / "out.usda"
    refine_usd(src, str(dst), 1, device="cpu")
    out = UsdGeom.PrimvarsAPI(out_prim(dst))
    for t in REINDEXED_TIMES:
        at_t = tmp_path / f"at_{t}.usda"  # the input as it is at t, refined (its primvars written at t)
        refine_usd(src, str(at_t), 1, device="cpu", frames=(t, t))
        expected = UsdGeom.PrimvarsAPI(out_prim(at_t))
        for name in ("v", "vy", "fv", "u"):
            got = np.asarray(out.GetPrimvar(name).ComputeFlattened(t))
            want = np.asarray(expected.GetPrimvar(name).ComputeFlattened(t))
            np.testing.assert_allclose(got, want, atol=1e-5, err_msg=f"{name} at {t}")
    src_api = UsdGeom.PrimvarsAPI(out_prim(src))
    assert np.all(np.asarray(src_api.GetPrimvar("fv").ComputeFlattened(4.0)) == 0.0)  # what the user saw
