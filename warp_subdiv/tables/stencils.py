"""Stencil tables: for each level, one CSR row per child vertex over the parent level's vertices.

Rows follow the child vertex order of :mod:`warp_subdiv.topology` (vertex children, face children for
Catmull-Clark, edge children). As OpenSubdiv's ``far/stencilTableFactory`` expands ``Sdc`` masks, this module
only decides which class each row is (from the level's vertex classes and :mod:`warp_subdiv.rules.crease`'s
sharpness decay), gathers the neighbourhood indices (by index arithmetic over the level's tables) and lays
out the role masks that :mod:`warp_subdiv.rules` returns for that class. Weights are float64.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rules import crease
from ..rules import weights as rules
from ..runtime.estimate import check_int32
from ..mesh import expand_counts, face_offsets_of
from ..rules import CATMULL_CLARK, CORNER, CREASE, DART, SMOOTH
from ..topology import Level, child_sharpness, has_semi_sharpness, level_child_rules, level_fractional_weight


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
        self.offsets = face_offsets_of(sizes)
        total = int(self.offsets[-1])
        check_int32(total, "a stencil table needs entries")  # its int32 offsets must not wrap
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


def rows_of(offsets: np.ndarray) -> np.ndarray:
    """Row id of every entry of a CSR layout with the given offsets."""
    return np.repeat(np.arange(len(offsets) - 1, dtype=np.int64), np.diff(offsets))


def crease_neighbours(level: Level, sharp_ends: np.ndarray | None = None,
                      vertices: np.ndarray | None = None) -> np.ndarray:
    """(V, 2) the far ends of the (up to two) sharp edges at each vertex (-1 where missing).

    These are the neighbours the crease rules weigh: the crease vertex rule of a step and the crease limit
    mask. ``sharp_ends`` (E, 2): whether edge e counts as sharp at its end j; by default the level's sharp
    edges at both ends (for the rule after a step: whether each half's child sharpness is above 0).
    ``vertices``: only these vertices' rows, (len(vertices), 2) (default: every vertex). Where a vertex has
    more than two, slot 0 is the last sharp edge's far end in edge order (ends 0 first), slot 1 the last one
    that differs from it; two sharp edges to the same neighbour (the halves of a degenerate control edge)
    fill both slots. The work is proportional to the sharp edges and ``vertices``, not to the level."""
    ev = level.edge_verts
    if sharp_ends is None:
        s0 = s1 = np.flatnonzero(level.edge_sharp)
    else:
        s0, s1 = np.flatnonzero(sharp_ends[:, 0]), np.flatnonzero(sharp_ends[:, 1])
    a = np.concatenate([ev[s0, 0], ev[s1, 1]]).astype(np.int64)
    b = np.concatenate([ev[s0, 1], ev[s1, 0]]).astype(np.int64)
    if vertices is None:
        vertices = np.arange(level.num_vertices, dtype=np.int64)
    nb = np.full((len(vertices), 2), -1, dtype=np.int64)
    if len(a) == 0:
        return nb
    order = np.argsort(a, kind="stable")  # each vertex's sharp edges as a run, in the order above
    a, b = a[order], b[order]
    run_start = np.flatnonzero(np.concatenate([[True], a[1:] != a[:-1]]))
    run_last = np.concatenate([run_start[1:], [len(a)]]) - 1
    first = b[run_last]  # slot 0: the run's last far end
    run_of = np.repeat(np.arange(len(run_start)), np.diff(np.concatenate([run_start, [len(a)]])))
    differs = np.where(b != first[run_of], np.arange(len(a)), -1)
    last_other = np.maximum.reduceat(differs, run_start)
    second = np.where(last_other >= 0, b[np.maximum(last_other, 0)],
                      np.where(run_last > run_start, first, -1))  # two edges to one neighbour: both slots
    run = np.searchsorted(a[run_start], vertices)
    found = run < len(run_start)
    found[found] = a[run_start[run[found]]] == vertices[found]
    nb[found, 0] = first[run[found]]
    nb[found, 1] = second[run[found]]
    return nb


def _smooth_edge_mask(level: Level, rule_set: str, me: np.ndarray, h0: np.ndarray, face_size_0: np.ndarray,
                      face_size_1: np.ndarray, smooth_triangles: bool = False) -> rules.EdgeMask:
    """Masks of the non-crease edges ``me`` (Catmull-Clark: face points as wings; docs/rules.md section 4).

    Which rule: the smooth one, or with the piecewise-smooth rule set the crease/corner-neighbour rule where
    an endpoint is a crease or corner vertex (OpenSubdiv's rule set uses the smooth rule next to creases
    too). The sector angle of such an endpoint is read at its corner in the edge's first face.
    ``face_size_*``: sizes of the faces on the edges' two sides (Catmull-Clark)."""
    scheme = level.scheme
    if scheme == CATMULL_CLARK:
        mask = rules.catmull_clark_edge_mask(face_size_0, face_size_1, smooth_triangles)
    else:
        mask = rules.smooth_edge_mask(scheme, len(me))
    if rule_set == "opensubdiv" or level.num_sectors == 0:
        return mask
    tagged = (level.vert_class == CREASE) | (level.vert_class == CORNER)
    ev = level.edge_verts
    near = np.flatnonzero(tagged[ev[me, 0]] | tagged[ev[me, 1]])
    if len(near) == 0:
        return mask
    e = me[near]
    a, b = ev[e, 0], ev[e, 1]
    g0 = h0[e]
    corner_vert = level.corner_vert
    at_a = np.where(corner_vert[g0] == a, g0, level.corner_next(g0))
    at_b = np.where(corner_vert[g0] == b, g0, level.corner_next(g0))
    shifted = rules.crease_neighbour_edge_mask(scheme, mask.take(near), level.corner_theta(at_a),
                                               level.corner_theta(at_b), tagged[a], tagged[b])
    mask.end_a[near] = shifted.end_a
    mask.end_b[near] = shifted.end_b
    return mask


def build_stencils(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop",
                   regular=None, smooth_triangles: bool = False, *, edge_corners=None) -> StencilTable:
    """The stencil table that refines ``level`` to the next level.

    Semi-sharp features follow OpenSubdiv's Sdc::Crease rules: where a vertex's rule changes during the step
    (its sharpness or its edges' decays to 0) its row lists the parent rule's mask times the fractional
    weight, then the child rule's mask times one minus it; a semi-sharp edge whose children are smooth lists
    the crease rule's mask times its sharpness, then the smooth rule's times one minus it.
    ``regular``: optional (vertex mask, edge mask) of the rows the regular kernels compute (see
    :func:`build_regular`); those rows are left out, and the table lists the rows it holds in ``rows``. The
    work is then proportional to the rows left (a boundary, the creases), not to the level, except on levels
    with semi-sharp features (their sharpness decay is computed level-wide).
    ``smooth_triangles``: OpenSubdiv's TRI_SUB_SMOOTH edge weights next to triangles (Catmull-Clark).
    ``edge_corners``: the level's :meth:`~warp_subdiv.topology.Level.edge_corner_pair`, when the caller has it.
    """
    scheme = level.scheme
    V, F, E = level.num_vertices, level.num_faces, level.num_edges
    cc = scheme == CATMULL_CLARK
    if regular is None:  # every row, in child vertex order
        vs, es = np.arange(V, dtype=np.int64), np.arange(E, dtype=np.int64)
    else:
        vs, es = np.flatnonzero(~regular[0]), np.flatnonzero(~regular[1])
    with_faces = cc and regular is None
    nv, ne = len(vs), len(es)
    face_sizes = level.face_sizes()
    corner_vert = level.corner_vert
    h0, h1 = edge_corners if edge_corners is not None else level.edge_corner_pair()

    # ----- which rule each row follows before and after the step (sharpness decay: warp_subdiv.rules.crease)
    parent_rule = level.vert_class[vs]
    sharp = level.edge_sharp[es]
    if has_semi_sharpness(level):
        halves, child_vs = child_sharpness(level)
        child_rule, edge_child_rule = level_child_rules(level, halves, child_vs)
        child_rule, edge_child_rule = child_rule[vs], edge_child_rule[es]
        transition = crease.vertex_transitions(parent_rule, child_rule)
        # rows without a transition follow their parent rule alone (fractional weight 1)
        fraction = (np.where(transition, level_fractional_weight(level, halves, child_vs)[vs], 1.0)
                    if np.any(transition) else np.ones(nv))
        child_pairs = crease_neighbours(level, halves > 0, vs)
    else:  # no sharpness decays: every rule stays as it is
        child_rule = parent_rule
        edge_child_rule = np.where(sharp, CREASE, SMOOTH).astype(np.int8)
        transition = np.zeros(nv, dtype=bool)
        fraction = np.ones(nv)
        child_pairs = None
    parent_weight, child_weight = rules.transition_weights(fraction)
    parent_pairs = crease_neighbours(level, vertices=vs)

    def smooth_rule(rule):
        return (rule == SMOOTH) | (rule == DART)

    # ----- row sizes (the smooth rule's only where some row uses it)
    needs_smooth = bool(np.any(smooth_rule(parent_rule)) or np.any(transition & smooth_rule(child_rule)))
    slots = None
    if needs_smooth:  # every corner around the rows' vertices, vertex by vertex in ring order
        voff = level.vert_corner_offsets
        first_slot = voff[vs].astype(np.int64)
        valence = voff[vs + 1] - first_slot
        owner, rank = expand_counts(valence)
        slot_corner = level.vert_corners[first_slot[owner] + rank].astype(np.int64)
        slot_face = level.corner_face(slot_corner)
        per_slot = (face_sizes[slot_face] - 2) if cc else np.ones(len(slot_corner), dtype=np.int64)
        slots = _Slots(owner, valence, slot_corner, slot_face, per_slot)
        smooth_size = 1 + np.bincount(owner, weights=per_slot, minlength=nv).astype(np.int64)
    else:
        smooth_size = np.zeros(nv, dtype=np.int64)

    def rule_size(rule):
        return np.where(smooth_rule(rule), smooth_size, np.where(rule == CREASE, 3, 1))

    first_size = rule_size(parent_rule)
    vertex_sizes = first_size + np.where(transition, rule_size(child_rule), 0)

    g0, g1 = h0[es], h1[es]
    m0, m1 = face_sizes[level.corner_face(g0)], face_sizes[level.corner_face(g1)]
    smooth_edge_size = (m0 + m1 - 2) if cc else np.full(ne, 4)
    # a semi-sharp edge whose children are not both sharp blends the crease and smooth rules
    edge_blend = crease.edge_transitions(sharp, edge_child_rule)
    edge_sizes = np.where(sharp, 2 + np.where(edge_blend, smooth_edge_size, 0), smooth_edge_size)
    out = _Layout(np.concatenate([vertex_sizes] + ([face_sizes] if with_faces else []) + [edge_sizes]), V)
    face_row0 = nv
    edge_row0 = nv + (F if with_faces else 0)

    # ----- vertex rows (row i is vertex vs[i]): the parent rule's mask, then (where the rule changes) the
    # child rule's mask
    row = np.arange(nv, dtype=np.int64)
    for rule, pairs, rows, pos, weight in (
        (parent_rule, parent_pairs, row, np.zeros(nv, np.int64), parent_weight),
        (child_rule, child_pairs, row[transition], first_size, child_weight),
    ):
        corner = rows[rule[rows] == CORNER]
        mask = rules.corner_vertex_mask(len(corner)).scaled(weight[corner])
        out.put(corner, pos[corner], vs[corner], mask.centre)
        creased = rows[rule[rows] == CREASE]
        mask = rules.crease_vertex_mask(len(creased)).scaled(weight[creased])
        nb = pairs[creased] if len(creased) else np.zeros((0, 2), np.int64)
        out.put(creased, pos[creased], vs[creased], mask.centre)
        out.put(creased, pos[creased] + 1, nb[:, 0], mask.edge)
        out.put(creased, pos[creased] + 2, nb[:, 1], mask.edge)
        if needs_smooth:
            _put_smooth_vertices(level, out, rows[smooth_rule(rule[rows])], vs, pos, weight, loop_beta, slots,
                                 h0, h1)

    # ----- face rows (Catmull-Clark)
    if with_faces:
        c = np.arange(level.num_corners, dtype=np.int64)
        f_of_c = level.corner_face(c)
        face_starts = level.face_starts()
        out.put(face_row0 + f_of_c, c - face_starts[f_of_c], corner_vert[c],
                rules.face_point_weights(face_sizes[f_of_c]))

    # ----- edge rows (row edge_row0 + j is edge es[j]): the crease rule's mask, then (semi-sharp edges whose
    # rule changes) the smooth rule's; the crease rule weighs 1 on crease edges, 0 on smooth ones and the
    # edge's sharpness where it blends
    ev = level.edge_verts[es].astype(np.int64)
    crease_weight, smooth_weight = rules.semi_sharp_edge_weights(
        np.where(edge_blend, level.edge_sharpness[es], np.where(sharp, 1.0, 0.0)))
    se = np.flatnonzero(sharp)
    mask = rules.crease_edge_mask(len(se)).scaled(crease_weight[se])
    out.put(edge_row0 + se, 0, ev[se, 0], mask.end_a)
    out.put(edge_row0 + se, 1, ev[se, 1], mask.end_b)

    me = np.flatnonzero(~sharp | edge_blend)
    g0, g1, m0, m1 = g0[me], g1[me], m0[me], m1[me]
    mask = _smooth_edge_mask(level, rule_set, es[me], h0, m0, m1, smooth_triangles)
    if cc:  # the two face points, written out over their faces' vertices
        mask = rules.expand_edge_face_points(mask, m0, m1)
    mask = mask.scaled(smooth_weight[me])
    pos0 = np.where(edge_blend[me], 2, 0)
    rows = edge_row0 + me
    out.put(rows, pos0, ev[me, 0], mask.end_a)
    out.put(rows, pos0 + 1, ev[me, 1], mask.end_b)
    # each side's face: its vertices after the edge (Loop: the one opposite vertex)
    for g, m, wing, base_pos in ((g0, m0, mask.wing_0, pos0 + 2), (g1, m1, mask.wing_1, pos0 + m0)):
        if level.face_size:  # one face size: the same number of vertices on every side
            for t in range(level.face_size - 2):
                out.put(rows, base_pos + t, corner_vert[_advance(level, g, t + 2)], wing)
            continue
        rep, t = expand_counts(m - 2)
        walk = _advance(level, g[rep], t + 2)
        out.put(rows[rep], base_pos[rep] + t, corner_vert[walk], wing[rep])
    table = out.table()
    if regular is not None:  # the child vertices of the rows kept (none is empty; the check is cheap)
        child = np.concatenate([vs, V + (F if cc else 0) + es])
        keep = np.flatnonzero(np.diff(table.offsets) > 0)
        table.rows = child[keep].astype(np.int32)
        table.offsets = np.concatenate([[0], np.cumsum(np.diff(table.offsets)[keep])]).astype(np.int32)
    return table


@dataclass
class _Slots:
    """The corners around some vertex rows, vertex by vertex in ring order: ``owner`` (the row of each),
    ``valence`` (corners per row), ``corner``, ``face`` (the corner's face) and ``per_slot`` (the row entries
    each corner adds under the smooth rule: its face's vertices other than the centre and the previous edge
    neighbour, Catmull-Clark; 1 under Loop)."""

    owner: np.ndarray
    valence: np.ndarray
    corner: np.ndarray
    face: np.ndarray
    per_slot: np.ndarray


def _put_smooth_vertices(level, out, rows, vs, pos, weight, loop_beta, slots: _Slots, h0, h1):
    """The smooth (interior) vertex rule for the vertex rows ``rows`` (ascending; row i is vertex vs[i]) at row
    position ``pos``, times ``weight``.

    Row layout: the vertex, then per slot (its corners in ring order) the edge neighbour that follows the
    corner and the corner face's other vertices (Catmull-Clark faces of four or more vertices)."""
    if len(rows) == 0:
        return
    cc = level.scheme == CATMULL_CLARK
    face_sizes = level.face_sizes()
    corner_vert = level.corner_vert
    selected = np.zeros(len(vs), dtype=bool)
    selected[rows] = True
    pick = np.flatnonzero(selected[slots.owner])  # the slots of these rows, row by row
    sl_r = slots.owner[pick]
    sl_h = slots.corner[pick]
    per_slot = slots.per_slot[pick]
    valence = slots.valence[rows]
    slot_row = np.repeat(np.arange(len(rows), dtype=np.int64), valence)
    # position of each slot's first entry inside its row: 1 + entries of the row's earlier slots
    cum = np.concatenate([[0], np.cumsum(per_slot)])
    first = np.repeat(cum[np.concatenate([[0], np.cumsum(valence)[:-1]])], valence)  # (a row of no slot: none)
    sl_pos = pos[sl_r] + 1 + cum[:-1] - first
    nxt = level.corner_next(sl_h)
    mask = rules.smooth_vertex_mask(level.scheme, valence, loop_beta)
    if cc:  # face sizes of the slot's face and of the face across the slot's edge, for the face points
        e_sl = level.corner_edge[sl_h].astype(np.int64)
        other = h0[e_sl] + h1[e_sl] - sl_h
        ring = rules.ring_mask(mask, slot_row, face_sizes[slots.face[pick]], face_sizes[level.corner_face(other)])
    else:
        ring = rules.ring_mask(mask, slot_row)
    ring = ring.scaled(weight[rows])
    out.put(rows, pos[rows], vs[rows], ring.centre)
    out.put(sl_r, sl_pos, corner_vert[nxt], ring.edge)
    # the slot face's vertices that are neither the centre nor its edge neighbours in the face
    if level.face_size:  # one face size: the same number in every slot (none for triangles)
        for t in range(level.face_size - 3):
            out.put(sl_r, sl_pos + 1 + t, corner_vert[_advance(level, nxt, t + 1)], ring.face)
        return
    rep, t = expand_counts(per_slot - 1)
    walk = _advance(level, nxt[rep], t + 1)
    out.put(sl_r[rep], sl_pos[rep] + 1 + t, corner_vert[walk], ring.face[rep])


@dataclass
class RegularTables:
    """What the regular kernels need to compute the smooth rows of one step from the level's index tables.

    Uniform levels only (all quads or all triangles). Only what index arithmetic cannot give is stored
    (issue 17): on a level of quads corner h belongs to face h // 4 and its next corner is
    h - h % 4 + (h + 1) % 4, so an edge is its two corners (its endpoints, the corner vertex and the next
    one, and its faces follow) and a vertex's ring is its corners (each one's next vertex and its face's face
    point); triangles keep each edge's four vertices and each vertex's ring vertices. ``vertex_regular`` and
    ``edge_regular`` (uint8) mark the rows the kernels compute, and are empty where every row is regular;
    every other row is in ``explicit``. ``ring_weights`` are per-valence weights (centre, each ring term) from
    :mod:`warp_subdiv.rules`; ``edge_weights`` are the smooth edge weights (each endpoint, each wing term).
    """

    face_size: int
    num_vertices: int
    num_faces: int
    corner_vert: np.ndarray  # quads: the level's face corners (empty for triangles: their kernels never read it)
    edge_neighbours: np.ndarray  # quads (E, 2): the edge's two corners; triangles (E, 4): a, b, opposite 0, 1
    vert_corner_offsets: np.ndarray
    ring: np.ndarray  # per vertex (CSR by vert_corner_offsets): quads its corners, triangles its ring vertices
    vertex_regular: np.ndarray  # (V,) uint8, or (0,): every vertex row is regular
    edge_regular: np.ndarray  # (E,) uint8, or (0,): every edge row is regular
    ring_weights: np.ndarray  # (max valence + 1, 2)
    edge_weights: np.ndarray  # (2,)
    explicit: StencilTable
    num_rows: int  # child vertices of the step

    @property
    def num_edges(self) -> int:
        return len(self.edge_neighbours)

    def nbytes(self, weight_bytes: int = 4) -> int:
        """Bytes of the tables the kernels read on the device (the weights per valence aside)."""
        arrays = (self.corner_vert, self.edge_neighbours, self.vert_corner_offsets, self.ring,
                  self.vertex_regular, self.edge_regular)
        return sum(a.nbytes for a in arrays) + self.explicit.nbytes(weight_bytes)


def _edge_neighbours(level: Level, h0: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """Per edge what the edge kernels read: on quads (E, 2) int32 its two corners (endpoints and face points
    follow by index arithmetic); on triangles (E, 4) int32 its endpoints, then the vertices opposite it, so
    the kernel reads four indices in a row."""
    if level.face_size == 4:
        out = np.empty((level.num_edges, 2), dtype=np.int32)
        out[:, 0], out[:, 1] = h0, h1
        return out
    out = np.empty((level.num_edges, 4), dtype=np.int32)
    # the endpoint pair as one 8-byte value per edge (half the element copies of a strided int32 copy)
    out.view(np.int64)[:, 0] = np.ascontiguousarray(level.edge_verts, dtype=np.int32).view(np.int64).reshape(-1)
    opposite = level.at_prev(level.corner_vert)  # the vertex before each corner: the one opposite its edge
    out[:, 2] = opposite[h0]
    out[:, 3] = opposite[h1]
    return out


def _flags(regular: np.ndarray) -> np.ndarray:
    """A row mask as the kernels read it: uint8, or empty where every row is regular."""
    return np.zeros(0, np.uint8) if regular.all() else regular.astype(np.uint8)


def build_regular(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop") -> RegularTables:
    """Split one step into rows the regular kernels compute from the index tables and explicit stencils.

    Regular rows: interior and dart vertices (the smooth vertex rule of their valence) and non-crease edges
    whose endpoint weights are the smooth ones (no crease/corner-neighbour shift). Crease and corner vertices,
    crease edges and the crease/corner-neighbour edges of extraordinary sectors get explicit stencils.
    """
    assert level.face_size == (4 if level.scheme == CATMULL_CLARK else 3), \
        "regular kernels need a level of quads (Catmull-Clark) or triangles (Loop)"
    scheme = level.scheme
    vclass = level.vert_class
    vertex_regular = (vclass == SMOOTH) | (vclass == DART)
    h0, h1 = level.edge_corner_pair()
    edge_regular = ~level.edge_sharp
    plain = rules.smooth_edge_mask(scheme, 1)
    w, w_wing = plain.end_a[0], plain.wing_0[0]
    if rule_set != "opensubdiv" and level.num_sectors:  # else every smooth edge has the smooth endpoint weights
        # only an edge with a crease or corner endpoint can have other endpoint weights (_smooth_edge_mask)
        tagged = (vclass == CREASE) | (vclass == CORNER)
        ev = level.edge_verts
        me = np.flatnonzero(edge_regular & (tagged[ev[:, 0]] | tagged[ev[:, 1]]))
        m = np.full(len(me), level.face_size, dtype=np.int64)
        mask = _smooth_edge_mask(level, rule_set, me, h0, m, m)
        edge_regular[me[(mask.end_a != w) | (mask.end_b != w)]] = False
    if vertex_regular.all() and edge_regular.all():  # nothing irregular on this level (common on closed meshes)
        explicit = StencilTable(np.zeros(1, np.int32), np.zeros(0, np.int32), np.zeros(0), level.num_vertices,
                                rows=np.zeros(0, np.int32))
    else:
        explicit = build_stencils(level, rule_set, loop_beta, regular=(vertex_regular, edge_regular),
                                  edge_corners=(h0, h1))
    valence = np.arange(np.diff(level.vert_corner_offsets).max() + 1, dtype=np.float64)
    valence[valence < 2] = 3  # unused entries (a smooth vertex has 2 faces or more: 2 in a closed pillow)
    ring_mask = rules.smooth_vertex_mask(scheme, valence, loop_beta)
    if scheme == CATMULL_CLARK:  # the quad kernels weigh ring and face-point terms alike: 1/n^2
        assert np.allclose(ring_mask.edge, ring_mask.face)
    ring = np.stack([ring_mask.centre, ring_mask.edge], axis=1)
    edge_weights = np.array([w, w_wing])  # Catmull-Clark: (a + b + f0 + f1) / 4
    quads = level.face_size == 4
    return RegularTables(
        face_size=level.face_size,
        num_vertices=level.num_vertices,
        num_faces=level.num_faces,
        corner_vert=level.corner_vert if quads else np.zeros(0, np.int32),
        edge_neighbours=_edge_neighbours(level, h0, h1),
        vert_corner_offsets=level.vert_corner_offsets.astype(np.int32),
        ring=level.vert_corners if quads else level.at_next(level.corner_vert)[level.vert_corners],
        vertex_regular=_flags(vertex_regular),
        edge_regular=_flags(edge_regular),
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
