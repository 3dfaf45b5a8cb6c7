"""Which faces of a level are polynomial patches (regular faces: a bicubic B-spline or quartic box-spline
patch, regular creases, boundaries and Catmull-Clark corners included), their control points gathered from the
lattice around them, and the phantom points across their sharp sides.
"""
from __future__ import annotations

import numpy as np

from ..mesh import INFINITE_SHARPNESS
from ..options import Options
from ..rules import CATMULL_CLARK, CORNER, CREASE, DART, SECTOR_CREASE, SMOOTH, edge_gamma_shift
from ..tables import projections
from ..topology import Level
from .bezier import QUAD_LOOKUP, TRI_LOOKUP, TRI_RING
from .local_refinement import face_corners


def _twin(level: Level) -> np.ndarray:
    """(C,) the corner across each corner's edge (its other corner on a two-face edge), else -1."""
    C = level.num_corners
    twin = np.full(C, -1, dtype=np.int64)
    counts = np.diff(level.edge_corner_offsets)
    h0, h1 = level.edge_corner_pair()
    two = counts == 2
    twin[h0[two]] = h1[two]
    twin[h1[two]] = h0[two]
    return twin


class LevelLookups:
    """Per-level lookups the gathering and classification need (built once per level)."""

    def __init__(self, level: Level, options: Options, normal_ids: np.ndarray):
        self.level = level
        self.twin = _twin(level)
        self.sizes = level.face_sizes()
        V = level.num_vertices
        es = level.edge_sharpness
        ev = level.edge_verts.astype(np.int64)
        self.edge_inf = es >= INFINITE_SHARPNESS
        semi = (es > 0) & ~self.edge_inf
        self.vert_semi = np.zeros(V, bool)
        self.vert_semi[ev[semi].reshape(-1)] = True
        vs = level.vert_sharpness
        self.vert_semi |= (vs > 0) & (vs < INFINITE_SHARPNESS)
        self.sharp_count = np.bincount(ev[es > 0].reshape(-1), minlength=V)
        self.valence = np.diff(level.vert_corner_offsets)
        counts = np.diff(level.edge_corner_offsets)
        self.boundary = np.zeros(V, bool)
        self.boundary[ev[counts != 2].reshape(-1)] = True
        # vertices whose neighbourhood follows modified rules: flatness (s > 0), the paper's crease- and
        # corner-neighbour edge rules (gamma shift), prescribed normals, darts and non-standard sectors
        special = np.zeros(V, bool)
        if level.num_sectors:
            k = level.sector_k()
            if options.piecewise_smooth:
                s = projections.resolve_flatness(level)
                shift = np.abs(edge_gamma_shift(options.scheme, level.sector_theta)) > 1e-15
                moved = (s > 0) | ((k >= 2) & shift)
                special[level.sector_vertex[moved]] = True
            regular_k = 2 if options.scheme == CATMULL_CLARK else 3
            odd = ~(((level.sector_kind == SECTOR_CREASE) & (k == regular_k)) | (k == 1))
            special[level.sector_vertex[odd]] = True
        special[normal_ids] = True
        special[level.vert_class == DART] = True
        self.special = special


def _rotate(scheme: str, vec: np.ndarray, steps: int) -> np.ndarray:
    """Lattice vectors (..., 2) turned by ``steps`` face angles (90 degrees on quads, 60 on triangles)."""
    out = vec
    for _ in range(steps % (4 if scheme == CATMULL_CLARK else 6)):
        i, j = out[..., 0], out[..., 1]
        out = np.stack([-j, i], -1) if scheme == CATMULL_CLARK else np.stack([-j, i + j], -1)
    return out


