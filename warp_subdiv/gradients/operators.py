"""Gradients of refinement: the sparse operator of a :class:`~warp_subdiv.refiner.Refiner` and its adjoint.

Refinement is linear in the control data. One step maps level k - 1 to level k as ``x_k = N_k F_k S_k x_{k-1}``:
``S_k`` the step's stencil rows (index tables and explicit stencils, :mod:`warp_subdiv.tables`), ``F_k = I +``
the flatness displacements (per column, any width) and ``N_k = I +`` the normal-control projections (positions
only: entries ``w n n^T`` couple the three coordinates; docs/rules.md section 7 has no ``x^0`` term, so normal
control is linear too and the affine offset is zero). Limit positions apply one more table; limit normals are
non-linear (normalised sums of cross products of two tangent masks).

* :func:`matrix` composes the per-step tables into the sparse map from control data to a level (or to the
  limit): a ``scipy.sparse.csr_matrix`` where scipy is installed, else a :class:`CSRMatrix` of the same arrays.
* The backward pass applies the **transposed** tables: the adjoint of a gather is a scatter, and the transposed
  table turns it back into a gather, one thread per parent row. On uniform levels the smooth rows are
  transposed as index tables over each parent vertex's corners (:class:`RegularAdjoint`, kernels in
  :mod:`warp_subdiv.kernels.adjoint`: no stored weights but the ring weights, as the forward kernels), the
  explicit rows, the steps of non-uniform levels, the displacements and the limit masks as transposed CSR
  tables (applied with the forward gather kernels). No atomics, so gradients are bitwise equal run to run and
  for any thread count. The tables are built once per refiner, on the first backward pass (:class:`Adjoint`).
* Entry points: :func:`evaluate`, :func:`limit_points`, :func:`limit_normals` take and return Warp arrays and
  record their backward on an active ``wp.Tape`` (``Tape.record_func``); :func:`evaluate_vjp`,
  :func:`limit_points_vjp`, :func:`limit_normals_vjp` take and return numpy arrays. The JAX and PyTorch adapters
  (:mod:`warp_subdiv.jax`, :mod:`warp_subdiv.torch`) call :meth:`Adjoint.forward` / :meth:`Adjoint.backward`.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import warp as wp

from .. import evaluator as ev
from ..errors import SubdivInputError
from ..mesh import expand_counts
from ..tables import RegularTables, StencilTable, rows_of

__all__ = ["Adjoint", "CSRMatrix", "adjoint", "evaluate", "evaluate_vjp", "limit_normals", "limit_normals_vjp",
           "limit_points", "limit_points_vjp", "matrix"]


# ------------------------------------------------------------------------------------------------ sparse helpers
class CSRMatrix:
    """A sparse matrix as CSR arrays (``data``, ``indices``, ``indptr``, ``shape``), as ``scipy.sparse.csr_matrix``
    holds it: what :func:`matrix` returns where scipy is not installed. Supports ``@`` with dense vectors and
    matrices, ``.T``, ``toarray()`` and ``nnz``."""

    def __init__(self, data, indices, indptr, shape):
        self.data = np.asarray(data, dtype=np.float64)
        self.indices = np.asarray(indices, dtype=np.int64)
        self.indptr = np.asarray(indptr, dtype=np.int64)
        self.shape = (int(shape[0]), int(shape[1]))

    @property
    def nnz(self) -> int:
        return len(self.data)

    def __repr__(self):
        return f"CSRMatrix(shape={self.shape}, nnz={self.nnz})"

    @property
    def T(self) -> "CSRMatrix":
        c = _from_coo(self.indices, rows_of(self.indptr), self.data, (self.shape[1], self.shape[0]))
        return CSRMatrix(c.data, c.indices, c.indptr, c.shape)

    def __matmul__(self, x):
        x = np.asarray(x)
        if x.shape[0] != self.shape[1]:
            raise ValueError(f"matrix of shape {self.shape} @ array of shape {x.shape}")
        out = np.zeros((self.shape[0],) + x.shape[1:], dtype=np.result_type(x.dtype, np.float64))
        w = self.data.reshape((-1,) + (1,) * (x.ndim - 1))
        np.add.at(out, rows_of(self.indptr), w * x[self.indices])
        return out

    dot = __matmul__

    def toarray(self) -> np.ndarray:
        out = np.zeros(self.shape)
        np.add.at(out, (rows_of(self.indptr), self.indices), self.data)
        return out


@dataclass
class _Csr:
    """Internal canonical CSR (rows sorted, duplicate entries merged), int64 indices, float64 data."""

    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray
    shape: tuple


def _from_coo(rows, cols, vals, shape) -> _Csr:
    """A canonical CSR from entries: sorted by (row, column); entries of one (row, column) summed in entry order."""
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    vals = np.asarray(vals, dtype=np.float64)
    key = rows * max(1, shape[1]) + cols
    order = np.argsort(key, kind="stable")
    key = key[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, np.int64)
    data = np.add.reduceat(vals[order], start) if len(key) else np.zeros(0)
    r = key[start] // max(1, shape[1])
    indptr = np.zeros(shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=shape[0]), out=indptr[1:])
    return _Csr(indptr, key[start] % max(1, shape[1]), data, (int(shape[0]), int(shape[1])))


def _spmm(a: _Csr, b: _Csr) -> _Csr:
    """a @ b."""
    counts = np.diff(b.indptr)[a.indices]
    entry, rank = expand_counts(counts)
    pos = b.indptr[a.indices[entry]] + rank
    a_rows = rows_of(a.indptr)
    return _from_coo(a_rows[entry], b.indices[pos], a.data[entry] * b.data[pos], (a.shape[0], b.shape[1]))


def _identity(n: int) -> _Csr:
    i = np.arange(n, dtype=np.int64)
    return _Csr(np.arange(n + 1, dtype=np.int64), i, np.ones(n), (n, n))


def _blocks(rows, cols, vals, shape, b: int) -> _Csr:
    """The entries as a matrix acting on each of ``b`` interleaved columns alike (kron with I_b)."""
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    c = np.arange(b, dtype=np.int64)
    return _from_coo((rows[:, None] * b + c).ravel(), (cols[:, None] * b + c).ravel(),
                     np.repeat(np.asarray(vals, np.float64), b), (shape[0] * b, shape[1] * b))


def _public(m: _Csr):
    """A scipy.sparse.csr_matrix where scipy is installed, else a :class:`CSRMatrix`."""
    try:
        import scipy.sparse as sp
    except ImportError:
        return CSRMatrix(m.data, m.indices, m.indptr, m.shape)
    return sp.csr_matrix((m.data, m.indices, m.indptr), shape=m.shape)


# ------------------------------------------------------------------------------------------------ step entries
def step_entries(t: StencilTable):
    """(rows, cols, weights) of every entry of a :class:`~warp_subdiv.tables.StencilTable` (int64, float64); rows
    mapped through ``t.rows`` where the table lists only some rows."""
    r = rows_of(t.offsets)
    if t.rows is not None:
        r = np.asarray(t.rows, np.int64)[r]
    return r, t.indices.astype(np.int64), np.asarray(t.weights, np.float64)


def _num_rows(t) -> int:
    return int(t.num_rows)




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


def _levels(refiner):
    """The levels 0..levels - 1 of ``refiner`` with their full topology, rebuilt from the control mesh as
    :meth:`Hierarchy.full_stencils` rebuilds them (the hierarchy keeps only its last two)."""
    from ..topology import base_level, refine_level

    h, o = refiner.hierarchy, refiner.options
    level = base_level(h.mesh, o.scheme, o.boundary, o.rules, o.triangulate,
                       flatness=o.flatness if o.piecewise_smooth else None, crease_method=o.crease_method,
                       linear=o.linear)
    for k in range(refiner.levels):
        yield level
        if k + 1 < refiner.levels:
            level = refine_level(level)


# ------------------------------------------------------------------------------------------------ operator
def _step_operator(refiner, k: int, b: int, normal_control: bool) -> _Csr:
    """Step k (0-based) as a matrix: N F S, on ``b`` interleaved columns (b = 3: positions, with normal control)."""
    hierarchy = refiner.hierarchy
    t = refiner.tables[k]
    rows, cols, vals = step_entries(t)
    nr, ns = t.num_rows, t.num_sources
    op = _blocks(rows, cols, vals, (nr, ns), b)
    flat = hierarchy.flatness_tables[k]
    if flat is not None:
        r = np.asarray(flat.targets, np.int64)[rows_of(flat.offsets)]
        i = np.arange(nr)
        f = _blocks(np.r_[i, r], np.r_[i, flat.indices], np.r_[np.ones(nr), flat.weights], (nr, nr), b)
        op = _spmm(f, op)
    norm = hierarchy.normal_tables[k] if normal_control else None
    if norm is not None:
        r = np.asarray(norm.targets, np.int64)[rows_of(norm.offsets)]
        nv = np.asarray(norm.normals, np.float64)[norm.normal_ids]  # (entries, 3)
        blocks = norm.weights[:, None, None] * nv[:, :, None] * nv[:, None, :]  # w n n^T
        a = np.arange(3)
        rr = (r[:, None, None] * 3 + a[None, :, None]) + 0 * a[None, None, :]
        cc = (np.asarray(norm.indices, np.int64)[:, None, None] * 3 + a[None, None, :]) + 0 * a[None, :, None]
        i = np.arange(3 * nr)
        p = _from_coo(np.r_[i, rr.ravel()], np.r_[i, cc.ravel()], np.r_[np.ones(3 * nr), blocks.ravel()],
                      (3 * nr, 3 * nr))
        op = _spmm(p, op)
    return op


def matrix(refiner, level=None, *, normal_control: bool = False, with_offset: bool = False):
    """The sparse map from control data to the data of ``level`` (None: the refiner's last level; 0..levels;
    ``"limit"``: limit positions of the last level, as :meth:`Refiner.limit_points` gives them).

    Without normal control the matrix is (rows of the level, control vertices) and acts on every column of data
    of any width alike: ``refiner.evaluate(data, normal_control=False) == M @ data``. With ``normal_control=True``
    it is (3 rows, 3 n) over positions flattened row by row (x0, y0, z0, x1, ...), the map of
    ``refiner.evaluate(points)``; for ``"limit"``, of ``refiner.limit_points(refiner.evaluate(points))``.
    ``with_offset``: return (M, b), b the affine offset (M.shape[0],) with ``out = M @ x + b``: zero, since
    normal control has no constant term (docs/rules.md section 7), returned for code that treats the map as
    affine. Flatness is part of the matrix (it acts on all data)."""
    limit = isinstance(level, str) and level == "limit"
    if level is None:
        level = refiner.levels
    elif not limit:
        if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 0 <= level <= refiner.levels:
            raise SubdivInputError(f"level must be None, 'limit' or an integer in 0..{refiner.levels}, got {level!r}",
                                   option="level", value=level)
        level = int(level)
    b = 3 if normal_control else 1
    h = refiner.hierarchy
    op = _identity(h.base_num_vertices * b)
    for k in range(refiner.levels if limit else level):
        op = _spmm(_step_operator(refiner, k, b, normal_control), op)
    if limit:
        source, deeper = refiner.limit_source()
        if deeper:
            op = _spmm(_step_operator(source, refiner.levels, b, normal_control), op)
        pos = adjoint(source).limit_tables().position
        keep = rows_of(pos.offsets) < refiner.num_vertices
        rows, cols, vals = step_entries(pos)
        lim = _blocks(rows[keep], cols[keep], vals[keep], (refiner.num_vertices, pos.num_sources), b)
        op = _spmm(lim, op)
    out = _public(op)
    if with_offset:
        return out, np.zeros(op.shape[0])
    return out


# ------------------------------------------------------------------------------------------------ device records
@dataclass(frozen=True)
class TransposedRecord:
    """A :class:`TransposedStep` on the device: the near gather (every parent row), then the far one added."""

    near: ev.StencilStep
    far: ev.ExplicitRows


@dataclass(frozen=True)
class RegularRecord:
    """A :class:`RegularAdjoint` on the device."""

    quads: bool
    num_vertices: int
    num_faces: int
    face_row: int
    offsets: wp.array
    slot_vert: wp.array
    slot_edge_row: wp.array
    slot_third: wp.array
    w_centre: wp.array
    w_vert: wp.array
    edge_weights: wp.array
    face_vert: wp.array | None
    face_edge_row: wp.array | None
    face_w_vert: wp.array | None
    quarter: wp.array
    explicit: ev.ExplicitRows
    far: tuple | None = None


def _upload_regular(up, a: RegularAdjoint) -> RegularRecord:
    i32 = np.int32
    opt = (lambda v, dtype=None: None if v is None else up(v, dtype))  # noqa: E731
    return RegularRecord(a.quads, len(a.offsets) - 1, a.num_faces, a.face_row, up(a.offsets, i32),
                         up(a.slot_vert, i32), up(a.slot_edge_row, i32), up(a.slot_third, i32), up(a.w_centre),
                         up(a.w_vert), up(a.edge_weights), opt(a.face_vert, i32), opt(a.face_edge_row, i32),
                         opt(a.face_w_vert), up([0.25]), up.explicit(a.explicit),
                         None if a.far is None else tuple(up(v, i32) for v in a.far))


@dataclass(frozen=True)
class AdjointStep:
    """The transposed records of one step: its rows (a :class:`RegularRecord` on uniform levels, else a
    :class:`TransposedRecord`), and the transposed flatness and normal-control displacements (applied first in
    the backward pass)."""

    rows: "TransposedRecord | RegularRecord"
    flatness: ev.Displacement | None
    normals: ev.Projection | None

    @property
    def num_moved(self) -> int:
        return max([0] + [d.count for d in (self.flatness, self.normals) if d is not None])


@dataclass(frozen=True)
class AdjointLimit:
    """Transposed limit masks of the first ``rows`` vertices: positions, and the two tangent masks stacked (u
    gradients in rows 0..T, v gradients in rows T..2T of one buffer)."""

    position: ev.StencilStep
    tangents: ev.StencilStep
    vertex_offsets: wp.array
    rows: int
    num_tangents: int


def adjoint(refiner) -> "Adjoint":
    """The refiner's :class:`Adjoint` (made on first use, then kept by the refiner: ``refiner.adjoint``)."""
    return refiner.adjoint


