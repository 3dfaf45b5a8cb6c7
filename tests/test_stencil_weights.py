"""Exact stencil weights of every subdivision rule, both schemes (docs/rules.md sections 0 to 5).

Every expected weight is written here from the formulas of docs/rules.md (never read from warp_subdiv.rules), so
that a wrong rule in the library makes a test fail. Tables are built in float64 and compared to 1e-12.

Row of a child vertex in ``Refiner.tables[level]``: vertex child of v is row v; Catmull-Clark face child of f
is row V + f; the edge child of edge e is row V (+ F for Catmull-Clark) + e.
"""
from math import acos, cos, pi

import numpy as np
import pytest

import warp_subdiv as ws

from conftest import MESHES, load_mesh

TOL = 1e-12
LOOP = "loop"
CC = "catmull-clark"


# --------------------------------------------------------------------------------------------------------
# helpers


def make_refiner(mesh, scheme, levels=1, **kw):
    return ws.Refiner(mesh, levels, scheme=scheme, device="cpu", precision="float64", **kw)


def table(mesh, scheme, level=0, **kw):
    return make_refiner(mesh, scheme, levels=level + 1, **kw).tables[level]


def edge_id(mesh, a, b):
    e = int(mesh.edges.find(np.array([[a, b]]), mesh.num_vertices)[0])
    assert e >= 0, f"({a}, {b}) is not an edge of the test mesh"
    return e


def edge_row(mesh, scheme, a, b):
    """Row of the level-0 edge (a, b)'s child in tables[0]."""
    extra = mesh.num_faces if scheme == CC else 0
    return mesh.num_vertices + extra + edge_id(mesh, a, b)


def face_row(mesh, f):
    return mesh.num_vertices + f


class LevelTopology:
    """The faces of refinement level ``level`` (from the public ``Refiner.topology()``), to locate the rows of
    that level's edge children in ``tables[level]`` without relying on the library's internal edge order."""

    def __init__(self, mesh, scheme, level, **kw):
        r = make_refiner(mesh, scheme, levels=level, **kw)
        counts, idx = r.topology()
        off = np.concatenate([[0], np.cumsum(counts)])
        self.faces = [idx[off[f]:off[f + 1]].tolist() for f in range(len(counts))]
        self.num_vertices = r.num_vertices
        self.first_edge_row = self.num_vertices + (len(self.faces) if scheme == CC else 0)

    def edge_faces(self, a, b):
        out = []
        for f in self.faces:
            n = len(f)
            if any({f[i], f[(i + 1) % n]} == {a, b} for i in range(n)):
                out.append(f)
        return out

    def neighbours(self, v):
        out = set()
        for f in self.faces:
            if v in f:
                j = f.index(v)
                out |= {f[j - 1], f[(j + 1) % len(f)]}
        return out

    def edge_row(self, tab, a, b):
        """Row of edge (a, b)'s child in ``tab`` (= tables[level]): the one edge row whose support is {a, b}
        (crease rule) or all vertices of the faces at the edge (any other rule)."""
        faces = self.edge_faces(a, b)
        assert faces, f"({a}, {b}) is not an edge of the level"
        union = set().union(*map(set, faces))
        hits = []
        for i in range(self.first_edge_row, tab.num_rows):
            support = {k for k, w in tab.row(i).items() if w != 0.0}
            if support == {a, b} or support == union:
                hits.append(i)
        assert len(hits) == 1, f"edge ({a}, {b}): rows {hits} match"
        return hits[0]


def assert_row(tab, i, expected, tol=TOL):
    got = tab.row(i)
    keys = set(got) | set(expected)
    bad = {k: (got.get(k, 0.0), expected.get(k, 0.0)) for k in sorted(keys)
           if abs(got.get(k, 0.0) - expected.get(k, 0.0)) > tol}
    assert not bad, f"row {i}: (got, expected) differ at {bad}; full row {got}"


def gamma_loop(theta):
    return 0.5 - cos(theta) / 4.0


def gamma_cc(theta):
    return 3.0 / 8.0 - cos(theta) / 4.0


def beta_loop(k):
    return (5.0 / 8.0 - (3.0 / 8.0 + cos(2.0 * pi / k) / 4.0) ** 2) / k


def beta_warren(k):
    return 3.0 / 16.0 if k == 3 else 3.0 / (8.0 * k)


# ----- small meshes built here


def tri_fan(k, z=0.3):
    """Closed fan of k triangles: centre 0 (interior, valence k), ring 1..k (boundary)."""
    pts = [[0.0, 0.0, z]] + [[cos(2 * pi * i / k), np.sin(2 * pi * i / k), 0.0] for i in range(k)]
    faces = [[0, 1 + i, 1 + (i + 1) % k] for i in range(k)]
    return ws.Mesh(np.array(pts), [3] * k, np.array(faces).reshape(-1))


def quad_fan(k, z=0.3):
    """Closed fan of k quads (0, p_i, q_i, p_i+1): centre 0 interior of valence k; p_i = 1 + i, q_i = 1 + k + i."""
    pts = [[0.0, 0.0, z]]
    pts += [[cos(2 * pi * i / k), np.sin(2 * pi * i / k), 0.0] for i in range(k)]
    pts += [[1.5 * cos(2 * pi * (i + 0.5) / k), 1.5 * np.sin(2 * pi * (i + 0.5) / k), 0.1] for i in range(k)]
    faces = [[0, 1 + i, 1 + k + i, 1 + (i + 1) % k] for i in range(k)]
    return ws.Mesh(np.array(pts), [4] * k, np.array(faces).reshape(-1))


def tri_sector(k, span, **tags):
    """An open sector of k triangles (c, p_i, p_i+1) around boundary vertex c = 0 spanning ``span`` radians
    (planar), with an outer ring so that p_1..p_k-1 are interior vertices.

    Ids: c = 0, p_i = 1 + i (i = 0..k), outer P_i = k + 2 + i. The sector's crease edges are (c, p_0), (c, p_k);
    the measured angle between them is min(span, 2 pi - span).
    """
    ang = [span * i / k for i in range(k + 1)]
    pts = [[0.0, 0.0, 0.0]] + [[cos(a), np.sin(a), 0.0] for a in ang] + [[2 * cos(a), 2 * np.sin(a), 0.0] for a in ang]
    p = lambda i: 1 + i  # noqa: E731
    P = lambda i: k + 2 + i  # noqa: E731
    faces = [[0, p(i), p(i + 1)] for i in range(k)]
    for i in range(k):
        faces += [[p(i), P(i), P(i + 1)], [p(i), P(i + 1), p(i + 1)]]
    return ws.Mesh(np.array(pts), [3] * len(faces), np.array(faces).reshape(-1), **tags)


def quad_sector(k, span, **tags):
    """An open sector of k quads (c, p_i, q_i, p_i+1) around boundary vertex c = 0 spanning ``span`` radians
    (planar), with quads (p_i, q_i-1, r_i, q_i) so that p_1..p_k-1 are interior vertices.

    Ids: c = 0, p_i = 1 + i (i = 0..k), q_i = k + 2 + i (i = 0..k-1), r_i = 2k + 1 + i (i = 1..k-1).
    """
    pts = [[0.0, 0.0, 0.0]]
    pts += [[cos(span * i / k), np.sin(span * i / k), 0.0] for i in range(k + 1)]
    pts += [[1.5 * cos(span * (i + 0.5) / k), 1.5 * np.sin(span * (i + 0.5) / k), 0.0] for i in range(k)]
    pts += [[2.0 * cos(span * i / k), 2.0 * np.sin(span * i / k), 0.0] for i in range(1, k)]
    p = lambda i: 1 + i  # noqa: E731
    q = lambda i: k + 2 + i  # noqa: E731
    r = lambda i: 2 * k + 1 + i  # noqa: E731
    faces = [[0, p(i), q(i), p(i + 1)] for i in range(k)]
    faces += [[p(i), q(i - 1), r(i), q(i)] for i in range(1, k)]
    return ws.Mesh(np.array(pts), [4] * len(faces), np.array(faces).reshape(-1), **tags)


def retag(mesh, **tags):
    """The same geometry and faces with other tags."""
    return ws.Mesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, **tags)


