"""API defects found by users, each pinned (face-varying data under Loop on polygons, option and input checks, duplicate tags).

Each test names its item of the issue. Comparisons with OpenSubdiv run through the C++ peer
(``peers/osd_peer.py``) and are skipped where it is not available.
"""
import os
import sys
import warnings

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh
from warp_subdiv import SubdivInputError
from warp_subdiv.options import FaceVaryingMode
from warp_subdiv.topology import triangulate

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
try:
    from peers import osd_peer

    HAVE_PEER = osd_peer.available()
except Exception:  # noqa: BLE001 (the peer is optional: any failure to load it means it is absent)
    HAVE_PEER = False

needs_peer = pytest.mark.skipif(not HAVE_PEER, reason="OpenSubdiv peer (libosd-dev) not available")

# two quads sharing edge (1, 4):  0 1 2 / 3 4 5
GRID_PTS = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], dtype=np.float64)
GRID_COUNTS = [4, 4]
GRID_IDX = [0, 1, 4, 3, 1, 2, 5, 4]


def grid(**tags):
    return ws.Mesh(GRID_PTS, GRID_COUNTS, GRID_IDX, **tags)


def build(mesh, levels=1, **kw):
    return ws.Refiner(mesh, levels, device="cpu", precision="float64", **kw)


def with_tags(mesh, **tags):
    return ws.Mesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, **tags)


# --------------------------------------------------------------------------------------------------------
# item 4: Loop on polygon meshes, face-varying data follows the refinement (of the fan triangles)

POLYGON_MESHES = ["cube", "grid3x3", "mixed_prism", "quad_lshape"]


@pytest.mark.parametrize("rules", ["opensubdiv", "piecewise-smooth"])
@pytest.mark.parametrize("boundary", ["edge-and-corner", "edge-only"])
def test_loop_polygon_channel_indexed_like_vertices_equals_vertex_refinement(rules, boundary):
    """Item 4: a quad (and polygon meshes) refined by Loop, UVs indexed like the vertices, mode none: the
    channel refines like vertex data (the value mesh is analysed on the fan triangles, as the vertices are)."""
    quad = ws.Mesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [4], [0, 1, 2, 3])
    for mesh in [quad] + [load_mesh(name) for name in POLYGON_MESHES]:
        r = build(mesh, 2, scheme="loop", rules="opensubdiv", boundary=boundary)
        vals = np.random.default_rng(0).random((mesh.num_vertices, 2))
        fv, fi = r.evaluate_face_varying(vals, mesh.face_vertex_indices, "none")
        _, vi = r.topology()
        np.testing.assert_allclose(fv[fi], r.evaluate(vals)[vi], atol=1e-12)
        assert len(fi) == len(vi)


def random_seams(mesh, rng, p=0.35):
    """Face-varying indices with random seams: each face corner keeps its vertex's value or gets its own."""
    idx = mesh.face_vertex_indices.astype(np.int64).copy()
    split = rng.random(len(idx)) < p
    idx[split] = mesh.num_vertices + np.arange(split.sum())
    return idx, mesh.num_vertices + int(split.sum())


@needs_peer
def test_loop_polygon_channels_match_opensubdiv_on_the_fan_triangles():
    """Item 4: OpenSubdiv's Loop refuses non-triangles; on the fan-triangulated mesh (vertex and face-varying
    indices alike) it gives what warp-subdiv gives for the polygon mesh, in every mode, with and without
    seams, tags and holes."""
    with pytest.raises(osd_peer.PeerError, match="non-triangular"):
        osd_peer.refine(GRID_PTS, GRID_COUNTS, GRID_IDX, 1, scheme="loop")
    rng = np.random.default_rng(15)
    cases, reqs = [], []
    for name in POLYGON_MESHES:
        base = load_mesh(name)
        holes = [1] if name in ("grid3x3", "quad_lshape") else None
        mesh = with_tags(base, creases=base.edges.edge_verts[:2], crease_sharpness=[10.0, 1.5], holes=holes)
        for mode in FaceVaryingMode.values():
            for trial in range(2):
                idx, nvals = random_seams(mesh, rng) if trial else (np.arange(len(mesh.face_vertex_indices)),
                                                                      len(mesh.face_vertex_indices))
                vals = rng.random((nvals, 2))
                tc, ti, parent = triangulate(mesh.face_vertex_counts, mesh.face_vertex_indices)
                _, tfv, _ = triangulate(mesh.face_vertex_counts, idx)
                tholes = np.flatnonzero(np.isin(parent, mesh.holes))
                cases.append((mesh, mode, idx, vals))
                reqs.append(osd_peer.request(mesh.points, tc, ti, 2, scheme="loop", creases=mesh.creases,
                                             crease_sharpness=mesh.crease_sharpness, holes=tholes,
                                             fvar=(vals, tfv), fvar_linear=mode))
    results = osd_peer.refine_many(reqs)
    worst = 0.0
    for (mesh, mode, idx, vals), out in zip(cases, results):
        r = build(mesh, 2, scheme="loop", rules="opensubdiv")
        fv, fi = r.evaluate_face_varying(vals, idx, mode)
        lv = out.levels[2]
        keep = ~np.asarray(lv.face_holes, dtype=bool)
        expected = lv.fvar_values[np.asarray(lv.fvar_indices).reshape(-1, 3)[keep].reshape(-1)]
        worst = max(worst, float(np.abs(fv[fi] - expected).max()))
    assert worst < 1e-9


