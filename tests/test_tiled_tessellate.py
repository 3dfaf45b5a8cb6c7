"""Tiled tessellation (warp_subdiv.tessellate_tiled): the tiles gathered by their global ids are the in-core
tessellation (LimitSurface.tessellate) bitwise (points, normals, faces), with uniform and edge-length rates, tiles
of one and of a few faces, on test meshes (quads with extraordinary vertices, mixed polygons, Loop triangles and
polygons, creases and corners, boundaries, holes); border vertices have the same bits in every tile; the command
line writes OBJ (shared vertices once) and USD (tile prims, valid) in tiles where the tessellation would not fit
--max-memory, and names a bad --max-memory."""
import os
import warnings

import numpy as np
import pytest

from conftest import MESHES
from test_tiled import gather_tile_layer, noisy_torus
import warp_subdiv as ws
from warp_subdiv.errors import NonManifoldWarning, SubdivInputError
from warp_subdiv.io.obj import read_obj
from warp_subdiv.tiled_tessellation import _Numbering, _SurfacePlan, _tile_bytes, tessellation_fits

#: Local refinement levels of the tests' surfaces (the default, 8, costs more; the halo does not depend on it).
DEPTH = 4


def gather(mesh, tile_faces, depth=DEPTH, **kw):
    """The in-core tessellation and the gathered tiles: asserts that every output face is in one tile with the
    in-core topology, that border vertices agree bitwise between tiles and are the vertices other tiles use, and
    that the tiles hold every vertex; returns (in-core, gathered points, gathered normals, tiles)."""
    rates = {k: kw.pop(k) for k in ("rate", "edge_length", "quads") if k in kw}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        t = ws.LimitSurface(mesh, depth=depth, device="cpu", **kw).tessellate(**rates)
        tiles = list(ws.tessellate_tiled(mesh, tile_faces=tile_faces, depth=depth, device="cpu", **rates, **kw))
    n = t.num_vertices
    points, normals = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    covered = np.zeros(n, bool)
    face_seen = np.zeros(t.num_faces, int)
    starts = np.concatenate([[0], np.cumsum(t.face_vertex_counts)])
    for tile in tiles:
        ids = tile.vertex_ids
        assert np.all(np.diff(ids) > 0), "tile vertices sorted by id, once each"
        again = covered[ids]
        assert np.array_equal(points[ids][again].view(np.uint8), tile.points[again].view(np.uint8)), \
            "a border vertex has other bits in another tile"
        points[ids], normals[ids], covered[ids] = tile.points, tile.limit_normals, True
        face_seen[tile.face_ids] += 1
        assert np.all(np.diff(tile.face_ids) > 0)
        assert np.array_equal(tile.face_vertex_counts, t.face_vertex_counts[tile.face_ids])
        corners = np.concatenate([np.arange(starts[f], starts[f + 1]) for f in tile.face_ids])
        assert np.array_equal(ids[tile.face_vertex_indices], t.face_vertex_indices[corners])
    assert np.all(face_seen == 1), "every output face in exactly one tile"
    assert covered.all(), "the tiles hold every vertex"
    uses = np.bincount(np.concatenate([tile.vertex_ids for tile in tiles]), minlength=n)
    for tile in tiles:
        assert np.array_equal(tile.border, uses[tile.vertex_ids] > 1), "border: the vertices other tiles use"
    return t, points, normals, tiles


def assert_bitwise(t, points, normals):
    assert np.array_equal(points.view(np.uint8), t.points.view(np.uint8))
    assert np.array_equal(normals.view(np.uint8), t.normals.view(np.uint8))


def _obj(name):
    data = read_obj(os.path.join(MESHES, name))
    return data.mesh, {k: v for k, v in data.options.items() if k in ("boundary", "crease_method")}


