"""Exceptions and warnings raised by warp-subdiv.

Errors carry structured fields besides their message, so that a front end (the USD reader, the CLI) can
say where the fault is in its own terms (a USD attribute, a command-line option) without parsing text:
``option`` names the keyword of the library call at fault, ``element`` the kind of mesh element ("face",
"vertex", "edge", "corner", "crease", "hole", "normal", "data"), ``index`` which one, ``value`` the value.
The library's messages never name command-line flags.
"""
from __future__ import annotations


class SubdivInputError(ValueError):
    """Bad input: the message names the face, vertex, edge, tag or option at fault.

    Fields (each ``None`` when it does not apply): ``option``, ``element``, ``index``, ``value``.
    """

    def __init__(self, message: str, *, option: str | None = None, element: str | None = None,
                 index: int | None = None, value=None):
        super().__init__(message)
        self.option = option
        self.element = element
        self.index = index
        self.value = value


class NonManifoldWarning(UserWarning):
    """The mesh has non-manifold edges or vertices; they are treated as OpenSubdiv treats them."""
