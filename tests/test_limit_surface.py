"""warp_subdiv.LimitSurface: limit evaluation at arbitrary (face, u, v) (README "Limit surface").

* regular regions against closed-form patches: the uniform bicubic B-spline (Catmull-Clark) and the quartic box
  spline (Loop), whose Bezier net is derived here again from Loop's regular stencils and de Casteljau
  subdivision (the unique refinable polynomial), positions and first and second derivatives;
* finite differences of positions against the returned derivatives, and of first against second derivatives;
* consistency with the uniformly refined mesh: at the parameters of level-2 vertices (face corners, edge
  middles, face centres of level 1 and 2) ``evaluate`` equals ``Refined.limit_points()``, and its normals
  ``Refined.limit_normals()`` where a vertex has one sector, for both rule sets and with the paper's projections
  (flatness, concave corners, prescribed normals) on;
* the parameterisation of n-gons and Loop polygons (``vertex_uv`` lands on the control vertices' limits);
* the end caps' error bound (README), errors, and every device present;
* a differential test against OpenSubdiv's Bfr (``peers/osd/bfr_peer.cpp``; skipped without libosd-dev) on the
  regression shapes and on random tagged meshes, ``rules="opensubdiv"``;
* vertex data (``evaluate_data``): subdivided with the points' weights (bitwise the points for data = points,
  linear, equal to limit_points of refined data under the piecewise-smooth rules);
* face-varying channels (``evaluate_face_varying``): equal to ``Refiner.limit_face_varying`` at refined corners
  under every interpolation mode, the modes' behaviour on seams, and Bfr's face-varying surfaces.
"""
import glob
import os
import sys
import warnings

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import DATA, load_mesh
from warp_subdiv import SubdivInputError
from warp_subdiv.tables.hierarchy import Hierarchy
from warp_subdiv.limit.bezier import LOOP_BEZIER, TRI_BEZIER_INDEX, TRI_RING
from warp_subdiv.limit.patches import END_CAP
from warp_subdiv.io.obj import read_obj
from warp_subdiv.topology import base_level, refine_level

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.append(ROOT)

RNG_SEED = 13


# ------------------------------------------------------------------------------------------ helpers
def refined_face_params(hierarchy: Hierarchy, level: int):
    """(control face (F,), corner (u, v) (F, n, 2)) of every face of ``level`` in its level-0 face's frame, from
    the hierarchy's parentage (independent of the patch tree): quads [0, 1]^2, triangles barycentric, an
    n-gon's sub-faces in their own unit squares (returned with the sub-face index)."""
    o = hierarchy.options
    n = 4 if o.scheme == "catmull-clark" else 3
    base = hierarchy.parentage
    F0 = len(base.base_face_hole)
    unit = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) if n == 4 else np.array([[0, 0], [1, 0], [0, 1]], float)
    uv = np.tile(unit, (F0, 1, 1))
    face = np.arange(F0)
    sub = np.full(F0, -1)
    sizes = hierarchy.base_face_size
    for lv in range(1, level + 1):
        parent, slot = hierarchy.face_parent(lv)
        rot = hierarchy.face_rotation(lv)
        P = uv[parent]
        m = len(parent)
        out = np.zeros((m, n, 2))
        rows = np.arange(m)
        if n == 4:
            polygon = np.zeros(m, bool)
            if lv == 1 and sizes != 4:  # n-gon: the child at corner j is sub-face j's unit square
                polygon = np.asarray(hierarchy.parentage.refinement(1).face_sizes())[parent] != 4
            j = slot
            pj, pn, pp, centre = P[rows, j % 4], P[rows, (j + 1) % 4], P[rows, (j - 1) % 4], P.mean(1)
            values = [pj, (pj + pn) / 2, centre, (pj + pp) / 2]
            for i in range(4):
                out[rows, (rot + i) % 4] = values[i]
            out[polygon] = unit  # rotation r = 0: corner 0 the vertex child
            sub = np.where(polygon, slot, sub[parent])
        else:
            corner = slot < 3
            j = np.where(corner, slot, 0)
            pj, pn, pp = P[rows, j], P[rows, (j + 1) % 3], P[rows, (j + 2) % 3]
            values = [pj, (pj + pn) / 2, (pj + pp) / 2]
            for i in range(3):
                out[rows, (rot + i) % 3] = np.where(corner[:, None], values[i], out[rows, (rot + i) % 3])
            for mm in range(3):
                e = (mm + 1) % 3
                out[~corner, mm] = ((P[rows, e] + P[rows, (e + 1) % 3]) / 2)[~corner]
            sub = sub[parent]
        uv, face = out, face[parent]
    return face, uv, sub


