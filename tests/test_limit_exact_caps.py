"""warp_subdiv.LimitSurface inside the end caps at extraordinary boundary and crease vertices
(warp_subdiv.limit.exact_caps, docs/limit-surface.md "How it is computed, and how exact").

There the end caps are replaced by exact evaluation (the self-similar two-ring step of the library's own rules,
its powers, and the regular patches two levels below each cap's parent face), so:

* the surface at depth 8 equals the surface at depth 12 inside the depth-8 end caps (before, under OpenSubdiv's
  rules, normals there were off by up to 1: the surface has no tangent plane at such a vertex from 5
  Catmull-Clark or 7 Loop faces on, and a polynomial cap cannot follow it);
* points deeper than 2^-12 equal the surface the library's local refinement builds 20 levels deep, where they
  lie in regular patches of refined points (no end cap, no step matrix involved);
* vertex data takes the positions' weights there too (data equal to the points gives the points bit for bit);
* against OpenSubdiv's Bfr at approximation level 10 (exact there: its regular patches) in the depth-8 caps.
"""
import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv.limit.patches import END_CAP, REGULAR

from test_limit_surface import _peer


def fan_mesh(n, triangles=False, rings=2, crease=False, seed=0):
    """Vertex 0 with n faces (quads or triangles; each face's corner 0) and ``rings`` rings of faces around it,
    random heights: a boundary vertex spanning an angle below 2 pi, or with ``crease`` an interior vertex whose
    faces close around it, with infinitely sharp creases along two of its edges (sectors of 2 and n - 2 faces)."""
    rng = np.random.default_rng(seed)
    angle = 2 * np.pi if crease else np.pi * min(1.6, 0.3 * n + 0.4)
    step = 1 if triangles else 2
    spokes = step * n + (0 if crease else 1)
    points, index = [(0.0, 0.0, 0.0)], {}
    for r in range(1, rings + 1):
        for j in range(spokes):
            a = angle * j / (step * n)
            index[r, j] = len(points)
            points.append((r * np.cos(a), r * np.sin(a), 0.15 * rng.standard_normal()))

    def at(r, j):
        return index[r, j % spokes]

    faces = [[0] + [at(1, step * k + i) for i in range(step + 1)] for k in range(n)]
    for r in range(1, rings):
        for j in range(spokes if crease else spokes - 1):
            q = [at(r, j), at(r + 1, j), at(r + 1, j + 1), at(r, j + 1)]
            faces += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] if triangles else [q]
    tags = {}
    if crease:
        tags = dict(creases=[[0, at(1, 0)], [0, at(1, 2 * step)]], crease_sharpness=[10.0, 10.0])
    return ws.Mesh(np.array(points), [len(f) for f in faces], np.concatenate(faces), **tags)


def cap_queries(faces, low, high, per_face, rng, triangles):
    """Random (face, u, v) at 2^-high .. 2^-low from corner 0 of each of ``faces`` (log-uniform; the distance
    is max(u, v) on quads, u + v on triangles)."""
    shape = (len(faces), per_face)
    r = 2.0 ** -rng.uniform(low, high, shape)
    a = rng.uniform(0.0, 1.0, shape)
    if triangles:
        u, v = r * a, r * (1.0 - a)
    else:
        swap = rng.random(shape) < 0.5
        u, v = np.where(swap, r * a, r), np.where(swap, r, r * a)
    return np.repeat(np.asarray(faces), per_face), u.ravel(), v.ravel()


def assert_same_surface(a, b, scale, position_tol=1e-12, tangent_tol=1e-10):
    """Points, normals and derivatives (relative to their size) of two evaluations agree."""
    assert np.abs(a.points - b.points).max() <= position_tol * scale
    assert np.abs(a.normals - b.normals).max() <= tangent_tol
    for key in ("du", "dv"):
        x, y = getattr(a, key), getattr(b, key)
        assert (np.linalg.norm(x - y, axis=1) / np.linalg.norm(y, axis=1)).max() <= tangent_tol, key
    if a.duu is not None:
        for key in ("duu", "duv", "dvv"):
            x, y = getattr(a, key), getattr(b, key)
            size = np.maximum(np.linalg.norm(y, axis=1), np.linalg.norm(b.du, axis=1))
            assert (np.linalg.norm(x - y, axis=1) / size).max() <= 1e3 * tangent_tol, key


