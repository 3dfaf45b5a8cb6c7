"""Threads for CPU work: how many, the shared pool, and contiguous row ranges.

Warp runs one CPU launch on one thread, but calls CPU kernels through ctypes, which releases the GIL; numpy
releases it inside large array operations too. So work over rows is split into a few contiguous ranges that
run on a process-wide thread pool, the calling thread taking the first range itself. Every row is computed
by the same code whatever the split, so results are bitwise equal to one thread's.

``threads`` is not a result-determining option: it sits beside ``device=`` and ``max_memory=`` (``Refiner``,
``refine``), not in :class:`~warp_subdiv.options.Options`. ``None`` means :func:`default_threads`: the value
set with :func:`set_default_threads` (the CLI's ``--threads``; a Dask worker sets its share), else the
``WARP_SUBDIV_THREADS`` environment variable, else the cores this process may use (``os.sched_getaffinity``).
"""
from __future__ import annotations

import contextlib
import numbers
import os
import threading
from concurrent.futures import ThreadPoolExecutor

from ..errors import SubdivInputError

#: Rows below which a launch is not split (a launch costs about 24 us of GIL-held Python time).
MIN_ROWS = 32768
#: Ranges per thread of a shared split (:func:`chunks`): a thread that finishes early, or runs while another
#: is descheduled by other processes, takes the next range instead of waiting at the end.
CHUNKS_PER_THREAD = 4

