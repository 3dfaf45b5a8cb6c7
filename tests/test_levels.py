"""Per-mesh levels of a USD bake: ``subdiv:levels`` on a mesh or an ancestor (instanced prototypes and variants
too), the run's default and ``max_levels``, levels from a camera's pixel error (checked by refining and projecting
through usd-core's own frustum; animated cameras, off-screen meshes, instances, chunks and distributed bakes), LOD
variants that compose to each level, ``tessellate --camera``, and the errors of bad levels, cameras, pixel errors
and LOD lists."""
import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom

import warp_subdiv as ws
from warp_subdiv import cli
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd import plan, refine_usd
from warp_subdiv.usd.levels import longest_projected_edge

from test_usd_production import CUBE, CUBE_FACES, assert_valid, define_mesh, new_stage

FACES_AT = {level: 6 * 4**level for level in range(8)}  # a cube's faces per level


def set_levels(prim, value, type_name=Sdf.ValueTypeNames.Int):
    prim.CreateAttribute("subdiv:levels", type_name).Set(value)


def faces(stage, path):
    return len(stage.GetPrimAtPath(path).GetAttribute("faceVertexCounts").Get())


def scene_levels(path):
    """/World/Default/Cube (no level), /World/Group (subdiv:levels 2) with Cube and Own (its own 0), two
    instances of /Proto whose /Proto/Geo says 3, and /World/Outer (subdiv:levels 0) with an instance of /Plain
    (no level inside)."""
    stage = new_stage(path)
    define_mesh(stage, "/World/Default/Cube", CUBE, CUBE_FACES)
    set_levels(UsdGeom.Xform.Define(stage, "/World/Group").GetPrim(), 2)
    define_mesh(stage, "/World/Group/Cube", CUBE, CUBE_FACES)
    set_levels(define_mesh(stage, "/World/Group/Own", CUBE, CUBE_FACES).GetPrim(), 0)
    for proto, level in (("/Proto", 3), ("/Plain", None)):
        stage.CreateClassPrim(proto)
        geo = UsdGeom.Xform.Define(stage, proto + "/Geo").GetPrim()
        if level is not None:
            set_levels(geo, level)
        define_mesh(stage, proto + "/Geo/Mesh", CUBE, CUBE_FACES)
    for inst, proto in (("/World/I1", "/Proto"), ("/World/I2", "/Proto"), ("/World/Outer/I3", "/Plain"),
                        ("/World/I4", "/Plain")):
        prim = UsdGeom.Xform.Define(stage, inst).GetPrim()
        prim.GetReferences().AddInternalReference(proto)
        prim.SetInstanceable(True)
    set_levels(stage.GetPrimAtPath("/World/Outer"), 0)
    stage.Save()
    return str(path)


def test_levels_from_mesh_ancestor_default_and_instances(tmp_path):
    src = scene_levels(tmp_path / "scene.usda")
    p = plan(src, 1)
    got = {path: level for path, (level, _) in p.level_sources.items()}
    assert got == {"/World/Default/Cube": 1, "/World/Group/Cube": 2, "/World/Group/Own": 0,
                   "/World/I1/Geo/Mesh": 3, "/World/Outer/I3/Geo/Mesh": 0, "/World/I4/Geo/Mesh": 1}
    assert p.level_sources["/World/Group/Cube"][1] == "subdiv:levels on /World/Group"
    assert p.level_sources["/World/I1/Geo/Mesh"][1] == "subdiv:levels on /World/I1/Geo"  # inside the prototype
    assert p.level_sources["/World/Default/Cube"][1] == "levels"
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1)
    out = Usd.Stage.Open(str(dst))
    expect = {"/World/Default/Cube": 1, "/World/Group/Cube": 2, "/World/Group/Own": 0, "/World/I1/Geo/Mesh": 3,
              "/World/I2/Geo/Mesh": 3, "/World/Outer/I3/Geo/Mesh": 0, "/World/I4/Geo/Mesh": 1}
    for path, level in expect.items():
        assert faces(out, path) == FACES_AT[level], path
    # identical cubes at different levels are refined apart, at one level once (I1 and I2 share a unit, and so do
    # /World/Default/Cube and I4's mesh at level 1; Own differs from I3's mesh by its own subdiv:levels)
    assert sorted(r.level for r in result.reports) == [0, 0, 1, 2, 3]
    # the refined points are those of warp_subdiv.refine at each mesh's level (as a set: the bake's order)
    for path, level in expect.items():
        want = ws.refine(ws.Mesh(CUBE, [4] * 6, np.ravel(CUBE_FACES)), level, device="cpu").points
        pts = np.asarray(out.GetPrimAtPath(path).GetAttribute("points").Get(), dtype=np.float64)
        assert np.allclose(np.sort(pts, axis=0), np.sort(want, axis=0), atol=1e-6), path
    assert out.GetPrimAtPath("/World/I1").IsInstance() and out.GetPrimAtPath("/World/I4").IsInstance()
    # instances whose meshes get different levels reference different refined prototypes
    refs = {inst: out.GetPrimAtPath(inst).GetPrototype() for inst in ("/World/I1", "/World/I2", "/World/I4")}
    assert refs["/World/I1"] == refs["/World/I2"] != refs["/World/I4"]
    record = dict(Sdf.Layer.FindOrOpen(str(dst)).customLayerData)["warpSubdiv"]
    assert record["levels"] == 1 and record["meshLevels"]["/World/Group/Own"] == 0
    assert record["meshLevels"]["/World/I1/Geo/Mesh"] == 3
    assert_valid(src, dst)