# --------------------------------------------------------------------------------------------------------
# the test meshes themselves (guards against a silently changed fixture)


def test_test_meshes_are_what_the_tests_assume():
    fan = load_mesh("tri_halffan")
    assert (fan.num_vertices, fan.num_faces) == (6, 4)
    qfan = load_mesh("quad_halffan")
    assert (qfan.num_vertices, qfan.num_faces) == (8, 3)
    prism = load_mesh("mixed_prism")
    assert prism.face_vertex_counts.tolist() == [5, 5, 3, 3, 4, 4, 4, 4]
    # closed: every edge in exactly two faces
    assert prism.num_edges == (5 + 5 + 3 + 3 + 4 * 4) // 2


# --------------------------------------------------------------------------------------------------------
# Loop interior vertex (docs/rules.md section 3)


@pytest.mark.parametrize("k", [3, 4, 5, 6, 7])
@pytest.mark.parametrize("variant", ["loop", "warren"])
def test_loop_interior_vertex_fan(k, variant):
    beta = beta_loop(k) if variant == "loop" else beta_warren(k)
    tab = table(tri_fan(k), LOOP, loop_beta=variant)
    expected = {0: 1.0 - k * beta}
    expected.update({1 + i: beta for i in range(k)})
    assert_row(tab, 0, expected)


def test_loop_beta_literal_values():
    """The formulas above, pinned to literal numbers (docs/rules.md: both give 3/16 at k = 3 and 1/16 at k = 6)."""
    for k, b in [(3, 3 / 16), (4, 31 / 256), (6, 1 / 16)]:
        assert_row(table(tri_fan(k), LOOP, loop_beta="loop"), 0, {0: 1 - k * b, **{1 + i: b for i in range(k)}})
    for k, b in [(3, 3 / 16), (4, 3 / 32), (5, 3 / 40), (6, 1 / 16), (7, 3 / 56)]:
        assert_row(table(tri_fan(k), LOOP, loop_beta="warren"), 0, {0: 1 - k * b, **{1 + i: b for i in range(k)}})


def test_loop_beta_default_is_loops_original():
    k = 5
    assert_row(table(tri_fan(k), LOOP), 0, {0: 1 - k * beta_loop(k), **{1 + i: beta_loop(k) for i in range(k)}})


@pytest.mark.parametrize("variant", ["loop", "warren"])
def test_loop_interior_vertex_closed_meshes(variant):
    beta = beta_loop if variant == "loop" else beta_warren
    # octahedron: vertex 0 = (1,0,0) has neighbours 2, 3, 4, 5 (valence 4)
    oct_ = load_mesh("octahedron")
    b = beta(4)
    assert_row(table(oct_, LOOP, loop_beta=variant), 0, {0: 1 - 4 * b, 2: b, 3: b, 4: b, 5: b})
    # icosahedron: every vertex has valence 5; vertex 0's neighbours from the faces f 1 12 6 ... (1-based)
    ico = load_mesh("icosahedron")
    b = beta(5)
    assert_row(table(ico, LOOP, loop_beta=variant), 0, {0: 1 - 5 * b, 11: b, 5: b, 1: b, 7: b, 10: b})


def test_loop_interior_vertex_level1_regular():
    """Level-1 vertices of the icosahedron's edge children are regular (valence 6): beta = 1/16."""
    ico = load_mesh("icosahedron")
    r = make_refiner(ico, LOOP, levels=2)
    topo = LevelTopology(ico, LOOP, 1)
    v = ico.num_vertices + edge_id(ico, 0, 1)
    ring = topo.neighbours(v)
    assert len(ring) == 6
    assert_row(r.tables[1], v, {v: 10 / 16, **{u: 1 / 16 for u in ring}})


# --------------------------------------------------------------------------------------------------------
# Catmull-Clark interior vertex (docs/rules.md section 3)


def cc_quad_interior(k, c, ps, qs):
    out = {c: 1 - 7 / (4 * k)}
    for p in ps:
        out[p] = out.get(p, 0.0) + 3 / (2 * k * k)
    for q in qs:
        out[q] = out.get(q, 0.0) + 1 / (4 * k * k)
    return out


@pytest.mark.parametrize("k", [3, 4, 5, 6])
def test_cc_interior_vertex_quad_fan(k):
    tab = table(quad_fan(k), CC)
    assert_row(tab, 0, cc_quad_interior(k, 0, [1 + i for i in range(k)], [1 + k + i for i in range(k)]))


def test_cc_interior_vertex_literal_values():
    # cube vertex 0: valence 3, edge neighbours 1, 3, 4; diagonals 2, 5, 7
    cube = load_mesh("cube")
    assert_row(table(cube, CC), 0, {0: 5 / 12, 1: 1 / 6, 3: 1 / 6, 4: 1 / 6, 2: 1 / 36, 5: 1 / 36, 7: 1 / 36})
    # open grid, interior vertex 5 = (1,1): valence 4, edge neighbours 1, 4, 6, 9; diagonals 0, 2, 8, 10
    grid = load_mesh("grid3x3")
    assert_row(table(grid, CC), 5, {5: 9 / 16, 1: 3 / 32, 4: 3 / 32, 6: 3 / 32, 9: 3 / 32,
                                    0: 1 / 64, 2: 1 / 64, 8: 1 / 64, 10: 1 / 64})
    # valence 5: 1 - 7/20 = 13/20, 3/50, 1/100
    assert_row(table(quad_fan(5), CC), 0, {0: 13 / 20, **{1 + i: 3 / 50 for i in range(5)},
                                           **{6 + i: 1 / 100 for i in range(5)}})


def cc_general_vertex(mesh, v):
    """((n-2)/n) v + (1/n^2) sum p + (1/n^2) sum face centroids, expanded onto control vertices."""
    counts = mesh.face_vertex_counts
    idx = mesh.face_vertex_indices
    off = np.concatenate([[0], np.cumsum(counts)])
    faces = [idx[off[f]:off[f + 1]].tolist() for f in range(len(counts))]
    nbrs = set()
    incident = []
    for f in faces:
        if v in f:
            incident.append(f)
            j = f.index(v)
            nbrs.add(f[(j + 1) % len(f)])
            nbrs.add(f[j - 1])
    n = len(nbrs)
    assert n == len(incident)  # closed manifold vertex
    out = {v: (n - 2) / n}
    for p in nbrs:
        out[p] = out.get(p, 0.0) + 1 / n ** 2
    for f in incident:
        for u in f:
            out[u] = out.get(u, 0.0) + 1 / (n ** 2 * len(f))
    return out


def test_cc_interior_vertex_mixed_polygons_by_hand():
    """mixed_prism vertex 0 (0-based): faces pentagon (4 3 2 1 0), triangles (0 1 6), (0 6 5), quad (4 0 5 9).

    n = 4 edge neighbours 1, 4, 5, 6; (n-2)/n = 1/2, 1/16 per neighbour, 1/(16 m) per vertex of each m-gon.
    """
    prism = load_mesh("mixed_prism")
    expected = {
        0: 1 / 2 + 1 / 80 + 2 / 48 + 1 / 64,
        1: 1 / 16 + 1 / 80 + 1 / 48,
        4: 1 / 16 + 1 / 80 + 1 / 64,
        6: 1 / 16 + 1 / 48 + 1 / 48,
        5: 1 / 16 + 1 / 48 + 1 / 64,
        2: 1 / 80,
        3: 1 / 80,
        9: 1 / 64,
    }
    assert abs(sum(expected.values()) - 1.0) < 1e-15
    assert_row(table(prism, CC), 0, expected)


def test_cc_interior_vertex_mixed_polygons_every_vertex():
    prism = load_mesh("mixed_prism")
    tab = table(prism, CC)
    for v in range(prism.num_vertices):
        assert_row(tab, v, cc_general_vertex(prism, v))


# --------------------------------------------------------------------------------------------------------
# smooth edges and face points (docs/rules.md sections 4, 5)