def _load(device) -> None:
    """Load the forward and adjoint kernel modules on ``device`` once (before threads launch them)."""
    k = _kernels()
    ev.load_kernels(device, (k.regular, k.stencil, k.projection, k.adjoint))


class Adjoint:
    """Forward and backward passes of one refiner on Warp arrays, with the transposed tables of its steps and
    limit masks (built on first use, then kept).

    Arrays are in the kernels' layout (:func:`warp_subdiv.evaluator.kernel_view`): vec3 rows for width 3, (rows, d)
    otherwise, of the refiner's precision, on its device. Every call returns fresh arrays (none is shared with
    the evaluator), so the results can be held by a tape or an autograd graph. Thread safe (a lock around the
    shared backward buffers)."""

    def __init__(self, refiner):
        self.refiner = refiner
        self.hierarchy = refiner.hierarchy
        self.evaluator = refiner.evaluator
        self.device = refiner.device
        self.precision = refiner.options.precision.value
        self.scalar_np, self.scalar, self.vec = ev.PRECISIONS[self.precision]
        self._lock = threading.RLock()
        self._steps: dict = {}
        self._limit: dict = {}
        self._limit_tables = None
        self._buffers = None
        self._face_buffers: dict = {}

    # ---------------------------------------------------------------------------------------- tables
    @property
    def launcher(self) -> ev.Launcher:
        return self.evaluator.launcher

    def step(self, k: int) -> AdjointStep:
        """The transposed records of step k (0-based); every step's are built and uploaded on first use."""
        with self._lock:
            if not self._steps:
                self.prepare()
            return self._steps[k]

    def prepare(self) -> None:
        """Build and upload every step's transposed tables now (else the first backward pass does): index tables
        over the parents' corners on uniform levels (the levels' topology is rebuilt from the control mesh, as
        :attr:`Refiner.tables` does), transposed stencils elsewhere, transposed displacement tables."""
        with self._lock:
            if self._steps or not self.refiner.levels:
                return
            h = self.hierarchy
            up = ev.Uploader(self.device, self.precision)
            for k, level in enumerate(_levels(self.refiner)):
                t = h.steps[k]
                if isinstance(t, RegularTables):
                    rows = _upload_regular(up, regular_adjoint(level, t))
                else:
                    split = transposed_step(t)
                    rows = TransposedRecord(up.stencil(split.near), up.explicit(split.far))
                self._steps[k] = AdjointStep(rows, up.displacement(transposed_displacement(h.flatness_tables[k])),
                                             up.projection(transposed_displacement(h.normal_tables[k])))

    def limit_tables(self):
        """The numpy limit tables of the last level (kept)."""
        with self._lock:
            if self._limit_tables is None:
                self._limit_tables = self.hierarchy.limit_tables()
            return self._limit_tables

    def limit(self, rows: int) -> AdjointLimit:
        """Transposed limit masks of the first ``rows`` vertices (built on first use)."""
        with self._lock:
            rec = self._limit.get(rows)
            if rec is None:
                t = self.limit_tables()
                n_src = t.position.num_sources
                r, c, w = step_entries(t.position)
                keep = r < rows
                pos = _grouped(r[keep], c[keep], w[keep], n_src, rows, pad=True)
                T = int(t.vertex_offsets[rows])
                parts = []
                for shift, table in ((0, t.tangent_u), (T, t.tangent_v)):
                    r, c, w = step_entries(table)
                    keep = r < T
                    parts.append((r[keep] + shift, c[keep], w[keep]))
                r, c, w = (np.concatenate(p) for p in zip(*parts))
                tan = _grouped(r, c, w, n_src, 2 * T, pad=True)
                up = ev.Uploader(self.device, self.precision)
                rec = AdjointLimit(up.stencil(pos), up.stencil(tan), up(t.vertex_offsets[: rows + 1], np.int32),
                                   rows=rows, num_tangents=T)
                self._limit[rows] = rec
            return rec

    # ---------------------------------------------------------------------------------------- arrays
    def empty(self, rows: int, width: int) -> wp.array:
        """A fresh array of ``rows`` rows of ``width`` in the kernels' layout."""
        if width == 3:
            return wp.empty(rows, dtype=self.vec, device=self.device)
        return wp.empty((rows, width), dtype=self.scalar, device=self.device)

    def zeros(self, rows: int, width: int) -> wp.array:
        a = self.empty(rows, width)
        a.zero_()
        return a

    def to_device(self, data: np.ndarray) -> wp.array:
        """Host (rows, d) data as a fresh device array in the kernels' layout."""
        host = np.ascontiguousarray(data, dtype=self.scalar_np)
        return ev.kernel_view(wp.array(host, dtype=self.scalar, device=self.device))

    def to_host(self, arr: wp.array) -> np.ndarray:
        out = arr.numpy()
        return np.array(out.reshape(len(out), -1), copy=True)

    @staticmethod
    def width(arr: wp.array) -> int:
        return 3 if arr.ndim == 1 else int(arr.shape[1])

    def level_rows(self, level: int) -> int:
        """Vertices of ``level`` (0..levels)."""
        return self.hierarchy.base_num_vertices if level == 0 else _num_rows(self.hierarchy.steps[level - 1])

    def _views(self, width: int):
        if self._buffers is None:
            rows = [self.level_rows(k) for k in range(self.refiner.levels + 1)]
            moved = [self.step(k).num_moved for k in range(self.refiner.levels)]
            self._buffers = ev.LevelBuffers(rows, moved, self.device, self.scalar)
        return self._buffers.views(width)

    def _faces(self, k: int, width: int):
        """The face-point gradient buffer of step k (quads) for data of ``width`` (kept), or None."""
        rec = self.step(k).rows
        if not isinstance(rec, RegularRecord) or not rec.quads:
            return None
        with self._lock:
            key = (k, width)
            buf = self._face_buffers.get(key)
            if buf is None:
                buf = self._face_buffers[key] = self.empty(rec.num_faces, width)
            return buf

    def _run(self):
        _load(self.device)
        return self.launcher

    # ---------------------------------------------------------------------------------------- refinement
    def forward(self, x: wp.array, normal_control: bool) -> wp.array:
        """Refine control data ``x`` (layout) through every step; a fresh array of the last level's rows."""
        width = self.width(x)
        ev.normal_control_for(normal_control, width)
        records = self.evaluator.records()
        run = self._run()
        out = self.empty(self.refiner.num_vertices, width)
        if not records:
            wp.copy(out, x)
            return out
        self.evaluator.run_steps(x, out, normal_control, run)  # the levels between in the evaluator's buffers
        return out

    def backward(self, grad: wp.array, normal_control: bool, out: wp.array | None = None,
                 accumulate: bool = False) -> wp.array:
        """The gradient with respect to the control data of a gradient ``grad`` (layout, last level's rows):
        written into ``out`` (or a fresh array), added to it with ``accumulate``."""
        width = self.width(grad)
        ev.normal_control_for(normal_control, width)
        L = self.refiner.levels
        n = self.hierarchy.base_num_vertices
        if out is None:
            out, accumulate = self.empty(n, width), False
        run = self._run()
        if L == 0:
            if accumulate:
                run.rows(_kernels().add_rows, n, [grad, out])
            else:
                wp.copy(out, grad)
            return out
        steps = [self.step(k) for k in range(L)]
        with self._lock:
            levels, scratch = self._views(width)
            src = grad
            for k in reversed(range(L)):
                st = steps[k]
                moves = st.flatness is not None or (normal_control and st.normals is not None)
                if moves and src is grad:  # the displacements work in place: not on the caller's array
                    wp.copy(levels[k + 1], grad)
                    src = levels[k + 1]
                if normal_control and st.normals is not None:
                    ev.displace(st.normals, src, scratch[k], run)
                if st.flatness is not None:
                    ev.displace(st.flatness, src, scratch[k], run)
                dst = out if (k == 0 and not accumulate) else levels[k]
                _apply_rows(st, src, dst, run, self._faces(k, width))
                src = dst
            if accumulate:
                run.rows(_kernels().add_rows, n, [src, out])
        return out

    def _last_step_forward(self, x: wp.array, normal_control: bool) -> wp.array:
        """Points of the second-to-last level through the last step only (fresh array)."""
        records = self.evaluator.records()
        width = self.width(x)
        out = self.empty(self.refiner.num_vertices, width)
        moved = records[-1].num_moved
        scratch = self.empty(moved, width) if moved else None
        ev.refine_step(records[-1], x, out, scratch, normal_control, self._run())
        return out

    def _last_step_backward(self, grad: wp.array, normal_control: bool) -> wp.array:
        """The adjoint of the last step alone; ``grad`` (fresh, last level's rows) is modified in place."""
        st = self.step(self.refiner.levels - 1)
        run = self._run()
        width = self.width(grad)
        scratch = self.empty(st.num_moved, width) if st.num_moved else None
        if normal_control and st.normals is not None:
            ev.displace(st.normals, grad, scratch, run)
        if st.flatness is not None:
            ev.displace(st.flatness, grad, scratch, run)
        out = self.empty(self.level_rows(self.refiner.levels - 1), width)
        with self._lock:  # the face buffer is shared
            _apply_rows(st, grad, out, run, self._faces(self.refiner.levels - 1, width))
        return out

    # ---------------------------------------------------------------------------------------- limits
    def limit_points_forward(self, x: wp.array) -> wp.array:
        """Limit values of the last level's data ``x`` (layout); width-3 data takes normal control in the extra
        step where the masks are read one level deeper (as :meth:`Refiner.limit_points`)."""
        source, deeper = self.refiner.limit_source()
        sa = adjoint(source)
        run = self._run()
        width = self.width(x)
        if deeper:
            x = sa._last_step_forward(x, width == 3)
        masks = source.evaluator.limit_masks()
        full = sa.empty(masks.num_vertices, width)
        ev.limit_positions(masks, x, full, run)
        out = self.empty(self.refiner.num_vertices, width)
        wp.copy(out, full, count=self.refiner.num_vertices)
        return out

    def limit_points_backward(self, grad: wp.array) -> wp.array:
        """The gradient with respect to the last level's data of a gradient of :meth:`limit_points_forward`."""
        source, deeper = self.refiner.limit_source()
        sa = adjoint(source)
        rec = sa.limit(self.refiner.num_vertices)
        width = self.width(grad)
        g = sa.empty(source.num_vertices, width)
        ev.apply(rec.position, grad, g, self._run())
        return sa._last_step_backward(g, width == 3) if deeper else g

    def _prescribed(self):
        h = self.hierarchy
        ids = np.asarray(h.normal_vertices, np.int64)
        if self.refiner.options.normal_strength <= 0:
            ids = ids[:0]
        return ids[ids < self.refiner.num_vertices], h.normal_vectors

    def limit_normals_forward(self, x: wp.array) -> wp.array:
        """Unit limit normals of the last level's positions ``x`` (vec3), as :meth:`Refiner.limit_normals`."""
        _check_positions(x)
        source, deeper = self.refiner.limit_source()
        sa = adjoint(source)
        run = self._run()
        if deeper:
            x = sa._last_step_forward(x, True)
        masks = source.evaluator.limit_masks()
        tu, tv = sa.empty(masks.num_tangents, 3), sa.empty(masks.num_tangents, 3)
        full = sa.empty(masks.num_vertices, 3)
        ev.limit_normals(masks, x, tu, tv, full, run)
        h = sa.hierarchy
        if len(h.normal_vertices) and self.refiner.options.normal_strength > 0:  # prescribed: as given
            ids = np.asarray(h.normal_vertices, np.int32)
            values = np.asarray(h.normal_vectors, dtype=self.scalar_np).reshape(-1, 3)
            wp.launch(_kernels().scatter_rows, dim=len(ids),
                      inputs=[wp.array(ids, device=self.device), wp.array(values, dtype=self.vec, device=self.device),
                              full], device=self.device)
        out = self.empty(self.refiner.num_vertices, 3)
        wp.copy(out, full, count=self.refiner.num_vertices)
        return out

    def limit_normals_backward(self, x: wp.array, grad: wp.array) -> wp.array:
        """The gradient with respect to the last level's positions ``x`` of a gradient ``grad`` of the limit
        normals (vec3 arrays); recomputes the tangents from ``x``."""
        _check_positions(x)
        _check_positions(grad)
        source, deeper = self.refiner.limit_source()
        sa = adjoint(source)
        run = self._run()
        k = _kernels()
        N = self.refiner.num_vertices
        xs = sa._last_step_forward(x, True) if deeper else x
        masks = source.evaluator.limit_masks()
        rec = sa.limit(N)
        T = rec.num_tangents
        tu, tv = sa.empty(masks.num_tangents, 3), sa.empty(masks.num_tangents, 3)
        ev.apply(masks.tangent_u, xs, tu, run)
        ev.apply(masks.tangent_v, xs, tv, run)
        g = grad
        ids, _ = self._prescribed()
        if len(ids):  # prescribed normals are constants
            g = self.empty(N, 3)
            wp.copy(g, grad)
            wp.launch(k.zero_rows, dim=len(ids), inputs=[wp.array(ids.astype(np.int32), device=self.device),
                                                        self.vec(), g], device=self.device)
        guv = sa.empty(2 * T, 3)
        run.rows(k.vertex_normals_adjoint, N, [rec.vertex_offsets, tu, tv, g, self.vec(), T, guv])
        gx = sa.empty(source.num_vertices, 3)
        ev.apply(rec.tangents, guv, gx, run)
        return sa._last_step_backward(gx, True) if deeper else gx