def test_max_levels_caps_every_mesh(tmp_path):
    src = scene_levels(tmp_path / "scene.usda")
    p = plan(src, 3, max_levels=2)
    got = {path: level for path, (level, _) in p.level_sources.items()}
    assert got == {"/World/Default/Cube": 2, "/World/Group/Cube": 2, "/World/Group/Own": 0,
                   "/World/I1/Geo/Mesh": 2, "/World/Outer/I3/Geo/Mesh": 0, "/World/I4/Geo/Mesh": 2}
    assert p.level_sources["/World/I1/Geo/Mesh"][1] == "max_levels (from subdiv:levels on /World/I1/Geo)"
    # the memory guard sees the chosen levels: the prediction is that of level 2, not 3
    assert max(len(e.counts) - 1 for e in p.estimates) == 2


def test_info_shows_levels_and_sources(tmp_path, capsys):
    src = scene_levels(tmp_path / "scene.usda")
    assert cli.main(["info", src, "--levels", "1", "--max-levels", "2"]) == 0
    text = capsys.readouterr().out
    assert "  level: 1 (--levels)" in text  # each refined unit
    assert "  level: 2 (subdiv:levels on /World/Group)" in text
    listed = text.split("levels (each mesh read")[1]  # each composed mesh
    for line in ("/World/Default/Cube: 1 (--levels)", "/World/Group/Cube: 2 (subdiv:levels on /World/Group)",
                 "/World/Group/Own: 0 (subdiv:levels on /World/Group/Own)",
                 "/World/I1/Geo/Mesh: 2 (--max-levels (from subdiv:levels on /World/I1/Geo))",
                 "/World/Outer/I3/Geo/Mesh: 0 (subdiv:levels on /World/Outer)", "/World/I4/Geo/Mesh: 1 (--levels)"):
        assert "\n  " + line + "\n" in listed, line
    assert "unknown attribute subdiv:levels" not in text


@pytest.mark.parametrize("value, type_name, message", [
    (-1, Sdf.ValueTypeNames.Int, "/World/Group.subdiv:levels must be an int >= 0, got -1"),
    (1.5, Sdf.ValueTypeNames.Float, "/World/Group.subdiv:levels must be an int >= 0, got a float"),
    ("2", Sdf.ValueTypeNames.String, "/World/Group.subdiv:levels must be an int >= 0, got a string"),
])
def test_bad_levels_name_the_prim(tmp_path, value, type_name, message):
    stage = new_stage(tmp_path / "bad.usda")
    set_levels(UsdGeom.Xform.Define(stage, "/World/Group").GetPrim(), value, type_name)
    define_mesh(stage, "/World/Group/Cube", CUBE, CUBE_FACES)
    stage.Save()
    with pytest.raises(SubdivInputError, match=message):
        refine_usd(str(tmp_path / "bad.usda"), str(tmp_path / "out.usda"), 1)
    assert not (tmp_path / "out.usda").exists()


def test_bad_level_on_the_mesh_itself_names_it(tmp_path):
    stage = new_stage(tmp_path / "bad.usda")
    set_levels(define_mesh(stage, "/World/Cube", CUBE, CUBE_FACES).GetPrim(), 2.0, Sdf.ValueTypeNames.Double)
    stage.Save()
    with pytest.raises(SubdivInputError, match="/World/Cube: subdiv:levels must be int"):
        plan(str(tmp_path / "bad.usda"), 1)


def test_bad_run_levels_name_the_flag(tmp_path, capsys):
    src = scene_levels(tmp_path / "scene.usda")
    assert cli.main(["refine", src, "-o", str(tmp_path / "o.usda"), "--levels", "1", "--max-levels", "-1"]) == 2
    assert "--max-levels must be an integer >= 0, got -1" in capsys.readouterr().err


# -- levels from a camera ----------------------------------------------------------------------------------------

RES = (640, 480)


def scene_camera(path, animated=False):
    """A camera at the origin looking down -z (aperture 4:3, like RES) and three identical cubes: /World/Near at
    z = -6, /World/Far at z = -60 (both wholly on screen) and /World/Behind at z = +10. ``animated``: the camera
    moves to z = -45 at time 2 (15 from Far)."""
    stage = new_stage(path)
    cam = UsdGeom.Camera.Define(stage, "/World/Cam")
    cam.CreateHorizontalApertureAttr(20.955)
    cam.CreateVerticalApertureAttr(20.955 * RES[1] / RES[0])
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.1, 1000.0))
    move = cam.AddTranslateOp()
    if animated:
        move.Set(Gf.Vec3d(0, 0, 0), 1.0)
        move.Set(Gf.Vec3d(0, 0, -45), 2.0)
    else:
        move.Set(Gf.Vec3d(0, 0, 0))
    for name, z in (("Near", -6.0), ("Far", -60.0), ("Behind", 10.0)):
        xform = UsdGeom.Xform.Define(stage, f"/World/{name}")
        xform.AddTranslateOp().Set(Gf.Vec3d(-0.5, -0.5, z))
        define_mesh(stage, f"/World/{name}/Cube", CUBE, CUBE_FACES)
    stage.Save()
    return str(path)