CASES = {  # name: (mesh factory, options, tile sizes)
    "cube": (lambda: _obj("cube.obj"), {"scheme": "catmull-clark"}, (1, 3)),
    "cube-creased": (lambda: _obj("cube_creased.obj"), {"scheme": "catmull-clark"}, (1, 3)),
    "mixed-prism": (lambda: _obj("mixed_prism.obj"), {"scheme": "catmull-clark"}, (1, 3)),
    "quad-lshape": (lambda: _obj("quad_lshape.obj"), {"scheme": "catmull-clark"}, (1, 2)),
    "icosahedron-loop": (lambda: _obj("icosahedron.obj"), {"scheme": "loop"}, (1, 4)),
    "tri-hexfan-loop": (lambda: _obj("tri_hexfan.obj"), {"scheme": "loop"}, (1, 2)),
    "torus-tagged": (lambda: (noisy_torus(8, 6, np.random.default_rng(0)), {}),
                     {"scheme": "catmull-clark", "rules": "piecewise-smooth"}, (2, 9)),
    "sheet-mixed-opensubdiv": (lambda: (noisy_torus(7, 5, np.random.default_rng(1), triangles=0.2, sheet=True), {}),
                               {"scheme": "catmull-clark", "rules": "opensubdiv", "boundary": "edge-only"}, (2, 9)),
    "torus-loop": (lambda: (noisy_torus(6, 5, np.random.default_rng(3), triangles=1.0), {}),
                   {"scheme": "loop", "rules": "piecewise-smooth"}, (3, 11)),
    "sheet-loop-polygons-none": (lambda: (noisy_torus(7, 5, np.random.default_rng(5), triangles=0.5, sheet=True), {}),
                                 {"scheme": "loop", "rules": "piecewise-smooth", "boundary": "none"}, (2, 9)),
}


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("rates", [{"rate": 3}, {"edge_length": 0.4}], ids=["rate", "edge-length"])
def test_tiles_are_the_in_core_tessellation_bitwise(name, rates):
    make, options, sizes = CASES[name]
    mesh, file_options = make()
    for tile_faces in sizes:
        t, points, normals, tiles = gather(mesh, tile_faces, **rates, **{**file_options, **options})
        assert len(tiles) > 1
        assert_bitwise(t, points, normals)


def test_triangles_per_face_rates_and_default_depth():
    """quads=False, one rate per face (an edge gets the larger of its faces'), and the default depth of the
    surface (8): still bitwise."""
    mesh, _ = _obj("cube.obj")
    t, points, normals, _ = gather(mesh, 2, depth=8, rate=np.arange(1, 7), quads=False)
    assert_bitwise(t, points, normals)
    assert np.all(t.face_vertex_counts == 3)


def test_linear_surface_and_rates_per_edge():
    """A linear (bilinear) surface, and rates given per edge as a dict: still bitwise."""
    mesh, _ = _obj("mixed_prism.obj")
    t, points, normals, _ = gather(mesh, 2, rate=3, linear=True)
    assert_bitwise(t, points, normals)
    t, points, normals, _ = gather(mesh, 2, rate={"edges": np.arange(mesh.num_edges) % 4 + 1})
    assert_bitwise(t, points, normals)


def test_one_tile_when_it_fits_and_ids_match():
    """Without tile_faces a mesh that fits is one tile: the in-core tessellation itself."""
    mesh, _ = _obj("mixed_prism.obj")
    t, points, normals, tiles = gather(mesh, None, rate=4)
    assert len(tiles) == 1 and not tiles[0].border.any()
    assert_bitwise(t, points, normals)


def test_max_memory_sizes_tiles(monkeypatch):
    """A max_memory below the whole tessellation's prediction gives several tiles, each predicted under it."""
    import warp_subdiv.tiled_tessellation as tt

    monkeypatch.setattr(tt, "resident_bytes", lambda: 0)
    mesh = noisy_torus(10, 8, np.random.default_rng(4), tags=False)
    plan = _SurfacePlan(mesh, ws.Options())
    numbering = _Numbering(plan, *tt.segment_rates(type("M", (), {"mesh": mesh})(), 6, None), True)
    whole = _tile_bytes(plan, numbering, np.arange(mesh.num_faces), 0, DEPTH)
    limit = 64 * 2**20 + tt.GLOBAL_BYTES_PER_CORNER * int(plan.counts.sum()) + whole // 2
    tiles = list(ws.tessellate_tiled(mesh, rate=6, max_memory=limit, depth=DEPTH, device="cpu"))
    assert len(tiles) > 1
    rings = (tt.HALO_RINGS_PROJECTING if plan.projects else tt.HALO_RINGS) + 1
    for tile in tiles:
        assert _tile_bytes(plan, numbering, tile.control_faces, rings, DEPTH) <= limit - 64 * 2**20
    fits, need = tessellation_fits(mesh, rate=6, max_memory=limit, depth=DEPTH)
    assert not fits and need == whole


def test_ids_past_32_bits():
    """Ids are int64 where the tessellation's counts pass 2^31 (182 x 182 quads at rate 256: 2.2e9 faces; only
    the numbering is made), int32 below; the counts are the in-core ones."""
    n = 182
    u, v = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    pts = np.stack([u, v, 0 * u], -1).reshape(-1, 3)
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)).reshape(-1)
    mesh = ws.Mesh(pts, np.full(n * n, 4), np.stack([q, q + n + 1, q + n + 2, q + 1], 1).reshape(-1))
    plan = _SurfacePlan(mesh, ws.Options())
    deep = _Numbering(plan, np.full(mesh.num_edges, 256), np.full(n * n, 256), True)
    assert deep.id_dtype == np.int64 and deep.num_faces == n * n * 256**2
    assert deep.num_vertices == (n * 256 + 1)**2
    last = deep.vertex_ids(np.array([deep.num_vertices + deep.dropped - 1]))
    assert last.dtype == np.int64 and last[0] == deep.num_vertices - 1
    shallow = _Numbering(plan, np.full(mesh.num_edges, 3), np.full(n * n, 3), True)
    t = ws.LimitSurface(mesh, device="cpu").tessellate(rate=3)
    assert shallow.id_dtype == np.int32 and (shallow.num_vertices, shallow.num_faces) == (t.num_vertices, t.num_faces)


