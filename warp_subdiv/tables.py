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
from .topology import Level, _offsets, _rows_of, child_rules, child_sharpness, expand_counts, fractional_weight


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


def _crease_neighbours(level: Level, sharp_ends: np.ndarray) -> np.ndarray:
    """(V, 2) the far ends of the (up to two) edges marked sharp at each vertex (-1 where missing).

    ``sharp_ends`` (E, 2): whether edge e counts as sharp at its end j."""
    ev = level.edge_verts.astype(np.int64)
    a = np.concatenate([ev[sharp_ends[:, 0], 0], ev[sharp_ends[:, 1], 1]])
    b = np.concatenate([ev[sharp_ends[:, 0], 1], ev[sharp_ends[:, 1], 0]])
    nb = np.full((level.num_vertices, 2), -1, dtype=np.int64)
    nb[a, 0] = b
    other = nb[a, 0] != b
    nb[a[other], 1] = b[other]
    return nb


def _edge_endpoint_weights(level: Level, rule_set: str, me: np.ndarray, h0: np.ndarray):
    """Endpoint weights (w_a, w_b) of the non-crease edges ``me`` (RULES.md section 4, both rule sets).

    Only edges with a crease or corner endpoint can differ from the smooth weights; the sector angle of
    such an endpoint is read at its corner in the edge's first face."""
    scheme = level.scheme
    w, _ = rules.smooth_edge_weights(scheme)
    w_a, w_b = np.full(len(me), w), np.full(len(me), w)
    if rule_set == "opensubdiv" or level.num_sectors == 0:  # OpenSubdiv: the smooth rule next to creases too
        return w_a, w_b
    tagged = (level.vert_class == CREASE) | (level.vert_class == CORNER)
    ev = level.edge_verts
    near = np.flatnonzero(tagged[ev[me, 0]] | tagged[ev[me, 1]])
    if len(near) == 0:
        return w_a, w_b
    e = me[near]
    a, b = ev[e, 0], ev[e, 1]
    g0 = h0[e]
    corner_vert = level.corner_vert
    at_a = np.where(corner_vert[g0] == a, g0, level.corner_next(g0))
    at_b = np.where(corner_vert[g0] == b, g0, level.corner_next(g0))
    shift_a = np.nan_to_num(rules.edge_gamma_shift(scheme, level.corner_theta(at_a)))
    shift_b = np.nan_to_num(rules.edge_gamma_shift(scheme, level.corner_theta(at_b)))
    w_a[near], w_b[near] = rules.tagged_edge_endpoint_weights(scheme, shift_a, shift_b, tagged[a], tagged[b])
    return w_a, w_b