@needs_peer
@pytest.mark.parametrize("name,scheme", [("grid3x3", "catmull-clark"), ("cube", "catmull-clark"),
                                         ("mixed_prism", "catmull-clark"), ("tri_grid3x3", "loop"),
                                         ("icosahedron", "loop")])
def test_disjoint_values_match_opensubdiv(name, scheme):
    """Item 4 (found with the fan triangles, where a polygon's first value spans several triangles): a value
    whose faces around its vertex are split by a seam or by its other values is "disjoint" in OpenSubdiv,
    hence sharp, and with corners-plus1/2 it makes the other value of a two-valued vertex sharp too; where
    the values around a vertex run A, B, A, B OpenSubdiv counts the second B as a value of its own."""
    mesh = load_mesh(name)
    rng = np.random.default_rng(4)
    cases, reqs = [], []
    for mode in FaceVaryingMode.values():
        for _ in range(3):  # up to two values per vertex, given to its faces at random
            idx = 2 * mesh.face_vertex_indices.astype(np.int64) + rng.integers(0, 2, len(mesh.face_vertex_indices))
            vals = rng.random((2 * mesh.num_vertices, 2))
            cases.append((mode, idx, vals))
            reqs.append(osd_peer.request(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, 2,
                                         scheme="catmark" if scheme == "catmull-clark" else "loop",
                                         fvar=(vals, idx), fvar_linear=mode))
    r = build(mesh, 2, scheme=scheme, rules="opensubdiv")
    for (mode, idx, vals), out in zip(cases, osd_peer.refine_many(reqs)):
        fv, fi = r.evaluate_face_varying(vals, idx, mode)
        lv = out.levels[2]
        np.testing.assert_allclose(fv[fi], lv.fvar_values[lv.fvar_indices], atol=1e-9, err_msg=mode)


# --------------------------------------------------------------------------------------------------------
# item 5: rules="opensubdiv" has Loop's original beta only


def test_opensubdiv_rules_refuse_warren_beta():
    """Item 5: OpenSubdiv has no Warren beta, so rules='opensubdiv' refuses loop_beta='warren' (as it refuses
    flatness) instead of silently departing from OpenSubdiv."""
    with pytest.raises(SubdivInputError, match="loop_beta") as info:
        ws.Options(rules="opensubdiv", loop_beta="warren")
    assert (info.value.option, info.value.value) == ("loop_beta", "warren")
    with pytest.raises(SubdivInputError, match="loop_beta"):
        build(load_mesh("icosahedron"), scheme="loop", rules="OpenSubdiv", loop_beta="Warren")
    assert ws.Options(rules="opensubdiv", loop_beta="loop").loop_beta == "loop"


def test_warren_refiner_face_varying_follows_opensubdiv():
    """Item 5: face-varying data follows OpenSubdiv's rules, so a piecewise-smooth Warren refiner still refines
    its channels (with Loop's beta), as a rules='opensubdiv' refiner does."""
    ico = load_mesh("icosahedron")
    vals = np.random.default_rng(3).random((ico.num_vertices, 2))
    warren = build(ico, 2, scheme="loop", loop_beta="warren")
    osd = build(ico, 2, scheme="loop", rules="opensubdiv")
    fv, fi = warren.evaluate_face_varying(vals, ico.face_vertex_indices, "none")
    gv, gi = osd.evaluate_face_varying(vals, ico.face_vertex_indices, "none")
    np.testing.assert_allclose(fv[fi], gv[gi], atol=1e-12)


# --------------------------------------------------------------------------------------------------------
# item 6: duplicate tags, the last one wins (OpenSubdiv, USD)