@pytest.mark.parametrize("bad", [{"tile_faces": 0}, {"tile_faces": 1.5}, {"depth": 0}, {"rate": 0},
                                 {"rate": 2, "edge_length": 1.0}, {"edge_length": -1.0}])
def test_bad_arguments(bad):
    mesh, _ = _obj("cube.obj")
    kw = {"rate": 2, **bad} if "rate" not in bad and "edge_length" not in bad else bad
    with pytest.raises(SubdivInputError):
        list(ws.tessellate_tiled(mesh, device="cpu", **kw))


def test_non_manifold_mesh_is_refused():
    from conftest import DATA

    mesh = read_obj(os.path.join(DATA, "opensubdiv-shapes", "catmark_nonman_edges.obj")).mesh
    with pytest.raises(SubdivInputError, match="manifold"):
        list(ws.tessellate_tiled(mesh, rate=2, tile_faces=10, device="cpu"))


def _cli_limit(mesh, rate):
    """A --max-memory under the in-core prediction (the tiles are sized as if the process held only Warp's
    runtime)."""
    plan = _SurfacePlan(mesh, ws.Options())
    numbering = _Numbering(plan, np.full(mesh.num_edges, rate), np.full(mesh.num_faces, rate), True)
    return 64 * 2**20 + _tile_bytes(plan, numbering, np.arange(mesh.num_faces), 0, 8) // 3


def _write_source(tmp_path, seed):
    from warp_subdiv.io.obj import write_obj

    mesh = noisy_torus(8, 6, np.random.default_rng(seed), tags=False)
    src = str(tmp_path / "in.obj")
    write_obj(src, mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices)
    return read_obj(src).mesh, src


def test_cli_obj_in_tiles(tmp_path, capsys, monkeypatch):
    """`tessellate --max-memory` with OBJ output whose tessellation would not fit: one OBJ file written in tiles,
    every vertex once, the in-core file's faces and points (after renumbering: compared as sorted rows of
    their corners' coordinates)."""
    import re

    import warp_subdiv.tiled_tessellation as tt
    from warp_subdiv.cli import main

    mesh, src = _write_source(tmp_path, 9)
    full, tiled = str(tmp_path / "full.obj"), str(tmp_path / "tiled.obj")
    assert main(["tessellate", src, "-o", full, "--rate", "5", "--device", "cpu", "--quiet"]) == 0
    monkeypatch.setattr(tt, "resident_bytes", lambda: 0)
    limit = _cli_limit(mesh, 5)
    assert main(["tessellate", src, "-o", tiled, "--rate", "5", "--device", "cpu", "--max-memory", str(limit)]) == 0
    assert re.search(r"in [2-9]\d* tiles \(the whole tessellation would not fit --max-memory\)",
                     capsys.readouterr().out)
    a, b = read_obj(full).mesh, read_obj(tiled).mesh
    assert a.num_faces == b.num_faces and a.num_vertices == b.num_vertices
    key = lambda m: np.sort(m.points[m.face_vertex_indices].reshape(m.num_faces, -1), axis=0)  # noqa: E731
    assert np.array_equal(key(a), key(b))


def test_cli_usd_in_tiles(tmp_path, capsys, monkeypatch):
    """`tessellate in.obj -o out.usda --max-memory` where the tessellation would not fit: an Xform of tile meshes
    (one layer each, their normals), gathered by their ids the in-core points (as float32), every face once; no
    validation error."""
    from test_usd_production import validation_errors

    import warp_subdiv.tiled_tessellation as tt
    from warp_subdiv.cli import main

    mesh, src = _write_source(tmp_path, 10)
    monkeypatch.setattr(tt, "resident_bytes", lambda: 0)
    out = str(tmp_path / "out" / "tiled.usda")
    assert main(["tessellate", src, "-o", out, "--rate", "4", "--device", "cpu", "--max-memory",
                 str(_cli_limit(mesh, 4))]) == 0
    assert "tiles (the whole tessellation would not fit" in capsys.readouterr().out
    t = ws.LimitSurface(mesh, device="cpu").tessellate(rate=4)
    def normals_per_point(tile):
        assert len(tile.GetNormalsAttr().Get()) == len(tile.GetPointsAttr().Get())

    points, faces = gather_tile_layer(out, len(t.points), each=normals_per_point)
    assert faces == t.num_faces
    assert np.array_equal(points, t.points.astype(np.float32))
    assert not validation_errors(out)


