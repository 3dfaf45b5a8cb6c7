"""The paper's claims as properties of the implementation (docs/rules.md sections 6 to 11).

Local subdivision matrices are read off the implementation itself: a patch whose vertex 0 has the wanted
neighbourhood is refined with unit basis vectors as vertex data through Refiner.evaluate, and the rows and
columns of vertex 0's local vector are kept (tests/fans.py).
"""
import numpy as np
import pytest
from numpy import pi

import warp_subdiv as ws
from conftest import dense, load_mesh
from fans import local_ids, local_matrix, only_at_centre, options_for, patch
from warp_subdiv.rules import limit_masks as M
from warp_subdiv.rules.weights import SECTOR_CONCAVE, SECTOR_CONVEX, SECTOR_CREASE

KIND = {"crease": SECTOR_CREASE, "convex": SECTOR_CONVEX, "concave": SECTOR_CONCAVE}

# docs/rules.md section 10: (scheme, configuration, k, alpha, Loop beta, leading eigenvalues by modulus at s = 0)
TABLE_10 = [
    ('loop', 'interior', 3, None, 'warren', [1.0, 0.25, 0.25, 0.0625]),
    ('loop', 'interior', 4, None, 'warren', [1.0, 0.375, 0.375, 0.25, 0.125]),
    ('loop', 'interior', 5, None, 'warren', [1.0, 0.4523, 0.4523, 0.25, 0.1727, 0.1727]),
    ('loop', 'interior', 6, None, 'warren', [1.0, 0.5, 0.5, 0.25, 0.25, 0.25, 0.125]),
    ('loop', 'interior', 3, None, 'loop', [1.0, 0.25, 0.25, 0.0625]),
    ('loop', 'interior', 4, None, 'loop', [1.0, 0.375, 0.375, 0.1406, 0.125]),
    ('loop', 'interior', 5, None, 'loop', [1.0, 0.4523, 0.4523, 0.2045, 0.1727, 0.1727]),
    ('loop', 'interior', 6, None, 'loop', [1.0, 0.5, 0.5, 0.25, 0.25, 0.25, 0.125]),
    ('catmull-clark', 'interior', 3, None, 'loop', [1.0, 0.4101, 0.4101, 0.1667, 0.1524, 0.1524, 0.0]),
    ('catmull-clark', 'interior', 4, None, 'loop', [1.0, 0.5, 0.5, 0.25, 0.25, 0.25, 0.125]),
    ('catmull-clark', 'interior', 5, None, 'loop', [1.0, 0.55, 0.55, 0.3401, 0.3401, 0.3225, 0.1838]),
    ('catmull-clark', 'interior', 6, None, 'loop', [1.0, 0.5797, 0.5797, 0.4101, 0.4101, 0.375, 0.25]),
    ('loop', 'crease', 1, None, 'loop', [1.0, 0.5, 0.25]),
    ('loop', 'crease', 2, None, 'loop', [1.0, 0.5, 0.5, 0.25]),
    ('loop', 'crease', 3, None, 'loop', [1.0, 0.5, 0.5, 0.25, 0.25]),
    ('loop', 'crease', 4, None, 'loop', [1.0, 0.5, 0.5, 0.3232, 0.25, 0.1464]),
    ('loop', 'crease', 5, None, 'loop', [1.0, 0.5, 0.5, 0.375, 0.25, 0.2205, 0.0955]),
    ('loop', 'crease', 6, None, 'loop', [1.0, 0.5, 0.5, 0.4085, 0.2835, 0.25, 0.1585]),
    ('loop', 'convex', 1, pi/2, 'loop', [1.0, 0.5, 0.5]),
    ('loop', 'convex', 2, pi/2, 'loop', [1.0, 0.5, 0.5, 0.3232]),
    ('loop', 'convex', 3, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4085, 0.1585]),
    ('loop', 'convex', 4, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4458, 0.269, 0.0923]),
    ('loop', 'convex', 5, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4645, 0.3395, 0.185, 0.06]),
    ('loop', 'convex', 6, pi/2, 'loop', [1.0, 0.5, 0.5, 0.475, 0.3835, 0.2585, 0.1335]),
    ('loop', 'convex', 2, 0.9*pi, 'loop', [1.0, 0.5, 0.5, 0.4609]),
    ('loop', 'convex', 4, 0.9*pi, 'loop', [1.0, 0.5, 0.5, 0.4867, 0.3099, 0.1331]),
    ('loop', 'convex', 6, 0.9*pi, 'loop', [1.0, 0.5, 0.5, 0.4938, 0.4022, 0.2772, 0.1522]),
    ('loop', 'concave', 2, pi/2, 'loop', [1.0, 0.6768, 0.5, 0.5]),
    ('loop', 'concave', 3, pi/2, 'loop', [1.0, 0.625, 0.5, 0.5, 0.375]),
    ('loop', 'concave', 4, pi/2, 'loop', [1.0, 0.5811, 0.5, 0.5, 0.4043, 0.2276]),
    ('loop', 'concave', 5, pi/2, 'loop', [1.0, 0.5553, 0.5, 0.5, 0.4303, 0.2758, 0.1508]),
    ('loop', 'concave', 6, pi/2, 'loop', [1.0, 0.5397, 0.5, 0.5, 0.4482, 0.3232, 0.1982]),
    ('loop', 'concave', 2, 0.9*pi, 'loop', [1.0, 0.5391, 0.5, 0.5]),
    ('loop', 'concave', 4, 0.9*pi, 'loop', [1.0, 0.5144, 0.5, 0.5, 0.3376, 0.1609]),
    ('loop', 'concave', 6, 0.9*pi, 'loop', [1.0, 0.5068, 0.5, 0.5, 0.4153, 0.2903, 0.1653]),
    ('catmull-clark', 'crease', 1, None, 'loop', [1.0, 0.5, 0.25, 0.25]),
    ('catmull-clark', 'crease', 2, None, 'loop', [1.0, 0.5, 0.5, 0.25, 0.25, 0.125]),
    ('catmull-clark', 'crease', 3, None, 'loop', [1.0, 0.5, 0.5, 0.3476, 0.25, 0.25, 0.0899]),
    ('catmull-clark', 'crease', 4, None, 'loop', [1.0, 0.5, 0.5, 0.4028, 0.2985, 0.25, 0.25]),
    ('catmull-clark', 'crease', 5, None, 'loop', [1.0, 0.5, 0.5, 0.4339, 0.35, 0.2788, 0.25]),
    ('catmull-clark', 'crease', 6, None, 'loop', [1.0, 0.5, 0.5, 0.4525, 0.3868, 0.3198, 0.2691]),
    ('catmull-clark', 'convex', 1, pi/2, 'loop', [1.0, 0.5, 0.5, 0.25]),
    ('catmull-clark', 'convex', 2, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4028, 0.25, 0.0454]),
    ('catmull-clark', 'convex', 3, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4525, 0.3198, 0.25, 0.0262]),
    ('catmull-clark', 'convex', 4, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4723, 0.3816, 0.2892, 0.25]),
    ('catmull-clark', 'convex', 5, pi/2, 'loop', [1.0, 0.5, 0.5, 0.482, 0.4186, 0.3396, 0.275]),
    ('catmull-clark', 'convex', 6, pi/2, 'loop', [1.0, 0.5, 0.5, 0.4874, 0.4412, 0.3779, 0.3142]),
    ('catmull-clark', 'convex', 2, 0.9*pi, 'loop', [1.0, 0.5, 0.5, 0.4749, 0.25, 0.111]),
    ('catmull-clark', 'convex', 4, 0.9*pi, 'loop', [1.0, 0.5, 0.5, 0.4929, 0.3972, 0.2959, 0.25]),
    ('catmull-clark', 'convex', 6, 0.9*pi, 'loop', [1.0, 0.5, 0.5, 0.4968, 0.4496, 0.3845, 0.3184]),
    ('catmull-clark', 'concave', 2, pi/2, 'loop', [1.0, 0.6333, 0.5, 0.5, 0.25, 0.1685]),
    ('catmull-clark', 'concave', 3, pi/2, 'loop', [1.0, 0.5797, 0.5, 0.5, 0.4101, 0.25, 0.1524]),
    ('catmull-clark', 'concave', 4, pi/2, 'loop', [1.0, 0.5472, 0.5, 0.5, 0.442, 0.3206, 0.25]),
    ('catmull-clark', 'concave', 5, pi/2, 'loop', [1.0, 0.5306, 0.5, 0.5, 0.4608, 0.3697, 0.2872]),
    ('catmull-clark', 'concave', 6, pi/2, 'loop', [1.0, 0.5214, 0.5, 0.5, 0.4719, 0.4028, 0.3303]),
    ('catmull-clark', 'concave', 2, 0.9*pi, 'loop', [1.0, 0.5269, 0.5, 0.5, 0.25, 0.1372]),
    ('catmull-clark', 'concave', 4, 0.9*pi, 'loop', [1.0, 0.5079, 0.5, 0.5, 0.4091, 0.3016, 0.25]),
    ('catmull-clark', 'concave', 6, 0.9*pi, 'loop', [1.0, 0.5036, 0.5, 0.5, 0.4557, 0.3894, 0.3215]),]


