"""LimitSurface.tessellate and ``warp-subdiv tessellate`` (README "Limit surface").

Watertightness with random per-edge and per-face rates and with ``edge_length``: every edge of the output inside
the control mesh is shared by exactly two faces in opposite directions, boundary edges of the output lie on the
control mesh's boundary, no two vertices share a position (so shared edges carry each vertex once), faces are
counter-clockwise (their normals agree with the limit normals), and the vertex and face-varying (u, v) evaluate to
the output points. The command writes OBJ and USD with the conventions of ``refine``.
"""
import os

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh, mesh_path
from warp_subdiv import SubdivInputError
from warp_subdiv.cli import main

MESHES = [("cube", "catmull-clark"), ("mixed_prism", "catmull-clark"), ("quad_lshape", "catmull-clark"),
          ("grid3x3", "catmull-clark"), ("icosahedron", "loop"), ("tri_grid3x3", "loop"), ("mixed_prism", "loop"),
          ("tri_halffan", "loop")]


def output_edges(t):
    """(directed edges (m, 2), their counts by undirected edge): every face's consecutive vertex pairs."""
    counts, idx = t.face_vertex_counts, t.face_vertex_indices
    starts = np.repeat(np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    pos = np.arange(len(idx))
    nxt = np.where(pos + 1 == starts + np.repeat(counts, counts), starts, pos + 1)
    directed = np.stack([idx, idx[nxt]], 1)
    return directed


def check_watertight(mesh, surface, t):
    """The checks of the module docstring on tessellation ``t`` of ``surface``."""
    directed = output_edges(t)
    undirected = np.sort(directed, axis=1)
    keys, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    assert counts.max() <= 2, "an edge is shared by more than two faces"
    # each directed edge once: consistent orientation, no T-junction (which would leave unmatched edges)
    assert len(np.unique(directed, axis=0)) == len(directed)
    # output boundary edges are the segments of the control mesh's open edges (incl. edges of hole faces)
    control_edges = mesh.edges.edge_verts
    face_of_corner = np.repeat(np.arange(len(mesh.face_vertex_counts)), mesh.face_vertex_counts)
    live = ~surface.holes[face_of_corner]
    uses = np.bincount(mesh.edges.corner_edge[live], minlength=len(control_edges))
    assert np.sum(counts == 1) == int(t.edge_rates[uses == 1].sum())
    # no two vertices at one position: shared edges carry each point once
    scale = np.abs(t.points).max()
    rounded = np.round(t.points / (scale * 1e-9)).astype(np.int64)
    assert len(np.unique(rounded, axis=0)) == len(t.points), "two vertices share a position"
    # counter-clockwise faces: the geometric normal agrees with the limit normals at their vertices
    starts = np.concatenate([[0], np.cumsum(t.face_vertex_counts)[:-1]])
    a = t.points[t.face_vertex_indices[starts]]
    b = t.points[t.face_vertex_indices[starts + 1]]
    c = t.points[t.face_vertex_indices[starts + 2]]
    geometric = np.cross(b - a, c - a)
    assert np.mean(np.einsum("ij,ij->i", geometric, t.normals[t.face_vertex_indices[starts]]) > 0) > 0.99
    # every vertex's (base face, uv), and every face corner's face-varying (u, v), evaluate to the point
    ev = surface.evaluate(t.base_face, t.uv[:, 0], t.uv[:, 1])
    np.testing.assert_allclose(ev.points, t.points, atol=1e-12 * scale)
    corner_face = np.repeat(t.face_base_face, t.face_vertex_counts)
    ev = surface.evaluate(corner_face, t.face_uv[:, 0], t.face_uv[:, 1])
    np.testing.assert_allclose(ev.points, t.points[t.face_vertex_indices], atol=1e-6 * scale)


@pytest.mark.parametrize("name,scheme", MESHES)
def test_random_edge_rates_are_watertight(name, scheme):
    """Random per-edge rates (1..9), random per-face rates (1..6), a uniform rate and an edge length: the
    tessellation is watertight (see module docstring) on closed and open meshes, n-gons and Loop polygons."""
    mesh = load_mesh(name)
    surface = ws.LimitSurface(mesh, scheme=scheme, depth=3)
    rng = np.random.default_rng(7)
    E, F = len(surface.edges), surface.num_faces
    for rate in ({"edges": rng.integers(1, 10, E)}, {"faces": rng.integers(1, 7, F)}, 3):
        check_watertight(mesh, surface, surface.tessellate(rate=rate))
    check_watertight(mesh, surface, surface.tessellate(edge_length=0.3 * np.abs(mesh.points).max()))


def test_uniform_rates_give_grids_of_quads():
    """A uniform rate over quads gives rate x rate quads per face sharing their edge points; quads=False splits
    them into triangles; Loop gives rate^2 triangles per triangle."""
    mesh = load_mesh("cube")
    surface = ws.LimitSurface(mesh, depth=3)
    t = surface.tessellate(rate=4)
    assert t.num_faces == 6 * 16 and np.all(t.face_vertex_counts == 4)
    assert t.num_vertices == 6 * 9 + 12 * 3 + 8
    t3 = surface.tessellate(rate=4, quads=False)
    assert t3.num_faces == 2 * 6 * 16 and np.all(t3.face_vertex_counts == 3)
    ico = ws.LimitSurface(load_mesh("icosahedron"), scheme="loop", depth=3)
    t = ico.tessellate(rate=3)
    assert t.num_faces == 20 * 9 and np.all(t.face_vertex_counts == 3)


def test_edge_length_rates():
    """edge_length sets each control edge's rate to ceil(limit curve length / edge_length): halving it about
    doubles the rates; the tessellation's edges along a control edge are about that long."""
    mesh = load_mesh("cube")
    surface = ws.LimitSurface(mesh, depth=3)
    coarse = surface.tessellate(edge_length=0.2)
    fine = surface.tessellate(edge_length=0.1)
    assert np.all(fine.edge_rates >= 2 * coarse.edge_rates - 1)
    directed = output_edges(fine)
    lengths = np.linalg.norm(fine.points[directed[:, 0]] - fine.points[directed[:, 1]], axis=1)
    assert np.median(lengths) < 0.1 * 1.5


def test_rate_arguments_are_checked():
    """Rates must be positive integers, one per face or per edge (a dict says which when the counts coincide);
    exactly one of rate and edge_length."""
    surface = ws.LimitSurface(load_mesh("cube"), depth=2)
    for bad in (0, -1, 2.5, [1, 2], "x"):
        with pytest.raises(SubdivInputError):
            surface.tessellate(rate=bad)
    with pytest.raises(SubdivInputError):
        surface.tessellate()
    with pytest.raises(SubdivInputError):
        surface.tessellate(rate=2, edge_length=0.1)
    with pytest.raises(SubdivInputError):
        surface.tessellate(edge_length=-1.0)
    assert surface.tessellate(rate={"faces": [1, 2, 3, 1, 2, 3]}).num_faces > 0


def test_holes_are_left_out():
    """Hole faces get no cells: their edges become boundary edges of the output."""
    base = load_mesh("grid3x3")
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, holes=[4])
    surface = ws.LimitSurface(mesh, depth=2)
    t = surface.tessellate(rate=2)
    assert t.num_faces == 8 * 4
    assert 4 not in set(t.face_base_face.tolist())
    check_watertight(mesh, surface, t)


