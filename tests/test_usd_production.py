"""Production USD structures: scene-graph instances (nested too), PointInstancer prototypes,
payloads, an asset referenced twice, variant sets (nested too, every variant with --all-variants), polygonal
meshes refined on request and time-varying topology. Every scene is written here from plain data; each test
checks face counts, points equal to ``warp_subdiv.refine`` on the composed control mesh, that instancing is
kept, that the input files are untouched and that the output passes usd-core's validators."""
import hashlib
import os

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdValidation, Vt

import warp_subdiv as ws
from warp_subdiv import cli
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd.refine import refine_usd

from test_usd_support import SCENES_DIR, as_baked

LEVELS = 2
CUBE = np.array([(x, y, z) for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
CUBE_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
TOP_LOOP = [4, 5, 7, 6, 4]  # the top square, as one closed crease
PLATE = np.array([(x, y, 0.0) for y in (0.0, 1.0) for x in (0.0, 1.0, 2.0)])  # a 2 x 1 quad plate
PLATE_FACES = [(0, 1, 4, 3), (1, 2, 5, 4)]


# -- writing scenes --------------------------------------------------------------------------------------------

def new_stage(path, default="World"):
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/" + default)
    stage.SetDefaultPrim(root.GetPrim())
    return stage


def define_mesh(stage, path, points, faces, scheme="catmullClark", color=(0.8, 0.3, 0.2)):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(scheme)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in faces]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for f in faces for i in f]))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, dtype=np.float32)))
    pts = np.asarray(points)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, pts.min(0))), Gf.Vec3f(*map(float, pts.max(0)))]))
    mesh.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*color)]))
    return mesh


def crease(mesh, loop=TOP_LOOP):
    mesh.CreateCreaseIndicesAttr(Vt.IntArray(loop))
    mesh.CreateCreaseLengthsAttr(Vt.IntArray([len(loop)]))
    mesh.CreateCreaseSharpnessesAttr(Vt.FloatArray([10.0]))


def write_asset(path):
    """/Asset: a Catmull-Clark cube /Asset/Geo/Mesh with a variant set crease = smooth (default) | sharp (the
    top square creased)."""
    stage = new_stage(path, "Asset")
    asset = stage.GetPrimAtPath("/Asset")
    UsdGeom.Xform.Define(stage, "/Asset/Geo")
    mesh = define_mesh(stage, "/Asset/Geo/Mesh", CUBE, CUBE_FACES)
    vset = asset.GetVariantSets().AddVariantSet("crease")
    for name in ("smooth", "sharp"):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        if name == "sharp":
            with vset.GetVariantEditContext():
                crease(mesh)
    vset.SetVariantSelection("smooth")
    stage.Save()
    return str(path)


def write_nested_variant_asset(path):
    """/Asset: variant set lod = high (default: the cube, with a nested variant set crease = soft (default) |
    hard inside it) | low (a two-quad plate instead)."""
    layer = Sdf.Layer.CreateNew(str(path))
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    asset = UsdGeom.Xform.Define(stage, "/Asset")
    stage.SetDefaultPrim(asset.GetPrim())
    UsdGeom.Xform.Define(stage, "/Asset/Geo")
    T = Sdf.ValueTypeNames

    def mesh_in(variant_path, points, faces):
        spec = Sdf.CreatePrimInLayer(layer, variant_path.AppendChild("Geo").AppendChild("Mesh"))
        spec.specifier, spec.typeName = Sdf.SpecifierDef, "Mesh"
        Sdf.AttributeSpec(spec, "faceVertexCounts", T.IntArray).default = Vt.IntArray([len(f) for f in faces])
        Sdf.AttributeSpec(spec, "faceVertexIndices", T.IntArray).default = Vt.IntArray([i for f in faces for i in f])
        Sdf.AttributeSpec(spec, "points", T.Point3fArray).default = Vt.Vec3fArray.FromNumpy(
            np.asarray(points, dtype=np.float32))
        return spec

    high = Sdf.Path("/Asset").AppendVariantSelection("lod", "high")
    mesh_in(high, CUBE, CUBE_FACES)
    Sdf.CreatePrimInLayer(layer, high.AppendVariantSelection("crease", "soft"))
    hard = Sdf.CreatePrimInLayer(layer, high.AppendVariantSelection("crease", "hard").AppendChild("Geo")
                                 .AppendChild("Mesh"))
    Sdf.AttributeSpec(hard, "creaseIndices", T.IntArray).default = Vt.IntArray(TOP_LOOP)
    Sdf.AttributeSpec(hard, "creaseLengths", T.IntArray).default = Vt.IntArray([len(TOP_LOOP)])
    Sdf.AttributeSpec(hard, "creaseSharpnesses", T.FloatArray).default = Vt.FloatArray([10.0])
    mesh_in(Sdf.Path("/Asset").AppendVariantSelection("lod", "low"), PLATE, PLATE_FACES)
    spec = layer.GetPrimAtPath("/Asset")
    spec.variantSelections["lod"] = "high"
    layer.GetPrimAtPath(high).variantSelections["crease"] = "soft"
    layer.Save()
    return str(path)


