"""Forward and backward passes of a refiner on Warp arrays: :class:`Adjoint`, one per refiner
(:func:`adjoint`), with the transposed tables of its steps and limit masks built on first use and kept.

The backward pass applies the transposed tables (:mod:`warp_subdiv.gradients.transposed`) in reverse step order:
a step's displacements first, then its rows. The forward passes run the evaluator's records through the
evaluator's step loop. The JAX and PyTorch adapters (:mod:`warp_subdiv.jax`, :mod:`warp_subdiv.torch`) call
:meth:`Adjoint.forward` / :meth:`Adjoint.backward` and the limit passes (:mod:`.limit_passes`).
"""
from __future__ import annotations

import threading

import numpy as np
import warp as wp

from ..evaluator import (PRECISIONS, LevelBuffers, Launcher, displace, kernel_view, load_kernels, normal_control_for,
                         refine_step)
from .checks import check_data
from .limit_passes import LimitPasses
from .records import RegularRecord, TransposedTables, _kernels, apply_rows


def adjoint(refiner) -> "Adjoint":
    """The refiner's :class:`Adjoint` (made on first use, then kept by the refiner: ``refiner.adjoint``)."""
    return refiner.adjoint


class Adjoint:
    """Forward and backward passes of one refiner on Warp arrays, with the transposed tables of its steps and
    limit masks (built on first use, then kept).

    Arrays are in the kernels' view (:func:`warp_subdiv.evaluator.kernel_view`): vec3 rows for width 3, (rows, d)
    otherwise, of the refiner's precision, on its device. Every call returns fresh arrays (none is shared with
    the evaluator), so the results can be held by a tape or an autograd graph. Thread safe (a lock around the
    shared backward buffers). ``tables``: the transposed tables (:class:`~.records.TransposedTables`); ``limits``:
    the limit passes (:class:`~.limit_passes.LimitPasses`);
    ``adapter_functions``: what framework adapters build over this adjoint and keep with it (the JAX adapter's
    differentiable functions)."""

    def __init__(self, refiner):
        self.refiner = refiner
        self.hierarchy = refiner.hierarchy
        self.evaluator = refiner.evaluator
        self.device = refiner.device
        self.precision = refiner.options.precision.value
        self.scalar_np, self.scalar, self.vec = PRECISIONS[self.precision]
        self.tables = TransposedTables(refiner)
        self.adapter_functions: dict = {}
        self._lock = threading.RLock()
        self._buffers = None
        self._face_buffers: dict = {}
        self.limits = LimitPasses(self)

    @property
    def launcher(self) -> Launcher:
        """The evaluator's launcher, with the forward and adjoint kernel modules loaded on the device."""
        k = _kernels()
        load_kernels(self.device, (k.regular, k.stencil, k.projection, k.adjoint))
        return self.evaluator.launcher

    def prepare(self) -> None:
        """Build and upload every step's transposed tables now (else the first backward pass does)."""
        self.tables.prepare()

    # ---------------------------------------------------------------------------------------- arrays
    def empty(self, rows: int, width: int) -> wp.array:
        """A fresh array of ``rows`` rows of ``width`` in the kernel view."""
        if width == 3:
            return wp.empty(rows, dtype=self.vec, device=self.device)
        return wp.empty((rows, width), dtype=self.scalar, device=self.device)

    def to_device(self, data: np.ndarray) -> wp.array:
        """Host (rows, d) data as a fresh device array in the kernel view."""
        host = np.ascontiguousarray(data, dtype=self.scalar_np)
        return kernel_view(wp.array(host, dtype=self.scalar, device=self.device))

    def to_host(self, arr: wp.array) -> np.ndarray:

        """A device array as a (rows, width) numpy array (a copy)."""
        out = arr.numpy()
        return np.array(out.reshape(len(out), -1), copy=True)

    @staticmethod
    def width(arr: wp.array) -> int:
        """The number of columns of a kernel-view array (vec3 rows: 3)."""
        return 3 if arr.ndim == 1 else int(arr.shape[1])

    def level_rows(self, level: int) -> int:
        """Vertices of ``level`` (0..levels)."""
        return self.hierarchy.base_num_vertices if level == 0 else int(self.hierarchy.steps[level - 1].num_rows)

    def _views(self, width: int):
        if self._buffers is None:
            rows = [self.level_rows(k) for k in range(self.refiner.levels + 1)]
            moved = [self.tables.step(k).num_moved for k in range(self.refiner.levels)]
            self._buffers = LevelBuffers(rows, moved, self.device, self.scalar)
        return self._buffers.views(width)

    def _faces(self, k: int, width: int):
        """The face-point gradient buffer of step k (quads) for data of ``width`` (kept), or None."""
        rec = self.tables.step(k).rows
        if not isinstance(rec, RegularRecord) or not rec.quads:
            return None
        with self._lock:
            key = (k, width)
            if key not in self._face_buffers:
                self._face_buffers[key] = self.empty(rec.num_faces, width)
            return self._face_buffers[key]

    # ---------------------------------------------------------------------------------------- refinement
    def forward(self, x: wp.array, normal_control: bool) -> wp.array:
        """Refine control data ``x`` (kernel view) through every step; a fresh array of the last level's rows."""
        check_data(self, x)
        width = self.width(x)
        normal_control_for(normal_control, width)
        records = self.evaluator.records()
        run = self.launcher
        out = self.empty(self.refiner.num_vertices, width)
        if not records:
            wp.copy(out, x)
            return out
        self.evaluator.run_steps(x, out, normal_control, run)  # the levels between in the evaluator's buffers
        return out

    def backward(self, grad: wp.array, normal_control: bool, out: wp.array | None = None,
                 accumulate: bool = False) -> wp.array:
        """The gradient with respect to the control data of a gradient ``grad`` (kernel view, last level's
        rows): written into ``out`` (or a fresh array), added to it with ``accumulate``."""
        check_data(self, grad, *([] if out is None else [out]))
        width = self.width(grad)
        normal_control_for(normal_control, width)
        L = self.refiner.levels
        n = self.hierarchy.base_num_vertices
        if out is None:
            out, accumulate = self.empty(n, width), False
        run = self.launcher
        if L == 0:
            if accumulate:
                run.rows(_kernels().add_rows, n, [grad, out])
            else:
                wp.copy(out, grad)
            return out
        steps = [self.tables.step(k) for k in range(L)]
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
                    displace(st.normals, src, scratch[k], run)
                if st.flatness is not None:
                    displace(st.flatness, src, scratch[k], run)
                dst = out if (k == 0 and not accumulate) else levels[k]
                apply_rows(st, src, dst, run, self._faces(k, width))
                src = dst
            if accumulate:
                run.rows(_kernels().add_rows, n, [src, out])
        return out

    def last_step_forward(self, x: wp.array, normal_control: bool) -> wp.array:
        """Points of the second-to-last level through the last step only (fresh array)."""
        records = self.evaluator.records()
        width = self.width(x)
        out = self.empty(self.refiner.num_vertices, width)
        moved = records[-1].num_moved
        scratch = self.empty(moved, width) if moved else None
        refine_step(records[-1], x, out, scratch, normal_control, self.launcher)
        return out

    def last_step_backward(self, grad: wp.array, normal_control: bool) -> wp.array:
        """The adjoint of the last step alone; ``grad`` (fresh, last level's rows) is modified in place."""
        st = self.tables.step(self.refiner.levels - 1)
        run = self.launcher
        width = self.width(grad)
        scratch = self.empty(st.num_moved, width) if st.num_moved else None
        if normal_control and st.normals is not None:
            displace(st.normals, grad, scratch, run)
        if st.flatness is not None:
            displace(st.flatness, grad, scratch, run)
        out = self.empty(self.level_rows(self.refiner.levels - 1), width)
        with self._lock:  # the face buffer is shared
            apply_rows(st, grad, out, run, self._faces(self.refiner.levels - 1, width))
        return out
