"""Evaluation of a :class:`~warp_subdiv.hierarchy.Hierarchy`'s step tables with Warp kernels.

The evaluator knows nothing about creases or schemes. As OpenSubdiv's ``Osd::CpuEvaluator`` it is stateless
evaluation over typed records:

* :func:`upload` turns the hierarchy's tables into device records once per evaluator: per step a
  :class:`StepRecord` holding a :class:`QuadStep` or :class:`TriangleStep` (smooth rows by index arithmetic,
  irregular rows as :class:`ExplicitRows`) or a :class:`StencilStep` (every row an explicit stencil), and
  the step's :class:`Displacement` (flatness) and :class:`Projection` (normal control) when it has them;
  :func:`upload_limit` makes the :class:`LimitMasks`.
* :func:`apply` (dispatching on the record's type), :func:`refine_step`, :func:`limit_positions` and
  :func:`limit_normals` launch the kernels of :mod:`warp_subdiv.kernels` over a record and source and
  destination buffers, always on an explicit device, through a :class:`Launcher`: on the CPU it splits each
  launch into a few contiguous row ranges run on several threads (:mod:`warp_subdiv.threads`; Warp runs one
  CPU launch on one thread and releases the GIL while a kernel runs). Every row is computed by the same code
  whatever the split, so results are bitwise equal to one thread's.

Vertex data of any width ``d`` lives in row-major (rows, d) device buffers of the evaluation precision and
reaches the kernels as a 2-D array, which is the buffer descriptor (its data pointer the offset, ``shape[1]``
the length, ``strides[0]`` the stride): one compiled kernel refines data of every width in one pass. Width-3
data (positions) is passed as a vec3 view of the same buffer instead, the faster layout on Warp's CPU
backend (see :mod:`warp_subdiv.kernels.layout`; the same kernels, another overload), and the one that the
normal-control and limit-normal kernels need.

:class:`Evaluator` owns the records and the per-level buffers (allocated once, grown when wider data comes,
reused by every later call). One lock guards the section that uses the shared buffers, so one evaluator
can serve several Python threads at once (each call's launches, on however many threads, finish before the
lock is released).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import singledispatch

import numpy as np
import warp as wp

from . import threads as _threads
from .errors import SubdivInputError
from .tables import RegularTables
from .topology import small_pages

PRECISIONS = {"float32": (np.float32, wp.float32, wp.vec3f), "float64": (np.float64, wp.float64, wp.vec3d)}


def default_device() -> str:
    """CUDA when a CUDA device is present, else the CPU."""
    return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"


def _kernels():
    from . import kernels  # imported late: building a hierarchy needs no Warp module

    return kernels


# ------------------------------------------------------------------------------------------------ records
@dataclass(frozen=True)
class ExplicitRows:
    """Rows of a uniform step that the index kernels leave out: dst[rows[i]] = CSR row i over the source."""

    rows: wp.array
    offsets: wp.array
    indices: wp.array
    weights: wp.array
    count: int


@dataclass(frozen=True)
class QuadStep:
    """One Catmull-Clark step over a level of quads: face, smooth edge and smooth vertex points from index
    tables, then the explicit rows. Child layout [V vertex points, F face points, E edge points]."""

    num_vertices: int
    num_faces: int
    num_edges: int
    num_rows: int
    corner_vert: wp.array
    edge_neighbours: wp.array  # (E, 2) int32: the edge's two corners
    ring_offsets: wp.array
    ring: wp.array  # each vertex's corners
    vertex_regular: wp.array  # empty: every row regular
    edge_regular: wp.array
    ring_weights: wp.array  # (max valence + 1, 2)
    edge_weights: wp.array  # (2,)
    quarter: wp.array  # (1,): the face-point weight in the evaluation precision
    explicit: ExplicitRows


@dataclass(frozen=True)
class TriangleStep:
    """One Loop step over a level of triangles: smooth edge and vertex points from index tables, then the
    explicit rows. Child layout [V vertex points, E edge points]."""

    num_vertices: int
    num_edges: int
    num_rows: int
    edge_neighbours: wp.array  # (E, 4) int32: a, b, opposite 0, opposite 1
    ring_offsets: wp.array
    ring: wp.array
    vertex_regular: wp.array
    edge_regular: wp.array
    ring_weights: wp.array
    edge_weights: wp.array
    explicit: ExplicitRows


@dataclass(frozen=True)
class StencilStep:
    """Rows that are all explicit stencils: dst[i] = CSR row i over the source (non-uniform steps, limit
    masks)."""

    offsets: wp.array
    indices: wp.array
    weights: wp.array
    num_rows: int


@dataclass(frozen=True)
class Displacement:
    """Flatness: out[targets[i]] = p[targets[i]] + sum_j w_j p[indices[j]] (data of any width)."""

    targets: wp.array
    offsets: wp.array
    indices: wp.array
    weights: wp.array
    count: int


@dataclass(frozen=True)
class Projection:
    """Normal control: out[targets[i]] = p[targets[i]] + sum_j w_j n_j (n_j . p[indices[j]]) (positions)."""

    targets: wp.array
    offsets: wp.array
    indices: wp.array
    weights: wp.array
    normal_ids: wp.array
    normals: wp.array  # vec3 of the evaluation precision
    count: int


@dataclass(frozen=True)
class StepRecord:
    """Everything one refinement step does: the child rows, then flatness, then normal control."""

    rows: QuadStep | TriangleStep | StencilStep
    flatness: Displacement | None
    normals: Projection | None

    @property
    def num_rows(self) -> int:
        return self.rows.num_rows

    @property
    def num_moved(self) -> int:
        """Rows of the scratch buffer the step's displacements need."""
        return max([0] + [d.count for d in (self.flatness, self.normals) if d is not None])