def place(stage, path, asset=None, target="/Asset", *, instanceable=False, payload=False, x=0.0, variants=None):
    prim = UsdGeom.Xform.Define(stage, path).GetPrim()
    UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(x, 0.0, 0.0))
    if asset is not None:
        arcs = prim.GetPayloads() if payload else prim.GetReferences()
        (arcs.AddPayload if payload else arcs.AddReference)(asset, target)
    if instanceable:
        prim.SetInstanceable(True)
    for vset, variant in (variants or {}).items():
        prim.GetVariantSets().GetVariantSet(vset).SetVariantSelection(variant)
    return prim


# -- checks ------------------------------------------------------------------------------------------------

def expected_of(prim, levels=LEVELS, time=Usd.TimeCode.Default(), scheme=None):
    """warp_subdiv.refine on the control mesh ``prim`` composes to (its creases and corners infinitely sharp),
    numbered as the default bake writes it (piecewise-smooth rules: the compact vertex order)."""
    m = UsdGeom.Mesh(prim)
    pts = np.asarray(m.GetPointsAttr().Get(time), dtype=np.float64)
    counts = np.asarray(m.GetFaceVertexCountsAttr().Get(time))
    indices = np.asarray(m.GetFaceVertexIndicesAttr().Get(time))
    kw, start = {}, 0
    pairs = []
    run = list(m.GetCreaseIndicesAttr().Get(time) or [])
    for n in m.GetCreaseLengthsAttr().Get(time) or []:
        pairs += list(zip(run[start:start + n - 1], run[start + 1:start + n]))
        start += n
    if pairs:
        kw["creases"] = np.array(pairs)
    if m.GetCornerIndicesAttr().Get(time):
        kw["corners"] = np.array(m.GetCornerIndicesAttr().Get(time))
    if scheme is None:
        scheme = {"catmullClark": "catmull-clark", "loop": "loop"}[m.GetSubdivisionSchemeAttr().Get()]
    return as_baked(ws.refine(ws.Mesh(pts, counts, indices, **kw), levels, scheme=scheme, device="cpu"))


def assert_refined(prim, expected, time=Usd.TimeCode.Default()):
    """The composed output mesh ``prim`` is the refined mesh ``expected``."""
    m = UsdGeom.Mesh(prim)
    assert m.GetSubdivisionSchemeAttr().Get() == "none", prim.GetPath()
    counts = m.GetFaceVertexCountsAttr().Get(time)
    assert len(counts) == expected.num_faces, prim.GetPath()
    np.testing.assert_array_equal(np.asarray(m.GetFaceVertexIndicesAttr().Get(time)), expected.face_vertex_indices)
    np.testing.assert_allclose(np.asarray(m.GetPointsAttr().Get(time)), expected.points, atol=1e-5)


def meshes(stage):
    return [p for p in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies()) if p.IsA(UsdGeom.Mesh)]


def instancing(stage):
    """({instance path: prototype path} of every instance, nested ones too; the number of prototypes)."""
    out = {str(p.GetPath()): str(p.GetPrototype().GetPath())
           for p in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies()) if p.IsInstance()}
    return out, len(stage.GetPrototypes())


def assert_instancing_kept(src, dst):
    """Every instance is still an instance, the same instances share prototypes, and no prototype is added."""
    a, na = instancing(src)
    b, nb = instancing(dst)

    def groups(m):
        return sorted(sorted(k for k in m if m[k] == v) for v in set(m.values()))

    assert set(a) == set(b) and groups(a) == groups(b) and nb == na


def folder_digest(folder):
    h = hashlib.sha256()
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if os.path.isfile(path):
            h.update(name.encode())
            h.update(open(path, "rb").read())
    return h.hexdigest()


