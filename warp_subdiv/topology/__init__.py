"""The topology of each level, by index arithmetic: the control mesh's analysis (edges, vertex rules, sectors), the
refinement of a level into the next, and the parentage of every child.

:mod:`.level` holds a level's tables; :mod:`.control_faces`, :mod:`.connectivity`, :mod:`.sectors` and
:mod:`.analysis` build level 0; :mod:`.refinement` derives each later level, with the sharpness decay of
:mod:`.sharpness`; :mod:`.parentage` states where each child comes from. Rules come from
:mod:`warp_subdiv.rules`; nothing here knows a stencil weight, a Warp array or a USD prim.
"""
from .analysis import base_level
from .control_faces import base_faces, triangulate
from .level import Level
from .parentage import EDGE, FACE, VERTEX, Refinement
from .refinement import refine_level
from .sharpness import child_sharpness, has_semi_sharpness, level_child_rules, level_fractional_weight

__all__ = ["EDGE", "FACE", "Level", "Refinement", "VERTEX", "base_faces", "base_level", "child_sharpness",
           "has_semi_sharpness", "level_child_rules", "level_fractional_weight", "refine_level", "triangulate"]
