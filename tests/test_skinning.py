"""Skinned meshes and blend shapes (UsdSkel): the bake refines what a renderer draws, against usd-core's own
skinning (UsdSkel.BakeSkinning) at every frame; bad bindings are refused by name."""
import importlib.util
import os
import sys

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

import warp_subdiv as ws
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.io.usd_read import read_mesh
from warp_subdiv.usd import refine_usd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES_DIR = os.path.join(ROOT, "scenes")
CHARACTER = "/World/Character"
MESHES = ("Leg", "Foot")


def scenes():
    name = "make_scenes_for_skinning"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, os.path.join(SCENES_DIR, "make_scenes.py"))
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


def character(tmp_path, name="character.usda", **kw) -> str:
    kw.setdefault("frames", 4)
    return scenes().write_skinned_character(str(tmp_path / name), **kw)


def mesh_paths(stage):
    return [p.GetPath() for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]


def world_points(prim, t) -> np.ndarray:
    m = np.array(UsdGeom.Imageable(prim).ComputeLocalToWorldTransform(t))
    pts = np.asarray(prim.GetAttribute("points").Get(t), dtype=np.float64)
    return pts @ m[:3, :3] + m[3, :3]


def usdskel_baked(src: str):
    """The input as UsdSkel.BakeSkinning poses it (in the session layer of a stage of its own)."""
    stage = Usd.Stage.Open(src)
    # the session layer's times are scaled to the root layer's by their timeCodesPerSecond: the same, unscaled
    stage.GetSessionLayer().timeCodesPerSecond = stage.GetRootLayer().timeCodesPerSecond
    stage.SetEditTarget(stage.GetSessionLayer())
    assert UsdSkel.BakeSkinning(UsdSkel.Root(stage.GetPrimAtPath(CHARACTER)),
                                Gf.Interval(stage.GetStartTimeCode(), stage.GetEndTimeCode()))
    return stage


def reference_refined(src_stage, baked_stage, path, t, levels) -> np.ndarray:
    """refine(UsdSkel's deformed control points at ``t``) in world space, OpenSubdiv's vertex order."""
    sp = read_mesh(src_stage.GetPrimAtPath(path))
    pts = world_points(baked_stage.GetPrimAtPath(path), t)
    return ws.Refiner(sp.mesh, levels, device="cpu").evaluate(pts)