_VALIDATORS = None


def validation_errors(path):
    """The names of the errors usd-core's validators (UsdValidation, every registered validator) report."""
    global _VALIDATORS
    if _VALIDATORS is None:
        _VALIDATORS = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors = UsdValidation.ValidationContext(_VALIDATORS).Validate(Usd.Stage.Open(str(path)))
    return {e.GetName() for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error}


def assert_valid(src, dst):
    """No validation error in the output that the input does not have."""
    assert validation_errors(dst) <= validation_errors(src)


_ASSET_FOLDERS = []


def refine(src, dst, levels=LEVELS, **kw):
    """refine_usd, checking that the input files (the scene's folder and the assets') are untouched."""
    folders = [os.path.dirname(src)] + _ASSET_FOLDERS
    before = [folder_digest(f) for f in folders]
    result = refine_usd(str(src), str(dst), levels, device="cpu", **kw)
    assert [folder_digest(f) for f in folders] == before
    return result


def with_selections(path, selections):
    """The stage of ``path`` with variant selections {prim path: {set: variant}} made in its session layer."""
    stage = Usd.Stage.Open(str(path))
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for prim_path, chosen in selections.items():
            for vset, variant in chosen.items():
                stage.GetPrimAtPath(prim_path).GetVariantSets().GetVariantSet(vset).SetVariantSelection(variant)
    return stage


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("assets")
    _ASSET_FOLDERS[:] = [str(folder)]
    return {"cube": write_asset(folder / "cube.usda"), "nested": write_nested_variant_asset(folder / "lod.usda"),
            "folder": folder}


# -- tests -------------------------------------------------------------------------------------------------

def instanced_scene(folder, asset):
    """Three instanceable references to the cube asset: two smooth, one sharp (two prototypes)."""
    (folder / "in").mkdir()
    path = folder / "in" / "instances.usda"
    stage = new_stage(path)
    place(stage, "/World/I1", asset, instanceable=True, x=0.0)
    place(stage, "/World/I2", asset, instanceable=True, x=2.0)
    place(stage, "/World/I3", asset, instanceable=True, x=4.0, variants={"crease": "sharp"})
    stage.Save()
    return path


def test_instances_are_refined_once_per_prototype_and_stay_instances(assets, tmp_path):
    """Instanceable references with a crease variant (three instances, two variants): each prototype is refined
    once, every instance composes to its variant's refined mesh, and the instances still share two
    prototypes (the output references one refined prototype per distinct prototype)."""
    src = instanced_scene(tmp_path, assets["cube"])
    dst = tmp_path / "out.usda"
    result = refine(src, dst)
    assert len(result.reports) == 2 and result.reports[0].faces_out == 6 * 4 ** LEVELS
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    for prim in meshes(after):
        assert prim.IsInstanceProxy()
        assert_refined(prim, expected_of(before.GetPrimAtPath(prim.GetPath())))
    assert_instancing_kept(before, after)
    layer = Sdf.Layer.FindOrOpen(str(dst))
    assert [str(c.path) for c in layer.GetPrimAtPath("/__warpSubdiv").nameChildren] == [
        "/__warpSubdiv/Prototype_1", "/__warpSubdiv/Prototype_2"]
    assert_valid(src, dst)


def test_all_variants_bakes_every_variant_inside_the_variant_set(assets, tmp_path):
    """`refine --all-variants` refines both crease variants of the instanced asset into one refined prototype
    that holds them in the same variant set: the output still switches variants (each instance, in each
    variant, composes to that variant's refined mesh) and keeps its two prototypes."""
    src = instanced_scene(tmp_path, assets["cube"])
    dst = tmp_path / "out.usda"
    before = folder_digest(src.parent), folder_digest(assets["folder"])
    assert cli.main(["refine", str(src), "-o", str(dst), "--levels", str(LEVELS), "--all-variants", "--device",
                     "cpu", "--quiet"]) == 0
    assert (folder_digest(src.parent), folder_digest(assets["folder"])) == before
    layer = Sdf.Layer.FindOrOpen(str(dst))
    proto = layer.GetPrimAtPath("/__warpSubdiv/Prototype_1")
    assert sorted(proto.variantSets["crease"].variants.keys()) == ["sharp", "smooth"]
    assert len(layer.GetPrimAtPath("/__warpSubdiv").nameChildren) == 1
    assert_instancing_kept(Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst)))
    for inst in ("/World/I1", "/World/I2", "/World/I3"):
        for variant in ("smooth", "sharp"):
            chosen = {inst: {"crease": variant}}
            out, inp = with_selections(dst, chosen), with_selections(src, chosen)
            assert_refined(out.GetPrimAtPath(inst + "/Geo/Mesh"), expected_of(inp.GetPrimAtPath(inst + "/Geo/Mesh")))
            assert out.GetPrimAtPath(inst).IsInstance() and len(out.GetPrototypes()) == len(inp.GetPrototypes())
    assert_valid(src, dst)


