"""Topology derived by index arithmetic equals topology rediscovered from scratch on the refined faces."""
import warnings

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import fin_mesh, load_mesh
from warp_subdiv.rules import weights as rules
from warp_subdiv.topology import base_level, refine_level, triangulate

CASES = [
    ("cube", "catmull-clark"),
    ("cube_creased", "catmull-clark"),
    ("grid3x3", "catmull-clark"),
    ("quad_lshape", "catmull-clark"),
    ("quad_halffan", "catmull-clark"),
    ("mixed_prism", "catmull-clark"),
    ("icosahedron", "loop"),
    ("tri_halffan", "loop"),
    ("tri_grid3x3", "loop"),
    ("mixed_prism", "loop"),
]


def levels_of(mesh, scheme, n, rule_set="piecewise-smooth"):
    level = base_level(mesh, scheme, "edge-and-corner", rule_set)
    out = [level]
    for _ in range(n):
        level = refine_level(level)
        out.append(level)
    return out


def check_tables(level):
    C = level.num_corners
    h = np.arange(C)
    nxt = level.corner_next(h)
    ends = np.sort(np.stack([level.corner_vert[h], level.corner_vert[nxt]], 1), 1)
    np.testing.assert_array_equal(np.sort(level.edge_verts[level.corner_edge], 1), ends)
    # edge -> corners lists every corner exactly once, under its own edge
    rows = np.repeat(np.arange(level.num_edges), np.diff(level.edge_corner_offsets))
    np.testing.assert_array_equal(level.corner_edge[level.edge_corners], rows)
    assert np.array_equal(np.sort(level.edge_corners), h)
    # vertex -> corners likewise
    rows = np.repeat(np.arange(level.num_vertices), np.diff(level.vert_corner_offsets))
    np.testing.assert_array_equal(level.corner_vert[level.vert_corners], rows)
    assert np.array_equal(np.sort(level.vert_corners), h)
    # prev/next are inverse
    np.testing.assert_array_equal(level.corner_prev(nxt), h)
    check_rings(level)
    check_sectors(level)


def check_rings(level):
    """Rings run counter-clockwise: the face after corner h around its vertex shares edge (v, prev vertex)."""
    off = level.vert_corner_offsets
    ring = level.vert_corners.astype(np.int64)
    rows = np.repeat(np.arange(level.num_vertices), np.diff(off))
    cur, nxt_in_ring = ring[:-1], ring[1:]
    same_vertex = rows[:-1] == rows[1:]
    joined = level.corner_vert[level.corner_prev(cur)] == level.corner_vert[level.corner_next(nxt_in_ring)]
    manifold = np.ones(level.num_vertices, bool)
    counts = np.diff(level.edge_corner_offsets)
    manifold[level.edge_verts[counts > 2].reshape(-1)] = False
    ok = joined | ~same_vertex | ~manifold[rows[:-1]]
    assert np.all(ok), np.flatnonzero(~ok)[:5]
    # a boundary vertex's ring starts at the face after its boundary edge
    first = ring[off[:-1][np.diff(off) > 0]]
    boundary_first = counts[level.corner_edge[first]] == 1
    vert = level.corner_vert[first]
    on_boundary = np.zeros(level.num_vertices, bool)
    on_boundary[level.edge_verts[counts == 1].reshape(-1)] = True
    assert np.all(boundary_first == on_boundary[vert])


def check_sectors(level):
    k = level.sector_k()
    corners = level.sector_corners.astype(np.int64)
    owner = np.repeat(np.arange(level.num_sectors), k)
    np.testing.assert_array_equal(level.corner_vert[corners], level.sector_vertex[owner])
    heads = corners[level.sector_offsets[:-1]]
    tails = corners[level.sector_offsets[1:] - 1]
    assert np.all(level.edge_sharp[level.corner_edge[heads]])
    assert np.all(level.edge_sharp[level.corner_edge[level.corner_prev(tails)]])
    inner = np.ones(len(corners), bool)
    inner[level.sector_offsets[1:] - 1] = False
    a, b = corners[inner], corners[np.flatnonzero(inner) + 1]
    np.testing.assert_array_equal(level.corner_vert[level.corner_prev(a)], level.corner_vert[level.corner_next(b)])
    assert not np.any(level.edge_sharp[level.corner_edge[b]])
    # every corner of a crease or corner vertex with two or more crease edges is in exactly one sector
    sharp_count = np.bincount(level.edge_verts[level.edge_sharp].reshape(-1), minlength=level.num_vertices)
    tagged = np.isin(level.vert_class, [rules.CREASE, rules.CORNER]) & (sharp_count >= 2)
    expected = np.flatnonzero(tagged[level.corner_vert])
    np.testing.assert_array_equal(np.sort(corners), expected)


