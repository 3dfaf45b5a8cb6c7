"""The :class:`Evaluator`: a :class:`~warp_subdiv.tables.hierarchy.Hierarchy`'s step tables applied to vertex
data with Warp kernels.

The evaluator knows nothing about creases or schemes. As OpenSubdiv's ``Osd::CpuEvaluator`` it is stateless
evaluation over typed records (:mod:`~warp_subdiv.evaluator.records`), each kind launching its kernels
(:mod:`~warp_subdiv.evaluator.dispatch`) through launchers, recorders and replayed plans
(:mod:`~warp_subdiv.evaluator.launch`) over per-level buffers (:mod:`~warp_subdiv.evaluator.buffers`).

:class:`Evaluator` owns the records and the per-level buffers (allocated once, grown when wider data comes,
reused by every later call). One lock guards the section that uses the shared buffers, so one evaluator
can serve several Python threads at once (each call's launches, on however many threads, finish before the
lock is released).
"""
from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..errors import SubdivInputError
from ..runtime import threads as _threads
from .buffers import LevelBuffers, LimitOutputs, Transfers
from .dispatch import limits, refine_step
from .launch import Launcher, LaunchPlan, OwnStream, Recorder
from .records import PRECISIONS, LimitMasks, StepRecord, StepRecords, upload_limit


def default_device() -> str:
    """CUDA when a CUDA device is present, else the CPU."""
    return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"


@dataclass
class Evaluated:
    """One pass of :meth:`Evaluator.evaluate_with_limits`: the refined ``points``, ``limit_points`` and unit
    ``limit_normals`` (None where not asked for); numpy arrays, or device arrays (views of the evaluator's
    buffers, valid until its next call) with ``on_device``."""

    points: object
    limit_points: object = None
    limit_normals: object = None


