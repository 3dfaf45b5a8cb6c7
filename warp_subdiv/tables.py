"""Stencil tables: for each level, one CSR row per child vertex over the parent level's vertices.

Rows follow the child vertex order of :mod:`warp_subdiv.topology` (vertex children, face children for
Catmull-Clark, edge children). The weights come from :mod:`warp_subdiv.rules`; this module only gathers the
neighbourhoods (by index arithmetic over the level's tables) and lays the weights out. Weights are float64.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import rules
from .rules import CATMULL_CLARK, CORNER, CREASE, DART, SMOOTH
from .topology import Level, _offsets, _rows_of, expand_counts


@dataclass
class StencilTable:
    """Child vertex i = sum_j weights[j] * parent[indices[j]] for j in offsets[i]..offsets[i+1]."""

    offsets: np.ndarray  # (rows+1,) int32
    indices: np.ndarray  # (entries,) int32
    weights: np.ndarray  # (entries,) float64
    num_sources: int
    rows: np.ndarray | None = None  # the child vertices the rows are for, when not all of them in order

    @property
    def num_rows(self) -> int:
        return len(self.offsets) - 1

    def nbytes(self, weight_bytes: int = 4) -> int:
        """Bytes of the table on the device with weights of ``weight_bytes`` each."""
        extra = 0 if self.rows is None else self.rows.nbytes
        return self.offsets.nbytes + self.indices.nbytes + len(self.weights) * weight_bytes + extra

    def row(self, i: int) -> dict:
        """Row i as {parent vertex: total weight} (duplicates merged); for tests and debugging."""
        out: dict = {}
        for j in range(int(self.offsets[i]), int(self.offsets[i + 1])):
            key = int(self.indices[j])
            out[key] = out.get(key, 0.0) + float(self.weights[j])
        return out


class _Layout:
    """Collects (row, position-in-row) -> (index, weight) entries for rows whose sizes are known up front."""

    def __init__(self, sizes: np.ndarray, num_sources: int):
        self.offsets = _offsets(sizes)
        total = int(self.offsets[-1])
        self.indices = np.full(total, -1, dtype=np.int64)
        self.weights = np.zeros(total, dtype=np.float64)
        self.num_sources = num_sources

    def put(self, rows, position, index, weight):
        at = self.offsets[rows] + position
        self.indices[at] = index
        self.weights[at] = weight

    def table(self) -> StencilTable:
        assert np.all(self.indices >= 0), "stencil layout left an entry unfilled"
        return StencilTable(
            offsets=self.offsets.astype(np.int32),
            indices=self.indices.astype(np.int32),
            weights=self.weights,
            num_sources=self.num_sources,
        )


def _crease_neighbours(level: Level) -> np.ndarray:
    """(V, 2) the two crease-edge neighbours of every vertex with exactly two sharp edges (-1 elsewhere)."""
    ev = level.edge_verts[level.edge_sharp].astype(np.int64)
    a = np.concatenate([ev[:, 0], ev[:, 1]])
    b = np.concatenate([ev[:, 1], ev[:, 0]])
    nb = np.full((level.num_vertices, 2), -1, dtype=np.int64)
    nb[a, 0] = b
    other = nb[a, 0] != b
    nb[a[other], 1] = b[other]
    return nb


def _edge_endpoint_weights(level: Level, rule_set: str, me: np.ndarray, h0: np.ndarray):
    """Endpoint weights (w_a, w_b) of the non-crease edges ``me`` (RULES.md section 4, both rule sets)."""
    scheme = level.scheme
    corner_vert = level.corner_vert
    vclass = level.vert_class
    ev = level.edge_verts
    a, b = ev[me, 0], ev[me, 1]
    g0 = h0[me]
    if rule_set == "opensubdiv":  # OpenSubdiv's smooth edge rule next to creases and corners too
        w, _ = rules.smooth_edge_weights(scheme)
        return np.full(len(me), w), np.full(len(me), w)
    # theta of the sector of each endpoint that contains this edge: read at that endpoint's corner in face f0
    at_a = np.where(corner_vert[g0] == a, g0, level.corner_next(g0))
    at_b = np.where(corner_vert[g0] == b, g0, level.corner_next(g0))
    tagged_a = (vclass[a] == CREASE) | (vclass[a] == CORNER)
    tagged_b = (vclass[b] == CREASE) | (vclass[b] == CORNER)
    theta = level.corner_theta()
    shift_a = np.nan_to_num(rules.edge_gamma_shift(scheme, theta[at_a]))
    shift_b = np.nan_to_num(rules.edge_gamma_shift(scheme, theta[at_b]))
    return rules.tagged_edge_endpoint_weights(scheme, shift_a, shift_b, tagged_a, tagged_b)


def _edge_corner_pairs(level: Level):
    """(h0, h1): the first and second corner of every edge (h1 = h0 on boundary edges)."""
    eoff = level.edge_corner_offsets
    h0 = level.edge_corners[eoff[:-1]].astype(np.int64)
    h1 = level.edge_corners[np.minimum(eoff[:-1] + 1, len(level.edge_corners) - 1)].astype(np.int64)
    return h0, h1


def build_stencils(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop",
                   regular=None, endpoint_weights=None) -> StencilTable:
    """The stencil table that refines ``level`` to the next level.

    ``regular``: optional (vertex mask, edge mask) of the rows the regular kernels compute (see
    :func:`build_regular`); those rows are left out, and the table lists the rows it holds in ``rows``.
    ``endpoint_weights``: the (w_a, w_b) of every non-crease edge, when the caller has them already.
    """
    scheme = level.scheme
    V, F, E = level.num_vertices, level.num_faces, level.num_edges
    cc = scheme == CATMULL_CLARK
    vclass = level.vert_class
    voff = level.vert_corner_offsets
    vcount = np.diff(voff)
    face_sizes = level.face_sizes()
    face_starts = level.face_starts()
    corner_vert = level.corner_vert.astype(np.int64)
    skip_vertex, skip_edge = regular if regular is not None else (np.zeros(V, bool), np.zeros(E, bool))
    with_faces = cc and regular is None

    # ----- row sizes
    smooth = ((vclass == SMOOTH) | (vclass == DART)) & ~skip_vertex
    slot_vertex = _rows_of(voff)
    slot_corner = level.vert_corners.astype(np.int64)
    slot_smooth = smooth[slot_vertex]
    slot_face = level.corner_face(slot_corner)
    per_slot = (face_sizes[slot_face] - 2) if cc else np.ones(len(slot_corner), dtype=np.int64)
    per_slot = np.where(slot_smooth, per_slot, 0)
    vertex_sizes = np.where(smooth, 1 + np.bincount(slot_vertex, weights=per_slot, minlength=V).astype(np.int64),
                            np.where(vclass == CREASE, 3, 1))
    vertex_sizes[skip_vertex] = 0

    h0, h1 = _edge_corner_pairs(level)
    sharp = level.edge_sharp
    f0 = level.corner_face(h0)
    f1 = level.corner_face(h1)
    if cc:
        edge_sizes = np.where(sharp, 2, face_sizes[f0] + face_sizes[f1] - 2)
    else:
        edge_sizes = np.where(sharp, 2, 4)
    edge_sizes[skip_edge] = 0
    sizes = [vertex_sizes] + ([face_sizes] if with_faces else ([np.zeros(F, np.int64)] if cc else [])) + [edge_sizes]
    out = _Layout(np.concatenate(sizes), V)
    face_row0 = V
    edge_row0 = V + (F if cc else 0)

    # ----- vertex rows
    v = np.arange(V, dtype=np.int64)
    out.put(v[vclass == CORNER], 0, v[vclass == CORNER], rules.corner_vertex_weights())
    crease_v = v[vclass == CREASE]
    w_c, w_n = rules.crease_vertex_weights()
    nb = _crease_neighbours(level)[crease_v]
    out.put(crease_v, 0, crease_v, w_c)
    out.put(crease_v, 1, nb[:, 0], w_n)
    out.put(crease_v, 2, nb[:, 1], w_n)

    sv = v[smooth]
    n = vcount[sv].astype(np.float64)
    slots = np.flatnonzero(slot_smooth)
    sl_v = slot_vertex[slots]
    sl_h = slot_corner[slots]
    sl_n = vcount[sl_v].astype(np.float64)
    # position of each slot's first entry inside its row: 1 + entries of the row's earlier slots
    cum = np.concatenate([[0], np.cumsum(per_slot)])
    sl_pos = 1 + cum[slots] - cum[voff[sl_v]]
    nxt = level.corner_next(sl_h)
    if cc:
        w_self, w_edge, w_face = rules.catmull_clark_interior_vertex_weights(n)
        m_f = face_sizes[slot_face[slots]].astype(np.float64)
        # every face point gives 1/n^2 * (1/m) to each of its vertices; v itself collects one per face
        self_faces = np.bincount(sl_v, weights=1.0 / (sl_n * sl_n * m_f), minlength=V)[sv]
        out.put(sv, 0, sv, w_self + self_faces)
        # the edge neighbour p: edge weight plus the face points on both sides of the edge
        e_sl = level.corner_edge[sl_h].astype(np.int64)
        other = h0[e_sl] + h1[e_sl] - sl_h
        m_g = face_sizes[level.corner_face(other)].astype(np.float64)
        _, w_edge_sl, w_face_sl = rules.catmull_clark_interior_vertex_weights(sl_n)
        out.put(sl_v, sl_pos, corner_vert[nxt], w_edge_sl + w_face_sl / m_f + w_face_sl / m_g)
        # the far vertices of the face (not v, not p, not the previous neighbour): face-point weight only
        far_count = (m_f - 3).astype(np.int64)
        rep, t = expand_counts(far_count)
        walk = nxt[rep]
        walk = _advance(level, walk, t + 1)
        out.put(sl_v[rep], sl_pos[rep] + 1 + t, corner_vert[walk], (w_face_sl / m_f)[rep])
    else:
        w_self, w_ring = rules.loop_interior_vertex_weights(n, loop_beta)
        out.put(sv, 0, sv, w_self)
        _, w_ring_sl = rules.loop_interior_vertex_weights(sl_n, loop_beta)
        out.put(sl_v, sl_pos, corner_vert[nxt], w_ring_sl)

    # ----- face rows (Catmull-Clark)
    if with_faces:
        c = np.arange(level.num_corners, dtype=np.int64)
        f_of_c = level.corner_face(c)
        out.put(face_row0 + f_of_c, c - face_starts[f_of_c], corner_vert, rules.face_point_weights(face_sizes[f_of_c]))

    # ----- edge rows
    e = np.arange(E, dtype=np.int64)
    ev = level.edge_verts.astype(np.int64)
    se = e[sharp & ~skip_edge]
    wa, wb = rules.crease_edge_weights()
    out.put(edge_row0 + se, 0, ev[se, 0], wa)
    out.put(edge_row0 + se, 1, ev[se, 1], wb)

    smooth_edges = np.flatnonzero(~sharp)
    if endpoint_weights is None:
        endpoint_weights = _edge_endpoint_weights(level, rule_set, smooth_edges, h0)
    keep = ~skip_edge[smooth_edges]
    me = smooth_edges[keep]
    w_a, w_b = endpoint_weights[0][keep], endpoint_weights[1][keep]
    a, b = ev[me, 0], ev[me, 1]
    g0, g1 = h0[me], h1[me]
    _, w_wing = rules.smooth_edge_weights(scheme)
    rows = edge_row0 + me
    if cc:
        m0 = face_sizes[level.corner_face(g0)].astype(np.int64)
        m1 = face_sizes[level.corner_face(g1)].astype(np.int64)
        # each new face point f weighs 1/4, i.e. 1/(4m) on each vertex of its face
        out.put(rows, 0, a, w_a + w_wing / m0 + w_wing / m1)
        out.put(rows, 1, b, w_b + w_wing / m0 + w_wing / m1)
        for g, m, base_pos in ((g0, m0, np.full(len(me), 2)), (g1, m1, m0)):
            rep, t = expand_counts(m - 2)
            walk = _advance(level, g[rep], t + 2)
            out.put(rows[rep], base_pos[rep] + t, corner_vert[walk], w_wing / m[rep])
    else:
        out.put(rows, 0, a, w_a)
        out.put(rows, 1, b, w_b)
        out.put(rows, 2, corner_vert[level.corner_prev(g0)], w_wing)
        out.put(rows, 3, corner_vert[level.corner_prev(g1)], w_wing)
    table = out.table()
    if regular is not None:  # keep the non-empty rows only
        keep = np.flatnonzero(np.diff(table.offsets) > 0)
        table.rows = keep.astype(np.int32)
        table.offsets = np.concatenate([[0], np.cumsum(np.diff(table.offsets)[keep])]).astype(np.int32)
    return table


@dataclass
class RegularTables:
    """What the regular kernels need to compute the smooth rows of one step from the level's index tables.

    Uniform levels only (all quads or all triangles). ``vertex_regular`` and ``edge_regular`` (uint8) mark
    the rows they compute; every other row is in ``explicit``. ``ring_weights`` are per-valence weights
    (centre, each ring term) from :mod:`warp_subdiv.rules`; ``edge_weights`` are the smooth edge weights
    (each endpoint, each wing term).
    """

    face_size: int
    num_vertices: int
    num_faces: int
    corner_vert: np.ndarray
    edge_verts: np.ndarray  # (E, 2)
    edge_corners: np.ndarray  # (E, 2) first and second corner
    vert_corner_offsets: np.ndarray
    vert_corners: np.ndarray
    vertex_regular: np.ndarray
    edge_regular: np.ndarray
    ring_weights: np.ndarray  # (max valence + 1, 2)
    edge_weights: np.ndarray  # (2,)
    explicit: StencilTable
    num_rows: int  # child vertices of the step

    def nbytes(self, weight_bytes: int = 4) -> int:
        arrays = (self.corner_vert, self.edge_verts, self.edge_corners, self.vert_corner_offsets,
                  self.vert_corners, self.vertex_regular, self.edge_regular)
        return sum(a.nbytes for a in arrays) + self.explicit.nbytes(weight_bytes)


def build_regular(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop") -> RegularTables:
    """Split one step into rows the regular kernels compute from the index tables and explicit stencils.

    Regular rows: interior and dart vertices (the smooth vertex rule of their valence) and non-crease edges
    whose endpoint weights are the smooth ones (no gamma(theta) shift). Crease and corner vertices, crease
    edges and the crease/corner-neighbour edges of extraordinary sectors get explicit stencils.
    """
    assert level.face_size in (3, 4), "regular kernels need a level of quads or triangles"
    scheme = level.scheme
    vclass = level.vert_class
    vertex_regular = (vclass == SMOOTH) | (vclass == DART)
    h0, h1 = _edge_corner_pairs(level)
    edge_regular = ~level.edge_sharp
    me = np.flatnonzero(edge_regular)
    w_a, w_b = _edge_endpoint_weights(level, rule_set, me, h0)
    w, w_wing = rules.smooth_edge_weights(scheme)
    edge_regular[me[(np.abs(w_a - w) > 0) | (np.abs(w_b - w) > 0)]] = False
    explicit = build_stencils(level, rule_set, loop_beta, regular=(vertex_regular, edge_regular),
                              endpoint_weights=(w_a, w_b))
    valence = np.arange(np.diff(level.vert_corner_offsets).max() + 1, dtype=np.float64)
    valence[valence < 3] = 3  # unused entries (valence < 3 is never a smooth vertex)
    if scheme == CATMULL_CLARK:
        centre, edge_w, face_w = rules.catmull_clark_interior_vertex_weights(valence)
        assert np.allclose(edge_w, face_w)
        ring = np.stack([centre, edge_w], axis=1)
        edge_weights = np.array([w, w_wing])  # (a + b + f0 + f1) / 4
    else:
        centre, beta = rules.loop_interior_vertex_weights(valence, loop_beta)
        ring = np.stack([centre, beta], axis=1)
        edge_weights = np.array([w, w_wing])
    return RegularTables(
        face_size=level.face_size,
        num_vertices=level.num_vertices,
        num_faces=level.num_faces,
        corner_vert=level.corner_vert,
        edge_verts=level.edge_verts,
        edge_corners=np.stack([h0, h1], axis=1).astype(np.int32),
        vert_corner_offsets=level.vert_corner_offsets.astype(np.int32),
        vert_corners=level.vert_corners,
        vertex_regular=vertex_regular.astype(np.uint8),
        edge_regular=edge_regular.astype(np.uint8),
        ring_weights=ring,
        edge_weights=edge_weights,
        explicit=explicit,
        num_rows=level.num_vertices + level.num_edges + (level.num_faces if scheme == CATMULL_CLARK else 0),
    )


def _advance(level: Level, h: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """The corner ``steps`` places after ``h`` in its face."""
    if level.face_size:
        n = level.face_size
        return h - h % n + (h % n + steps) % n
    f = level.corner_face(h)
    start = level.face_offsets[f]
    size = level.face_offsets[f + 1] - start
    return start + (h - start + steps) % size
