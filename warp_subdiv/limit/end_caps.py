"""End caps of the patch tree: the Bezier patches over faces still irregular at the tree's depth, which
interpolate the exact limit positions of their corners, the corners' tangent planes, and per corner and edge a
derivative along the edge (exact at regular corners, else from the parabola through the edge's limit points).
"""
from __future__ import annotations

import numpy as np

from ..options import Options
from ..rules import CATMULL_CLARK, SMOOTH
from ..rules import limit_masks as M
from ..tables import projections
from ..topology import Level
from .bezier import TRI_BEZIER_INDEX
from .local_refinement import LocalLevel, child_corners, csr_apply, face_corners


# ----------------------------------------------------------------------------------------- end caps
def _limit_data(level: Level, points: np.ndarray, options: Options):
    """Limit positions (V, D) of ``level``'s vertices, the two limit tangents of every tangent pair (T, D) each,
    the unit normal of every pair (T, 3, from the positions: the first three columns) and the pairs of each
    vertex (CSR offsets (V + 1,)): one pair per sector, one for other vertices."""
    o = options
    s = projections.resolve_flatness(level) if o.piecewise_smooth else np.zeros(level.num_sectors)
    tables = projections.limit_tables(level, s, o.loop_beta, o.rules)
    pos = csr_apply(tables.position, points)
    tu = csr_apply(tables.tangent_u, points)
    tv = csr_apply(tables.tangent_v, points)
    normals = np.cross(tu[:, :3], tv[:, :3])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    return pos, tu, tv, normals, tables.vertex_offsets.astype(np.int64)


def _regular_derivatives(level: Level, points: np.ndarray, vertices: np.ndarray, toward: np.ndarray, options):
    """Exact derivatives at regular vertices (valence 4 / 6 interior) along the edge to ``toward``, per unit of
    this level's parameter; NaN where the vertex is not a regular interior vertex of this level."""
    out = np.full((len(vertices), points.shape[1]), np.nan)
    scheme = options.scheme
    k = 4 if scheme == CATMULL_CLARK else 6
    valence = np.diff(level.vert_corner_offsets)[vertices]
    counts = np.diff(level.edge_corner_offsets)
    boundary = np.zeros(level.num_vertices, bool)
    boundary[level.edge_verts[counts != 2].reshape(-1)] = True
    sharp = np.zeros(level.num_vertices, bool)
    sharp[level.edge_verts[level.edge_sharpness > 0].reshape(-1)] = True
    use = (valence == k) & (level.vert_class[vertices] == SMOOTH) & ~boundary[vertices] & ~sharp[vertices]
    if not use.any():
        return out
    vs = vertices[use]
    local = projections.ring_local_vectors(level, vs, k)
    m = M.interior_masks(scheme, k, len(vs), options.loop_beta)
    p = points[local]  # (n, L, D)
    t1 = np.zeros((len(vs), points.shape[1]))
    t2 = np.zeros((len(vs), points.shape[1]))
    for j in range(p.shape[1]):  # term by term: the same operations for every column (as the Bezier conversion sums)
        t1 += m.l1[:, j, None] * p[:, j]
        t2 += m.l2[:, j, None] * p[:, j]
    ring = local[:, 1:1 + k]
    pos = np.argmax(ring == toward[use][:, None], axis=1)
    found = ring[np.arange(len(vs)), pos] == toward[use]
    x1 = m.x1[np.arange(len(vs)), 1 + pos][:, None]
    x2 = m.x2[np.arange(len(vs)), 1 + pos][:, None]
    d = x1 * t1 + x2 * t2
    d[~found] = np.nan
    out[use] = d
    return out


def end_cap_bezier(P: np.ndarray, D_next: np.ndarray, D_prev: np.ndarray, scheme: str) -> np.ndarray:
    """Bezier control points of end caps from corner positions P (F, n, D) and, per corner, the derivatives
    along the edge to the next corner and to the previous one (F, n, D), per unit of the cap's parameter."""
    F, D = len(P), P.shape[-1]
    if scheme == CATMULL_CLARK:
        b = np.zeros((F, 4, 4, D))  # [b (v), a (u)]
        corner_uv = [(0, 0), (3, 0), (3, 3), (0, 3)]
        # (d/du, d/dv) at each corner from its (next, prev) edge derivatives
        du = [D_next[:, 0], -D_prev[:, 1], -D_next[:, 2], D_prev[:, 3]]
        dv = [D_prev[:, 0], D_next[:, 1], -D_prev[:, 2], -D_next[:, 3]]
        for j, (a, bb) in enumerate(corner_uv):
            b[:, bb, a] = P[:, j]
            sa = 1 if a == 0 else -1
            sb = 1 if bb == 0 else -1
            b[:, bb, a + sa] = P[:, j] + sa * du[j] / 3.0
            b[:, bb + sb, a] = P[:, j] + sb * dv[j] / 3.0
            b[:, bb + sb, a + sa] = b[:, bb, a + sa] + b[:, bb + sb, a] - P[:, j]
        return b.reshape(F, 16, D)
    index = {e: n for n, e in enumerate(TRI_BEZIER_INDEX)}
    out = np.zeros((F, 15, D))
    unit = [(4, 0, 0), (0, 4, 0), (0, 0, 4)]
    for j in range(3):
        out[:, index[unit[j]]] = P[:, j]
    for j in range(3):  # edge j from corner j to corner j + 1: elevated cubic Hermite
        a, b_ = j, (j + 1) % 3
        c1 = P[:, a] + D_next[:, a] / 3.0
        c2 = P[:, b_] + D_prev[:, b_] / 3.0
        q = [P[:, a], (P[:, a] + 3 * c1) / 4.0, (c1 + c2) / 2.0, (3 * c2 + P[:, b_]) / 4.0, P[:, b_]]
        for t in range(1, 4):
            e = [0, 0, 0]
            e[a], e[b_] = 4 - t, t
            out[:, index[tuple(e)]] = q[t]
    for j in range(3):  # interior point next to corner j: parallelogram of its two edge neighbours
        e_next = [0, 0, 0]
        e_next[j], e_next[(j + 1) % 3] = 3, 1
        e_prev = [0, 0, 0]
        e_prev[j], e_prev[(j + 2) % 3] = 3, 1
        inner = [1, 1, 1]
        inner[j] = 2
        out[:, index[tuple(inner)]] = out[:, index[tuple(e_next)]] + out[:, index[tuple(e_prev)]] - P[:, j]
    return out


