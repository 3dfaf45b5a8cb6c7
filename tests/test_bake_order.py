"""The compact vertex order of the USD bake (warp_subdiv.usd.order): the same surface and values, renumbered so that
usdc compresses the indices; and the face-varying fast path that refines UVs on the vertex topology away from
their seams."""
import os
import warnings

import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv.usd.order import OrderedRefiner, appearance_order, fast_face_varying

MODES = ("none", "corners-only", "corners-plus1", "corners-plus2", "boundaries")


def torus(nu, nv, seed=0):
    """A torus of quads with a UV grid (seams along u = 0 and v = 0)."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(nu) * 2 * np.pi / nu, np.arange(nv) * 2 * np.pi / nv, indexing="ij")
    pts = np.stack([(1 + 0.35 * np.cos(v)) * np.cos(u), (1 + 0.35 * np.cos(v)) * np.sin(u), 0.35 * np.sin(v)],
                   -1).reshape(-1, 3) + 0.01 * rng.standard_normal((nu * nv, 3))
    i, j = (a.reshape(-1) for a in np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij"))
    vid = lambda a, b: (a % nu) * nv + b % nv  # noqa: E731
    uid = lambda a, b: a * (nv + 1) + b  # noqa: E731
    quads = np.stack([vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)], 1).reshape(-1)
    uvq = np.stack([uid(i, j), uid(i + 1, j), uid(i + 1, j + 1), uid(i, j + 1)], 1).reshape(-1)
    gu, gv = np.meshgrid(np.arange(nu + 1) / nu, np.arange(nv + 1) / nv, indexing="ij")
    return pts, np.full(nu * nv, 4), quads, np.stack([gu.reshape(-1), gv.reshape(-1)], 1), uvq


def islands(rng, nx, ny, tri=False):
    """An open grid whose UVs are cut into random islands (random seams), with random creases and a hole."""
    x, y = np.meshgrid(np.arange(nx + 1, dtype=float), np.arange(ny + 1, dtype=float))
    pts = np.stack([x.ravel(), y.ravel(), 0.3 * rng.standard_normal(x.size)], axis=1)
    v = lambda i, j: j * (nx + 1) + i  # noqa: E731
    faces = [[v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)] for j in range(ny) for i in range(nx)]
    if tri:
        faces = [f for a, b, c, d in faces for f in ([a, b, c], [a, c, d])]
    island = rng.integers(0, 3, len(faces))
    idx = np.array([island[f] * len(pts) + vv for f, face in enumerate(faces) for vv in face])
    uv = rng.random((3 * len(pts), 2))
    counts = np.array([len(f) for f in faces])
    indices = np.concatenate(faces)
    creases = [[v(1, 1), v(2, 1)], [v(2, 1), v(3, 1)]]
    return pts, counts, indices, uv, idx, dict(creases=creases, crease_sharpness=[10.0, 2.5],
                                               holes=[int(rng.integers(len(faces)))])


def test_appearance_order_numbers_by_first_use():
    """Ids below keep stay; the rest follow their first use; unused ids go last; the two maps are inverse."""
    new, old = appearance_order(np.array([5, 1, 7, 5, 3, 7, 9]), 10, keep=2)
    assert new[:2].tolist() == [0, 1]
    assert [new[i] for i in (5, 7, 3, 9)] == [2, 3, 4, 5]
    assert sorted(new[[2, 4, 6, 8]].tolist()) == [6, 7, 8, 9]  # unused, in their old order
    np.testing.assert_array_equal(old[new], np.arange(10))


@pytest.mark.parametrize("scheme,rules", [("catmull-clark", "piecewise-smooth"), ("loop", "opensubdiv")])
def test_ordered_refiner_is_the_same_surface_renumbered(scheme, rules):
    """Every refined face corner has the same position, limit position and normal in both orders; control
    vertex v keeps index v; and the compact indices have much smaller jumps than OpenSubdiv's."""
    rng = np.random.default_rng(3)
    pts, counts, indices, _, _, tags = islands(rng, 6, 5, tri=scheme == "loop")
    mesh = ws.Mesh(pts, counts, indices, **tags)
    plain = ws.Refiner(mesh, 2, scheme=scheme, rules=rules, device="cpu", precision="float64")
    ordered = OrderedRefiner(plain)
    c0, i0 = plain.topology()
    c1, i1 = ordered.topology()
    np.testing.assert_array_equal(c0, c1)
    p0, p1 = plain.evaluate(pts), ordered.evaluate(pts)
    np.testing.assert_allclose(p1[i1], p0[i0], atol=1e-12)
    np.testing.assert_allclose(p1[: mesh.num_vertices], p0[: mesh.num_vertices], atol=1e-12)
    np.testing.assert_allclose(ordered.limit_points(p1)[i1], plain.limit_points(p0)[i0], atol=1e-12)
    np.testing.assert_allclose(ordered.limit_normals(p1)[i1], plain.limit_normals(p0)[i0], atol=1e-9)
    assert np.median(np.abs(np.diff(i1.astype(np.int64)))) < np.median(np.abs(np.diff(i0.astype(np.int64))))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_fast_face_varying_matches_the_channel_on_a_torus(mode, rules):
    """Away from the seams the UVs are refined on the vertex topology, near them by the channel of a small
    mesh: at every refined corner the value equals Refiner.evaluate_face_varying's (creases and a hole
    included), and the fast path did apply."""
    pts, counts, idx, uv, uvi = torus(24, 16)
    mesh = ws.Mesh(pts, counts, idx, creases=[[0, 1], [1, 2]], crease_sharpness=[10.0, 1.5], holes=[40])
    refiner = ws.Refiner(mesh, 2, rules=rules, device="cpu", precision="float64")
    fast = fast_face_varying(refiner, uv, uvi, mode)
    assert fast is not None
    values, indices = refiner.evaluate_face_varying(uv, uvi, mode=mode)
    np.testing.assert_allclose(fast[0][fast[1]], values[indices], atol=1e-12)


