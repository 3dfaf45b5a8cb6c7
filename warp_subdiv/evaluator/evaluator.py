"""Evaluation of a :class:`~warp_subdiv.tables.hierarchy.Hierarchy`'s step tables with Warp kernels.

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
  launch into a few contiguous row ranges run on several threads (:mod:`warp_subdiv.runtime.threads`; Warp runs one
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

import contextlib
import ctypes
import threading
from dataclasses import dataclass
from functools import singledispatch

import numpy as np
import warp as wp

from ..runtime import threads as _threads
from ..errors import SubdivInputError
from ..tables import RegularTables
from ..runtime.pages import small_pages

PRECISIONS = {"float32": (np.float32, wp.float32, wp.vec3f), "float64": (np.float64, wp.float64, wp.vec3d)}


def default_device() -> str:
    """CUDA when a CUDA device is present, else the CPU."""
    return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"


def _kernels():
    from .. import kernels  # imported late: building a hierarchy needs no Warp module

    return kernels


def _convert():
    from ..kernels import convert

    return convert


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
    # expanded tables (the CPU's choice, see kernels.regular): (E, 4) endpoints and faces, ring vertices, faces
    edge_ends: wp.array | None = None
    ring_vertices: wp.array | None = None
    ring_faces: wp.array | None = None


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
    host_vertex_offsets: np.ndarray | None = None  # the same offsets on the host (for :meth:`first`)

    def first(self, rows: int) -> "LimitMasks":
        """The masks of vertices 0..rows only (views: the rows of a deeper level's vertex children, which come
        first; each row is computed by the same code as in the full masks)."""
        if rows >= self.num_vertices:
            return self
        tangents = int(self.host_vertex_offsets[rows])

        def cut(step: StencilStep, n: int) -> StencilStep:
            return StencilStep(step.offsets[: n + 1], step.indices, step.weights, n)

        return LimitMasks(cut(self.position, rows), cut(self.tangent_u, tangents), cut(self.tangent_v, tangents),
                          self.vertex_offsets[: rows + 1], rows, tangents, self.host_vertex_offsets[: rows + 1])


# ------------------------------------------------------------------------------------------------ upload
class _Uploader:
    """Device arrays of host tables on ``device``; on the CPU they share the numpy arrays' memory instead of
    copying them (the hierarchy keeps its tables, so the memory stays alive)."""

    def __init__(self, device, precision: str, expand: bool | None = None, min_rows: int = 0):
        self.device = wp.get_device(device)
        self.scalar, _, self.vec = PRECISIONS[precision]
        self.expand = self.device.is_cpu if expand is None else bool(expand)
        self.min_rows = int(min_rows)  # quad steps of fewer rows keep their compact tables

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
                            **common, **(self.expanded(t) if self.expand and t.num_rows >= self.min_rows else {}))
        return TriangleStep(**common)

    def expanded(self, t: RegularTables) -> dict:
        """The expanded tables of a quad step (the lookups of index arithmetic done once): per edge its
        endpoints and faces, per vertex its ring vertices and faces."""
        cv = np.asarray(t.corner_vert)
        h0, h1 = t.edge_neighbours[:, 0], t.edge_neighbours[:, 1]  # int32 arithmetic: corners fit int32
        ends = np.empty((len(h0), 4), dtype=np.int32)
        ends[:, 0], ends[:, 1] = cv[h0], cv[(h0 & ~3) | ((h0 + 1) & 3)]
        ends[:, 2], ends[:, 3] = h0 >> 2, h1 >> 2
        ring = np.asarray(t.ring)
        return dict(edge_ends=self(ends, np.int32), ring_vertices=self(cv[(ring & ~3) | ((ring + 1) & 3)], np.int32),
                    ring_faces=self(ring >> 2, np.int32))

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


def upload(hierarchy, device, precision: str, expand: bool | None = None, min_rows: int = 0) -> list[StepRecord]:
    """The device records of every step of ``hierarchy`` (index tables, explicit stencils, displacements);
    ``expand``: quad steps of at least ``min_rows`` rows also get their expanded tables (None: on the CPU, see
    :mod:`warp_subdiv.kernels.regular`)."""
    up = _Uploader(device, precision, expand, min_rows)
    records = []
    for t, flat, norm in zip(hierarchy.steps, hierarchy.flatness_tables, hierarchy.normal_tables):
        rows = up.regular(t) if isinstance(t, RegularTables) else up.stencil(t)
        records.append(StepRecord(rows, up.displacement(flat), up.projection(norm)))
    return records


def upload_limit(tables, device, precision: str) -> LimitMasks:
    """The device records of a :class:`~warp_subdiv.tables.projections.LimitTables`."""
    up = _Uploader(device, precision)
    return LimitMasks(up.stencil(tables.position), up.stencil(tables.tangent_u), up.stencil(tables.tangent_v),
                      up(tables.vertex_offsets, np.int32), num_vertices=tables.position.num_rows,
                      num_tangents=tables.tangent_u.num_rows,
                      host_vertex_offsets=np.asarray(tables.vertex_offsets))


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
            for module in (k.regular, k.stencil, k.projection, _convert()):
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


class Recorder(Launcher):
    """A :class:`Launcher` that records its launches (``wp.launch(..., record_cmd=True)``) instead of running
    them: :func:`apply`, :func:`displace`, :func:`limit_positions` and :func:`limit_normals` issue through it the
    launches they would run, split into the same row ranges, and a :class:`Plan` replays them. ``groups``: per
    launch, its recorded row ranges (one, or one per CPU thread)."""

    def __init__(self, device, threads: int = 1):
        super().__init__(device, threads)
        self.groups: list[list] = []

    def _spans(self, n: int) -> list[tuple[int, int]]:
        if self.threads == 1 or n < 2 * _threads.MIN_ROWS:
            return [(0, n)]
        return _threads.ranges(n, self.threads, _threads.MIN_ROWS)

    def _record(self, kernel, dim: int, inputs: list):
        return wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)

    def rows(self, kernel, n: int, inputs: list) -> None:
        if n > 0:
            self.groups.append([self._record(kernel, b - a, inputs + [a]) for a, b in self._spans(n)])

    def sliced(self, kernel, n: int, inputs_of) -> None:
        if n > 0:
            self.groups.append([self._record(kernel, b - a, inputs_of(a, b)) for a, b in self._spans(n)])


class Plan:
    """Launches recorded once by a :class:`Recorder` and replayed by every later call that needs them.

    With ``graphs``, each run of one-range launches is captured once as a Warp graph (``wp.ScopedCapture``: a
    CUDA graph on CUDA, Warp's replay of the recorded launches on the CPU) and replayed with
    ``wp.capture_launch``; without, or where a capture fails, the recorded launches run one after another (on
    the CPU each as one native call with its arguments packed once, :func:`_cpu_call`). A launch split into
    row ranges (CPU threads) runs its ranges on the thread pool. Either way every launch runs with the
    arguments it was recorded with, in the recorded order: results are bitwise those of the direct launches.
    The buffers a plan was recorded over must outlive it and keep their addresses.
    """

    def __init__(self, device, threads: int, groups: list[list], graphs: bool = False, stream=None):
        self.device = wp.get_device(device)
        self.threads = threads
        self.groups = groups
        self.stream = stream  # CUDA: the stream the plan is captured and replayed on (None: the current one)
        self.segments: list[tuple[str, object]] = []
        pending: list = []
        for group in groups:
            if len(group) == 1:
                pending.append(group[0])
                continue
            self._add(pending, graphs)
            pending = []
            self.segments.append(("ranges", [self._call(launch) for launch in group]))
        self._add(pending, graphs)

    def _call(self, launch):
        if self.device.is_cpu:
            return _cpu_call(launch)
        stream = self.stream
        return lambda: launch.launch(stream)

    def _add(self, launches: list, graphs: bool) -> None:
        if not launches:
            return
        graph = _capture(self.device, launches, self.stream) if graphs else None
        if graph is not None:
            self.segments.append(("graph", graph))
        else:
            self.segments.append(("calls", [self._call(launch) for launch in launches]))

    @property
    def num_launches(self) -> int:
        """Recorded launches (row ranges counted one by one)."""
        return sum(len(g) for g in self.groups)

    @property
    def graphs(self) -> int:
        """Captured graphs the plan replays."""
        return sum(1 for kind, _ in self.segments if kind == "graph")

    def run(self) -> None:
        for kind, item in self.segments:
            if kind == "graph":
                wp.capture_launch(item, stream=self.stream)
            elif kind == "calls":
                for call in item:
                    call()
            else:
                _threads.run(item, self.threads)


#: Quad steps of at least this many rows get expanded tables from a CPU refiner's third evaluation on (with
#: ``Evaluator.expand_tables`` None): smaller steps evaluate about as fast from the compact ones, so building
#: expanded tables for them is pure cost (``bench/bench_expand.py``, later evaluations: no faster at 208,000 rows,
#: 0-20% faster at 832,000, 25-30% at 3.3 million).
EXPAND_MIN_ROWS = 1 << 19

#: ctypes argument structs of recorded CPU launches, by their fields (:func:`_cpu_call`).
_ARG_STRUCTS: dict = {}


def _cpu_call(launch):
    """A no-argument callable that runs a recorded CPU launch as Warp's ``Launch.launch`` does -- the kernel's
    forward entry point called with the launch bounds and the kernel's argument struct -- with the struct
    packed once here instead of on every call (about 0.7 us a launch instead of 4-9). Where the launch is not
    a plain forward CPU launch of the layout this expects, ``launch.launch`` itself."""
    try:
        params, kernel, hooks = launch.params, launch.kernel, launch.hooks
        plain = (not launch.adjoint and getattr(launch, "block_dim", 1) <= 1 and hooks.forward is not None
                 and len(params) == len(kernel.adj.args) + 1)
        if not plain:
            return launch.launch
        fields = tuple((arg.label, type(value)) for arg, value in zip(kernel.adj.args, params[1:]))
        struct = _ARG_STRUCTS.get(fields)
        if struct is None:  # a ctypes class per argument layout (making one costs about 0.1 ms)
            struct = _ARG_STRUCTS.setdefault(fields, type("Args", (ctypes.Structure,), {"_fields_": list(fields)}))
        args = struct()
        for (name, _), value in zip(fields, params[1:]):
            setattr(args, name, value)
        forward, bounds, packed = hooks.forward, ctypes.byref(params[0]), ctypes.byref(args)
    except Exception:  # noqa: BLE001 (another Warp's internals: the recorded launch as Warp runs it)
        return launch.launch

    def call():
        forward(bounds, packed)

    call.keep = (launch, args)  # the struct and the arrays it points to live as long as the call
    return call


_capture_lock = threading.Lock()


def _capture(device, launches: list, stream=None):
    """A Warp graph of ``launches`` replayed in order, or None where Warp cannot capture on ``device``; on CUDA
    captured on ``stream`` (None: the device's current stream). Captures are serialised: on the CPU Warp
    records any CPU launch made while a capture is open, from any thread."""
    with _capture_lock:
        try:
            with wp.ScopedCapture(device=device, stream=stream, force_module_load=False) as capture:
                for launch in launches:
                    launch.launch(stream)
        except Exception:  # noqa: BLE001 (no capture here: the plan runs its recorded launches instead)
            return None
    return capture.graph


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
    if record.edge_ends is not None:  # expanded tables (the CPU's)
        run.rows(k.quad_edge_points_expanded, record.num_edges,
                 [record.edge_ends, record.edge_regular, src, dst, V, V + F, record.edge_weights])
        run.rows(k.quad_vertex_points_expanded, V,
                 [record.ring_offsets, record.ring_vertices, record.ring_faces, record.vertex_regular, src, dst, V,
                  record.ring_weights])
    else:
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


def normal_control_for(normal_control, width: int) -> bool:
    """Whether prescribed normals apply to data of ``width`` columns (``normal_control`` None: the default, on
    for (n, 3) positions only); asking for them on other widths is refused."""
    if normal_control is None:
        return width == 3
    if normal_control and width != 3:
        raise SubdivInputError("normal control applies to (n, 3) positions only", option="normal_control")
    return normal_control


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
    """Limit values of the masks' vertices from the level's points ``src`` (any width, ``out`` in the same
    layout, ``masks.num_vertices`` rows; see :meth:`LimitMasks.first`)."""
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


def set_normals(ids: wp.array, normals: wp.array, out: wp.array, device) -> None:
    """out[ids[i]] = normals[i]: prescribed normals replace the computed ones (vec3 arrays)."""
    launcher(device).sliced(_kernels().scatter_rows, ids.shape[0], lambda a, b: [ids[a:b], normals[a:b], out])


def layout(rows_by_width: wp.array) -> wp.array:
    """The kernels' view of a contiguous (rows, d) buffer: a vec3 array for d = 3, else the 2-D array itself."""
    if rows_by_width.shape[1] == 3:
        scalar = rows_by_width.dtype
        return rows_by_width.view(wp.vec3d if scalar == wp.float64 else wp.vec3f)
    return rows_by_width


# ------------------------------------------------------------------------------------------------ buffers
class _LevelBuffers:
    """Per-level device buffers for data of any width, allocated once for the widest data seen so far; a
    call takes views of them for its width (in the kernels' :func:`layout`). ``generation`` counts the
    allocations: plans recorded over older buffers are stale."""

    def __init__(self, rows: list[int], moved: list[int], device, scalar):
        self.rows, self.moved, self.device, self.scalar = rows, moved, device, scalar
        self.width = 0
        self.generation = 0
        self.flat: list[wp.array] = []
        self.scratch_flat: list[wp.array | None] = []
        self._views: dict = {}
        self._rows: dict = {}

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
                return layout(flat[: n * width].reshape((n, width)))

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


class _Staging:
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


@dataclass
class Evaluated:
    """One pass of :meth:`Evaluator.evaluate_with_limits`: the refined ``points``, ``limit_points`` and unit
    ``limit_normals`` (None where not asked for); numpy arrays, or device arrays (views of the evaluator's
    buffers, valid until its next call) with ``on_device``."""

    points: object
    limit_points: object = None
    limit_normals: object = None


# ------------------------------------------------------------------------------------------------ evaluator
class Evaluator:
    """Applies a hierarchy's steps to vertex data on ``device`` in ``precision``.

    The device records are uploaded and the level buffers allocated on first use and reused by every later
    call. Each kind of call records its launches once (a :class:`Plan`, per data width and normal-control
    choice) and replays them after: no argument packing per call; on CUDA (and on the CPU with ``graphs=True``)
    the whole step loop is one captured graph. Input data is host data (a checked numpy array) or a device
    array as a (rows, width) Warp view (:mod:`warp_subdiv.evaluator.interop`); it is copied into the level-0 buffer (on
    CUDA from a reused pinned buffer, or on the device). On CUDA the evaluator works on a stream of its own,
    ordered after the device's current stream on entry, and the current stream waits for it on exit.

    Thread safety: a lock guards every call's use of the shared level buffers (upload, launches and the
    copy of the result to the host), so concurrent calls from several threads run one after the other and
    each gets its own result. Device results (:meth:`evaluate_device`, ``on_device``) are views of shared
    buffers, valid until the next call.

    ``threads``: CPU threads per launch (None: :func:`warp_subdiv.runtime.threads.default_threads`); each launch of
    many rows is split into that many contiguous row ranges. ``graphs``: capture plans as Warp graphs (None:
    on CUDA only; on the CPU Warp records every CPU launch made while a capture is open, from any thread, so
    it is an opt-in there). ``expand_tables`` (an attribute, set before the first evaluation): quad steps
    read expanded tables (True), the compact ones (False), or (None) on CUDA the compact ones (half the bytes,
    see :mod:`warp_subdiv.kernels.regular`) and on the CPU the compact ones for the first two evaluations and
    from the third on the expanded ones for quad steps of :data:`EXPAND_MIN_ROWS` rows or more: they make an
    evaluation of a large step up to a third faster (none of a small one) but cost two or three evaluations'
    gain to build, which a refiner evaluated once or twice (a mesh and its UVs baked at one time) never gets
    back. Results depend on none of them.
    """

    def __init__(self, hierarchy, *, device, precision: str, threads: int | None = None, graphs: bool | None = None):
        self.hierarchy = hierarchy
        self.device = wp.get_device(device)
        self.threads = _threads.resolve(threads)
        self.graphs = self.device.is_cuda if graphs is None else bool(graphs)
        #: quad steps read expanded tables (None: on the CPU; set before the first evaluation)
        self.expand_tables: bool | None = None
        self._launcher = None
        self.precision = str(precision)
        self._scalar_np, self._scalar, self._vec = PRECISIONS[self.precision]
        self._lock = threading.RLock()
        self._records: list[StepRecord] | None = None
        self._expanded = False  # whether the records hold expanded quad tables
        self._evaluations = 0  # evaluations run (the CPU's tables are expanded for the third)
        self._buffers: _LevelBuffers | None = None
        self._limit: LimitMasks | None = None
        self._plans: dict = {}
        self._plans_generation = 0
        self._limit_out: dict = {}
        self._prescribed: dict = {}
        self._staging = _Staging()
        self._stream = None
        self._staged = None  # CUDA: event after the last upload from the pinned input buffer

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
                self._expanded = bool(self.expand_tables)  # None: compact tables first (see the class docstring)
                self._records = upload(self.hierarchy, self.device, self.precision, self._expanded)
            return self._records

    def _count_evaluation(self) -> None:
        """Note one evaluation (lock held); before the third on the CPU with ``expand_tables`` None, the quad
        steps' records are uploaded again with expanded tables, and the recorded launches that read the old ones
        are dropped."""
        self._evaluations += 1
        if (self._evaluations == 3 and self.expand_tables is None and self.device.is_cpu and not self._expanded
                and self._records is not None
                and any(isinstance(t, RegularTables) and t.face_size == 4 and t.num_rows >= EXPAND_MIN_ROWS
                        for t in self.hierarchy.steps)):
            self._expanded = True
            self._records = upload(self.hierarchy, self.device, self.precision, True, EXPAND_MIN_ROWS)
            self._plans, self._limit_out = {}, {}

    def limit_masks(self) -> LimitMasks:
        """The limit masks on this evaluator's device (built and uploaded on first use)."""
        with self._lock:
            if self._limit is None:
                self._limit = upload_limit(self.hierarchy.limit_tables(), self.device, self.precision)
            return self._limit

    def level_rows(self) -> list[int]:
        """Vertices of every level 0..levels."""
        return [self.hierarchy.base_num_vertices] + [r.num_rows for r in self.records()]

    def _level_views(self, width: int):
        if self._buffers is None:
            records = self.records()
            self._buffers = _LevelBuffers(self.level_rows(), [r.num_moved for r in records], self.device,
                                          self._scalar)
        if width > self._buffers.width:
            from ..runtime import estimate  # the buffers of this width must fit 32-bit sizes and the device

            rows = self._buffers.rows + self._buffers.moved
            estimate.check_buffer_elements(max(rows) * width, f"data of width {width}")
            wbytes = np.dtype(self._scalar_np).itemsize
            estimate.check_device_memory(sum(rows) * (width - self._buffers.width) * wbytes, self.device,
                                         f"level buffers for data of width {width}")
            self._plans, self._limit_out = {}, {}  # they hold the old buffers, freed before the new ones come
        views = self._buffers.views(width)
        if self._buffers.generation != self._plans_generation:  # new buffers: the recorded launches are stale
            self._plans, self._limit_out = {}, {}
            self._plans_generation = self._buffers.generation
        return views

    @contextlib.contextmanager
    def _device_scope(self):
        """The lock, and on CUDA the evaluator's own stream, ordered after the device's current stream on entry;
        the current stream waits for it at the end. Every copy, launch and graph of the evaluator names this
        stream (the device's current stream, which is per device and not per thread, is left alone)."""
        with self._lock:
            if not self.device.is_cuda:
                yield
                return
            if self._stream is None:
                self._stream = wp.Stream(self.device)
            current = wp.get_stream(self.device)
            self._stream.wait_stream(current)
            try:
                yield
            finally:
                current.wait_stream(self._stream)

    def _plan(self, key, issue) -> Plan:
        """The plan of ``issue(launcher)``'s launches, recorded on first use per ``key`` (lock held)."""
        plan = self._plans.get(key)
        if plan is None:
            recorder = Recorder(self.device, self.threads)
            issue(recorder)
            plan = self._plans[key] = Plan(self.device, recorder.threads, recorder.groups, graphs=self.graphs,
                                           stream=self._stream)
        return plan

    def _steps_plan(self, width: int, controls: tuple, start: int = 0) -> Plan:
        """Steps ``start``.. of data of ``width``; ``controls[i]``: normal control in step ``start + i``."""
        records = self.records()
        levels, scratch = self._level_views(width)

        def issue(run):
            for i, control in enumerate(controls, start):
                refine_step(records[i], levels[i], levels[i + 1], scratch[i], control, run)

        return self._plan(("steps", width, start, controls), issue)

    # ---------------------------------------------------------------------------------------- data
    def _load(self, level: int, data) -> None:
        """Copy (rows, width) ``data`` -- a checked numpy array, or a Warp view of a device array -- into level
        ``level``'s buffer, converting to the evaluation precision (lock held)."""
        width = data.shape[1]
        self._level_views(width)
        dst, host_dst = self._buffers.rows_view(level, width)
        if isinstance(data, wp.array) and data.device != self.device:
            data = data.numpy()  # an array on another device: through the host
        if self.device.is_cpu:  # one pass: conversion straight into the buffer
            np.copyto(host_dst, data.numpy() if isinstance(data, wp.array) else data, casting="unsafe")
        elif isinstance(data, wp.array):
            self._copy_rows(data, dst)
        else:  # host data on CUDA: into the pinned buffer, then one transfer
            stage, host_stage = self._staging.get("in", dst.shape, self._scalar)
            if self._staged is not None:  # the previous upload from it must be done before it is overwritten
                wp.synchronize_event(self._staged)
            np.copyto(host_stage, data, casting="unsafe")
            wp.copy(dst, stage, stream=self._stream)
            self._staged = self._stream.record_event()

    def _copy_rows(self, src: wp.array, dst: wp.array) -> None:
        """Device (rows, width) ``src`` into ``dst`` of the same shape, any strides and precisions."""
        from . import interop

        if src.dtype == dst.dtype and interop.is_contiguous_rows(src) and interop.is_contiguous_rows(dst):
            wp.copy(dst, src, stream=self._stream)
        elif self.device.is_cpu:
            np.copyto(dst.numpy(), src.numpy(), casting="unsafe")
        else:
            wp.launch(_convert().cast_rows, dim=src.shape[0], inputs=[src, dst], device=self.device,
                      stream=self._stream)

    def _host(self, arr: wp.array) -> np.ndarray:
        """A new numpy array with the contents of device array ``arr`` (written once, read in order: small
        pages, see topology.small_pages). On CUDA one transfer into a reused pinned buffer, then a copy."""
        with small_pages():
            if self.device.is_cpu:
                out = arr.numpy()
            else:
                stage, out = self._staging.get("out", arr.shape, arr.dtype)
                wp.copy(stage, arr, stream=self._stream)
                wp.synchronize_stream(self._stream)
            if self.threads == 1 or len(out) < 2 * _threads.MIN_ROWS:
                return np.array(out, copy=True)
            copy = np.empty_like(out)  # copied in row ranges on the evaluator's threads (numpy frees the GIL)
            _threads.map_ranges(lambda a, b: np.copyto(copy[a:b], out[a:b]), len(out), self.threads)
            return copy

    def _input(self, data, rows: int, what: str):
        """Checked data as (rows, d): numpy arrays as they are (callers check values), Warp views checked for
        shape."""
        if isinstance(data, wp.array):
            if data.ndim != 2 or data.shape[0] != rows:
                raise SubdivInputError(f"{what} must have shape ({rows}, d), got {tuple(data.shape)}",
                                       element="data", value=tuple(data.shape))
            return data
        arr = np.asarray(data)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] != rows or arr.shape[1] < 1:
            raise SubdivInputError(f"{what} must have shape ({rows}, d), got {np.shape(data)}", element="data",
                                   value=np.shape(data))
        return arr

    # ---------------------------------------------------------------------------------------- evaluation
    def _run(self, data, controls) -> wp.array:
        """Refine (n, d) data through every step (lock held); returns the last level's view. ``controls``:
        normal control in every step (a bool) or per step (a tuple)."""
        self._count_evaluation()
        n = len(self.records())
        controls = (bool(controls),) * n if isinstance(controls, (bool, np.bool_)) else tuple(controls)
        self._load(0, data)
        self._steps_plan(data.shape[1], controls).run()
        return self._level_views(data.shape[1])[0][-1]

    def evaluate(self, data, normal_control: bool, rows=None) -> np.ndarray:
        """Refine checked (n, d) data of any width in one pass; returns a new numpy array (N, d) of the
        evaluation precision, or with ``rows`` (int array) only those rows of it, in that order (on the CPU
        gathered straight from the level buffer: one pass instead of a copy and a gather)."""
        with self._device_scope():
            result = self._run(data, normal_control)
            if rows is None:
                return self._host(result)
            if self.device.is_cpu:
                return np.take(result.numpy(), rows, axis=0)
            return np.take(self._host(result), rows, axis=0)

    def evaluate_device(self, data, normal_control: bool, out: wp.array | None = None) -> wp.array:
        """Refine checked (n, 3) positions (host data or a device view); returns the last level's device array of
        vec3 (a view of a shared buffer, overwritten by the next call), or writes it into ``out`` (a (N, 3)
        device view on this device, any strides and precision) and returns ``out``."""
        with self._device_scope():
            result = self._run(data, normal_control)
            if out is None:
                return result
            self._copy_rows(self._buffers.rows_view(len(self._buffers.rows) - 1, data.shape[1])[0], out)
            return out

    def _last_step(self, points) -> wp.array:
        """Points of the second-to-last level (lock held) refined through the last step only; returns the last
        level's view. Normal control acts on (n, 3) data."""
        self._count_evaluation()
        n = len(self.records())
        arr = self._input(points, self._level_rows(-2), "points of the second-to-last level")
        self._load(n - 1, arr)
        self._steps_plan(arr.shape[1], (arr.shape[1] == 3,), start=n - 1).run()
        return self._level_views(arr.shape[1])[0][-1]

    def _level_rows(self, level: int) -> int:
        return self.level_rows()[level]

    def evaluate_last_step(self, points_one_level_up) -> np.ndarray:
        """Refine points (n, d) of the second-to-last level through the last step only."""
        with self._device_scope():
            return self._host(self._last_step(points_one_level_up))

    # ------------------------------------------------------------------------------------------ limits
    def _last_level(self, points) -> wp.array:
        """Last-level points (N, d) in the last level's buffer (lock held); nothing is copied when they are
        that buffer already (the result of :meth:`evaluate_device`)."""
        arr = self._input(points, self.hierarchy.num_vertices, "refined points")
        width = arr.shape[1]
        levels, _ = self._level_views(width)
        last = len(levels) - 1
        own = self._buffers.rows_view(last, width)[0]
        if not (isinstance(arr, wp.array) and arr.ptr == own.ptr and arr.strides == own.strides
                and arr.dtype == own.dtype):
            self._load(last, arr)
        return levels[-1]

    def _prescribed_arrays(self, prescribed):
        """Prescribed normals (ids, normals) on the device, uploaded once."""
        ids, normals = prescribed
        ids = np.asarray(ids, dtype=np.int32)
        normals = np.asarray(normals, dtype=self._scalar_np).reshape(-1, 3)
        key = (ids.tobytes(), normals.tobytes())
        if key not in self._prescribed:
            up = _Uploader(self.device, self.precision)
            self._prescribed[key] = (up(ids, np.int32), wp.array(normals, dtype=self._vec, device=self.device))
        return self._prescribed[key]

    def _limit_outputs(self, width: int, rows: int, tangents: int):
        """Reused device outputs of the limit plans: (points (rows, width) layout, tangent u, tangent v, normals)."""
        key = (width, rows)
        if key not in self._limit_out:
            dev, scalar = self.device, self._scalar
            self._limit_out[key] = (
                layout(wp.empty((rows, width), dtype=scalar, device=dev)),
                wp.empty(tangents, dtype=self._vec, device=dev), wp.empty(tangents, dtype=self._vec, device=dev),
                wp.empty(rows, dtype=self._vec, device=dev))
        return self._limit_out[key]

    def _limits(self, width: int, rows: int | None, points: bool, normals: bool, prescribed):
        """Limit points and/or normals of the first ``rows`` vertices from the last level's buffer (lock held):
        (points, normals) device views, None where not asked for."""
        masks = self.limit_masks()
        rows = masks.num_vertices if rows is None else rows
        masks = masks.first(rows)
        levels, _ = self._level_views(width)
        src = levels[-1]
        if normals and src.ndim != 1:
            raise SubdivInputError(f"limit normals take (n, 3) positions, got width {width}", element="data",
                                   value=width)
        out, tu, tv, nout = self._limit_outputs(width, rows, masks.num_tangents)
        ids, values = self._prescribed_arrays(prescribed) if normals and prescribed is not None and len(
            prescribed[0]) else (None, None)

        def issue(run):
            if points:
                limit_positions(masks, src, out, run)
            if normals:
                limit_normals(masks, src, tu, tv, nout, run)
                if ids is not None:
                    set_normals(ids, values, nout, run)

        key = ("limits", width, rows, points, normals, None if ids is None else ids.ptr)
        self._plan(key, issue).run()
        return (out if points else None), (nout if normals else None)

    def limit_points(self, refined_points, *, last_step: bool = False, rows: int | None = None,
                     on_device: bool = False):
        """Limit values (N, d) of the last level's vertices, any width: the position mask applied to each
        vertex's ring. ``last_step``: the points are of the second-to-last level and are refined through the
        last step first (for masks read one level deeper); ``rows``: only the first rows (a deeper level's
        vertex children). A numpy array, or with ``on_device`` a view of a shared device buffer."""
        with self._device_scope():
            src = self._last_step(refined_points) if last_step else self._last_level(refined_points)
            width = 3 if src.ndim == 1 else src.shape[1]
            out, _ = self._limits(width, rows, True, False, None)
            return out if on_device else self._host(out)

    def limit_normals(self, refined_points, prescribed, *, last_step: bool = False, rows: int | None = None,
                      on_device: bool = False):
        """Unit limit normals (N, 3) of the last level's vertices from positions (N, 3); ``prescribed``
        (ids, normals) replace theirs. ``last_step``, ``rows``, ``on_device`` as in :meth:`limit_points`."""
        with self._device_scope():
            src = self._last_step(refined_points) if last_step else self._last_level(refined_points)
            if src.ndim != 1:
                raise SubdivInputError(f"limit normals take (n, 3) positions, got {tuple(src.shape)}",
                                       element="data", value=tuple(src.shape))
            _, out = self._limits(3, rows, False, True, prescribed)
            return out if on_device else self._host(out)

    def evaluate_with_limits(self, data, controls, *, points: bool = True, limit_points: bool = True,
                             limit_normals: bool = True, prescribed=None, level: int = -1, rows: int | None = None,
                             on_device: bool = False) -> Evaluated:
        """Refine checked (n, d) data through every step and take limit points and normals from the last
        level's buffer in the same pass, with no copy in between. ``controls``: normal control per step (or
        one bool); ``level``: the level whose points are returned (-2 where a refiner one level deeper serves
        the limits, with ``rows`` its vertex children: that level's vertices)."""
        with self._device_scope():
            self._run(data, controls)
            width = data.shape[1]
            lp, ln = self._limits(width, rows, limit_points, limit_normals, prescribed)
            pts = self._level_views(width)[0][level] if points else None
            if on_device:
                return Evaluated(pts, lp, ln)
            return Evaluated(*(None if a is None else self._host(a) for a in (pts, lp, ln)))

    def table_bytes(self) -> int:
        """Bytes of everything a step keeps on the device (index tables, masks, explicit stencils)."""
        wbytes = np.dtype(self._scalar_np).itemsize
        return sum(t.nbytes(wbytes) for t in self.hierarchy.steps)