def test_cli_bad_max_memory_is_named(tmp_path, capsys):
    from warp_subdiv.cli import main

    src = os.path.join(MESHES, "cube.obj")
    code = main(["tessellate", src, "-o", str(tmp_path / "o.obj"), "--rate", "2", "--max-memory", "lots"])
    assert code != 0
    assert "--max-memory" in capsys.readouterr().err


def _usd_stage(path, meshes, uv=None):
    """A stage of plain meshes ({name: Mesh}) under /World; ``uv``: a face-varying primvar on the first."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    for i, (name, mesh) in enumerate(meshes.items()):
        prim = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        prim.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(mesh.points, np.float32)))
        prim.GetFaceVertexCountsAttr().Set(np.asarray(mesh.face_vertex_counts).tolist())
        prim.GetFaceVertexIndicesAttr().Set(np.asarray(mesh.face_vertex_indices).tolist())
        prim.GetSubdivisionSchemeAttr().Set("catmullClark")
        prim.AddTranslateOp().Set((3.0 * i, 0.0, 0.0))
        if uv and i == 0:
            pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                         UsdGeom.Tokens.faceVarying)
            pv.Set(Vt.Vec2fArray.FromNumpy(np.zeros((len(mesh.face_vertex_indices), 2), np.float32)))
    stage.Save()


def test_usd_mesh_in_tiles(tmp_path, monkeypatch):
    """USD input: a mesh whose tessellation would not fit max_memory is tessellated in tiles (deactivated, a
    sibling Xform of tile meshes with its transform, points gathered by id the in-core tessellation's), the mesh
    that fits in core as before; the output is valid."""
    from test_usd_production import validation_errors

    import warp_subdiv.tiled_tessellation as tt
    from pxr import Usd, UsdGeom
    from warp_subdiv.usd.tessellate import tessellate_file

    monkeypatch.setattr(tt, "resident_bytes", lambda: 0)
    torus = noisy_torus(8, 6, np.random.default_rng(11), tags=False)
    small = noisy_torus(3, 3, np.random.default_rng(12), tags=False)
    src, out = str(tmp_path / "in.usda"), str(tmp_path / "out.usda")
    _usd_stage(src, {"Torus": torus, "Small": small})
    torus32 = ws.Mesh(np.asarray(torus.points, np.float32).astype(np.float64), torus.face_vertex_counts,
                      torus.face_vertex_indices)
    result = tessellate_file(src, out, rate=4, max_memory=_cli_limit(torus32, 4), device="cpu")
    by_path = {r.path: r for r in result.reports}
    assert by_path["/World/Torus"].tiles > 1 and by_path["/World/Small"].tiles == 0
    assert any("tessellated in tiles" in w for w in result.warnings)
    stage = Usd.Stage.Open(out)
    assert not stage.GetPrimAtPath("/World/Torus").IsActive()
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/World/Small")).GetSubdivisionSchemeAttr().Get() == "none"
    tiles = stage.GetPrimAtPath("/World/Torus_tiles")
    assert tiles.GetTypeName() == "Xform" and len(tiles.GetChildren()) == by_path["/World/Torus"].tiles
    t = ws.LimitSurface(torus32, device="cpu").tessellate(rate=4)
    points = np.full(t.points.shape, np.nan, np.float32)
    for child in tiles.GetChildren():
        ids = np.array(child.GetAttribute("warpSubdiv:vertexIds").Get())
        points[ids] = np.array(UsdGeom.Mesh(child).GetPointsAttr().Get())
    assert np.array_equal(points, t.points.astype(np.float32))
    assert not validation_errors(out)


def test_usd_mesh_that_tiles_cannot_write_is_refused_by_name(tmp_path, monkeypatch):
    """A mesh that must be tiled but has a face-varying primvar (tiles carry points, faces and normals) is
    refused, naming the prim."""
    import warp_subdiv.tiled_tessellation as tt
    from warp_subdiv.usd.tessellate import tessellate_file

    monkeypatch.setattr(tt, "resident_bytes", lambda: 0)
    mesh, _ = _obj("cube.obj")
    path = str(tmp_path / "in.usda")
    _usd_stage(path, {"Cube": mesh}, uv=True)
    with pytest.raises(SubdivInputError, match="/World/Cube.*face-varying primvars"):
        tessellate_file(path, str(tmp_path / "out.usda"), rate=64, max_memory=1000, device="cpu")