def _kernels():
    from .. import kernels

    return kernels


def _add_explicit(x: ev.ExplicitRows, src, dst, run: ev.Launcher) -> None:
    run.rows(_kernels().explicit_rows_add, x.count, [x.rows, x.offsets, x.indices, x.weights, src, dst])


def _apply_rows(st: AdjointStep, src: wp.array, dst: wp.array, run: ev.Launcher, faces=None) -> None:
    """dst = S^T src for the step's rows; ``faces``: a work buffer of the step's face count (quads) in the
    layout of ``src``."""
    rec, k = st.rows, _kernels()
    if isinstance(rec, TransposedRecord):
        ev.apply(rec.near, src, dst, run)
        _add_explicit(rec.far, src, dst, run)
        return
    V = rec.num_vertices
    if rec.quads:
        run.rows(k.quad_face_adjoint, rec.num_faces, [rec.face_vert, rec.face_edge_row, rec.face_w_vert,
                                                      rec.edge_weights, src, rec.face_row, faces])
        run.rows(k.quad_vertex_adjoint, V, [rec.offsets, rec.slot_vert, rec.slot_edge_row, rec.slot_third,
                                            rec.w_centre, rec.w_vert, rec.edge_weights, rec.quarter, src, faces,
                                            dst])
    elif rec.far is not None:
        run.rows(k.tri_ring_adjoint, V, [rec.offsets, rec.slot_vert, rec.w_centre, rec.w_vert, src, dst])
        run.rows(k.tri_edge_adjoint, V, list(rec.far) + [rec.edge_weights, src, dst])
    else:
        run.rows(k.tri_vertex_adjoint, V, [rec.offsets, rec.slot_vert, rec.slot_edge_row, rec.slot_third,
                                           rec.w_centre, rec.w_vert, rec.edge_weights, src, dst])
    _add_explicit(rec.explicit, src, dst, run)