def test_command_writes_obj_and_usd(tmp_path):
    """warp-subdiv tessellate IN -o OUT --rate N / --edge-length L writes OBJ (from OBJ) and USD, the USD as a
    layer over the input with the mesh's points, faces and normals, subdivisionScheme none."""
    out = tmp_path / "cube.obj"
    assert main(["tessellate", mesh_path("cube"), "-o", str(out), "--rate", "3", "--quiet"]) == 0
    from warp_subdiv.io.obj import read_obj
    back = read_obj(str(out)).mesh
    assert len(back.face_vertex_counts) == 6 * 9
    out2 = tmp_path / "cube_len.obj"
    assert main(["tessellate", mesh_path("cube"), "-o", str(out2), "--edge-length", "0.25", "--quiet"]) == 0
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom
    usd_in = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes",
                          "shared_boundary.usda")
    usd_out = tmp_path / "shared.usda"
    assert main(["tessellate", usd_in, "-o", str(usd_out), "--rate", "2", "--quiet"]) == 0
    stage = Usd.Stage.Open(str(usd_out))
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert meshes
    for m in meshes:
        assert m.GetSubdivisionSchemeAttr().Get() == "none"
        assert len(m.GetNormalsAttr().Get()) == len(m.GetPointsAttr().Get())