@pytest.mark.parametrize("name,scheme", CASES)
def test_derived_tables_are_consistent(name, scheme):
    for level in levels_of(load_mesh(name), scheme, 3):
        check_tables(level)


@pytest.mark.parametrize("name,scheme", CASES)
def test_derived_equals_rediscovered(name, scheme):
    mesh = load_mesh(name)
    lv = levels_of(mesh, scheme, 2)
    top = lv[-1]
    # a fresh Mesh of the level-2 faces with its sharp edges tagged as creases and its corners as corners
    pts = ws.refine(mesh, 2, scheme=scheme, device="cpu", precision="float64").points
    sharp = top.edge_verts[top.edge_sharp]
    fresh = ws.Mesh(pts, top.face_vertex_counts(), top.corner_vert, creases=sharp,
                    corners=np.flatnonzero(top.vert_class == rules.CORNER))
    again = base_level(fresh, scheme, "edge-and-corner", "piecewise-smooth")
    # same edges (as sets) with the same sharpness
    def key(ev):
        return ev.min(1).astype(np.int64) * top.num_vertices + ev.max(1)
    k1, k2 = key(top.edge_verts), key(again.edge_verts)
    assert len(k1) == len(np.unique(k1)) == len(k2)
    o1, o2 = np.argsort(k1), np.argsort(k2)
    np.testing.assert_array_equal(k1[o1], k2[o2])
    np.testing.assert_array_equal(top.edge_sharp[o1], again.edge_sharp[o2])
    np.testing.assert_array_equal(top.vert_class, again.vert_class)
    # crease-vertex sectors: theta = pi/k with k recounted on the refined mesh
    crease = top.vert_class[top.corner_vert] == rules.CREASE
    np.testing.assert_allclose(top.corner_theta()[crease], again.corner_theta()[crease], atol=1e-12)
    # boundary edges of the refined mesh are exactly the children of boundary edges
    counts = np.diff(top.edge_corner_offsets)
    assert np.all(top.edge_sharp[counts == 1])


def test_counts_per_level():
    lv = levels_of(load_mesh("cube"), "catmull-clark", 3)
    assert [l.num_vertices for l in lv] == [8, 26, 98, 386]
    assert [l.num_faces for l in lv] == [6, 24, 96, 384]
    assert [l.num_edges for l in lv] == [12, 48, 192, 768]
    lv = levels_of(load_mesh("icosahedron"), "loop", 3)
    assert [l.num_vertices for l in lv] == [12, 42, 162, 642]
    assert [l.num_faces for l in lv] == [20, 80, 320, 1280]


def test_vertex_classes_on_control_mesh():
    lv = base_level(load_mesh("quad_lshape"), "catmull-clark", "edge-and-corner", "piecewise-smooth")
    # one-face boundary vertices are corners, the 3-face concave vertex 10 a crease, interior ones smooth
    assert set(np.flatnonzero(lv.vert_class == rules.CORNER)) == {0, 3, 11, 12, 14}
    assert lv.vert_class[10] == rules.CREASE
    assert set(np.flatnonzero(lv.vert_class == rules.SMOOTH)) == {5, 6, 9}
    lv = base_level(load_mesh("quad_lshape"), "catmull-clark", "edge-only", "piecewise-smooth")
    assert not np.any(lv.vert_class == rules.CORNER)