def test_loop_smooth_edge():
    ico = load_mesh("icosahedron")
    # edge (0, 5) lies in faces (0 11 5) and (0 5 1): opposite vertices 11 and 1
    assert_row(table(ico, LOOP), edge_row(ico, LOOP, 0, 5), {0: 3 / 8, 5: 3 / 8, 11: 1 / 8, 1: 1 / 8})
    oct_ = load_mesh("octahedron")
    # edge (0, 2) in faces (0 2 4) and (2 0 5): opposite 4 and 5
    assert_row(table(oct_, LOOP), edge_row(oct_, LOOP, 0, 2), {0: 3 / 8, 2: 3 / 8, 4: 1 / 8, 5: 1 / 8})


def test_cc_smooth_edge_quads():
    cube = load_mesh("cube")
    # edge (0, 1) in faces (0 3 2 1) and (0 1 5 4)
    assert_row(table(cube, CC), edge_row(cube, CC, 0, 1),
               {0: 3 / 8, 1: 3 / 8, 3: 1 / 16, 2: 1 / 16, 5: 1 / 16, 4: 1 / 16})
    grid = load_mesh("grid3x3")
    # interior edge (5, 6) in faces (1 2 6 5) and (5 6 10 9)
    assert_row(table(grid, CC), edge_row(grid, CC, 5, 6),
               {5: 3 / 8, 6: 3 / 8, 1: 1 / 16, 2: 1 / 16, 9: 1 / 16, 10: 1 / 16})


def test_cc_smooth_edge_pentagon_triangle():
    """Edge (0, 1) of mixed_prism between the pentagon (4 3 2 1 0) and the triangle (0 1 6):
    (v1 + v2 + f1 + f2)/4 gives 1/4 + 1/20 + 1/12 on each endpoint, 1/20 on 2, 3, 4 and 1/12 on 6."""
    prism = load_mesh("mixed_prism")
    end = 1 / 4 + 1 / (4 * 5) + 1 / (4 * 3)
    assert_row(table(prism, CC), edge_row(prism, CC, 0, 1),
               {0: end, 1: end, 2: 1 / 20, 3: 1 / 20, 4: 1 / 20, 6: 1 / 12})


def test_cc_smooth_edge_every_edge_mixed_polygons():
    """Every edge of mixed_prism (closed, no tags): (v1 + v2 + f1 + f2)/4 with f the centroids of the two
    faces, i.e. 1/4 + 1/(4 m0) + 1/(4 m1) on each endpoint and 1/(4m) on the other vertices of an m-gon."""
    prism = load_mesh("mixed_prism")
    tab = table(prism, CC)
    counts = prism.face_vertex_counts
    idx = prism.face_vertex_indices
    off = np.concatenate([[0], np.cumsum(counts)])
    faces = [idx[off[f]:off[f + 1]].tolist() for f in range(len(counts))]
    for a, b in prism.edges.edge_verts.tolist():
        adj = [f for f in faces if a in f and b in f]
        assert len(adj) == 2
        m0, m1 = len(adj[0]), len(adj[1])
        expected = {a: 1 / 4 + 1 / (4 * m0) + 1 / (4 * m1), b: 1 / 4 + 1 / (4 * m0) + 1 / (4 * m1)}
        for f in adj:
            for u in f:
                if u not in (a, b):
                    expected[u] = expected.get(u, 0.0) + 1 / (4 * len(f))
        assert_row(tab, edge_row(prism, CC, a, b), expected)


def test_cc_face_points():
    cube = load_mesh("cube")
    tab = table(cube, CC)
    assert_row(tab, face_row(cube, 0), {0: 1 / 4, 3: 1 / 4, 2: 1 / 4, 1: 1 / 4})
    assert_row(tab, face_row(cube, 4), {2: 1 / 4, 3: 1 / 4, 7: 1 / 4, 6: 1 / 4})
    prism = load_mesh("mixed_prism")
    tab = table(prism, CC)
    assert_row(tab, face_row(prism, 0), {4: 1 / 5, 3: 1 / 5, 2: 1 / 5, 1: 1 / 5, 0: 1 / 5})
    assert_row(tab, face_row(prism, 1), {5: 1 / 5, 6: 1 / 5, 7: 1 / 5, 8: 1 / 5, 9: 1 / 5})
    assert_row(tab, face_row(prism, 2), {0: 1 / 3, 1: 1 / 3, 6: 1 / 3})
    assert_row(tab, face_row(prism, 4), {1: 1 / 4, 2: 1 / 4, 7: 1 / 4, 6: 1 / 4})


def test_cc_face_points_are_centroids_after_boundary_and_tags():
    """The face rule is the centroid always, next to creases and corners too (docs/rules.md section 5)."""
    lshape = load_mesh("quad_lshape")
    tab = table(retag(lshape, corners=[10], concave=[[10, 6]]), CC)
    # face 5 = (6 7 11 10) touches the concave corner 10
    assert_row(tab, face_row(lshape, 5), {6: 1 / 4, 7: 1 / 4, 11: 1 / 4, 10: 1 / 4})


# --------------------------------------------------------------------------------------------------------
# crease and corner vertices, darts (docs/rules.md sections 1, 3)


@pytest.mark.parametrize("scheme", [LOOP, CC])
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_crease_vertex_boundary(scheme, rules):
    if scheme == CC:
        grid = load_mesh("grid3x3")
        # boundary vertex 1 = (1,0): crease neighbours 0 and 2
        assert_row(table(grid, CC, rules=rules), 1, {1: 3 / 4, 0: 1 / 8, 2: 1 / 8})
        qfan = load_mesh("quad_halffan")
        # vertex 0 of the half fan (3 faces): crease neighbours 1 and 4
        assert_row(table(qfan, CC, rules=rules), 0, {0: 3 / 4, 1: 1 / 8, 4: 1 / 8})
    else:
        hexfan = load_mesh("tri_hexfan")
        assert_row(table(hexfan, LOOP, rules=rules), 1, {1: 3 / 4, 2: 1 / 8, 6: 1 / 8})
        fan = load_mesh("tri_halffan")
        assert_row(table(fan, LOOP, rules=rules), 0, {0: 3 / 4, 1: 1 / 8, 5: 1 / 8})


def test_crease_vertex_interior_tagged_loop():
    """Octahedron with the equator 0-2-1-3-0 tagged: vertex 0 is a crease vertex with neighbours 2, 3."""
    oct_ = load_mesh("octahedron")
    m = retag(oct_, creases=[[0, 2], [2, 1], [1, 3], [3, 0]])
    tab = table(m, LOOP)
    assert_row(tab, 0, {0: 3 / 4, 2: 1 / 8, 3: 1 / 8})
    assert_row(tab, 2, {2: 3 / 4, 0: 1 / 8, 1: 1 / 8})
    # the poles stay interior vertices (valence 4, Loop beta)
    b = beta_loop(4)
    assert_row(tab, 4, {4: 1 - 4 * b, 0: b, 1: b, 2: b, 3: b})


def test_crease_vertex_interior_tagged_cc():
    """Cube with the loop of edges around face (0 3 2 1) tagged: vertex 0 has crease neighbours 1 and 3."""
    cube = load_mesh("cube")
    m = retag(cube, creases=[[0, 1], [1, 2], [2, 3], [3, 0]])
    tab = table(m, CC)
    assert_row(tab, 0, {0: 3 / 4, 1: 1 / 8, 3: 1 / 8})
    assert_row(tab, 2, {2: 3 / 4, 1: 1 / 8, 3: 1 / 8})
    # vertex 4 is untouched: interior, valence 3 (neighbours 0, 5, 7; diagonals 1, 3, 6)
    assert_row(tab, 4, {4: 5 / 12, 0: 1 / 6, 5: 1 / 6, 7: 1 / 6, 1: 1 / 36, 3: 1 / 36, 6: 1 / 36})


@pytest.mark.parametrize("scheme", [LOOP, CC])
def test_corner_vertex_tagged(scheme):
    if scheme == CC:
        cube = load_mesh("cube_creased")  # all 8 vertices tagged corners (and all edges creases)
        tab = table(cube, CC)
        for v in range(8):
            assert_row(tab, v, {v: 1.0})
        # a tagged corner on a smooth boundary vertex with 3 faces (that would otherwise be a crease)
        tab = table(retag(load_mesh("quad_halffan"), corners=[0]), CC)
        assert_row(tab, 0, {0: 1.0})
    else:
        tab = table(retag(load_mesh("tri_halffan"), corners=[0]), LOOP)
        assert_row(tab, 0, {0: 1.0})
        # an interior vertex tagged as corner interpolates too
        tab = table(retag(load_mesh("icosahedron"), corners=[3]), LOOP)
        assert_row(tab, 3, {3: 1.0})


