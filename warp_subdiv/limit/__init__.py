"""The limit surface: exact evaluation at any (face, u, v) from a tree of patches (Bezier patches of regular regions,
exact eigen-masks at extraordinary vertices), and tessellation of the limit surface by uniform or per-edge rates.
"""
from .surface import LimitEvaluation, LimitSurface
from .tessellation import tessellate_file

__all__ = ["LimitEvaluation", "LimitSurface", "tessellate_file"]