CASES = {
    "lbs": dict(method="classicLinear", blend_shapes=False, geom_bind_transform=False, rigid=False),
    "lbs-blend-bind-rigid-xform": dict(method="classicLinear", animated_xform=True),
    "dqs": dict(method="dualQuaternion", blend_shapes=False, rigid=False),
    "dqs-blend-rigid-xform": dict(method="dualQuaternion", geom_bind_transform=False, animated_xform=True),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bake_is_the_refinement_of_usdskel_points_at_every_frame(tmp_path, case):
    """Linear-blend and dual-quaternion skinning, with and without blend shapes and a geomBindTransform, rigid
    (constant) influences, under an animated Xform: at every frame the baked mesh is, in world space, the
    refinement of the control points UsdSkel.BakeSkinning computes (for a rigid mesh it bakes a transform)."""
    levels = 1
    src = character(tmp_path, **CASES[case])
    out = str(tmp_path / "out.usda")
    result = refine_usd(src, out, levels, device="cpu", vertex_order="opensubdiv")
    assert not [w for w in result.warnings if "skel" in w], result.warnings
    source, baked, refined = Usd.Stage.Open(src), usdskel_baked(src), Usd.Stage.Open(out)
    paths = mesh_paths(source)
    assert len(paths) == (1 if "rigid" not in case else 2)
    for path in paths:
        prim = refined.GetPrimAtPath(path)
        times = prim.GetAttribute("points").GetTimeSamples()
        assert times == [1.0, 2.0, 3.0, 4.0]
        for t in times:
            got = world_points(prim, t)
            expected = reference_refined(source, baked, path, t, levels)
            np.testing.assert_allclose(got, expected, atol=2e-6, err_msg=f"{path} at {t}")
            extent = np.asarray(prim.GetAttribute("extent").Get(t))
            local = np.asarray(prim.GetAttribute("points").Get(t))
            np.testing.assert_array_equal(extent, [local.min(0), local.max(0)])
        # the pose moves: frames differ
        assert np.abs(world_points(prim, 4.0) - world_points(prim, 1.0)).max() > 0.1
    # nothing skins the refined meshes again; the skeleton and its animation stay
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(refined.GetPrimAtPath(CHARACTER))
    cache.Populate(root, Usd.TraverseInstanceProxies())
    assert all(len(b.GetSkinningTargets()) == 0 for b in cache.ComputeSkelBindings(root, Usd.TraverseInstanceProxies()))
    assert refined.GetPrimAtPath(CHARACTER + "/Skel/Anim").IsA(UsdSkel.Animation)
    for path in paths:
        prim = refined.GetPrimAtPath(path)
        assert not UsdSkel.BindingAPI(prim).GetInheritedSkeleton()
        for name in ("primvars:skel:jointIndices", "primvars:skel:jointWeights"):
            assert prim.GetAttribute(name).Get() is None


def test_default_time_is_usdskel_pose_there_and_frames_select_samples(tmp_path):
    """The default value is the pose UsdSkel gives at the default time (the rest pose for an animation without
    defaults: without a geomBindTransform, the rest points); ``frames`` selects the samples baked."""
    src = character(tmp_path, method="classicLinear", rigid=False, geom_bind_transform=False)
    out = str(tmp_path / "out.usda")
    refine_usd(src, out, 1, device="cpu", vertex_order="opensubdiv", frames=(2, 3))
    refined, source = Usd.Stage.Open(out), Usd.Stage.Open(src)
    path = CHARACTER + "/Leg"
    prim = refined.GetPrimAtPath(path)
    assert prim.GetAttribute("points").GetTimeSamples() == [2.0, 3.0]
    sp = read_mesh(source.GetPrimAtPath(path))
    rest = ws.Refiner(sp.mesh, 1, device="cpu").evaluate(sp.points_default)
    np.testing.assert_allclose(np.asarray(prim.GetAttribute("points").Get()), rest, atol=1e-6)


def test_skinning_none_refines_the_rest_pose_and_drops_the_binding(tmp_path):
    src = character(tmp_path)
    out = str(tmp_path / "out.usda")
    result = refine_usd(src, out, 1, device="cpu", vertex_order="opensubdiv", skinning="none")
    assert any("skinning none" in w and "/Leg" in w for w in result.warnings)
    refined, source = Usd.Stage.Open(out), Usd.Stage.Open(src)
    prim = refined.GetPrimAtPath(CHARACTER + "/Leg")
    assert prim.GetAttribute("points").GetTimeSamples() == []
    sp = read_mesh(source.GetPrimAtPath(CHARACTER + "/Leg"))
    rest = ws.Refiner(sp.mesh, 1, device="cpu").evaluate(sp.points_default)
    np.testing.assert_allclose(np.asarray(prim.GetAttribute("points").Get()), rest, atol=1e-6)
    assert not UsdSkel.BindingAPI(prim).GetInheritedSkeleton()
    assert prim.GetAttribute("skel:blendShapes").Get() is None


def test_the_character_scene_is_what_make_scenes_writes(tmp_path):
    path = scenes().write_skinned_character(str(tmp_path / "skinned_character.usda"))
    with open(os.path.join(SCENES_DIR, "skinned_character.usda")) as fh:
        assert open(path).read() == fh.read()


def _edited(tmp_path, edit, **kw):
    src = character(tmp_path, **kw)
    stage = Usd.Stage.Open(src)
    edit(stage)
    stage.GetRootLayer().Save()
    return src


def _refuse(src, tmp_path, match, **kw):
    with pytest.raises(SubdivInputError, match=match):
        refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu", **kw)
    assert not os.path.exists(tmp_path / "out.usda")


def test_joint_index_out_of_range_is_refused(tmp_path):
    def edit(stage):
        attr = stage.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("primvars:skel:jointIndices")
        idx = list(attr.Get())
        idx[5] = 7
        attr.Set(Vt.IntArray(idx))
    _refuse(_edited(tmp_path, edit), tmp_path,
            r"/World/Character/Leg: primvars:skel:jointIndices\[5\] = 7 is not one of the 2 joints")


def test_element_size_mismatch_is_refused(tmp_path):
    def edit(stage):
        UsdGeom.Primvar(stage.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("primvars:skel:jointWeights")
                        ).SetElementSize(4)
    _refuse(_edited(tmp_path, edit), tmp_path, r"/World/Character/Leg: primvars:skel:jointWeights has 40 values; "
                                               r"with elementSize 4")


def test_animation_that_is_not_a_skel_animation_is_refused(tmp_path):
    def edit(stage):
        UsdGeom.Xform.Define(stage, "/World/NotAnAnimation")
        UsdSkel.BindingAPI(stage.GetPrimAtPath(CHARACTER + "/Skel")).GetAnimationSourceRel().SetTargets(
            ["/World/NotAnAnimation"])
    _refuse(_edited(tmp_path, edit), tmp_path, r"/World/Character/Skel: skel:animationSource targets "
                                               r"/World/NotAnAnimation, which is not a SkelAnimation")


def test_animation_arrays_that_do_not_fit_the_joints_are_refused(tmp_path):
    """UsdSkel would pose such a frame as the rest pose with a console warning only."""
    def edit(stage):
        stage.GetPrimAtPath(CHARACTER + "/Skel/Anim").GetAttribute("translations").Set(
            Vt.Vec3fArray([Gf.Vec3f(0, 0, 0)]), 3.0)
    _refuse(_edited(tmp_path, edit), tmp_path,
            r"/World/Character/Skel/Anim: translations at time 3 has 1 entries for 2 joints")


def test_skeleton_without_animation_or_rest_pose_is_refused(tmp_path):
    def edit(stage):
        skel = stage.GetPrimAtPath(CHARACTER + "/Skel")
        UsdSkel.BindingAPI(skel).GetAnimationSourceRel().ClearTargets(True)
        skel.GetAttribute("restTransforms").Clear()
    _refuse(_edited(tmp_path, edit), tmp_path, r"/World/Character/Skel: no skel:animationSource and no "
                                               r"restTransforms")


def test_weights_that_do_not_sum_to_one_are_reported(tmp_path):
    def edit(stage):
        attr = stage.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("primvars:skel:jointWeights")
        attr.Set(Vt.FloatArray([2 * w for w in attr.Get()]))
    src = _edited(tmp_path, edit)
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert any("/World/Character/Leg: primvars:skel:jointWeights do not sum to one at 20 of 20 points" in w
               for w in result.warnings), result.warnings


def test_bad_skinning_option_is_refused(tmp_path):
    _refuse(character(tmp_path), tmp_path, r"skinning must be one of bake, keep, none", skinning="bend")
    _refuse(character(tmp_path), tmp_path, r"max_influences must be an integer >= 1", skinning="keep",
            max_influences=0)
    _refuse(character(tmp_path), tmp_path, r"max_influences applies to skinning keep", max_influences=2)


def test_influences_without_a_skeleton_are_dropped_with_a_warning(tmp_path):
    def edit(stage):
        UsdSkel.BindingAPI(stage.GetPrimAtPath(CHARACTER + "/Leg")).GetSkeletonRel().ClearTargets(True)
    src = _edited(tmp_path, edit, rigid=False)
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert any("/World/Character/Leg: joint influences or blend shapes without a bound skeleton" in w
               for w in result.warnings), result.warnings
    assert not any("cannot be interpolated" in w for w in result.warnings)


def _validation_errors(stage):
    from pxr import UsdValidation

    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    return [e.GetMessage() for e in UsdValidation.ValidationContext(validators).Validate(stage)]


def test_keep_writes_a_valid_binding_whose_deviation_is_reported(tmp_path):
    """keep: UsdValidation is clean, UsdSkel skins the output, weights sum to one with the input's elementSize,
    the rest pose refines exactly, blend-shape offsets are the refinement of the input's, and the largest deviation
    reported is the one UsdSkel's own bake of the output shows against the baked surface (and it is small)."""
    levels = 2
    src = character(tmp_path)
    kept, baked = str(tmp_path / "kept.usda"), str(tmp_path / "baked.usda")
    result = refine_usd(src, kept, levels, device="cpu", vertex_order="opensubdiv", skinning="keep")
    refine_usd(src, baked, levels, device="cpu", vertex_order="opensubdiv")
    notes = [w for w in result.warnings if "skinning keep" in w]
    assert len(notes) == 1 and notes[0].startswith("/World/Character/Leg: ")
    reported = float(notes[0].split("largest deviation ")[1].split(" ")[0])
    out, source = Usd.Stage.Open(kept), Usd.Stage.Open(src)
    assert _validation_errors(out) == []
    leg = out.GetPrimAtPath(CHARACTER + "/Leg")
    weights = UsdGeom.Primvar(leg.GetAttribute("primvars:skel:jointWeights"))
    indices = UsdGeom.Primvar(leg.GetAttribute("primvars:skel:jointIndices"))
    assert weights.GetElementSize() == indices.GetElementSize() == 2
    assert weights.GetInterpolation() == indices.GetInterpolation() == "vertex"
    w = np.asarray(weights.Get()).reshape(-1, 2)
    assert len(w) == len(leg.GetAttribute("points").Get())
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-6)
    assert np.all(np.diff(w, axis=1) <= 0)  # largest first
    sp = read_mesh(source.GetPrimAtPath(CHARACTER + "/Leg"))
    refiner = ws.Refiner(sp.mesh, levels, device="cpu")
    np.testing.assert_allclose(np.asarray(leg.GetAttribute("points").Get()), refiner.evaluate(sp.points_default),
                               atol=1e-6)
    # the blend shape's refined offsets: exactly the refinement of the input's (zero where they reach nothing)
    shape_in = UsdSkel.BlendShape(source.GetPrimAtPath(CHARACTER + "/Leg/bulge"))
    dense = np.zeros((sp.mesh.num_vertices, 3))
    dense[np.asarray(shape_in.GetPointIndicesAttr().Get())] = np.asarray(shape_in.GetOffsetsAttr().Get())
    expected = refiner.evaluate(dense, normal_control=False)
    shape_out = UsdSkel.BlendShape(out.GetPrimAtPath(CHARACTER + "/Leg/bulge"))
    got = np.zeros_like(expected)
    got[np.asarray(shape_out.GetPointIndicesAttr().Get())] = np.asarray(shape_out.GetOffsetsAttr().Get())
    np.testing.assert_allclose(got, expected, atol=1e-7)
    assert 0 < len(shape_out.GetPointIndicesAttr().Get()) < len(expected)
    # UsdSkel's own skinning of the output against the baked surface: the deviation reported
    skinned = usdskel_baked(kept)
    reference = Usd.Stage.Open(baked)
    worst = 0.0
    for t in range(1, 5):
        for name in MESHES:
            path = f"{CHARACTER}/{name}"
            d = np.linalg.norm(world_points(skinned.GetPrimAtPath(path), t)
                               - world_points(reference.GetPrimAtPath(path), t), axis=1).max()
            if name == "Foot":
                assert d < 1e-5  # rigid influences commute with refinement
            worst = max(worst, d)
    assert worst == pytest.approx(reported, rel=2e-2)
    assert 0.01 < reported < 0.2  # bounded on the test character (under 10% of its 2-unit leg, knee bent 90°)


