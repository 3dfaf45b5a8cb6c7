"""Publishing finished output files, shared by the OBJ, USD and PNG writers; no pxr here, so that writing an OBJ
file loads no USD.

Every output is written to a temporary file beside it and renamed over it at the end, so that a failed run leaves
no partial file. ``tempfile.mkstemp`` creates that file readable by its owner only (0600), and a rename keeps
the mode: :func:`publish` gives it the permissions ``open()`` would have given the output first.
"""
from __future__ import annotations

import os


def current_umask() -> int:
    """The process's file mode creation mask. Linux states it in /proc/self/status; elsewhere it is read by
    setting it and setting it back (``os.umask`` has no way to only read it)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    umask = os.umask(0o077)
    os.umask(umask)
    return umask


def publish(tmp: str, output: str) -> None:
    """Rename the finished temporary file ``tmp`` over ``output``, with the permissions a new file would get
    (0666 less the umask) or those of the file it replaces, as writing ``output`` with ``open()`` would give."""
    try:
        mode = os.stat(output).st_mode & 0o7777
    except OSError:
        mode = 0o666 & ~current_umask()
    os.chmod(tmp, mode)
    os.replace(tmp, output)


__all__ = ["current_umask", "publish"]
