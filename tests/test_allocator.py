"""The command line keeps freed memory for reuse (warp_subdiv.runtime.allocator); the library leaves it to the user."""

import numpy as np
import pytest

import warp_subdiv.runtime.allocator as allocator
from conftest import mesh_path
from warp_subdiv import cli


@pytest.mark.skipif(allocator.glibc() is None, reason="glibc's mallopt only")
def test_retain_freed_memory_sets_glibc_thresholds():
    """On glibc both mallopt calls succeed (True), and numpy keeps working on temporaries across the heap/mmap
    boundary it moves (arrays of 64 KiB to 64 MiB, freed and made again, with the same contents)."""
    assert allocator.retain_freed_memory() is True
    assert allocator.release_free_memory() is True
    for size in (1 << 13, 1 << 20, 1 << 22, 1 << 23):  # float64 counts: 64 KiB .. 64 MiB
        a = np.arange(size, dtype=np.float64)
        b = a * 2
        del a
        c = np.arange(size, dtype=np.float64)
        np.testing.assert_array_equal(b, 2 * c)


def test_retain_freed_memory_does_nothing_off_linux(monkeypatch):
    """Elsewhere than Linux nothing is called and the answer is False."""
    monkeypatch.setattr(allocator.sys, "platform", "darwin")
    monkeypatch.setattr(allocator.ctypes, "CDLL", lambda *a, **k: pytest.fail("no C library is loaded"))
    assert allocator.glibc() is None
    assert allocator.retain_freed_memory() is False
    assert allocator.release_free_memory() is False


@pytest.mark.parametrize("value, expected", [(None, True), ("1", True), ("0", False), (" 0 ", False)])
def test_command_line_retains_unless_told_not_to(monkeypatch, capsys, value, expected):
    """``warp-subdiv`` keeps freed memory at start (any command) unless WARP_SUBDIV_RETAIN_MEMORY=0."""
    calls = []
    monkeypatch.setattr(allocator, "retain_freed_memory", lambda **kw: calls.append(kw) or True)
    if value is None:
        monkeypatch.delenv("WARP_SUBDIV_RETAIN_MEMORY", raising=False)
    else:
        monkeypatch.setenv("WARP_SUBDIV_RETAIN_MEMORY", value)
    assert cli.main(["info", mesh_path("cube")]) == 0
    assert bool(calls) is expected