def _gather(topo: LevelLookups, faces: np.ndarray, scheme: str):
    """Control point ids of the regular patch of ``faces`` (each with 4 or 3 corners), phantoms not yet made.

    Returns (ids (F, G) int64 with -1 where a point lies across a sharp side or is missing, side_sharp (F, n)
    bool, sector_faces (F, n): faces of the face's sector at each corner (or -1 when the walk around the
    corner closed), ok (F,) bool: consistent lattice and all faces of the right size)."""
    level = topo.level
    n = 4 if scheme == CATMULL_CLARK else 3
    offset, size, lookup = QUAD_LOOKUP if n == 4 else TRI_LOOKUP
    G = 16 if n == 4 else 12
    F = len(faces)
    ids = np.full((F, G), -1, dtype=np.int64)
    ok = np.ones(F, bool)
    corners = face_corners(level, faces, n)
    cv = level.corner_vert.astype(np.int64)
    ce = level.corner_edge.astype(np.int64)
    lat = np.array([(0, 0), (1, 0), (1, 1), (0, 1)] if n == 4 else [(0, 0), (1, 0), (0, 1)], dtype=np.int64)
    side_sharp = topo.edge_inf[ce[corners]] | (topo.twin[corners] < 0)
    sector_faces = np.zeros((F, n), dtype=np.int64)
    rows = np.arange(F)

    def put(points_lat, vertex, valid):
        points_lat = np.broadcast_to(points_lat, (F, 2))
        key = (points_lat[:, 0] + offset) * size + (points_lat[:, 1] + offset)
        inside = (points_lat[:, 0] >= -offset) & (points_lat[:, 0] < size - offset) & \
                 (points_lat[:, 1] >= -offset) & (points_lat[:, 1] < size - offset)
        slot = np.where(inside, lookup[np.clip(key, 0, size * size - 1)], -1)
        use = valid & (slot >= 0)
        r, s, v = rows[use], slot[use], vertex[use]
        prev = ids[r, s]
        clash = (prev >= 0) & (prev != v)
        ok[r[clash]] = False
        ids[r, s] = v

    for j in range(n):
        h = corners[:, j]
        c = lat[j]
        e1 = lat[(j + 1) % n] - c
        e2 = lat[(j - 1) % n] - c
        put(np.broadcast_to(c, (F, 2)), cv[h], np.ones(F, bool))
        count = np.ones(F, dtype=np.int64)
        closed = np.zeros(F, bool)
        turns = 4 if n == 4 else 6
        # counter-clockwise: across the incoming edge (prev corner -> h)
        g = h.copy()
        alive = np.ones(F, bool)
        for step in range(1, turns + 1):
            inc = level.corner_prev(g)
            t = topo.twin[inc]
            alive &= (t >= 0) & ~topo.edge_inf[ce[inc]]
            g = np.where(alive, t, g)
            back = alive & (g == h)
            closed |= back
            alive &= ~back
            if not alive.any():
                break
            alive &= topo.sizes[level.corner_face(g)] == n
            if step >= turns:
                ok[alive] = False
                break
            a1 = _rotate(scheme, e1, step)
            a2 = _rotate(scheme, e2, step)
            put(c + a1, cv[level.corner_next(g)], alive)
            put(c + a2, cv[level.corner_prev(g)], alive)
            if n == 4:
                put(c + a1 + a2, cv[level.corner_next(level.corner_next(g))], alive)
            count += alive
        # clockwise: across the outgoing edge (h -> next)
        g = h.copy()
        alive = ~closed
        for step in range(1, turns + 1):
            t = topo.twin[g]
            alive &= (t >= 0) & ~topo.edge_inf[ce[g]]
            g = np.where(alive, level.corner_next(np.maximum(t, 0)), g)
            if not alive.any():
                break
            alive &= topo.sizes[level.corner_face(g)] == n
            if step >= turns:
                ok[alive] = False
                break
            a1 = _rotate(scheme, e1, -step)
            a2 = _rotate(scheme, e2, -step)
            put(c + a1, cv[level.corner_next(g)], alive)
            put(c + a2, cv[level.corner_prev(g)], alive)
            if n == 4:
                put(c + a1 + a2, cv[level.corner_next(level.corner_next(g))], alive)
            count += alive
        sector_faces[:, j] = np.where(closed, -1, count)
    return ids, side_sharp, sector_faces, ok