class Evaluator:
    """Applies a hierarchy's steps to checked vertex data (:mod:`warp_subdiv.evaluator.inputs`) on ``device`` in
    ``precision``.

    Records and level buffers are made on first use and reused by every later call. Each kind of call records
    its launches once (a :class:`~warp_subdiv.evaluator.launch.LaunchPlan`, per data width and normal-control
    choice) and replays them after; on CUDA (and on the CPU with ``graphs``) the step loop is one captured
    graph. Input data (host data, or a (rows, width) Warp view of a device array) is copied into the level-0
    buffer. On CUDA the evaluator works on a stream of its own, ordered after the device's current stream on
    entry, and the current stream waits for it on exit. A lock makes concurrent calls run one after the other;
    device results (:meth:`evaluate_device`, ``on_device``) are views of shared buffers, valid until the next
    call. ``threads``: CPU threads per launch (None: :func:`warp_subdiv.runtime.threads.default_threads`).
    ``graphs``: capture plans as Warp graphs (None: on CUDA only; on the CPU Warp records every CPU launch made
    while a capture is open, from any thread, so it is an opt-in there). ``expand_tables`` (an attribute, set
    before the first evaluation): which quad tables the steps read (see
    :class:`~warp_subdiv.evaluator.records.StepRecords`). Results depend on none of them.
    """

    def __init__(self, hierarchy, *, device, precision: str, threads: int | None = None, graphs: bool | None = None):
        self.hierarchy = hierarchy
        self.device = wp.get_device(device)
        self.threads = _threads.resolve(threads)
        self.graphs = self.device.is_cuda if graphs is None else bool(graphs)
        self.expand_tables: bool | None = None
        self.precision = str(precision)
        self._scalar_np, self._scalar, self._vec = PRECISIONS[self.precision]
        self._launcher = None
        self._lock = threading.RLock()
        self._records = StepRecords(hierarchy, self.device, self.precision)
        self._buffers: LevelBuffers | None = None
        self._limit: LimitMasks | None = None
        self._plans: dict = {}
        self._plans_generation = 0
        self._limit_out = LimitOutputs(self.device, self.precision)
        self._stream = OwnStream(self.device)
        self._transfers = Transfers(self.device, self._scalar, self.threads, self._stream)

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
            return self._records.get(self.expand_tables)

    def _count_evaluation(self) -> None:
        """Note one evaluation (lock held); the recorded launches go where the records were replaced."""
        if self._records.count_evaluation(self.expand_tables):
            self._drop_plans()

    @property
    def has_limit_masks(self) -> bool:
        """Whether the limit masks are built and uploaded already."""
        return self._limit is not None

    def limit_masks(self) -> LimitMasks:
        """The limit masks on this evaluator's device (built and uploaded on first use)."""
        with self._lock:
            if self._limit is None:
                self._limit = upload_limit(self.hierarchy.limit_tables(), self.device, self.precision)
            return self._limit

    def level_rows(self) -> list[int]:
        """Vertices of every level 0..levels."""
        return [self.hierarchy.base_num_vertices] + [r.num_rows for r in self.records()]

    def level_views(self, width: int):
        """(levels, scratch): the shared level buffers as views for data of ``width`` (kernel views; see
        :meth:`~warp_subdiv.evaluator.buffers.LevelBuffers.views`), allocated or grown here (lock held)."""
        if self._buffers is None:
            self._buffers = LevelBuffers(self.level_rows(), [r.num_moved for r in self.records()], self.device,
                                         self._scalar)
        if width > self._buffers.width:
            self._buffers.check_growth(width)
            self._drop_plans()  # they hold the old buffers, freed before the new ones come
        views = self._buffers.views(width)
        if self._buffers.generation != self._plans_generation:  # new buffers: the recorded launches are stale
            self._drop_plans()
            self._plans_generation = self._buffers.generation
        return views

    def _drop_plans(self) -> None:
        self._plans = {}
        self._limit_out.clear()

    @contextlib.contextmanager
    def _device_scope(self):
        """The lock, and on CUDA the evaluator's own stream (:class:`~warp_subdiv.evaluator.launch.OwnStream`)."""
        with self._lock, self._stream.ordered():
            yield

    def _plan(self, key, issue) -> LaunchPlan:
        """The plan of ``issue(launcher)``'s launches, recorded on first use per ``key`` (lock held)."""
        plan = self._plans.get(key)
        if plan is None:
            recorder = Recorder(self.device, self.threads)
            issue(recorder)
            plan = self._plans[key] = LaunchPlan(self.device, recorder.threads, recorder.groups, graphs=self.graphs,
                                                 stream=self._stream.stream)
        return plan

    def _steps_plan(self, width: int, controls: tuple, start: int = 0) -> LaunchPlan:
        """Steps ``start``.. of data of ``width``; ``controls[i]``: normal control in step ``start + i``."""
        records = self.records()
        levels, scratch = self.level_views(width)

        def issue(run):
            for i, control in enumerate(controls, start):
                refine_step(records[i], levels[i], levels[i + 1], scratch[i], control, run)

        return self._plan(("steps", width, start, controls), issue)

    def _load(self, level: int, data) -> None:
        """Copy checked (rows, width) ``data`` into level ``level``'s buffer, converting to the evaluation
        precision (lock held)."""
        width = data.shape[1]
        self.level_views(width)
        self._transfers.load(data, *self._buffers.rows_view(level, width))

    def _run(self, data, controls) -> wp.array:
        """Refine (n, d) data through every step (lock held); returns the last level's view. ``controls``:
        normal control in every step (a bool) or per step (a tuple)."""
        self._count_evaluation()
        n = len(self.records())
        controls = (bool(controls),) * n if isinstance(controls, (bool, np.bool_)) else tuple(controls)
        self._load(0, data)
        self._steps_plan(data.shape[1], controls).run()
        return self.level_views(data.shape[1])[0][-1]

    def evaluate(self, data, normal_control: bool, rows=None) -> np.ndarray:
        """Refine checked (n, d) data of any width in one pass; returns a new numpy array (N, d) of the
        evaluation precision, or with ``rows`` (int array) only those rows of it, in that order (on the CPU
        gathered straight from the level buffer: one pass instead of a copy and a gather)."""
        with self._device_scope():
            result = self._run(data, normal_control)
            if rows is None:
                return self._transfers.to_host(result)
            if self.device.is_cpu:
                return np.take(result.numpy(), rows, axis=0)
            return np.take(self._transfers.to_host(result), rows, axis=0)

    def evaluate_device(self, data, normal_control: bool, out: wp.array | None = None) -> wp.array:
        """Refine checked (n, 3) positions; returns the last level's device array of vec3 (a view of a shared
        buffer, overwritten by the next call), or writes it into ``out`` (a (N, 3) device view on this device,
        any strides and precision) and returns ``out``."""
        with self._device_scope():
            result = self._run(data, normal_control)
            if out is None:
                return result
            self._transfers.copy_rows(self._buffers.rows_view(len(self._buffers.rows) - 1, data.shape[1])[0], out)
            return out

    def run_steps(self, src: wp.array, out: wp.array, normal_control: bool, run: Launcher) -> None:
        """Refine device data ``src`` (control rows, kernel view) through every step into ``out`` (the last
        level's rows), launching through ``run`` as it goes (nothing recorded: the caller's arrays change from
        call to call); the levels between go through the shared level buffers, under the lock."""
        records = self.records()
        with self._lock:
            levels, scratch = self.level_views(3 if src.ndim == 1 else src.shape[1])
            for k, step in enumerate(records):
                dst = out if k == len(records) - 1 else levels[k + 1]
                refine_step(step, src, dst, scratch[k], normal_control, run)
                src = dst

    # ------------------------------------------------------------------------------------------ limits
    def _last_level(self, points, last_step: bool, normal_control: bool) -> wp.array:
        """The last level's buffer holding checked points (lock held): points of the second-to-last level refined
        through the last step (``last_step``, ``normal_control`` in it), or the last level's points, copied in
        unless they are that buffer already (the result of :meth:`evaluate_device`)."""
        width = points.shape[1]
        if last_step:
            self._count_evaluation()
            start = len(self.records()) - 1
            self._load(start, points)
            self._steps_plan(width, (bool(normal_control),), start=start).run()
            return self.level_views(width)[0][-1]
        levels, _ = self.level_views(width)
        own = self._buffers.rows_view(len(levels) - 1, width)[0]
        if not (isinstance(points, wp.array) and points.ptr == own.ptr and points.strides == own.strides
                and points.dtype == own.dtype):
            self._load(len(levels) - 1, points)
        return levels[-1]

    def _limits(self, width: int, rows: int | None, points: bool, normals: bool, prescribed):
        """Limit points and/or normals of the first ``rows`` vertices from the last level's buffer (lock held):
        (points, normals) device views, None where not asked for."""
        masks = self.limit_masks()
        rows = masks.num_vertices if rows is None else rows
        masks = masks.first(rows)
        src = self.level_views(width)[0][-1]
        if normals and src.ndim != 1:
            raise SubdivInputError(f"limit normals take (n, 3) positions, got width {width}", element="data",
                                   value=width)
        outputs = self._limit_out.outputs(width, rows, masks.num_tangents)
        ids = self._limit_out.prescribed(prescribed) if normals and prescribed is not None and len(
            prescribed[0]) else None
        key = ("limits", width, rows, points, normals, None if ids is None else ids[0].ptr)
        self._plan(key, lambda run: limits(masks, src, outputs, ids, points, normals, run)).run()
        return (outputs[0] if points else None), (outputs[3] if normals else None)

    def limit_points(self, refined_points, *, last_step: bool = False, normal_control: bool = False,
                     rows: int | None = None, on_device: bool = False):
        """Limit values (N, d) of the last level's vertices from checked points, any width: the position mask
        applied to each vertex's ring. ``last_step``: the points are of the second-to-last level, refined through
        the last step first (masks read one level deeper), with ``normal_control``; ``rows``: only the first rows
        (a deeper level's vertex children). A numpy array, or with ``on_device`` a view of a shared buffer."""
        with self._device_scope():
            src = self._last_level(refined_points, last_step, normal_control)
            width = 3 if src.ndim == 1 else src.shape[1]
            out, _ = self._limits(width, rows, True, False, None)
            return out if on_device else self._transfers.to_host(out)

    def limit_normals(self, refined_points, prescribed, *, last_step: bool = False, normal_control: bool = True,
                      rows: int | None = None, on_device: bool = False):
        """Unit limit normals (N, 3) of the last level's vertices from checked positions (N, 3); ``prescribed``
        (ids, normals) replace theirs. ``last_step``, ``normal_control``, ``rows``, ``on_device`` as in
        :meth:`limit_points`."""
        with self._device_scope():
            src = self._last_level(refined_points, last_step, normal_control)
            if src.ndim != 1:
                raise SubdivInputError(f"limit normals take (n, 3) positions, got {tuple(src.shape)}",
                                       element="data", value=tuple(src.shape))
            _, out = self._limits(3, rows, False, True, prescribed)
            return out if on_device else self._transfers.to_host(out)

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
            pts = self.level_views(width)[0][level] if points else None
            if on_device:
                return Evaluated(pts, lp, ln)
            return Evaluated(*(None if a is None else self._transfers.to_host(a) for a in (pts, lp, ln)))

    def table_bytes(self) -> int:
        """Bytes of everything a step keeps on the device (index tables, masks, explicit stencils)."""
        wbytes = np.dtype(self._scalar_np).itemsize
        return sum(t.nbytes(wbytes) for t in self.hierarchy.steps)