@dataclass(frozen=True)
class LimitMasks:
    """Limit position masks (one row per vertex) and tangent masks (one row per (vertex, sector))."""

    position: StencilStep
    tangent_u: StencilStep
    tangent_v: StencilStep
    vertex_offsets: wp.array  # (V+1,): the tangent pairs of each vertex
    num_vertices: int
    num_tangents: int


# ------------------------------------------------------------------------------------------------ upload
class _Uploader:
    """Device arrays of host tables on ``device``; on the CPU they share the numpy arrays' memory instead of
    copying them (the hierarchy keeps its tables, so the memory stays alive)."""

    def __init__(self, device, precision: str):
        self.device = wp.get_device(device)
        self.scalar, _, self.vec = PRECISIONS[precision]

    def __call__(self, values, dtype=None):
        host = np.ascontiguousarray(values, dtype=self.scalar if dtype is None else dtype)
        if self.device.is_cpu:
            return wp.array(host, device=self.device, copy=False)
        return wp.array(host, device=self.device)

    def csr(self, t):
        i32 = np.int32
        return self(t.offsets, i32), self(t.indices, i32), self(t.weights)

    def stencil(self, t) -> StencilStep:
        return StencilStep(*self.csr(t), num_rows=t.num_rows)

    def explicit(self, t) -> ExplicitRows:
        rows = np.zeros(0, np.int32) if t.rows is None else t.rows
        return ExplicitRows(self(rows, np.int32), *self.csr(t), count=t.num_rows)

    def regular(self, t: RegularTables):
        i32, u8 = np.int32, np.uint8
        common = dict(num_vertices=t.num_vertices, num_edges=len(t.edge_neighbours), num_rows=t.num_rows,
                      edge_neighbours=self(t.edge_neighbours, i32), ring_offsets=self(t.vert_corner_offsets, i32),
                      ring=self(t.ring, i32), vertex_regular=self(t.vertex_regular, u8),
                      edge_regular=self(t.edge_regular, u8), ring_weights=self(t.ring_weights),
                      edge_weights=self(t.edge_weights), explicit=self.explicit(t.explicit))
        if t.face_size == 4:
            return QuadStep(num_faces=t.num_faces, corner_vert=self(t.corner_vert, i32), quarter=self([0.25]),
                            **common)
        return TriangleStep(**common)

    def displacement(self, t) -> Displacement | None:
        if t is None:
            return None
        return Displacement(self(t.targets, np.int32), *self.csr(t), count=t.num_rows)

    def projection(self, t) -> Projection | None:
        if t is None:
            return None
        normals = wp.array(np.ascontiguousarray(t.normals, dtype=self.scalar), dtype=self.vec, device=self.device)
        offsets, indices, weights = self.csr(t)
        return Projection(self(t.targets, np.int32), offsets, indices, weights, self(t.normal_ids, np.int32),
                          normals, count=t.num_rows)


