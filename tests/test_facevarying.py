"""Face-varying channels (UVs) with OpenSubdiv's FVarLinearInterpolation modes."""
import os
import sys

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh
from warp_subdiv.options import FaceVaryingMode

FVAR_MODES = FaceVaryingMode.values()

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
try:
    from peers import osd_peer

    HAVE_PEER = osd_peer.available()
except Exception:  # noqa: BLE001 (the peer is optional: any failure to load it means it is absent)
    HAVE_PEER = False


def islands(mesh):
    """Every face its own UV island: seams on every edge."""
    return np.arange(len(mesh.face_vertex_indices))


def test_continuous_channel_equals_vertex_refinement():
    """Values indexed like the vertices, mode none (fully smooth): the channel refines like vertex data."""
    cube = load_mesh("cube")
    r = ws.Refiner(cube, 2, rules="opensubdiv", device="cpu", precision="float64")
    vals = np.random.default_rng(0).random((8, 2))
    fv, fi = r.evaluate_face_varying(vals, cube.face_vertex_indices, "none")
    _, vi = r.topology()
    np.testing.assert_allclose(fv[fi], r.evaluate(vals)[vi], atol=1e-12)


def test_mode_all_is_bilinear():
    cube = load_mesh("cube")
    idx = islands(cube)
    vals = np.random.default_rng(1).random((24, 2))
    r = ws.Refiner(cube, 1, device="cpu", precision="float64")
    fv, fi = r.evaluate_face_varying(vals, idx, "all")
    corners = fv[fi].reshape(-1, 4, 2)  # child quad j of face f: (vertex, edge j, centre, edge j-1)
    for f in range(6):
        v = vals[idx[4 * f:4 * f + 4]]
        for j in range(4):
            child = corners[4 * f + j]
            np.testing.assert_allclose(child[j], v[j], atol=1e-12)  # OpenSubdiv's rotation: vertex at j
            np.testing.assert_allclose(child[(j + 2) % 4], v.mean(axis=0), atol=1e-12)
            mids = {tuple(np.round((v[j] + v[(j + 1) % 4]) / 2, 12)), tuple(np.round((v[j] + v[j - 1]) / 2, 12))}
            got = {tuple(np.round(child[(j + 1) % 4], 12)), tuple(np.round(child[(j + 3) % 4], 12))}
            assert got == mids