def spectrum(S):
    return np.sort(np.abs(np.linalg.eigvals(S)))[::-1]


def theta_of(kind, k, alpha):
    return {"crease": pi / k, "convex": alpha / k, "concave": (2 * pi - alpha) / k}[kind]


def linear_matrix(scheme, mesh, kind, k, **options):
    """The local matrix of the linear rules alone (s = 0), from the level's stencil table."""
    options.update(options_for(kind, k))
    r = ws.Refiner(mesh, 1, scheme=scheme, device="cpu", precision="float64", **options)
    ids0, ids1 = local_ids(scheme, mesh, kind, k, **options)
    return dense(r.tables[0])[np.ix_(ids1, ids0)]


@pytest.mark.parametrize("scheme,kind,k,alpha,beta,expected", TABLE_10)
def test_spectrum_at_s0_matches_rules_table(scheme, kind, k, alpha, beta, expected):
    mesh = patch(scheme, k, kind, alpha=alpha or pi / 2)
    S = linear_matrix(scheme, mesh, kind, k, loop_beta=beta)
    got = spectrum(S)[: len(expected)]
    np.testing.assert_allclose(got, expected, atol=6e-5)


def sector_cases():
    for scheme in ("loop", "catmull-clark"):
        for k in range(1, 7):
            yield scheme, "crease", k, pi / 2
        for alpha in (pi / 2, 2 * pi / 3, 0.9 * pi):
            for k in range(1, 7):
                yield scheme, "convex", k, alpha
            for k in range(2, 7):
                yield scheme, "concave", k, alpha


