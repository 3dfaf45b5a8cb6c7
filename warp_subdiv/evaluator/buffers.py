"""Device buffers of the evaluator and the copies in and out of them.

Vertex data of any width ``d`` lives in row-major (rows, d) device buffers of the evaluation precision and
reaches the kernels as a 2-D array, which is the buffer descriptor (its data pointer the offset, ``shape[1]``
the length, ``strides[0]`` the stride): one compiled kernel refines data of every width in one pass. Width-3
data (positions) is passed as a vec3 view of the same buffer instead (:func:`kernel_view`), the faster layout on
Warp's CPU backend (see :mod:`warp_subdiv.kernels.layout`; the same kernels, another overload), and the one that
the normal-control and limit-normal kernels need.

:class:`LevelBuffers` are the per-level buffers (allocated once, grown when wider data comes); :class:`Transfers`
copies data into them and results out (on CUDA through reused pinned :class:`Staging` buffers);
:class:`LimitOutputs` are the reused outputs of the limit launches.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime import estimate
from ..runtime import threads as _threads
from ..runtime.pages import small_pages
from .interop import is_contiguous_rows
from .launch import OwnStream
from .records import PRECISIONS, Uploader


def kernel_view(rows_by_width: wp.array) -> wp.array:
    """The kernels' view of a contiguous (rows, d) buffer: a vec3 array for d = 3, else the 2-D array itself."""
    if rows_by_width.shape[1] == 3:
        scalar = rows_by_width.dtype
        return rows_by_width.view(wp.vec3d if scalar == wp.float64 else wp.vec3f)
    return rows_by_width


class LevelBuffers:
    """Per-level device buffers for data of any width, allocated once for the widest data seen so far; a
    call takes views of them for its width (in the kernels' :func:`kernel_view`). ``generation`` counts the
    allocations: plans recorded over older buffers are stale."""

    def __init__(self, rows: list[int], moved: list[int], device, scalar):
        self.rows, self.moved, self.device, self.scalar = rows, moved, device, scalar
        self.width = 0
        self.generation = 0
        self.flat: list[wp.array] = []
        self.scratch_flat: list[wp.array | None] = []
        self._views: dict = {}
        self._rows: dict = {}

    def check_growth(self, width: int) -> None:
        """Refuse buffers for data of ``width`` before allocating them where they would not fit 32-bit sizes or
        the device's free memory (nothing to check when the current ones are wide enough)."""
        if width <= self.width:
            return
        rows = self.rows + self.moved
        estimate.check_buffer_elements(max(rows) * width, f"data of width {width}")
        wbytes = wp.types.type_size_in_bytes(self.scalar)
        estimate.check_device_memory(sum(rows) * (width - self.width) * wbytes, self.device,
                                     f"level buffers for data of width {width}")

    def views(self, width: int):
        """(levels, scratch): per level a (rows, width) view, per step a (moved, width) view or None."""
        if width > self.width:
            # the old buffers and their views go first (a wider set can need the memory)
            self.flat, self.scratch_flat, self._views, self._rows = [], [], {}, {}
            self.flat = [wp.empty(n * width, dtype=self.scalar, device=self.device) for n in self.rows]
            self.scratch_flat = [wp.empty(n * width, dtype=self.scalar, device=self.device) if n else None
                                 for n in self.moved]
            self.width = width
            self.generation += 1
        if width not in self._views:
            def view(flat, n):
                return kernel_view(flat[: n * width].reshape((n, width)))

            self._views[width] = ([view(f, n) for f, n in zip(self.flat, self.rows)],
                                  [None if f is None else view(f, n) for f, n in zip(self.scratch_flat, self.moved)])
        return self._views[width]

    def rows_view(self, level: int, width: int):
        """(device view, host view or None): level ``level``'s buffer as (rows, width) scalars, and on the CPU
        the same memory as a numpy array (made once per level and width)."""
        key = (level, width)
        if key not in self._rows:
            n = self.rows[level]
            arr = self.flat[level][: n * width].reshape((n, width))
            self._rows[key] = (arr, arr.numpy() if self.device.is_cpu else None)
        return self._rows[key]


class Staging:
    """Pinned host buffers (CUDA), one per role, shape and dtype, reused by every call: host data goes to the
    device and results come back in one transfer each, at full bandwidth, with no page-locking per call."""

    def __init__(self):
        self._arrays: dict = {}

    def get(self, role: str, shape: tuple, dtype) -> tuple[wp.array, np.ndarray]:
        key = (role, tuple(shape), dtype)
        if key not in self._arrays:
            same_role = [k for k in self._arrays if k[0] == role]
            for old in same_role[: max(0, len(same_role) - 3)]:  # at most 4 shapes per role, the latest
                del self._arrays[old]
            arr = wp.empty(shape, dtype=dtype, device="cpu", pinned=True)
            self._arrays[key] = (arr, arr.numpy())
        return self._arrays[key]


