"""Builders of a step's tables: for each level, one CSR row per child vertex over the parent level's vertices.

Rows follow the child vertex order of :mod:`warp_subdiv.topology` (vertex children, face children for
Catmull-Clark, edge children). As OpenSubdiv's ``far/stencilTableFactory`` expands ``Sdc`` masks, this module
only decides which class each row is (from the level's vertex classes and :mod:`warp_subdiv.rules.crease`'s
sharpness decay), gathers the neighbourhood indices (by index arithmetic over the level's tables) and writes
the role masks that :mod:`warp_subdiv.rules` returns for that class into the rows. Weights are float64. The
tables themselves are :mod:`warp_subdiv.tables.stencil_table`'s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rules import crease
from ..rules import weights as rules
from ..runtime.estimate import check_int32
from ..runtime.threads import take
from ..mesh import expand_counts, face_offsets_of
from ..rules import CATMULL_CLARK, CORNER, CREASE, DART, SMOOTH
from ..topology import Level, child_sharpness, has_semi_sharpness, level_child_rules, level_fractional_weight
from .stencil_table import RegularTables, StencilTable


class _StencilEntries:
    """The entries of a stencil table's rows while they are filled: (row, position in row) -> (parent vertex,
    weight), for rows whose sizes are known up front."""

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
        assert np.all(self.indices >= 0), "a stencil row left an entry unfilled"
        return StencilTable(
            offsets=self.offsets.astype(np.int32),
            indices=self.indices.astype(np.int32),
            weights=self.weights,
            num_sources=self.num_sources,
        )


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
    V, F, E = level.num_vertices, level.num_faces, level.num_edges
    cc = level.scheme == CATMULL_CLARK
    if regular is None:  # every row, in child vertex order
        vs, es = np.arange(V, dtype=np.int64), np.arange(E, dtype=np.int64)
    else:
        vs, es = np.flatnonzero(~regular[0]), np.flatnonzero(~regular[1])
    with_faces = cc and regular is None
    face_sizes = level.face_sizes()
    h0, h1 = edge_corners if edge_corners is not None else level.edge_corner_pair()
    row_rules = _row_rules(level, vs, es)
    slots = _Slots.around(level, vs, face_sizes) if row_rules.needs_smooth else None
    vertex_first, vertex_sizes = _vertex_row_sizes(row_rules, slots)
    sides = _EdgeSides.of(level, es, h0, h1, face_sizes)
    out = _StencilEntries(np.concatenate([vertex_sizes] + ([face_sizes] if with_faces else [])
                                         + [_edge_row_sizes(row_rules, sides, cc)]), V)
    _put_vertex_rows(level, out, vs, row_rules, vertex_first, slots, loop_beta, h0, h1)
    if with_faces:
        _put_face_rows(level, out, len(vs), face_sizes)
    _put_edge_rows(level, out, len(vs) + (F if with_faces else 0), es, row_rules, sides, rule_set, h0,
                   smooth_triangles)
    table = out.table()
    if regular is not None:  # the child vertices of the rows kept (none is empty; the check is cheap)
        child = np.concatenate([vs, V + (F if cc else 0) + es])
        keep = np.flatnonzero(np.diff(table.offsets) > 0)
        table.rows = child[keep].astype(np.int32)
        table.offsets = np.concatenate([[0], np.cumsum(np.diff(table.offsets)[keep])]).astype(np.int32)
    return table


def _smooth_rule(rule: np.ndarray) -> np.ndarray:
    """Whether rows of vertex class ``rule`` follow the smooth (interior) vertex rule."""
    return (rule == SMOOTH) | (rule == DART)


@dataclass
class _RowRules:
    """Which rule each row of a step follows before and after the step (sharpness decay:
    :mod:`warp_subdiv.rules.crease`).

    Vertex rows (row i is vertex ``vs[i]``): ``parent_rule`` and ``child_rule`` (vertex classes), ``transition``
    where they differ; such a row lists the parent rule's mask times ``parent_weight``, then the child rule's
    times ``child_weight`` (rows without a transition: the parent rule alone, weight 1). ``parent_pairs`` and
    ``child_pairs``: the crease neighbours each rule weighs (``child_pairs`` None where no sharpness decays).
    Edge rows (row j is edge ``es[j]``): ``sharp``, ``edge_blend`` (a semi-sharp edge whose children are not
    both sharp blends the crease and smooth rules) and ``edge_sharpness`` (the edge's sharpness, the crease
    rule's weight where it blends).
    """

    parent_rule: np.ndarray
    child_rule: np.ndarray
    transition: np.ndarray
    parent_weight: np.ndarray
    child_weight: np.ndarray
    parent_pairs: np.ndarray
    child_pairs: np.ndarray | None
    sharp: np.ndarray
    edge_blend: np.ndarray
    edge_sharpness: np.ndarray

    @property
    def needs_smooth(self) -> bool:
        """Whether some vertex row uses the smooth rule (only then are the rows' rings gathered)."""
        return bool(np.any(_smooth_rule(self.parent_rule))
                    or np.any(self.transition & _smooth_rule(self.child_rule)))


def _row_rules(level: Level, vs: np.ndarray, es: np.ndarray) -> _RowRules:
    """The rules of the vertex rows ``vs`` and edge rows ``es`` of a step over ``level``."""
    parent_rule = level.vert_class[vs]
    sharp = level.edge_sharp[es]
    if has_semi_sharpness(level):
        halves, child_vs = child_sharpness(level)
        child_rule, edge_child_rule = level_child_rules(level, halves, child_vs)
        child_rule, edge_child_rule = child_rule[vs], edge_child_rule[es]
        transition = crease.vertex_transitions(parent_rule, child_rule)
        # rows without a transition follow their parent rule alone (fractional weight 1)
        fraction = (np.where(transition, level_fractional_weight(level, halves, child_vs)[vs], 1.0)
                    if np.any(transition) else np.ones(len(vs)))
        child_pairs = crease_neighbours(level, halves > 0, vs)
    else:  # no sharpness decays: every rule stays as it is
        child_rule = parent_rule
        edge_child_rule = np.where(sharp, CREASE, SMOOTH).astype(np.int8)
        transition = np.zeros(len(vs), dtype=bool)
        fraction = np.ones(len(vs))
        child_pairs = None
    parent_weight, child_weight = rules.transition_weights(fraction)
    return _RowRules(parent_rule, child_rule, transition, parent_weight, child_weight,
                     crease_neighbours(level, vertices=vs), child_pairs, sharp,
                     crease.edge_transitions(sharp, edge_child_rule), level.edge_sharpness[es])


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

    @classmethod
    def around(cls, level: Level, vs: np.ndarray, face_sizes: np.ndarray) -> _Slots:
        """Every corner around the vertices ``vs`` (the vertex rows), vertex by vertex in ring order."""
        voff = level.vert_corner_offsets
        first_slot = voff[vs].astype(np.int64)
        valence = voff[vs + 1] - first_slot
        owner, rank = expand_counts(valence)
        slot_corner = level.vert_corners[first_slot[owner] + rank].astype(np.int64)
        slot_face = level.corner_face(slot_corner)
        per_slot = ((face_sizes[slot_face] - 2) if level.scheme == CATMULL_CLARK
                    else np.ones(len(slot_corner), dtype=np.int64))
        return cls(owner, valence, slot_corner, slot_face, per_slot)

    def smooth_row_sizes(self, num_rows: int) -> np.ndarray:
        """Entries of each of the ``num_rows`` vertex rows under the smooth rule: the vertex and its slots'."""
        return 1 + np.bincount(self.owner, weights=self.per_slot, minlength=num_rows).astype(np.int64)


def _vertex_row_sizes(row_rules: _RowRules, slots: _Slots | None) -> tuple[np.ndarray, np.ndarray]:
    """(entries of the parent rule's mask, entries in all) of every vertex row: the parent rule's mask, then
    (where the rule changes) the child rule's. ``slots``: the rows' rings (None where no row is smooth)."""
    nv = len(row_rules.parent_rule)
    smooth_size = slots.smooth_row_sizes(nv) if slots is not None else np.zeros(nv, dtype=np.int64)

    def rule_size(rule):
        return np.where(_smooth_rule(rule), smooth_size, np.where(rule == CREASE, 3, 1))

    first_size = rule_size(row_rules.parent_rule)
    return first_size, first_size + np.where(row_rules.transition, rule_size(row_rules.child_rule), 0)


def _put_vertex_rows(level: Level, out: _StencilEntries, vs: np.ndarray, row_rules: _RowRules,
                     first_size: np.ndarray, slots: _Slots | None, loop_beta: str, h0: np.ndarray, h1: np.ndarray):
    """The vertex rows (row i is vertex vs[i]): the parent rule's mask, then (where the rule changes) the
    child rule's mask from position ``first_size``."""
    nv = len(vs)
    row = np.arange(nv, dtype=np.int64)
    r = row_rules
    for rule, pairs, rows, pos, weight in (
        (r.parent_rule, r.parent_pairs, row, np.zeros(nv, np.int64), r.parent_weight),
        (r.child_rule, r.child_pairs, row[r.transition], first_size, r.child_weight),
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
        if slots is not None:
            _put_smooth_vertices(level, out, rows[_smooth_rule(rule[rows])], vs, pos, weight, loop_beta, slots,
                                 h0, h1)


def _put_smooth_vertices(level, out, rows, vs, pos, weight, loop_beta, slots: _Slots, h0, h1):
    """The smooth (interior) vertex rule for the vertex rows ``rows`` (ascending; row i is vertex vs[i]) at row
    position ``pos``, times ``weight``.

    A row holds the vertex, then per slot (its corners in ring order) the edge neighbour that follows the
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


def _put_face_rows(level: Level, out: _StencilEntries, first_row: int, face_sizes: np.ndarray):
    """The face point rows of Catmull-Clark (row ``first_row`` + f is face f): the face's vertices."""
    c = np.arange(level.num_corners, dtype=np.int64)
    f_of_c = level.corner_face(c)
    face_starts = level.face_starts()
    out.put(first_row + f_of_c, c - face_starts[f_of_c], level.corner_vert[c],
            rules.face_point_weights(face_sizes[f_of_c]))


@dataclass
class _EdgeSides:
    """The two faces of some edge rows: the edge's corner in each (``g0``, ``g1``; the level's
    ``edge_corner_pair``) and their face sizes (``m0``, ``m1``)."""

    g0: np.ndarray
    g1: np.ndarray
    m0: np.ndarray
    m1: np.ndarray

    @classmethod
    def of(cls, level: Level, es: np.ndarray, h0: np.ndarray, h1: np.ndarray, face_sizes: np.ndarray) -> _EdgeSides:
        g0, g1 = h0[es], h1[es]
        return cls(g0, g1, face_sizes[level.corner_face(g0)], face_sizes[level.corner_face(g1)])


def _edge_row_sizes(row_rules: _RowRules, sides: _EdgeSides, cc: bool) -> np.ndarray:
    """Entries of every edge row: the crease rule's two, the smooth rule's (endpoints and wings), or both
    where a semi-sharp edge blends them."""
    smooth_edge_size = (sides.m0 + sides.m1 - 2) if cc else np.full(len(sides.m0), 4)
    sharp, blend = row_rules.sharp, row_rules.edge_blend
    return np.where(sharp, 2 + np.where(blend, smooth_edge_size, 0), smooth_edge_size)


def _put_edge_rows(level: Level, out: _StencilEntries, first_row: int, es: np.ndarray, row_rules: _RowRules,
                   sides: _EdgeSides, rule_set: str, h0: np.ndarray, smooth_triangles: bool):
    """The edge rows (row ``first_row`` + j is edge es[j]): the crease rule's mask, then (semi-sharp edges whose
    rule changes) the smooth rule's; the crease rule weighs 1 on crease edges, 0 on smooth ones and the
    edge's sharpness where it blends."""
    corner_vert = level.corner_vert
    sharp, edge_blend = row_rules.sharp, row_rules.edge_blend
    ev = level.edge_verts[es].astype(np.int64)
    crease_weight, smooth_weight = rules.semi_sharp_edge_weights(
        np.where(edge_blend, row_rules.edge_sharpness, np.where(sharp, 1.0, 0.0)))
    se = np.flatnonzero(sharp)
    mask = rules.crease_edge_mask(len(se)).scaled(crease_weight[se])
    out.put(first_row + se, 0, ev[se, 0], mask.end_a)
    out.put(first_row + se, 1, ev[se, 1], mask.end_b)

    me = np.flatnonzero(~sharp | edge_blend)
    g0, g1, m0, m1 = sides.g0[me], sides.g1[me], sides.m0[me], sides.m1[me]
    mask = _smooth_edge_mask(level, rule_set, es[me], h0, m0, m1, smooth_triangles)
    if level.scheme == CATMULL_CLARK:  # the two face points, written out over their faces' vertices
        mask = rules.expand_edge_face_points(mask, m0, m1)
    mask = mask.scaled(smooth_weight[me])
    pos0 = np.where(edge_blend[me], 2, 0)
    rows = first_row + me
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


def _edge_neighbours(level: Level, h0: np.ndarray, h1: np.ndarray, threads: int = 1) -> np.ndarray:
    """Per edge what the edge kernels read: on quads (E, 2) int32 its two corners (endpoints and face points
    follow by index arithmetic); on triangles (E, 4) int32 its endpoints, then the vertices opposite it, so
    the kernel reads four indices in a row (gathered on ``threads`` threads)."""
    if level.face_size == 4:
        out = np.empty((level.num_edges, 2), dtype=np.int32)
        out[:, 0], out[:, 1] = h0, h1
        return out
    out = np.empty((level.num_edges, 4), dtype=np.int32)
    # the endpoint pair as one 8-byte value per edge (half the element copies of a strided int32 copy)
    out.view(np.int64)[:, 0] = np.ascontiguousarray(level.edge_verts, dtype=np.int32).view(np.int64).reshape(-1)
    opposite = level.at_prev(level.corner_vert)  # the vertex before each corner: the one opposite its edge
    out[:, 2] = take(opposite, h0, threads)
    out[:, 3] = take(opposite, h1, threads)
    return out


def _flags(regular: np.ndarray) -> np.ndarray:
    """A row mask as the kernels read it: uint8, or empty where every row is regular."""
    return np.zeros(0, np.uint8) if regular.all() else regular.astype(np.uint8)


def build_regular(level: Level, rule_set: str = "piecewise-smooth", loop_beta: str = "loop",
                  threads: int = 1) -> RegularTables:
    """Split one step into rows the regular kernels compute from the index tables and explicit stencils (their
    large gathers on ``threads`` threads; the tables do not depend on it).

    Regular rows: interior and dart vertices (the smooth vertex rule of their valence) and non-crease edges
    whose endpoint weights are the smooth ones (no crease/corner-neighbour shift). Crease and corner vertices,
    crease edges and the crease/corner-neighbour edges of extraordinary sectors get explicit stencils.
    """
    assert level.face_size == (4 if level.scheme == CATMULL_CLARK else 3), \
        "regular kernels need a level of quads (Catmull-Clark) or triangles (Loop)"
    scheme = level.scheme
    vclass = level.vert_class
    vertex_regular = (vclass == SMOOTH) | (vclass == DART)
    h0, h1 = level.edge_corner_pair(threads)
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
        edge_neighbours=_edge_neighbours(level, h0, h1, threads),
        vert_corner_offsets=level.vert_corner_offsets.astype(np.int32),
        ring=level.vert_corners if quads else take(level.at_next(level.corner_vert), level.vert_corners, threads),
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