@pytest.mark.parametrize("scheme", [LOOP, CC])
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_one_face_boundary_vertex_by_boundary_mode(scheme, rules):
    """A boundary vertex with one face: a corner with edge-and-corner, the crease rule with edge-only."""
    if scheme == CC:
        grid = load_mesh("grid3x3")  # vertex 0 = (0,0): one face, crease neighbours 1 and 4
        v, nbrs = 0, (1, 4)
    else:
        grid = load_mesh("tri_grid3x3")  # vertex 3 = (3,0): one face (2 3 7), crease neighbours 2 and 7
        v, nbrs = 3, (2, 7)
    assert_row(table(grid, scheme, rules=rules, boundary="edge-and-corner"), v, {v: 1.0})
    assert_row(table(grid, scheme, rules=rules), v, {v: 1.0})  # edge-and-corner is the default
    assert_row(table(grid, scheme, rules=rules, boundary="edge-only"), v,
               {v: 3 / 4, nbrs[0]: 1 / 8, nbrs[1]: 1 / 8})


def test_dart_loop():
    """Octahedron with one tagged crease edge (0, 2): 0 and 2 are darts (interior rule); the crease edge is a
    midpoint, the other edges at the darts follow the smooth rule."""
    m = retag(load_mesh("octahedron"), creases=[[0, 2]])
    tab = table(m, LOOP)
    b = beta_loop(4)
    assert_row(tab, 0, {0: 1 - 4 * b, 2: b, 3: b, 4: b, 5: b})
    assert_row(tab, 2, {2: 1 - 4 * b, 0: b, 1: b, 4: b, 5: b})
    assert_row(tab, edge_row(m, LOOP, 0, 2), {0: 1 / 2, 2: 1 / 2})
    # (0, 4) in faces (0 2 4), (3 0 4); (0, 5) in (2 0 5), (0 3 5); (2, 4) in (0 2 4), (2 1 4)
    assert_row(tab, edge_row(m, LOOP, 0, 4), {0: 3 / 8, 4: 3 / 8, 2: 1 / 8, 3: 1 / 8})
    assert_row(tab, edge_row(m, LOOP, 0, 5), {0: 3 / 8, 5: 3 / 8, 2: 1 / 8, 3: 1 / 8})
    assert_row(tab, edge_row(m, LOOP, 2, 4), {2: 3 / 8, 4: 3 / 8, 0: 1 / 8, 1: 1 / 8})


def test_dart_cc():
    """Cube with one tagged crease edge (0, 1): darts 0 and 1 keep the interior rule, their edges the smooth
    rule, the crease edge is a midpoint."""
    m = retag(load_mesh("cube"), creases=[[0, 1]])
    tab = table(m, CC)
    assert_row(tab, 0, {0: 5 / 12, 1: 1 / 6, 3: 1 / 6, 4: 1 / 6, 2: 1 / 36, 5: 1 / 36, 7: 1 / 36})
    assert_row(tab, edge_row(m, CC, 0, 1), {0: 1 / 2, 1: 1 / 2})
    # (0, 4) in faces (0 1 5 4) and (3 0 4 7)
    assert_row(tab, edge_row(m, CC, 0, 4), {0: 3 / 8, 4: 3 / 8, 1: 1 / 16, 5: 1 / 16, 3: 1 / 16, 7: 1 / 16})
    # (0, 3) in faces (0 3 2 1) and (3 0 4 7)
    assert_row(tab, edge_row(m, CC, 0, 3), {0: 3 / 8, 3: 3 / 8, 2: 1 / 16, 1: 1 / 16, 4: 1 / 16, 7: 1 / 16})


# --------------------------------------------------------------------------------------------------------
# crease edges (docs/rules.md section 4)


@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_crease_edge_midpoint(rules):
    grid = load_mesh("grid3x3")
    tab = table(grid, CC, rules=rules)
    assert_row(tab, edge_row(grid, CC, 0, 1), {0: 1 / 2, 1: 1 / 2})
    assert_row(tab, edge_row(grid, CC, 11, 15), {11: 1 / 2, 15: 1 / 2})
    m = retag(load_mesh("octahedron"), creases=[[0, 2], [2, 1], [1, 3], [3, 0]])
    tab = table(m, LOOP, rules=rules)
    assert_row(tab, edge_row(m, LOOP, 1, 3), {1: 1 / 2, 3: 1 / 2})
    cube = load_mesh("cube_creased")
    tab = table(cube, CC, rules=rules)
    for a, b in cube.edges.edge_verts.tolist():
        assert_row(tab, edge_row(cube, CC, a, b), {a: 1 / 2, b: 1 / 2})


def test_crease_edge_midpoint_level1():
    """The halves of a crease edge are crease edges on the next level too."""
    grid = load_mesh("grid3x3")
    r = make_refiner(grid, CC, levels=2)
    topo = LevelTopology(grid, CC, 1)
    child = grid.num_vertices + grid.num_faces + edge_id(grid, 0, 1)
    assert_row(r.tables[1], topo.edge_row(r.tables[1], 0, child), {0: 1 / 2, child: 1 / 2})


# --------------------------------------------------------------------------------------------------------
# crease-neighbour edge rule at extraordinary boundary vertices (docs/rules.md section 4)


def test_loop_crease_neighbour_k4_level1():
    """tri_halffan vertex 0, k = 4, theta = pi/4. On level 1 its neighbours through non-crease edges are the
    (smooth) children of edges (0,2), (0,3), (0,4): the one-sided rule applies."""
    fan = load_mesh("tri_halffan")
    V = fan.num_vertices
    ch = {j: V + edge_id(fan, 0, j) for j in range(1, 6)}  # level-1 child of edge (0, j)
    r = make_refiner(fan, LOOP, levels=2)
    topo = LevelTopology(fan, LOOP, 1)
    t1 = r.tables[1]
    g = gamma_loop(pi / 4)
    for j in (2, 3, 4):
        assert_row(t1, topo.edge_row(t1, 0, ch[j]),
                   {0: 3 / 4 - g, ch[j]: g, ch[j - 1]: 1 / 8, ch[j + 1]: 1 / 8})
    # literal: gamma = 1/2 - sqrt(2)/8
    assert_row(t1, topo.edge_row(t1, 0, ch[3]),
               {0: 1 / 4 + 2 ** 0.5 / 8, ch[3]: 1 / 2 - 2 ** 0.5 / 8, ch[2]: 1 / 8, ch[4]: 1 / 8})


def test_loop_crease_neighbour_k4_level2():
    """theta stays pi/4 on later levels (k does not change). The level-2 child of a level-1 edge has the id
    of that edge's row in tables[1]."""
    fan = load_mesh("tri_halffan")
    r = make_refiner(fan, LOOP, levels=3)
    V = fan.num_vertices
    ch1 = {j: V + edge_id(fan, 0, j) for j in range(1, 6)}
    topo1 = LevelTopology(fan, LOOP, 1)
    ch2 = {j: topo1.edge_row(r.tables[1], 0, ch1[j]) for j in range(1, 6)}
    topo2 = LevelTopology(fan, LOOP, 2)
    g = gamma_loop(pi / 4)
    t2 = r.tables[2]
    for j in (2, 3, 4):
        assert_row(t2, topo2.edge_row(t2, 0, ch2[j]), {0: 3 / 4 - g, ch2[j]: g, ch2[j - 1]: 1 / 8, ch2[j + 1]: 1 / 8})


def test_loop_crease_neighbour_k2_level1():
    """tri_halffan vertex 2 (2 faces, k = 2, theta = pi/2, gamma = 1/2): on level 1 the edge to the child of
    (0, 2) gets 1/4 on vertex 2, 1/2 on the child, 1/8 on the children of (1, 2) and (2, 3)."""
    fan = load_mesh("tri_halffan")
    V = fan.num_vertices
    c02, c12, c23 = (V + edge_id(fan, *e) for e in [(0, 2), (1, 2), (2, 3)])
    r = make_refiner(fan, LOOP, levels=2)
    topo = LevelTopology(fan, LOOP, 1)
    t1 = r.tables[1]
    assert_row(t1, topo.edge_row(t1, 2, c02), {2: 1 / 4, c02: 1 / 2, c12: 1 / 8, c23: 1 / 8})