@pytest.mark.parametrize("rules", ["opensubdiv", "piecewise-smooth"])
def test_duplicate_tags_last_one_wins(rules):
    """Item 6: an edge tagged twice (either orientation) or a corner tagged twice takes the last sharpness,
    as OpenSubdiv and USD do, not the largest."""
    cube = load_mesh("cube")
    pts = cube.points

    def refined(**tags):
        return build(with_tags(cube, **tags), 2, rules=rules).refine().points

    for first, last in ((3.0, 1.0), (1.0, 3.0), (3.0, 0.0), (10.0, 2.0)):
        got = refined(creases=[[6, 7], [7, 6]], crease_sharpness=[first, last])
        np.testing.assert_allclose(got, refined(creases=[[6, 7]], crease_sharpness=[last]), atol=1e-12)
        got = refined(corners=[6, 6], corner_sharpness=[first, last])
        np.testing.assert_allclose(got, refined(corners=[6], corner_sharpness=[last]), atol=1e-12)
    assert len(pts) == 8


@needs_peer
def test_duplicate_tags_match_opensubdiv():
    """Item 6: duplicate crease and corner tags against OpenSubdiv itself (which keeps the last one)."""
    for scheme, name, (a, b) in (("catmull-clark", "cube", (6, 7)), ("loop", "octahedron", (0, 2))):
        mesh_of = load_mesh(name)
        for tags in (dict(creases=[[a, b], [b, a]], crease_sharpness=[3.0, 1.0]),
                     dict(creases=[[a, b], [a, b]], crease_sharpness=[1.0, 3.0]),
                     dict(corners=[a, a], corner_sharpness=[3.0, 1.0]),
                     dict(corners=[a, b, a], corner_sharpness=[1.0, 2.0, 3.0])):
            mesh = with_tags(mesh_of, **tags)
            ours = build(mesh, 2, scheme=scheme, rules="opensubdiv").refine().points
            peer = osd_peer.refine(mesh_of.points, mesh_of.face_vertex_counts, mesh_of.face_vertex_indices, 2,
                                   scheme="catmark" if scheme == "catmull-clark" else "loop", **tags)
            np.testing.assert_allclose(ours, peer.levels[2].points, atol=1e-12, err_msg=f"{scheme} {tags}")


# --------------------------------------------------------------------------------------------------------
# item 7: face-varying indices are checked before the channel cache


def test_face_varying_indices_checked_before_the_cache():
    """Item 7: a 2-D index array is refused whether or not a channel with the same bytes was built before."""
    r = build(grid(), 1)
    vals = np.random.default_rng(7).random((6, 2))
    idx = np.array(GRID_IDX)
    with pytest.raises(SubdivInputError, match="one entry per face corner") as fresh:
        r.evaluate_face_varying(vals, idx.reshape(2, 4), "none")
    assert fresh.value.option == "indices"
    r.evaluate_face_varying(vals, idx, "none")
    with pytest.raises(SubdivInputError, match="one entry per face corner"):
        r.evaluate_face_varying(vals, idx.reshape(2, 4), "none")
    with pytest.raises(SubdivInputError, match="one entry per face corner"):
        r.limit_face_varying(vals, idx.reshape(2, 4), "none")
    with pytest.raises(SubdivInputError, match="integers"):
        r.evaluate_face_varying(vals, idx.astype(np.float64) + 0.5, "none")
    # the same indices as int32 reuse the channel
    channel = r.face_varying_channel(idx, "none")
    assert r.face_varying_channel(idx.astype(np.int32), "none") is channel
    assert r.face_varying_channel(list(GRID_IDX), FaceVaryingMode.NONE) is channel


# --------------------------------------------------------------------------------------------------------
# item 9: input checks and messages


def test_sharpness_length_must_match_the_tags():
    """Item 9: a sharpness list must have one value per tag (a list of one value for no tags, or for two tags,
    is refused); a single number still applies to every tag."""
    with pytest.raises(SubdivInputError, match=r"crease_sharpness has 1 values for 0 tags") as info:
        grid(crease_sharpness=[1.0])
    assert info.value.option == "crease_sharpness"
    with pytest.raises(SubdivInputError, match=r"corner_sharpness has 1 values for 0 tags"):
        grid(corner_sharpness=[1.0])
    with pytest.raises(SubdivInputError, match=r"crease_sharpness has 1 values for 2 tags"):
        grid(creases=[[0, 1], [1, 2]], crease_sharpness=[2.0])
    m = grid(creases=[[0, 1], [1, 2]], crease_sharpness=2.0)
    np.testing.assert_array_equal(m.crease_sharpness, [2.0, 2.0])
    assert len(grid(corners=[0], corner_sharpness=[2.0]).corner_sharpness) == 1