def test_keep_max_influences(tmp_path):
    src = character(tmp_path, blend_shapes=False, rigid=False)
    out = str(tmp_path / "kept.usda")
    refine_usd(src, out, 1, device="cpu", skinning="keep", max_influences=1)
    stage = Usd.Stage.Open(out)
    leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
    weights = UsdGeom.Primvar(leg.GetAttribute("primvars:skel:jointWeights"))
    assert weights.GetElementSize() == 1
    np.testing.assert_array_equal(np.asarray(weights.Get()), 1.0)
    assert set(np.asarray(leg.GetAttribute("primvars:skel:jointIndices").Get())) == {0, 1}
    assert _validation_errors(stage) == []


def _same_points(a: str, b: str, times):
    sa, sb = Usd.Stage.Open(a), Usd.Stage.Open(b)
    for name in MESHES:
        pa, pb = sa.GetPrimAtPath(f"{CHARACTER}/{name}"), sb.GetPrimAtPath(f"{CHARACTER}/{name}")
        for t in [Usd.TimeCode.Default()] + list(times):
            for attr in ("points", "extent"):
                np.testing.assert_array_equal(np.asarray(pa.GetAttribute(attr).Get(t)),
                                              np.asarray(pb.GetAttribute(attr).Get(t)), err_msg=f"{name} {attr} {t}")
        assert not UsdSkel.BindingAPI(pb).GetInheritedSkeleton()