@pytest.mark.parametrize("seed", range(8))
def test_fast_face_varying_matches_the_channel_on_random_islands(seed):
    """Random UV islands on open grids (boundaries, seams everywhere), both schemes, every mode but "all",
    three levels: the same values at every refined corner as the channel's, or no fast path."""
    rng = np.random.default_rng(seed)
    scheme = ("catmull-clark", "loop")[seed % 2]
    pts, counts, indices, uv, idx, tags = islands(rng, 7, 6, tri=scheme == "loop")
    mesh = ws.Mesh(pts, counts, indices, **tags)
    refiner = ws.Refiner(mesh, 1 + seed % 3, scheme=scheme, device="cpu", precision="float64",
                         boundary=("edge-and-corner", "edge-only", "none")[seed % 3])
    mode = MODES[seed % len(MODES)]
    fast = fast_face_varying(refiner, uv, idx, mode)
    values, fidx = refiner.evaluate_face_varying(uv, idx, mode=mode)
    if fast is not None:
        np.testing.assert_allclose(fast[0][fast[1]], values[fidx], atol=1e-12)
    ordered = OrderedRefiner(refiner)
    v2, i2 = ordered.evaluate_face_varying(uv, idx, mode=mode)
    np.testing.assert_allclose(v2[i2], values[fidx], atol=1e-12)
    if fast is None:
        assert len(v2) == len(np.unique(i2))  # no value that no corner uses


def test_fast_face_varying_refuses_what_the_channel_refuses():
    """Indices out of range and non-finite values raise SubdivInputError on the fast path too."""
    pts, counts, idx, uv, uvi = torus(8, 6)
    refiner = ws.Refiner(ws.Mesh(pts, counts, idx), 1, device="cpu")
    with pytest.raises(ws.SubdivInputError):
        fast_face_varying(refiner, uv[:10], uvi)
    bad = uv.copy()
    bad[3] = np.nan
    with pytest.raises(ws.SubdivInputError):
        fast_face_varying(refiner, bad, uvi)