def upload(hierarchy, device, precision: str) -> list[StepRecord]:
    """The device records of every step of ``hierarchy`` (index tables, explicit stencils, displacements)."""
    up = _Uploader(device, precision)
    records = []
    for t, flat, norm in zip(hierarchy.steps, hierarchy.flatness_tables, hierarchy.normal_tables):
        rows = up.regular(t) if isinstance(t, RegularTables) else up.stencil(t)
        records.append(StepRecord(rows, up.displacement(flat), up.projection(norm)))
    return records


def upload_limit(tables, device, precision: str) -> LimitMasks:
    """The device records of a :class:`~warp_subdiv.projections.LimitTables`."""
    up = _Uploader(device, precision)
    return LimitMasks(up.stencil(tables.position), up.stencil(tables.tangent_u), up.stencil(tables.tangent_v),
                      up(tables.vertex_offsets, np.int32), num_vertices=tables.position.num_rows,
                      num_tangents=tables.tangent_u.num_rows)


# ------------------------------------------------------------------------------------------------ launches
_loaded: set = set()
_load_lock = threading.Lock()


def _load_kernels(device) -> None:
    """Load the kernel modules on ``device`` (once per process and device) before threads launch them: a
    module must not be compiled or loaded from two threads at once."""
    key = str(device)
    if key in _loaded:
        return
    with _load_lock:
        if key not in _loaded:
            k = _kernels()
            for module in (k.regular, k.stencil, k.projection):
                wp.load_module(module, device=device)
            _loaded.add(key)


class Launcher:
    """Launches kernels on ``device``; on the CPU with ``threads`` > 1, a launch of many rows runs as a few
    contiguous row ranges on the process's thread pool (the calling thread runs the first), and returns when
    every range is done. On CUDA one launch, whatever ``threads``."""

    def __init__(self, device, threads: int = 1):
        self.device = wp.get_device(device)
        self.threads = max(1, int(threads)) if self.device.is_cpu else 1
        if self.threads > 1:
            _load_kernels(self.device)

    def __repr__(self):
        return f"Launcher({self.device}, threads={self.threads})"

    def rows(self, kernel, n: int, inputs: list) -> None:
        """``kernel`` over rows 0..n, its last parameter the first row of the launch (``row0``)."""
        if n <= 0:
            return
        if self.threads == 1 or n < 2 * _threads.MIN_ROWS:
            wp.launch(kernel, dim=n, inputs=inputs + [0], device=self.device)
            return
        dev = self.device
        _threads.map_ranges(lambda a, b: wp.launch(kernel, dim=b - a, inputs=inputs + [a], device=dev), n,
                            self.threads)

    def sliced(self, kernel, n: int, inputs_of) -> None:
        """``kernel`` over rows 0..n of a kernel without a row offset: ``inputs_of(start, stop)`` gives the
        inputs of one range (views of the arrays' rows start..stop)."""
        if n <= 0:
            return
        if self.threads == 1 or n < 2 * _threads.MIN_ROWS:
            wp.launch(kernel, dim=n, inputs=inputs_of(0, n), device=self.device)
            return
        dev = self.device
        _threads.map_ranges(lambda a, b: wp.launch(kernel, dim=b - a, inputs=inputs_of(a, b), device=dev), n,
                            self.threads)


