"""Exceptions and warnings raised by warp-subdiv."""


class SubdivInputError(ValueError):
    """Bad input: the message names the face, vertex, edge or tag at fault."""


class NonManifoldWarning(UserWarning):
    """The mesh has non-manifold edges or vertices; they are treated as OpenSubdiv treats them."""