def test_frame_chunks_of_a_skinned_bake_stitch_to_the_single_bake(tmp_path):
    """`refine --frames A:B` chunks of a skinned bake (a farm's, or a distributed bake's frame tasks) stitch
    to the single-process bake."""
    from warp_subdiv.usd import stitch

    src = character(tmp_path, frames=6)
    single = str(tmp_path / "single.usda")
    refine_usd(src, single, 1, device="cpu")
    chunks = []
    for k, frames in enumerate([(None, 3), (3, None)]):
        chunks.append(str(tmp_path / f"chunk{k}.usdc"))
        refine_usd(src, chunks[-1], 1, device="cpu", frames=frames)
    stitch(chunks, str(tmp_path / "stitched.usda"))
    _same_points(single, str(tmp_path / "stitched.usda"), range(1, 7))
    other = str(tmp_path / "other.usdc")
    refine_usd(src, other, 1, device="cpu", frames=(3, None), skinning="none")
    with pytest.raises(SubdivInputError, match=r"skinning differs"):
        stitch([chunks[0], other], str(tmp_path / "nope.usda"))


def test_distributed_bake_of_a_skinned_character(tmp_path):
    """The distributed bake splits a skinned mesh's frames across workers, each deforming its own frames."""
    from conftest import dask_client
    from warp_subdiv.usd import bake

    src = character(tmp_path, frames=6)
    single = str(tmp_path / "single.usda")
    refine_usd(src, single, 1, device="cpu")
    out = str(tmp_path / "dist.usda")
    with dask_client(n_workers=2, processes=False) as client:
        result = bake(src, out, 1, chunk_frames=2, client=client, device="cpu")
    assert [r.samples for r in result.reports] == [6, 6]
    _same_points(single, out, range(1, 7))


def crowd(tmp_path) -> str:
    """Two instanceable references to the character asset."""
    asset = character(tmp_path, name="asset.usda")
    layer = Sdf.Layer.CreateNew(str(tmp_path / "crowd.usda"))
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    for i in range(2):
        prim = UsdGeom.Xform.Define(stage, f"/Crowd/C{i}")
        prim.AddTranslateOp().Set(Gf.Vec3d(3.0 * i, 0, 0))
        prim.GetPrim().GetReferences().AddReference(asset, "/World")
        prim.GetPrim().SetInstanceable(True)
    layer.Save()
    return layer.realPath


def test_skinned_meshes_inside_instances(tmp_path):
    """Inside instances, bake is refused (each instance may be posed by its own animation: baking would take
    the instances apart); keep refines the prototype once, which every instance still skins, and none too."""
    src = crowd(tmp_path)
    _refuse(src, tmp_path, r"/Crowd/C0/Character/Leg: a skinned mesh inside an instance: .* skinning keep")
    for mode in ("keep", "none"):
        out = str(tmp_path / f"{mode}.usda")
        result = refine_usd(src, out, 1, device="cpu", skinning=mode)
        assert len(result.reports) == 2  # one prototype's leg and foot
        stage = Usd.Stage.Open(out)
        for i in range(2):
            assert stage.GetPrimAtPath(f"/Crowd/C{i}").IsInstance()
            leg = stage.GetPrimAtPath(f"/Crowd/C{i}/Character/Leg")
            assert len(leg.GetAttribute("points").Get()) == 74
            root = UsdSkel.Root(stage.GetPrimAtPath(f"/Crowd/C{i}/Character"))
            cache = UsdSkel.Cache()
            cache.Populate(root, Usd.TraverseInstanceProxies())
            query = cache.GetSkinningQuery(leg)
            if mode == "keep":
                assert query.HasJointInfluences() and query.HasBlendShapes()
                assert len(leg.GetAttribute("primvars:skel:jointWeights").Get()) == 2 * 74
            else:
                assert not UsdSkel.BindingAPI(leg).GetInheritedSkeleton()


