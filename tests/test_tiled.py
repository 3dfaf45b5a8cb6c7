"""Tiled refinement (warp_subdiv.refine_tiled): the tiles gathered by their global ids are refine()'s result
bitwise (points, faces, limit points and normals), whatever the tile size, on the test meshes and on seeded
random tagged meshes large enough that small tiles have halos well inside the mesh; every refined face is in
exactly one tile and a border vertex has the same bits in every tile that uses it; tiles sized by max_memory
stay under their prediction and are spatially coherent."""
import glob
import os
import warnings

import numpy as np
import pytest

from conftest import DATA, MESHES
import warp_subdiv as ws
from warp_subdiv.errors import NonManifoldWarning
from warp_subdiv.io.obj import read_obj
from warp_subdiv.tiled import Tile, _Plan, _tile_bytes, refine_tiled, resident_bytes

TEST_MESHES = sorted(glob.glob(os.path.join(MESHES, "*.obj")) + glob.glob(os.path.join(DATA, "opensubdiv-shapes",
                                                                                        "*.obj")))


def gather(mesh, levels, tile_faces=None, limits=False, **options):
    """refine() and the gathered tiles: asserts that every face is in one tile, that border vertices agree
    bitwise between tiles, and that tiles' topology is refine()'s; returns (reference, points, limit points,
    limit normals, covered vertices, tiles)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        ref = ws.refine(mesh, levels, device="cpu", **options)
        tiles = list(refine_tiled(mesh, levels, tile_faces=tile_faces, device="cpu", limit_points=limits,
                                  limit_normals=limits, **options))
    n = len(ref.points)
    points = np.zeros_like(ref.points)
    lp, ln = np.zeros_like(ref.points), np.zeros_like(ref.points)
    covered = np.zeros(n, bool)
    face_seen = np.zeros(len(ref.face_vertex_counts), int)
    starts = np.concatenate([[0], np.cumsum(ref.face_vertex_counts)])
    for tile in tiles:
        assert isinstance(tile, Tile)
        ids = tile.vertex_ids
        assert np.all(np.diff(ids) > 0), "tile vertices sorted by id, once each"
        again = covered[ids]
        assert np.array_equal(points[ids][again].view(np.uint8), tile.points[again].view(np.uint8)), \
            "a border vertex has other bits in another tile"
        points[ids], covered[ids] = tile.points, True
        if limits:
            lp[ids], ln[ids] = tile.limit_points, tile.limit_normals
        face_seen[tile.face_ids] += 1
        assert np.array_equal(tile.face_vertex_counts, ref.face_vertex_counts[tile.face_ids])
        corners = np.concatenate([np.arange(starts[f], starts[f + 1]) for f in tile.face_ids]) \
            if len(tile.face_ids) else np.zeros(0, int)
        assert np.array_equal(ids[tile.face_vertex_indices], ref.face_vertex_indices[corners])
    assert np.all(face_seen == 1), "every refined face in exactly one tile"
    uses = np.bincount(np.concatenate([t.vertex_ids for t in tiles]), minlength=n)
    for tile in tiles:
        assert np.array_equal(tile.border, uses[tile.vertex_ids] > 1), "border: the vertices other tiles use"
    assert np.array_equal(covered, np.isin(np.arange(n), ref.face_vertex_indices)), "tiles hold the used vertices"
    return ref, points, lp, ln, covered, tiles


def assert_bitwise(ref, points, covered):
    assert points.dtype == ref.points.dtype
    assert np.array_equal(points[covered].view(np.uint8), ref.points[covered].view(np.uint8))


def noisy_torus(nu, nv, rng, triangles=0.0, tags=True, sheet=False):
    """A noisy torus (or with ``sheet`` an open, twisted grid) of nu x nv quads, a fraction ``triangles`` of
    them split; with ``tags`` random crease tags (infinitely and semi-sharp), corners and holes."""
    u, v = np.meshgrid(np.arange(nu + sheet), np.arange(nv + sheet), indexing="ij")
    if sheet:
        pts = np.stack([u, v, 0.3 * np.sin(u + v)], -1).reshape(-1, 3).astype(float)
    else:
        a, b = 2 * np.pi * u / nu, 2 * np.pi * v / nv
        pts = np.stack([(3 + np.cos(b)) * np.cos(a), (3 + np.cos(b)) * np.sin(a), np.sin(b)], -1).reshape(-1, 3)
    pts = pts + rng.normal(scale=0.05, size=pts.shape)
    cols = nv + sheet
    faces = []
    for i in range(nu):
        for j in range(nv):
            i1, j1 = (i + 1) if sheet else (i + 1) % nu, (j + 1) if sheet else (j + 1) % nv
            q = [i * cols + j, i1 * cols + j, i1 * cols + j1, i * cols + j1]
            faces += [q[:3], [q[0], q[2], q[3]]] if rng.random() < triangles else [q]
    counts = np.array([len(f) for f in faces])
    indices = np.concatenate(faces)
    kw = {}
    if tags:
        nxt = np.concatenate([f[1:] + f[:1] for f in faces])
        edges = np.unique(np.sort(np.stack([indices, nxt], 1), 1), axis=0)
        tagged = rng.random(len(edges)) < 0.15
        kw["creases"] = edges[tagged]
        kw["crease_sharpness"] = np.where(rng.random(int(tagged.sum())) < 0.5, 10.0,
                                          rng.integers(4, 50, int(tagged.sum())) / 16)
        kw["corners"] = np.flatnonzero(rng.random(len(pts)) < 0.05)
        kw["corner_sharpness"] = rng.integers(4, 200, len(kw["corners"])) / 16
        kw["holes"] = np.flatnonzero(rng.random(len(faces)) < 0.05)
    return ws.Mesh(pts, counts, indices, **kw)


@pytest.mark.parametrize("path", TEST_MESHES, ids=os.path.basename)
@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_test_meshes_bitwise(path, scheme, rules):
    """Every test mesh, both schemes and rule sets, one face per tile at level 1, three at level 2 (level 3:
    the random tagged meshes below and the rule variants, where it costs less)."""
    data = read_obj(path)
    options = {k: v for k, v in data.options.items() if k in ("boundary", "crease_method")}
    for levels, tile_faces in ((1, 1), (2, 3)):
        ref, points, *_, covered, _ = gather(data.mesh, levels, tile_faces, scheme=scheme, rules=rules, **options)
        assert_bitwise(ref, points, covered)


CASES = [  # (seed, scheme, rules, triangles, boundary, sheet)
    (0, "catmull-clark", "piecewise-smooth", 0.0, "edge-and-corner", False),
    (1, "catmull-clark", "opensubdiv", 0.2, "edge-only", True),
    (2, "catmull-clark", "piecewise-smooth", 0.2, "none", True),
    (3, "loop", "piecewise-smooth", 1.0, "edge-and-corner", False),
    (4, "loop", "opensubdiv", 0.0, "edge-only", True),
    (5, "loop", "piecewise-smooth", 0.5, "none", True),
    (6, "catmull-clark", "opensubdiv", 1.0, "edge-and-corner", False),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"seed{c[0]}-{c[1]}-{c[2]}")
def test_random_tagged_meshes_bitwise(case):
    """Noisy tagged tori and open sheets (creases, semi-sharp tags, corners, holes, mixed polygons), levels 1-3,
    tiles of 1, 5 and 40 faces: the halos lie inside the mesh, where only the halo makes tiles right."""
    seed, scheme, rules, triangles, boundary, sheet = case
    rng = np.random.default_rng(seed)
    mesh = noisy_torus(8, 6, rng, triangles=triangles, sheet=sheet)
    crease_method = "chaikin" if seed % 2 else "uniform"
    for levels, tile_faces in ((1, 1), (2, 5), (3, 40)):
        ref, points, *_, covered, tiles = gather(mesh, levels, tile_faces, scheme=scheme, rules=rules,
                                                 boundary=boundary, crease_method=crease_method)
        assert_bitwise(ref, points, covered)
        assert len(tiles) > 1


@pytest.mark.parametrize("options", [{"scheme": "catmull-clark", "triangle_subdivision": "smooth"},
                                     {"scheme": "loop", "loop_beta": "warren"}], ids=["smooth-triangles", "warren"])
def test_rule_variants_bitwise(options):
    """OpenSubdiv's smooth triangle rule (weights that depend on the faces at an edge) and the paper's Warren
    beta, on a mixed tagged mesh."""
    mesh = noisy_torus(8, 6, np.random.default_rng(12), triangles=0.4)
    for levels, tile_faces in ((1, 1), (2, 6)):
        ref, points, *_, covered, _ = gather(mesh, levels, tile_faces, **options)
        assert_bitwise(ref, points, covered)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_projections_bitwise(scheme):
    """The paper's projections: explicit and per-vertex flatness at crease sectors, prescribed normals with
    normal control (at interior vertices); float64."""
    rng = np.random.default_rng(11)
    base = noisy_torus(8, 6, rng, triangles=0.3 if scheme == "loop" else 0.0)
    normal_ids = np.array([9, 20, 33])
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, creases=base.creases,
                   crease_sharpness=np.full(len(base.creases), 10.0), normals=(normal_ids, normals))
    flatness = np.where(rng.random(mesh.num_vertices) < 0.5, 0.7, np.nan)
    cases = (({"flatness": 0.5}, 2, 3), ({"flatness": flatness, "precision": "float64"}, 3, 20), ({}, 1, 1))
    for options, levels, tile_faces in cases:
        ref, points, *_, covered, _ = gather(mesh, levels, tile_faces, scheme=scheme, **options)
        assert_bitwise(ref, points, covered)


@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_limits_bitwise(scheme, rules):
    """Limit points and normals of every tile are refine()'s, with masks read one level deeper where the
    whole mesh's are (extraordinary crease sectors) though a tile's own would not be, and the other way round
    (a tile's cut-off halo has crease sectors the whole mesh does not)."""
    rng = np.random.default_rng(5)
    mesh = noisy_torus(8, 6, rng, triangles=0.4 if scheme == "loop" else 0.0)
    for levels, tile_faces in ((1, 2), (2, 7)):
        ref, points, lp, ln, covered, _ = gather(mesh, levels, tile_faces, limits=True, scheme=scheme, rules=rules)
        assert_bitwise(ref, points, covered)
        assert np.array_equal(lp[covered], ref.limit_points()[covered])
        assert np.array_equal(ln[covered], ref.limit_normals()[covered])


def test_level_zero_and_one_tile():
    """Level 0: the tiles are the control faces (Loop: the fan triangles); no tile size or memory limit: one tile,
    the whole mesh. A control vertex no face uses is in no tile (its row of refine() is its own point)."""
    mesh = noisy_torus(6, 4, np.random.default_rng(2), triangles=0.3)
    ref, points, *_, covered, tiles = gather(mesh, 0, 5)
    assert_bitwise(ref, points, covered)
    ref, points, *_, covered, tiles = gather(mesh, 0, 5, scheme="loop")
    assert_bitwise(ref, points, covered)
    spare = ws.Mesh(np.vstack([mesh.points, [[9.0, 9.0, 9.0]]]), mesh.face_vertex_counts, mesh.face_vertex_indices)
    ref, points, *_, covered, tiles = gather(spare, 2, 7)
    assert_bitwise(ref, points, covered)
    assert not covered[mesh.num_vertices]
    ref, points, *_, covered, tiles = gather(mesh, 2)
    assert len(tiles) == 1
    assert_bitwise(ref, points, covered)


def test_tiles_are_coherent():
    """Tiles along the Morton curve are compact: on a 16 x 16 sheet, tiles of 16 faces share fewer vertices
    with other tiles than rows of the grid would (32 border vertices per row of 16 faces, shared on both
    sides)."""
    mesh = noisy_torus(16, 16, np.random.default_rng(3), tags=False, sheet=True)
    tiles = list(refine_tiled(mesh, 1, tile_faces=16, device="cpu"))
    assert len(tiles) == 16
    uses = np.bincount(np.concatenate([t.vertex_ids for t in tiles]))
    shared = np.count_nonzero(uses > 1)
    assert shared < 0.75 * 15 * 33  # rows: 15 shared rows of 33 level-1 vertices


def test_max_memory_sizes_tiles():
    """max_memory: tiles are cut so that each one's prediction fits beside what the process holds; more memory,
    fewer tiles; too little for one face is refused, naming max_memory."""
    mesh = noisy_torus(16, 12, np.random.default_rng(4), tags=False)
    plan = _Plan(mesh, 3, ws.Options())
    whole = _tile_bytes(plan, np.arange(mesh.num_faces), 0, False, False)
    share = whole // 3
    tiles = list(refine_tiled(mesh, 3, max_memory=resident_bytes() + share, device="cpu"))
    assert len(tiles) > 3
    for tile in tiles:
        assert _tile_bytes(plan, tile.control_faces, 2, False, False) <= share
    fewer = list(refine_tiled(mesh, 3, max_memory=resident_bytes() + 2 * whole, device="cpu"))
    assert len(fewer) == 1
    with pytest.raises(ws.SubdivInputError) as err:
        list(refine_tiled(mesh, 3, max_memory=resident_bytes() // 2, device="cpu"))
    assert err.value.option == "max_memory"


@pytest.mark.parametrize("bad", [0, -1, 2.5, True])
def test_bad_tile_faces(bad):
    mesh = noisy_torus(4, 4, np.random.default_rng(0), tags=False)
    with pytest.raises(ws.SubdivInputError) as err:
        refine_tiled(mesh, 1, tile_faces=bad)
    assert err.value.option == "tile_faces"


def test_obj_tiles_stream(tmp_path):
    """write_obj_tiles: one OBJ of the tiles, every used vertex written once (border vertices too), the faces
    refine()'s faces in tile order, their points refine()'s."""
    from warp_subdiv.io.obj import write_obj_tiles

    mesh = noisy_torus(6, 5, np.random.default_rng(8))
    ref = ws.refine(mesh, 2, device="cpu")
    tiles = list(refine_tiled(mesh, 2, tile_faces=4, device="cpu"))
    path = str(tmp_path / "tiled.obj")
    vertices, faces = write_obj_tiles(path, iter(tiles))
    back = read_obj(path).mesh
    assert vertices == back.num_vertices == len(np.unique(ref.face_vertex_indices))
    order = np.concatenate([t.face_ids for t in tiles])
    assert faces == back.num_faces == len(order)
    starts = np.concatenate([[0], np.cumsum(ref.face_vertex_counts)])
    ref_corners = np.concatenate([np.arange(starts[f], starts[f + 1]) for f in order])
    assert np.array_equal(back.points[back.face_vertex_indices].astype(np.float32),
                          ref.points[ref.face_vertex_indices[ref_corners]])


def test_cli_obj_in_tiles(tmp_path, capsys, monkeypatch):
    """`refine --max-memory` with OBJ output whose refinement would not fit: written in tiles, the same faces
    and points as the in-core run. (The tiles are sized as if the process held only Warp's runtime, as the
    guard's model has it, so that a limit the guard refuses leaves room for tiles.)"""
    import re

    import warp_subdiv.tiled
    from warp_subdiv.cli import main
    from warp_subdiv.io.obj import write_obj

    mesh = noisy_torus(12, 10, np.random.default_rng(9), tags=False)
    src = str(tmp_path / "in.obj")
    write_obj(src, mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices)
    full, tiled = str(tmp_path / "full.obj"), str(tmp_path / "tiled.obj")
    assert main(["refine", src, "-o", full, "--levels", "3", "--device", "cpu", "--max-memory", "none"]) == 0
    plan = _Plan(mesh, 3, ws.Options())
    limit = 64 * 2**20 + _tile_bytes(plan, np.arange(mesh.num_faces), 0, False, False) // 3
    monkeypatch.setattr(warp_subdiv.tiled, "resident_bytes", lambda: 0)
    assert main(["refine", src, "-o", tiled, "--levels", "3", "--device", "cpu", "--max-memory", str(limit)]) == 0
    assert re.search(r"3 levels in [2-9]\d* tiles", capsys.readouterr().out)
    a, b = read_obj(full).mesh, read_obj(tiled).mesh
    assert a.num_faces == b.num_faces and b.num_vertices == a.num_vertices
    key = lambda m: np.sort(m.points[m.face_vertex_indices].reshape(m.num_faces, -1), axis=0)  # noqa: E731
    assert np.array_equal(key(a), key(b))


def test_ids_past_32_bits():
    """Ids are int64 where the refined mesh's counts pass 2^31 (level 15 of a cube: 6.4e9 faces; only the plan
    is made), int32 below; the counts per level follow the closed forms."""
    cube = read_obj(os.path.join(MESHES, "cube.obj")).mesh
    deep = _Plan(cube, 15, ws.Options())
    assert deep.id_dtype == np.int64 and deep.level_counts[-1][1] == 6 * 4**15
    assert deep.first_child[-1] == 5 * 4**15
    shallow = _Plan(cube, 3, ws.Options())
    assert shallow.id_dtype == np.int32
    ref = ws.refine(cube, 3, device="cpu")
    assert shallow.level_counts[-1][:2] == (len(ref.points), len(ref.face_vertex_counts))


def test_non_manifold_warns_once():
    """The whole mesh's analysis warns of non-manifold input once; the tiles' own analyses do not warn."""
    mesh = read_obj(os.path.join(DATA, "opensubdiv-shapes", "catmark_nonman_edges.obj")).mesh
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tiles = list(refine_tiled(mesh, 1, tile_faces=20, device="cpu"))
    assert len(tiles) > 1
    assert sum(issubclass(w.category, NonManifoldWarning) for w in caught) == 1


def test_cli_usd_in_tiles(tmp_path, capsys, monkeypatch):
    """`refine in.obj -o out.usda --max-memory` where the refinement would not fit: an Xform of tile meshes, one
    layer per tile loaded as a payload; gathered by their vertex ids the tiles are the in-core points, every face
    once; no validation error."""
    import re

    from test_usd_production import validation_errors

    import warp_subdiv.tiled
    from warp_subdiv.cli import main
    from warp_subdiv.io.obj import write_obj

    mesh = noisy_torus(10, 8, np.random.default_rng(10), tags=False)
    src = str(tmp_path / "in.obj")
    write_obj(src, mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices)
    plan = _Plan(mesh, 3, ws.Options())
    limit = 64 * 2**20 + _tile_bytes(plan, np.arange(mesh.num_faces), 0, False, False) // 3
    monkeypatch.setattr(warp_subdiv.tiled, "resident_bytes", lambda: 0)
    out = str(tmp_path / "out" / "tiled.usda")
    assert main(["refine", src, "-o", out, "--levels", "3", "--device", "cpu", "--max-memory", str(limit)]) == 0
    assert re.search(r"3 levels in [2-9]\d* tiles", capsys.readouterr().out)
    ref = ws.refine(read_obj(src).mesh, 3, device="cpu")
    points, faces = gather_tile_layer(out, len(ref.points))
    assert faces == len(ref.face_vertex_counts)
    assert np.array_equal(points, ref.points)
    assert not validation_errors(out)


def gather_tile_layer(path, num_vertices: int, each=None):
    """The tiles of a tiled layer (an Xform default prim of tile meshes, each with ``warpSubdiv:vertexIds``),
    gathered by vertex id: (points (float32, NaN where no tile has the vertex), faces in all). Asserts that there
    are several tiles and that a vertex in several tiles has the same bits in each; ``each(tile)``: more checks
    of every tile (a UsdGeom.Mesh, valid while the stage is open here)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    root = stage.GetDefaultPrim()
    assert root.GetTypeName() == "Xform"
    children = root.GetChildren()
    assert len(children) > 1
    points = np.full((num_vertices, 3), np.nan, np.float32)
    faces = 0
    for child in children:
        tile = UsdGeom.Mesh(child)
        ids = np.array(child.GetAttribute("warpSubdiv:vertexIds").Get())
        pts = np.array(tile.GetPointsAttr().Get())
        assert np.all(np.isnan(points[ids]) | (points[ids] == pts))
        points[ids] = pts
        faces += len(tile.GetFaceVertexCountsAttr().Get())
        if each is not None:
            each(tile)
    return points, faces


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("mode", ["corners-plus1", "boundaries", "all"])
def test_face_varying_bitwise(scheme, mode):
    """A face-varying channel with seams (values split at random vertices): each tile's values and indices,
    gathered by value id, are Refiner.evaluate_face_varying's bitwise."""
    rng = np.random.default_rng(13)
    mesh = noisy_torus(8, 6, rng, triangles=0.3)
    # a value per (vertex, face) pair at a random third of the vertices, one per vertex elsewhere
    corners = mesh.face_vertex_indices.astype(np.int64)
    split = rng.random(mesh.num_vertices) < 0.3
    keys = np.where(split[corners], mesh.num_vertices + np.arange(len(corners)), corners)
    _, indices = np.unique(keys, return_inverse=True)
    values = rng.random((int(indices.max()) + 1, 2))
    for levels, tile_faces in ((1, 1), (2, 5)):
        refiner = ws.Refiner(mesh, levels, scheme=scheme, device="cpu")
        ref_values, ref_indices = refiner.evaluate_face_varying(values, indices, mode)
        ref = refiner.refine()
        starts = np.concatenate([[0], np.cumsum(ref.face_vertex_counts)])
        gathered = np.full(ref_values.shape, np.nan)
        for tile in refine_tiled(mesh, levels, tile_faces=tile_faces, scheme=scheme, device="cpu",
                                 face_varying=(values, indices, mode)):
            fv = tile.face_varying
            if not len(tile.face_ids):  # a tile of hole faces
                continue
            known = ~np.isnan(gathered[fv.value_ids, 0])
            assert np.array_equal(gathered[fv.value_ids][known], fv.values[known])
            gathered[fv.value_ids] = fv.values
            corners_of_tile = np.concatenate([np.arange(starts[f], starts[f + 1]) for f in tile.face_ids])
            assert np.array_equal(fv.value_ids[fv.indices], ref_indices[corners_of_tile])
        used = np.isin(np.arange(len(ref_values)), ref_indices)
        assert np.array_equal(gathered[used].astype(ref_values.dtype).view(np.uint8), ref_values[used].view(np.uint8))


def test_several_face_varying_channels_in_one_pass():
    """A list of channels: each tile carries a list of TileFaceVarying in that order, each equal to the tile of
    the same channel asked for alone (the tiles are the same)."""
    rng = np.random.default_rng(5)
    mesh = noisy_torus(6, 5, rng, triangles=0.3)
    n = len(mesh.face_vertex_indices)
    channels = [(rng.random((n, 2)), np.arange(n), "corners-plus1"),
                (rng.random((mesh.num_vertices, 1)), mesh.face_vertex_indices, "all")]
    both = list(refine_tiled(mesh, 2, tile_faces=4, device="cpu", face_varying=channels))
    for k, channel in enumerate(channels):
        alone = list(refine_tiled(mesh, 2, tile_faces=4, device="cpu", face_varying=channel))
        assert len(alone) == len(both)
        for a, b in zip(alone, both):
            assert isinstance(b.face_varying, list) and len(b.face_varying) == 2
            got = b.face_varying[k]
            assert np.array_equal(a.face_varying.values, got.values)
            assert np.array_equal(a.face_varying.indices, got.indices)
            assert np.array_equal(a.face_varying.value_ids, got.value_ids)


@pytest.mark.parametrize("scheme,rules,limit", [("catmull-clark", "piecewise-smooth", False),
                                                ("catmull-clark", "opensubdiv", True),
                                                ("loop", "piecewise-smooth", True)])
def test_vertex_data_and_face_parents_bitwise(scheme, rules, limit):
    """Vertex data (an (n,) and an (n, 3) array) refined beside the points: each tile's rows, gathered by vertex
    id, are Refiner.evaluate's with normal_control=False bitwise, and their limit values Refiner.limit_points'
    (normal_control=False); each tile face's face_parent is FaceMap.parent's for its id (a mixed mesh: Loop
    faces come from the polygons' fans)."""
    from warp_subdiv.tables import FaceMap

    rng = np.random.default_rng(21)
    mesh = noisy_torus(8, 6, rng, triangles=0.3)
    data = [rng.random(mesh.num_vertices), rng.random((mesh.num_vertices, 3))]
    for levels, tile_faces in ((1, 1), (2, 5)):
        refiner = ws.Refiner(mesh, levels, scheme=scheme, rules=rules, device="cpu")
        expected = [refiner.evaluate(a.reshape(len(a), -1), normal_control=False) for a in data]
        expected_limit = [refiner.limit_points(e, normal_control=False) for e in expected]
        parent = FaceMap(mesh, levels, scheme, refiner.options.boundary.value, hierarchy=refiner.hierarchy).parent
        gathered = [np.full(e.shape, np.nan, e.dtype) for e in expected]
        gathered_limit = [np.full(e.shape, np.nan, e.dtype) for e in expected]
        faces = 0
        for tile in refine_tiled(mesh, levels, tile_faces=tile_faces, scheme=scheme, rules=rules, device="cpu",
                                 vertex_data=data, limit_points=limit):
            assert np.array_equal(tile.face_parent, parent[tile.face_ids])
            faces += tile.num_faces
            for k in range(len(data)):
                gathered[k][tile.vertex_ids] = tile.vertex_data[k]
                if limit:
                    gathered_limit[k][tile.vertex_ids] = tile.limit_vertex_data[k]
            assert (tile.limit_vertex_data is not None) == limit
        assert faces == len(parent)
        used = np.isin(np.arange(len(expected[0])), refiner.refine().face_vertex_indices)
        for k in range(len(data)):
            assert np.array_equal(gathered[k][used].view(np.uint8), expected[k][used].view(np.uint8))
            if limit:
                assert np.array_equal(gathered_limit[k][used].view(np.uint8), expected_limit[k][used].view(np.uint8))


def test_vertex_data_is_checked():
    """vertex_data that is not a list of per-vertex arrays is refused, naming it."""
    mesh = noisy_torus(4, 4, np.random.default_rng(0), tags=False)
    with pytest.raises(ws.SubdivInputError, match="vertex_data must be a list"):
        next(refine_tiled(mesh, 1, vertex_data=np.zeros(mesh.num_vertices)))
    with pytest.raises(ws.SubdivInputError, match=r"vertex_data\[0\]"):
        next(refine_tiled(mesh, 1, vertex_data=[np.zeros(mesh.num_vertices + 1)]))


def _grid_stage(path, n=16):
    """A stage with an n x n Catmull-Clark grid (transformed, bound to a material, a constant displayColor and
    a face-varying st) and a small quad that fits any budget."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    material = UsdShade.Material.Define(stage, "/World/Looks/Mat")
    u, v = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    rng = np.random.default_rng(3)
    points = np.stack([u.ravel(), v.ravel(), rng.normal(0, 0.2, u.size)], 1).astype(np.float32)
    quads = np.array([[j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i]
                      for j in range(n) for i in range(n)])
    grid = UsdGeom.Mesh.Define(stage, "/World/Grid")
    grid.CreatePointsAttr(points)
    grid.CreateFaceVertexCountsAttr([4] * len(quads))
    grid.CreateFaceVertexIndicesAttr(quads.ravel().tolist())
    grid.CreateSubdivisionSchemeAttr("catmullClark")
    grid.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(points))
    grid.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    grid.CreatePurposeAttr(UsdGeom.Tokens.render)
    grid.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(0.2, 0.4, 0.6)])
    st = UsdGeom.PrimvarsAPI(grid).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying)
    st.Set(points[quads.ravel(), :2] / n)
    UsdShade.MaterialBindingAPI.Apply(grid.GetPrim()).Bind(material)
    small = UsdGeom.Mesh.Define(stage, "/World/Small")
    small.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    small.CreateFaceVertexCountsAttr([4])
    small.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    small.CreateExtentAttr([(0, 0, 0), (1, 1, 0)])
    stage.Save()
    return grid.GetPrim(), points, quads


def test_usd_bake_in_tiles(tmp_path, monkeypatch):
    """A USD mesh that does not fit max_memory is baked in tiles: the mesh deactivated, a sibling Xform of tile
    meshes with its transform, binding and constant primvars; gathered by their vertex ids the tiles are
    refine()'s points and face-varying values bitwise, every face once; the mesh that fits is refined as
    always; no validation error."""
    from test_usd_production import validation_errors

    import warp_subdiv.tiled
    from pxr import Usd, UsdGeom, UsdShade
    from warp_subdiv.usd import refine_usd

    src, out = str(tmp_path / "in.usda"), str(tmp_path / "out.usda")
    _, points, quads = _grid_stage(src)
    mesh = ws.Mesh(points, np.full(len(quads), 4), quads.ravel())
    monkeypatch.setattr(warp_subdiv.tiled, "resident_bytes", lambda: 0)
    plan = _Plan(mesh, 3, ws.Options())
    limit = ws.runtime.estimate.RUNTIME_BYTES + _tile_bytes(plan, np.arange(mesh.num_faces), 0, True, False, 3) // 3
    result = refine_usd(src, out, 3, device="cpu", max_memory=limit, normals=True, resume=False)
    assert any("refined in tiles" in w for w in result.warnings)
    ref = ws.refine(mesh, 3, device="cpu")
    stage = Usd.Stage.Open(out)
    assert not stage.GetPrimAtPath("/World/Grid").IsActive()
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/World/Small")).GetSubdivisionSchemeAttr().Get() == "none"
    assert not stage.GetPrimAtPath("/World/Small_tiles")  # it fits: refined as always
    root = stage.GetPrimAtPath("/World/Grid_tiles")
    assert root.GetTypeName() == "Xform"
    assert UsdGeom.Xformable(root).GetLocalTransformation().ExtractTranslation() == (1, 2, 3)
    got = np.full(ref.points.shape, np.nan, np.float32)
    st_values, st_indices = ws.Refiner(mesh, 3, device="cpu").evaluate_face_varying(
        (points[quads.ravel(), :2] / 16).astype(np.float64), np.arange(quads.size), "corners-plus1")
    ref_uv = np.asarray(st_values, np.float32)[st_indices]
    uv = np.full(ref_uv.shape, np.nan, np.float32)
    faces = 0
    tiles = root.GetChildren()
    assert len(tiles) > 1
    for child in tiles:
        tile = UsdGeom.Mesh(child)
        assert tile.GetSubdivisionSchemeAttr().Get() == "none"
        assert UsdGeom.Imageable(child).ComputePurpose() == UsdGeom.Tokens.render
        assert UsdShade.MaterialBindingAPI(child).ComputeBoundMaterial()[0].GetPath() == "/World/Looks/Mat"
        assert tuple(tile.GetDisplayColorPrimvar().Get()[0]) == pytest.approx((0.2, 0.4, 0.6))
        assert len(tile.GetNormalsAttr().Get()) == len(tile.GetPointsAttr().Get())
        ids = np.array(child.GetAttribute("warpSubdiv:vertexIds").Get())
        pts = np.array(tile.GetPointsAttr().Get())
        assert np.all(np.isnan(got[ids]) | (got[ids] == pts))
        got[ids] = pts
        st = UsdGeom.PrimvarsAPI(child).GetPrimvar("st")
        face_ids = np.array(child.GetAttribute("warpSubdiv:faceIds").Get())
        corners = (face_ids[:, None] * 4 + np.arange(4)).ravel()  # quads: corner k of face f is row 4f + k
        uv[corners] = np.array(st.Get())[np.array(st.GetIndices())]
        faces += len(tile.GetFaceVertexCountsAttr().Get())
    assert faces == len(ref.face_vertex_counts)
    assert np.array_equal(got, ref.points)
    assert np.array_equal(uv, ref_uv)
    assert not validation_errors(out)


def _add_per_vertex_and_per_face_data(src):
    """Give the grid of :func:`_grid_stage` a vertex primvar, a uniform one, an indexed uniform one and a
    partition of its faces into two material subsets bound to two materials."""
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(src)
    grid = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Grid"))
    n_points = len(grid.GetPointsAttr().Get())
    n_faces = len(grid.GetFaceVertexCountsAttr().Get())
    rng = np.random.default_rng(8)
    pv = UsdGeom.PrimvarsAPI(grid)
    pv.CreatePrimvar("height", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        rng.random(n_points).astype(np.float32))
    pv.CreatePrimvar("tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.uniform).Set(
        rng.random((n_faces, 3)).astype(np.float32))
    kind = pv.CreatePrimvar("kind", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform)
    kind.Set([10, 20, 30])
    kind.SetIndices(rng.integers(0, 3, n_faces).tolist())
    left = np.flatnonzero(np.arange(n_faces) % 16 < 8)
    right = np.setdiff1d(np.arange(n_faces), left)
    for name, ids in (("left", left), ("right", right)):
        material = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        subset = UsdShade.MaterialBindingAPI(grid.GetPrim()).CreateMaterialBindSubset(name, ids.tolist())
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)
    UsdShade.MaterialBindingAPI(grid.GetPrim()).SetMaterialBindSubsetsFamilyType(UsdGeom.Tokens.partition)
    stage.Save()


@pytest.mark.parametrize("limit", [False, True])
def test_usd_bake_in_tiles_carries_primvars_and_subsets(tmp_path, monkeypatch, limit):
    """Vertex, uniform (plain and indexed) primvars and material subsets of a mesh baked in tiles: on each tile,
    the values and faces the in-core bake (OpenSubdiv's vertex order) gives the same vertex and face ids, bitwise;
    each tile face bound to the material its control face's subset binds; the subset family kept; no
    validation error."""
    from test_usd_production import validation_errors

    import warp_subdiv.tiled
    from pxr import Usd, UsdGeom, UsdShade
    from warp_subdiv.usd import refine_usd

    src = str(tmp_path / "in.usda")
    _, points, quads = _grid_stage(src)
    _add_per_vertex_and_per_face_data(src)
    mesh = ws.Mesh(points, np.full(len(quads), 4), quads.ravel())
    monkeypatch.setattr(warp_subdiv.tiled, "resident_bytes", lambda: 0)
    budget = ws.runtime.estimate.RUNTIME_BYTES + _tile_bytes(_Plan(mesh, 2, ws.Options()), np.arange(mesh.num_faces),
                                                             0, True, False, 4) // 3
    common = dict(device="cpu", limit=limit, normals=True, resume=False, vertex_order="opensubdiv")
    refine_usd(src, str(tmp_path / "whole.usda"), 2, **common)
    result = refine_usd(src, str(tmp_path / "tiled.usda"), 2, max_memory=budget, **common)
    assert any("refined in tiles" in w for w in result.warnings)
    whole = Usd.Stage.Open(str(tmp_path / "whole.usda"))
    ref = UsdGeom.Mesh(whole.GetPrimAtPath("/World/Grid"))
    ref_pv = UsdGeom.PrimvarsAPI(ref)
    ref_face_material = {}
    for subset in UsdShade.MaterialBindingAPI(ref.GetPrim()).GetMaterialBindSubsets():
        material = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0].GetPath()
        ref_face_material.update({int(f): material for f in subset.GetIndicesAttr().Get()})
    stage = Usd.Stage.Open(str(tmp_path / "tiled.usda"))
    tiles = stage.GetPrimAtPath("/World/Grid_tiles").GetChildren()
    assert len(tiles) > 1
    seen = 0
    for child in tiles:
        tile = UsdGeom.Mesh(child)
        vids = np.array(child.GetAttribute("warpSubdiv:vertexIds").Get())
        fids = np.array(child.GetAttribute("warpSubdiv:faceIds").Get())
        pv = UsdGeom.PrimvarsAPI(tile)
        assert np.array_equal(np.array(pv.GetPrimvar("height").Get()), np.array(ref_pv.GetPrimvar("height").Get())[vids])
        assert pv.GetPrimvar("height").GetInterpolation() == "vertex"
        assert np.array_equal(np.array(pv.GetPrimvar("tint").Get()), np.array(ref_pv.GetPrimvar("tint").Get())[fids])
        kind, ref_kind = pv.GetPrimvar("kind"), ref_pv.GetPrimvar("kind")
        assert np.array_equal(np.array(kind.ComputeFlattened()), np.array(ref_kind.ComputeFlattened())[fids])
        assert kind.IsIndexed()
        binding = UsdShade.MaterialBindingAPI(child)
        assert binding.GetMaterialBindSubsetsFamilyType() == UsdGeom.Tokens.partition
        subsets = binding.GetMaterialBindSubsets()
        assert subsets
        for subset in subsets:
            material = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0].GetPath()
            for f in subset.GetIndicesAttr().Get():
                assert ref_face_material[int(fids[f])] == material
                seen += 1
    assert seen == len(ref_face_material) == len(ref.GetFaceVertexCountsAttr().Get())
    assert not validation_errors(str(tmp_path / "tiled.usda"))


@pytest.mark.parametrize("what", ["time samples", "varying primvars", "edge GeomSubsets"])
def test_usd_bake_refuses_what_tiles_cannot_write(tmp_path, what):
    """A mesh that must be tiled but has what tiles do not carry (time samples, a varying primvar, an edge
    subset) is refused, naming the prim and saying it is refined in tiles; nothing is written."""
    from pxr import Sdf, Usd, UsdGeom
    from warp_subdiv.runtime.estimate import RUNTIME_BYTES
    from warp_subdiv.usd import refine_usd

    src = str(tmp_path / "in.usda")
    prim, points, _ = _grid_stage(src)
    stage = Usd.Stage.Open(src)
    grid = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Grid"))
    if what == "time samples":
        grid.GetPointsAttr().Set(points, 1.0)
    elif what == "varying primvars":
        UsdGeom.PrimvarsAPI(grid).CreatePrimvar("w", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.varying).Set(
            np.zeros(len(points), np.float32))
    else:
        UsdGeom.Subset.CreateGeomSubset(grid, "seam", "edge", [0, 1, 1, 2])
    stage.Save()
    with pytest.raises(ws.SubdivInputError, match=f"/World/Grid.*in tiles.*{what}"):
        refine_usd(src, str(tmp_path / "out.usda"), 3, device="cpu", max_memory=RUNTIME_BYTES + 1, resume=False)
    assert sorted(os.listdir(tmp_path)) == ["in.usda"]  # nothing written


def test_cli_usd_bake_in_tiles(tmp_path, capsys, monkeypatch):
    """`warp-subdiv refine in.usda -o out.usda --max-memory` where a mesh does not fit: it is written in tiles,
    the command says so and succeeds."""
    import warp_subdiv.tiled
    from pxr import Usd
    from warp_subdiv.cli import main

    src, out = str(tmp_path / "in.usda"), str(tmp_path / "out.usda")
    _, points, quads = _grid_stage(src)
    mesh = ws.Mesh(points, np.full(len(quads), 4), quads.ravel())
    monkeypatch.setattr(warp_subdiv.tiled, "resident_bytes", lambda: 0)
    limit = ws.runtime.estimate.RUNTIME_BYTES + _tile_bytes(_Plan(mesh, 3, ws.Options()), np.arange(mesh.num_faces),
                                                            0, True, False, 3) // 3
    assert main(["refine", src, "-o", out, "--levels", "3", "--device", "cpu", "--normals",
                 "--max-memory", str(limit)]) == 0
    printed = capsys.readouterr()
    assert "refined in tiles" in printed.out + printed.err, printed
    stage = Usd.Stage.Open(out)
    assert len(stage.GetPrimAtPath("/World/Grid_tiles").GetChildren()) > 1
    assert not stage.GetPrimAtPath("/World/Grid").IsActive()


def test_usd_tile_folders_are_per_mesh_and_reruns_leave_no_stale_tiles(tmp_path, monkeypatch):
    """Meshes whose paths flatten alike (/A_B/C, /A/B_C) get tile folders of their own; a rerun that writes
    fewer tiles removes the tile layers it no longer references."""
    import warp_subdiv.tiled
    from warp_subdiv.usd import refine_usd
    from warp_subdiv.usd.tiles import tile_folder_name

    assert tile_folder_name("/A_B/C") != tile_folder_name("/A/B_C")
    assert tile_folder_name("/World/Grid").startswith("World_Grid_")
    src, out = str(tmp_path / "in.usda"), str(tmp_path / "out.usda")
    _, points, quads = _grid_stage(src)
    mesh = ws.Mesh(points, np.full(len(quads), 4), quads.ravel())
    monkeypatch.setattr(warp_subdiv.tiled, "resident_bytes", lambda: 0)
    whole = _tile_bytes(_Plan(mesh, 3, ws.Options()), np.arange(mesh.num_faces), 0, True, False, 3)
    folder = os.path.join(str(tmp_path / "out_tiles"), tile_folder_name("/World/Grid"))
    counts = []
    for share in (6, 3):  # (more tiles, then fewer)
        refine_usd(src, out, 3, device="cpu", max_memory=ws.runtime.estimate.RUNTIME_BYTES + whole // share,
                   normals=True, resume=False)
        counts.append(sorted(os.listdir(folder)))
    assert len(counts[1]) < len(counts[0])
    assert counts[1] == [f"tile_{k:04d}.usdc" for k in range(len(counts[1]))]  # nothing stale left