def end_cap_nets(sub: LocalLevel, child: Level, child_points: np.ndarray, faces: np.ndarray, options: Options):
    """Bezier nets of end caps over ``faces`` of ``sub`` (local ids), from the limit masks of ``child`` (one
    level deeper, where the masks of the faces' corners are exact)."""
    scheme = options.scheme
    n = 4 if scheme == CATMULL_CLARK else 3
    level = sub.level
    pos, pair_tu, pair_tv, pair_normals, voff = _limit_data(child, child_points, options)
    corners = face_corners(level, faces, n)
    c = level.corner_vert.astype(np.int64)[corners]  # vertex children keep their ids
    # the child corner of each face corner; its next and previous corners are the children of the face's edges
    # at that corner
    child_corner = child_corners(level, child, corners.reshape(-1), scheme).reshape(corners.shape)
    ccv = child.corner_vert.astype(np.int64)
    mid_next = ccv[child.corner_next(child_corner)]
    mid_prev = ccv[child.corner_prev(child_corner)]
    P = pos[c]
    # tangent plane of each corner: the limit tangents; where a vertex has several sectors, the sector whose
    # normal is closest to the face's own normal at that corner (positions decide: the first three columns)
    geometry = child_points[:, :3]
    geo = np.cross(geometry[mid_next] - geometry[c], geometry[mid_prev] - geometry[c])
    count = voff[c + 1] - voff[c]
    pair = np.where(count > 0, np.minimum(voff[c], max(len(pair_normals) - 1, 0)), -1)
    multi = count > 1
    if multi.any():
        best = np.full(c.shape, -np.inf)
        for t in range(int(count.max())):
            has = multi & (count > t)
            candidate = np.where(has, voff[c] + t, 0)
            score = np.einsum("...c,...c->...", pair_normals[candidate], geo)
            better = has & (score > best)
            pair[better] = candidate[better]
            best = np.where(better, score, best)
    # derivatives along the face's edges, per unit of the face's parameter (twice the child level's), projected
    # onto the tangent plane. The positions' derivative d becomes its orthogonal projection written in the
    # plane's limit tangents, x t_u + y t_v (Gram-Schmidt on the positions' tangents); a data column gets the
    # same combination of its own limit tangents, so every column is a linear function of the control values
    # with the positions' weights. Where the positions' tangents are (nearly) parallel (a singular point, e.g.
    # under normal control) the positions are projected along the pair's normal and data columns are not.
    if not len(pair_tu):  # no tangent pairs at all: nothing to project on
        pair_tu = pair_tv = np.zeros((1, child_points.shape[1]))
        pair_normals = np.zeros((1, 3))
        pair[:] = -1
    t_u = pair_tu[np.maximum(pair, 0)]
    t_v = pair_tv[np.maximum(pair, 0)]
    N = pair_normals[np.maximum(pair, 0)] * (pair >= 0)[..., None]
    g_u, g_v = np.ascontiguousarray(t_u[..., :3]), np.ascontiguousarray(t_v[..., :3])
    len_u = np.sqrt(np.einsum("...c,...c->...", g_u, g_u))
    e1 = g_u / np.where(len_u > 0, len_u, 1.0)[..., None]
    along = np.einsum("...c,...c->...", g_v, e1)
    w = g_v - along[..., None] * e1
    len_w = np.sqrt(np.einsum("...c,...c->...", w, w))
    len_v = np.sqrt(np.einsum("...c,...c->...", g_v, g_v))
    plane = (pair >= 0) & (len_u > 0) & (len_w > 1e-6 * len_v)
    len_u = np.where(plane, len_u, 1.0)
    len_w = np.where(plane, len_w, 1.0)
    D = []
    far = [np.roll(c, -1, axis=1), np.roll(c, 1, axis=1)]
    for mid, end in ((mid_next, far[0]), (mid_prev, far[1])):
        exact = 2.0 * _regular_derivatives(child, child_points, c.reshape(-1), mid.reshape(-1),
                                           options).reshape(c.shape + (child_points.shape[1],))
        parabola = -3.0 * P + 4.0 * pos[mid] - pos[end]
        d = np.where(np.isnan(exact[..., :1]), parabola, exact)
        dg = np.ascontiguousarray(d[..., :3])
        alpha = np.einsum("...c,...c->...", dg, e1)
        beta = np.einsum("...c,...c->...", dg, w) / len_w
        x = (alpha / len_u - beta * along / (len_w * len_u))[..., None]
        y = (beta / len_w)[..., None]
        singular = d.copy()
        singular[..., :3] = dg - np.einsum("...c,...c->...", dg, N)[..., None] * N
        d = np.where(plane[..., None], x * t_u + y * t_v, singular)
        D.append(d)
    return end_cap_bezier(P, D[0], D[1], scheme)
