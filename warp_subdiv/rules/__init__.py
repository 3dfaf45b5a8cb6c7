"""Subdivision rules as pure functions: stencil weights and role masks, crease sharpness arithmetic, eigen-analysis and
limit masks (docs/rules.md).

Nothing here sees a mesh array, a Warp array or a USD prim: inputs are valences, sector angles, sharpness values and
counts; outputs are weights. The table builders of :mod:`warp_subdiv.tables` decide which rule each child vertex
follows and lay out the weights these functions give.
"""
from .crease import semi_sharp_vertices, vertex_rule
from .weights import (CATMULL_CLARK, CORNER, CREASE, DART, LOOP, SECTOR_CONCAVE, SECTOR_CONVEX, SECTOR_CREASE, SMOOTH,
                      edge_gamma_shift)

__all__ = ["CATMULL_CLARK", "CORNER", "CREASE", "DART", "LOOP", "SECTOR_CONCAVE", "SECTOR_CONVEX", "SECTOR_CREASE",
           "SMOOTH", "edge_gamma_shift", "semi_sharp_vertices", "vertex_rule"]
