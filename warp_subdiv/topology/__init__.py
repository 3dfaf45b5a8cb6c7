"""The topology of each level, by index arithmetic: the control mesh's analysis (edges, vertex rules, sectors), the
refinement of a level into the next, and the parentage of every child.

Rules come from :mod:`warp_subdiv.rules`; nothing here knows a stencil weight, a Warp array or a USD prim.
"""
from .refinement import (EDGE, Level, Refinement, VERTEX, base_faces, base_level, child_rules,
                         child_sharpness, fractional_weight, has_semi_sharpness, refine_level, triangulate)

__all__ = ["EDGE", "Level", "Refinement", "VERTEX", "base_faces", "base_level", "child_rules",
           "child_sharpness", "fractional_weight", "has_semi_sharpness", "refine_level", "triangulate"]