#: (scheme, faces at the vertex, crease, the faces whose caps are exact). Loop's two faces along the boundary
#: keep their end caps (their grandchildren along the boundary touch it at one vertex: not polynomial).
CASES = [("catmull-clark", 4, False, None), ("catmull-clark", 6, False, None), ("catmull-clark", 8, False, None),
         ("catmull-clark", 6, True, None), ("loop", 7, False, slice(1, 6))]


@pytest.mark.parametrize("rules", ["opensubdiv", "piecewise-smooth"])
@pytest.mark.parametrize("scheme,n,crease,exact_faces", CASES)
def test_exact_caps_equal_the_deeper_surface(scheme, n, crease, exact_faces, rules):
    """Inside the depth-8 end caps but outside the depth-12 ones, depth 8 and depth 12 agree to round-off in
    points, normals, first and second derivatives; exactly at the vertex the end cap still answers."""
    triangles = scheme == "loop"
    mesh = fan_mesh(n, triangles, crease=crease)
    coarse = ws.LimitSurface(mesh, scheme=scheme, rules=rules, depth=8)
    fine = ws.LimitSurface(mesh, scheme=scheme, rules=rules, depth=12)
    faces = np.arange(n)[exact_faces if exact_faces is not None else slice(None)]
    assert coarse.tree.stats["exact_end_caps"] >= 4 * len(faces)
    rng = np.random.default_rng(5)
    f, u, v = cap_queries(faces, 7.2, 11.8, 40, rng, triangles)
    a, b = coarse.evaluate(f, u, v, derivatives=2), fine.evaluate(f, u, v, derivatives=2)
    assert (coarse.tree.patch_kind[a.patch] == END_CAP).mean() > 0.5
    assert_same_surface(a, b, np.abs(mesh.points).max())
    at_vertex = coarse.evaluate(faces, np.zeros(len(faces)), np.zeros(len(faces)))
    refined = ws.refine(mesh, 1, scheme=scheme, rules=rules, precision="float64").limit_points()
    np.testing.assert_allclose(at_vertex.points, np.repeat(refined[:1], len(faces), 0), atol=1e-12)
    assert np.all(coarse.tree.patch_kind[at_vertex.patch] == END_CAP)


@pytest.mark.parametrize("scheme,n,crease,exact_faces", [CASES[1], CASES[3], CASES[4]])
def test_deep_points_equal_the_locally_refined_surface(scheme, n, crease, exact_faces):
    """Points 2^-13 .. 2^-19 from the vertex, evaluated from the depth-8 tree (powers of the step matrix), equal
    the depth-20 tree, where they lie in regular patches of the library's refined points."""
    triangles = scheme == "loop"
    mesh = fan_mesh(n, triangles, crease=crease)
    coarse = ws.LimitSurface(mesh, scheme=scheme, rules="opensubdiv", depth=8)
    reference = ws.LimitSurface(mesh, scheme=scheme, rules="opensubdiv", depth=20)
    faces = np.arange(n)[exact_faces if exact_faces is not None else slice(None)]
    rng = np.random.default_rng(7)
    f, u, v = cap_queries(faces, 13.0, 19.0, 25, rng, triangles)
    a, b = coarse.evaluate(f, u, v), reference.evaluate(f, u, v)
    assert np.all(coarse.tree.patch_kind[a.patch] == END_CAP)
    assert np.all(reference.tree.patch_kind[b.patch] == REGULAR)
    assert_same_surface(a, b, np.abs(mesh.points).max(), tangent_tol=1e-9)


