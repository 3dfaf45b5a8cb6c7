"""Refinement as a sparse linear operator: :func:`matrix` composes the per-step tables into the map from control
data to a level (or to the limit), a ``scipy.sparse.csr_matrix`` where scipy is installed, else a
:class:`CSRMatrix` of the same arrays.

One step maps level k - 1 to level k as ``x_k = N_k F_k S_k x_{k-1}``: ``S_k`` the step's stencil rows (index
tables and explicit stencils, :mod:`warp_subdiv.tables`), ``F_k = I +`` the flatness displacements (per column,
any width) and ``N_k = I +`` the normal-control projections (positions only: entries ``w n n^T`` couple the three
coordinates; docs/rules.md section 7 has no ``x^0`` term, so normal control is linear too and the affine offset
is zero). Limit positions apply one more table.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SubdivInputError
from ..mesh import expand_counts
from ..tables import StencilTable, rows_of


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
        """The number of stored entries."""
        return len(self.data)

    def __repr__(self):
        return f"CSRMatrix(shape={self.shape}, nnz={self.nnz})"

    @property
    def T(self) -> "CSRMatrix":
        """The transposed matrix."""
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

    def dot(self, x):
        """The product with a dense array ``x`` (as ``self @ x``), as scipy.sparse matrices offer it."""
        return self @ x

    def toarray(self) -> np.ndarray:

        """The matrix as a dense numpy array."""
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
        pos = source.adjoint.tables.limit_tables().position
        keep = rows_of(pos.offsets) < refiner.num_vertices
        rows, cols, vals = step_entries(pos)
        lim = _blocks(rows[keep], cols[keep], vals[keep], (refiner.num_vertices, pos.num_sources), b)
        op = _spmm(lim, op)
    out = _public(op)
    if with_offset:
        return out, np.zeros(op.shape[0])
    return out