def pixels_of_longest_edge(stage, mesh_path, level, time):
    """The longest edge of the cube refined ``level`` times (warp_subdiv.refine), placed by the mesh's world
    transform and projected through usd-core's frustum of /World/Cam at ``time``, in pixels at RES: every
    point transformed by Gf (its projective divide), edge by edge."""
    refined = ws.refine(ws.Mesh(CUBE, [4] * 6, np.ravel(CUBE_FACES)), level, device="cpu")
    world = UsdGeom.Xformable(stage.GetPrimAtPath(mesh_path)).ComputeLocalToWorldTransform(time)
    frustum = UsdGeom.Camera(stage.GetPrimAtPath("/World/Cam")).GetCamera(time).frustum
    to_clip = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    ndc = [to_clip.Transform(world.Transform(Gf.Vec3d(*map(float, p)))) for p in refined.points]
    assert all(-1 <= v[0] <= 1 and -1 <= v[1] <= 1 for v in ndc)  # wholly on screen: every edge counts
    longest = 0.0
    counts, indices = refined.face_vertex_counts, refined.face_vertex_indices
    start = 0
    for n in counts:
        face = indices[start:start + n]
        start += n
        for a, b in zip(face, np.roll(face, -1)):
            dx = (ndc[a][0] - ndc[b][0]) * RES[0] / 2
            dy = (ndc[a][1] - ndc[b][1]) * RES[1] / 2
            longest = max(longest, float(np.hypot(dx, dy)))
    return longest


def camera_levels(src, **kw):
    p = plan(src, kw.pop("levels", 6), camera="/World/Cam", pixel_error=kw.pop("pixel_error", 12.0),
             resolution=kw.pop("resolution", "640x480"), **kw)
    return {path: level for path, (level, _) in p.level_sources.items()}, p


def test_camera_near_gets_more_levels_each_the_smallest_that_meets_the_error(tmp_path):
    src = scene_camera(tmp_path / "scene.usda")
    levels, p = camera_levels(src, pixel_error=12.0)
    near, far = levels["/World/Near/Cube"], levels["/World/Far/Cube"]
    assert near > far >= 1
    stage = Usd.Stage.Open(src)
    for path, level in (("/World/Near/Cube", near), ("/World/Far/Cube", far)):
        assert pixels_of_longest_edge(stage, path, level, Usd.TimeCode.Default()) <= 12.0, path
        assert pixels_of_longest_edge(stage, path, level - 1, Usd.TimeCode.Default()) > 12.0, path
    assert levels["/World/Behind/Cube"] == 0  # off-screen
    assert p.level_sources["/World/Behind/Cube"][1] == "camera /World/Cam (off-screen; at most levels)"
    # the cap: --levels
    capped, _ = camera_levels(src, pixel_error=12.0, levels=2)
    assert capped["/World/Near/Cube"] == 2 and capped["/World/Far/Cube"] == min(far, 2)


def test_camera_offscreen_level_and_bake(tmp_path):
    src = scene_camera(tmp_path / "scene.usda")
    dst = tmp_path / "out.usda"
    assert cli.main(["refine", src, "-o", str(dst), "--levels", "4", "--camera", "/World/Cam", "--pixel-error", "30",
                     "--resolution", "640x480", "--offscreen-level", "1", "--quiet"]) == 0
    out = Usd.Stage.Open(str(dst))
    levels, _ = camera_levels(src, pixel_error=30.0, levels=4, offscreen_level=1)
    assert levels["/World/Behind/Cube"] == 1
    for path, level in levels.items():
        assert faces(out, path) == FACES_AT[level], path
    assert levels["/World/Near/Cube"] > levels["/World/Far/Cube"]
    assert_valid(src, dst)


def test_camera_resolution_from_render_settings(tmp_path):
    src = scene_camera(tmp_path / "scene.usda")
    stage = Usd.Stage.Open(src)
    from pxr import UsdRender

    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateResolutionAttr(Gf.Vec2i(2 * RES[0], 2 * RES[1]))
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    stage.Save()
    p = plan(src, 6, camera="/World/Cam", pixel_error=24.0)
    doubled = {path: level for path, (level, _) in p.level_sources.items()}
    same, _ = camera_levels(src, pixel_error=12.0)  # twice the pixels, twice the error: the same levels
    assert doubled == same


