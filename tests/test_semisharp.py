"""Semi-sharp creases and corners (DeRose, Kass, Truong 1998; OpenSubdiv's Sdc::Crease), hand-computed cases."""

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh
from warp_subdiv.topology import base_level, refine_level


def cube_with(creases, sharpness, corners=None, corner_sharpness=None):
    c = load_mesh("cube")
    return ws.Mesh(c.points, c.face_vertex_counts, c.face_vertex_indices, creases=creases,
                   crease_sharpness=sharpness, corners=corners, corner_sharpness=corner_sharpness)


def levels(mesh, n, crease_method="uniform"):
    lv = [base_level(mesh, "catmull-clark", "edge-and-corner", "opensubdiv", crease_method=crease_method)]
    for _ in range(n):
        lv.append(refine_level(lv[-1]))
    return lv


def edge_rows(refiner, level_topology, level, edge_ids):
    table = refiner.tables[level]
    t = level_topology
    return [table.row(t.num_vertices + t.num_faces + int(e)) for e in edge_ids]


def smooth_quad_edge_row(t, e):
    """Hand-made smooth Catmull-Clark edge row on a quad level: 3/8 on the ends, 1/16 on the four others."""
    a, b = (int(x) for x in t.edge_verts[e])
    row = {a: 3 / 8, b: 3 / 8}
    for h in t.edge_corners[t.edge_corner_offsets[e]:t.edge_corner_offsets[e + 1]]:
        f = int(h) // 4
        for v in t.corner_vert[4 * f:4 * f + 4]:
            if int(v) not in (a, b):
                row[int(v)] = row.get(int(v), 0.0) + 1 / 16
    return row


def blend(rows, weights):
    out = {}
    for row, w in zip(rows, weights):
        for k, v in row.items():
            out[k] = out.get(k, 0.0) + w * v
    return out


def assert_rows_equal(got, expected):
    keys = set(got) | set(expected)
    for k in keys:
        assert abs(got.get(k, 0.0) - expected.get(k, 0.0)) < 1e-12, (k, got, expected)


@pytest.mark.parametrize("s", [1.0, 2.0, 2.5, 10.0])
def test_edge_sharp_for_floor_s_levels_then_blended_then_smooth(s):
    """An edge of sharpness s: its children are crease edge points while the sharpness is >= 1, blend
    s_frac * midpoint + (1 - s_frac) * smooth at the level where it falls below 1, and are smooth after."""
    mesh = cube_with([[0, 1]], [s])
    top = 5
    lv = levels(mesh, top)
    r = ws.Refiner(mesh, top, rules="opensubdiv", device="cpu", precision="float64")
    for j in range(top):
        t = lv[j]
        sharpness_now = s if s >= 10 else max(s - j, 0.0)
        chain = np.flatnonzero(np.isclose(t.edge_sharpness, sharpness_now)) if sharpness_now > 0 else []
        if sharpness_now <= 0:
            assert not np.any(t.edge_sharpness > 0)
            continue
        assert len(chain) == 2 ** j
        for e, row in zip(chain, edge_rows(r, t, j, chain)):
            a, b = (int(x) for x in t.edge_verts[e])
            crease = {a: 0.5, b: 0.5}
            if sharpness_now >= 1.0:
                expected = crease if (sharpness_now > 1.0 or s >= 10) else blend([crease], [1.0])
            else:
                expected = blend([crease, smooth_quad_edge_row(t, e)], [sharpness_now, 1 - sharpness_now])
            assert_rows_equal(row, expected)
    # level 1: the edge's child is its midpoint (s >= 1 means fully sharp for the first step)
    pts = ws.refine(mesh, 1, rules="opensubdiv", device="cpu", precision="float64").points
    e = int(mesh.edges.find(np.array([[0, 1]]), 8)[0])
    np.testing.assert_allclose(pts[8 + 6 + e], (mesh.points[0] + mesh.points[1]) / 2, atol=1e-12)