class Transfers:
    """Copies between a caller's data and device buffers, on the stream of ``own`` (an
    :class:`~warp_subdiv.evaluator.launch.OwnStream`, the evaluator's): host data in (on CUDA through a reused
    pinned buffer, then one transfer), device arrays in (a copy, or a cast kernel), results out into new numpy
    arrays."""

    def __init__(self, device, scalar, threads: int, own: OwnStream):
        self.device, self.scalar, self.threads, self.own = device, scalar, threads, own
        self._staging = Staging()
        self._staged = None  # CUDA: event after the last upload from the pinned input buffer

    def load(self, data, dst: wp.array, host_dst: np.ndarray | None) -> None:
        """Copy (rows, width) ``data`` -- a checked numpy array, or a Warp view of a device array -- into the
        device buffer ``dst`` of the same shape (``host_dst``: its memory as numpy on the CPU), converting to
        the buffer's precision."""
        if isinstance(data, wp.array) and data.device != self.device:
            data = data.numpy()  # an array on another device: through the host
        if self.device.is_cpu:  # one pass: conversion straight into the buffer
            np.copyto(host_dst, data.numpy() if isinstance(data, wp.array) else data, casting="unsafe")
        elif isinstance(data, wp.array):
            self.copy_rows(data, dst)
        else:  # host data on CUDA: into the pinned buffer, then one transfer
            stage, host_stage = self._staging.get("in", dst.shape, self.scalar)
            if self._staged is not None:  # the previous upload from it must be done before it is overwritten
                wp.synchronize_event(self._staged)
            np.copyto(host_stage, data, casting="unsafe")
            wp.copy(dst, stage, stream=self.own.stream)
            self._staged = self.own.stream.record_event()

    def copy_rows(self, src: wp.array, dst: wp.array) -> None:
        """Device (rows, width) ``src`` into ``dst`` of the same shape, any strides and precisions."""
        if src.dtype == dst.dtype and is_contiguous_rows(src) and is_contiguous_rows(dst):
            wp.copy(dst, src, stream=self.own.stream)
        elif self.device.is_cpu:
            np.copyto(dst.numpy(), src.numpy(), casting="unsafe")
        else:
            from ..kernels import convert

            wp.launch(convert.cast_rows, dim=src.shape[0], inputs=[src, dst], device=self.device,
                      stream=self.own.stream)

    def to_host(self, arr: wp.array) -> np.ndarray:
        """A new numpy array with the contents of device array ``arr`` (written once, read in order: small
        pages, see :func:`warp_subdiv.runtime.pages.small_pages`). On CUDA one transfer into a reused pinned
        buffer, then a copy."""
        with small_pages():
            if self.device.is_cpu:
                out = arr.numpy()
            else:
                stage, out = self._staging.get("out", arr.shape, arr.dtype)
                wp.copy(stage, arr, stream=self.own.stream)
                wp.synchronize_stream(self.own.stream)
            if self.threads == 1 or len(out) < 2 * _threads.MIN_ROWS:
                return np.array(out, copy=True)
            copy = np.empty_like(out)  # copied in row ranges on the evaluator's threads (numpy frees the GIL)
            _threads.each_chunk(lambda a, b: np.copyto(copy[a:b], out[a:b]), len(out), self.threads)
            return copy


class LimitOutputs:
    """The device outputs of the limit launches, reused per data width and row count (recorded launches write
    into them), and prescribed normals uploaded once."""

    def __init__(self, device, precision: str):
        self.device, self.precision = device, precision
        self.scalar_np, self.scalar, self.vec = PRECISIONS[precision]
        self._outputs: dict = {}
        self._prescribed: dict = {}

    def clear(self) -> None:
        """Drop the outputs (the launches recorded over them are dropped too)."""
        self._outputs = {}

    def outputs(self, width: int, rows: int, tangents: int):
        """(points (rows, width) in the kernel view, tangent u, tangent v, normals)."""
        key = (width, rows)
        if key not in self._outputs:
            dev, scalar = self.device, self.scalar
            self._outputs[key] = (
                kernel_view(wp.empty((rows, width), dtype=scalar, device=dev)),
                wp.empty(tangents, dtype=self.vec, device=dev), wp.empty(tangents, dtype=self.vec, device=dev),
                wp.empty(rows, dtype=self.vec, device=dev))
        return self._outputs[key]

    def prescribed(self, prescribed):
        """Prescribed normals (ids, normals) on the device, uploaded once."""
        ids, normals = prescribed
        ids = np.asarray(ids, dtype=np.int32)
        normals = np.asarray(normals, dtype=self.scalar_np).reshape(-1, 3)
        key = (ids.tobytes(), normals.tobytes())
        if key not in self._prescribed:
            up = Uploader(self.device, self.precision)
            self._prescribed[key] = (up(ids, np.int32), wp.array(normals, dtype=self.vec, device=self.device))
        return self._prescribed[key]