def test_tessellate_bakes_the_skinned_pose(tmp_path):
    """tessellate: at every frame, the tessellation of the control points UsdSkel poses there; binding dropped."""
    from warp_subdiv.usd.tessellate import tessellate_file

    src = character(tmp_path, rigid=False)
    out = str(tmp_path / "tess.usda")
    tessellate_file(src, out, rate=2, rules="opensubdiv")
    stage, baked, source = Usd.Stage.Open(out), usdskel_baked(src), Usd.Stage.Open(src)
    path = CHARACTER + "/Leg"
    prim = stage.GetPrimAtPath(path)
    assert prim.GetAttribute("points").GetTimeSamples() == [1.0, 2.0, 3.0, 4.0]
    sp = read_mesh(source.GetPrimAtPath(path))
    for t in (2.0, 4.0):
        posed = np.asarray(baked.GetPrimAtPath(path).GetAttribute("points").Get(t), dtype=np.float64)
        expected = ws.LimitSurface(ws.Mesh(posed, sp.mesh.face_vertex_counts, sp.mesh.face_vertex_indices),
                                   rules="opensubdiv").tessellate(rate=2).points
        np.testing.assert_allclose(np.asarray(prim.GetAttribute("points").Get(t)), expected, atol=2e-6)
    assert not UsdSkel.BindingAPI(prim).GetInheritedSkeleton()


def test_render_draws_the_skinned_pose(tmp_path):
    """render --time of the input (refined for the preview) draws what the bake wrote at that time, not the rest
    pose."""
    from warp_subdiv.render import render_file

    src = character(tmp_path)
    baked, rest = str(tmp_path / "baked.usda"), str(tmp_path / "rest.usda")
    refine_usd(src, baked, 1, device="cpu")
    refine_usd(src, rest, 1, device="cpu", skinning="none")
    kw = dict(size=(96, 72), samples=1, device="cpu", view=(-60.0, 20.0), time=4.0)
    img_in = render_file(src, str(tmp_path / "in.png"), levels=1, **kw).astype(np.float64)
    img_baked = render_file(baked, str(tmp_path / "baked.png"), **kw).astype(np.float64)
    img_rest = render_file(rest, str(tmp_path / "rest.png"), **kw).astype(np.float64)
    assert np.abs(img_in - img_baked).mean() < 0.01 * np.abs(img_in - img_rest).mean()


def test_cli_skinning_and_info(tmp_path, capsys):
    from warp_subdiv.cli import main

    src = character(tmp_path)
    assert main(["info", src, "--levels", "1"]) == 0
    text = capsys.readouterr().out
    assert ("skinned: bound to /World/Character/Skel (2 joints, animation /World/Character/Skel/Anim); 2 vertex "
            "influences, dualQuaternion; 1 blend shapes; baked at 4 times (1 to 4)") in text
    assert "1 constant influences" in text
    out = str(tmp_path / "out.usda")
    assert main(["refine", src, "-o", out, "--levels", "1", "--skinning", "keep", "--max-influences", "1",
                 "--device", "cpu", "--quiet"]) == 0
    assert "skinning keep" in capsys.readouterr().err
    stage = Usd.Stage.Open(out)
    leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
    assert UsdGeom.Primvar(leg.GetAttribute("primvars:skel:jointWeights")).GetElementSize() == 1
    assert main(["refine", src, "-o", out, "--levels", "1", "--skinning", "bend", "--quiet"]) == 2


def test_limit_points_and_normals_per_sample_batched_or_not(tmp_path):
    """--limit --normals: limit points and normals of the posed cage at every frame; small meshes evaluated in a
    batch write what they write alone."""
    src = character(tmp_path, rigid=False, geom_bind_transform=False)
    outs = [str(tmp_path / f"out{b}.usda") for b in (0, 1)]
    for batch, out in zip((False, True), outs):
        refine_usd(src, out, 1, device="cpu", vertex_order="opensubdiv", limit=True, normals=True, batch=batch)
    stages = [Usd.Stage.Open(o) for o in outs]
    baked, source = usdskel_baked(src), Usd.Stage.Open(src)
    path = CHARACTER + "/Leg"
    sp = read_mesh(source.GetPrimAtPath(path))
    refiner = ws.Refiner(sp.mesh, 1, device="cpu")
    for t in (1.0, 3.0):
        posed = np.asarray(baked.GetPrimAtPath(path).GetAttribute("points").Get(t), dtype=np.float64)
        res = refiner.evaluate_with_limits(posed, limit_points=True, limit_normals=True)
        prims = [s.GetPrimAtPath(path) for s in stages]
        np.testing.assert_allclose(np.asarray(prims[0].GetAttribute("points").Get(t)), res.limit_points, atol=2e-6)
        np.testing.assert_allclose(np.asarray(prims[0].GetAttribute("normals").Get(t)), res.limit_normals, atol=2e-5)
        for name in ("points", "normals", "extent"):
            np.testing.assert_array_equal(np.asarray(prims[0].GetAttribute(name).Get(t)),
                                          np.asarray(prims[1].GetAttribute(name).Get(t)))
    assert stages[0].GetPrimAtPath(path).GetAttribute("normals").GetTimeSamples() == [1.0, 2.0, 3.0, 4.0]


def test_binding_api_without_influences_is_a_plain_mesh(tmp_path):
    """Exporters apply SkelBindingAPI widely: a mesh under the SkelRoot with it but neither joint influences nor
    blend shapes is not deformed by UsdSkel, and is refined as any mesh, without a word."""
    def edit(stage):
        src = stage.GetPrimAtPath(CHARACTER + "/Foot")
        prop = UsdGeom.Mesh.Define(stage, CHARACTER + "/Prop")
        for name in ("points", "faceVertexCounts", "faceVertexIndices"):
            prop.GetPrim().GetAttribute(name).Set(src.GetAttribute(name).Get())
        UsdSkel.BindingAPI.Apply(prop.GetPrim())
    src = _edited(tmp_path, edit)
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert not [w for w in result.warnings if "Prop" in w], result.warnings
    stage = Usd.Stage.Open(str(tmp_path / "out.usda"))
    assert stage.GetPrimAtPath(CHARACTER + "/Prop").GetAttribute("points").GetTimeSamples() == []
    assert len(stage.GetPrimAtPath(CHARACTER + "/Prop").GetAttribute("points").Get()) == 26