def test_animated_camera_worst_frame_wins(tmp_path):
    src = scene_camera(tmp_path / "scene.usda", animated=True)
    stage = Usd.Stage.Open(src)
    each = [camera_levels(src, frames=(t, t))[0]["/World/Far/Cube"] for t in (1.0, 2.0)]
    assert each[1] > each[0]  # closer at time 2
    both, _ = camera_levels(src, frames=(1.0, 2.0))
    level = both["/World/Far/Cube"]
    assert level == max(each)
    assert all(pixels_of_longest_edge(stage, "/World/Far/Cube", level, t) <= 12.0 for t in (1.0, 2.0))
    assert pixels_of_longest_edge(stage, "/World/Far/Cube", level - 1, 2.0) > 12.0
    every, _ = camera_levels(src)  # no frames: every time sample
    assert every["/World/Far/Cube"] == level


def test_longest_projected_edge_clips_at_the_near_plane():
    frustum = Gf.Frustum()  # at the origin, looking down -z
    frustum.SetPerspective(90.0, 1.0, 1.0, 100.0)
    matrix = np.array(frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix())
    square = np.array([(-1, -1, -4), (1, -1, -4), (1, 1, -4), (-1, 1, -4)], dtype=float)
    # 2 units at distance 4 through a 90 degree field of view: half the width of 100 pixels
    assert longest_projected_edge(square, [4], [0, 1, 2, 3], matrix, (100, 100)) == pytest.approx(25.0)
    behind = square * [1, 1, -1]
    assert longest_projected_edge(behind, [4], [0, 1, 2, 3], matrix, (100, 100)) == 0.0
    # edges that cross the near plane (z = -1) are measured from there: the longest, from (0.6, 0, 4) to
    # (0.5, 0, -4), crosses it at x = 0.5375
    crossing = np.array([(0.5, 0, -4), (0.5, 0, 4), (0.6, 0, 4)], dtype=float)
    got = longest_projected_edge(crossing, [3], [0, 1, 2], matrix, (100, 100))
    assert got == pytest.approx((0.5375 / 1 - 0.5 / 4) * 50)