def test_vertex_data_in_exact_caps():
    """evaluate_data inside exact caps: data equal to the points gives the points bit for bit, and an affine
    image of the points gives that image of the points (and of their derivatives)."""
    mesh = fan_mesh(6)
    surface = ws.LimitSurface(mesh, scheme="catmull-clark", rules="opensubdiv", depth=6)
    rng = np.random.default_rng(3)
    f, u, v = cap_queries(np.arange(6), 5.5, 14.0, 20, rng, False)
    ev = surface.evaluate(f, u, v)
    assert (surface.tree.patch_kind[ev.patch] == END_CAP).all()
    same = surface.evaluate_data(mesh.points, f, u, v, derivatives=1)
    np.testing.assert_array_equal(same.values, ev.points)
    np.testing.assert_array_equal(same.du, ev.du)
    A = np.array([[1.0, 2.0, 0.5], [0.0, -1.0, 3.0]])
    data = mesh.points @ A.T + np.array([4.0, -2.0])
    got = surface.evaluate_data(data, f, u, v, derivatives=1)
    np.testing.assert_allclose(got.values, ev.points @ A.T + np.array([4.0, -2.0]), atol=1e-12)
    np.testing.assert_allclose(got.dv, ev.dv @ A.T, rtol=1e-10, atol=1e-10 * np.abs(ev.dv).max())


@pytest.mark.parametrize("n", [4, 6, 8])
def test_exact_caps_against_bfr(n):
    """OpenSubdiv's Bfr at approximation level 10 (regular patches beyond 2^-10 of the vertex, exact there):
    LimitSurface at its default depth 8 agrees inside its end caps, 2^-8 .. 2^-10 from a boundary vertex with
    4, 6 and 8 faces."""
    peer = _peer()
    mesh = fan_mesh(n)
    surface = ws.LimitSurface(mesh, scheme="catmull-clark", rules="opensubdiv")
    rng = np.random.default_rng(11)
    f, u, v = cap_queries(np.arange(n), 8.1, 9.9, 30, rng, False)
    ev = surface.evaluate(f, u, v)
    assert (surface.tree.patch_kind[ev.patch] == END_CAP).all()
    rec = peer.mesh_request(mesh, 0, scheme="catmark")
    b = peer.bfr_evaluate(rec, f, np.c_[u, v], approx_smooth=10, approx_sharp=10)
    assert b["valid"].all()
    scale = np.abs(mesh.points).max()
    assert np.abs(ev.points - b["points"]).max() <= 1e-12 * scale
    for key in ("du", "dv"):
        rel = np.linalg.norm(getattr(ev, key) - b[key], axis=1) / np.linalg.norm(b[key], axis=1)
        assert rel.max() <= 1e-11, key


def test_exact_caps_only_where_the_structure_repeats():
    """A semi-sharp edge at the vertex whose sharpness outlives the tree's depth, or a prescribed normal at the
    vertex, keeps the end caps; a sharpness that decays above the depth does not (and is exact there)."""
    base = fan_mesh(6)
    rng = np.random.default_rng(2)
    f, u, v = cap_queries(np.arange(6), 7.2, 11.8, 10, rng, False)

    def with_tags(**tags):
        return ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, **tags)

    inner_edge = [[0, int(base.face_vertex_indices[3])]]  # to face 0's last corner: an edge inside the fan
    for sharpness, exact in ((7.5, False), (3.0, True)):
        mesh = with_tags(creases=inner_edge, crease_sharpness=[sharpness])
        surface = ws.LimitSurface(mesh, scheme="catmull-clark", rules="opensubdiv", depth=8)
        assert (surface.tree.stats["exact_end_caps"] > 0) == exact, sharpness
        if exact:
            fine = ws.LimitSurface(mesh, scheme="catmull-clark", rules="opensubdiv", depth=12)
            assert_same_surface(surface.evaluate(f, u, v), fine.evaluate(f, u, v), np.abs(mesh.points).max())
    normal = with_tags(normals=([0], [[0.0, 0.0, 1.0]]))
    surface = ws.LimitSurface(normal, scheme="catmull-clark", rules="piecewise-smooth", depth=8)
    assert surface.tree.stats["exact_end_caps"] == 0
    assert np.isfinite(surface.evaluate(f, u, v).normals).all()