_default: int | None = None
_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()
_local = threading.local()  # .in_pool: this thread runs a job of the pool


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no sched_getaffinity (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def check_threads(value, option: str = "threads") -> int | None:
    """``value`` as a thread count (an integer >= 1) or None; a :class:`SubdivInputError` otherwise."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise SubdivInputError(f"{option} must be an integer >= 1 (or None: the cores this process may use), "
                               f"got {value!r}", option=option, value=value)
    return int(value)


def set_default_threads(value: int | None) -> None:
    """Set the thread count that ``threads=None`` means in this process (None: back to the automatic one)."""
    global _default
    _default = check_threads(value)


def default_threads() -> int:
    """What ``threads=None`` means: :func:`set_default_threads`'s value, else ``WARP_SUBDIV_THREADS``, else
    :func:`available_cores`."""
    if _default is not None:
        return _default
    env = os.environ.get("WARP_SUBDIV_THREADS", "").strip()
    if env:
        try:
            return check_threads(int(env), "WARP_SUBDIV_THREADS")
        except ValueError:
            raise SubdivInputError(f"WARP_SUBDIV_THREADS must be an integer >= 1, got {env!r}",
                                   option="WARP_SUBDIV_THREADS", value=env) from None
    return available_cores()


def resolve(threads) -> int:
    """A checked thread count: ``threads``, or :func:`default_threads` for None."""
    threads = check_threads(threads)
    return default_threads() if threads is None else threads


def pool(threads: int) -> ThreadPoolExecutor | None:
    """The process-wide pool that serves ``threads``-way work (``threads - 1`` workers: the caller runs one
    range itself); None for one thread."""
    if threads <= 1:
        return None
    with _pools_lock:
        ex = _pools.get(threads)
        if ex is None:
            ex = _pools[threads] = ThreadPoolExecutor(threads - 1, thread_name_prefix=f"warp-subdiv-{threads}")
        return ex


def ranges(n: int, parts: int, min_rows: int = MIN_ROWS) -> list[tuple[int, int]]:
    """At most ``parts`` contiguous (start, stop) ranges covering 0..n, none shorter than ``min_rows`` (one
    range when n is small)."""
    parts = max(1, min(parts, n // max(1, min_rows)))
    bounds = [(n * i) // parts for i in range(parts + 1)]
    return [(bounds[i], bounds[i + 1]) for i in range(parts) if bounds[i + 1] > bounds[i]]


def chunks(n: int, threads: int, min_rows: int | None = None) -> list[tuple[int, int]]:
    """Contiguous (start, stop) ranges covering 0..n for :func:`run_shared` on ``threads`` threads: up to
    :data:`CHUNKS_PER_THREAD` per thread, none shorter than ``min_rows`` (None: :data:`MIN_ROWS`); one range
    for one thread or small n."""
    min_rows = MIN_ROWS if min_rows is None else min_rows
    if threads <= 1 or n < 2 * min_rows:
        return [(0, n)] if n > 0 else []
    return ranges(n, threads * CHUNKS_PER_THREAD, min_rows)


def run_shared(jobs, threads: int) -> None:
    """Run the callables ``jobs`` (no arguments, results dropped) on ``threads`` threads that take them in
    order from one shared queue, the calling thread among them: no thread waits while a job is left, whatever
    the other processes on the machine do to one of them. The first exception is raised after every started
    job has finished (no new job starts after one failed)."""
    jobs = list(jobs)
    ex = pool(threads)
    if ex is None or len(jobs) <= 1 or getattr(_local, "in_pool", False):
        for job in jobs:
            job()
        return
    queue = iter(jobs)  # next() on a list iterator is atomic under the GIL
    errors: list = []

    def drain():
        for job in queue:
            if errors:
                return
            try:
                job()
            except BaseException as exc:  # noqa: BLE001 (re-raised by the caller after the others stop)
                errors.append(exc)
                return

    futures = [ex.submit(_pooled, drain) for _ in range(min(threads, len(jobs)) - 1)]
    drain()
    for f in futures:
        f.result()
    if errors:
        raise errors[0]


def run(jobs, threads: int) -> list:
    """Run the callables ``jobs`` (no arguments) on ``threads`` threads, the first on the calling thread;
    returns their results in order. The first exception is raised after every job has finished."""
    jobs = list(jobs)
    ex = pool(threads)
    if ex is None or len(jobs) <= 1 or getattr(_local, "in_pool", False):
        return [job() for job in jobs]  # (a job of the pool runs nested work itself: the pool may be full)
    futures = [ex.submit(_pooled, job) for job in jobs[1:]]
    first, error = None, None
    try:
        first = jobs[0]()
    except BaseException as exc:  # noqa: BLE001 (re-raised below, after the other jobs are done)
        error = exc
    results = [first]
    for f in futures:
        try:
            results.append(f.result())
        except BaseException as exc:  # noqa: BLE001
            error = error or exc
    if error is not None:
        raise error
    return results


@contextlib.contextmanager
def inline():
    """Run the block's threaded work on the calling thread: for a thread that is itself one of several running
    side by side (the USD bake's workers), so that they do not also queue their ranges on the shared pool."""
    before = getattr(_local, "in_pool", False)
    _local.in_pool = True
    try:
        yield
    finally:
        _local.in_pool = before


def _pooled(job):
    with inline():  # a job of the pool: its nested work runs on its own thread
        return job()


def map_ranges(fn, n: int, threads: int, min_rows: int = MIN_ROWS) -> list:
    """``fn(start, stop)`` over contiguous ranges of 0..n on ``threads`` threads; results in range order."""
    return run([(lambda a=a, b=b: fn(a, b)) for a, b in ranges(n, threads, min_rows)], threads)


def take(values, index, threads: int):
    """``values[index]`` (rows of ``values``, a new array) gathered in the :func:`chunks` of ``index`` on ``threads``
    threads (numpy frees the GIL inside a gather). For the library's own index tables, valid by construction:
    out-of-range indices are clipped, not refused (refusing would make numpy buffer every chunk)."""
    import numpy as np

    index = np.asarray(index)
    out = np.empty(index.shape + values.shape[1:], dtype=values.dtype)
    each_chunk(lambda a, b: np.take(values, index[a:b], axis=0, out=out[a:b], mode="clip"), len(index), threads)
    return out


def each_chunk(fn, n: int, threads: int, min_rows: int | None = None) -> None:
    """``fn(start, stop)`` over the :func:`chunks` of 0..n, run by :func:`run_shared` (results dropped)."""
    run_shared([(lambda a=a, b=b: fn(a, b)) for a, b in chunks(n, threads, min_rows)], threads)