def _check_positions(x: wp.array) -> None:
    if x.ndim != 1:
        raise SubdivInputError(f"limit normals take (n, 3) positions, got {tuple(x.shape)}", element="data",
                               value=tuple(x.shape))


# ------------------------------------------------------------------------------------------------ numpy entry points
def _host_rows(refiner, data, rows: int, what: str) -> np.ndarray:
    return ev.host_rows(data, rows, what, refiner.options.precision.value)


def _shaped(out: np.ndarray, like) -> np.ndarray:
    return out[:, 0] if np.ndim(like) == 1 else out


def evaluate_vjp(refiner, grad, normal_control=None) -> np.ndarray:
    """The gradient with respect to the control data of ``grad`` (N, d) (or (N,)), a gradient of
    ``refiner.evaluate(data, normal_control)``: the transposed map applied to it (the map is linear, so the
    control data itself is not needed). ``normal_control`` as in :meth:`Refiner.evaluate` (None: on for width
    3). Returns (n, d) in the evaluation precision."""
    g = _host_rows(refiner, grad, refiner.num_vertices, "gradient")
    if normal_control is None:
        normal_control = g.shape[1] == 3
    adj = adjoint(refiner)
    return _shaped(adj.to_host(adj.backward(adj.to_device(g), bool(normal_control))), grad)


