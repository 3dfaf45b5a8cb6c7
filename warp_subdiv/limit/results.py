"""What evaluating a :class:`~warp_subdiv.limit.LimitSurface` returns: points and derivatives of the surface
(:class:`LimitEvaluation`), or values and derivatives of data carried on it (:class:`DataEvaluation`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class LimitEvaluation:
    """Results of :meth:`LimitSurface.evaluate`, numpy float64 arrays of shape (n, 3) for n queries (the
    queries' shape + (3,) for queries of more dimensions): ``points``, first derivatives ``du``, ``dv``, unit
    ``normals``, and with ``derivatives=2`` the second derivatives ``duu``, ``duv``, ``dvv`` (None otherwise).
    ``patch``: the leaf patch each point was evaluated on (internal), of the queries' shape."""

    points: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    normals: np.ndarray
    duu: np.ndarray | None = None
    duv: np.ndarray | None = None
    dvv: np.ndarray | None = None
    patch: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    def reshaped(self, shape: tuple) -> LimitEvaluation:
        """These results of flat queries with their one axis made ``shape`` (the queries' broadcast shape)."""
        if len(shape) == 1:
            return self
        arrays = (self.points, self.du, self.dv, self.normals, self.duu, self.duv, self.dvv, self.patch)
        return LimitEvaluation(*(_leading(x, shape) for x in arrays))


@dataclass
class DataEvaluation:
    """Results of :meth:`LimitSurface.evaluate_data` and :meth:`LimitSurface.evaluate_face_varying`: numpy
    float64 ``values`` (n, k), or (n,) for 1-D data (for queries of more dimensions, their shape in place of n),
    and with ``derivatives=1`` their first derivatives ``du``, ``dv`` with respect to the face's (u, v), of the
    same shape (None otherwise)."""

    values: np.ndarray
    du: np.ndarray | None = None
    dv: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.values)

    def reshaped(self, shape: tuple) -> DataEvaluation:
        """These results of flat queries with their one axis made ``shape`` (the queries' broadcast shape)."""
        if len(shape) == 1:
            return self
        return DataEvaluation(*(_leading(x, shape) for x in (self.values, self.du, self.dv)))


#: How far from 1 the squared length of an evaluation's normal may be before the normal is recomputed: a
#: normal of tangents of ordinary scale is of unit length to a few ulps; one of tangents whose cross product
#: overflows or underflows float64 (points scaled by 1e160, or 1e-80) is nan, zero or visibly not of unit length.
UNIT_LENGTH_TOLERANCE = 1e-10


def scale_free_normals(du: np.ndarray, dv: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``normals`` (n, 3), the unit du x dv an evaluation computed, with every row that is not of unit length
    (where du x dv overflowed to inf and nan, or its squared length underflowed) recomputed from the tangents
    scaled by powers of two (exact), their cross product scaled the same way before its length is taken. The
    rows of unit length are kept bit for bit, and so are rows whose tangents are parallel or zero (the normal
    is zero) or not finite; rows are changed in place."""
    squared = np.einsum("ij,ij->i", normals, normals)
    redo = np.flatnonzero(~(np.abs(squared - 1.0) <= UNIT_LENGTH_TOLERANCE))
    if not len(redo):
        return normals
    du_r, dv_r = du[redo], dv[redo]
    with np.errstate(invalid="ignore", over="ignore"):
        du_r = np.ldexp(du_r, -np.frexp(np.abs(du_r).max(axis=1))[1][:, None])
        dv_r = np.ldexp(dv_r, -np.frexp(np.abs(dv_r).max(axis=1))[1][:, None])
        n = np.cross(du_r, dv_r)
        n = np.ldexp(n, -np.frexp(np.abs(n).max(axis=1))[1][:, None])
        length = np.linalg.norm(n, axis=1)
    ok = length > 0  # not a zero normal (nor nan)
    normals[redo[ok]] = n[ok] / length[ok, None]
    return normals


def _leading(x: np.ndarray | None, shape: tuple) -> np.ndarray | None:
    """``x`` (n, ...) as ``shape`` + (...) (None stays None)."""
    return None if x is None else x.reshape(shape + x.shape[1:])