def launcher(device_or_launcher) -> Launcher:
    """A :class:`Launcher` as given, or a one-thread launcher on the given device."""
    if isinstance(device_or_launcher, Launcher):
        return device_or_launcher
    return Launcher(device_or_launcher, 1)


@singledispatch
def apply(record, src: wp.array, dst: wp.array, device) -> None:
    """Write the rows of ``record`` into ``dst`` from ``src`` (both in one :func:`layout`) on ``device`` (a
    Warp device, or a :class:`Launcher` that may split the launches over threads)."""
    raise TypeError(f"no evaluation for {type(record).__name__}")


@apply.register
def _(record: QuadStep, src, dst, device) -> None:
    k, run = _kernels(), launcher(device)
    V, F = record.num_vertices, record.num_faces
    # face points first: edge and vertex points read them from dst (each launch ends before the next starts)
    run.rows(k.quad_face_points, F, [record.corner_vert, src, dst, V, record.quarter])
    run.rows(k.quad_edge_points, record.num_edges,
             [record.edge_neighbours, record.corner_vert, record.edge_regular, src, dst, V, V + F,
              record.edge_weights])
    run.rows(k.quad_vertex_points, V,
             [record.ring_offsets, record.ring, record.corner_vert, record.vertex_regular, src, dst, V,
              record.ring_weights])
    apply(record.explicit, src, dst, run)


@apply.register
def _(record: TriangleStep, src, dst, device) -> None:
    k, run = _kernels(), launcher(device)
    V = record.num_vertices
    run.rows(k.tri_edge_points, record.num_edges,
             [record.edge_neighbours, record.edge_regular, src, dst, V, record.edge_weights])
    run.rows(k.tri_vertex_points, V, [record.ring_offsets, record.ring, record.vertex_regular, src, dst,
                                      record.ring_weights])
    apply(record.explicit, src, dst, run)


@apply.register
def _(record: ExplicitRows, src, dst, device) -> None:
    launcher(device).rows(_kernels().explicit_rows, record.count,
                          [record.rows, record.offsets, record.indices, record.weights, src, dst])


@apply.register
def _(record: StencilStep, src, dst, device) -> None:
    launcher(device).rows(_kernels().stencil_rows, record.num_rows,
                          [record.offsets, record.indices, record.weights, src, dst])


@singledispatch
def displace(record, points: wp.array, scratch: wp.array, device) -> None:
    """Move the target rows of ``points`` in place; every row reads unmoved points (through ``scratch``)."""
    raise TypeError(f"no displacement for {type(record).__name__}")


@displace.register
def _(record: Displacement, points, scratch, device) -> None:
    k, run = _kernels(), launcher(device)
    tmp = scratch[: record.count]
    run.sliced(k.displace_rows, record.count, lambda a, b: [
        record.targets[a:b], record.offsets[a:b + 1], record.indices, record.weights, points, tmp[a:b]])
    _scatter(run, record.targets, tmp, points, record.count)


def _scatter(run: Launcher, targets, values, dst, n: int) -> None:
    """dst[targets[i]] = values[i] for i < n (after every row of ``values`` is computed)."""
    run.sliced(_kernels().scatter_rows, n, lambda a, b: [targets[a:b], values[a:b], dst])


@displace.register
def _(record: Projection, points, scratch, device) -> None:
    if points.ndim != 1:
        raise SubdivInputError("normal control applies to (n, 3) positions only", option="normal_control")
    k, run = _kernels(), launcher(device)
    tmp = scratch[: record.count]
    run.sliced(k.project_rows, record.count, lambda a, b: [
        record.targets[a:b], record.offsets[a:b + 1], record.indices, record.weights, record.normal_ids,
        record.normals, points, tmp[a:b]])
    _scatter(run, record.targets, tmp, points, record.count)