@pytest.mark.parametrize("data", [[["a", "b", "c"]] * 6, np.zeros((6, 0)), np.zeros((6, 3), dtype=complex),
                                  np.full((6, 2), None)])
def test_evaluate_refuses_non_numeric_or_empty_data(data):
    """Item 9: strings, objects, complex numbers or zero-width data are refused with SubdivInputError, not
    numpy's errors."""
    r = build(grid(), 1)
    with pytest.raises(SubdivInputError, match="vertex data") as info:
        r.evaluate(data)
    assert info.value.element == "data"


@pytest.mark.parametrize("values", [[["a", "b"]] * 6, np.zeros((6, 0)), np.full((6, 2), np.nan), np.zeros((5, 2))])
def test_evaluate_face_varying_refuses_bad_values(values):
    """Item 9: face-varying values that are not real numbers, have no columns, are not finite or are too few
    are refused with SubdivInputError (element "data")."""
    r = build(grid(), 1)
    with pytest.raises(SubdivInputError, match="values") as info:
        r.evaluate_face_varying(values, GRID_IDX, "none")
    assert info.value.element == "data"


def test_limit_points_refuse_bad_points():
    """Item 9: limit points and normals refuse NaN points and points of the wrong shape."""
    r = build(grid(), 1)
    refined = r.refine()
    pts = refined.points.copy()
    pts[3, 1] = np.nan
    with pytest.raises(SubdivInputError, match=r"row 3 is not finite") as info:
        r.limit_points(pts)
    assert (info.value.element, info.value.index) == ("data", 3)
    with pytest.raises(SubdivInputError, match=r"row 3 is not finite"):
        r.limit_normals(pts)
    with pytest.raises(SubdivInputError, match="refined"):
        r.limit_points(pts[:-1])
    assert np.all(np.isfinite(refined.limit_points()))


@pytest.mark.parametrize("make,option,element,index", [
    (lambda: ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, 5, 1e20]), "face_vertex_indices", "face", 1),
    (lambda: ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, 5, -1e20]), "face_vertex_indices", "face", 1),
    (lambda: ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, 5, 10**20]), "face_vertex_indices", "face", 1),
    (lambda: ws.Mesh(GRID_PTS, GRID_COUNTS, np.array([0, 1, 4, 3, 1, 2, 5, 2**64 - 1], dtype=np.uint64)),
     "face_vertex_indices", "face", 1),
    (lambda: grid(corners=[0, 1e20]), "corners", "corner", 1),
    (lambda: grid(creases=[[0, 1], [1, 1e20]]), "creases", "crease", 1),
    (lambda: grid(concave=[[1e20, 1]]), "concave", "concave", 0),
    (lambda: grid(holes=[1e20]), "holes", "hole", 0),
    (lambda: grid(normals=([1e20], [[0, 0, 1]])), "normals", "vertex", 0),
])
def test_huge_index_reported_as_given(make, option, element, index):
    """Item 9: an index far out of range (1e20, 10**20, 2**64 - 1) is reported as the value given, not as
    what it wraps to in int64."""
    with pytest.raises(SubdivInputError) as info:
        make()
    exc = info.value
    assert "-9223372036854775808" not in str(exc) and "9223372036854775807" not in str(exc), str(exc)
    assert (exc.option, exc.element, exc.index) == (option, element, index), str(exc)
    assert float(exc.value) in (1e20, -1e20, 2.0**64 - 1), str(exc)
    assert str(exc.value) in str(exc)


def test_concave_tag_on_semi_sharp_corner_says_so():
    """Item 9: a concave tag needs an infinitely sharp corner with infinitely sharp creases; a semi-sharp one
    is refused with that reason (not "0 crease edges"), and the error names the tag."""
    lshape = load_mesh("quad_lshape")
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(10, 6\): corner 10 is semi-sharp \(sharpness "
                                               r"2\).*infinitely sharp") as info:
        build(with_tags(lshape, corners=[10], corner_sharpness=[2.0], concave=[[10, 6]]))
    assert (info.value.option, info.value.element, info.value.index) == ("concave", "concave", 0)
    g = load_mesh("grid3x3")  # interior vertex 5, creases to 6 and 9
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(5, 4\): the creases of corner 5 are semi-sharp "
                                               r"\(\(5, 6\) sharpness 2\).*infinitely sharp"):
        build(with_tags(g, creases=[[5, 6], [5, 9]], crease_sharpness=[2.0, 10.0], corners=[5], concave=[[5, 4]]))
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(5, 4\): corner 5 has 0 crease edges"):
        build(with_tags(g, corners=[5], concave=[[5, 4]]))
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(5, 4\): corner 5 has 1 crease edge\b"):
        build(with_tags(g, creases=[[5, 6]], corners=[5], concave=[[5, 4]]))
    build(with_tags(g, creases=[[5, 6], [5, 9]], corners=[5], concave=[[5, 4]]))  # infinitely sharp: accepted


