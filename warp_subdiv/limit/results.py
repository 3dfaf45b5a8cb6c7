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


#: Tangent scales (the largest |component| of du times that of dv) within which du x dv and its squared length
#: are computed without overflow or underflow in float64: normals computed from such tangents are kept as the
#: evaluation returns them; outside (points scaled by 1e160, or 1e-80), they are recomputed scale-free.
SAFE_TANGENT_PRODUCT = (2.0 ** -400, 2.0 ** 400)


def scale_free_normals(du: np.ndarray, dv: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``normals`` (n, 3), the unit du x dv an evaluation computed, with every row whose tangents are too large or
    too small for du x dv in float64 (where it overflows to inf and nan, or its squared length underflows and
    the normal is not of unit length) recomputed from the tangents scaled by powers of two (exact), their cross
    product scaled the same way before its length is taken. Rows of ordinary scale, of a zero tangent (a zero
    normal) or of non-finite tangents are left as they are; rows are changed in place."""
    a, b = np.abs(du).max(axis=1, initial=0.0), np.abs(dv).max(axis=1, initial=0.0)
    with np.errstate(over="ignore", under="ignore"):
        product = a * b
    lo, hi = SAFE_TANGENT_PRODUCT
    redo = np.isfinite(product) & (a > 0) & (b > 0) & ((product < lo) | (product > hi))
    redo |= np.isinf(product) & np.isfinite(a) & np.isfinite(b)
    if not redo.any():
        return normals
    du_r = np.ldexp(du[redo], -np.frexp(a[redo])[1][:, None])
    dv_r = np.ldexp(dv[redo], -np.frexp(b[redo])[1][:, None])
    n = np.cross(du_r, dv_r)
    n = np.ldexp(n, -np.frexp(np.abs(n).max(axis=1))[1][:, None])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    normals[redo] = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    return normals


def _leading(x: np.ndarray | None, shape: tuple) -> np.ndarray | None:
    """``x`` (n, ...) as ``shape`` + (...) (None stays None)."""
    return None if x is None else x.reshape(shape + x.shape[1:])