def refine_step(step: StepRecord, src: wp.array, dst: wp.array, scratch: wp.array | None, normal_control: bool,
                device) -> None:
    """One refinement step from ``src`` into ``dst`` (both in one layout, see :func:`layout`): the child rows,
    then flatness, then (when ``normal_control``) normal control; ``scratch`` holds at least
    ``step.num_moved`` rows of the same layout."""
    apply(step.rows, src, dst, device)
    if step.flatness is not None:
        displace(step.flatness, dst, scratch, device)
    if normal_control and step.normals is not None:
        displace(step.normals, dst, scratch, device)


def limit_positions(masks: LimitMasks, src: wp.array, out: wp.array, device) -> None:
    """Limit values of the last level's vertices from its points ``src`` (any width, ``out`` in the same
    layout)."""
    apply(masks.position, src, out, device)


def limit_normals(masks: LimitMasks, src: wp.array, tangent_u: wp.array, tangent_v: wp.array, out: wp.array,
                  device) -> None:
    """Unit limit normals ``out`` from positions ``src`` (vec3 arrays); ``tangent_u``/``tangent_v`` are vec3
    work buffers of ``masks.num_tangents`` rows."""
    run = launcher(device)
    apply(masks.tangent_u, src, tangent_u, run)
    apply(masks.tangent_v, src, tangent_v, run)
    zero = src.dtype()
    run.sliced(_kernels().vertex_normals, masks.num_vertices, lambda a, b: [
        masks.vertex_offsets[a:b + 1], tangent_u, tangent_v, zero, out[a:b]])


def layout(rows_by_width: wp.array) -> wp.array:
    """The kernels' view of a contiguous (rows, d) buffer: a vec3 array for d = 3, else the 2-D array itself."""
    if rows_by_width.shape[1] == 3:
        scalar = rows_by_width.dtype
        return rows_by_width.view(wp.vec3d if scalar == wp.float64 else wp.vec3f)
    return rows_by_width


# ------------------------------------------------------------------------------------------------ buffers
class _LevelBuffers:
    """Per-level device buffers for data of any width, allocated once for the widest data seen so far; a
    call takes views of them for its width (in the kernels' :func:`layout`)."""

    def __init__(self, rows: list[int], moved: list[int], device, scalar):
        self.rows, self.moved, self.device, self.scalar = rows, moved, device, scalar
        self.width = 0
        self.flat: list[wp.array] = []
        self.scratch_flat: list[wp.array | None] = []
        self._views: dict = {}

    def views(self, width: int):
        """(levels, scratch): per level a (rows, width) view, per step a (moved, width) view or None."""
        if width > self.width:
            self.flat = [wp.empty(n * width, dtype=self.scalar, device=self.device) for n in self.rows]
            self.scratch_flat = [wp.empty(n * width, dtype=self.scalar, device=self.device) if n else None
                                 for n in self.moved]
            self.width = width
            self._views = {}
        if width not in self._views:
            def view(flat, n):
                return layout(flat[: n * width].reshape((n, width)))

            self._views[width] = ([view(f, n) for f, n in zip(self.flat, self.rows)],
                                  [None if f is None else view(f, n) for f, n in zip(self.scratch_flat, self.moved)])
        return self._views[width]


