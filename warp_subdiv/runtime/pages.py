"""Memory pages of large temporaries: numpy's transparent-huge-page hint switched off while arrays that are
written once and read in order are made (a refinement step's topology, output copies)."""
import contextlib
import threading

import numpy as np

_pages_lock = threading.Lock()
_pages_state = {"depth": 0, "previous": None}


@contextlib.contextmanager
def small_pages():
    """Let numpy skip its transparent-huge-page hint for arrays written once and read in order.

    A refinement step writes many large temporaries once each; with the hint the kernel zeroes (and on a
    fragmented machine first compacts) 2 MiB pages at every first touch (BENCHMARKS.md, "Where the build
    time goes"). Used for topology steps and output copies; everything else keeps the host's setting.
    numpy's switch is private: without it, nothing changes.
    """
    switch = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        yield
        return
    with _pages_lock:  # nested or concurrent users: the first switches off, the last restores
        if _pages_state["depth"] == 0:
            _pages_state["previous"] = switch(False)
        _pages_state["depth"] += 1
    try:
        yield
    finally:
        with _pages_lock:
            _pages_state["depth"] -= 1
            if _pages_state["depth"] == 0:
                switch(_pages_state["previous"])