def kept_values(scheme, kind, k):
    """Eigenvalues flatness leaves alone: 1, 1/2, 1/2 (only one 1/2 when k = 1) and a crease's B-spline 1/4."""
    kept = [1.0, 0.5] if k == 1 and kind == "crease" else [1.0, 0.5, 0.5]
    if kind == "crease":
        kept.append(0.25)
    return kept


def remove_once(values, kept):
    values = list(values)
    for v in kept:
        i = int(np.argmin(np.abs(np.array(values) - v)))
        assert abs(values[i] - v) < 1e-6, (values, v)
        values.pop(i)
    return np.array(values)


@pytest.mark.parametrize("scheme,kind,k,alpha", list(sector_cases()))
def test_flatness_scales_the_other_eigenvalues_by_one_minus_s(scheme, kind, k, alpha):
    mesh = patch(scheme, k, kind, alpha=alpha)
    S0 = linear_matrix(scheme, mesh, kind, k)
    theta = theta_of(kind, k, alpha)
    s_star = float(M.optimal_flatness(scheme, KIND[kind], k, theta))
    kept = kept_values(scheme, kind, k)
    rest0 = remove_once(np.linalg.eigvals(S0).real if False else spectrum(S0), kept)
    s_values = [s_star, 0.3, 1.0]
    if kind == "concave":
        s_min = float(M.concave_min_flatness(scheme, k, theta))
        assert s_star > s_min
        assert rest0.max() > 0.5  # 1/2 is not subdominant without flatness (docs/rules.md section 10)
        s_values = [s_star, 1.0] + ([0.3] if 0.3 > s_min else [])
    for s in s_values:
        S = local_matrix(scheme, mesh, kind, k, flatness=only_at_centre(mesh, s))
        got = spectrum(S)
        expected = np.sort(np.concatenate([kept, (1 - s) * rest0]))[::-1]
        np.testing.assert_allclose(got, expected, atol=1e-7, err_msg=f"s = {s}")
        if s == s_star and rest0.size and (1 - s) * rest0.max() > 1e-12:
            # s* bounds the curvature: the largest scaled eigenvalue becomes lambda^2 = 1/4, or stays below
            assert (1 - s) * rest0.max() <= 0.25 + 1e-9
            if s > 0:
                np.testing.assert_allclose((1 - s) * rest0.max(), 0.25, atol=1e-9)