def test_nested_instances_reference_their_prototypes_from_inside(assets, tmp_path):
    """Nested instances: a group asset holding two instanceable references to the cube, instanced twice, and
    the cube instanced directly. Every mesh is refined, the cube's prototype once, and the three prototypes
    stay three (the group's refined content references the cube's)."""
    folder = tmp_path / "in"
    folder.mkdir()
    group = new_stage(folder / "group.usda", "Group")
    place(group, "/Group/A", assets["cube"], instanceable=True, x=0.0)
    place(group, "/Group/B", assets["cube"], instanceable=True, x=2.0, variants={"crease": "sharp"})
    group.Save()
    stage = new_stage(folder / "scene.usda")
    place(stage, "/World/G1", str(folder / "group.usda"), "/Group", instanceable=True, x=0.0)
    place(stage, "/World/G2", str(folder / "group.usda"), "/Group", instanceable=True, x=5.0)
    place(stage, "/World/C", assets["cube"], instanceable=True, x=10.0)
    stage.Save()
    src, dst = folder / "scene.usda", tmp_path / "out.usda"
    result = refine(src, dst)
    assert len(result.reports) == 2
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    assert len(meshes(after)) == 5
    for prim in meshes(after):
        assert_refined(prim, expected_of(before.GetPrimAtPath(prim.GetPath())))
    assert_instancing_kept(before, after)
    assert_valid(src, dst)


def test_point_instancer_prototypes_are_refined(assets, tmp_path):
    """A PointInstancer with a subdivision prototype defined under it, an instanceable reference as a second
    prototype and a third authored as an over (not drawn on its own): all are refined (the first and third in
    place, the second through its prototype), the instancer's prototypes and indices are unchanged."""
    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    UsdGeom.Scope.Define(stage, "/World/Scatter/Prototypes")
    define_mesh(stage, "/World/Scatter/Prototypes/Plate", PLATE, PLATE_FACES)
    place(stage, "/World/Scatter/Prototypes/Cube", assets["cube"], instanceable=True)
    hidden = define_mesh(stage, "/World/Scatter/Prototypes/Hidden", PLATE * 2.0, PLATE_FACES)
    hidden.GetPrim().SetSpecifier(Sdf.SpecifierOver)
    pi.CreatePrototypesRel().SetTargets(["/World/Scatter/Prototypes/Plate", "/World/Scatter/Prototypes/Cube",
                                         "/World/Scatter/Prototypes/Hidden"])
    pi.CreateProtoIndicesAttr(Vt.IntArray([0, 1, 0, 2]))
    pi.CreatePositionsAttr(Vt.Vec3fArray([(0, 0, 0), (3, 0, 0), (6, 0, 0), (9, 0, 0)]))
    stage.Save()
    src, dst = folder / "scene.usda", tmp_path / "out.usda"
    refine(src, dst)
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    for path in ("/World/Scatter/Prototypes/Plate", "/World/Scatter/Prototypes/Cube/Geo/Mesh",
                 "/World/Scatter/Prototypes/Hidden"):
        assert_refined(after.GetPrimAtPath(path), expected_of(before.GetPrimAtPath(path)))
    out_pi = UsdGeom.PointInstancer(after.GetPrimAtPath("/World/Scatter"))
    assert out_pi.GetPrototypesRel().GetTargets() == pi.GetPrototypesRel().GetTargets()
    assert list(out_pi.GetProtoIndicesAttr().Get()) == [0, 1, 0, 2]
    assert_instancing_kept(before, after)
    assert_valid(src, dst)


