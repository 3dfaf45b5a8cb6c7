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


def _leading(x: np.ndarray | None, shape: tuple) -> np.ndarray | None:
    """``x`` (n, ...) as ``shape`` + (...) (None stays None)."""
    return None if x is None else x.reshape(shape + x.shape[1:])