def test_loop_crease_neighbour_k2_interior_crease():
    """Octahedron with its equator tagged: vertex 0 has two sectors with k = 2 (theta = pi/2, gamma = 1/2);
    the edge to the (interior) pole 4 lies in faces (0 2 4), (3 0 4)."""
    m = retag(load_mesh("octahedron"), creases=[[0, 2], [2, 1], [1, 3], [3, 0]])
    tab = table(m, LOOP)
    g = gamma_loop(pi / 2)
    assert g == 0.5
    assert_row(tab, edge_row(m, LOOP, 0, 4), {0: 3 / 4 - g, 4: g, 2: 1 / 8, 3: 1 / 8})
    assert_row(tab, edge_row(m, LOOP, 0, 5), {0: 1 / 4, 5: 1 / 2, 2: 1 / 8, 3: 1 / 8})
    assert_row(tab, edge_row(m, LOOP, 1, 4), {1: 1 / 4, 4: 1 / 2, 2: 1 / 8, 3: 1 / 8})
    tab = table(m, LOOP, rules="opensubdiv")
    assert_row(tab, edge_row(m, LOOP, 0, 4), {0: 3 / 8, 4: 3 / 8, 2: 1 / 8, 3: 1 / 8})


@pytest.mark.parametrize("k", [2, 4, 5])
def test_loop_crease_neighbour_sector_level0(k):
    """A boundary vertex with k triangles whose ring vertices p_1..p_k-1 are interior: one-sided rule on the
    control mesh, theta = pi/k whatever the geometry."""
    m = tri_sector(k, 0.8 * pi)
    tab = table(m, LOOP)
    g = gamma_loop(pi / k)
    for i in range(1, k):
        assert_row(tab, edge_row(m, LOOP, 0, 1 + i), {0: 3 / 4 - g, 1 + i: g, i: 1 / 8, 2 + i: 1 / 8})


def test_cc_crease_neighbour_k3_level1():
    """quad_halffan vertex 0, k = 3, theta = pi/3, gamma = 3/8 - cos(pi/3)/4 = 1/4. On level 1 the edge from
    0 to the child of (0, 2) lies in child faces (0, e01, F0, e02) and (0, e02, F1, e03)."""
    qfan = load_mesh("quad_halffan")
    V, F = qfan.num_vertices, qfan.num_faces
    ch = {j: V + F + edge_id(qfan, 0, j) for j in range(1, 5)}
    fc = {f: V + f for f in range(F)}
    r = make_refiner(qfan, CC, levels=2)
    topo = LevelTopology(qfan, CC, 1)
    t1 = r.tables[1]
    g = gamma_cc(pi / 3)
    assert abs(g - 1 / 4) < 1e-15
    assert_row(t1, topo.edge_row(t1, 0, ch[2]),
               {0: 3 / 4 - g, ch[2]: g, ch[1]: 1 / 16, fc[0]: 1 / 16, fc[1]: 1 / 16, ch[3]: 1 / 16})
    assert_row(t1, topo.edge_row(t1, 0, ch[3]),
               {0: 1 / 2, ch[3]: 1 / 4, ch[2]: 1 / 16, fc[1]: 1 / 16, fc[2]: 1 / 16, ch[4]: 1 / 16})


@pytest.mark.parametrize("k", [3, 4, 5])
def test_cc_crease_neighbour_sector_level0(k):
    m = quad_sector(k, 0.8 * pi)
    tab = table(m, CC)
    g = gamma_cc(pi / k)
    p = lambda i: 1 + i  # noqa: E731
    q = lambda i: k + 2 + i  # noqa: E731
    for i in range(1, k):
        assert_row(tab, edge_row(m, CC, 0, p(i)),
                   {0: 3 / 4 - g, p(i): g, p(i - 1): 1 / 16, p(i + 1): 1 / 16, q(i - 1): 1 / 16, q(i): 1 / 16})


def test_crease_neighbour_opensubdiv_uses_smooth_rule():
    # Loop, tri_halffan level 1
    fan = load_mesh("tri_halffan")
    V = fan.num_vertices
    ch = {j: V + edge_id(fan, 0, j) for j in range(1, 6)}
    r = make_refiner(fan, LOOP, levels=2, rules="opensubdiv")
    topo = LevelTopology(fan, LOOP, 1)
    for j in (2, 3, 4):
        assert_row(r.tables[1], topo.edge_row(r.tables[1], 0, ch[j]),
                   {0: 3 / 8, ch[j]: 3 / 8, ch[j - 1]: 1 / 8, ch[j + 1]: 1 / 8})
    # level-0 edges of the fan too (both endpoints are crease vertices there)
    assert_row(r.tables[0], edge_row(fan, LOOP, 0, 3), {0: 3 / 8, 3: 3 / 8, 2: 1 / 8, 4: 1 / 8})
    # CC, quad_halffan level 1 and level 0
    qfan = load_mesh("quad_halffan")
    V, F = qfan.num_vertices, qfan.num_faces
    ch = {j: V + F + edge_id(qfan, 0, j) for j in range(1, 5)}
    r = make_refiner(qfan, CC, levels=2, rules="opensubdiv")
    topo = LevelTopology(qfan, CC, 1)
    assert_row(r.tables[1], topo.edge_row(r.tables[1], 0, ch[2]),
               {0: 3 / 8, ch[2]: 3 / 8, ch[1]: 1 / 16, V: 1 / 16, V + 1: 1 / 16, ch[3]: 1 / 16})
    # level-0 (0, 2) in faces (0 1 5 2) and (0 2 6 3)
    assert_row(r.tables[0], edge_row(qfan, CC, 0, 2), {0: 3 / 8, 2: 3 / 8, 1: 1 / 16, 5: 1 / 16, 6: 1 / 16, 3: 1 / 16})
    # sector meshes with interior ring vertices, corner-tagged too
    for tags in ({}, {"corners": [0]}):
        m = tri_sector(4, 0.5 * pi, **tags)
        assert_row(table(m, LOOP, rules="opensubdiv"), edge_row(m, LOOP, 0, 3),
                   {0: 3 / 8, 3: 3 / 8, 2: 1 / 8, 4: 1 / 8})
        m = quad_sector(3, 0.5 * pi, **tags)
        assert_row(table(m, CC, rules="opensubdiv"), edge_row(m, CC, 0, 2),
                   {0: 3 / 8, 2: 3 / 8, 1: 1 / 16, 3: 1 / 16, 5: 1 / 16, 6: 1 / 16})


# --------------------------------------------------------------------------------------------------------
# convex and concave corner neighbours (docs/rules.md sections 2, 4)


@pytest.mark.parametrize("k,alpha", [(2, pi / 2), (3, pi / 2), (4, 2 * pi / 3), (3, 0.9 * pi), (2, 0.3 * pi)])
def test_loop_convex_corner_neighbour(k, alpha):
    m = tri_sector(k, alpha, corners=[0])
    tab = table(m, LOOP)
    g = gamma_loop(alpha / k)
    assert_row(tab, 0, {0: 1.0})
    for i in range(1, k):
        assert_row(tab, edge_row(m, LOOP, 0, 1 + i), {0: 3 / 4 - g, 1 + i: g, i: 1 / 8, 2 + i: 1 / 8})


@pytest.mark.parametrize("k,alpha", [(2, pi / 2), (3, pi / 2), (4, 2 * pi / 3), (3, 0.9 * pi), (2, 0.3 * pi)])
def test_cc_convex_corner_neighbour(k, alpha):
    m = quad_sector(k, alpha, corners=[0])
    tab = table(m, CC)
    g = gamma_cc(alpha / k)
    p = lambda i: 1 + i  # noqa: E731
    q = lambda i: k + 2 + i  # noqa: E731
    assert_row(tab, 0, {0: 1.0})
    for i in range(1, k):
        assert_row(tab, edge_row(m, CC, 0, p(i)),
                   {0: 3 / 4 - g, p(i): g, p(i - 1): 1 / 16, p(i + 1): 1 / 16, q(i - 1): 1 / 16, q(i): 1 / 16})