def limit_points_vjp(refiner, grad) -> np.ndarray:
    """The gradient with respect to the refined data of ``grad``, a gradient of ``refiner.limit_points(data)``
    (same shape as the data; width-3 data is treated as positions, as there)."""
    g = _host_rows(refiner, grad, refiner.num_vertices, "gradient")
    adj = adjoint(refiner)
    return _shaped(adj.to_host(adj.limit_points_backward(adj.to_device(g))), grad)


def limit_normals_vjp(refiner, refined_points, grad) -> np.ndarray:
    """The gradient with respect to the refined positions (N, 3) of ``grad`` (N, 3), a gradient of
    ``refiner.limit_normals(refined_points)``: the true derivative of the normalised normals (rows of vertices
    with a prescribed normal pass none)."""
    x = _host_rows(refiner, refined_points, refiner.num_vertices, "refined points")
    g = _host_rows(refiner, grad, refiner.num_vertices, "gradient")
    for name, a in (("refined points", x), ("gradient", g)):
        if a.shape[1] != 3:
            raise SubdivInputError(f"limit normals take (N, 3) {name}, got {a.shape}", element="data",
                                   value=a.shape)
    adj = adjoint(refiner)
    return adj.to_host(adj.limit_normals_backward(adj.to_device(x), adj.to_device(g)))