def test_crease_vertex_transition_uses_the_fractional_weight():
    """Vertex 1 on a crease chain of sharpness 1.5: crease rule at level 0, at level 1 the blend
    0.5 * crease + 0.5 * smooth (both edges end with sharpness 0.5), smooth after."""
    mesh = cube_with([[0, 1], [1, 2]], [1.5, 1.5])
    lv = levels(mesh, 2)
    r = ws.Refiner(mesh, 3, rules="opensubdiv", device="cpu", precision="float64")
    t1 = lv[1]
    assert_rows_equal(r.tables[0].row(1), {1: 0.75, 0: 0.125, 2: 0.125})
    # level 1: the crease neighbours of vertex 1 are its two sharp half-edges
    nbs = [int(t1.edge_verts[e].sum() - 1) for e in np.flatnonzero(t1.edge_sharpness > 0) if 1 in t1.edge_verts[e]]
    assert len(nbs) == 2
    crease = {1: 0.75, nbs[0]: 0.125, nbs[1]: 0.125}
    n = int(np.diff(t1.vert_corner_offsets)[1])
    smooth = {1: 1 - 7 / (4 * n)}
    for h in t1.vert_corners[t1.vert_corner_offsets[1]:t1.vert_corner_offsets[2]]:
        h = int(h)
        pnext = int(t1.corner_vert[h - h % 4 + (h % 4 + 1) % 4])
        q = int(t1.corner_vert[h - h % 4 + (h % 4 + 2) % 4])
        smooth[pnext] = smooth.get(pnext, 0) + 3 / (2 * n * n)
        smooth[q] = smooth.get(q, 0) + 1 / (4 * n * n)
    assert_rows_equal(r.tables[1].row(1), blend([crease, smooth], [0.5, 0.5]))
    assert t1.vert_class[1] == 2 and lv[2].vert_class[1] == 0  # crease, then interior


def test_semi_sharp_corner():
    """A corner of sharpness 1.5 interpolates at level 0, blends 0.5 corner + 0.5 smooth at level 1."""
    mesh = cube_with(None, None, corners=[6], corner_sharpness=[1.5])
    r = ws.Refiner(mesh, 2, rules="opensubdiv", device="cpu", precision="float64")
    assert_rows_equal(r.tables[0].row(6), {6: 1.0})
    row = r.tables[1].row(6)
    assert abs(row[6] - (0.5 * 1.0 + 0.5 * (1 - 7 / 12))) < 1e-12
    assert abs(sum(row.values()) - 1.0) < 1e-12


def test_chaikin_on_a_chain_with_varying_sharpness():
    """Chaikin: the child at vertex v gets 3/4 of the edge's sharpness + 1/4 of the mean of v's other
    semi-sharp edges, minus 1; at a chain end (one semi-sharp edge) it decays by 1."""
    mesh = cube_with([[0, 1], [1, 2]], [2.0, 1.0])
    t0, t1 = levels(mesh, 1, crease_method="chaikin")
    e01 = int(mesh.edges.find(np.array([[0, 1]]), 8)[0])
    e12 = int(mesh.edges.find(np.array([[1, 2]]), 8)[0])

    def half(e, v):
        """Sharpness at level 1 of the half of edge e at vertex v (halves are C + 2e + side)."""
        side = 0 if t0.edge_verts[e, 0] == v else 1
        return t1.edge_sharpness[t0.num_corners + 2 * e + side]

    assert abs(half(e01, 1) - (0.75 * 2.0 + 0.25 * 1.0 - 1.0)) < 1e-12  # 0.75
    assert abs(half(e12, 1) - (0.75 * 1.0 + 0.25 * 2.0 - 1.0)) < 1e-12  # 0.25
    assert abs(half(e01, 0) - 1.0) < 1e-12 and half(e12, 2) == 0.0  # chain ends: decrement
    uniform = levels(mesh, 1)[1]
    assert sorted(set(np.round(uniform.edge_sharpness[uniform.edge_sharpness > 0], 12))) == [1.0]


def test_piecewise_smooth_follows_opensubdiv_at_semi_sharp_features():
    mesh = cube_with([[0, 1], [1, 2], [4, 5]], [1.5, 2.5, 0.7], corners=[6], corner_sharpness=[2.2])
    a = ws.refine(mesh, 4, device="cpu", precision="float64").points
    b = ws.refine(mesh, 4, rules="opensubdiv", device="cpu", precision="float64").points
    np.testing.assert_allclose(a, b, atol=1e-12)