def to_face_uv(surface, face, uv, sub):
    """Map tree-local (u, v) of level-0 faces (and n-gon sub-faces) to the public (control face, u, v)."""
    out = uv.copy()
    polygon = sub >= 0
    w = surface.face_tiles[face]
    tile = np.stack([sub % w, sub // w], -1).astype(float)
    out[polygon] = (tile[:, None, :] + 0.5 * uv)[polygon]
    return face, out


def single_sector_vertices(mesh, options, level):
    """(V,) bool: vertices of ``level`` with at most one sector (interior, boundary and single-sector vertices),
    where a limit normal is the surface normal of every face around it."""
    lvl = base_level(mesh, options.scheme, options.boundary, options.rules, True,
                     flatness=options.flatness if options.piecewise_smooth else None,
                     crease_method=options.crease_method)
    for _ in range(level):
        lvl = refine_level(lvl)
    count = np.bincount(lvl.sector_vertex, minlength=lvl.num_vertices)
    return count <= 1, lvl


def scene_meshes(name):
    """Meshes of scenes/make_scenes.py (plain data) as warp_subdiv.Mesh with their rule set."""
    import importlib.util
    module_name = "warp_subdiv_scene_data"
    if module_name not in sys.modules:
        spec = importlib.util.spec_from_file_location(module_name, os.path.join(ROOT, "scenes", "make_scenes.py"))
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        spec.loader.exec_module(module)
    scene = sys.modules[module_name].SCENES[name]
    out = []
    for spec in scene.meshes:
        scheme = "loop" if spec.scheme == "loop" else "catmull-clark"
        out.append((ws.Mesh(spec.points, spec.counts, spec.indices, **spec.tags()), scheme,
                    spec.rules or "piecewise-smooth"))
    return out


def sample(surface, n, rng, margin=0.0):
    """n random (face, u, v) inside non-hole faces (at least ``margin`` inside each face or sub-face domain)."""
    ok = np.flatnonzero(~surface.holes)
    f = rng.choice(ok, n)
    u = margin + (1 - 2 * margin) * rng.random(n)
    v = margin + (1 - 2 * margin) * rng.random(n)
    c = surface.face_size[f]
    if surface.triangles:
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        fan = c > 3
        k = rng.integers(0, np.maximum(c - 2, 1))
        u[fan] = (k + 0.5 * u)[fan]
        v[fan] = (0.5 * v)[fan]
    else:
        polygon = c != 4
        w = surface.face_tiles[f]
        s = rng.integers(0, c)
        u[polygon] = (s % w + 0.5 * u)[polygon]
        v[polygon] = (s // w + 0.5 * v)[polygon]
    return f, u, v


# ------------------------------------------------------------------------------------------ closed forms
def bspline_basis(t):
    """Uniform cubic B-spline basis (value, first, second derivative) at t, each (n, 4)."""
    t = np.asarray(t, float)
    s = 1 - t
    b = np.stack([s ** 3, 3 * t ** 3 - 6 * t ** 2 + 4, -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1, t ** 3], -1) / 6
    d = np.stack([-s ** 2, 3 * t ** 2 - 4 * t, -3 * t ** 2 + 2 * t + 1, t ** 2], -1) / 2
    dd = np.stack([s, 3 * t - 2, 1 - 3 * t, t], -1)
    return b, d, dd


def loop_bezier_from_stencils():
    """The quartic Bezier net (15 x 12) of the regular Loop patch, derived from first principles: the unique N
    with N 1 = 1 such that de Casteljau-subdividing the net equals the net of Loop's regular stencils applied to
    the 12 control points, for each of the four child triangles."""
    from math import factorial
    nb = [(1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1)]
    index = {p: i for i, p in enumerate(TRI_RING)}

    def stencil(q):  # child point at half-lattice position q: Loop's regular vertex and edge rules
        if q[0] % 2 == 0 and q[1] % 2 == 0:
            c = (q[0] // 2, q[1] // 2)
            out = {c: 10 / 16}
            for d in nb:
                out[(c[0] + d[0], c[1] + d[1])] = 1 / 16
            return out
        for d in nb[:3]:
            a2 = (q[0] - d[0], q[1] - d[1])
            if a2[0] % 2 == 0 and a2[1] % 2 == 0:
                a = (a2[0] // 2, a2[1] // 2)
                b = (a[0] + d[0], a[1] + d[1])
                common = {(a[0] + e[0], a[1] + e[1]) for e in nb} & {(b[0] + e[0], b[1] + e[1]) for e in nb}
                out = {a: 3 / 8, b: 3 / 8}
                for o in common:
                    out[o] = 1 / 8
                return out

    def bern(u, v):
        w = (1 - u - v, u, v)
        return np.array([factorial(4) / (factorial(a) * factorial(b) * factorial(c)) * w[0] ** a * w[1] ** b *
                         w[2] ** c for a, b, c in TRI_BEZIER_INDEX])

    colloc = [(i / 4, j / 4) for i in range(5) for j in range(5) if i + j <= 4]
    B = np.array([bern(u, v) for u, v in colloc])
    children = [((0, 0), (1, 0), (0, 1)), ((1, 0), (1, 0), (0, 1)), ((0, 1), (1, 0), (0, 1)),
                ((1, 1), (-1, 0), (0, -1))]
    rows = []
    for o, e1, e2 in children:
        S = np.zeros((12, 12))
        for r, (i, j) in enumerate(TRI_RING):
            for p, w in stencil((o[0] + i * e1[0] + j * e2[0], o[1] + i * e1[1] + j * e2[1])).items():
                S[r, index[p]] += w
        C = np.array([bern((o[0] + s * e1[0] + t * e2[0]) / 2, (o[1] + s * e1[1] + t * e2[1]) / 2) for s, t in colloc])
        Sub = np.linalg.solve(B, C)
        rows.append(np.kron(Sub, np.eye(12)) - np.kron(np.eye(15), S.T))
    A = np.vstack(rows + [np.kron(np.eye(15), np.ones((1, 12)))])
    rhs = np.concatenate([np.zeros(sum(len(r) for r in rows)), np.ones(15)])
    sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
    assert np.abs(A @ sol - rhs).max() < 1e-12
    return sol.reshape(15, 12), bern


def grid_mesh(n, rng, triangles=False):
    """An (n x n)-cell grid with random heights: quads, or triangles along the (i, j) -> (i+1, j+1) diagonal."""
    pts = np.array([(i, j, 0.3 * rng.standard_normal()) for j in range(n + 1) for i in range(n + 1)], float)
    faces = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i
            faces += [[a, b, c], [a, c, d]] if triangles else [[a, b, c, d]]
    return ws.Mesh(pts, [len(f) for f in faces], np.concatenate(faces)), pts, n


def torus_mesh(n, m, triangles=False):
    """A torus of n x m quads (or triangles along one diagonal): every vertex regular (valence 4, or 6)."""
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a, b = 2 * np.pi * i.ravel() / n, 2 * np.pi * j.ravel() / m
    pts = np.stack([(2 + 0.7 * np.cos(b)) * np.cos(a), (2 + 0.7 * np.cos(b)) * np.sin(a), 0.7 * np.sin(b)], 1)
    vid = (i * m + j).ravel()
    right, up, both = ((i + 1) % n * m + j).ravel(), (i * m + (j + 1) % m).ravel(), ((i + 1) % n * m + (j + 1) % m).ravel()
    faces = np.stack([vid, right, both, vid, both, up], 1).reshape(-1, 3) if triangles else \
        np.stack([vid, right, both, up], 1)
    return ws.Mesh(pts, np.full(len(faces), faces.shape[1]), faces.ravel()), pts


# ------------------------------------------------------------------------------------------ tests
def test_bicubic_patch_matches_closed_form_bspline(device):
    """An interior face of a regular quad grid is the uniform bicubic B-spline of its 4x4 control points:
    positions, first and second derivatives at random (u, v), on every device."""
    rng = np.random.default_rng(RNG_SEED)
    mesh, pts, n = grid_mesh(6, rng)
    surface = ws.LimitSurface(mesh, rules="opensubdiv", device=device)
    face = 2 * n + 3  # cell (3, 2): two rings inside
    i0, j0 = 3, 2
    grid = np.array([[pts[(j0 + b - 1) * (n + 1) + (i0 + a - 1)] for a in range(4)] for b in range(4)])  # [v][u]
    u, v = rng.random(50), rng.random(50)
    ev = surface.evaluate(np.full(50, face), u, v, derivatives=2)
    bu, du, ddu = bspline_basis(u)
    bv, dv, ddv = bspline_basis(v)
    for got, wu, wv in ((ev.points, bu, bv), (ev.du, du, bv), (ev.dv, bu, dv), (ev.duu, ddu, bv),
                        (ev.duv, du, dv), (ev.dvv, bu, ddv)):
        want = np.einsum("na,nb,bac->nc", wu, wv, grid)
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_quartic_box_spline_matches_closed_form():
    """The regular Loop patch is the quartic box spline: the library's Bezier matrix equals the one derived here
    from Loop's stencils, and an interior triangle of a regular triangle grid evaluates (with derivatives) as
    that Bezier net of its 12 control points (points and first derivatives to 1e-12)."""
    N, bern = loop_bezier_from_stencils()
    np.testing.assert_allclose(LOOP_BEZIER, N, atol=1e-12)
    rng = np.random.default_rng(RNG_SEED)
    mesh, pts, n = grid_mesh(6, rng, triangles=True)
    surface = ws.LimitSurface(mesh, scheme="loop", rules="opensubdiv")
    i0, j0 = 3, 2
    face = 2 * (j0 * n + i0)  # the lower triangle (i, j), (i+1, j), (i+1, j+1) of cell (3, 2)
    # in that triangle's frame: corner 0 = (i, j), corner 1 = (i+1, j), corner 2 = (i+1, j+1); lattice
    # coordinates of TRI_RING (a along edge 0, b along edge 2 reversed) map to grid (i + a + b, j + b)
    ring = np.array([pts[(j0 + b) * (n + 1) + i0 + a + b] for a, b in TRI_RING])
    net = N @ ring
    u = rng.random(40) * 0.5
    v = rng.random(40) * 0.5
    ev = surface.evaluate(np.full(40, face), u, v, derivatives=2)
    h = 1e-6
    for k in range(40):
        def at(x, y):
            return bern(x, y) @ net
        np.testing.assert_allclose(ev.points[k], at(u[k], v[k]), atol=1e-12)
        # first derivatives exactly (complex step: the net is a polynomial), second by finite differences
        np.testing.assert_allclose(ev.du[k], at(u[k] + 1e-30j, v[k]).imag / 1e-30, atol=1e-12)
        np.testing.assert_allclose(ev.dv[k], at(u[k], v[k] + 1e-30j).imag / 1e-30, atol=1e-12)
        np.testing.assert_allclose(ev.duv[k], (at(u[k] + h, v[k] + h) - at(u[k] + h, v[k] - h) - at(u[k] - h, v[k] + h)
                                               + at(u[k] - h, v[k] - h)) / (4 * h * h), atol=1e-3)


@pytest.mark.parametrize("name,scheme,tags", [
    ("cube", "catmull-clark", {}), ("mixed_prism", "catmull-clark", {}), ("quad_lshape", "catmull-clark", {}),
    ("icosahedron", "loop", {}), ("mixed_prism", "loop", {}),
    ("grid3x3", "catmull-clark", {"creases": [[5, 6]], "crease_sharpness": [2.5], "corners": [10]}),
])
def test_finite_differences_match_derivatives(name, scheme, tags):
    """Central differences of positions equal du, dv, and of du, dv equal duu, duv, dvv, at random points
    (extraordinary vertices, n-gons, Loop polygons, semi-sharp creases, boundaries)."""
    base = load_mesh(name)
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, **tags) if tags else base
    surface = ws.LimitSurface(mesh, scheme=scheme, depth=5)
    rng = np.random.default_rng(RNG_SEED)
    f, u, v = sample(surface, 400, rng, margin=0.05)
    h = 1e-6
    ev = surface.evaluate(f, u, v, derivatives=2)
    e = {k: surface.evaluate(f, u + a, v + b, derivatives=2) for k, (a, b) in
         {"u+": (h, 0), "u-": (-h, 0), "v+": (0, h), "v-": (0, -h)}.items()}
    same = np.all([x.patch == ev.patch for x in e.values()], axis=0)
    assert same.mean() > 0.9
    scale = np.abs(mesh.points).max()
    for got, a, b, field in ((ev.du, "u+", "u-", "points"), (ev.dv, "v+", "v-", "points"), (ev.duu, "u+", "u-", "du"),
                             (ev.duv, "v+", "v-", "du"), (ev.dvv, "v+", "v-", "dv")):
        fd = (getattr(e[a], field) - getattr(e[b], field)) / (2 * h)
        err = np.linalg.norm(fd - got, axis=1)[same] / np.maximum(np.linalg.norm(got, axis=1)[same], scale)
        assert err.max() < 1e-4, (field, err.max())
    n = np.cross(ev.du, ev.dv)
    np.testing.assert_allclose(ev.normals, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-12)


CONSISTENCY = [
    ("cube", "catmull-clark", "opensubdiv", {}), ("cube", "catmull-clark", "piecewise-smooth", {}),
    ("mixed_prism", "catmull-clark", "piecewise-smooth", {}), ("quad_lshape", "catmull-clark", "opensubdiv", {}),
    ("quad_lshape", "catmull-clark", "piecewise-smooth", {}), ("quad_halffan", "catmull-clark", "piecewise-smooth", {}),
    ("cube_creased", "catmull-clark", "piecewise-smooth", {"flatness": 0.5}),
    ("icosahedron", "loop", "opensubdiv", {}), ("tri_halffan", "loop", "piecewise-smooth", {}),
    ("tri_grid3x3", "loop", "opensubdiv", {"boundary": "edge-only"}), ("mixed_prism", "loop", "piecewise-smooth", {}),
]


def check_consistency(mesh, scheme, rules, options, level=2, depth=4):
    """Evaluate at the parameters of every vertex of ``level`` and compare with limit_points / limit_normals."""
    o = ws.Options(scheme=scheme, rules=rules, precision="float64", **options)
    surface = ws.LimitSurface(mesh, options=o, depth=depth)
    refiner = ws.Refiner(mesh, level, options=o)
    refined = refiner.refine()
    want_p, want_n = refined.limit_points(), refined.limit_normals()
    faces, u, v_par, v = refined_vertex_params(surface, refiner, level)
    ev = surface.evaluate(faces, u, v_par)
    scale = np.abs(mesh.points).max()
    np.testing.assert_allclose(ev.points, want_p[v], atol=1e-10 * scale)
    single, lvl = single_sector_vertices(mesh, o, level)
    check = single[v]
    if rules == "opensubdiv":  # OpenSubdiv's tangent masks at irregular crease / corner vertices depend on the level
        k = lvl.sector_k()
        regular_k = 2 if scheme == "catmull-clark" else 3
        odd = np.zeros(lvl.num_vertices, bool)
        odd[lvl.sector_vertex[(k != regular_k) & (k != 1)]] = True
        check &= ~odd[v]
    assert check.mean() > 0.5
    err = np.linalg.norm(ev.normals - want_n[v], axis=1)
    # a prescribed normal may point against the faces' winding (Fig. 13's "down"): du x dv is then its negation
    prescribed = np.isin(v, mesh.normal_vertices)
    err[prescribed] = np.minimum(err, np.linalg.norm(ev.normals + want_n[v], axis=1))[prescribed]
    assert err[check].max() < 1e-8, (np.flatnonzero(check & (err > 1e-8))[:5], err[check].max())


@pytest.mark.parametrize("name,scheme,rules,options", CONSISTENCY)
def test_consistency_with_limit_points_and_normals(name, scheme, rules, options):
    """At the parameters of refined vertices (corners, edge middles and centres of level-1 and level-2 faces)
    evaluate() equals Refined.limit_points(), and its normals Refined.limit_normals() at single-sector vertices,
    with both rule sets (flatness on where given)."""
    check_consistency(load_mesh(name), scheme, rules, options)


@pytest.mark.parametrize("scene", ["concave_corner", "complex_corner", "plane_normals", "icosahedron_normals"])
def test_consistency_with_projections(scene):
    """The paper's projections: concave corners (flatness above s_min), complex corners, prescribed normals at
    interior and boundary vertices: evaluate() still equals the refined mesh's limit points and normals."""
    for mesh, scheme, rules in scene_meshes(scene)[:2]:
        check_consistency(mesh, scheme, rules, {}, level=2, depth=3)


def refined_vertex_params(surface, refiner, level):
    """(faces, u, v, vertex ids) of every corner of every face of ``level``: the parameters at which the limit
    surface passes through that refined vertex's limit (Loop polygons mapped onto their fan tiles)."""
    face, uv, sub = refined_face_params(refiner.hierarchy, level)
    n = uv.shape[1]
    verts = refiner.hierarchy.final.corner_vert.reshape(-1, n)
    control = refiner.hierarchy.parentage.control_face
    if control is not None:
        first = np.searchsorted(control, control)
        k = face - first[face]
        face = control[face]
        fan = surface.face_size[face] > 3
        uv[fan] = np.stack([k[fan][:, None] + 0.5 * uv[fan][..., 0], 0.5 * uv[fan][..., 1]], -1)
    face_ids, uv = to_face_uv(surface, face, uv, sub)
    keep = ~surface.holes[face_ids]
    return (np.repeat(face_ids[keep], n), uv[keep, :, 0].ravel(), uv[keep, :, 1].ravel(),
            verts[keep].ravel().astype(np.int64))


def tagged(mesh, rng, sharpness=(0.5, 2.0, 10.0)):
    """``mesh`` with a few random creases (semi-sharp and infinitely sharp) and corners, its points jittered.
    Semi-sharp tags are at most 2 (10 is infinitely sharp): refined vertices of level 2 then have limit masks
    that are exact (a vertex still semi-sharp at the level takes the sharp masks, which the surface does not)."""
    edges = mesh.edges.edge_verts
    pick = rng.choice(len(edges), max(1, len(edges) // 6), replace=False)
    corners = rng.choice(mesh.num_vertices, max(1, mesh.num_vertices // 8), replace=False)
    return ws.Mesh(mesh.points + 0.03 * rng.standard_normal(mesh.points.shape), mesh.face_vertex_counts,
                   mesh.face_vertex_indices, creases=edges[pick], crease_sharpness=rng.choice(sharpness, len(pick)),
                   corners=corners, corner_sharpness=rng.choice([2.0, 10.0], len(corners)), concave=mesh.concave,
                   holes=mesh.holes)


def data_cases():
    """(id, mesh, scheme) under the piecewise-smooth rules: concave and convex corners (sector angles from the
    geometry), complex corners, creases and corners, n-gons, Loop polygons."""
    rng = np.random.default_rng(RNG_SEED)
    concave = scene_meshes("concave_corner")
    complex_ = scene_meshes("complex_corner")
    return [("concave_corner", concave[0][0], "catmull-clark"), ("concave_corners4", concave[1][0], "catmull-clark"),
            ("complex_corner", complex_[0][0], "catmull-clark"),
            ("quad_lshape_tagged", tagged(load_mesh("quad_lshape"), rng), "catmull-clark"),
            ("mixed_prism_tagged", tagged(load_mesh("mixed_prism"), rng), "catmull-clark"),
            ("tri_halffan_tagged", tagged(load_mesh("tri_halffan"), rng), "loop"),
            ("mixed_prism_loop", tagged(load_mesh("mixed_prism"), rng), "loop")]


@pytest.mark.parametrize("case", range(7), ids=[c[0] for c in data_cases()])
def test_vertex_data_takes_the_weights_of_the_points(case):
    """evaluate_data subdivides data with the positions' weights (piecewise-smooth sector angles, flatness, end
    caps' tangent planes from the geometry): data equal to the points gives evaluate()'s points and derivatives
    bit for bit, and so do two of the points' columns alone (weights taken from the data would change the
    sector angles); the result is linear (a x + b y to 1e-12); at refined vertices it equals limit_points() of
    Refiner.evaluate() of the same data."""
    name, mesh, scheme = data_cases()[case]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        o = ws.Options(scheme=scheme, rules="piecewise-smooth", precision="float64")
        surface = ws.LimitSurface(mesh, options=o, depth=3)
        refiner = ws.Refiner(mesh, 2, options=o)
    rng = np.random.default_rng(RNG_SEED + case)
    f, u, v = sample(surface, 400, rng)
    ev = surface.evaluate(f, u, v)
    same = surface.evaluate_data(mesh.points, f, u, v, derivatives=1)
    assert np.array_equal(same.values, ev.points) and np.array_equal(same.du, ev.du)
    assert np.array_equal(same.dv, ev.dv)
    assert np.array_equal(surface.evaluate_data(mesh.points[:, :2], f, u, v).values, ev.points[:, :2])
    x = rng.standard_normal((mesh.num_vertices, 2))
    y = rng.standard_normal(mesh.num_vertices)
    a = surface.evaluate_data(2.5 * x - 1.5 * y[:, None], f, u, v).values
    b = 2.5 * surface.evaluate_data(x, f, u, v).values - 1.5 * surface.evaluate_data(y, f, u, v).values[:, None]
    assert np.abs(a - b).max() < 1e-12
    rf, ru, rv, verts = refined_vertex_params(surface, refiner, 2)
    want = refiner.limit_points(refiner.evaluate(x))
    got = surface.evaluate_data(x, rf, ru, rv).values
    np.testing.assert_allclose(got, want[verts], atol=1e-10)


FV_MODES = ["none", "corners-only", "corners-plus1", "corners-plus2", "boundaries", "all"]


def seamed_channel(mesh, rng):
    """A face-varying channel with seams: one value per (vertex, face of a random 3-colouring of the faces)
    pair, so the islands meet along seams, some vertices carry two values and some three or more."""
    counts = np.asarray(mesh.face_vertex_counts)
    island = rng.integers(0, 3, len(counts))
    idx = mesh.face_vertex_indices.astype(np.int64) * 3 + np.repeat(island, counts)
    return rng.random((3 * mesh.num_vertices, 2)), idx


@pytest.mark.parametrize("name,scheme,boundary", [("mixed_prism", "catmull-clark", "edge-and-corner"),
                                                  ("quad_lshape", "catmull-clark", "edge-only"),
                                                  ("mixed_prism", "loop", "edge-and-corner"),
                                                  ("tri_grid3x3", "loop", "edge-and-corner")])
def test_face_varying_consistency_with_limit_face_varying(name, scheme, boundary):
    """evaluate_face_varying at the parameters of every corner of every level-2 face equals
    Refiner.limit_face_varying of the uniformly refined channel there, under every interpolation mode, on
    channels with seams (n-gons, Loop polygons and boundaries included)."""
    mesh = load_mesh(name)
    values, idx = seamed_channel(mesh, np.random.default_rng(RNG_SEED))
    o = ws.Options(scheme=scheme, boundary=boundary, precision="float64")
    surface = ws.LimitSurface(mesh, options=o, depth=3)
    refiner = ws.Refiner(mesh, 2, options=o)
    rf, ru, rv, _ = refined_vertex_params(surface, refiner, 2)
    for mode in FV_MODES:
        got = surface.evaluate_face_varying(values, idx, rf, ru, rv, mode=mode).values
        limit, refined_idx = refiner.limit_face_varying(values, idx, mode=mode)
        np.testing.assert_allclose(got, limit[refined_idx], atol=1e-12, err_msg=mode)


def seam_grid():
    """A 4 x 4 quad grid whose UVs form three islands: A (faces left of x = 2), B (right, below y = 2) and C
    (right, above). The centre vertex 12 has three values: A's spans two faces there, B's and C's one each."""
    mesh, pts, n = grid_mesh(4, np.random.default_rng(RNG_SEED))
    a, b = np.meshgrid(np.arange(4), np.arange(4))
    island = np.where(a.ravel() <= 1, 0, np.where(b.ravel() <= 1, 1, 2))
    idx = mesh.face_vertex_indices.astype(np.int64) * 3 + np.repeat(island, 4)
    return mesh, np.random.default_rng(RNG_SEED + 1).random((75, 2)), idx


def test_face_varying_modes_on_seams():
    """On seams the values follow the modes: "none" smooths even a one-face corner of an island; "corners-only"
    interpolates it but keeps a seam value that spans two faces on a smooth boundary curve (the B-spline
    boundary mask (1, 4, 1) / 6 of its island's values); "corners-plus1" also interpolates that value (its
    vertex has three values); "boundaries" makes seams linear (an edge's middle is the mean of its ends);
    "all" is bilinear interpolation inside each face; the modes agree on a face away from the seams."""
    mesh, values, idx = seam_grid()
    surface = ws.LimitSurface(mesh, depth=3)

    def at(face, u, v, mode):
        return surface.evaluate_face_varying(values, idx, [face], [u], [v], mode=mode).values[0]

    def value(vertex, island):
        return values[3 * vertex + island]

    # face 5 (island A, below left of the centre): its corner 2 is vertex 12, on A's seam x = 2
    smooth_boundary = (value(7, 0) + 4 * value(12, 0) + value(17, 0)) / 6
    np.testing.assert_allclose(at(5, 1, 1, "corners-only"), smooth_boundary, atol=1e-12)
    assert np.abs(smooth_boundary - value(12, 0)).max() > 1e-2
    for mode in ("corners-plus1", "corners-plus2", "boundaries", "all"):
        np.testing.assert_allclose(at(5, 1, 1, mode), value(12, 0), atol=1e-12, err_msg=mode)
    # face 6 (island B): its corner 3 is vertex 12, a one-face corner of B
    assert np.abs(at(6, 0, 1, "none") - value(12, 1)).max() > 1e-3
    for mode in FV_MODES[1:]:
        np.testing.assert_allclose(at(6, 0, 1, mode), value(12, 1), atol=1e-12, err_msg=mode)
    # face 9 (island A, above left): the middle of its seam edge 12 - 17
    mean = (value(12, 0) + value(17, 0)) / 2
    np.testing.assert_allclose(at(9, 1, 0.5, "boundaries"), mean, atol=1e-12)
    assert np.abs(at(9, 1, 0.5, "corners-plus1") - mean).max() > 1e-3
    # "all": bilinear in every face
    rng = np.random.default_rng(RNG_SEED)
    f, u, v = rng.integers(0, 16, 50), rng.random(50), rng.random(50)
    c = values[idx.reshape(16, 4)[f]]
    uu, vv = u[:, None], v[:, None]
    bilinear = (1 - uu) * (1 - vv) * c[:, 0] + uu * (1 - vv) * c[:, 1] + uu * vv * c[:, 2] + (1 - uu) * vv * c[:, 3]
    np.testing.assert_allclose(surface.evaluate_face_varying(values, idx, f, u, v, mode="all").values, bilinear,
                               atol=1e-12)
    # face 0 is two rings away from any seam (the mesh boundary aside): "none" .. "corners-plus2" agree inside
    inner = [surface.evaluate_face_varying(values, idx, [0], [0.9], [0.9], mode=m).values for m in FV_MODES[:4]]
    for other in inner[1:]:
        np.testing.assert_allclose(other, inner[0], atol=1e-12)


def test_face_varying_input_is_checked():
    """Too few values, indices of the wrong length or negative, an unknown mode are refused with
    SubdivInputError; derivatives of a channel equal finite differences of its values (mode "all" too)."""
    mesh, values, idx = seam_grid()
    surface = ws.LimitSurface(mesh, depth=3)
    with pytest.raises(SubdivInputError, match="values"):
        surface.evaluate_face_varying(values[:10], idx, [0], [0.5], [0.5])
    with pytest.raises(SubdivInputError, match="indices"):
        surface.evaluate_face_varying(values, idx[:-1], [0], [0.5], [0.5])
    with pytest.raises(SubdivInputError, match="negative"):
        surface.evaluate_face_varying(values, -idx, [0], [0.5], [0.5])
    with pytest.raises(SubdivInputError, match="mode"):
        surface.evaluate_face_varying(values, idx, [0], [0.5], [0.5], mode="sometimes")
    with pytest.raises(SubdivInputError, match="derivatives"):
        surface.evaluate_face_varying(values, idx, [0], [0.5], [0.5], derivatives=2)
    h = 1e-6
    f, u, v = [5, 5, 5, 5, 5], [0.3 + h, 0.3 - h, 0.3, 0.3, 0.3], [0.6, 0.6, 0.6 + h, 0.6 - h, 0.6]
    for mode in ("corners-plus1", "all"):
        res = surface.evaluate_face_varying(values, idx, f, u, v, mode=mode, derivatives=1)
        np.testing.assert_allclose((res.values[0] - res.values[1]) / (2 * h), res.du[4], rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose((res.values[2] - res.values[3]) / (2 * h), res.dv[4], rtol=1e-6, atol=1e-8)
    one = surface.evaluate_face_varying(values[:, 0], idx, f, u, v, mode="all")
    assert one.values.shape == (5,)
    np.testing.assert_allclose(one.values, res.values[:, 0], atol=1e-14)


@pytest.mark.parametrize("name,scheme", [("mixed_prism", "catmull-clark"), ("quad_lshape", "catmull-clark"),
                                         ("mixed_prism", "loop")])
def test_linear_surface(name, scheme):
    """linear=True (bilinear meshes): at the parameters of every level-2 vertex the surface equals linear
    refinement (Refiner with linear=True), derivatives equal finite differences, data and face-varying data are
    interpolated linearly, and the tessellation is watertight with flat faces' normals."""
    mesh = load_mesh(name)
    o = ws.Options(scheme=scheme, linear=True, precision="float64")
    surface = ws.LimitSurface(mesh, options=o)
    assert surface.linear and surface.tree is None
    refiner = ws.Refiner(mesh, 2, options=o)
    rf, ru, rv, verts = refined_vertex_params(surface, refiner, 2)
    np.testing.assert_allclose(surface.evaluate(rf, ru, rv).points, refiner.refine().points[verts], atol=1e-12)
    x = np.random.default_rng(RNG_SEED).standard_normal((mesh.num_vertices, 2))
    np.testing.assert_allclose(surface.evaluate_data(x, rf, ru, rv).values, refiner.evaluate(x)[verts], atol=1e-12)
    values, idx = seamed_channel(mesh, np.random.default_rng(RNG_SEED))
    fv, fi = refiner.evaluate_face_varying(values, idx, "all")
    got = surface.evaluate_face_varying(values, idx, rf, ru, rv, mode="none").values  # linear: every mode
    np.testing.assert_allclose(got, fv[fi], atol=1e-12)
    f, u, v = sample(surface, 300, np.random.default_rng(RNG_SEED), margin=0.01)
    h = 1e-6
    ev = surface.evaluate(f, u, v, derivatives=2)
    fd_u = (surface.evaluate(f, u + h, v).points - surface.evaluate(f, u - h, v).points) / (2 * h)
    fd_v = (surface.evaluate(f, u, v + h).points - surface.evaluate(f, u, v - h).points) / (2 * h)
    inside = np.ones(len(f), bool)
    if scheme == "catmull-clark":  # away from the sub-face tiles' borders (where the derivative jumps)
        frac_u, frac_v = np.modf(2 * u)[0], np.modf(2 * v)[0]
        inside = (np.minimum(frac_u, 1 - frac_u) > 1e-3) & (np.minimum(frac_v, 1 - frac_v) > 1e-3)
    np.testing.assert_allclose(ev.du[inside], fd_u[inside], atol=1e-6)
    np.testing.assert_allclose(ev.dv[inside], fd_v[inside], atol=1e-6)
    t = surface.tessellate(rate=3)
    edges = np.sort(np.stack([t.face_vertex_indices, np.concatenate(
        [np.roll(t.face_vertex_indices[o:o + c], -1) for o, c in
         zip(np.concatenate([[0], np.cumsum(t.face_vertex_counts)[:-1]]), t.face_vertex_counts)])], 1), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert uses.max() <= 2


def test_parameterisation_of_polygons():
    """vertex_uv() of every corner of n-gons (Catmull-Clark sub-face tiles) and Loop polygons (fan triangle tiles)
    evaluates to the limit position of that control vertex, and an n-gon's centre to its face point's limit."""
    mesh = load_mesh("mixed_prism")
    for scheme in ("catmull-clark", "loop"):
        surface = ws.LimitSurface(mesh, scheme=scheme, depth=3)
        refined = ws.refine(mesh, 1, scheme=scheme, precision="float64")
        lp = refined.limit_points()
        counts = mesh.face_vertex_counts
        faces = np.repeat(np.arange(len(counts)), counts)
        corners = np.arange(len(faces)) - np.repeat(np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
        uv = surface.vertex_uv(faces, corners)
        ev = surface.evaluate(faces, uv[:, 0], uv[:, 1])
        np.testing.assert_allclose(ev.points, lp[mesh.face_vertex_indices], atol=1e-10)
    surface = ws.LimitSurface(mesh, depth=3)
    pentagon = int(np.flatnonzero(counts == 5)[0])
    centre = surface.evaluate([pentagon], [0.5], [0.5]).points[0]  # sub-face 0's (1, 1): the face point
    face_point = ws.refine(mesh, 1, precision="float64").limit_points()[mesh.num_vertices + pentagon]
    np.testing.assert_allclose(centre, face_point, atol=1e-10)


@pytest.mark.parametrize("name", ["octahedron", "icosahedron"])
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_catmull_clark_on_all_triangle_meshes(name, rules):
    """Catmull-Clark on a mesh of triangles only (every face a 3-gon of three quad sub-faces, as OpenSubdiv
    accepts it): the tree builds without quad faces at level 0, every control vertex's (u, v) evaluates to its
    limit position, the surface agrees with limit_points / limit_normals at level-3 vertices, and the points of
    a deeper refinement converge onto it (their distance shrinks about fourfold per level)."""
    mesh = load_mesh(name)
    o = ws.Options(scheme="catmull-clark", rules=rules, precision="float64")
    surface = ws.LimitSurface(mesh, options=o, depth=5)
    assert (surface.face_kind == ws.limit.SUBFACES).all()
    counts = mesh.face_vertex_counts
    faces = np.repeat(np.arange(len(counts)), counts)
    corners = np.tile(np.arange(3), len(counts))
    uv = surface.vertex_uv(faces, corners)
    want = ws.Refiner(mesh, 1, options=o).refine().limit_points()[mesh.face_vertex_indices]
    np.testing.assert_allclose(surface.evaluate(faces, uv[:, 0], uv[:, 1]).points, want, atol=1e-12)
    check_consistency(mesh, "catmull-clark", rules, {}, level=3, depth=5)
    distance = []
    for level in (3, 4, 5):
        refiner = ws.Refiner(mesh, level, options=o)
        f, u, v, verts = refined_vertex_params(surface, refiner, level)
        got = surface.evaluate(f, u, v).points
        distance.append(np.linalg.norm(got - refiner.refine().points[verts], axis=1).max())
    assert distance[-1] < 1e-2 * np.abs(mesh.points).max()
    assert distance[1] < distance[0] / 3 and distance[2] < distance[1] / 3, distance


def corner_samples(surface, depth, per_corner, rng):
    """Random (face, u, v) in the 2^-depth squares (sub-face squares of n-gons) at every corner of every
    quad or triangle face and n-gon: where the end caps are."""
    faces, us, vs = [], [], []
    for f in np.flatnonzero(~surface.holes):
        n = int(surface.face_size[f])
        uv = surface.vertex_uv(np.full(n, f), np.arange(n))
        for c in range(n):
            r = rng.random((per_corner, 2)) * 2.0 ** -depth
            if surface.triangles:
                if n != 3:
                    continue
                p = uv[c] + r[:, :1] * (uv[(c + 1) % 3] - uv[c]) + r[:, 1:] * (uv[(c - 1) % 3] - uv[c])
            elif n == 4:
                p = uv[c] + np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]])[c] * r
            else:
                p = uv[c] + 0.5 * r
            faces.append(np.full(per_corner, f))
            us.append(p[:, 0])
            vs.append(p[:, 1])
    return np.concatenate(faces), np.concatenate(us), np.concatenate(vs)


@pytest.mark.parametrize("name,scheme,rules", [("cube", "catmull-clark", "piecewise-smooth"),
                                               ("quad_halffan", "catmull-clark", "opensubdiv"),
                                               ("icosahedron", "loop", "opensubdiv")])
def test_end_cap_error_bound(name, scheme, rules):
    """Inside the end caps (the 2^-depth corners at irregular vertices) positions are within the README's bound
    0.06 * 0.6^depth * (median control edge length) of the surface computed 8 levels deeper, and normals within
    0.3 * 0.6^depth; the caps interpolate the exact limit positions at their corners."""
    mesh = load_mesh(name)
    edges = mesh.edges.edge_verts
    h = np.median(np.linalg.norm(mesh.points[edges[:, 0]] - mesh.points[edges[:, 1]], axis=1))
    rng = np.random.default_rng(RNG_SEED)
    for depth in (2, 4, 6):
        coarse = ws.LimitSurface(mesh, scheme=scheme, rules=rules, depth=depth)
        fine = ws.LimitSurface(mesh, scheme=scheme, rules=rules, depth=depth + 8)
        f, u, v = corner_samples(coarse, depth, 12, rng)
        a, b = coarse.evaluate(f, u, v), fine.evaluate(f, u, v)
        cap = coarse.tree.patch_kind[a.patch] == END_CAP
        assert cap.any()
        assert np.linalg.norm(a.points - b.points, axis=1)[cap].max() <= 0.06 * 0.6 ** depth * h
        assert np.linalg.norm(a.normals - b.normals, axis=1)[cap].max() <= 0.3 * 0.6 ** depth
    refined = ws.refine(mesh, 1, scheme=scheme, rules=rules, precision="float64").limit_points()
    corner = coarse.evaluate([0], [0.0], [0.0]).points[0]
    np.testing.assert_allclose(corner, refined[mesh.face_vertex_indices[0]], atol=1e-12)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("linear", [False, True])
def test_normals_do_not_depend_on_the_scale(scheme, linear):
    """Points scaled by 1e160 (du x dv overflows float64) or 1e-80 (its squared length underflows) have the unit
    normals of the unscaled mesh, not [0, 0, nan] or normals of length 0.99997; positions and tangents scale
    with the points. (A torus: every patch regular, no end caps.)"""
    mesh, pts = torus_mesh(6, 4, triangles=scheme == "loop")
    f, u, v = sample(ws.LimitSurface(mesh, scheme=scheme, linear=True), 200, np.random.default_rng(RNG_SEED))
    unit = ws.LimitSurface(mesh, scheme=scheme, linear=linear, depth=3).evaluate(f, u, v)
    for scale in (1e160, 1e-80, 1e150, 1e-150):
        scaled = ws.Mesh(pts * scale, mesh.face_vertex_counts, mesh.face_vertex_indices)
        ev = ws.LimitSurface(scaled, scheme=scheme, linear=linear, depth=3).evaluate(f, u, v)
        np.testing.assert_allclose(ev.points / scale, unit.points, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ev.du / scale, unit.du, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(ev.normals, axis=1), 1.0, atol=1e-15, err_msg=str(scale))
        np.testing.assert_allclose(ev.normals, unit.normals, atol=1e-14, err_msg=str(scale))


def test_results_of_successive_evaluations_are_independent():
    """evaluate's arrays (numpy memory wrapped for the kernel on the CPU) belong to the caller: a later call
    does not overwrite them, each is contiguous and writable, and the same queries give the same bits."""
    rng = np.random.default_rng(RNG_SEED)
    for scheme in ("loop", "catmull-clark"):
        mesh = grid_mesh(4, rng, triangles=scheme == "loop")[0]
        surface = ws.LimitSurface(mesh, scheme=scheme, device="cpu")
        f, u, v = rng.integers(0, surface.num_faces, 500), rng.random(500) * 0.5, rng.random(500) * 0.5
        first = surface.evaluate(f, u, v, derivatives=2)
        kept = {k: getattr(first, k).copy() for k in ("points", "du", "dv", "normals", "duu", "duv", "dvv")}
        other = surface.evaluate(f[::-1], v, u, derivatives=2)
        for k, value in kept.items():
            got = getattr(first, k)
            assert got.flags.c_contiguous and got.flags.writeable and got.shape == (500, 3)
            np.testing.assert_array_equal(got, value)
            assert not np.shares_memory(got, getattr(other, k))
        again = surface.evaluate(f, u, v, derivatives=2)
        for k, value in kept.items():
            np.testing.assert_array_equal(getattr(again, k), value)


def test_bad_input_is_refused():
    """Hole faces, face ids out of range, non-finite parameters, a bad depth or derivatives value are refused with
    SubdivInputError naming the problem."""
    base = load_mesh("grid3x3")
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, holes=[4])
    surface = ws.LimitSurface(mesh, depth=2)
    assert surface.holes.tolist() == [i == 4 for i in range(9)]
    with pytest.raises(SubdivInputError, match="hole"):
        surface.evaluate([4], [0.5], [0.5])
    with pytest.raises(SubdivInputError, match="outside"):
        surface.evaluate([9], [0.5], [0.5])
    with pytest.raises(SubdivInputError, match="finite"):
        surface.evaluate([0], [np.nan], [0.5])
    with pytest.raises(SubdivInputError, match="derivatives"):
        surface.evaluate([0], [0.5], [0.5], derivatives=3)
    with pytest.raises(SubdivInputError, match="depth"):
        ws.LimitSurface(mesh, depth=0)
    assert len(surface.evaluate([], [], []).points) == 0


# (face, u, v) outside each kind of face (mixed_prism: face 0 a pentagon, 2 a triangle, 4 a quad), and inside
OUTSIDE = {
    "catmull-clark": [(4, 1.5, 0.5), (4, 1e10, 0.5), (4, 0.5, -0.01), (4, -1e-5, 0.0),  # quad: [0, 1]^2
                      (0, 0.7, 0.2), (0, 2.2, 1.2), (0, 3.1, 0.2), (0, -0.1, 0.3),  # pentagon: 5 tiles of 3 x 2
                      (2, 1.2, 1.2), (2, 0.2, 0.6)],  # triangle: 3 tiles of 2 x 2
    "loop": [(2, 0.8, 0.8), (2, -0.01, 0.5), (2, 0.5, 0.5 + 1e-5),  # triangle: u, v >= 0, u + v <= 1
             (0, 0.3, 0.3), (0, 3.1, 0.1), (0, 2.6, 0.0), (0, 0.2, -0.1),  # pentagon: 3 fan triangles at (k, 0)
             (4, 0.1, 0.45)],  # quad: 2 fan triangles
}
INSIDE = {
    "catmull-clark": [(4, 1.0, 1.0), (4, 0.0, 0.3), (0, 2.5, 0.5), (0, 1.5, 1.5), (0, 1.0, 0.0), (2, 0.5, 1.5)],
    "loop": [(2, 0.5, 0.5), (2, 0.0, 1.0), (0, 2.5, 0.0), (0, 2.0, 0.5), (0, 1.25, 0.25), (4, 1.0, 0.5)],
}


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("linear", [False, True])
def test_queries_outside_their_face_are_refused(scheme, linear):
    """A (u, v) outside its face's domain (a quad's unit square, a triangle's u, v >= 0, u + v <= 1, an n-gon's
    sub-face tiles, a Loop polygon's fan triangles) is refused with SubdivInputError naming the query (index,
    face, u, v) and the domain, by evaluate, evaluate_data and evaluate_face_varying alike, instead of being
    clamped onto the domain; the domain's own boundary is accepted, and so is round-off beyond it (up to
    DOMAIN_TOLERANCE), evaluated on the domain's side (the kernel's clamp)."""
    mesh = load_mesh("mixed_prism")
    surface = ws.LimitSurface(mesh, scheme=scheme, linear=linear, depth=3)
    inside = np.array(INSIDE[scheme], dtype=object)
    f_in, u_in, v_in = inside[:, 0].astype(int), inside[:, 1].astype(float), inside[:, 2].astype(float)
    surface.evaluate(f_in, u_in, v_in)
    idx = np.arange(len(mesh.face_vertex_indices))
    for face, u, v in OUTSIDE[scheme]:
        faces, us, vs = np.append(f_in, face), np.append(u_in, u), np.append(v_in, v)
        query = len(f_in)
        for call in (lambda: surface.evaluate(faces, us, vs),
                     lambda: surface.evaluate_data(mesh.points, faces, us, vs),
                     lambda: surface.evaluate_face_varying(mesh.points[mesh.face_vertex_indices], idx, faces, us, vs)):
            with pytest.raises(SubdivInputError, match="outside the domain") as err:
                call()
            message = str(err.value)
            assert f"query {query} (face {face}, u={u!r}, v={v!r})" in message, message
            assert err.value.option == "uv" and err.value.index == query
    # round-off beyond a side: evaluated on it (clamped onto a square, scaled toward a triangle's corner 0,
    # moving the point by less than the tolerance), a hair farther: refused
    tol = ws.limit.DOMAIN_TOLERANCE
    edge = (4, 1.0, 0.25) if scheme == "catmull-clark" else (2, 0.75, 0.25)
    on = surface.evaluate([edge[0]], [edge[1]], [edge[2]])
    near = surface.evaluate([edge[0]], [edge[1] + 0.5 * tol], [edge[2]]).points
    assert np.linalg.norm(near - on.points) <= tol * np.linalg.norm(np.concatenate([on.du, on.dv]))
    with pytest.raises(SubdivInputError, match="outside the domain"):
        surface.evaluate([edge[0]], [edge[1] + 2 * tol], [edge[2]])


@pytest.mark.parametrize("linear", [False, True])
def test_query_arrays_keep_their_shape(linear):
    """faces, u and v broadcast together as numpy arrays do, and every result takes their shape (points (2, 2, 3)
    for (2, 2) queries, data (2, 2, k), 1-D data (2, 2), patch (2, 2)), with the values of the flat queries; a
    query of three scalars is one query (results (1, 3))."""
    mesh = load_mesh("mixed_prism")
    surface = ws.LimitSurface(mesh, depth=3, linear=linear)
    faces = np.array([[1, 4], [5, 6]])
    u = np.array([[0.25, 0.5], [0.75, 0.1]])
    v = np.array([[0.5], [0.3]])  # broadcasts against (2, 2)
    flat = surface.evaluate(faces.ravel(), u.ravel(), np.broadcast_to(v, (2, 2)).ravel(), derivatives=2)
    ev = surface.evaluate(faces, u, v, derivatives=2)
    for name in ("points", "du", "dv", "normals", "duu", "duv", "dvv"):
        assert getattr(ev, name).shape == (2, 2, 3), name
        np.testing.assert_array_equal(getattr(ev, name).reshape(4, 3), getattr(flat, name))
    assert ev.patch.shape == (2, 2)
    assert surface.evaluate(faces[:, :, None], u[:, :, None], [[[0.2, 0.3, 0.4]]]).points.shape == (2, 2, 3, 3)
    assert surface.evaluate(4, 0.5, 0.5).points.shape == (1, 3)
    x = np.random.default_rng(RNG_SEED).standard_normal((mesh.num_vertices, 2))
    res = surface.evaluate_data(x, faces, u, v, derivatives=1)
    assert res.values.shape == res.du.shape == res.dv.shape == (2, 2, 2)
    np.testing.assert_array_equal(res.values.reshape(4, 2), surface.evaluate_data(
        x, faces.ravel(), u.ravel(), np.broadcast_to(v, (2, 2)).ravel()).values)
    assert surface.evaluate_data(x[:, 0], faces, u, v).values.shape == (2, 2)
    values, idx = seamed_channel(mesh, np.random.default_rng(RNG_SEED))
    for mode in ("corners-plus1", "all"):
        fv = surface.evaluate_face_varying(values, idx, faces, u, v, mode=mode, derivatives=1)
        assert fv.values.shape == fv.du.shape == (2, 2, 2), mode
        assert surface.evaluate_face_varying(values[:, 0], idx, faces, u, v, mode=mode).values.shape == (2, 2)


# ------------------------------------------------------------------------------------------ OpenSubdiv Bfr
def _peer():
    from peers import osd_peer
    if not osd_peer.bfr_available():
        pytest.skip("OpenSubdiv Bfr peer unavailable (needs libosd-dev 3.5+ and g++: peers/install_osd.sh) "
                    + osd_peer.bfr_build_log()[-300:])
    return osd_peer


#: Bfr's default approximation (ApproxLevelSmooth 2, ApproxLevelSharp 6) uses Gregory end caps around irregular
#: features; there the surfaces may differ by this much (relative to the mesh size; measured up to 3.7e-2).
BFR_APPROXIMATE_TOL = 8e-2


def compare_with_bfr(peer, mesh, scheme, boundary="edge-and-corner", creasing="uniform", n=1500, seed=RNG_SEED):
    """Random (face, u, v): to 1e-5 (relative to the mesh's size; derivatives relative to their size) where Bfr
    is exact (its result does not change at approximation level 10), within BFR_APPROXIMATE_TOL where it
    approximates, and everywhere within 1e-4 of Bfr at approximation level 10."""
    surface = ws.LimitSurface(mesh, scheme=scheme, rules="opensubdiv", boundary=boundary, crease_method=creasing)
    rng = np.random.default_rng(seed)
    f, u, v = sample(surface, n, rng)
    ev = surface.evaluate(f, u, v, derivatives=2)
    rec = peer.mesh_request(mesh, 0, scheme="catmark" if scheme == "catmull-clark" else "loop", boundary=boundary,
                            creasing=creasing)
    b = peer.bfr_evaluate(rec, f, np.c_[u, v])
    b10 = peer.bfr_evaluate(rec, f, np.c_[u, v], approx_smooth=10, approx_sharp=10)
    assert b["valid"].all()
    scale = np.abs(mesh.points).max()
    exact = np.linalg.norm(b["points"] - b10["points"], axis=1) < 1e-12 * scale
    d = np.linalg.norm(ev.points - b["points"], axis=1) / scale
    assert d[exact].max() < 1e-5
    assert d.max() < BFR_APPROXIMATE_TOL
    assert (np.linalg.norm(ev.points - b10["points"], axis=1) / scale).max() < 1e-4
    for key in ("du", "dv"):
        ref = b[key][exact]
        size = np.maximum(np.linalg.norm(ref, axis=1), 1e-3 * scale)
        rel = np.linalg.norm(getattr(ev, key)[exact] - ref, axis=1) / size
        assert np.quantile(rel, 0.999) < 1e-5, (key, rel.max())
    # second derivatives where Bfr's patch is regular (Bfr 3.5's second derivatives on irregular Loop patches
    # disagree with its own first derivatives' finite differences; ours agree with those)
    regular = (b["face_regular"][f] == 1)
    for key in ("duu", "duv", "dvv"):
        ref = b[key][regular]
        rel = np.linalg.norm(getattr(ev, key)[regular] - ref, axis=1) / np.maximum(np.linalg.norm(ref, axis=1), scale)
        assert rel.max() < 1e-5 if regular.any() else True
    return exact.mean()


SHAPES = sorted(glob.glob(os.path.join(DATA, "opensubdiv-shapes", "*.obj")))


@pytest.mark.parametrize("path", SHAPES, ids=[os.path.basename(p) for p in SHAPES])
def test_bfr_regression_shapes(path):
    """OpenSubdiv's regression shapes (their tags and options): LimitSurface against Bfr::Surface::Evaluate.
    catmark_nonman_edges repeats a vertex in a face, which warp_subdiv refuses; catmark_chaikin1 is compared with
    OpenSubdiv's Far limit instead (Bfr 3.5 differs from Far's own Chaikin refinement by about 1e-3)."""
    peer = _peer()
    name = os.path.basename(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            data = read_obj(path)
        except SubdivInputError:
            pytest.skip("faces that repeat a vertex are refused (see tests/test_osd_differential.py)")
    scheme = "loop" if name.startswith("loop") else "catmull-clark"
    opts = data.options
    if opts.get("crease_method") == "chaikin":
        o = ws.Options(scheme=scheme, rules="opensubdiv", crease_method="chaikin", precision="float64")
        res = peer.refine(data.mesh.points, data.mesh.face_vertex_counts, data.mesh.face_vertex_indices, 5,
                          scheme="catmark", creasing="chaikin", creases=data.mesh.creases,
                          crease_sharpness=data.mesh.crease_sharpness, limit=True)
        surface = ws.LimitSurface(data.mesh, options=o)
        refiner = ws.Refiner(data.mesh, 5, options=o)
        face, uv, sub = refined_face_params(refiner.hierarchy, 5)
        face, uv = to_face_uv(surface, face, uv, sub)
        ev = surface.evaluate(np.repeat(face, 4), uv[..., 0].ravel(), uv[..., 1].ravel())
        verts = refiner.hierarchy.final.corner_vert.reshape(-1, 4).ravel()
        np.testing.assert_allclose(ev.points, res.limit_points[verts], atol=1e-9)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        compare_with_bfr(peer, data.mesh, scheme, boundary=opts.get("boundary", "edge-and-corner"))


def random_tagged_mesh(rng, name):
    """A test mesh with random infinitely sharp and semi-sharp creases and corners."""
    base = load_mesh(name)
    edges = base.edges.edge_verts
    pick = rng.choice(len(edges), max(1, len(edges) // 5), replace=False)
    sharp = rng.choice([0.5, 1.5, 3.0, 10.0], len(pick))
    corners = rng.choice(base.num_vertices, max(1, base.num_vertices // 6), replace=False)
    corner_sharp = rng.choice([2.0, 10.0], len(corners))
    points = base.points + 0.05 * rng.standard_normal(base.points.shape)
    return ws.Mesh(points, base.face_vertex_counts, base.face_vertex_indices, creases=edges[pick],
                   crease_sharpness=sharp, corners=corners, corner_sharpness=corner_sharp)


@pytest.mark.parametrize("seed", range(4))
def test_bfr_random_tagged_meshes(seed):
    """Random creases, corners and semi-sharp tags on closed and open meshes (boundaries, extraordinary vertices,
    n-gons under Catmull-Clark), three boundary modes, both schemes: LimitSurface against Bfr."""
    peer = _peer()
    rng = np.random.default_rng(seed)
    cases = [("cube", "catmull-clark"), ("quad_lshape", "catmull-clark"), ("mixed_prism", "catmull-clark"),
             ("icosahedron", "loop"), ("tri_grid3x3", "loop")]
    boundary = ["edge-and-corner", "edge-only", "none"][seed % 3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, scheme in cases[seed % 2::2]:
            compare_with_bfr(peer, random_tagged_mesh(rng, name), scheme, boundary=boundary, n=600, seed=seed)


def test_bfr_tessellation_coordinates():
    """Bfr::Tessellation's coordinates of every face (uniform rate 4), evaluated by LimitSurface, give Bfr's
    points; and LimitSurface.tessellate with the same rate has, face by face, the same (u, v) on quads and
    triangles."""
    peer = _peer()
    for name, scheme in (("mixed_prism", "catmull-clark"), ("icosahedron", "loop"), ("quad_lshape", "catmull-clark")):
        mesh = load_mesh(name)
        surface = ws.LimitSurface(mesh, scheme=scheme, rules="opensubdiv")
        rec = peer.mesh_request(mesh, 0, scheme="catmark" if scheme == "catmull-clark" else "loop")
        t = peer.bfr_tessellate(rec, np.full(len(mesh.face_vertex_counts), 4))
        offsets = t["coord_offsets"]
        faces = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
        ev = surface.evaluate(faces, t["coords"][:, 0], t["coords"][:, 1])
        np.testing.assert_allclose(ev.points, t["points"], atol=1e-9 * np.abs(mesh.points).max())
        ours = surface.tessellate(rate=4)
        counts = mesh.face_vertex_counts
        for f in np.flatnonzero(counts == (4 if scheme == "catmull-clark" else 3)):
            mine = np.unique(np.round(ours.face_uv[np.repeat(ours.face_base_face, ours.face_vertex_counts) == f], 9),
                             axis=0)
            theirs = np.unique(np.round(t["coords"][offsets[f]:offsets[f + 1]], 9), axis=0)
            np.testing.assert_allclose(mine, theirs)


BFR_FV_CASES = [("mixed_prism", "catmull-clark", FV_MODES), ("quad_lshape", "catmull-clark", FV_MODES),
                ("cube", "catmull-clark", FV_MODES),
                ("icosahedron", "loop", FV_MODES[2:]), ("tri_grid3x3", "loop", FV_MODES[2:])]


@pytest.mark.parametrize("name,scheme,modes", BFR_FV_CASES, ids=[c[0] + "-" + c[1] for c in BFR_FV_CASES])
def test_bfr_face_varying(name, scheme, modes):
    """Face-varying channels with seams against Bfr's face-varying surfaces (InitFaceVaryingSurface, the
    channel's interpolation mode): values to 1e-10 and derivatives to 1e-8 (relative) where Bfr is exact (its
    result does not change at approximation level 10), values within 1e-4 of Bfr at level 10 everywhere.
    Loop under "none" and "corners-only": see test_bfr_loop_face_varying_differs_from_far."""
    peer = _peer()
    mesh = load_mesh(name)
    values, idx = seamed_channel(mesh, np.random.default_rng(RNG_SEED))
    surface = ws.LimitSurface(mesh, scheme=scheme, rules="opensubdiv")
    f, u, v = sample(surface, 600, np.random.default_rng(RNG_SEED))
    osd_scheme = "catmark" if scheme == "catmull-clark" else "loop"
    for mode in modes:
        rec = peer.mesh_request(mesh, 0, scheme=osd_scheme, fvar=(values, idx), fvar_linear=mode)
        b = peer.bfr_evaluate(rec, f, np.c_[u, v])
        b10 = peer.bfr_evaluate(rec, f, np.c_[u, v], approx_smooth=10, approx_sharp=10)
        assert b["fvar_valid"].all()
        ours = surface.evaluate_face_varying(values, idx, f, u, v, mode=mode, derivatives=int(mode != "all"))
        exact = np.linalg.norm(b["fvar_points"] - b10["fvar_points"], axis=1) < 1e-12
        assert exact.mean() > 0.6, mode
        d = np.linalg.norm(ours.values - b["fvar_points"], axis=1)
        assert d[exact].max() < 1e-10, (mode, d[exact].max())
        assert np.linalg.norm(ours.values - b10["fvar_points"], axis=1).max() < 1e-4, mode
        if mode != "all":
            for key in ("du", "dv"):
                ref = b["fvar_" + key][exact]
                size = np.maximum(np.linalg.norm(ref, axis=1), 1e-3)
                rel = np.linalg.norm(getattr(ours, key)[exact] - ref, axis=1) / size
                assert rel.max() < 1e-8, (mode, key, rel.max())


def test_bfr_loop_face_varying_differs_from_far():
    """Bfr 3.5's Loop face-varying surface under "none" (and "corners-only") interpolates a seam value at a
    vertex with three values where OpenSubdiv's own refinement (Far, which warp-subdiv's refine matches) smooths
    it: at that corner, Far's refined value converges (levels 2, 4, 6) to evaluate_face_varying's, away from
    Bfr's. warp-subdiv follows Far (this test fails if Bfr or Far change)."""
    peer = _peer()
    mesh = load_mesh("tri_grid3x3")
    values, idx = seamed_channel(mesh, np.random.default_rng(RNG_SEED))
    surface = ws.LimitSurface(mesh, scheme="loop", rules="opensubdiv")
    face, corner = 15, 0  # corner 45: vertex 9 (valence 6), values 27, 28, 29 around it
    uv = surface.vertex_uv([face], [corner])
    ours = surface.evaluate_face_varying(values, idx, [face], uv[:, 0], uv[:, 1], mode="none").values[0]
    rec = peer.mesh_request(mesh, 0, scheme="loop", fvar=(values, idx), fvar_linear="none")
    bfr = peer.bfr_evaluate(rec, [face], uv)["fvar_points"][0]
    np.testing.assert_allclose(bfr, values[idx[3 * face + corner]], atol=1e-12)  # Bfr: the value itself
    far = []
    for level in (2, 4, 6):
        out = peer.refine(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, level, scheme="loop",
                          fvar_linear="none", fvar=(values, idx))
        lv = out.levels[level]
        far.append(lv.fvar_values[lv.fvar_indices[3 * face * 4 ** level + corner]])  # child 0 keeps corner 0
    errors = [np.linalg.norm(x - ours) for x in far]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 2e-3
    assert np.linalg.norm(bfr - ours) > 0.1