@pytest.mark.parametrize("kw,option", [
    (dict(rules="bad"), "rules"), (dict(rules=None), "rules"), (dict(scheme="quad"), "scheme"),
    (dict(normal_strength=float("nan")), "normal_strength"), (dict(normal_strength="1"), "normal_strength"),
    (dict(boundary="all"), "boundary"), (dict(precision=64), "precision"), (dict(flatness=float("nan")), "flatness"),
    (dict(crease_method="bspline"), "crease_method"), (dict(triangle_subdivision=3), "triangle_subdivision"),
    (dict(triangulate="yes"), "triangulate"),
])
def test_bad_option_values_raise_subdiv_input_error(kw, option):
    """Item 9: every bad option value raises SubdivInputError naming the option."""
    with pytest.raises(SubdivInputError) as info:
        ws.Refiner(grid(), 1, device="cpu", **kw)
    assert info.value.option == option


@pytest.mark.parametrize("levels", [-1, 2.5, "2", True, None])
def test_bad_levels_raise_subdiv_input_error(levels):
    """Item 9: levels must be an integer >= 0."""
    with pytest.raises(SubdivInputError) as info:
        ws.Refiner(grid(), levels, device="cpu")
    assert info.value.option == "levels"


@pytest.mark.parametrize("mode", ["bad", None, 3, "corners_plus1"])
def test_bad_face_varying_mode_raises_subdiv_input_error(mode):
    """Item 9: a face-varying mode outside OpenSubdiv's six is refused with SubdivInputError (option "mode")."""
    r = build(grid(), 1)
    with pytest.raises(SubdivInputError) as info:
        r.evaluate_face_varying(np.zeros((6, 2)), GRID_IDX, mode)
    assert info.value.option == "mode"


def test_option_values_in_any_letter_case():
    """Item 9: scheme="LOOP" and rules="OpenSubdiv" are the same options as their lower-case values."""
    mesh = load_mesh("mixed_prism")
    a = ws.refine(mesh, 2, scheme="LOOP", rules="OpenSubdiv", boundary="Edge-Only", device="cpu")
    b = ws.refine(mesh, 2, scheme="loop", rules="opensubdiv", boundary="edge-only", device="cpu")
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.face_vertex_indices, b.face_vertex_indices)
    assert (a.scheme, a.rules) == ("loop", "opensubdiv")
    assert ws.Options(scheme="LOOP", rules="OpenSubdiv") == ws.Options(scheme="loop", rules="opensubdiv")
    r = build(mesh, 1, scheme="Catmull-Clark")
    fv, _ = r.evaluate_face_varying(np.zeros((mesh.num_vertices, 2)), mesh.face_vertex_indices, "Corners-Plus1")
    assert len(fv)


def test_max_memory_values():
    """Item 9: max_memory takes bytes or a size string as the CLI's --max-memory does ("512M", "1G"; "none" and
    None: no limit); negative numbers and other types are refused (SubdivInputError, option "max_memory")."""
    from warp_subdiv.runtime.estimate import MemoryGuardError

    cube = load_mesh("cube")
    assert ws.refine(cube, 1, device="cpu", max_memory="1G").num_faces == 24
    assert ws.refine(cube, 1, device="cpu", max_memory="none").num_faces == 24
    assert ws.refine(cube, 1, device="cpu", max_memory=None).num_faces == 24
    assert ws.refine(cube, 1, device="cpu", max_memory=2**30).num_faces == 24
    with pytest.raises(MemoryGuardError, match="more than max_memory 1.0 MiB"):
        ws.refine(cube, 1, device="cpu", max_memory="1M")
    for bad in (-1, -1.5, "-1G", "lots", float("nan"), True, [1]):
        with pytest.raises(SubdivInputError) as info:
            ws.refine(cube, 1, device="cpu", max_memory=bad)
        assert not isinstance(info.value, MemoryGuardError), bad
        assert info.value.option == "max_memory", bad


def test_no_warning_for_valid_input():
    """The fixes add no warnings to valid input."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build(with_tags(load_mesh("cube"), creases=[[6, 7]], crease_sharpness=[1.0]), 1).refine()