def test_convex_corner_neighbour_literal():
    """Loop k = 3 quarter disc: theta = pi/6, gamma = 1/2 - sqrt(3)/8; CC k = 2, alpha = pi/2: theta = pi/4,
    gamma = 3/8 - sqrt(2)/8."""
    m = tri_sector(3, pi / 2, corners=[0])
    g = 1 / 2 - 3 ** 0.5 / 8
    assert_row(table(m, LOOP), edge_row(m, LOOP, 0, 2), {0: 1 / 4 + 3 ** 0.5 / 8, 2: g, 1: 1 / 8, 3: 1 / 8})
    m = quad_sector(2, pi / 2, corners=[0])
    g = 3 / 8 - 2 ** 0.5 / 8
    assert_row(table(m, CC), edge_row(m, CC, 0, 2),
               {0: 3 / 8 + 2 ** 0.5 / 8, 2: g, 1: 1 / 16, 3: 1 / 16, 4: 1 / 16, 5: 1 / 16})


@pytest.mark.parametrize("k,span", [(2, 1.5 * pi), (3, 1.5 * pi), (4, 1.25 * pi), (3, 1.1 * pi)])
def test_loop_concave_corner_neighbour(k, span):
    """A sector occupying span > pi: the measured alpha is 2 pi - span, theta = (2 pi - alpha)/k = span/k."""
    m = tri_sector(k, span, corners=[0], concave=[[0, 2]])
    alpha = 2 * pi - span
    tab = table(m, LOOP)
    g = gamma_loop((2 * pi - alpha) / k)
    assert_row(tab, 0, {0: 1.0})
    for i in range(1, k):
        assert_row(tab, edge_row(m, LOOP, 0, 1 + i), {0: 3 / 4 - g, 1 + i: g, i: 1 / 8, 2 + i: 1 / 8})
    # without the concave tag the same corner is convex: theta = alpha/k
    m = tri_sector(k, span, corners=[0])
    g = gamma_loop(alpha / k)
    assert_row(table(m, LOOP), edge_row(m, LOOP, 0, 2), {0: 3 / 4 - g, 2: g, 1: 1 / 8, 3: 1 / 8})


@pytest.mark.parametrize("k,span", [(2, 1.5 * pi), (3, 1.5 * pi), (4, 1.25 * pi), (3, 1.1 * pi)])
def test_cc_concave_corner_neighbour(k, span):
    m = quad_sector(k, span, corners=[0], concave=[[0, 1 + k - 1]])  # tag named by the last inner edge
    alpha = 2 * pi - span
    tab = table(m, CC)
    g = gamma_cc((2 * pi - alpha) / k)
    p = lambda i: 1 + i  # noqa: E731
    q = lambda i: k + 2 + i  # noqa: E731
    for i in range(1, k):
        assert_row(tab, edge_row(m, CC, 0, p(i)),
                   {0: 3 / 4 - g, p(i): g, p(i - 1): 1 / 16, p(i + 1): 1 / 16, q(i - 1): 1 / 16, q(i): 1 / 16})


@pytest.mark.parametrize("concave", [False, True])
def test_cc_lshape_corner_neighbour(concave):
    """quad_lshape vertex 10 = (2,2,0.5): 3 faces, crease edges to 11 = (3,2,0) and 14 = (2,3,0), so
    cos(alpha) = ((1,0,-.5).(0,1,-.5))/1.25 = 0.2. Inner edges (10, 6) and (10, 9) end at interior vertices."""
    lshape = load_mesh("quad_lshape")
    tags = {"corners": [10]}
    if concave:
        tags["concave"] = [[10, 6]]
    m = retag(lshape, **tags)
    alpha = acos(0.2)
    theta = (2 * pi - alpha) / 3 if concave else alpha / 3
    g = gamma_cc(theta)
    tab = table(m, CC)
    assert_row(tab, 10, {10: 1.0})
    # (10, 6) in faces (5 6 10 9) and (6 7 11 10); (10, 9) in faces (5 6 10 9) and (9 10 14 13)
    assert_row(tab, edge_row(m, CC, 10, 6), {10: 3 / 4 - g, 6: g, 5: 1 / 16, 9: 1 / 16, 7: 1 / 16, 11: 1 / 16})
    assert_row(tab, edge_row(m, CC, 10, 9), {10: 3 / 4 - g, 9: g, 5: 1 / 16, 6: 1 / 16, 13: 1 / 16, 14: 1 / 16})


def test_cc_lshape_untagged_is_crease_k3():
    """Without a corner tag, vertex 10 of quad_lshape is a smooth crease with k = 3: theta = pi/3."""
    lshape = load_mesh("quad_lshape")
    tab = table(lshape, CC)
    g = gamma_cc(pi / 3)
    assert_row(tab, 10, {10: 3 / 4, 11: 1 / 8, 14: 1 / 8})
    assert_row(tab, edge_row(lshape, CC, 10, 6), {10: 3 / 4 - g, 6: g, 5: 1 / 16, 9: 1 / 16, 7: 1 / 16, 11: 1 / 16})


def _angle(points, c, a, b):
    u, w = points[a] - points[c], points[b] - points[c]
    return acos(float(np.dot(u, w) / np.linalg.norm(u) / np.linalg.norm(w)))


def test_loop_concave_tag_affects_only_its_sector():
    """Octahedron with the equator 0-2-1-3-0 tagged and vertex 0 = (1,0,0) tagged corner: two sectors of
    k = 2, {(0 2 4), (3 0 4)} and {(2 0 5), (0 3 5)}, alpha = pi/2 between the crease edges to 2 and 3.
    Tagging the upper sector concave gives it theta = (2 pi - alpha)/2 = 3 pi/4; the lower one stays convex,
    theta = alpha/2 = pi/4."""
    base = retag(load_mesh("octahedron"), creases=[[0, 2], [2, 1], [1, 3], [3, 0]])
    alpha = _angle(base.points, 0, 2, 3)
    assert abs(alpha - pi / 2) < 1e-12
    tags = dict(creases=base.creases, corners=[0])
    for concave, theta_up in ((None, alpha / 2), ([[0, 4]], (2 * pi - alpha) / 2)):
        m = retag(base, concave=concave, **tags)
        tab = table(m, LOOP)
        g_up, g_down = gamma_loop(theta_up), gamma_loop(alpha / 2)
        assert_row(tab, 0, {0: 1.0})
        assert_row(tab, edge_row(m, LOOP, 0, 4), {0: 3 / 4 - g_up, 4: g_up, 2: 1 / 8, 3: 1 / 8})
        assert_row(tab, edge_row(m, LOOP, 0, 5), {0: 3 / 4 - g_down, 5: g_down, 2: 1 / 8, 3: 1 / 8})


def test_cc_concave_tag_affects_only_its_sector():
    """grid3x3 with the vertical line 1-5-9-13 tagged and interior vertex 5 tagged corner: sectors
    left {(0 1 5 4), (4 5 9 8)} and right {(1 2 6 5), (5 6 10 9)}, k = 2 each, alpha measured between 5->1
    and 5->9. Tag the right sector concave: edge (5, 6) (6 interior) gets theta = (2 pi - alpha)/2; the left
    edge (5, 4) joins corner 5 (convex, theta = alpha/2) and crease vertex 4 (k = 2, gamma = 3/8): average."""
    grid = load_mesh("grid3x3")
    tags = dict(creases=[[1, 5], [5, 9], [9, 13]], corners=[5])
    alpha = _angle(grid.points, 5, 1, 9)
    for concave, theta_right in ((None, alpha / 2), ([[5, 6]], (2 * pi - alpha) / 2)):
        m = retag(grid, concave=concave, **tags)
        tab = table(m, CC)
        g_r, g_l = gamma_cc(theta_right), gamma_cc(alpha / 2)
        assert_row(tab, 5, {5: 1.0})
        assert_row(tab, edge_row(m, CC, 5, 6), {5: 3 / 4 - g_r, 6: g_r, 1: 1 / 16, 2: 1 / 16, 10: 1 / 16, 9: 1 / 16})
        assert_row(tab, edge_row(m, CC, 5, 4), {5: ((3 / 4 - g_l) + 3 / 8) / 2, 4: (g_l + 3 / 8) / 2,
                                                0: 1 / 16, 1: 1 / 16, 9: 1 / 16, 8: 1 / 16})
        # the tagged line: vertex 9 is a crease vertex (neighbours 5, 13), its edges are midpoints
        assert_row(tab, 9, {9: 3 / 4, 5: 1 / 8, 13: 1 / 8})
        assert_row(tab, edge_row(m, CC, 5, 9), {5: 1 / 2, 9: 1 / 2})