def build_stencils(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop",
                   regular=None, smooth_triangles: bool = False) -> StencilTable:
    """The stencil table that refines ``level`` to the next level.

    Semi-sharp features follow OpenSubdiv's Sdc::Crease rules: where a vertex's rule changes during the step
    (its sharpness or its edges' decays to 0) its mask blends the parent and child rules with the fractional
    weight; a semi-sharp edge whose children are smooth blends the crease and smooth rules with its sharpness.
    ``regular``: optional (vertex mask, edge mask) of the rows the regular kernels compute (see
    :func:`build_regular`); those rows are left out, and the table lists the rows it holds in ``rows``.
    ``smooth_triangles``: OpenSubdiv's TRI_SUB_SMOOTH edge weights next to triangles (Catmull-Clark).
    """
    scheme = level.scheme
    V, F, E = level.num_vertices, level.num_faces, level.num_edges
    cc = scheme == CATMULL_CLARK
    voff = level.vert_corner_offsets
    face_sizes = level.face_sizes()
    face_starts = level.face_starts()
    corner_vert = level.corner_vert.astype(np.int64)
    skip_vertex, skip_edge = regular if regular is not None else (np.zeros(V, bool), np.zeros(E, bool))
    with_faces = cc and regular is None

    # ----- rules before and after the step
    halves, child_vs = child_sharpness(level)
    parent_rule = level.vert_class
    child_rule, edge_child_rule = child_rules(level, halves, child_vs)
    transition = np.isin(parent_rule, [CREASE, CORNER]) & (child_rule != parent_rule) & ~skip_vertex
    parent_weight = (np.where(transition, fractional_weight(level, halves, child_vs), 1.0)
                     if np.any(transition) else np.ones(V))
    sharp_now = np.repeat(level.edge_sharp[:, None], 2, axis=1)
    pairs = {"parent": _crease_neighbours(level, sharp_now), "child": _crease_neighbours(level, halves > 0)}

    # ----- row sizes (the smooth rule's only where some row uses it)
    needs_smooth = np.any(~skip_vertex & np.isin(parent_rule, [SMOOTH, DART])) or np.any(
        transition & np.isin(child_rule, [SMOOTH, DART]))
    if needs_smooth:
        slot_vertex = _rows_of(voff)
        slot_corner = level.vert_corners.astype(np.int64)
        slot_face = level.corner_face(slot_corner)
        per_slot = (face_sizes[slot_face] - 2) if cc else np.ones(len(slot_corner), dtype=np.int64)
        smooth_size = 1 + np.bincount(slot_vertex, weights=per_slot, minlength=V).astype(np.int64)
    else:
        slot_vertex = slot_corner = slot_face = per_slot = None
        smooth_size = np.zeros(V, dtype=np.int64)

    def rule_size(rule):
        return np.where((rule == SMOOTH) | (rule == DART), smooth_size, np.where(rule == CREASE, 3, 1))

    first_size = rule_size(parent_rule)
    vertex_sizes = first_size + np.where(transition, rule_size(child_rule), 0)
    vertex_sizes[skip_vertex] = 0

    h0, h1 = level.edge_corner_pair()
    sharp = level.edge_sharp
    f0 = level.corner_face(h0)
    f1 = level.corner_face(h1)
    smooth_edge_size = (face_sizes[f0] + face_sizes[f1] - 2) if cc else np.full(E, 4)
    # a semi-sharp edge whose children are not both sharp blends the crease and smooth rules
    edge_blend = sharp & (edge_child_rule != CREASE)
    edge_sizes = np.where(sharp, 2 + np.where(edge_blend, smooth_edge_size, 0), smooth_edge_size)
    edge_sizes[skip_edge] = 0
    sizes = [vertex_sizes] + ([face_sizes] if with_faces else ([np.zeros(F, np.int64)] if cc else [])) + [edge_sizes]
    out = _Layout(np.concatenate(sizes), V)
    face_row0 = V
    edge_row0 = V + (F if cc else 0)

    # ----- vertex rows: the parent rule's mask, then (where the rule changes) the child rule's mask
    v = np.arange(V, dtype=np.int64)
    keep_v = ~skip_vertex
    for which, rule, verts, pos, scale in (
        ("parent", parent_rule, v[keep_v], np.zeros(V, np.int64), parent_weight),
        ("child", child_rule, v[transition], first_size, 1.0 - parent_weight),
    ):
        corner = verts[rule[verts] == CORNER]
        out.put(corner, pos[corner], corner, scale[corner] * rules.corner_vertex_weights())
        crease = verts[rule[verts] == CREASE]
        w_c, w_n = rules.crease_vertex_weights()
        nb = pairs[which][crease]
        out.put(crease, pos[crease], crease, scale[crease] * w_c)
        out.put(crease, pos[crease] + 1, nb[:, 0], scale[crease] * w_n)
        out.put(crease, pos[crease] + 2, nb[:, 1], scale[crease] * w_n)
        smooth = np.zeros(V, dtype=bool)
        smooth[verts[np.isin(rule[verts], [SMOOTH, DART])]] = True
        if not needs_smooth:
            continue
        _put_smooth_vertices(level, out, smooth, pos, scale, loop_beta, slot_vertex, slot_corner, slot_face,
                             per_slot, h0, h1)

    # ----- face rows (Catmull-Clark)
    if with_faces:
        c = np.arange(level.num_corners, dtype=np.int64)
        f_of_c = level.corner_face(c)
        out.put(face_row0 + f_of_c, c - face_starts[f_of_c], corner_vert, rules.face_point_weights(face_sizes[f_of_c]))

    # ----- edge rows
    e = np.arange(E, dtype=np.int64)
    ev = level.edge_verts.astype(np.int64)
    se = e[sharp & ~skip_edge]
    crease_scale = np.where(edge_blend, level.edge_sharpness, 1.0)
    wa, wb = rules.crease_edge_weights()
    out.put(edge_row0 + se, 0, ev[se, 0], wa * crease_scale[se])
    out.put(edge_row0 + se, 1, ev[se, 1], wb * crease_scale[se])

    me = np.flatnonzero((~sharp | edge_blend) & ~skip_edge)
    w_a, w_b = _edge_endpoint_weights(level, rule_set, me, h0)
    scale = np.where(edge_blend[me], 1.0 - level.edge_sharpness[me], 1.0)
    pos0 = np.where(edge_blend[me], 2, 0)
    a, b = ev[me, 0], ev[me, 1]
    g0, g1 = h0[me], h1[me]
    _, w_wing = rules.smooth_edge_weights(scheme)
    rows = edge_row0 + me
    if cc:
        m0 = face_sizes[level.corner_face(g0)].astype(np.int64)
        m1 = face_sizes[level.corner_face(g1)].astype(np.int64)
        # endpoints and the two new face points (weight w_face each, i.e. w_face/m on each face vertex);
        # "smooth triangles" re-weights them where a triangle touches the edge
        w_end, w_face = rules.catmull_clark_edge_weights(m0, m1, smooth_triangles)
        w_a = w_a - w_wing + w_end
        w_b = w_b - w_wing + w_end
        out.put(rows, pos0, a, scale * (w_a + w_face / m0 + w_face / m1))
        out.put(rows, pos0 + 1, b, scale * (w_b + w_face / m0 + w_face / m1))
        for g, m, base_pos in ((g0, m0, pos0 + 2), (g1, m1, pos0 + m0)):
            rep, t = expand_counts(m - 2)
            walk = _advance(level, g[rep], t + 2)
            out.put(rows[rep], base_pos[rep] + t, corner_vert[walk], (scale * w_face / m)[rep])
    else:
        out.put(rows, pos0, a, scale * w_a)
        out.put(rows, pos0 + 1, b, scale * w_b)
        out.put(rows, pos0 + 2, corner_vert[level.corner_prev(g0)], scale * w_wing)
        out.put(rows, pos0 + 3, corner_vert[level.corner_prev(g1)], scale * w_wing)
    table = out.table()
    if regular is not None:  # keep the non-empty rows only
        keep = np.flatnonzero(np.diff(table.offsets) > 0)
        table.rows = keep.astype(np.int32)
        table.offsets = np.concatenate([[0], np.cumsum(np.diff(table.offsets)[keep])]).astype(np.int32)
    return table