# ------------------------------------------------------------------------------------------------ Warp arrays + tape
def _active_tape():
    ctx = getattr(getattr(wp, "_src", None), "context", None) or wp.context
    return ctx.runtime.tape if ctx.runtime is not None else None


class _NoTape:
    """Within the block no Warp tape records (our kernels have no adjoints; the backward is recorded whole)."""

    def __enter__(self):
        ctx = getattr(getattr(wp, "_src", None), "context", None) or wp.context
        self.ctx = ctx
        self.tape = ctx.runtime.tape if ctx.runtime is not None else None
        if self.tape is not None:
            ctx.runtime.tape = None
        return self.tape

    def __exit__(self, *exc):
        if self.tape is not None:
            self.ctx.runtime.tape = self.tape


def _user_array(refiner, arr, rows: int, what: str) -> wp.array:
    """A caller's Warp array as the kernel view (vec3 for width 3), checked: (rows,), (rows, d) or vec3 (rows,),
    on the refiner's device, of its precision, contiguous (the tape writes its gradient in place)."""
    if not isinstance(arr, wp.array):
        raise TypeError(f"{what} must be a warp array, got {type(arr).__name__}")
    precision = refiner.options.precision.value
    _, scalar, vec = ev.PRECISIONS[precision]
    if arr.device != refiner.device:
        raise SubdivInputError(f"{what} is on {arr.device}, the refiner on {refiner.device}", element="data")
    view = ev.device_rows(arr, rows, what, refiner.device)
    if arr.dtype not in (scalar, vec):
        raise SubdivInputError(f"{what} must hold {precision} (the refiner's precision) or its vec3, got "
                               f"{arr.dtype.__name__}", element="data")
    if not arr.is_contiguous:
        raise SubdivInputError(f"{what} must be contiguous", element="data")
    return arr if arr.dtype == vec else ev.kernel_view(view)