@pytest.mark.parametrize("scheme", [LOOP, CC])
def test_level1_regular_crease_vertices_use_standard_edge_rule(scheme):
    """On level 1 the children of boundary edges are regular crease vertices (Loop k = 3, CC k = 2, so
    gamma = 3/8): the non-crease level-1 edge from such a child into the interior gets 3/8 on both endpoints
    (CC: 1/16 on the 4 other quad vertices; Loop: 1/8 on the 2 opposite vertices)."""
    mesh = load_mesh("grid3x3" if scheme == CC else "tri_hexfan")
    r = make_refiner(mesh, scheme, levels=2)
    t1 = r.tables[1]
    topo0 = LevelTopology(mesh, scheme, 0)
    topo1 = LevelTopology(mesh, scheme, 1)
    V0 = mesh.num_vertices + (mesh.num_faces if scheme == CC else 0)
    boundary_children = {V0 + e for e, (a, b) in enumerate(mesh.edges.edge_verts.tolist())
                         if len(topo0.edge_faces(a, b)) == 1}
    assert boundary_children
    checked = 0
    for c in sorted(boundary_children):
        inner = [u for u in topo1.neighbours(c) if u >= mesh.num_vertices and u not in boundary_children]
        assert len(inner) == (1 if scheme == CC else 2)
        for u in inner:
            faces = topo1.edge_faces(c, u)
            assert len(faces) == 2
            wing = 1 / 16 if scheme == CC else 1 / 8
            expected = {c: 3 / 8, u: 3 / 8}
            for f in faces:
                expected.update({x: wing for x in f if x not in (c, u)})
            assert_row(t1, topo1.edge_row(t1, c, u), expected)
            checked += 1
    assert checked


def test_corner_theta_is_fixed_on_later_levels():
    """alpha is measured once on the control mesh; on level 1 the corner's sector keeps theta = alpha/k."""
    k, alpha = 3, pi / 2
    m = tri_sector(k, alpha, corners=[0])
    r = make_refiner(m, LOOP, levels=2)
    topo = LevelTopology(m, LOOP, 1)
    V = m.num_vertices
    ch = {i: V + edge_id(m, 0, 1 + i) for i in range(k + 1)}
    g = gamma_loop(alpha / k)
    t1 = r.tables[1]
    for i in (1, 2):
        assert_row(t1, topo.edge_row(t1, 0, ch[i]), {0: 3 / 4 - g, ch[i]: g, ch[i - 1]: 1 / 8, ch[i + 1]: 1 / 8})


# --------------------------------------------------------------------------------------------------------
# both endpoints tagged: the average of the two one-sided rules (docs/rules.md section 1)


def test_loop_both_endpoints_tagged_average():
    """tri_halffan on the control mesh: vertex 0 (k = 4, gamma_0 = 1/2 - cos(pi/4)/4) and vertex 3
    (k = 2, gamma_3 = 1/2) are both crease vertices; edge (0, 3) lies in faces (0 2 3), (0 3 4)."""
    fan = load_mesh("tri_halffan")
    g0, g3 = gamma_loop(pi / 4), gamma_loop(pi / 2)
    rule0 = {0: 3 / 4 - g0, 3: g0}
    rule3 = {3: 3 / 4 - g3, 0: g3}
    expected = {0: (rule0[0] + rule3[0]) / 2, 3: (rule0[3] + rule3[3]) / 2, 2: 1 / 8, 4: 1 / 8}
    tab = table(fan, LOOP)
    assert_row(tab, edge_row(fan, LOOP, 0, 3), expected)
    # edge (0, 2): vertex 2 has k = 2 as well; opposite vertices 1 and 3
    assert_row(tab, edge_row(fan, LOOP, 0, 2), {0: expected[0], 2: expected[3], 1: 1 / 8, 3: 1 / 8})


def test_cc_both_endpoints_tagged_average():
    """quad_halffan on the control mesh: vertex 0 (k = 3, gamma_0 = 1/4) and vertex 2 (k = 2, gamma_2 = 3/8,
    the standard rule) are crease vertices; (0, 2) lies in faces (0 1 5 2), (0 2 6 3)."""
    qfan = load_mesh("quad_halffan")
    g0, g2 = gamma_cc(pi / 3), gamma_cc(pi / 2)
    w0 = ((3 / 4 - g0) + g2) / 2
    w2 = (g0 + (3 / 4 - g2)) / 2
    assert abs(w0 - 7 / 16) < 1e-15 and abs(w2 - 5 / 16) < 1e-15
    tab = table(qfan, CC)
    assert_row(tab, edge_row(qfan, CC, 0, 2), {0: w0, 2: w2, 1: 1 / 16, 5: 1 / 16, 6: 1 / 16, 3: 1 / 16})


def test_cc_corner_and_crease_endpoints_average():
    """quad_halffan with vertex 0 tagged corner: its sector (k = 3) is convex with alpha measured between
    (1,0,-1/4) and (-1,0,-1/4); edge (0, 3) joins it to crease vertex 3 (k = 2, standard)."""
    qfan = load_mesh("quad_halffan")
    m = retag(qfan, corners=[0])
    alpha = acos((-1 + 1 / 16) / (1 + 1 / 16))
    g0, g3 = gamma_cc(alpha / 3), gamma_cc(pi / 2)
    w0 = ((3 / 4 - g0) + g3) / 2
    w3 = (g0 + (3 / 4 - g3)) / 2
    # (0, 3) in faces (0 2 6 3) and (0 3 7 4)
    assert_row(table(m, CC), edge_row(m, CC, 0, 3), {0: w0, 3: w3, 2: 1 / 16, 6: 1 / 16, 7: 1 / 16, 4: 1 / 16})


def test_cc_two_corners_average():
    """quad_halffan with vertices 0 and 2 tagged corners: the inner edge (0, 2) joins two convex corners,
    vertex 0's sector (k = 3, crease edges to 1 and 4) and vertex 2's sector (k = 2, crease edges to 5, 6).
    Each alpha is the measured angle between the sector's two crease edges."""
    qfan = load_mesh("quad_halffan")
    m = retag(qfan, corners=[0, 2])
    P = qfan.points

    def angle(c, a, b):
        u, w = P[a] - P[c], P[b] - P[c]
        return acos(float(np.dot(u, w) / np.linalg.norm(u) / np.linalg.norm(w)))

    g0 = gamma_cc(angle(0, 1, 4) / 3)
    g2 = gamma_cc(angle(2, 5, 6) / 2)
    w0 = ((3 / 4 - g0) + g2) / 2
    w2 = (g0 + (3 / 4 - g2)) / 2
    tab = table(m, CC)
    assert_row(tab, 2, {2: 1.0})
    assert_row(tab, edge_row(m, CC, 0, 2), {0: w0, 2: w2, 1: 1 / 16, 5: 1 / 16, 6: 1 / 16, 3: 1 / 16})


# --------------------------------------------------------------------------------------------------------
# regular boundaries: piecewise-smooth equals opensubdiv (gamma = 3/8)


def test_cc_regular_boundary_inner_edge_is_standard():
    """grid3x3: boundary vertex 1 has k = 2; its inner edge (1, 5) gets 3/8, 3/8, 1/16 x 4 in both rule sets."""
    grid = load_mesh("grid3x3")
    assert abs(gamma_cc(pi / 2) - 3 / 8) < 1e-16
    for rules in ("piecewise-smooth", "opensubdiv"):
        tab = table(grid, CC, rules=rules)
        # (1, 5) in faces (0 1 5 4) and (1 2 6 5)
        assert_row(tab, edge_row(grid, CC, 1, 5), {1: 3 / 8, 5: 3 / 8, 0: 1 / 16, 4: 1 / 16, 2: 1 / 16, 6: 1 / 16})