@pytest.mark.parametrize("scheme,kind,k,alpha", [c for c in sector_cases() if c[2] >= 2])
def test_sector_eigenvectors_and_masks(scheme, kind, k, alpha):
    """l^m S = lambda l^m and S x^m = lambda x^m with biorthonormal masks, before and after flatness."""
    mesh = patch(scheme, k, kind, alpha=alpha)
    theta = theta_of(kind, k, alpha)
    for s in (0.0, float(M.optimal_flatness(scheme, KIND[kind], k, theta)), 1.0):
        if kind == "concave" and s == 0.0:
            S = linear_matrix(scheme, mesh, kind, k)
        else:
            S = local_matrix(scheme, mesh, kind, k, flatness=only_at_centre(mesh, s))
        m = M.sector_masks(scheme, np.array([KIND[kind]]), k, np.array([theta]), np.array([s]))
        x0 = np.ones(S.shape[0])
        for l, lam in ((m.l0[0], 1.0), (m.l1[0], 0.5), (m.l2[0], 0.5)):
            np.testing.assert_allclose(l @ S, lam * l, atol=1e-10)
        for x, lam in ((x0, 1.0), (m.x1[0], 0.5), (m.x2[0], 0.5)):
            np.testing.assert_allclose(S @ x, lam * x, atol=1e-10)
        L = np.stack([m.l0[0], m.l1[0], m.l2[0]])
        X = np.stack([x0, m.x1[0], m.x2[0]], axis=1)
        np.testing.assert_allclose(L @ X, np.eye(3), atol=1e-10)


@pytest.mark.parametrize("scheme", ["loop", "catmull-clark"])
@pytest.mark.parametrize("k", [3, 4, 5, 6, 7, 8])
def test_interior_eigenvectors_and_masks(scheme, k):
    mesh = patch(scheme, k, "interior")
    S = local_matrix(scheme, mesh, "interior", k)
    m = M.interior_masks(scheme, k, 1)
    tk = pi / k
    if scheme == "loop":
        lam = 3 / 8 + np.cos(2 * tk) / 4
    else:
        lam = (5 + np.cos(2 * tk) + np.cos(tk) * np.sqrt(2 * (9 + np.cos(2 * tk)))) / 16
    np.testing.assert_allclose(spectrum(S)[1:3], [lam, lam], atol=1e-10)
    np.testing.assert_allclose(m.l0[0] @ S, m.l0[0], atol=1e-10)
    for l, x in ((m.l1[0], m.x1[0]), (m.l2[0], m.x2[0])):
        np.testing.assert_allclose(l @ S, lam * l, atol=1e-10)
        np.testing.assert_allclose(S @ x, lam * x, atol=1e-10)
    L = np.stack([m.l0[0], m.l1[0], m.l2[0]])
    X = np.stack([np.ones(S.shape[0]), m.x1[0], m.x2[0]], axis=1)
    np.testing.assert_allclose(L @ X, np.eye(3), atol=1e-10)


def test_rules_table_11_s_values():
    """s* and s_min against docs/rules.md section 11."""
    cases = [
        ("loop", "crease", 4, pi / 4, 0.22654, 0), ("loop", "crease", 6, pi / 6, 0.38800, 0),
        ("loop", "convex", 4, pi / 8, 0.43922, 0), ("loop", "concave", 2, 3 * pi / 4, 0.63060, 0.26120),
        ("loop", "concave", 3, pi / 2, 0.60000, 0.20000), ("loop", "concave", 6, (1.5 * pi) / 6, 0.53681, 0.07361),
        ("catmull-clark", "crease", 2, pi / 2, 0.0, 0), ("catmull-clark", "crease", 3, pi / 3, 0.28078, 0),
        ("catmull-clark", "crease", 6, pi / 6, 0.44750, 0), ("catmull-clark", "convex", 4, pi / 8, 0.47073, 0),
        ("catmull-clark", "concave", 2, 0.75 * pi, 0.60525, 0.21049),
        ("catmull-clark", "concave", 4, 1.5 * pi / 4, 0.54314, 0.08627),
    ]
    for scheme, kind, k, theta, s_star, s_min in cases:
        np.testing.assert_allclose(M.optimal_flatness(scheme, KIND[kind], k, theta), s_star, atol=1e-5)
        if kind == "concave":
            np.testing.assert_allclose(M.concave_min_flatness(scheme, k, theta), s_min, atol=1e-5)