def test_payloads_are_loaded_and_refined(assets, tmp_path):
    """An asset brought in by a payload (and an instanceable payload) is loaded and refined."""
    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    place(stage, "/World/P", assets["cube"], payload=True)
    place(stage, "/World/Q", assets["cube"], payload=True, instanceable=True, x=3.0, variants={"crease": "sharp"})
    stage.Save()
    src, dst = folder / "scene.usda", tmp_path / "out.usda"
    refine(src, dst)
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    for path in ("/World/P/Geo/Mesh", "/World/Q/Geo/Mesh"):
        assert_refined(after.GetPrimAtPath(path), expected_of(before.GetPrimAtPath(path)))
    assert after.GetPrimAtPath("/World/Q").IsInstance()
    assert_valid(src, dst)


def test_an_asset_referenced_twice_is_refined_and_written_once(assets, tmp_path):
    """The same asset referenced twice (not instanced, no overrides) is refined once and written once: both
    meshes reference one shared refined mesh. A third reference whose mesh has a local opinion on an attribute
    the refined mesh sets (same inputs, so refined with them) gets its own copy, because a reference would
    lose against that opinion: every mesh composes to the refined data."""
    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    for name, x in (("A", 0.0), ("B", 2.0), ("C", 4.0)):
        place(stage, "/World/" + name, assets["cube"], x=x)
    stage.GetPrimAtPath("/World/C/Geo/Mesh").GetAttribute("subdivisionScheme").Set("catmullClark")
    stage.Save()
    src, dst = folder / "scene.usda", tmp_path / "out.usda"
    result = refine(src, dst)
    assert len(result.reports) == 1
    layer = Sdf.Layer.FindOrOpen(str(dst))
    with_points = []
    layer.Traverse(Sdf.Path.absoluteRootPath,
                   lambda p: with_points.append(str(p.GetPrimPath())) if p.IsPropertyPath() and p.name == "points"
                   else None)
    assert sorted(with_points) == ["/World/C/Geo/Mesh", "/__warpSubdiv/Mesh_1"]
    for name in ("A", "B"):
        refs = layer.GetPrimAtPath(f"/World/{name}/Geo/Mesh").referenceList.prependedItems
        assert [str(r.primPath) for r in refs] == ["/__warpSubdiv/Mesh_1"]
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    for name in ("A", "B", "C"):
        path = f"/World/{name}/Geo/Mesh"
        assert_refined(after.GetPrimAtPath(path), expected_of(before.GetPrimAtPath(path)))
    assert_valid(src, dst)


def test_nested_variant_sets_are_baked_with_all_variants(assets, tmp_path):
    """Nested variant sets (lod = high | low, and crease = soft | hard inside lod = high), on a referenced asset
    and on an instanced one: with --all-variants every combination composes to its refined mesh in the output;
    without, the selected variants are refined as composed."""
    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    place(stage, "/World/Ref", assets["nested"])
    place(stage, "/World/Inst", assets["nested"], instanceable=True, x=3.0)
    stage.Save()
    src = folder / "scene.usda"
    refine(src, tmp_path / "selected.usda")
    before, after = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(tmp_path / "selected.usda"))
    for prim in meshes(after):
        assert_refined(prim, expected_of(before.GetPrimAtPath(prim.GetPath())))
    dst = tmp_path / "all.usda"
    refine(src, dst, all_variants=True)
    combos = [{"lod": "high", "crease": "soft"}, {"lod": "high", "crease": "hard"}, {"lod": "low"}]
    faces = set()
    for root in ("/World/Ref", "/World/Inst"):
        for combo in combos:
            out, inp = with_selections(dst, {root: combo}), with_selections(src, {root: combo})
            expected = expected_of(inp.GetPrimAtPath(root + "/Geo/Mesh"))
            assert_refined(out.GetPrimAtPath(root + "/Geo/Mesh"), expected)
            faces.add((expected.num_faces, expected.points.round(4).tobytes()))
    assert len(faces) == 3  # three different refined meshes
    assert_instancing_kept(Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst)))
    assert_valid(src, dst)