def test_appearance_order_equals_a_first_occurrence_sort():
    """On random ids (repeats, unused ids, any keep, int32/int64/uint32 input) the numbering equals the one
    np.unique's first occurrences give: kept ids, then the others by first use, then the unused; int32."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        num = int(rng.integers(1, 40))
        ids = rng.integers(0, num, int(rng.integers(0, 120))).astype(rng.choice([np.int32, np.int64, np.uint32]))
        keep = int(rng.integers(0, num + 1))
        new, old = appearance_order(ids, num, keep)
        uniq, first = np.unique(ids, return_index=True)
        later = uniq[np.argsort(first)]
        later = later[later >= keep]
        expect = np.concatenate([np.arange(keep), later, np.setdiff1d(np.arange(keep, num), later)])
        assert old.dtype == new.dtype == np.int32
        np.testing.assert_array_equal(old, expect)
        np.testing.assert_array_equal(new[old], np.arange(num))


def test_ordered_refiner_reuses_its_face_varying_plan_only_for_the_same_channel():
    """OrderedRefiner keeps the fast path's analysis of the last channel (indices and mode): a second set of
    values, another mode or other indices give what a fresh OrderedRefiner gives, bit for bit."""
    pts, counts, idx, uv, uvi = torus(16, 12)
    refiner = ws.Refiner(ws.Mesh(pts, counts, idx), 2, device="cpu", precision="float64")
    kept = OrderedRefiner(refiner)
    other = uvi.copy()
    other[5] = len(uv)  # one corner with a value of its own: another seam
    uv2 = np.concatenate([uv, [[0.5, 0.5]]])
    for values, indices, mode in ((uv, uvi, "none"), (uv * 3 + 1, uvi, "none"), (uv, uvi, "boundaries"),
                                  (uv2, other, "boundaries"), (uv2[:, 0], other, "boundaries")):
        got = kept.evaluate_face_varying(values, indices, mode=mode)
        fresh = OrderedRefiner(refiner).evaluate_face_varying(values, indices, mode=mode)
        for a, b in zip(got, fresh):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


def _scene(path):
    from pxr import Sdf, Vt

    pts, counts, idx, uv, uvi = torus(20, 12)
    layer = Sdf.Layer.CreateNew(path)
    prim = Sdf.CreatePrimInLayer(layer, "/Torus")
    prim.specifier = Sdf.SpecifierDef
    prim.typeName = "Mesh"
    T = Sdf.ValueTypeNames
    Sdf.AttributeSpec(prim, "points", T.Point3fArray).default = Vt.Vec3fArray.FromNumpy(pts.astype(np.float32))
    Sdf.AttributeSpec(prim, "faceVertexCounts", T.IntArray).default = Vt.IntArray.FromNumpy(counts.astype(np.int32))
    Sdf.AttributeSpec(prim, "faceVertexIndices", T.IntArray).default = Vt.IntArray.FromNumpy(idx.astype(np.int32))
    st = Sdf.AttributeSpec(prim, "primvars:st", T.TexCoord2fArray)
    st.default = Vt.Vec2fArray.FromNumpy(uv.astype(np.float32))
    st.SetInfo("interpolation", "faceVarying")
    Sdf.AttributeSpec(prim, "primvars:st:indices", T.IntArray).default = Vt.IntArray.FromNumpy(uvi.astype(np.int32))
    pv = Sdf.AttributeSpec(prim, "primvars:w", T.FloatArray)
    pv.default = Vt.FloatArray.FromNumpy(pts[:, 0].astype(np.float32))
    pv.SetInfo("interpolation", "vertex")
    layer.Save()


def test_bake_in_compact_order_writes_the_same_surface(tmp_path):
    """refine_usd(vertex_order="compact") and "opensubdiv" write the same points, vertex primvar and UVs at
    every refined face corner, the same faces, and phase times; the CLI takes --vertex-order."""
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    from warp_subdiv.cli import main
    from warp_subdiv.usd.refine import refine_usd

    src = str(tmp_path / "torus.usda")
    _scene(src)
    got = {}
    for order in ("opensubdiv", "compact"):
        out = str(tmp_path / f"{order}.usdc")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = refine_usd(src, out, 2, device="cpu", vertex_order=order)
        assert set(result.phases) >= {"read", "analyse", "refine", "face-varying", "write"}
        stage = Usd.Stage.Open(out)
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Torus"))
        idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
        api = UsdGeom.PrimvarsAPI(mesh.GetPrim())
        got[order] = (np.array(mesh.GetPointsAttr().Get())[idx], np.array(api.GetPrimvar("w").Get())[idx],
                      np.array(api.GetPrimvar("st").ComputeFlattened()),
                      np.array(mesh.GetFaceVertexCountsAttr().Get()))
    for a, b in zip(got["opensubdiv"], got["compact"]):
        np.testing.assert_allclose(a, b, atol=1e-6)
    out = str(tmp_path / "cli.usdc")
    assert main(["refine", src, "-o", out, "--levels", "1", "--vertex-order", "compact", "--quiet"]) == 0
    assert os.path.exists(out)


def _baked(path):
    """{prim path: (points, faceVertexCounts, faceVertexIndices, primvar w, st values, st indices)} of the two
    tori of a baked layer."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path)
    out = {}
    for prim in ("/Torus", "/OsdTorus"):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(prim))
        api = UsdGeom.PrimvarsAPI(mesh.GetPrim())
        st = api.GetPrimvar("st")
        out[prim] = tuple(np.asarray(a) for a in (
            mesh.GetPointsAttr().Get(), mesh.GetFaceVertexCountsAttr().Get(), mesh.GetFaceVertexIndicesAttr().Get(),
            api.GetPrimvar("w").Get(), st.Get(), st.GetIndices()))
    return out