def regular_faces(topo: LevelLookups, faces: np.ndarray, scheme: str):
    """(ok (F,), ids (F, G)): which faces are polynomial patches, and their gathered control point ids."""
    level = topo.level
    n = 4 if scheme == CATMULL_CLARK else 3
    if len(faces) == 0:
        return np.zeros(0, bool), np.zeros((0, 16 if n == 4 else 12), np.int64), np.zeros((0, n), bool)
    ok = topo.sizes[faces] == n
    ids, side_sharp, sector_faces, gathered = _gather(topo, faces, scheme)
    ok &= gathered
    corners = face_corners(level, faces, n)
    v = level.corner_vert.astype(np.int64)[corners]
    vclass = level.vert_class[v]
    vs = level.vert_sharpness[v]
    sharp_n = topo.sharp_count[v]
    semi = topo.vert_semi[v]
    regular_valence = 4 if n == 4 else 6
    regular_sector = 2 if n == 4 else 3
    interior = (vclass == SMOOTH) & (sharp_n == 0) & ~topo.boundary[v] & (topo.valence[v] == regular_valence) \
        & (vs == 0) & (sector_faces == -1)
    side_in = side_sharp  # side j leaves corner j; side j-1 enters it
    side_out = np.roll(side_sharp, 1, axis=1)
    one_side = side_in ^ side_out
    crease = (vclass == CREASE) & (sharp_n == 2) & (vs == 0) & one_side & (sector_faces == regular_sector)
    corner = np.zeros_like(crease)
    if n == 4:
        sharp_or_none = (vs == 0) | (vs >= INFINITE_SHARPNESS)
        corner = (vclass == CORNER) & side_in & side_out & (sector_faces == 1) & sharp_or_none
    ok &= np.all((interior | crease | corner) & ~semi, axis=1)
    # sharp sides must be infinitely sharp or boundary (checked by the corner rules) and no modified rule may
    # reach the patch's control points
    present = np.where(ids >= 0, ids, 0)
    ok &= ~np.any(topo.special[present] & (ids >= 0), axis=1)
    return ok, ids, side_sharp


def phantom_points(points: np.ndarray, ids: np.ndarray, side_sharp: np.ndarray, scheme: str) -> np.ndarray:
    """(F, G, D) control points with the phantom points across sharp sides made (B-spline: reflection;
    box spline: parallelograms); D: the columns of ``points``."""
    F = len(ids)
    D = points.shape[1]
    P = np.where((ids >= 0)[..., None], points[np.maximum(ids, 0)], np.nan)
    if scheme == CATMULL_CLARK:
        g = P.reshape(F, 4, 4, D)  # [j + 1, i + 1]

        def at(i, j):
            return g[:, j + 1, i + 1]

        def setp(i, j, value, mask):
            g[mask, j + 1, i + 1] = value[mask]
        bottom, right, top, left = (side_sharp[:, k] for k in range(4))
        for i in (0, 1):
            setp(i, -1, 2 * at(i, 0) - at(i, 1), bottom)
            setp(i, 2, 2 * at(i, 1) - at(i, 0), top)
        for j in (0, 1):
            setp(-1, j, 2 * at(0, j) - at(1, j), left)
            setp(2, j, 2 * at(1, j) - at(0, j), right)
        # grid corners: across a sharp side by rows, else across the other side by columns
        for (i, j, di, dj, row_side, col_side) in ((-1, -1, 1, 1, bottom, left), (2, -1, -1, 1, bottom, right),
                                                   (2, 2, -1, -1, top, right), (-1, 2, 1, -1, top, left)):
            setp(i, j, 2 * at(i, j + dj) - at(i, j + 2 * dj), row_side)
            setp(i, j, 2 * at(i + di, j) - at(i + 2 * di, j), col_side & ~row_side)
        return g.reshape(F, 16, D)
    idx = {p: n for n, p in enumerate(TRI_RING)}

    def at(p):
        return P[:, idx[p]]

    rules = (  # side 0 (c0 -> c1), side 1 (c1 -> c2), side 2 (c2 -> c0): phantom = a + b - c
        ((1, -1), (0, 0), (1, 0), (0, 1), 0), ((0, -1), (-1, 0), (0, 0), (-1, 1), 0),
        ((2, -1), (1, 0), (2, 0), (1, 1), 0), ((1, 1), (1, 0), (0, 1), (0, 0), 1),
        ((2, 0), (1, 0), (2, -1), (1, -1), 1), ((0, 2), (0, 1), (-1, 2), (-1, 1), 1),
        ((-1, 1), (0, 0), (0, 1), (1, 0), 2), ((-1, 0), (0, -1), (0, 0), (1, -1), 2),
        ((-1, 2), (0, 1), (0, 2), (1, 1), 2),
    )
    for target, a, b, c, side in rules:
        mask = side_sharp[:, side]
        P[mask, idx[target]] = (at(a) + at(b) - at(c))[mask]
    return P
