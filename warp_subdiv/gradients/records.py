"""The transposed tables on the device (:class:`AdjointStep`, :class:`AdjointLimit`), uploaded with the
evaluator's :class:`~warp_subdiv.evaluator.Uploader` and kept per refiner (:class:`TransposedTables`), and
:func:`apply_rows`, which launches a step's transposed rows.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..evaluator import Displacement, ExplicitRows, Launcher, Projection, StencilStep, Uploader, apply
from ..tables import RegularTables
from .transposed import (RegularAdjoint, levels_of, regular_adjoint, transposed_displacement, transposed_limit,
                         transposed_step)


@dataclass(frozen=True)
class TransposedRecord:
    """A :class:`TransposedStep` on the device: the near gather (every parent row), then the far one added."""

    near: StencilStep
    far: ExplicitRows


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
    explicit: ExplicitRows
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
    flatness: Displacement | None
    normals: Projection | None

    @property
    def num_moved(self) -> int:
        return max([0] + [d.count for d in (self.flatness, self.normals) if d is not None])


@dataclass(frozen=True)
class AdjointLimit:
    """Transposed limit masks of the first ``rows`` vertices: positions, and the two tangent masks stacked (u
    gradients in rows 0..T, v gradients in rows T..2T of one buffer)."""

    position: StencilStep
    tangents: StencilStep
    vertex_offsets: wp.array
    rows: int
    num_tangents: int



def upload_adjoint_step(up: Uploader, level, t, flatness, normals) -> AdjointStep:
    """The transposed records of one step: ``t`` the step's tables over ``level`` (its full topology), with its
    flatness and normal-control displacement tables (or None): index tables over the parents' corners on
    uniform levels, transposed stencils elsewhere."""
    if isinstance(t, RegularTables):
        rows = _upload_regular(up, regular_adjoint(level, t))
    else:
        split = transposed_step(t)
        rows = TransposedRecord(up.stencil(split.near), up.explicit(split.far))
    return AdjointStep(rows, up.displacement(transposed_displacement(flatness)),
                       up.projection(transposed_displacement(normals)))


def upload_adjoint_limit(up: Uploader, tables, rows: int) -> AdjointLimit:
    """The transposed limit masks of ``tables`` for the first ``rows`` vertices, on the device."""
    pos, tan, T = transposed_limit(tables, rows)
    return AdjointLimit(up.stencil(pos), up.stencil(tan), up(tables.vertex_offsets[: rows + 1], np.int32),
                        rows=rows, num_tangents=T)


class TransposedTables:
    """The transposed records of one refiner on its device, built and uploaded on first use, then kept: every
    step's (all at once) and the limit masks' per number of rows. Thread safe."""

    def __init__(self, refiner):
        self.refiner = refiner
        self.device = refiner.device
        self.precision = refiner.options.precision.value
        self.steps: dict = {}
        self._limit: dict = {}
        self._limit_tables = None
        self._lock = threading.RLock()

    def step(self, k: int) -> AdjointStep:
        """The transposed records of step k (0-based)."""
        with self._lock:
            if not self.steps:
                self.prepare()
            return self.steps[k]

    def prepare(self) -> None:
        """Build and upload every step's transposed tables now: index tables over the parents' corners on uniform
        levels (the levels' topology is rebuilt from the control mesh, as :attr:`Refiner.tables` does),
        transposed stencils elsewhere, transposed displacement tables."""
        with self._lock:
            if self.steps or not self.refiner.levels:
                return
            h = self.refiner.hierarchy
            up = Uploader(self.device, self.precision)
            for k, level in enumerate(levels_of(self.refiner)):
                self.steps[k] = upload_adjoint_step(up, level, h.steps[k], h.flatness_tables[k], h.normal_tables[k])

    def limit_tables(self):
        """The numpy limit tables of the last level (kept)."""
        with self._lock:
            if self._limit_tables is None:
                self._limit_tables = self.refiner.hierarchy.limit_tables()
            return self._limit_tables

    def limit(self, rows: int) -> AdjointLimit:
        """Transposed limit masks of the first ``rows`` vertices."""
        with self._lock:
            if rows not in self._limit:
                up = Uploader(self.device, self.precision)
                self._limit[rows] = upload_adjoint_limit(up, self.limit_tables(), rows)
            return self._limit[rows]


def _kernels():
    from .. import kernels  # imported late, as the evaluator does

    return kernels


def _add_explicit(x: ExplicitRows, src, dst, run: Launcher) -> None:
    run.rows(_kernels().explicit_rows_add, x.count, [x.rows, x.offsets, x.indices, x.weights, src, dst])


def apply_rows(st: AdjointStep, src: wp.array, dst: wp.array, run: Launcher, faces=None) -> None:
    """dst = S^T src for the step's rows; ``faces``: a work buffer of the step's face count (quads) in the
    kernel view of ``src``."""
    rec, k = st.rows, _kernels()
    if isinstance(rec, TransposedRecord):
        apply(rec.near, src, dst, run)
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