def test_seam_keeps_two_sides():
    """A cube with one UV island per face keeps its seams: the two faces at an edge keep their own values."""
    cube = load_mesh("cube")
    idx = islands(cube)
    vals = np.random.default_rng(2).random((24, 2)) + np.repeat(np.arange(6), 4)[:, None] * 10  # islands apart
    r = ws.Refiner(cube, 3, device="cpu", precision="float64")
    fv, fi = r.evaluate_face_varying(vals, idx, "corners-plus1")
    counts, vi = r.topology()
    parent_face = np.repeat(np.arange(6), len(counts) // 6)  # children follow parent faces
    island = (fv[fi].reshape(-1, 4, 2)[:, :, 0] // 10).astype(int)
    assert np.all(island == parent_face[:, None])
    # a refined vertex on a seam has as many values as islands meeting there
    assert len(np.unique(fi)) > len(np.unique(vi))


def test_boundaries_mode_makes_island_boundaries_linear():
    """Mode boundaries: boundary values are interpolated (corners kept, edges linear); mode none smooths them."""
    grid = load_mesh("grid3x3")
    uv = grid.points[:, :2] / 3.0 + np.random.default_rng(3).normal(0, 0.02, (16, 2))
    r = ws.Refiner(grid, 2, device="cpu", precision="float64")
    fv, fi = r.evaluate_face_varying(uv, grid.face_vertex_indices, "boundaries")
    smooth, _ = r.evaluate_face_varying(uv, grid.face_vertex_indices, "none")
    ring = [0, 1, 2, 3, 7, 11, 15, 14, 13, 12, 8, 4]
    # every boundary value of the island stays, and the boundary is the polyline through them
    for v in ring:
        assert np.min(np.linalg.norm(fv - uv[v], axis=1)) < 1e-12
        assert np.min(np.linalg.norm(smooth - uv[v], axis=1)) > 1e-6 or v in (0, 3, 12, 15)
    a, b = uv[ring], uv[np.roll(ring, -1)]
    mids = (a + b) / 2
    for m in mids:
        assert np.min(np.linalg.norm(fv - m, axis=1)) < 1e-12


def test_face_varying_input_errors():
    cube = load_mesh("cube")
    r = ws.Refiner(cube, 1, device="cpu")
    with pytest.raises(ws.SubdivInputError, match="one entry per face corner"):
        r.evaluate_face_varying(np.zeros((4, 2)), np.zeros(5, dtype=int))
    with pytest.raises(ws.SubdivInputError, match="refer to value 23"):
        r.evaluate_face_varying(np.zeros((4, 2)), np.arange(24))
    with pytest.raises(ValueError, match="face-varying mode"):
        r.evaluate_face_varying(np.zeros((24, 2)), np.arange(24), "cornersPlus1")


def random_seams(mesh, rng, p=0.35):
    """Face-varying indices with random seams: each face corner keeps its vertex's value or gets its own."""
    idx = mesh.face_vertex_indices.astype(np.int64).copy()
    split = rng.random(len(idx)) < p
    idx[split] = mesh.num_vertices + np.arange(split.sum())
    return idx, mesh.num_vertices + int(split.sum())


@pytest.mark.skipif(not HAVE_PEER, reason="OpenSubdiv peer (libosd-dev) not available")
@pytest.mark.parametrize("mode", FVAR_MODES)
@pytest.mark.parametrize("name,scheme", [("cube", "catmull-clark"), ("grid3x3", "catmull-clark"),
                                         ("mixed_prism", "catmull-clark"), ("icosahedron", "loop"),
                                         ("tri_grid3x3", "loop"), ("cube_creased", "catmull-clark")])
def test_matches_opensubdiv(mode, name, scheme):
    rng = np.random.default_rng(abs(hash((mode, name))) % 2**32)
    mesh = load_mesh(name)
    for trial in range(3):
        idx, nvals = random_seams(mesh, rng) if trial else (islands(mesh), len(mesh.face_vertex_indices))
        vals = rng.random((nvals, 2))
        for level in (1, 2):
            r = ws.Refiner(mesh, level, scheme=scheme, rules="opensubdiv", device="cpu", precision="float64")
            fv, fi = r.evaluate_face_varying(vals, idx, mode)
            out = osd_peer.refine(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, level,
                                  scheme="catmark" if scheme == "catmull-clark" else "loop",
                                  creases=mesh.creases, crease_sharpness=mesh.crease_sharpness,
                                  corners=mesh.corners, corner_sharpness=mesh.corner_sharpness,
                                  fvar_linear=mode, fvar=(vals, idx))
            lv = out.levels[level]
            np.testing.assert_allclose(fv[fi], lv.fvar_values[lv.fvar_indices], atol=1e-9,
                                       err_msg=f"trial {trial} level {level}")


def test_limit_of_a_continuous_channel_equals_the_vertex_limit():
    """A channel indexed like the vertices (mode none) has the limit of vertex data."""
    cube = load_mesh("cube")
    r = ws.Refiner(cube, 2, rules="opensubdiv", device="cpu", precision="float64")
    vals = np.random.default_rng(5).random((8, 2))
    lv, li = r.limit_face_varying(vals, cube.face_vertex_indices, "none")
    _, vi = r.topology()
    refined = r.evaluate(np.column_stack([vals, np.zeros(8)]))
    expected = r.limit_points(refined)[:, :2]
    np.testing.assert_allclose(lv[li], expected[vi], atol=1e-12)


def test_limit_of_linear_and_island_channels():
    """Mode all: every value is a corner, so the limit values are the refined values; on islands with sharp
    corners the island corners keep their values in the limit."""
    cube = load_mesh("cube")
    r = ws.Refiner(cube, 2, device="cpu", precision="float64")
    vals = np.random.default_rng(6).random((24, 2))
    fv, fi = r.evaluate_face_varying(vals, islands(cube), "all")
    lv, li = r.limit_face_varying(vals, islands(cube), "all")
    np.testing.assert_allclose(lv[li], fv[fi], atol=1e-12)
    lv, li = r.limit_face_varying(vals, islands(cube), "corners-only")
    for v in vals:  # each island corner value survives
        assert np.min(np.linalg.norm(lv - v, axis=1)) < 1e-12


NUM_RANDOM_UV = 150


def random_uv_case(seed):
    """A random mesh of the differential tests (tags, semi-sharp, holes, Chaikin, boundary modes) with a random
    UV channel (random seams) and one of the six modes."""
    from test_osd_differential import random_case

    src, scheme, boundary, level, tri_sub = random_case(seed)
    rng = np.random.default_rng(10_000 + seed)
    mesh = ws.Mesh(src["points"], src["counts"], src["indices"])
    idx, nvals = random_seams(mesh, rng, p=float(rng.choice([0.0, 0.2, 0.5])))
    vals = rng.random((nvals, 2))
    return src, scheme, boundary, level, tri_sub, idx, vals, FVAR_MODES[seed % len(FVAR_MODES)]


@pytest.fixture(scope="module")
def random_uv_peer():
    from test_osd_differential import peer_request

    reqs = []
    for seed in range(NUM_RANDOM_UV):
        src, scheme, boundary, level, tri_sub, idx, vals, mode = random_uv_case(seed)
        channel = osd_peer.request(src["points"], src["counts"], src["indices"], level, fvar=(vals, idx),
                                   fvar_linear=mode)
        reqs.append({**peer_request(src, level, scheme, boundary, triangle_sub=tri_sub),
                     **{key: channel[key] for key in ("fvar_values", "fvar_indices", "fvar_linear")}})
    return dict(enumerate(osd_peer.refine_many(reqs)))


CHAIKIN_AT_SEAMS = (
    "Chaikin creasing of semi-sharp edges at a vertex where UV seams meet: OpenSubdiv decays the channel's "
    "crease sharpness with the vertex's own neighbourhood (all its semi-sharp edges), warp-subdiv with the value "
    "mesh's (the edges of that UV island only), so values near such vertices differ (about 1e-3 here)")


def random_uv_marks(seed):
    return [pytest.mark.xfail(strict=True, reason=CHAIKIN_AT_SEAMS)] if seed in (76, 139) else []


@pytest.mark.skipif(not HAVE_PEER, reason="OpenSubdiv peer (libosd-dev) not available")
@pytest.mark.parametrize("seed", [pytest.param(s, marks=random_uv_marks(s)) for s in range(NUM_RANDOM_UV)])
def test_random_meshes_with_uvs_match_opensubdiv(random_uv_peer, seed):
    import warnings

    from test_osd_differential import mesh_of

    src, scheme, boundary, level, tri_sub, idx, vals, mode = random_uv_case(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ws.NonManifoldWarning)
        r = ws.Refiner(mesh_of(src), level, scheme=scheme, rules="opensubdiv", boundary=boundary, device="cpu",
                       precision="float64", crease_method=src["creasing"], triangle_subdivision=tri_sub)
        fv, fi = r.evaluate_face_varying(vals, idx, mode)
    peer = random_uv_peer[seed].levels[level]
    keep = ~np.asarray(peer.face_holes, dtype=bool)
    n = int(np.asarray(peer.face_counts)[0]) if len(peer.face_counts) else 3
    expected = peer.fvar_values[np.asarray(peer.fvar_indices).reshape(-1, n)[keep].reshape(-1)]
    np.testing.assert_allclose(fv[fi], expected, atol=1e-9, err_msg=f"seed {seed}: {scheme} {boundary} L{level} {mode}")


def _bits(a):
    a = np.ascontiguousarray(a)
    return a.view(np.uint32 if a.dtype == np.float32 else np.uint64)


@pytest.fixture
def every_island_apart(monkeypatch):
    """Refine every island apart, however few share a vertex order (small test meshes have few)."""
    from warp_subdiv.tables import facevarying

    monkeypatch.setattr(facevarying, "MIN_ISLANDS", 1)


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("min_islands, put_runs, run_entries", [(1, 1024, 0), (4, 1024, 0), (1, 0, 0),
                                                               (1, 1024, 1024)])
def test_islands_refined_apart_equal_the_whole_value_mesh_bit_for_bit(seed, min_islands, put_runs, run_entries,
                                                                       monkeypatch):
    """Faces that are UV islands of their own (per-corner values) refine apart from the rest of the value mesh
    (one small refiner per face size and vertex order): on random open grids of quads, triangles or mixed
    polygons, with shared-value regions, creases (one on an island), a hole and a semi-sharp corner, every
    mode, both precisions, levels 1-3: the same bits at every refined corner as the whole value mesh's refiner
    gives. ``min_islands`` 4: the islands of rarer vertex orders refine with the rest. ``put_runs`` 0: the
    islands' refined indices and value order are scattered, not written run by run; ``run_entries`` 0: written run
    by run however short the runs (1024, the default: short runs scattered)."""
    from warp_subdiv.tables import facevarying

    monkeypatch.setattr(facevarying, "MIN_ISLANDS", min_islands)
    monkeypatch.setattr(facevarying, "PUT_RUNS", put_runs)
    monkeypatch.setattr(facevarying, "PUT_RUN_ENTRIES", run_entries)
    rng = np.random.default_rng(seed)
    nx, ny = 6, 5
    x, y = np.meshgrid(np.arange(nx + 1, dtype=float), np.arange(ny + 1, dtype=float))
    pts = np.stack([x.ravel(), y.ravel(), 0.3 * rng.standard_normal(x.size)], axis=1)
    v = lambda i, j: j * (nx + 1) + i  # noqa: E731
    faces = []
    for j in range(ny):
        for i in range(nx):
            a, b, c, d = v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)
            shape = rng.integers(3) if seed % 3 == 2 else seed % 3
            if shape == 1:
                faces += [[a, b, c], [a, c, d]]
            else:
                quad = [a, b, c, d]
                k = int(rng.integers(4))  # any starting corner: islands in several vertex orders
                faces.append(quad[k:] + quad[:k])
    counts = np.array([len(f) for f in faces])
    indices = np.concatenate(faces)
    # shared values (one per vertex) on some faces, values of their own on the others
    own = rng.random(len(faces)) < 0.6
    corner_face = np.repeat(np.arange(len(faces)), counts)
    idx = np.where(own[corner_face], len(pts) + np.arange(len(indices)), indices)
    uv = rng.random((len(pts) + len(indices), 2))
    mesh = ws.Mesh(pts, counts, indices, creases=[[v(1, 1), v(2, 1)], [v(3, 3), v(3, 4)]],
                   crease_sharpness=[10.0, 2.5], corners=[v(2, 2)], corner_sharpness=[1.5],
                   holes=[int(rng.integers(len(faces)))])
    scheme = "loop" if seed % 3 == 1 or seed == 8 else "catmull-clark"  # (seed 8: Loop on mixed polygons)
    r = ws.Refiner(mesh, 1 + seed % 3, scheme=scheme, device="cpu", precision=("float32", "float64")[seed % 2],
                   boundary=("edge-and-corner", "edge-only", "none")[seed % 3])
    for mode in FVAR_MODES:
        channel = r.face_varying_channel(idx, mode)
        values, at = channel.evaluate(uv)
        whole = channel.refiner  # the whole value mesh's refiner
        expected = whole.evaluate(uv[channel.source], normal_control=False)[whole.topology()[1]]
        assert values.dtype == expected.dtype
        np.testing.assert_array_equal(_bits(values[at]), _bits(expected))
        if mode != "none":  # (where corners are smooth no face is an island)
            assert channel._islands is not None


def test_unindexed_uvs_refine_islands_apart(every_island_apart):
    """Per-corner UVs (every face an island) on a cube: no refiner of the whole value mesh is built, and the
    values are its values."""
    cube = load_mesh("cube")
    r = ws.Refiner(cube, 2, device="cpu")
    vals = np.random.default_rng(5).random((24, 2))
    channel = r.face_varying_channel(islands(cube), "corners-plus1")
    values, at = channel.evaluate(vals)
    assert channel._refiner is None and channel._islands.rest is None
    whole = channel.refiner
    np.testing.assert_array_equal(_bits(values[at]), _bits(whole.evaluate(vals[channel.source], normal_control=False)[
        whole.topology()[1]]))


def test_many_islands_evaluate_in_chunks_with_the_same_bits(monkeypatch):
    """Islands beyond ISLANDS_PER_EVALUATION per vertex order are evaluated in padded chunks: the same bits."""
    from warp_subdiv.tables import facevarying

    mesh = load_mesh("grid3x3")
    r = ws.Refiner(mesh, 2, device="cpu", precision="float64")
    vals = np.random.default_rng(6).random((len(mesh.face_vertex_indices), 3))
    full = r.face_varying_channel(islands(mesh), "corners-only").refiner  # the whole value mesh's refiner
    source = r.face_varying_channel(islands(mesh), "corners-only").source
    expected = full.evaluate(vals[source], normal_control=False)[full.topology()[1]]
    monkeypatch.setattr(facevarying, "ISLANDS_PER_EVALUATION", 2)
    monkeypatch.setattr(facevarying, "MIN_ISLANDS", 1)
    chunked = facevarying.FaceVaryingChannel(r, islands(mesh), "corners-only")
    assert max(v.shape[1] for _, v in chunked._islands.groups) > 2  # (some group is chunked)
    values, at = chunked.evaluate(vals)
    np.testing.assert_array_equal(_bits(values[at]), _bits(expected))


def test_rare_vertex_orders_refine_with_the_rest():
    """With the default MIN_ISLANDS a small mesh's few islands refine with the rest: no single-face refiner,
    the same bits as the whole value mesh's refiner."""
    cube = load_mesh("cube")
    r = ws.Refiner(cube, 2, device="cpu")
    vals = np.random.default_rng(7).random((24, 2))
    channel = r.face_varying_channel(islands(cube), "corners-plus1")
    values, at = channel.evaluate(vals)
    assert channel._islands.groups == [] and channel._islands.rest is not None
    whole = channel.refiner
    np.testing.assert_array_equal(_bits(values[at]), _bits(whole.evaluate(vals[channel.source], normal_control=False)[
        whole.topology()[1]]))