def test_default_bake_order_is_compact_for_piecewise_smooth_and_opensubdivs_for_its_rules(tmp_path):
    """The bake's default vertex order is "auto", in refine_usd and in the CLI: a mesh with the piecewise-smooth
    rules (subdiv:rules not authored) is written exactly as vertex_order="compact" writes it, a mesh with
    subdiv:rules = "opensubdiv" exactly as vertex_order="opensubdiv" writes it (points, faces, vertex and
    face-varying primvars, index for index); and the two orders really differ on each mesh, so the comparison
    tells them apart. `--vertex-order opensubdiv` gives OpenSubdiv's numbering to both."""
    pytest.importorskip("pxr")
    from pxr import Sdf

    from warp_subdiv.cli import main
    from warp_subdiv.usd.refine import refine_usd

    src = str(tmp_path / "tori.usda")
    _scene(src)
    layer = Sdf.Layer.FindOrOpen(src)
    assert Sdf.CopySpec(layer, "/Torus", layer, "/OsdTorus")
    rules = Sdf.AttributeSpec(layer.GetPrimAtPath("/OsdTorus"), "subdiv:rules", Sdf.ValueTypeNames.Token)
    rules.default = "opensubdiv"
    layer.Save()
    baked = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for order in (None, "compact", "opensubdiv"):
            out = str(tmp_path / f"{order or 'default'}.usda")
            refine_usd(src, out, 2, device="cpu", **({} if order is None else {"vertex_order": order}))
            baked[order] = _baked(out)
        for name, flags in (("cli", []), ("cli-opensubdiv", ["--vertex-order", "opensubdiv"])):
            out = str(tmp_path / f"{name}.usda")
            assert main(["refine", src, "-o", out, "--levels", "2", "--device", "cpu", "--quiet", *flags]) == 0
            baked[name] = _baked(out)

    def same(a, b):
        return len(a) == len(b) and all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b))

    for prim, expected, other in (("/Torus", "compact", "opensubdiv"), ("/OsdTorus", "opensubdiv", "compact")):
        assert not same(baked[expected][prim], baked[other][prim]), prim  # the orders differ
        assert same(baked[None][prim], baked[expected][prim]), prim
        assert same(baked["cli"][prim], baked[expected][prim]), prim
        assert same(baked["cli-opensubdiv"][prim], baked["opensubdiv"][prim]), prim