def test_cc_regular_boundary_tables_equal_opensubdiv():
    grid = load_mesh("grid3x3")
    a = make_refiner(grid, CC, levels=2, rules="piecewise-smooth")
    b = make_refiner(grid, CC, levels=2, rules="opensubdiv")
    from conftest import dense

    for ta, tb in zip(a.tables, b.tables):
        np.testing.assert_allclose(dense(ta), dense(tb), atol=TOL, rtol=0)


def test_loop_regular_boundary_inner_edge_is_standard():
    """tri_grid3x3: boundary vertex 1 = (1,0) has k = 3 faces (0 1 5), (1 2 6), (1 6 5); gamma = 3/8."""
    grid = load_mesh("tri_grid3x3")
    assert abs(gamma_loop(pi / 3) - 3 / 8) < 1e-16
    for rules in ("piecewise-smooth", "opensubdiv"):
        tab = table(grid, LOOP, rules=rules)
        # (1, 5) in (0 1 5) and (1 6 5): opposite 0, 6; (1, 6) in (1 2 6) and (1 6 5): opposite 2, 5
        assert_row(tab, edge_row(grid, LOOP, 1, 5), {1: 3 / 8, 5: 3 / 8, 0: 1 / 8, 6: 1 / 8})
        assert_row(tab, edge_row(grid, LOOP, 1, 6), {1: 3 / 8, 6: 3 / 8, 2: 1 / 8, 5: 1 / 8})


def test_loop_two_face_boundary_corner_differs_from_opensubdiv():
    """tri_grid3x3 vertex 0 = (0,0) has 2 faces (k = 2, gamma = 1/2): its inner edge (0, 5) to the interior
    vertex 5 follows the crease-neighbour rule (1/4, 1/2), where OpenSubdiv keeps 3/8, 3/8."""
    grid = load_mesh("tri_grid3x3")
    # (0, 5) in faces (0 1 5) and (0 5 4): opposite 1 and 4
    assert_row(table(grid, LOOP), edge_row(grid, LOOP, 0, 5), {0: 1 / 4, 5: 1 / 2, 1: 1 / 8, 4: 1 / 8})
    assert_row(table(grid, LOOP, rules="opensubdiv"), edge_row(grid, LOOP, 0, 5),
               {0: 3 / 8, 5: 3 / 8, 1: 1 / 8, 4: 1 / 8})


# --------------------------------------------------------------------------------------------------------
# affine invariance: every row of every table sums to 1


def _all_meshes():
    import os

    names = sorted(f[:-4] for f in os.listdir(MESHES) if f.endswith(".obj"))
    out = [(n, load_mesh(n)) for n in names]
    lshape = load_mesh("quad_lshape")
    out.append(("quad_lshape+concave", retag(lshape, corners=[10], concave=[[10, 6]])))
    out.append(("quad_lshape+corner", retag(lshape, corners=[10])))
    out.append(("tri_sector_concave", tri_sector(3, 1.5 * pi, corners=[0], concave=[[0, 2]])))
    out.append(("quad_sector_convex", quad_sector(3, 0.5 * pi, corners=[0])))
    out.append(("octahedron+equator", retag(load_mesh("octahedron"), creases=[[0, 2], [2, 1], [1, 3], [3, 0]])))
    return out


@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
@pytest.mark.parametrize("scheme", [LOOP, CC])
def test_every_row_sums_to_one(scheme, rules):
    checked = 0
    for name, mesh in _all_meshes():
        for boundary in ("edge-and-corner", "edge-only"):
            r = make_refiner(mesh, scheme, levels=2, rules=rules, boundary=boundary)
            for level, t in enumerate(r.tables):
                assert np.all(np.isfinite(t.weights)), (name, level)
                assert np.all((t.indices >= 0) & (t.indices < t.num_sources)), (name, level)
                sizes = np.diff(t.offsets.astype(np.int64))
                assert np.all(sizes > 0), (name, level)
                sums = np.add.reduceat(t.weights, t.offsets[:-1].astype(np.int64))
                worst = int(np.argmax(np.abs(sums - 1)))
                assert abs(sums[worst] - 1) < TOL, f"{name} {boundary} level {level} row {worst}: {t.row(worst)}"
                checked += 1
    assert checked == 2 * 2 * len(_all_meshes())


@pytest.mark.parametrize("scheme", [LOOP, CC])
def test_table_shapes(scheme):
    """Row counts: V + E for Loop, V + F + E for Catmull-Clark; sources are the parent level's vertices."""
    m = load_mesh("cube") if scheme == CC else load_mesh("icosahedron")
    r = make_refiner(m, scheme, levels=2)
    t0 = r.tables[0]
    V, F, E = m.num_vertices, m.num_faces, m.num_edges
    assert t0.num_sources == V
    assert t0.num_rows == (V + F + E if scheme == CC else V + E)
    assert r.tables[1].num_sources == t0.num_rows


# --------------------------------------------------------------------------------------------------------
# the explicit rows of a uniform level: only the irregular rows, computed on their own


def _semi_sharp_grid():
    """A 6 x 6 grid of quads (open boundary) with semi-sharp creases and a semi-sharp corner inside."""
    n = 6
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")

    def vid(a, b):
        return a * (n + 1) + b

    quads = np.stack([vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)], axis=-1).reshape(-1)
    gx, gy = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    pts = np.stack([gx, gy, 0.1 * np.sin(gx * gy)], axis=-1).reshape(-1, 3)
    creases = np.array([[vid(2, 1), vid(2, 2)], [vid(2, 2), vid(2, 3)], [vid(2, 3), vid(2, 4)], [vid(4, 2), vid(4, 3)]])
    return ws.Mesh(pts, np.full(n * n, 4), quads, creases=creases, crease_sharpness=[2.5, 1.0, 3.0, 10.0],
                   corners=[vid(3, 3)], corner_sharpness=[1.5])


@pytest.mark.parametrize("scheme", [CC, LOOP])
@pytest.mark.parametrize("rules", ["opensubdiv", "piecewise-smooth"])
@pytest.mark.parametrize("crease_method", ["uniform", "chaikin"])
def test_explicit_rows_of_a_uniform_level_are_the_full_tables_rows(scheme, rules, crease_method):
    """build_regular's explicit stencils (the rows the regular kernels do not compute: boundary, crease, corner
    and crease-neighbour rows) are built from those rows alone; each must be bitwise the same row of the full
    stencil table of the level, on every level of a mesh with boundaries, semi-sharp creases that decay over
    the steps, and (piecewise-smooth) crease-neighbour edges."""
    from warp_subdiv.options import Options
    from warp_subdiv.tables.stencil_builder import build_regular, build_stencils
    from warp_subdiv.topology import base_level, refine_level

    mesh = _semi_sharp_grid() if scheme == CC else load_mesh("tri_grid3x3")
    if scheme == LOOP:  # tags on the triangle grid too
        mesh = ws.Mesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices,
                       creases=mesh.edges.edge_verts[:3], crease_sharpness=[1.5, 10.0, 2.0])
    o = Options(scheme=scheme, rules=rules, crease_method=crease_method)
    level = base_level(mesh, o.scheme, o.boundary, o.rules, o.triangulate, crease_method=o.crease_method)
    checked = 0
    for _ in range(4):
        full = build_stencils(level, o.rules, o.loop_beta)
        part = build_regular(level, o.rules, o.loop_beta).explicit
        assert 0 < part.num_rows < full.num_rows
        for i, row in enumerate(part.rows):
            a, b = full.offsets[row], full.offsets[row + 1]
            c, d = part.offsets[i], part.offsets[i + 1]
            np.testing.assert_array_equal(part.indices[c:d], full.indices[a:b])
            np.testing.assert_array_equal(part.weights[c:d], full.weights[a:b])
        checked += part.num_rows
        level = refine_level(level)
    assert checked > 100