def test_deformed_points_kept_for_a_second_request_are_bounded(tmp_path, monkeypatch):
    """A second request of a time (the writer after a worker) gets the same points, kept or computed again;
    what is kept stays under CACHE_BYTES, the oldest times dropped first."""
    from warp_subdiv.usd import skinning
    from warp_subdiv.usd.planning import plan

    p = plan(character(tmp_path, rigid=False, frames=6), 1, device="cpu")
    sp = p.prims[0]
    frame_bytes = sp.mesh.num_vertices * 3 * 4
    monkeypatch.setattr(skinning, "CACHE_BYTES", 2 * frame_bytes)
    first = {t: skinning.skinned_points(sp, t) for t in sp.point_times}
    assert list(sp.skin.cache) == [5.0, 6.0]
    for t in sp.point_times:
        np.testing.assert_array_equal(skinning.skinned_points(sp, t), first[t])  # kept or computed again


def test_a_mesh_with_its_own_joint_order(tmp_path):
    """skel:joints on the mesh (its own joint order, indices into it): bake and keep skin as with the skeleton's
    order and the indices mapped."""
    plain = character(tmp_path, name="plain.usda", rigid=False)

    def edit(stage):
        leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
        UsdSkel.BindingAPI(leg).CreateJointsAttr(["hip/knee", "hip"])
        attr = leg.GetAttribute("primvars:skel:jointIndices")
        attr.Set(Vt.IntArray([1 - i for i in attr.Get()]))
    reordered = _edited(tmp_path, edit, name="reordered.usda", rigid=False)
    for mode in ("bake", "keep"):
        outs = [str(tmp_path / f"{mode}_{k}.usda") for k in range(2)]
        notes = [refine_usd(src, out, 1, device="cpu", skinning=mode).warnings for src, out in zip((plain, reordered),
                                                                                                    outs)]
        assert [n.split("deviation")[-1] for n in notes[0]] == [n.split("deviation")[-1] for n in notes[1]]
        stages = [Usd.Stage.Open(o) for o in outs]
        for t in (2.0, 4.0):
            a, b = (np.asarray(s.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("points").Get(t)) for s in stages)
            np.testing.assert_allclose(a, b, atol=1e-6)
        if mode == "keep":  # the same weight per joint name at every refined vertex
            dense = []
            for stage, order in zip(stages, ([0, 1], [1, 0])):
                leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
                idx = np.asarray(leg.GetAttribute("primvars:skel:jointIndices").Get()).reshape(-1, 2)
                w = np.asarray(leg.GetAttribute("primvars:skel:jointWeights").Get()).reshape(-1, 2)
                out = np.zeros((len(w), 2))
                np.add.at(out, (np.repeat(np.arange(len(w)), 2), np.asarray(order)[idx.reshape(-1)]), w.reshape(-1))
                dense.append(out)
            np.testing.assert_allclose(dense[0], dense[1], atol=1e-7)


def test_info_describes_skinned_meshes_inside_instances(tmp_path, capsys):
    """info never refuses a valid file: a skinned mesh inside an instance, which the default bake refuses, is
    described (joints, animation, the times its pose changes at) with the treatments that apply."""
    from warp_subdiv.cli import main

    assert main(["info", crowd(tmp_path), "--levels", "1"]) == 0
    text = capsys.readouterr().out
    lines = [line for line in text.splitlines() if line.startswith("  skinned: ")]
    assert len(lines) == 2, text  # the prototype's leg and foot, once each
    assert lines[0].startswith("  skinned: bound to /Crowd/C0/Character/Skel (2 joints, animation "
                               "/Crowd/C0/Character/Skel/Anim); 2 vertex influences, dualQuaternion; 1 blend shapes")
    for line in lines:
        assert line.endswith("; posed at 4 times (1 to 4); skinning bake refused inside an instance (each instance "
                             "may be posed by its own animation, so baking it would take the instance apart): use "
                             "keep (the refined prototype stays skinned) or none, or make the instance not "
                             "instanceable"), line
    assert "time: static points" in text  # predicted as keep and none refine it: the rest pose