# ------------------------------------------------------------------------------------------------------
# surfaces: no gap, tangent-plane continuity, no fold, limit positions and normals


def boundary_points(refined):
    """Positions of the vertices on boundary edges (edges with one face) of a refined mesh, sorted."""
    counts, idx = refined.face_vertex_counts, refined.face_vertex_indices.astype(np.int64)
    n = int(counts[0])
    f = idx.reshape(-1, n)
    a, b = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1)
    key = np.minimum(a, b) * len(refined.points) + np.maximum(a, b)
    uniq, cnt = np.unique(key, return_counts=True)
    on = np.unique(np.concatenate([uniq[cnt == 1] // len(refined.points), uniq[cnt == 1] % len(refined.points)]))
    pts = refined.points[on]
    return pts[np.lexsort(pts.T[::-1])]


def same_boundary_meshes():
    """A 3x3 quad grid and a 12-triangle fan with the same 12 boundary points, corners tagged in both."""
    grid = load_mesh("grid3x3")
    corners = [0, 3, 12, 15]
    a = ws.Mesh(grid.points, grid.face_vertex_counts, grid.face_vertex_indices, corners=corners)
    ring = [0, 1, 2, 3, 7, 11, 15, 14, 13, 12, 8, 4]
    pts = np.vstack([grid.points, [[1.5, 1.5, -0.7]]])
    tris = [[16, ring[i], ring[(i + 1) % 12]] for i in range(12)]
    b = ws.Mesh(pts, [3] * 12, np.array(tris).reshape(-1), corners=corners)
    return a, b


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("flatness", [None, 1.0])
def test_no_gap_between_meshes_sharing_a_boundary(scheme, flatness):
    """Fig. 10a: the boundary curve depends on the boundary polygon alone, at every level."""
    a, b = same_boundary_meshes()
    for level in range(1, 5):
        ra = ws.refine(a, level, scheme=scheme, flatness=flatness, device="cpu", precision="float64")
        rb = ws.refine(b, level, scheme=scheme, flatness=flatness, device="cpu", precision="float64")
        pa, pb = boundary_points(ra), boundary_points(rb)
        assert len(pa) == 12 * 2 ** level
        np.testing.assert_allclose(pa, pb, atol=1e-12)


def ring_normal(refined, vertex):
    """The area-weighted normal of the faces around a vertex of a refined mesh."""
    n = int(refined.face_vertex_counts[0])
    f = refined.face_vertex_indices.reshape(-1, n)
    around = f[np.any(f == vertex, axis=1)]
    p = refined.points
    normal = np.zeros(3)
    for face in around:
        for i in range(1, n - 1):
            normal += np.cross(p[face[i]] - p[face[0]], p[face[i + 1]] - p[face[0]])
    return normal / np.linalg.norm(normal)


@pytest.mark.parametrize("scheme,k", [("catmull-clark", 3), ("catmull-clark", 5), ("loop", 5), ("loop", 7)])
def test_tangent_plane_converges_at_twisted_extraordinary_boundary_vertex(scheme, k):
    """Fig. 3 / 10b: at a boundary vertex with k faces and a twisted (non-planar) ring, the normal estimated
    from the refined ring converges geometrically to the limit normal."""
    mesh = patch(scheme, k, "crease", twist=0.35)
    normals = []
    for level in range(1, 7):
        normals.append(ring_normal(ws.refine(mesh, level, scheme=scheme, device="cpu", precision="float64"), 0))
    steps = [np.arccos(np.clip(a @ b, -1, 1)) for a, b in zip(normals[:-1], normals[1:])]
    assert steps[-1] < 0.6 * steps[0]
    assert all(b <= 0.75 * a + 1e-12 for a, b in zip(steps[:-1], steps[1:])), steps
    limit = ws.refine(mesh, 4, scheme=scheme, device="cpu", precision="float64").limit_normals()[0]
    assert np.arccos(np.clip(normals[-1] @ limit, -1, 1)) < 0.02


def planar_lshape(n=2, pull=0.0):
    """An L of (2n)^2 - n^2 unit quads in the plane; the concave corner vertex, moved by ``pull`` along (1, 1)."""
    ids, pts = {}, []
    for j in range(2 * n + 1):
        for i in range(2 * n + 1):
            if i > n and j > n:
                continue
            ids[i, j] = len(pts)
            pts.append([i, j, 0.0])
    quads = [[ids[i, j], ids[i + 1, j], ids[i + 1, j + 1], ids[i, j + 1]]
             for j in range(2 * n) for i in range(2 * n) if not (i >= n and j >= n)]
    pts = np.array(pts, dtype=float)
    c = ids[n, n]
    pts[c, :2] += pull
    return pts, np.array(quads), c, ids[n - 1, n]


def folded_faces_near(refined, centre, radius):
    n = int(refined.face_vertex_counts[0])
    f = refined.face_vertex_indices.reshape(-1, n)
    p = refined.points
    near = np.linalg.norm(p[f].mean(axis=1)[:, :2] - centre[:2], axis=1) < radius
    area = np.full(len(f), np.inf)
    for i in range(1, n - 1):
        a, b = p[f[:, i]] - p[f[:, 0]], p[f[:, i + 1]] - p[f[:, 0]]
        area = np.minimum(area, a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    return int(np.sum(near & (area <= 0)))


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_no_fold_at_concave_corner(scheme):
    """Fig. 2 and 11: with the corner of an L pulled into the L, OpenSubdiv's rules fold the surface near it;
    the concave-corner rules do not (no refined face near the corner flips its orientation)."""
    pts, quads, c, neighbour = planar_lshape(2, pull=-0.6)
    faces = quads if scheme == "catmull-clark" else np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    mesh = ws.Mesh(pts, [faces.shape[1]] * len(faces), faces.reshape(-1), corners=[c], concave=[[c, neighbour]])
    ours = ws.refine(mesh, 6, scheme=scheme, device="cpu", precision="float64")
    osd = ws.refine(mesh, 6, scheme=scheme, rules="opensubdiv", device="cpu", precision="float64")
    assert folded_faces_near(ours, pts[c], 0.3) == 0
    assert folded_faces_near(osd, pts[c], 0.3) > 10
    # and the concave corner's limit normal keeps pointing up (docs/rules.md section 9's sign flip)
    np.testing.assert_allclose(ours.limit_normals()[c], [0, 0, 1], atol=1e-9)


@pytest.mark.parametrize("scheme,name", [("catmull-clark", "cube"), ("catmull-clark", "cube_creased"),
                                         ("catmull-clark", "quad_lshape"), ("catmull-clark", "mixed_prism"),
                                         ("loop", "icosahedron"), ("loop", "tri_halffan"), ("loop", "tri_grid3x3")])
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_refinement_converges_to_limit_points(scheme, name, rules):
    mesh = load_mesh(name)
    deep = ws.refine(mesh, 6, scheme=scheme, rules=rules, device="cpu", precision="float64")
    size = np.ptp(mesh.points, axis=0).max()
    for start in (0, 1):
        coarse = ws.refine(mesh, start, scheme=scheme, rules=rules, device="cpu", precision="float64")
        limit = coarse.limit_points()
        n = len(coarse.points)
        err = np.linalg.norm(deep.points[:n] - limit, axis=1).max()
        assert err < 4e-3 * size, (start, err)
        mid = ws.refine(mesh, 4, scheme=scheme, rules=rules, device="cpu", precision="float64")
        assert err < 0.3 * np.linalg.norm(mid.points[:n] - limit, axis=1).max() + 1e-12


@pytest.mark.parametrize("scheme,name", [("catmull-clark", "cube"), ("loop", "icosahedron"),
                                         ("catmull-clark", "cube_creased"), ("loop", "octahedron")])
def test_limit_normals_point_outward(scheme, name):
    out = ws.refine(load_mesh(name), 2, scheme=scheme, device="cpu", precision="float64")
    n = out.limit_normals()
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    centred = out.limit_points() - out.limit_points().mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", n, centred) > 0)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_planar_mesh_normals_are_up_everywhere(scheme):
    """Interior, crease, convex and concave corner vertices of a planar counter-clockwise mesh all get +z."""
    pts, quads, c, neighbour = planar_lshape(2)
    faces = quads if scheme == "catmull-clark" else np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    mesh = ws.Mesh(pts, [faces.shape[1]] * len(faces), faces.reshape(-1), corners=[c], concave=[[c, neighbour]])
    for level in (0, 1, 2):
        n = ws.refine(mesh, level, scheme=scheme, device="cpu", precision="float64").limit_normals()
        np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (len(n), 1)), atol=1e-9)


# ------------------------------------------------------------------------------------------------------
# prescribed normals (docs/rules.md section 7)


def mask_tangents(scheme, mesh, level, vertex, points, **options):
    """Tangents l^1.p, l^2.p of an interior vertex's ring at ``level`` (the masks of docs/rules.md 8)."""
    k = int(np.sum(mesh.face_vertex_indices == vertex))
    ids = local_ids(scheme, mesh, "interior", k, levels=level)[-1] if vertex == 0 else None
    from warp_subdiv.tables.projections import ring_local_vectors
    from warp_subdiv.topology import base_level, refine_level

    lv = base_level(mesh, scheme, "edge-and-corner", "piecewise-smooth")
    for _ in range(level):
        lv = refine_level(lv)
    ids = ring_local_vectors(lv, np.array([vertex]), k)[0]
    m = M.interior_masks(scheme, k, 1)
    return m.l1[0] @ points[ids], m.l2[0] @ points[ids]


def normal_error(t1, t2, n):
    """|normal components of the tangents| / |tangential components|: tan of the angle to the tangent plane."""
    nc = np.hypot(t1 @ n, t2 @ n)
    tc = np.linalg.norm(np.concatenate([t1 - (t1 @ n) * n, t2 - (t2 @ n) * n]))
    return nc / tc


@pytest.mark.parametrize("scheme,name", [("loop", "icosahedron"), ("catmull-clark", "cube")])
def test_prescribed_normal_interior(scheme, name):
    base = load_mesh(name)
    n = base.points[0] / np.linalg.norm(base.points[0]) + [0.5, -0.3, 0.2]  # outward, tilted
    n /= np.linalg.norm(n)
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, normals=([0], [n]))
    plain = ws.Refiner(base, 5, scheme=scheme, device="cpu", precision="float64")
    for s in (1.0, 0.5, 0.2):
        errors = []
        for level in range(1, 6):
            r = ws.Refiner(mesh, level, scheme=scheme, normal_strength=s, device="cpu", precision="float64")
            pts = r.evaluate(mesh.points)
            t1, t2 = mask_tangents(scheme, mesh, level, 0, pts)
            errors.append(normal_error(t1, t2, n))
            nn = np.cross(t1, t2)
            if s == 1.0:  # one step makes the mask normal n
                np.testing.assert_allclose(nn / np.linalg.norm(nn), n, atol=1e-6)
        if s < 1.0:  # the error shrinks by (1 - s) per level
            np.testing.assert_allclose(np.array(errors[1:]) / errors[:-1], 1 - s, rtol=1e-6)
        # the vertex's limit position does not move
        np.testing.assert_allclose(r.limit_points(pts)[0], plain.limit_points(plain.evaluate(base.points))[0],
                                   atol=1e-12)
        # its reported limit normal is n
        np.testing.assert_allclose(r.limit_normals(pts)[0], n, atol=1e-6)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_prescribed_normal_on_boundary_keeps_the_boundary_a_curve_of_crease_points(scheme):
    """A boundary vertex with a prescribed normal: the normal is reached and the boundary curve still depends
    only on boundary points (moving an interior control vertex leaves it unchanged)."""
    grid = load_mesh("grid3x3" if scheme == "catmull-clark" else "tri_grid3x3")
    n = np.array([0.6, -0.48, 0.64])
    mesh = ws.Mesh(grid.points, grid.face_vertex_counts, grid.face_vertex_indices, normals=([1], [n]))
    r = ws.Refiner(mesh, 4, scheme=scheme, device="cpu", precision="float64")
    moved = grid.points.copy()
    moved[5] += [0.2, 0.1, 0.4]
    a = ws.Refined(r.evaluate(grid.points), *r.topology(), 4, scheme)
    b = ws.Refined(r.evaluate(moved), *r.topology(), 4, scheme)
    np.testing.assert_allclose(boundary_points(a), boundary_points(b), atol=1e-12)
    plain = ws.refine(grid, 4, scheme=scheme, device="cpu", precision="float64")
    assert np.abs(boundary_points(a) - boundary_points(plain)).max() > 1e-3  # the normal did bend the boundary
    np.testing.assert_allclose(r.limit_normals(a.points)[1], n, atol=1e-12)
