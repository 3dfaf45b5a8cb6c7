"""How a control face is parameterised by the limit surface: directly (a quad, a Loop triangle), by its quad
sub-faces (a Catmull-Clark n-gon, as Bfr's QUAD_SUBFACES) or by its fan triangles (a Loop polygon), and linear
interpolation of face-corner data inside it in those coordinates (varying primvars, bilinear meshes).
"""
from __future__ import annotations

import numpy as np

from ..mesh import face_offsets_of

#: How a control face is parameterised (``LimitSurface.face_kind``).
DIRECT, SUBFACES, FAN = 0, 1, 2


def corner_weights(surface, faces, uv, *, derivatives: bool = False) -> tuple:
    """Linear interpolation inside control faces (refine's varying primvars, bilinear meshes): (corners (n, m)
    int64 into the face-vertex list, -1 padded; weights (n, m)) such that a value at (face, u, v) is the
    weighted sum of the face's corner values. A quad: bilinear; a Loop triangle: barycentric; a Catmull-Clark
    n-gon: bilinear in the sub-face (corner, edge middles, centre = mean of the corners); a Loop polygon:
    barycentric in its fan triangle (v0, v_k+1, v_k+2). ``derivatives``: also the weights' derivatives
    d/du, d/dv and d2/dudv (each (n, m)): (corners, weights, du, dv, duv)."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    counts = np.asarray(surface.mesh.face_vertex_counts, dtype=np.int64)
    offsets = face_offsets_of(counts)
    n = counts[faces]
    m = max(int(n.max()), 4) if len(n) else 4  # room for a quad's four weights in any case
    W = np.zeros((4, len(faces), m))  # value, d/du, d/dv, d2/dudv
    kind = surface.face_kind[faces]
    u, v = uv[:, 0], uv[:, 1]
    rows = np.arange(len(faces))
    one, zero = np.ones(len(faces)), np.zeros(len(faces))
    quad = (kind == DIRECT) & (n == 4)
    for c, terms in enumerate(([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], [v - 1, 1 - v, v, -v],
                               [u - 1, -u, u, 1 - u], [one, -one, one, -one])):
        for j in range(4):
            W[c, quad, j] = terms[j][quad]
    tri = (kind == DIRECT) & (n == 3)
    for c, terms in enumerate(([1 - u - v, u, v], [-one, one, zero], [-one, zero, one], [zero, zero, zero])):
        for j in range(3):
            W[c, tri, j] = terms[j][tri]
    sub = kind == SUBFACES
    if sub.any():
        w = surface.face_tiles[faces].astype(np.int64)
        tx, ty = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        i = np.clip(ty * w + tx, 0, n - 1)
        s = np.clip(2 * (u - tx), 0, 1)
        t = np.clip(2 * (v - ty), 0, 1)
        # (w00, w10, w11, w01) of the sub-face's own square and their derivatives (ds/du = dt/dv = 2)
        parts = ([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t],
                 [2 * (t - 1), 2 * (1 - t), 2 * t, -2 * t], [2 * (s - 1), -2 * s, 2 * s, 2 * (1 - s)],
                 [4 * one, -4 * one, 4 * one, -4 * one])
        r = rows[sub]
        for c, (w00, w10, w11, w01) in enumerate(parts):
            Wn = np.zeros((len(faces), m))
            Wn[r] += (w11 / np.maximum(n, 1))[sub][:, None] * (np.arange(m)[None] < n[sub][:, None])
            np.add.at(Wn, (r, i[sub]), (w00 + 0.5 * w10 + 0.5 * w01)[sub])
            np.add.at(Wn, (r, ((i + 1) % n)[sub]), (0.5 * w10)[sub])
            np.add.at(Wn, (r, ((i - 1) % n)[sub]), (0.5 * w01)[sub])
            W[c, sub] = Wn[sub]
    fan = kind == FAN
    if fan.any():
        k = np.clip(np.floor(u).astype(np.int64), 0, n - 3)
        s, t = 2 * (u - k), 2 * v
        r = rows[fan]
        for c, (a, b, d) in enumerate(((1 - s - t, s, t), (-2 * one, 2 * one, zero), (-2 * one, zero, 2 * one))):
            np.add.at(W[c], (r, np.zeros(len(r), np.int64)), a[fan])
            np.add.at(W[c], (r, (k + 1)[fan]), b[fan])
            np.add.at(W[c], (r, (k + 2)[fan]), d[fan])
    j = np.arange(m)[None]
    corners = np.where(j < n[:, None], offsets[faces][:, None] + j, -1)
    if derivatives:
        return corners, W[0], W[1], W[2], W[3]
    return corners, W[0]
