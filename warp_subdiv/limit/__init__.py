"""The limit surface: exact evaluation at any (face, u, v) from a tree of patches (Bezier patches of regular
regions, exact eigen-masks at extraordinary vertices), and watertight tessellation of the limit surface by uniform
or per-edge rates.
"""
from .parameterisation import DIRECT, DOMAIN_TOLERANCE, FAN, SUBFACES, corner_weights
from .results import DataEvaluation, LimitEvaluation
from .surface import DEFAULT_DEPTH, LimitSurface
from .tessellation import MAX_RATE, Tessellation, edge_curves, tessellate

__all__ = ["LimitSurface", "LimitEvaluation", "DataEvaluation", "Tessellation", "tessellate", "corner_weights",
           "DEFAULT_DEPTH", "DIRECT", "SUBFACES", "FAN", "DOMAIN_TOLERANCE", "edge_curves", "MAX_RATE"]