def _put_smooth_vertices(level, out, selected, pos, scale, loop_beta, slot_vertex, slot_corner, slot_face,
                         per_slot, h0, h1):
    """The smooth (interior) vertex rule for the ``selected`` vertices, at row position ``pos``, times ``scale``."""
    V = level.num_vertices
    cc = level.scheme == CATMULL_CLARK
    voff = level.vert_corner_offsets
    vcount = np.diff(voff)
    face_sizes = level.face_sizes()
    corner_vert = level.corner_vert.astype(np.int64)
    sv = np.flatnonzero(selected)
    if len(sv) == 0:
        return
    n = vcount[sv].astype(np.float64)
    slots = np.flatnonzero(selected[slot_vertex])
    sl_v = slot_vertex[slots]
    sl_h = slot_corner[slots]
    sl_n = vcount[sl_v].astype(np.float64)
    # position of each slot's first entry inside its row: 1 + entries of the row's earlier slots
    cum = np.concatenate([[0], np.cumsum(np.where(selected[slot_vertex], per_slot, 0))])
    sl_pos = pos[sl_v] + 1 + cum[slots] - cum[voff[sl_v]]
    sl_scale = scale[sl_v]
    nxt = level.corner_next(sl_h)
    if cc:
        w_self, w_edge, w_face = rules.catmull_clark_interior_vertex_weights(n)
        m_f = face_sizes[slot_face[slots]].astype(np.float64)
        # every face point gives 1/n^2 * (1/m) to each of its vertices; v itself collects one per face
        self_faces = np.bincount(sl_v, weights=1.0 / (sl_n * sl_n * m_f), minlength=V)[sv]
        out.put(sv, pos[sv], sv, scale[sv] * (w_self + self_faces))
        # the edge neighbour p: edge weight plus the face points on both sides of the edge
        e_sl = level.corner_edge[sl_h].astype(np.int64)
        other = h0[e_sl] + h1[e_sl] - sl_h
        m_g = face_sizes[level.corner_face(other)].astype(np.float64)
        _, w_edge_sl, w_face_sl = rules.catmull_clark_interior_vertex_weights(sl_n)
        out.put(sl_v, sl_pos, corner_vert[nxt], sl_scale * (w_edge_sl + w_face_sl / m_f + w_face_sl / m_g))
        # the far vertices of the face (not v, not p, not the previous neighbour): face-point weight only
        far_count = (m_f - 3).astype(np.int64)
        rep, t = expand_counts(far_count)
        walk = _advance(level, nxt[rep], t + 1)
        out.put(sl_v[rep], sl_pos[rep] + 1 + t, corner_vert[walk], (sl_scale * w_face_sl / m_f)[rep])
    else:
        w_self, w_ring = rules.loop_interior_vertex_weights(n, loop_beta)
        out.put(sv, pos[sv], sv, scale[sv] * w_self)
        _, w_ring_sl = rules.loop_interior_vertex_weights(sl_n, loop_beta)
        out.put(sl_v, sl_pos, corner_vert[nxt], sl_scale * w_ring_sl)


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
    edge_neighbours: np.ndarray  # (E, 4): endpoints a, b, then the two face ids (quads) or opposite vertices
    vert_corner_offsets: np.ndarray
    ring: np.ndarray  # per vertex (CSR by vert_corner_offsets): its ring vertices
    ring_faces: np.ndarray  # the faces around it, in the same order (quads; empty for triangles)
    vertex_regular: np.ndarray
    edge_regular: np.ndarray
    ring_weights: np.ndarray  # (max valence + 1, 2)
    edge_weights: np.ndarray  # (2,)
    explicit: StencilTable
    num_rows: int  # child vertices of the step

    def nbytes(self, weight_bytes: int = 4) -> int:
        arrays = (self.corner_vert, self.edge_neighbours, self.vert_corner_offsets,
                  self.ring, self.ring_faces, self.vertex_regular, self.edge_regular)
        return sum(a.nbytes for a in arrays) + self.explicit.nbytes(weight_bytes)