@pytest.mark.parametrize("argv, message", [
    (["--camera", "/World/Near", "--pixel-error", "2"], "--camera /World/Near: a Xform, not a Camera"),
    (["--camera", "/World/Nothing", "--pixel-error", "2"], "--camera /World/Nothing: no prim"),
    (["--camera", "/World/Cam", "--pixel-error", "0"], "--pixel-error must be a number > 0 (pixels), got 0.0"),
    (["--camera", "/World/Cam"], "--camera needs --pixel-error"),
    (["--pixel-error", "2"], "--pixel-error is for levels from --camera: give --camera too"),
    (["--camera", "/World/Cam", "--pixel-error", "2", "--resolution", "640"], "--resolution must be WxH"),
])
def test_bad_camera_input_names_the_flag(tmp_path, capsys, argv, message):
    src = scene_camera(tmp_path / "scene.usda")
    assert cli.main(["refine", src, "-o", str(tmp_path / "o.usda"), "--levels", "2"] + argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o.usda").exists()


# -- LOD variants --------------------------------------------------------------------------------------------------

def scene_assets(folder):
    """asset.usda (a cube /Asset/Geo/Mesh) referenced by /World/A and /World/B (identical meshes) and by the
    instances /World/I1, /World/I2; shot.usda holds no mesh opinion of its own (the LOD variants' case)."""
    from test_usd_production import write_asset

    asset = write_asset(folder / "asset.usda")
    stage = new_stage(folder / "shot.usda")
    for name, instance in (("A", False), ("B", False), ("I1", True), ("I2", True)):
        prim = UsdGeom.Xform.Define(stage, f"/World/{name}").GetPrim()
        prim.GetReferences().AddReference("./asset.usda")
        prim.SetInstanceable(instance)
    stage.Save()
    return asset, str(folder / "shot.usda")


MESHES = ("/World/A/Geo/Mesh", "/World/B/Geo/Mesh", "/World/I1/Geo/Mesh", "/World/I2/Geo/Mesh")


def with_selection(dst, level, tmp_path):
    """The output with every subdivLOD variant set selecting ``level`` (a copy of the layer, selections edited)."""
    layer = Sdf.Layer.FindOrOpen(str(dst))
    copy = tmp_path / f"selected{level}.usda"
    layer.Export(str(copy))
    edited = Sdf.Layer.FindOrOpen(str(copy))
    found = []

    def visit(path):
        spec = edited.GetPrimAtPath(path) if path.IsPrimPath() else None
        if spec is not None and "subdivLOD" in spec.variantSets.keys():
            spec.variantSelections["subdivLOD"] = f"level{level}"
            found.append(str(path))

    edited.Traverse(Sdf.Path.absoluteRootPath, visit)
    edited.Save()
    return str(copy), found


def test_lod_variants_compose_to_each_level(tmp_path):
    asset, src = scene_assets(tmp_path)
    dst = tmp_path / "lod.usda"
    assert cli.main(["refine", src, "-o", str(dst), "--levels", "1", "--lod-variants", "0,2,1", "--quiet"]) == 0
    layer = Sdf.Layer.FindOrOpen(str(dst))
    # the identical meshes share one refined mesh, the instances one prototype: each written once per level
    homes = with_selection(dst, 1, tmp_path)[1]
    assert len(homes) == 2
    assert list(dict(layer.customLayerData)["warpSubdiv"]["lodVariants"]) == [0, 2, 1]
    default = Usd.Stage.Open(str(dst))
    assert all(faces(default, m) == FACES_AT[1] for m in MESHES)  # the last level is selected
    assert default.GetPrimAtPath("/World/I1").IsInstance()
    for level in (0, 1, 2):
        path, found = with_selection(dst, level, tmp_path)
        out = Usd.Stage.Open(path)
        want = ws.refine(ws.Mesh(CUBE, [4] * 6, np.ravel(CUBE_FACES)), level, device="cpu")
        for mesh in MESHES:
            prim = out.GetPrimAtPath(mesh)
            assert len(prim.GetAttribute("faceVertexCounts").Get()) == want.num_faces, (level, mesh)
            pts = np.asarray(prim.GetAttribute("points").Get(), dtype=np.float64)
            assert np.allclose(np.sort(pts, axis=0), np.sort(want.points, axis=0), atol=1e-6), (level, mesh)
            assert prim.GetAttribute("subdivisionScheme").Get() == "none"
    assert_valid(src, dst)


def test_lod_variants_bad_input(tmp_path, capsys):
    _, src = scene_assets(tmp_path)
    out = str(tmp_path / "o.usda")
    assert cli.main(["refine", src, "-o", out, "--levels", "1", "--lod-variants", "0,x"]) == 2
    assert "--lod-variants must be levels separated by commas (0,1,2), got '0,x'" in capsys.readouterr().err
    assert cli.main(["refine", src, "-o", out, "--levels", "1", "--lod-variants", "1,1"]) == 2
    assert "--lod-variants lists a level twice" in capsys.readouterr().err
    with pytest.raises(SubdivInputError, match="lod_variants does not combine with camera"):
        refine_usd(src, out, 1, lod_variants=[0, 1], camera="/World/Cam", pixel_error=1.0)


# -- levels with variants, instances, chunks and distributed bakes -----------------------------------------------

def test_levels_inside_variants_with_all_variants(tmp_path):
    """A variant that sets subdiv:levels on the asset's Geo refines its mesh at that level, inside the variant."""
    from test_usd_production import write_asset

    asset = write_asset(tmp_path / "asset.usda")  # variant set crease = smooth | sharp on /Asset
    layer = Sdf.Layer.FindOrOpen(asset)
    geo = Sdf.CreatePrimInLayer(layer, Sdf.Path("/Asset{crease=sharp}Geo"))
    Sdf.AttributeSpec(geo, "subdiv:levels", Sdf.ValueTypeNames.Int).default = 2
    layer.Save()
    stage = new_stage(tmp_path / "shot.usda")
    stage.DefinePrim("/World/A").GetReferences().AddReference("./asset.usda")
    stage.Save()
    dst = tmp_path / "out.usda"
    refine_usd(str(tmp_path / "shot.usda"), str(dst), 1, all_variants=True)
    out = Usd.Stage.Open(str(dst))
    assert faces(out, "/World/A/Geo/Mesh") == FACES_AT[1]  # smooth, selected
    out.GetPrimAtPath("/World/A").GetVariantSet("crease").SetVariantSelection("sharp")
    assert faces(out, "/World/A/Geo/Mesh") == FACES_AT[2]


def test_camera_levels_split_instances_by_distance(tmp_path):
    """Instances of one prototype near and far get different levels (different refined prototypes); two at the
    same distance share one."""
    stage = Usd.Stage.Open(scene_camera(tmp_path / "scene.usda"))
    stage.CreateClassPrim("/Proto")
    define_mesh(stage, "/Proto/Cube", CUBE, CUBE_FACES)
    for name, (x, z) in {"N1": (-1.0, -6.0), "N2": (0.0, -6.0), "F": (0.0, -60.0)}.items():
        inst = UsdGeom.Xform.Define(stage, f"/World/{name}")
        inst.AddTranslateOp().Set(Gf.Vec3d(x, -0.5, z))
        inst.GetPrim().GetReferences().AddInternalReference("/Proto")
        inst.GetPrim().SetInstanceable(True)
    stage.Save()
    src = str(tmp_path / "scene.usda")
    levels, _ = camera_levels(src)
    assert levels["/World/N1/Cube"] == levels["/World/N2/Cube"] > levels["/World/F/Cube"]
    dst = tmp_path / "out.usda"
    refine_usd(src, str(dst), 6, camera="/World/Cam", pixel_error=12.0, resolution=(640, 480))
    out = Usd.Stage.Open(str(dst))
    for name in ("N1", "N2", "F"):
        assert faces(out, f"/World/{name}/Cube") == FACES_AT[levels[f"/World/{name}/Cube"]]
        assert out.GetPrimAtPath(f"/World/{name}").IsInstance()
    assert out.GetPrimAtPath("/World/N1").GetPrototype() == out.GetPrimAtPath("/World/N2").GetPrototype()
    assert out.GetPrimAtPath("/World/N1").GetPrototype() != out.GetPrimAtPath("/World/F").GetPrototype()
    assert_valid(src, dst)


def composed_values(stage):
    """{attribute path: composed default value} of every prim of ``stage``, instance proxies too (arrays as
    numpy)."""
    out = {}
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        for attr in prim.GetAttributes():
            value = attr.Get()
            out[str(attr.GetPath())] = np.asarray(value) if hasattr(value, "__len__") and not isinstance(
                value, str) else value
    return out


def assert_same_values(got, want, label):
    assert sorted(got) == sorted(want), label
    for path, value in want.items():
        if isinstance(value, np.ndarray):
            assert np.array_equal(got[path], value), (label, path)
        else:
            assert got[path] == value, (label, path)


@pytest.mark.parametrize("flatten", [False, True])
def test_lod_variants_of_meshes_authored_in_the_input(tmp_path, flatten):
    """Meshes the input defines itself (concave_corner.usda: four plates, two rule sets, concave corners) get
    their levels in a flattened output (flattened with a warning when flatten is not asked for): every selection
    composes to exactly the plain flattened bake at that level (every attribute of every prim), whose refined
    points are ws.refine's; a cube with a face subset and a face-varying primvar beside them too."""
    import os

    import shutil
    src = str(tmp_path / "concave_corner.usda")
    shutil.copy(os.path.join(os.path.dirname(__file__), "..", "scenes", "concave_corner.usda"), src)
    stage = Usd.Stage.Open(src)
    cube = define_mesh(stage, "/World/Cube", CUBE, CUBE_FACES)
    UsdGeom.Subset.CreateGeomSubset(cube, "top", UsdGeom.Tokens.face, [1, 2])
    uv = UsdGeom.PrimvarsAPI(cube).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying)
    uv.Set([(i % 4 * 0.25, i // 4 * 0.1) for i in range(24)])
    stage.Save()
    meshes = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    dst = tmp_path / "lod.usda"
    result = refine_usd(src, str(dst), 1, lod_variants=[0, 2, 1], flatten=flatten, device="cpu")
    assert any("the output is flattened" in w for w in result.warnings) == (not flatten)
    layer = Sdf.Layer.FindOrOpen(str(dst))
    assert not layer.subLayerPaths  # self-contained
    record = dict(layer.customLayerData)["warpSubdiv"]
    assert record["flattened"] and list(record["lodVariants"]) == [0, 2, 1]
    out = Usd.Stage.Open(str(dst))
    assert all(out.GetPrimAtPath(m).GetVariantSet("subdivLOD").GetVariantSelection() == "level1" for m in meshes)
    out.SetEditTarget(out.GetSessionLayer())  # selections in the session layer: the output stays as written
    for level in (1, 0, 2):  # the selected one first
        plain = tmp_path / f"plain{level}.usda"
        refine_usd(src, str(plain), level, flatten=True, mesh_levels={m: level for m in meshes}, device="cpu")
        for mesh in meshes:
            out.GetPrimAtPath(mesh).GetVariantSet("subdivLOD").SetVariantSelection(f"level{level}")
        assert_same_values(composed_values(out), composed_values(Usd.Stage.Open(str(plain))), level)
        want = ws.refine(ws.Mesh(CUBE, [4] * 6, np.ravel(CUBE_FACES)), level, device="cpu")
        prim = out.GetPrimAtPath("/World/Cube")
        assert len(prim.GetAttribute("faceVertexCounts").Get()) == want.num_faces
        pts = np.asarray(prim.GetAttribute("points").Get(), dtype=np.float64)
        assert np.allclose(np.sort(pts, axis=0), np.sort(want.points, axis=0), atol=1e-6), level
        assert len(out.GetPrimAtPath("/World/Cube/top").GetAttribute("indices").Get()) == 2 * 4**level
    assert_valid(src, dst)


def test_lod_variants_flattened_with_instances_and_identical_meshes(tmp_path):
    """--flatten on referenced meshes: the identical meshes flattened apart, the instances' mesh inside the
    flattened prototype, each with its variants; every selection composes to the plain flattened bake."""
    _, src = scene_assets(tmp_path)
    dst = tmp_path / "lod.usda"
    assert cli.main(["refine", src, "-o", str(dst), "--levels", "1", "--lod-variants", "0,2", "--flatten",
                     "--quiet"]) == 0
    assert Usd.Stage.Open(str(dst)).GetPrimAtPath("/World/I1").IsInstance()
    for level in (0, 2):
        path, found = with_selection(dst, level, tmp_path)
        assert len(found) == 3  # /World/A and /World/B's meshes, the flattened prototype's
        plain = tmp_path / f"plain{level}.usda"
        refine_usd(src, str(plain), level, flatten=True, device="cpu")
        assert_same_values(composed_values(Usd.Stage.Open(path)), composed_values(Usd.Stage.Open(str(plain))),
                           level)
        assert faces(Usd.Stage.Open(path), "/World/I2/Geo/Mesh") == FACES_AT[level]
    assert_valid(src, dst)


def test_render_levels_read_subdiv_levels(tmp_path):
    """render --levels N refines each mesh as refine does: /World/Group's subdiv:levels 2 for its cube, N for the
    other, through an instance too; the preview has the baked output's triangles, corner for corner; without
    levels the meshes are drawn as stored."""
    from warp_subdiv.render import stage_soup

    stage = new_stage(tmp_path / "scene.usda")
    set_levels(UsdGeom.Xform.Define(stage, "/World/Group").GetPrim(), 2)
    define_mesh(stage, "/World/Group/Cube", CUBE, CUBE_FACES)
    define_mesh(stage, "/World/Plain", CUBE, CUBE_FACES)
    stage.CreateClassPrim("/Proto")
    define_mesh(stage, "/Proto/Cube", CUBE, CUBE_FACES)
    inst = stage.DefinePrim("/World/Group/Inst")
    inst.GetReferences().AddInternalReference("/Proto")
    inst.SetInstanceable(True)
    stage.Save()
    src = str(tmp_path / "scene.usda")
    dst = tmp_path / "out.usda"
    refine_usd(src, str(dst), 1, device="cpu")
    preview = stage_soup(Usd.Stage.Open(src), levels=1, device="cpu")
    baked = stage_soup(Usd.Stage.Open(str(dst)))
    assert len(preview.corners) == 3 * 2 * (2 * FACES_AT[2] + FACES_AT[1])  # quads drawn as two triangles
    assert np.allclose(np.sort(preview.corners, axis=0), np.sort(baked.corners, axis=0), atol=1e-5)
    assert len(stage_soup(Usd.Stage.Open(src)).corners) == 3 * 2 * 3 * FACES_AT[0]
    assert cli.main(["render", src, "-o", str(tmp_path / "p.png"), "--levels", "1", "--size", "16x12",
                     "--samples", "1", "--device", "cpu"]) == 0


def camera_over_grid(path):
    """A 3 x 1 plate moving up each frame (1-12) under a camera that comes down from z = 12 to z = 3."""
    from test_distributed_outputs import animated_grid

    src = animated_grid(path, 3)
    stage = Usd.Stage.Open(src)
    cam = UsdGeom.Camera.Define(stage, "/World/Cam")
    cam.CreateHorizontalApertureAttr(20.955)
    cam.CreateVerticalApertureAttr(20.955 * RES[1] / RES[0])
    move = cam.AddTranslateOp()
    for t in range(1, 13):
        move.Set(Gf.Vec3d(1.5, 0.5, 12.0 - 9.0 * (t - 1) / 11), float(t))
    stage.Save()
    return src


def test_stitch_refuses_chunks_at_other_levels(tmp_path):
    from warp_subdiv.usd import distributed as dist

    src = camera_over_grid(tmp_path / "in.usda")
    first, second = str(tmp_path / "c0.usdc"), str(tmp_path / "c1.usdc")
    # a camera chooses over each chunk's own frames: the later chunk is nearer, so finer
    kw = dict(camera="/World/Cam", pixel_error=40.0, resolution=RES)
    refine_usd(src, first, 5, frames=(None, 6), **kw)
    refine_usd(src, second, 5, frames=(6, None), **kw)
    levels = [dict(Sdf.Layer.FindOrOpen(c).customLayerData)["warpSubdiv"]["meshLevels"]["/World/Mesh"]
              for c in (first, second)]
    assert levels[0] < levels[1]
    with pytest.raises(SubdivInputError, match=r"c1.usdc: the meshes' levels differs from .*c0.usdc's"):
        dist.stitch([first, second], str(tmp_path / "out.usda"))
    # the levels decided once (mesh_levels) make chunks that stitch
    fixed = {"/World/Mesh": levels[1]}
    refine_usd(src, first, 5, frames=(None, 6), mesh_levels=fixed)
    refine_usd(src, second, 5, frames=(6, None), mesh_levels=fixed)
    dist.stitch([first, second], str(tmp_path / "out.usda"))


def test_distributed_camera_bake_chooses_once(tmp_path):
    """Frame tasks see their own frames; the driver chooses the levels over all of them and hands them on, so
    the bake equals the single-process one."""
    pytest.importorskip("distributed")
    from conftest import dask_client
    from test_distributed import assert_same_composition
    from warp_subdiv.usd import distributed as dist

    src = camera_over_grid(tmp_path / "in.usda")
    kw = dict(camera="/World/Cam", pixel_error=40.0, resolution=RES)
    single = str(tmp_path / "single.usda")
    refine_usd(src, single, 5, **kw)
    with dask_client(n_workers=1, processes=False) as client:
        result = dist.bake(src, str(tmp_path / "dist.usda"), 5, client=client, chunk_frames=4, **kw)
    assert len(result.timings["units"]) >= 2  # frame chunks
    assert_same_composition(single, str(tmp_path / "dist.usda"))


# -- tessellate --camera -------------------------------------------------------------------------------------------

def test_tessellate_camera_rates(tmp_path):
    """One quad facing the camera near and the same quad far: each of its (straight) limit edges gets
    ceil(projected length / px) segments, the length projected through usd-core's frustum by Gf; a quad behind
    the camera gets rate 1; the tessellation is the rate x rate grid."""
    quad = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0), (0.0, 1.0, 0.0)]
    stage = Usd.Stage.Open(scene_camera(tmp_path / "scene.usda"))
    for name in ("Near", "Far", "Behind"):
        stage.RemovePrim(f"/World/{name}/Cube")
        define_mesh(stage, f"/World/{name}/Quad", quad, [(0, 1, 2, 3)])
    stage.Save()
    src, dst = str(tmp_path / "scene.usda"), tmp_path / "tess.usda"
    assert cli.main(["tessellate", src, "-o", str(dst), "--camera", "/World/Cam", "--pixel-error", "7",
                     "--resolution", "640x480", "--quiet"]) == 0
    out = Usd.Stage.Open(str(dst))
    frustum = UsdGeom.Camera(stage.GetPrimAtPath("/World/Cam")).GetCamera(Usd.TimeCode.Default()).frustum
    to_clip = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    rates = {}
    for name in ("Near", "Far"):
        world = UsdGeom.Xformable(stage.GetPrimAtPath(f"/World/{name}/Quad")).ComputeLocalToWorldTransform(0)
        a, b = (to_clip.Transform(world.Transform(Gf.Vec3d(*p))) for p in quad[:2])
        pixels = np.hypot((a[0] - b[0]) * RES[0] / 2, (a[1] - b[1]) * RES[1] / 2)
        rates[name] = int(np.ceil(pixels / 7.0))
        assert faces(out, f"/World/{name}/Quad") == rates[name] ** 2, name
    assert rates["Near"] > rates["Far"] > 1
    assert faces(out, "/World/Behind/Quad") == 1
    assert_valid(src, dst)
    assert cli.main(["tessellate", src, "-o", str(dst), "--camera", "/World/Near", "--pixel-error", "7"]) == 2


def test_lod_variants_ignore_scene_levels_and_refuse_max_levels(tmp_path):
    """Every mesh gets every listed level whatever its subdiv:levels says (and the memory guard predicts the
    highest); max_levels is refused rather than dropped."""
    asset, src = scene_assets(tmp_path)
    layer = Sdf.Layer.FindOrOpen(src)
    Sdf.AttributeSpec(layer.GetPrimAtPath("/World/A"), "subdiv:levels", Sdf.ValueTypeNames.Int).default = 0
    layer.Save()
    p = plan(src, 2, scene_levels=False)
    assert set(p.levels) == {2}
    dst = tmp_path / "lod.usda"
    refine_usd(src, str(dst), 1, lod_variants=[1, 2])
    assert faces(Usd.Stage.Open(str(dst)), "/World/A/Geo/Mesh") == FACES_AT[2]
    with pytest.raises(SubdivInputError, match="lod_variants does not combine with max_levels"):
        refine_usd(src, str(dst), 1, lod_variants=[1, 2], max_levels=1)


def test_camera_bake_takes_the_measured_tables_and_writes_what_given_levels_write(tmp_path):
    """The bake's refiners take the tables the camera measured with (not built again), and the layer holds the
    same values as a bake given the chosen levels."""
    src = scene_camera(tmp_path / "scene.usda")
    kw = dict(camera="/World/Cam", pixel_error=12.0, resolution=RES)
    p = plan(src, 6, **kw)
    measured = [t for t in p.tables if t is not None]
    assert measured and all(t.levels == lv for t, lv in zip(p.tables, p.levels) if t is not None)
    chosen = {path: level for path, (level, _) in p.level_sources.items()}
    refine_usd(src, str(tmp_path / "cam.usda"), 6, **kw)
    refine_usd(src, str(tmp_path / "given.usda"), 6, mesh_levels=chosen)
    a, b = Usd.Stage.Open(str(tmp_path / "cam.usda")), Usd.Stage.Open(str(tmp_path / "given.usda"))
    for path in chosen:
        for name in ("points", "faceVertexIndices"):
            assert a.GetPrimAtPath(path).GetAttribute(name).Get() == b.GetPrimAtPath(path).GetAttribute(name).Get()


def test_info_and_refine_show_camera_levels(tmp_path, capsys):
    src = scene_camera(tmp_path / "scene.usda")
    levels, _ = camera_levels(src, levels=4, pixel_error=12.0)
    assert cli.main(["info", src, "--levels", "4", "--camera", "/World/Cam", "--pixel-error", "12",
                     "--resolution", "640x480"]) == 0
    text = capsys.readouterr().out.split("levels (each mesh read")[1]
    assert f"  /World/Near/Cube: {levels['/World/Near/Cube']} (camera /World/Cam (" in text
    assert "  /World/Behind/Cube: 0 (camera /World/Cam (off-screen; at most --levels))" in text
    assert cli.main(["refine", src, "-o", str(tmp_path / "o.usda"), "--levels", "4", "--camera", "/World/Cam",
                     "--pixel-error", "12", "--resolution", "640x480"]) == 0
    out = capsys.readouterr().out
    assert "4 levels on" in out and "(per mesh: see the level column)" in out
    header = next(line for line in out.splitlines() if "faces in" in line).split()
    row = next(line for line in out.splitlines() if line.strip().startswith("/World/Near/Cube")).split()
    assert row[header.index("level")] == str(levels["/World/Near/Cube"])
