"""Refined data that reaches a mesh through an internal reference or a variant, where the input holds an opinion
that is stronger than that arc: a shot-level override on meshes that share one refined mesh, a class that
instances inherit, a local opinion beside the variants of --all-variants. The composed output must show the
refined values everywhere (primvars, face-varying indices, subsets, normals, points), each the refinement of the
input value that wins, and what cannot be written so is an error naming the opinion. Each test writes its own
small scene; the values expected are those of the same mesh baked where no arc is involved."""
import os

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from test_usd_production import CUBE, CUBE_FACES, define_mesh, expected_of, new_stage, place
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd.refine import refine_usd

LEVELS = 2
FACES = 6 * 4 ** LEVELS
T = Sdf.ValueTypeNames
SIX = Vt.Vec3fArray([Gf.Vec3f(i / 6.0, 1.0 - i / 6.0, 0.5) for i in range(6)])
_OPEN = []


@pytest.fixture(autouse=True)
def _close_stages():
    yield
    _OPEN.clear()


def opened(path):
    stage = Usd.Stage.Open(str(path))
    _OPEN.append(stage)
    return stage


def write_cube_asset(path, *, st=False, subset=False, colors=None):
    """/Asset/Geo/Mesh: a Catmull-Clark cube; ``st``: indexed face-varying texture coordinates; ``subset``: a
    face subset /Asset/Geo/Mesh/top of face 1; ``colors``: a uniform displayColor."""
    stage = new_stage(path, "Asset")
    UsdGeom.Xform.Define(stage, "/Asset/Geo")
    mesh = define_mesh(stage, "/Asset/Geo/Mesh", CUBE, CUBE_FACES)
    if st:
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", T.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray([(0, 0), (1, 0), (1, 1), (0, 1)]))
        pv.SetIndices(Vt.IntArray([0, 1, 2, 3] * 6))
    if subset:
        UsdGeom.Subset.CreateGeomSubset(mesh, "top", UsdGeom.Tokens.face, Vt.IntArray([1]))
    if colors is not None:
        set_colors(mesh.GetPrim(), colors)
    stage.Save()
    return str(path)


def set_colors(prim, colors=SIX):
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("displayColor", T.Color3fArray, UsdGeom.Tokens.uniform)
    pv.Set(colors)


def bake(tmp_path, name, build, asset_kw=None, **kw):
    """Write a scene (``build(stage, asset)``) next to a cube asset, bake it; the output path."""
    folder = tmp_path / name
    folder.mkdir()
    asset = write_cube_asset(folder / "cube.usda", **(asset_kw or {}))
    src = folder / "scene.usda"
    stage = new_stage(src)
    build(stage, asset)
    stage.Save()
    dst = folder / "out.usda"
    refine_usd(str(src), str(dst), LEVELS, device="cpu", **kw)
    return dst


def mesh_at(path, prim):
    return UsdGeom.Mesh(opened(path).GetPrimAtPath(prim))


def colors_of(mesh):
    return np.asarray(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("displayColor").ComputeFlattened())


def class_over(stage, name="/_Cube"):
    stage.CreateClassPrim(name)
    return stage.OverridePrim(name + "/Geo/Mesh")


def instance(stage, path, asset, x=0.0, inherit="/_Cube", **kw):
    prim = place(stage, path, asset, instanceable=True, x=x, **kw)
    if inherit:
        prim.GetInherits().AddInherit(inherit)
    return prim


