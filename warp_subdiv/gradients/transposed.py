"""The transposed tables of a refinement, built on the host (numpy) for the backward pass.

The adjoint of a gather is a scatter, and the transposed table turns it back into a gather, one thread per
parent row: no atomics, so gradients are bitwise equal run to run and for any thread count. On uniform levels
the smooth rows are transposed as index tables over each parent vertex's corners (:class:`RegularAdjoint`,
applied by the kernels of :mod:`warp_subdiv.kernels.adjoint`: no stored weights but the ring weights, as the
forward kernels); the explicit rows, the steps of non-uniform levels (:class:`TransposedStep`), the displacements
(:func:`transposed_displacement`) and the limit masks (:func:`transposed_limit`) as transposed CSR tables
(applied with the forward gather kernels).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import expand_counts
from ..tables import StencilTable, rows_of
from ..topology import base_level, refine_level
from .sparse import step_entries


def _by_column(rows, cols, vals, num_cols: int):
    """Entries regrouped by column, stably (entries of one column in entry order), with entries of the same
    (column, row) that end up adjacent merged (float64, in entry order): (column offsets, rows, weights).

    Entries in row order (a CSR table's) come out sorted by (column, row) with every duplicate merged. scipy's
    linear-time CSR-to-CSC conversion does the regrouping where scipy is installed (the same order as numpy's
    stable sort, which is used otherwise), so the tables are bitwise the same either way."""
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    vals = np.asarray(vals, np.float64)
    n = len(rows)
    sorted_rows = n == 0 or bool(np.all(rows[1:] >= rows[:-1]))
    num_rows = int(rows.max()) + 1 if n else 0
    try:
        if not sorted_rows or n >= 2 ** 31 or num_cols >= 2 ** 31:
            raise ImportError
        import scipy.sparse as sp
    except ImportError:
        order = np.argsort(cols, kind="stable")
        r, c, w = rows[order], cols[order], vals[order]
    else:
        indptr = np.zeros(num_rows + 1, np.int64)
        np.cumsum(np.bincount(rows, minlength=num_rows), out=indptr[1:])
        m = sp.csr_matrix((vals, cols, indptr), shape=(num_rows, num_cols)).tocsc()
        r, w = m.indices.astype(np.int64), m.data
        c = rows_of(m.indptr)
    if n:
        start = np.flatnonzero(np.r_[True, (c[1:] != c[:-1]) | (r[1:] != r[:-1])])
        if len(start) < n:
            w = np.add.reduceat(w, start)
            r, c = r[start], c[start]
    offsets = np.zeros(num_cols + 1, np.int64)
    np.cumsum(np.bincount(c, minlength=num_cols), out=offsets[1:])
    return offsets, r, w


def _grouped(rows, cols, vals, num_groups: int, num_rows: int, pad: bool) -> StencilTable:
    """The entries regrouped by column: a CSR table with one row per column (``num_groups``) listing (row, weight)
    (see :func:`_by_column`). ``pad``: an empty group gets one zero-weight entry (the gather kernels read a
    row's first entry unconditionally)."""
    offsets, r, w = _by_column(rows, cols, vals, num_groups)
    return _table(offsets, r, w, num_rows, pad)


def _table(offsets, r, w, num_rows: int, pad: bool) -> StencilTable:
    """A CSR table of grouped entries, empty rows padded with a zero-weight entry to row 0 where ``pad``."""
    counts = np.diff(offsets)
    if pad and np.any(counts == 0):
        filled = counts > 0
        new_counts = np.where(filled, counts, 1)
        new = np.zeros(len(counts) + 1, np.int64)
        np.cumsum(new_counts, out=new[1:])
        at = np.repeat(new[:-1][filled] - offsets[:-1][filled], counts[filled]) + np.arange(len(r))
        rr, ww = np.zeros(new[-1], np.int64), np.zeros(new[-1])
        rr[at], ww[at] = r, w
        offsets, r, w = new, rr, ww
    return StencilTable(np.asarray(offsets).astype(np.int32), np.asarray(r).astype(np.int32), np.asarray(w),
                        num_rows)


@dataclass
class TransposedStep:
    """The transposed rows of one step, as two gathers over the parent vertices (both in the table order of
    :func:`_by_column`): ``near`` reads the child rows below the parent count (the vertex children, which lie
    near their parents and are a parent level's size) and assigns every parent row; ``far`` reads the other
    child rows (face and edge children) and adds to the parents that have some, visited in the order of their
    first such child (``far.rows``), so that the reads of a stretch of the far rows run through one region of
    the child level. Two passes with smaller working sets run faster than one over the whole child level."""

    near: StencilTable
    far: StencilTable


#: Child levels of at least this many rows are read in two passes (:class:`TransposedStep`); below it one pass,
#: whose working set fits the caches anyway, is faster (measured on Loop and Catmull-Clark, BENCHMARKS.md).
SPLIT_ROWS = 1 << 20


def transposed_step(t: StencilTable, split: bool | None = None) -> TransposedStep:
    """The transposed table of one step (a gather per parent vertex over the child rows); ``split`` (default:
    child levels of :data:`SPLIT_ROWS` rows or more) reads the far child rows in a second pass."""
    rows, cols, vals = step_entries(t)
    P = t.num_sources
    offsets, r, w = _by_column(rows, cols, vals, P)
    c = rows_of(offsets)
    if split is None:
        split = t.num_rows >= SPLIT_ROWS
    if not split:
        return TransposedStep(_table(offsets, r, w, t.num_rows, pad=True), _table(np.zeros(1, np.int64), r[:0],
                                                                                  w[:0], t.num_rows, pad=False))
    low = r < P
    near_offsets = np.zeros(P + 1, np.int64)
    np.cumsum(np.bincount(c[low], minlength=P), out=near_offsets[1:])
    near = _table(near_offsets, r[low], w[low], t.num_rows, pad=True)
    far_c, far_r, far_w = c[~low], r[~low], w[~low]
    counts = np.bincount(far_c, minlength=P)
    parents = np.flatnonzero(counts)
    first = np.zeros(P, np.int64)
    if len(far_r):
        starts = np.zeros(P + 1, np.int64)
        np.cumsum(counts, out=starts[1:])
        first[parents] = far_r[starts[parents]]
    order = parents[np.argsort(first[parents], kind="stable")]
    new = np.zeros(len(order) + 1, np.int64)
    np.cumsum(counts[order], out=new[1:])
    starts = np.zeros(P + 1, np.int64)
    np.cumsum(counts, out=starts[1:])
    group, rank = expand_counts(counts[order])
    pos = starts[order][group] + rank
    far = StencilTable(new.astype(np.int32), far_r[pos].astype(np.int32), far_w[pos], t.num_rows,
                       rows=order.astype(np.int32))
    return TransposedStep(near, far)


@dataclass
class _Displacement:
    """A transposed displacement table, in the layout of :class:`~warp_subdiv.tables.projections.DisplacementTable`."""

    targets: np.ndarray
    offsets: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    normal_ids: np.ndarray | None = None
    normals: np.ndarray | None = None

    @property
    def num_rows(self) -> int:
        return len(self.targets)


def transposed_displacement(d):
    """(I + D)^T as a displacement table: rows are the points D reads, entries the points it moves (with their
    normals for normal control, whose n n^T blocks are symmetric). None stays None."""
    if d is None:
        return None
    tgt = np.asarray(d.targets, np.int64)[rows_of(d.offsets)]
    src = np.asarray(d.indices, np.int64)
    order = np.lexsort((tgt, src))  # by source, then target; entry order among equals
    src, tgt = src[order], tgt[order]
    w = np.asarray(d.weights, np.float64)[order]
    uniq, counts = np.unique(src, return_counts=True)
    offsets = np.zeros(len(uniq) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    out = _Displacement(uniq.astype(np.int32), offsets.astype(np.int32), tgt.astype(np.int32), w)
    if d.normal_ids is not None:
        out.normal_ids = np.asarray(d.normal_ids)[order].astype(np.int32)
        out.normals = d.normals
    return out


@dataclass
class RegularAdjoint:
    """The transposed smooth rows of one uniform step (:class:`~warp_subdiv.tables.RegularTables`) as index
    tables over the parent level, in the manner of the forward kernels: one *slot* per corner h of a parent
    vertex j (CSR by ``offsets``, the level's vertex corners), holding h's next vertex u with the ring weight of
    u's row, the child row of h's edge and (quads) h's face or (triangles) the child row of the edge opposite j.
    Edge rows carry the step's smooth edge weights ``edge_weights`` (endpoint, wing); an edge row left to the
    explicit stencils is -1 (and a vertex row's weight 0). Quads add per face corner its vertex, its ring
    weight and the child row of its edge, for the face-point gradients (:func:`quad_face_adjoint`).
    ``explicit``: the explicit rows transposed (rows: the parents they read, in order). ``far`` (triangles on
    large levels): the edge terms again, for a second pass in another parent order (:func:`tri_edge_adjoint`):
    (order, offsets, edge rows, opposite rows)."""

    quads: bool
    face_row: int
    offsets: np.ndarray
    slot_vert: np.ndarray
    slot_edge_row: np.ndarray
    slot_third: np.ndarray  # quads: the slot's face; triangles: the child row of the opposite edge (or -1)
    w_centre: np.ndarray
    w_vert: np.ndarray
    edge_weights: np.ndarray
    face_vert: np.ndarray | None
    face_edge_row: np.ndarray | None
    face_w_vert: np.ndarray | None
    explicit: StencilTable
    num_faces: int
    far: tuple | None = None


def _flags(mask: np.ndarray, n: int) -> np.ndarray:
    return np.asarray(mask, bool) if len(mask) else np.ones(n, bool)


def regular_adjoint(level, t, split: bool | None = None) -> RegularAdjoint:
    """The :class:`RegularAdjoint` of the step ``t`` (a RegularTables) over ``level`` (its full topology).
    ``split`` (triangles; default: child levels of :data:`SPLIT_ROWS` rows or more): the edge terms go to a
    second pass (:func:`tri_edge_adjoint`), which reads the edge children in long runs."""
    V, E = level.num_vertices, level.num_edges
    quads = t.face_size == 4
    F = level.num_faces if quads else 0
    edge_row = V + F
    vreg, ereg = _flags(t.vertex_regular, V), _flags(t.edge_regular, E)
    off = np.asarray(level.vert_corner_offsets, np.int64)
    valence = np.diff(off)
    rw = np.asarray(t.ring_weights, np.float64)
    cv = np.asarray(level.corner_vert, np.int64)
    ce = np.asarray(level.corner_edge, np.int64)
    h = np.asarray(level.vert_corners, np.int64)
    nxt = level.corner_next(h)
    u, e = cv[nxt], ce[h]
    ring_w = np.where(vreg, rw[np.minimum(valence, len(rw) - 1), 1], 0.0)  # each vertex row's ring weight
    x = t.explicit
    r = (np.asarray(x.rows, np.int64)[rows_of(x.offsets)] if x.rows is not None else rows_of(x.offsets))
    offsets, er, ew = _by_column(r, x.indices, x.weights, V)
    parents = np.flatnonzero(np.diff(offsets))
    explicit = StencilTable(np.r_[0, np.cumsum(np.diff(offsets)[parents])].astype(np.int32), er.astype(np.int32),
                            ew, t.num_rows, rows=parents.astype(np.int32))
    i32 = np.int32

    def edge_rows(edges):
        return np.where(ereg[edges], edge_row + edges, -1).astype(i32)

    common = dict(quads=quads, face_row=V, offsets=off.astype(i32), slot_vert=u.astype(i32),
                  slot_edge_row=edge_rows(e), w_centre=np.where(vreg, rw[np.minimum(valence, len(rw) - 1), 0], 0.0),
                  w_vert=ring_w[u], edge_weights=np.asarray(t.edge_weights, np.float64), explicit=explicit,
                  num_faces=F)
    if quads:
        return RegularAdjoint(slot_third=(h // 4).astype(i32), face_vert=cv.astype(i32), face_edge_row=edge_rows(ce),
                              face_w_vert=ring_w[cv], **common)
    out = RegularAdjoint(slot_third=edge_rows(ce[nxt]), face_vert=None, face_edge_row=None, face_w_vert=None,
                         **common)
    if split is None:
        split = t.num_rows >= SPLIT_ROWS
    if split:  # the edge terms in a second pass, parents in the order of their last incident edge
        last = np.full(V, -1, np.int64)
        has = valence > 0
        last[has] = np.maximum.reduceat(out.slot_edge_row, off[:-1][has])
        order = np.argsort(last, kind="stable")
        group, rank = expand_counts(valence[order])
        pos = off[order][group] + rank
        out.far = (order.astype(i32), np.r_[0, np.cumsum(valence[order])].astype(i32), out.slot_edge_row[pos],
                   out.slot_third[pos])
    return out


def levels_of(refiner):
    """The levels 0..levels - 1 of ``refiner`` with their full topology, rebuilt from the control mesh as
    :meth:`Hierarchy.full_stencils` rebuilds them (the hierarchy keeps only its last two)."""
    h, o = refiner.hierarchy, refiner.options
    level = base_level(h.mesh, o.scheme, o.boundary, o.rules, o.triangulate,
                       flatness=o.flatness if o.piecewise_smooth else None, crease_method=o.crease_method,
                       linear=o.linear)
    for k in range(refiner.levels):
        yield level
        if k + 1 < refiner.levels:
            level = refine_level(level)


def transposed_limit(tables, rows: int) -> tuple:
    """(positions, tangents, T): the transposed limit masks of ``tables`` (a
    :class:`~warp_subdiv.tables.projections.LimitTables`) for the first ``rows`` vertices, one gather row per
    source vertex; the two tangent masks stacked (u gradients in rows 0..T, v gradients in rows T..2T of one
    buffer, T the tangents of those vertices)."""
    n_src = tables.position.num_sources
    r, c, w = step_entries(tables.position)
    keep = r < rows
    pos = _grouped(r[keep], c[keep], w[keep], n_src, rows, pad=True)
    T = int(tables.vertex_offsets[rows])
    parts = []
    for shift, table in ((0, tables.tangent_u), (T, tables.tangent_v)):
        r, c, w = step_entries(table)
        keep = r < T
        parts.append((r[keep] + shift, c[keep], w[keep]))
    r, c, w = (np.concatenate(p) for p in zip(*parts))
    return pos, _grouped(r, c, w, n_src, 2 * T, pad=True), T