def test_keep_with_limit_writes_rest_limit_data_and_no_normals(tmp_path):
    """keep with limit: the rest pose's limit points, the limit values of each joint's weight column and of the
    blend-shape offsets (so rest pose and blend shapes stay exact), the deviation measured against the baked limit
    surface; normals asked for are not written on a mesh that stays skinned (renderers treat them differently),
    with a warning, and the input's authored normals are blocked."""
    from warp_subdiv.usd.skinning_output import KEPT_NORMALS

    levels = 1

    def edit(stage):  # authored normals on the control mesh: they must not reach the refined one
        leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
        UsdGeom.Mesh(leg).CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)] * 20))
    src = _edited(tmp_path, edit)
    kept, baked = str(tmp_path / "kept.usda"), str(tmp_path / "baked.usda")
    result = refine_usd(src, kept, levels, device="cpu", vertex_order="opensubdiv", skinning="keep", limit=True,
                        normals=True)
    refine_usd(src, baked, levels, device="cpu", vertex_order="opensubdiv", limit=True)
    assert f"{CHARACTER}/Leg: {KEPT_NORMALS}" in result.warnings
    out, source = Usd.Stage.Open(kept), Usd.Stage.Open(src)
    assert _validation_errors(out) == []
    leg = out.GetPrimAtPath(CHARACTER + "/Leg")
    assert leg.GetAttribute("normals").Get() is None
    sp = read_mesh(source.GetPrimAtPath(CHARACTER + "/Leg"))
    refiner = ws.Refiner(sp.mesh, levels, device="cpu")

    def limit_of(rows):
        return refiner.evaluate_with_limits(np.asarray(rows, dtype=np.float64), limit_points=True).limit_points

    np.testing.assert_allclose(np.asarray(leg.GetAttribute("points").Get()), limit_of(sp.points_default), atol=1e-6)
    # weights: the limit of each joint's column (two joints, two influences: none dropped), per joint
    idx_in = np.asarray(source.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("primvars:skel:jointIndices").Get())
    w_in = np.asarray(source.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("primvars:skel:jointWeights").Get())
    columns = np.zeros((sp.mesh.num_vertices, 2))
    np.add.at(columns, (np.repeat(np.arange(sp.mesh.num_vertices), 2), idx_in), w_in)
    expected = np.stack([limit_of(np.repeat(columns[:, j:j + 1], 3, axis=1))[:, 0] for j in range(2)], axis=1)
    idx = np.asarray(leg.GetAttribute("primvars:skel:jointIndices").Get()).reshape(-1, 2)
    w = np.asarray(leg.GetAttribute("primvars:skel:jointWeights").Get()).reshape(-1, 2)
    got = np.zeros_like(expected)
    np.add.at(got, (np.repeat(np.arange(len(w)), 2), idx.reshape(-1)), w.reshape(-1))
    np.testing.assert_allclose(got, expected / expected.sum(axis=1, keepdims=True), atol=1e-6)
    # the blend shape's offsets: the limit of the input's
    shape_in = UsdSkel.BlendShape(source.GetPrimAtPath(CHARACTER + "/Leg/bulge"))
    dense = np.zeros((sp.mesh.num_vertices, 3))
    dense[np.asarray(shape_in.GetPointIndicesAttr().Get())] = np.asarray(shape_in.GetOffsetsAttr().Get())
    shape_out = UsdSkel.BlendShape(out.GetPrimAtPath(CHARACTER + "/Leg/bulge"))
    offsets = np.zeros((len(w), 3))
    offsets[np.asarray(shape_out.GetPointIndicesAttr().Get())] = np.asarray(shape_out.GetOffsetsAttr().Get())
    np.testing.assert_allclose(offsets, limit_of(dense), atol=1e-7)
    # the deviation reported: UsdSkel's skinning of the kept limit data against the baked limit surface
    note = next(n for n in result.warnings if "largest deviation" in n)
    reported = float(note.split("largest deviation ")[1].split(" ")[0])
    skinned, reference = usdskel_baked(kept), Usd.Stage.Open(baked)
    worst = max(np.linalg.norm(world_points(skinned.GetPrimAtPath(CHARACTER + "/Leg"), t)
                               - world_points(reference.GetPrimAtPath(CHARACTER + "/Leg"), t), axis=1).max()
                for t in range(1, 5))
    assert worst == pytest.approx(reported, rel=2e-2) and 0.01 < reported < 0.3


def _with_velocities(tmp_path, name="moving.usda", tcps=30.0):
    """The character (its leg only, deformed; 6 frames) with rest-space velocities and accelerations authored on
    the leg, as an exporter might leave them, and ``tcps`` time codes per second."""
    def edit(stage):
        stage.SetTimeCodesPerSecond(tcps)
        leg = UsdGeom.Mesh(stage.GetPrimAtPath(CHARACTER + "/Leg"))
        leg.CreateVelocitiesAttr(Vt.Vec3fArray([Gf.Vec3f(1, 2, 3)] * 20))
        leg.CreateAccelerationsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, -9.8)] * 20))
    return _edited(tmp_path, edit, name=name, rigid=False, frames=6)


def test_bake_writes_the_velocities_of_the_pose(tmp_path):
    """bake: authored velocities (the rest pose's) become the baked pose's: at each frame the refinement of the
    central difference of UsdSkel's deformed points around it (one-sided at the ends), per second (the stage's
    timeCodesPerSecond); zero at the default time; accelerations are dropped with a warning. A range of frames
    baked alone writes the velocities the whole bake writes (its neighbours lie outside the range)."""
    levels, tcps = 1, 30.0
    src = _with_velocities(tmp_path, tcps=tcps)
    out, chunk = str(tmp_path / "out.usda"), str(tmp_path / "chunk.usda")
    result = refine_usd(src, out, levels, device="cpu", vertex_order="opensubdiv")
    refine_usd(src, chunk, levels, device="cpu", vertex_order="opensubdiv", frames=(4, None))
    assert any(w.startswith(f"{CHARACTER}/Leg: accelerations dropped (") for w in result.warnings), result.warnings
    source, baked, refined = Usd.Stage.Open(src), usdskel_baked(src), Usd.Stage.Open(out)
    leg = refined.GetPrimAtPath(CHARACTER + "/Leg")
    assert leg.GetAttribute("accelerations").Get(3.0) is None
    velocities = leg.GetAttribute("velocities")
    assert velocities.GetTimeSamples() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    sp = read_mesh(source.GetPrimAtPath(CHARACTER + "/Leg"))
    refiner = ws.Refiner(sp.mesh, levels, device="cpu")

    def posed(t):
        return np.asarray(baked.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("points").Get(t), dtype=np.float64)

    for t, (a, b) in {1.0: (1, 2), 3.0: (2, 4), 6.0: (5, 6)}.items():
        expected = refiner.evaluate((posed(b) - posed(a)) * tcps / (b - a))
        np.testing.assert_allclose(np.asarray(velocities.Get(t)), expected, atol=2e-4 * np.abs(expected).max(),
                                   err_msg=f"at {t}")
        assert np.abs(expected).max() > 0.5  # the pose moves
    np.testing.assert_array_equal(np.asarray(velocities.Get()), 0.0)
    chunk_stage = Usd.Stage.Open(chunk)
    part = chunk_stage.GetPrimAtPath(CHARACTER + "/Leg").GetAttribute("velocities")
    for t in (4.0, 5.0, 6.0):
        np.testing.assert_array_equal(np.asarray(part.Get(t)), np.asarray(velocities.Get(t)))