def assert_refined_colors(colors, control=SIX):
    """``colors``: ``control`` (6 colours) refined as a uniform primvar, one per refined face (each refined
    face takes its control face's colour: 16 faces of each)."""
    assert len(colors) == FACES
    values, counts = np.unique(np.asarray(colors), axis=0, return_counts=True)
    np.testing.assert_allclose(values, np.unique(np.asarray(control), axis=0))
    assert list(counts) == [FACES // 6] * 6


def test_shot_override_on_meshes_that_share_one_refinement(tmp_path):
    """Two references to one asset, both with the same shot-level displayColor override on the mesh (6 values,
    one per face): one refinement serves both, and the override is stronger than a reference to it, so each
    mesh composes the refined colours (96, one per refined face), as a mesh baked on its own does."""
    def build(stage, asset, names=("A", "B")):
        for x, name in enumerate(names):
            place(stage, "/World/" + name, asset, x=2.0 * x)
            set_colors(stage.GetPrimAtPath(f"/World/{name}/Geo/Mesh"))

    dst = bake(tmp_path, "shared", build)
    ref = colors_of(mesh_at(bake(tmp_path, "ref", lambda s, a: build(s, a, ["A"])), "/World/A/Geo/Mesh"))
    assert_refined_colors(ref)
    for name in ("A", "B"):
        mesh = mesh_at(dst, f"/World/{name}/Geo/Mesh")
        assert len(mesh.GetFaceVertexCountsAttr().Get()) == FACES
        np.testing.assert_array_equal(colors_of(mesh), ref)
    # nothing is left referencing the shared refined mesh: it is gone, and so is the container
    layer = Sdf.Layer.FindOrOpen(str(dst))
    assert not layer.GetPrimAtPath("/__warpSubdiv")


def test_instances_inheriting_a_class_with_a_primvar_override(tmp_path):
    """Instances that inherit a class overriding displayColor (6 values): the class is stronger than the
    instances' reference to their refined prototype, so the refined colours are written over the class's
    opinion; every instance shows 96 colours, and the instances keep sharing one prototype."""
    def build(stage, asset):
        set_colors(class_over(stage))
        instance(stage, "/World/I1", asset)
        instance(stage, "/World/I2", asset, x=2.0)
        place(stage, "/World/Alone", asset, x=4.0).GetInherits().AddInherit("/_Cube")

    dst = bake(tmp_path, "class", build)
    stage = opened(dst)
    ref = colors_of(mesh_at(dst, "/World/Alone/Geo/Mesh"))
    assert_refined_colors(ref)
    for name in ("I1", "I2"):
        mesh = mesh_at(dst, f"/World/{name}/Geo/Mesh")
        assert len(mesh.GetFaceVertexCountsAttr().Get()) == FACES
        np.testing.assert_array_equal(colors_of(mesh), ref)
        assert stage.GetPrimAtPath("/World/" + name).IsInstance()
    assert len(stage.GetPrototypes()) == 1


def test_a_class_one_instance_inherits_with_the_values_it_has(tmp_path):
    """One of two instances inherits a class that overrides displayColor with the values the asset has: both
    instances refine alike (one refinement), but the class is stronger for the one that inherits it; it must
    show the refined colours too."""
    def build(stage, asset):
        set_colors(class_over(stage))
        instance(stage, "/World/I1", asset, inherit=None)
        instance(stage, "/World/I2", asset, x=2.0)

    dst = bake(tmp_path, "one", build, asset_kw={"colors": SIX})
    first = colors_of(mesh_at(dst, "/World/I1/Geo/Mesh"))
    assert len(first) == FACES
    np.testing.assert_array_equal(colors_of(mesh_at(dst, "/World/I2/Geo/Mesh")), first)


@pytest.mark.parametrize("all_variants", [False, True])
def test_a_variant_set_authored_on_each_instance(tmp_path, all_variants):
    """A shot authors a variant set on each instance prim whose variants override displayColor (the variant is
    stronger than the instance's reference to its refined prototype): the selected variant (every variant with
    all_variants) shows the refined colours on every instance, the instances staying instances."""
    blue = Vt.Vec3fArray([Gf.Vec3f(0.0, 0.0, i / 6.0) for i in range(6)])

    def build(stage, asset):
        for x, name in enumerate(("I1", "I2")):
            prim = instance(stage, "/World/" + name, asset, x=2.0 * x, inherit=None)
            looks = prim.GetVariantSets().AddVariantSet("look")
            for look, colors in (("red", SIX), ("blue", blue)):
                looks.AddVariant(look)
                looks.SetVariantSelection(look)
                with looks.GetVariantEditContext():
                    set_colors(stage.OverridePrim(f"/World/{name}/Geo/Mesh"), colors)
            looks.SetVariantSelection("red")

    dst = bake(tmp_path, "looks", build, all_variants=all_variants)
    for look, colors in (("red", SIX), ("blue", blue)) if all_variants else (("red", SIX),):
        stage = opened(dst)
        for name in ("I1", "I2"):
            stage.GetPrimAtPath("/World/" + name).GetVariantSet("look").SetVariantSelection(look)
        for name in ("I1", "I2"):
            assert stage.GetPrimAtPath("/World/" + name).IsInstance()
            got = colors_of(UsdGeom.Mesh(stage.GetPrimAtPath(f"/World/{name}/Geo/Mesh")))
            assert_refined_colors(got, colors)


def test_a_class_override_of_face_varying_values(tmp_path):
    """A class overrides the values of an indexed face-varying st (not its indices): the refined values are
    written over the class's, so values and indices are both refined and ComputeFlattened works."""
    def build(stage, asset):
        class_over(stage).CreateAttribute("primvars:st", T.TexCoord2fArray).Set(
            Vt.Vec2fArray([(0, 0), (0.5, 0), (0.5, 0.5), (0, 0.5)]))
        instance(stage, "/World/I1", asset)
        place(stage, "/World/Alone", asset, x=4.0).GetInherits().AddInherit("/_Cube")

    dst = bake(tmp_path, "st", build, asset_kw={"st": True})
    ref = UsdGeom.PrimvarsAPI(mesh_at(dst, "/World/Alone/Geo/Mesh")).GetPrimvar("st").ComputeFlattened()
    pv = UsdGeom.PrimvarsAPI(mesh_at(dst, "/World/I1/Geo/Mesh")).GetPrimvar("st")
    flat = pv.ComputeFlattened()
    assert flat is not None and len(flat) == 4 * FACES
    np.testing.assert_array_equal(np.asarray(flat), np.asarray(ref))
    assert np.asarray(flat).max() == pytest.approx(0.5)  # the class's values, refined


def test_a_class_override_of_points(tmp_path):
    """A class overrides the points (the cube scaled by 2): the refined points of the class's points are written
    over its opinion (the bake used to fail, advising to refine without all_variants)."""
    def build(stage, asset):
        class_over(stage).CreateAttribute("points", T.Point3fArray).Set(
            Vt.Vec3fArray.FromNumpy((CUBE * 2).astype(np.float32)))
        instance(stage, "/World/I1", asset)
        instance(stage, "/World/I2", asset, x=3.0)

    dst = bake(tmp_path, "points", build)
    src = opened(tmp_path / "points" / "scene.usda")
    expected = expected_of(src.GetPrimAtPath("/World/I1/Geo/Mesh"))
    for name in ("I1", "I2"):
        mesh = mesh_at(dst, f"/World/{name}/Geo/Mesh")
        assert len(mesh.GetFaceVertexCountsAttr().Get()) == expected.num_faces
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get()), expected.points, atol=1e-5)
        assert np.asarray(mesh.GetPointsAttr().Get()).max() > 1.5