def _result_like(adj: Adjoint, x_user: wp.array, rows: int, width: int, requires_grad: bool):
    """(the array handed back, in the caller's shape convention, and its view in the kernels' layout)."""
    if x_user.ndim == 1 and x_user.dtype == adj.vec:
        shape, dtype = rows, adj.vec
    elif x_user.ndim == 1:
        shape, dtype = rows, adj.scalar
    else:
        shape, dtype = (rows, width), adj.scalar
    out = wp.empty(shape, dtype=dtype, device=adj.device, requires_grad=requires_grad)
    if out.ndim == 2:
        return out, ev.kernel_view(out)
    return out, (out if dtype == adj.vec else out.reshape((rows, 1)))


def _grad_view(arr: wp.array, rows: int) -> wp.array:
    g = arr.grad
    if g.ndim == 1 and g.dtype in (wp.vec3f, wp.vec3d):
        return g
    return ev.kernel_view(g.reshape((rows, 1)) if g.ndim == 1 else g)


def _record(inputs, output, backward) -> None:
    tape = _active_tape()
    if tape is None or not any(a.requires_grad for a in inputs):
        return
    tape.record_func(backward, [a for a in list(inputs) + [output] if a.requires_grad])


def evaluate(refiner, points: wp.array, normal_control=None, requires_grad=None) -> wp.array:
    """Refine a Warp array of control data (vec3 (n,), (n, d) or (n,) of the refiner's precision, on its device);
    returns a fresh array of the last level in the same convention. ``normal_control`` as in
    :meth:`Refiner.evaluate` (None: on for width 3). ``requires_grad`` (default: the input's): the result has a
    gradient array, and under an active ``wp.Tape`` the backward pass (the transposed tables) is recorded; it
    adds to ``points.grad``."""
    adj = adjoint(refiner)
    x = _user_array(refiner, points, refiner.base_num_vertices, "points")
    width = adj.width(x)
    nc = bool(ev.normal_control_for(normal_control, width))
    rg = points.requires_grad if requires_grad is None else bool(requires_grad)
    out, view = _result_like(adj, points, refiner.num_vertices, width, rg)
    with _NoTape():
        wp.copy(view, adj.forward(x, nc))
    n = refiner.base_num_vertices

    def backward():
        adj.backward(_grad_view(out, refiner.num_vertices), nc, out=_grad_view(points, n), accumulate=True)

    _record([points], out, backward)
    return out