def _edge_neighbours(level: Level, h0: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """(E, 4) int32 per edge: its endpoints, then the faces on its two sides (quads: their face points) or the
    vertices opposite it (triangles), so the edge kernels read four indices in a row."""
    out = np.empty((level.num_edges, 4), dtype=np.int32)
    out[:, :2] = level.edge_verts
    if level.face_size == 4:
        out[:, 2], out[:, 3] = h0 // 4, h1 // 4
    else:
        out[:, 2] = level.corner_vert[level.corner_prev(h0)]
        out[:, 3] = level.corner_vert[level.corner_prev(h1)]
    return out


def build_regular(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop") -> RegularTables:
    """Split one step into rows the regular kernels compute from the index tables and explicit stencils.

    Regular rows: interior and dart vertices (the smooth vertex rule of their valence) and non-crease edges
    whose endpoint weights are the smooth ones (no gamma(theta) shift). Crease and corner vertices, crease
    edges and the crease/corner-neighbour edges of extraordinary sectors get explicit stencils.
    """
    assert level.face_size == (4 if level.scheme == CATMULL_CLARK else 3), \
        "regular kernels need a level of quads (Catmull-Clark) or triangles (Loop)"
    scheme = level.scheme
    vclass = level.vert_class
    vertex_regular = (vclass == SMOOTH) | (vclass == DART)
    h0, h1 = level.edge_corner_pair()
    edge_regular = ~level.edge_sharp
    w, w_wing = rules.smooth_edge_weights(scheme)
    if rule_set != "opensubdiv" and level.num_sectors:  # else every smooth edge has the smooth endpoint weights
        me = np.flatnonzero(edge_regular)
        w_a, w_b = _edge_endpoint_weights(level, rule_set, me, h0)
        edge_regular[me[(w_a != w) | (w_b != w)]] = False
    if vertex_regular.all() and edge_regular.all():  # nothing irregular on this level (common on closed meshes)
        explicit = StencilTable(np.zeros(1, np.int32), np.zeros(0, np.int32), np.zeros(0), level.num_vertices,
                                rows=np.zeros(0, np.int32))
    else:
        explicit = build_stencils(level, rule_set, loop_beta, regular=(vertex_regular, edge_regular))
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
        edge_neighbours=_edge_neighbours(level, h0, h1),
        vert_corner_offsets=level.vert_corner_offsets.astype(np.int32),
        ring=level.at_next(level.corner_vert)[level.vert_corners],
        ring_faces=level.vert_corners // 4 if level.face_size == 4 else np.zeros(0, np.int32),
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