def test_polygonal_meshes_are_refined_on_request(tmp_path, capsys):
    """A mesh with subdivisionScheme none is left alone, and the error says how to refine it; an explicit
    --scheme with --prim refines the meshes at or under that path whatever their scheme says."""
    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    define_mesh(stage, "/World/Poly", PLATE, PLATE_FACES, scheme="none")
    define_mesh(stage, "/World/Other/Poly", PLATE, PLATE_FACES, scheme="none")
    stage.Save()
    src, before = folder / "scene.usda", folder_digest(folder)
    assert cli.main(["refine", str(src), "-o", str(tmp_path / "x.usda"), "--levels", "1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no subdivision meshes" in err and "--scheme loop or catmull-clark with --prim" in err
    for scheme in ("catmull-clark", "loop"):
        dst = tmp_path / f"{scheme}.usda"
        assert cli.main(["refine", str(src), "-o", str(dst), "--levels", str(LEVELS), "--scheme", scheme, "--prim",
                         "/World/Poly", "--device", "cpu", "--quiet"]) == 0
        inp, out = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
        assert_refined(out.GetPrimAtPath("/World/Poly"), expected_of(inp.GetPrimAtPath("/World/Poly"), scheme=scheme))
        assert len(out.GetPrimAtPath("/World/Other/Poly").GetAttribute("faceVertexCounts").Get()) == 2
        assert_valid(src, dst)
    assert folder_digest(folder) == before


def test_time_varying_topology_is_refined_per_sample(tmp_path, monkeypatch):
    """Topology that changes over time (a plate of 2 quads at times 1 and 2, 3 quads at 3, 2 again at 5) is
    refined per sample with the topology of that time: one refiner per distinct topology (2), time-sampled
    faceVertexCounts / faceVertexIndices in the output wherever the topology changes."""
    from warp_subdiv.usd import refine as usd

    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(5)
    mesh = define_mesh(stage, "/World/Strip", PLATE, PLATE_FACES)
    long_pts = np.array([(x, y, 0.0) for y in (0.0, 1.0) for x in (0.0, 1.0, 2.0, 3.0)])
    long_faces = [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6)]
    for t, (pts, faces) in {1.0: (PLATE, PLATE_FACES), 2.0: (PLATE + [0, 0, 0.2], PLATE_FACES),
                            3.0: (long_pts, long_faces), 5.0: (PLATE + [0, 0, 0.5], PLATE_FACES)}.items():
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(pts, dtype=np.float32)), t)
        mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray([len(f) for f in faces]), t)
        mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray([i for f in faces for i in f]), t)
    stage.Save()
    built = []
    make = usd.make_refiner
    monkeypatch.setattr(usd, "make_refiner", lambda sp, levels, **kw: (built.append(levels), make(sp, levels, **kw))[1])
    src, dst = folder / "scene.usda", tmp_path / "out.usda"
    refine(src, dst)
    assert built.count(LEVELS) == 2
    inp, out = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(dst))
    prim = out.GetPrimAtPath("/World/Strip")
    assert UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().GetTimeSamples() == [1.0, 3.0, 5.0]
    for t in (1.0, 2.0, 3.0, 4.0, 5.0):
        assert_refined(prim, expected_of(inp.GetPrimAtPath("/World/Strip"), time=Usd.TimeCode(t)), Usd.TimeCode(t))
    assert_valid(src, dst)


def test_render_draws_point_instanced_copies(tmp_path):
    """`render` draws a PointInstancer's prototype at every instance's position and orientation (not the
    prototype once): seen from above with an orthographic camera, each of the three copies covers as many red
    pixels as the plate drawn on its own, and the copy turned by 90 degrees is as tall as the others are wide."""
    from warp_subdiv.render import render_file

    folder = tmp_path / "in"
    folder.mkdir()

    def scene(path, instanced):
        stage = new_stage(path)
        cam = UsdGeom.Camera.Define(stage, "/World/Cam")
        cam.CreateProjectionAttr("orthographic")
        cam.CreateHorizontalApertureAttr(120.0)  # tenths of a unit: 12 units across
        cam.CreateVerticalApertureAttr(40.0)
        cam.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 10.0))
        if instanced:
            pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
            define_mesh(stage, "/World/Scatter/Plate", PLATE - [1.0, 0.5, 0.0], PLATE_FACES, color=(1, 0, 0))
            pi.CreatePrototypesRel().SetTargets(["/World/Scatter/Plate"])
            pi.CreateProtoIndicesAttr(Vt.IntArray([0, 0, 0]))
            pi.CreatePositionsAttr(Vt.Vec3fArray([(-4, 0, 0), (0, 0, 0), (4, 0, 0)]))
            turn = Gf.Rotation(Gf.Vec3d(0, 0, 1), 90).GetQuat()
            pi.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(1), Gf.Quath(turn), Gf.Quath(1)]))
        else:
            define_mesh(stage, "/World/Plate", PLATE - [1.0, 0.5, 0.0], PLATE_FACES, color=(1, 0, 0))
        stage.Save()
        return str(path)

    def red(img):
        return (img[..., 0] > 120) & (img[..., 1] < 90) & (img[..., 2] < 90)

    size = (240, 80)  # 20 pixels per unit
    one = red(render_file(scene(folder / "one.usda", False), str(tmp_path / "one.png"), camera="/World/Cam",
                          size=size, samples=1, device="cpu"))
    many = red(render_file(scene(folder / "many.usda", True), str(tmp_path / "many.png"), camera="/World/Cam",
                           size=size, samples=1, device="cpu"))
    single = int(one.sum())
    assert 700 < single < 900  # 2 x 1 units at 20 pixels per unit
    thirds = [many[:, :80], many[:, 80:160], many[:, 160:]]
    for part in thirds:
        assert abs(int(part.sum()) - single) <= 0.03 * single
    rows, cols = np.nonzero(thirds[1])
    assert np.ptp(rows) > np.ptp(cols)  # turned by 90 degrees: taller than wide
    rows, cols = np.nonzero(thirds[0])
    assert np.ptp(cols) > np.ptp(rows)