def test_a_class_override_of_subset_indices_and_normals(tmp_path):
    """A class overrides a face subset's indices and authors control normals: the subset's refined indices
    (the children of the class's faces) and the block of the control normals are written over it; with
    normals=True the refined normals are."""
    def build(stage, asset):
        over = class_over(stage)
        stage.OverridePrim("/_Cube/Geo/Mesh/top").CreateAttribute("indices", T.IntArray).Set(Vt.IntArray([0, 2]))
        over.CreateAttribute("normals", T.Normal3fArray).Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)] * 8))
        instance(stage, "/World/I1", asset)
        place(stage, "/World/Alone", asset, x=4.0).GetInherits().AddInherit("/_Cube")

    dst = bake(tmp_path, "subset", build, asset_kw={"subset": True})
    ref = mesh_at(dst, "/World/Alone/Geo/Mesh").GetPrim().GetChild("top").GetAttribute("indices").Get()
    assert len(ref) == 2 * 4 ** LEVELS
    got = mesh_at(dst, "/World/I1/Geo/Mesh").GetPrim().GetChild("top").GetAttribute("indices").Get()
    assert list(got) == list(ref)
    assert mesh_at(dst, "/World/I1/Geo/Mesh").GetNormalsAttr().Get() is None
    dst = bake(tmp_path, "normals", build, asset_kw={"subset": True}, normals=True)
    points = mesh_at(dst, "/World/I1/Geo/Mesh").GetPointsAttr().Get()
    normals = mesh_at(dst, "/World/I1/Geo/Mesh").GetNormalsAttr().Get()
    assert len(normals) == len(points) > 8
    np.testing.assert_array_equal(np.asarray(normals),
                                  np.asarray(mesh_at(dst, "/World/Alone/Geo/Mesh").GetNormalsAttr().Get()))


