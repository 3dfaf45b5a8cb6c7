"""How launches run: directly, split into row ranges on CPU threads, or recorded once and replayed.

A :class:`Launcher` launches kernels on an explicit device; on the CPU it splits each launch into a few
contiguous row ranges that several threads take from one queue (:mod:`warp_subdiv.runtime.threads`; Warp runs
one CPU launch on one thread and releases the GIL while a kernel runs). Every row is computed by the same code
whatever the split, so results are bitwise equal to one thread's. A :class:`Recorder` issues the same launches
as records, and a :class:`LaunchPlan` replays them (as captured Warp graphs, or as native calls with their
arguments packed once). :func:`load_kernels` is the one registry of loaded kernel modules (the evaluator's,
the gradients', the bake's).
"""
from __future__ import annotations

import contextlib
import ctypes
import inspect
import threading

import warp as wp

from ..runtime import threads as _threads

_loaded: set = set()  # (device, kernel module name) pairs loaded in this process
_load_lock = threading.Lock()
#: Whether this Warp's force_load compiles several modules at once (its max_workers: not in every Warp accepted).
_PARALLEL_LOADS = "max_workers" in inspect.signature(wp.force_load).parameters
_ready: set = set()  # aliases of the devices whose evaluation kernels are loaded (a launcher's fast check)


def _kernels():
    from .. import kernels  # imported late: building a hierarchy needs no Warp module

    return kernels


def evaluation_kernels() -> tuple:
    """The kernel modules evaluation launches: index and stencil rows, displacements and projections, casts."""
    from ..kernels import convert

    k = _kernels()
    return k.regular, k.stencil, k.projection, convert


def load_kernels(device, modules=None) -> None:
    """Load kernel ``modules`` (default: :func:`evaluation_kernels`) on ``device``, each once per process and
    device, before threads launch them: a module must not be compiled or loaded from two threads at once.

    A module loads from the binary the package ships where it fits this machine and Warp
    (:mod:`warp_subdiv.kernels.prebuilt`: no compile on a first run); the others compile, several at once."""
    key = str(device)
    modules = evaluation_kernels() if modules is None else tuple(modules)
    if all((key, m.__name__) in _loaded for m in modules):
        return
    from ..kernels import prebuilt

    with _load_lock:
        device = wp.get_device(device)
        missing = [m for m in modules if (key, m.__name__) not in _loaded and not prebuilt.load(m, device)]
        if missing and _PARALLEL_LOADS:
            wp.force_load(device=device, modules=[wp.get_module(m.__name__) for m in missing],
                          max_workers=min(len(missing), _threads.available_cores()))
        elif missing:  # a Warp that loads one module at a time
            for module in missing:
                wp.load_module(module, device=device)
        _loaded.update((key, m.__name__) for m in modules)


class Launcher:
    """Launches kernels on ``device``; on the CPU with ``threads`` > 1, a launch of many rows runs as a few
    contiguous row ranges (:func:`~warp_subdiv.runtime.threads.chunks`: several per thread) that the calling
    thread and the process's thread pool take from one queue, and returns when every range is done. On CUDA one
    launch, whatever ``threads``."""

    def __init__(self, device, threads: int = 1):
        self.device = wp.get_device(device)
        self.threads = max(1, int(threads)) if self.device.is_cpu else 1
        if self.device.alias not in _ready:  # before the first launch: shipped binaries, or compiled at once
            load_kernels(self.device)
            _ready.add(self.device.alias)

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
        _threads.each_chunk(lambda a, b: wp.launch(kernel, dim=b - a, inputs=inputs + [a], device=dev), n,
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
        _threads.each_chunk(lambda a, b: wp.launch(kernel, dim=b - a, inputs=inputs_of(a, b), device=dev), n,
                            self.threads)

    @contextlib.contextmanager
    def together(self):
        """The block's launches read nothing another of them writes, and write disjoint rows: they may run
        with no barrier between them. Direct launches keep theirs (one after another, as issued); a
        :class:`Recorder` on several threads records them as one group whose ranges share one queue."""
        yield


def launcher(device_or_launcher) -> Launcher:
    """A :class:`Launcher` as given, or a one-thread launcher on the given device."""
    if isinstance(device_or_launcher, Launcher):
        return device_or_launcher
    return Launcher(device_or_launcher, 1)


class Recorder(Launcher):
    """A :class:`Launcher` that records its launches (``wp.launch(..., record_cmd=True)``) instead of running
    them: the functions of :mod:`~warp_subdiv.evaluator.dispatch` issue through it the launches they would run,
    split into the same row ranges, and a :class:`LaunchPlan` replays them. ``groups``: per launch (or per block
    of launches issued :meth:`together` on several threads), its recorded row ranges (one, or several per CPU
    thread)."""

    def __init__(self, device, threads: int = 1):
        super().__init__(device, threads)
        self.groups: list[list] = []

    def _spans(self, n: int) -> list[tuple[int, int]]:
        return _threads.chunks(n, self.threads)

    @contextlib.contextmanager
    def together(self):
        start = len(self.groups)
        yield
        if self.threads > 1 and len(self.groups) - start > 1:  # one queue for every range of the block
            self.groups[start:] = [[launch for group in self.groups[start:] for launch in group]]

    def _record(self, kernel, dim: int, inputs: list):
        return wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)

    def rows(self, kernel, n: int, inputs: list) -> None:
        if n > 0:
            self.groups.append([self._record(kernel, b - a, inputs + [a]) for a, b in self._spans(n)])

    def sliced(self, kernel, n: int, inputs_of) -> None:
        if n > 0:
            self.groups.append([self._record(kernel, b - a, inputs_of(a, b)) for a, b in self._spans(n)])


class LaunchPlan:
    """Launches recorded once by a :class:`Recorder` and replayed by every later call that needs them.

    With ``graphs``, each run of one-range launches is captured once as a Warp graph (``wp.ScopedCapture``: a
    CUDA graph on CUDA, Warp's replay of the recorded launches on the CPU) and replayed with
    ``wp.capture_launch``; without, or where a capture fails, the recorded launches run one after another (on
    the CPU each as one native call with its arguments packed once, :func:`_cpu_call`). A launch split into
    row ranges (CPU threads) runs its ranges from one queue on the thread pool and the calling thread. Either way
    every launch runs with the
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
                _threads.run_shared(item, self.threads)


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


class OwnStream:
    """A CUDA stream of one's own for every copy, launch and graph of its owner (made on first use): the device's
    current stream, which is per device and not per thread, is left alone. :meth:`ordered` orders it after the
    current stream on entry and the current stream after it on exit. On the CPU ``stream`` stays None."""

    def __init__(self, device):
        self.device = wp.get_device(device)
        self.stream = None

    @contextlib.contextmanager
    def ordered(self):
        if not self.device.is_cuda:
            yield
            return
        if self.stream is None:
            self.stream = wp.Stream(self.device)
        current = wp.get_stream(self.device)
        self.stream.wait_stream(current)
        try:
            yield
        finally:
            current.wait_stream(self.stream)