# ------------------------------------------------------------------------------------------------ evaluator
class Evaluator:
    """Applies a hierarchy's steps to vertex data on ``device`` in ``precision``.

    The device records are uploaded and the level buffers allocated on first use and reused by every later
    call. Thread safety: a lock guards every call's use of the shared level buffers (upload, launches and the
    copy of the result to the host), so concurrent calls from several threads run one after the other and
    each gets its own result. :meth:`evaluate_device` returns a shared buffer, valid until the next call.

    ``threads``: CPU threads per launch (None: :func:`warp_subdiv.threads.default_threads`); each launch of
    many rows is split into that many contiguous row ranges. Results do not depend on it.
    """

    def __init__(self, hierarchy, *, device, precision: str, threads: int | None = None):
        self.hierarchy = hierarchy
        self.device = wp.get_device(device)
        self.threads = _threads.resolve(threads)
        self._launcher = None
        self.precision = str(precision)
        self._scalar_np, self._scalar, self._vec = PRECISIONS[self.precision]
        self._lock = threading.RLock()
        self._records: list[StepRecord] | None = None
        self._buffers: _LevelBuffers | None = None
        self._limit: LimitMasks | None = None

    # ---------------------------------------------------------------------------------------- state
    @property
    def launcher(self) -> Launcher:
        """The :class:`Launcher` of this evaluator's device and thread count (made on first use, so that
        building a refiner loads no Warp module)."""
        if self._launcher is None:
            self._launcher = Launcher(self.device, self.threads)
        return self._launcher

    def records(self) -> list[StepRecord]:
        """The step records on this evaluator's device (uploaded on first use)."""
        with self._lock:
            if self._records is None:
                self._records = upload(self.hierarchy, self.device, self.precision)
            return self._records

    def limit_masks(self) -> LimitMasks:
        """The limit masks on this evaluator's device (built and uploaded on first use)."""
        with self._lock:
            if self._limit is None:
                self._limit = upload_limit(self.hierarchy.limit_tables(), self.device, self.precision)
            return self._limit

    def _level_views(self, width: int):
        if self._buffers is None:
            records = self.records()
            rows = [self.hierarchy.base_num_vertices] + [r.num_rows for r in records]
            self._buffers = _LevelBuffers(rows, [r.num_moved for r in records], self.device, self._scalar)
        return self._buffers.views(width)

    def _put(self, dst: wp.array, data: np.ndarray) -> None:
        """Copy host ``data`` (rows, d) into the device view ``dst``, converting to the evaluation precision."""
        if self.device.is_cpu:
            dst.numpy()[...] = data  # one pass: conversion straight into the buffer
        else:
            host = np.ascontiguousarray(data, dtype=self._scalar_np)
            wp.copy(dst, wp.array(host, dtype=dst.dtype, device="cpu"))

    def _host(self, arr: wp.array) -> np.ndarray:
        """A new numpy array with the contents of device array ``arr`` (written once, read in order: small
        pages, see topology.small_pages)."""
        with small_pages():
            out = arr.numpy()
            if not self.device.is_cpu:
                return out
            if self.threads == 1 or len(out) < 2 * _threads.MIN_ROWS:
                return np.array(out, copy=True)
            copy = np.empty_like(out)  # copied in row ranges on the evaluator's threads (numpy frees the GIL)
            _threads.map_ranges(lambda a, b: np.copyto(copy[a:b], out[a:b]), len(out), self.threads)
            return copy

    def _input(self, data, rows: int, what: str) -> np.ndarray:
        arr = np.asarray(data)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] != rows or arr.shape[1] < 1:
            raise SubdivInputError(f"{what} must have shape ({rows}, d), got {np.shape(data)}", element="data",
                                   value=np.shape(data))
        return arr

    # ---------------------------------------------------------------------------------------- evaluation
    def _run(self, arr: np.ndarray, normal_control: bool) -> wp.array:
        """Refine (n, d) data through every step (lock held); returns the last level's view."""
        records = self.records()
        levels, scratch = self._level_views(arr.shape[1])
        self._put(levels[0], arr)
        for step, src, dst, tmp in zip(records, levels[:-1], levels[1:], scratch):
            refine_step(step, src, dst, tmp, normal_control, self.launcher)
        return levels[-1]

    def evaluate(self, arr: np.ndarray, normal_control: bool) -> np.ndarray:
        """Refine checked (n, d) data of any width in one pass; returns a new numpy array (N, d) of the
        evaluation precision."""
        with self._lock:
            return self._host(self._run(arr, normal_control))

    def evaluate_device(self, arr: np.ndarray, normal_control: bool) -> wp.array:
        """Refine checked (n, 3) positions; returns the last level's device array of vec3 (a view of a shared
        buffer, overwritten by the next call)."""
        with self._lock:
            return self._run(arr, normal_control)

    def _last_step(self, points) -> wp.array:
        """Points of the second-to-last level (lock held) refined through the last step only; returns the last
        level's view. Normal control acts on (n, 3) data."""
        records = self.records()
        arr = self._input(points, self._level_rows(-2), "points of the second-to-last level")
        levels, scratch = self._level_views(arr.shape[1])
        self._put(levels[-2], arr)
        refine_step(records[-1], levels[-2], levels[-1], scratch[-1], arr.shape[1] == 3, self.launcher)
        return levels[-1]

    def _level_rows(self, level: int) -> int:
        rows = [self.hierarchy.base_num_vertices] + [r.num_rows for r in self.records()]
        return rows[level]

    def evaluate_last_step(self, points_one_level_up) -> np.ndarray:
        """Refine points (n, d) of the second-to-last level through the last step only."""
        with self._lock:
            return self._host(self._last_step(points_one_level_up))

    # ------------------------------------------------------------------------------------------ limits
    def _device_points(self, points) -> wp.array:
        """Last-level points (N, d) on the device (a fresh array: limit evaluation keeps no shared state)."""
        arr = self._input(points, self.hierarchy.num_vertices, "refined points")
        host = np.ascontiguousarray(arr, dtype=self._scalar_np)
        return layout(wp.array(host, dtype=self._scalar, device=self.device, copy=not self.device.is_cpu))

    def limit_points(self, refined_points, *, last_step: bool = False) -> np.ndarray:
        """Limit values (N, d) of the last level's vertices, any width: the position mask applied to each
        vertex's ring. ``last_step``: the points are of the second-to-last level and are refined through the
        last step first (for masks read one level deeper)."""
        masks = self.limit_masks()
        with self._lock:
            src = self._last_step(refined_points) if last_step else self._device_points(refined_points)
            out = wp.empty(src.shape, dtype=src.dtype, device=self.device)
            limit_positions(masks, src, out, self.launcher)
            return self._host(out)

    def limit_normals(self, refined_points, prescribed, *, last_step: bool = False) -> np.ndarray:
        """Unit limit normals (N, 3) of the last level's vertices from positions (N, 3); ``prescribed``
        (ids, normals) replace theirs. ``last_step`` as in :meth:`limit_points`."""
        masks = self.limit_masks()
        with self._lock:
            src = self._last_step(refined_points) if last_step else self._device_points(refined_points)
            if src.ndim != 1:
                raise SubdivInputError(f"limit normals take (n, 3) positions, got {tuple(src.shape)}",
                                       element="data", value=tuple(src.shape))
            dev, vec = self.device, self._vec
            tu = wp.empty(masks.num_tangents, dtype=vec, device=dev)
            tv = wp.empty(masks.num_tangents, dtype=vec, device=dev)
            out = wp.empty(masks.num_vertices, dtype=vec, device=dev)
            limit_normals(masks, src, tu, tv, out, self.launcher)
            ids, normals = prescribed
            if len(ids):
                up = _Uploader(dev, self.precision)
                values = wp.array(np.asarray(normals, dtype=self._scalar_np).reshape(-1, 3), dtype=vec, device=dev)
                wp.launch(_kernels().scatter_rows, dim=len(ids), inputs=[up(ids, np.int32), values, out],
                          device=dev)
            return self._host(out)

    def table_bytes(self) -> int:
        """Bytes of everything a step keeps on the device (index tables, masks, explicit stencils)."""
        wbytes = np.dtype(self._scalar_np).itemsize
        return sum(t.nbytes(wbytes) for t in self.hierarchy.steps)