def test_sector_angles_on_control_mesh():
    m = load_mesh("quad_lshape")
    tagged = ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, corners=[10, 0], concave=[[10, 6]])
    lv = base_level(tagged, "catmull-clark", "edge-and-corner", "piecewise-smooth")
    def at(v):
        return lv.corner_theta()[lv.corner_vert == v]
    # vertex 10 (2, 2, 0.5): three faces, crease edges to (3, 2, 0) and (2, 3, 0): cos alpha = 0.25/1.25;
    # concave: theta = (2 pi - alpha)/3
    np.testing.assert_allclose(at(10), (2 * np.pi - np.arccos(0.2)) / 3)
    # vertex 0: one face, convex, alpha = pi/2: theta = alpha/1
    np.testing.assert_allclose(at(0), np.pi / 2)
    # a regular boundary vertex (2 faces): theta = pi/2
    np.testing.assert_allclose(at(1), np.pi / 2)
    # OpenSubdiv has no concave sectors: the tag is ignored there
    lv = base_level(tagged, "catmull-clark", "edge-and-corner", "opensubdiv")
    assert not np.any(lv.sector_kind == rules.SECTOR_CONCAVE)


def test_fan_triangulation():
    counts, idx, parent = triangulate(np.array([5, 4, 3]), np.arange(12))
    assert list(counts) == [3] * 6
    assert idx.reshape(-1, 3).tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [5, 6, 7], [5, 7, 8], [9, 10, 11]]
    assert parent.tolist() == [0, 0, 0, 1, 1, 2]


def test_small_pages_restores_numpy_hint_after_nesting_and_errors():
    """Topology steps switch numpy's huge-page hint off; the host's setting comes back afterwards, also when
    uses nest (concurrent refiners) or a step raises."""
    from warp_subdiv.runtime.pages import small_pages

    switch = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        pytest.skip("this numpy has no huge-page switch")
    original = switch(True)
    try:
        with small_pages():
            with small_pages():
                assert switch(False) is False  # off inside
            assert switch(False) is False  # still off: the outer use is active
        assert switch(True) is True  # restored
        with pytest.raises(RuntimeError):
            with small_pages():
                raise RuntimeError("a failing step")
        assert switch(True) is True
    finally:
        switch(original)


def _vertex_corners_by_concatenation(level, split, slots):
    """The child vertex -> corner table as counts per child vertex, a running sum and concatenated blocks."""
    from warp_subdiv.mesh import face_offsets_of

    m = split.edge_child_corners.shape[1]
    counts = [np.diff(level.vert_corner_offsets)]
    blocks = [split.vertex_child_corner[level.vert_corners]]
    if split.face_child_corners is not None:
        counts.append(level.face_sizes())
        blocks.append(split.face_child_corners)
    counts.append(m * slots.count)
    blocks.append(split.edge_child_corners[slots.corner].reshape(-1))
    return face_offsets_of(np.concatenate(counts)), np.concatenate(blocks)


@pytest.mark.parametrize("name, scheme", CASES + [("fin", "catmull-clark"), ("fin", "loop")])
def test_child_vertex_corners_equal_concatenated_blocks(name, scheme, monkeypatch):
    """The child vertex -> corner table, gathered in place with offsets from the parent's, is the table of
    per-vertex counts and concatenated blocks, values and types (quads, mixed polygons, Loop, non-manifold),
    on every step."""
    from warp_subdiv.topology import refinement

    mesh = fin_mesh(scheme == "loop") if name == "fin" else load_mesh(name)
    built = refinement._child_vertex_corners
    seen = []

    def compare(level, split, slots):
        offsets, corners = built(level, split, slots)
        ref_offsets, ref_corners = _vertex_corners_by_concatenation(level, split, slots)
        assert offsets.dtype == ref_offsets.dtype and corners.dtype == ref_corners.dtype
        np.testing.assert_array_equal(offsets, ref_offsets)
        np.testing.assert_array_equal(corners, ref_corners)
        seen.append(level.num_corners)
        return offsets, corners

    monkeypatch.setattr(refinement, "_child_vertex_corners", compare)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fin's non-manifold warning
        levels_of(mesh, scheme, 3)
    assert len(seen) == 3