def test_all_variants_with_a_local_primvar_override(tmp_path):
    """--all-variants with a shot-level displayColor on the mesh, beside the asset's variant set: the local
    opinion is stronger than the variants that hold the refined data; both variants refine it alike, so the
    refined colours are written over it and every variant shows them."""
    from test_usd_production import write_asset

    folder = tmp_path / "variants"
    folder.mkdir()
    asset = write_asset(folder / "cube.usda")
    src = folder / "scene.usda"
    stage = new_stage(src)
    place(stage, "/World/A", asset)
    set_colors(stage.GetPrimAtPath("/World/A/Geo/Mesh"))
    stage.Save()
    dst = folder / "out.usda"
    refine_usd(str(src), str(dst), LEVELS, device="cpu", all_variants=True)
    for variant in ("smooth", "sharp"):
        out = opened(dst)
        out.GetPrimAtPath("/World/A").GetVariantSet("crease").SetVariantSelection(variant)
        mesh = UsdGeom.Mesh(out.GetPrimAtPath("/World/A/Geo/Mesh"))
        assert len(mesh.GetFaceVertexCountsAttr().Get()) == FACES
        assert len(colors_of(mesh)) == FACES


def test_stronger_opinions_that_cannot_take_the_refined_value_are_errors(tmp_path):
    """A class whose refined value would also reach an instance that is not refined (--prim names the other),
    a class whose instances refine to different points, a local opinion on points beside variants that
    refine it differently: each is an error naming the opinion, and nothing is written."""
    def reach(stage, asset):
        set_colors(class_over(stage))
        instance(stage, "/World/I1", asset)
        instance(stage, "/World/I2", asset, x=2.0)

    with pytest.raises(SubdivInputError, match=r"/World/I2/Geo/Mesh: takes primvars:displayColor from "
                                               r"/_Cube/Geo/Mesh.primvars:displayColor.*not refined"):
        bake(tmp_path, "reach", reach, prims=["/World/I1"])
    assert not os.path.exists(tmp_path / "reach" / "out.usda")

    def differ(stage, asset):
        class_over(stage).CreateAttribute("points", T.Point3fArray).Set(
            Vt.Vec3fArray.FromNumpy((CUBE * 2).astype(np.float32)))
        instance(stage, "/World/I1", asset)
        instance(stage, "/World/I2", asset, x=2.0, variants={"crease": "sharp"})

    from test_usd_production import write_asset

    def with_variants(name, build, **kw):
        folder = tmp_path / name
        folder.mkdir()
        asset = write_asset(folder / "cube.usda")
        stage = new_stage(folder / "scene.usda")
        build(stage, asset)
        stage.Save()
        refine_usd(str(folder / "scene.usda"), str(folder / "out.usda"), LEVELS, device="cpu", **kw)

    with pytest.raises(SubdivInputError, match=r"/_Cube/Geo/Mesh.points is stronger than their refined points, "
                                               r"which differ"):
        with_variants("differ", differ)

    def local_points(stage, asset):
        place(stage, "/World/A", asset)
        stage.GetPrimAtPath("/World/A/Geo/Mesh").GetAttribute("points").Set(
            Vt.Vec3fArray.FromNumpy((CUBE * 2).astype(np.float32)))

    with pytest.raises(SubdivInputError, match=r"crease = .*/World/A/Geo/Mesh.points is stronger.*all_variants"):
        with_variants("local", local_points, all_variants=True)
