"""The C allocator's thresholds for a bake process: keep freed memory for reuse instead of returning it.

A bake makes many large temporaries (index arrays of 0.1 to 30 MB, most written once), and glibc's ``malloc``
serves each with a fresh ``mmap`` and returns it with ``munmap`` on free (above its dynamic threshold, and it
trims the top of its heap likewise), so every temporary faults its pages in again: zeroed by the kernel, a
fault per 4 KiB page, which is slow on a virtual machine (BENCHMARKS.md, "Cheaper set-up, memory kept for
reuse"). :func:`retain_freed_memory`
raises both thresholds (``mallopt``): blocks up to ``mmap_threshold`` come from the heap, and up to
``trim_threshold`` of freed memory at its top stays mapped, so later temporaries reuse pages already faulted
in. The bake's results are the same; the process keeps more memory mapped between uses (at most the trim
threshold beyond what it holds), which a command-line process that exits soon can afford.

``warp-subdiv`` (the command) calls it at start unless ``WARP_SUBDIV_RETAIN_MEMORY=0``; a library user opts in
by calling it (it is process-wide: a host application's allocator changes with it). glibc on Linux only;
elsewhere it does nothing and returns False.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: The largest block glibc lets come from the heap (its M_MMAP_THRESHOLD maximum on 64-bit: 32 MiB).
MMAP_THRESHOLD = 32 << 20
#: Freed memory kept mapped at the top of a heap before it is returned (glibc's default: 128 KiB).
TRIM_THRESHOLD = 512 << 20


def glibc():
    """This process's C library when it is glibc's on Linux (the one whose ``mallopt`` and ``malloc_trim`` do
    what this module relies on; musl's ``mallopt`` does nothing), else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        _ = libc.gnu_get_libc_version, libc.mallopt, libc.malloc_trim
    except (OSError, AttributeError):
        return None
    return libc


def retain_freed_memory(*, mmap_threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD) -> bool:
    """Set glibc's M_MMAP_THRESHOLD and M_TRIM_THRESHOLD for this process (see the module docstring); True
    where both were set, False where the C library is not glibc's (nothing changes)."""
    libc = glibc()
    if libc is None:
        return False
    mallopt = libc.mallopt
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))) and bool(mallopt(_M_TRIM_THRESHOLD,
                                                                                  int(trim_threshold)))


def release_free_memory() -> bool:
    """Return the C heap's free memory to the system now (glibc's ``malloc_trim(0)``); False elsewhere. For
    measurements that must not count memory an earlier step freed but left mapped."""
    libc = glibc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True


def retain_for_command() -> bool:
    """What the command line does at start: :func:`retain_freed_memory` unless the environment variable
    ``WARP_SUBDIV_RETAIN_MEMORY`` is ``0`` (then nothing, False)."""
    if os.environ.get("WARP_SUBDIV_RETAIN_MEMORY", "1").strip() == "0":
        return False
    return retain_freed_memory()