def limit_points(refiner, refined: wp.array, requires_grad=None) -> wp.array:
    """Limit values of a Warp array of the last level's data (as :func:`evaluate` takes data), recorded on an
    active tape; see :meth:`Refiner.limit_points`."""
    adj = adjoint(refiner)
    N = refiner.num_vertices
    x = _user_array(refiner, refined, N, "refined points")
    rg = refined.requires_grad if requires_grad is None else bool(requires_grad)
    out, view = _result_like(adj, refined, N, adj.width(x), rg)
    with _NoTape():
        wp.copy(view, adj.limit_points_forward(x))

    def backward():
        g = adj.limit_points_backward(_grad_view(out, N))
        adj._run().rows(_kernels().add_rows, N, [g, _grad_view(refined, N)])

    _record([refined], out, backward)
    return out


def limit_normals(refiner, refined: wp.array, requires_grad=None) -> wp.array:
    """Unit limit normals of a Warp array of the last level's positions (vec3 (N,) or (N, 3)), recorded on an
    active tape (the backward recomputes the tangents from ``refined`` as it is then); see
    :meth:`Refiner.limit_normals`."""
    adj = adjoint(refiner)
    N = refiner.num_vertices
    x = _user_array(refiner, refined, N, "refined points")
    _check_positions(x)
    rg = refined.requires_grad if requires_grad is None else bool(requires_grad)
    out, view = _result_like(adj, refined, N, 3, rg)
    with _NoTape():
        wp.copy(view, adj.limit_normals_forward(x))

    def backward():
        g = adj.limit_normals_backward(x, _grad_view(out, N))
        adj._run().rows(_kernels().add_rows, N, [g, _grad_view(refined, N)])

    _record([refined], out, backward)
    return out