def test_render_levels_refines_instanced_meshes_as_refine_does(assets, tmp_path):
    """`render --levels N` on instances and point-instanced prototypes draws exactly the triangles of the
    refined output (same points, same faces, same places)."""
    from warp_subdiv.render import stage_soup

    folder = tmp_path / "in"
    folder.mkdir()
    stage = new_stage(folder / "scene.usda")
    place(stage, "/World/I1", assets["cube"], instanceable=True)
    place(stage, "/World/I2", assets["cube"], instanceable=True, x=2.0, variants={"crease": "sharp"})
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    define_mesh(stage, "/World/Scatter/Plate", PLATE, PLATE_FACES)
    pi.CreatePrototypesRel().SetTargets(["/World/Scatter/Plate"])
    pi.CreateProtoIndicesAttr(Vt.IntArray([0, 0]))
    pi.CreatePositionsAttr(Vt.Vec3fArray([(0, 4, 0), (3, 4, 1)]))
    stage.Save()
    src, dst = folder / "scene.usda", tmp_path / "out.usda"
    refine(src, dst)
    preview = stage_soup(Usd.Stage.Open(str(src)), levels=LEVELS)
    baked = stage_soup(Usd.Stage.Open(str(dst)))
    triangles = 2 * (2 * 6 * 4 ** LEVELS + 2 * 2 * 4 ** LEVELS)  # two cubes and two plates, quads in halves
    assert len(preview.corners) == len(baked.corners) == 3 * triangles
    np.testing.assert_allclose(preview.corners, baked.corners, atol=1e-5)


@pytest.mark.parametrize("name", sorted(n[:-5] for n in os.listdir(SCENES_DIR) if n.endswith(".usda")))
def test_bundled_scenes_refine_to_valid_usd(name, tmp_path):
    """The refined layer of every scene in scenes/ has no validation error its input does not have (a scene
    without subdivision meshes has nothing to refine)."""
    src = os.path.join(SCENES_DIR, name + ".usda")
    dst = tmp_path / "out.usda"
    try:
        refine_usd(src, str(dst), 1, device="cpu")
    except SubdivInputError as exc:
        if "no subdivision meshes" not in str(exc):
            raise
        pytest.skip(f"{name}: no subdivision meshes")
    assert_valid(src, dst)


def test_info_and_plan_say_where_one_refinement_goes(assets, tmp_path, capsys):
    """`info` lists a prototype's mesh once and says how many meshes it is refined for; Plan.one_place_each
    tells a mesh-by-mesh (distributed) bake whether each refined mesh goes to its own path only."""
    from warp_subdiv.usd import plan

    src = instanced_scene(tmp_path, assets["cube"])
    assert cli.main(["info", str(src), "--levels", "1"]) == 0
    out = capsys.readouterr().out
    assert out.count("/World/I") == 2 and "refined once for 2 meshes" in out
    assert not plan(str(src), 1).one_place_each
    stage = new_stage(tmp_path / "in" / "plain.usda")
    define_mesh(stage, "/World/A", PLATE, PLATE_FACES)
    define_mesh(stage, "/World/B", CUBE, CUBE_FACES)
    stage.Save()
    assert plan(str(tmp_path / "in" / "plain.usda"), 1).one_place_each