def test_keep_and_none_refine_authored_velocities_as_they_are(tmp_path):
    """keep and none refine the rest pose, whose authored velocities (and accelerations) are refined as read."""
    src = _with_velocities(tmp_path)
    for mode in ("keep", "none"):
        out = str(tmp_path / f"{mode}.usda")
        refine_usd(src, out, 1, device="cpu", skinning=mode)
        stage = Usd.Stage.Open(out)
        leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
        np.testing.assert_allclose(np.asarray(leg.GetAttribute("velocities").Get()), [[1, 2, 3]] * 74, atol=1e-6)
        np.testing.assert_allclose(np.asarray(leg.GetAttribute("accelerations").Get()), [[0, 0, -9.8]] * 74,
                                   atol=1e-5)


def test_indexed_influences_and_other_skel_primvars(tmp_path):
    """Indexed joint weights are read flattened, as UsdSkel reads them (bake and keep write what the plain
    character writes); a primvar of the skel: namespace that is not a joint influence is refined as any primvar,
    not left at the control mesh's size."""
    plain = character(tmp_path, name="plain.usda", rigid=False)

    def edit(stage):
        leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
        pv = UsdGeom.Primvar(leg.GetAttribute("primvars:skel:jointWeights"))
        rows, which = np.unique(np.asarray(pv.Get()).reshape(-1, 2), axis=0, return_inverse=True)
        assert len(rows) < 20
        pv.Set(Vt.FloatArray.FromNumpy(rows.reshape(-1).astype(np.float32)))
        pv.SetIndices(Vt.IntArray.FromNumpy(which.reshape(-1).astype(np.int32)))
        extra = UsdGeom.PrimvarsAPI(leg).CreatePrimvar("skel:extra", Sdf.ValueTypeNames.FloatArray, "vertex")
        extra.Set(Vt.FloatArray.FromNumpy(np.arange(20, dtype=np.float32)))
    indexed = _edited(tmp_path, edit, name="indexed.usda", rigid=False)
    for mode in ("bake", "keep"):
        stages = []
        for src in (plain, indexed):
            out = str(tmp_path / f"{mode}_{os.path.basename(src)}")
            refine_usd(src, out, 1, device="cpu", skinning=mode)
            stages.append(Usd.Stage.Open(out))
        legs = [s.GetPrimAtPath(CHARACTER + "/Leg") for s in stages]
        for t in (2.0, 4.0):
            np.testing.assert_array_equal(*(np.asarray(leg.GetAttribute("points").Get(t)) for leg in legs))
        if mode == "keep":
            for name in ("primvars:skel:jointIndices", "primvars:skel:jointWeights"):
                np.testing.assert_array_equal(*(np.asarray(leg.GetAttribute(name).Get()) for leg in legs))
            assert legs[1].GetAttribute("primvars:skel:jointWeights:indices").Get() is None
        assert len(legs[1].GetAttribute("primvars:skel:extra").Get()) == 74


def test_tessellate_writes_the_velocities_of_the_pose(tmp_path):
    """tessellate bakes the pose as refine does: its velocities are the tessellation's of the pose's velocities,
    so (the tessellation being linear in the points with OpenSubdiv's rules) the central difference of the
    tessellated points per second; accelerations are dropped."""
    from warp_subdiv.usd.tessellate import tessellate_file

    tcps = 30.0
    src = _with_velocities(tmp_path, tcps=tcps)
    out = str(tmp_path / "tess.usda")
    tessellate_file(src, out, rate=1, rules="opensubdiv", prims=[CHARACTER + "/Leg"], frames="2:4")
    stage = Usd.Stage.Open(out)
    leg = stage.GetPrimAtPath(CHARACTER + "/Leg")
    points, velocities = leg.GetAttribute("points"), leg.GetAttribute("velocities")
    assert velocities.GetTimeSamples() == points.GetTimeSamples() == [2.0, 3.0, 4.0]
    expected = (np.asarray(points.Get(4.0), dtype=np.float64) - np.asarray(points.Get(2.0))) * tcps / 2
    np.testing.assert_allclose(np.asarray(velocities.Get(3.0)), expected, atol=2e-4 * np.abs(expected).max())
    assert leg.GetAttribute("accelerations").Get(3.0) is None
