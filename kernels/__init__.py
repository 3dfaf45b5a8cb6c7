"""Warp kernels of warp-subdiv (installed as ``warp_subdiv.kernels``).

Kernels know nothing about creases or schemes: they apply tables that :mod:`warp_subdiv.tables` built.
"""
from .stencil import apply_stencils_vec, apply_stencils_rows, STENCIL_OVERLOADS  # noqa: F401
