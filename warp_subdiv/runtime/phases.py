"""Wall-clock time by phase: where a run (the USD bake) spends its time.

A :class:`Phases` recorder collects exclusive time per named phase: entering a phase inside another pauses the
outer one, so the phases of one thread add up to the time spent in them. Code deep in a pipeline marks its
work with ``with phase("refine"):``, which costs nothing when no recorder is active (:func:`recording` makes
one active for the current thread and what it calls). Work done on another thread (:class:`Phases` is
thread-safe) is recorded under its own phase names, and its time overlaps the main thread's: a job handed to
another thread records into the caller's recorder when it is wrapped with :func:`bound` (threads do not
inherit the context of the thread that submits their jobs).

The USD bake's phases (:func:`warp_subdiv.usd.refine_usd`, ``Result.phases``; ``warp-subdiv refine
--verbose``): ``read`` (open the stage, read and check the meshes, predict sizes), ``analyse`` (control-mesh
analysis, per-level topology and tables), ``refine`` (vertex data: points, velocities, vertex and varying
primvars), ``face-varying`` (face-varying channels: their topology and values), ``write`` (converting to Vt
arrays, authoring the layer and saving it), and ``waiting`` (the writer waiting for a mesh its workers refine
ahead: :class:`warp_subdiv.usd.ahead.Ahead`; the workers' own time counts to analyse, refine and face-varying,
so with workers the phases add up to more than the wall time).
"""
from __future__ import annotations

import contextlib
import contextvars
import functools
import threading
import time

#: The order phases are reported in (others follow in the order they were first seen).
ORDER = ("read", "analyse", "refine", "face-varying", "write", "waiting")

_active: contextvars.ContextVar = contextvars.ContextVar("warp_subdiv_phases", default=None)


class Phases:
    """Exclusive wall-clock seconds per phase name (thread-safe)."""

    def __init__(self):
        self._seconds: dict = {}
        self._lock = threading.Lock()
        self._local = threading.local()

    def _add(self, name: str, seconds: float) -> None:
        with self._lock:
            self._seconds[name] = self._seconds.get(name, 0.0) + seconds

    @contextlib.contextmanager
    def phase(self, name: str):
        stack = getattr(self._local, "stack", None)
        if stack is None:
            stack = self._local.stack = []
        now = time.perf_counter()
        if stack:  # pause the enclosing phase
            outer, since = stack[-1]
            self._add(outer, now - since)
        stack.append([name, now])
        try:
            yield
        finally:
            now = time.perf_counter()
            _, since = stack.pop()
            self._add(name, now - since)
            if stack:
                stack[-1][1] = now  # resume the enclosing phase

    @property
    def seconds(self) -> dict:
        """{phase: seconds}, in :data:`ORDER` first."""
        with self._lock:
            items = dict(self._seconds)
        ordered = {k: items.pop(k) for k in ORDER if k in items}
        ordered.update(items)
        return ordered


@contextlib.contextmanager
def recording(recorder: Phases | None = None):
    """Make ``recorder`` (a new :class:`Phases` by default) the active one while the block runs; yields it."""
    recorder = recorder if recorder is not None else Phases()
    token = _active.set(recorder)
    try:
        yield recorder
    finally:
        _active.reset(token)


def active() -> Phases | None:
    """The recorder active in this context (None outside :func:`recording`)."""
    return _active.get()


@contextlib.contextmanager
def phase(name: str):
    """Count the block's time to phase ``name`` of the active recorder (nothing when none is active)."""
    recorder = _active.get()
    if recorder is None:
        yield
        return
    with recorder.phase(name):
        yield


def bound(func, *args, **kwargs):
    """A callable that runs ``func(*args, **kwargs)`` with the recorder active here (None: none) as the active
    one, for a job another thread runs: its phases count to the caller's run. It may be called on any thread,
    several times, at once."""
    recorder = _active.get()

    def run():
        token = _active.set(recorder)
        try:
            return func(*args, **kwargs)
        finally:
            _active.reset(token)

    return run


def timed(name: str):
    """Decorator: every call of the function counts to phase ``name`` (see :func:`phase`)."""
    def decorate(func):
        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            recorder = _active.get()
            if recorder is None:
                return func(*args, **kwargs)
            with recorder.phase(name):
                return func(*args, **kwargs)
        return wrapper
    return decorate


def records(func):
    """Decorator for a run that returns an object with a ``phases`` attribute: the call records its phases
    (time outside every named phase counts as "other") and sets ``result.phases`` to them."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with recording() as recorder:
            with recorder.phase("other"):
                result = func(*args, **kwargs)
        try:
            result.phases = recorder.seconds
        except AttributeError:
            pass
        return result
    return wrapper
