"""A level's sharpness after one step, read off the level (OpenSubdiv's Sdc::Crease semantics; DeRose, Kass,
Truong 1998).

The arithmetic on sharpness values is :mod:`warp_subdiv.rules.crease`'s; these functions hand it a level's
arrays, and skip it where nothing is semi-sharp (then no rule changes between levels). The stencils of a step
(:mod:`warp_subdiv.tables.stencils`) and the child level (:mod:`.refinement`) read the same values.
"""
from __future__ import annotations

import numpy as np

from ..rules import CREASE, SMOOTH
from ..rules import crease
from .level import Level


def has_semi_sharpness(level: Level) -> bool:
    """True when some edge or vertex of the level has a finite, non-zero sharpness (cached on the level)."""
    if level.semi_sharp is None:
        level.semi_sharp = crease.any_semi_sharp(level.edge_sharpness, level.vert_sharpness)
    return level.semi_sharp


def child_sharpness(level: Level):
    """Sharpness after one step: (halves (E, 2) -- the child of edge e at its end j --, vertex children (V,)).

    Uniform creasing decrements by one. Chaikin creasing (OpenSubdiv's CREASE_CHAIKIN) gives the child at
    vertex v 3/4 of the edge's sharpness plus 1/4 of the mean of v's other semi-sharp edges, minus one.
    Without semi-sharp features nothing changes (0 stays 0, infinite stays infinite)."""
    if not has_semi_sharpness(level):
        return np.repeat(level.edge_sharpness[:, None], 2, axis=1), level.vert_sharpness
    halves = crease.child_edge_sharpness(level.edge_sharpness, level.edge_verts, level.num_vertices,
                                         level.crease_method)
    return halves, crease.decrement_sharpness(level.vert_sharpness)


def level_child_rules(level: Level, halves: np.ndarray, child_vertex_sharpness: np.ndarray):
    """Classes of the vertex children (V,) and edge children (E,) of ``level`` after one step
    (:func:`warp_subdiv.rules.crease.child_rules` on the level's edges; ``halves`` and
    ``child_vertex_sharpness`` from :func:`child_sharpness`)."""
    if not has_semi_sharpness(level):  # rules do not change: vertex children keep theirs
        return level.vert_class, np.where(level.edge_sharp, CREASE, SMOOTH).astype(np.int8)
    return crease.child_rules(level.edge_verts, halves, child_vertex_sharpness)


def level_fractional_weight(level: Level, halves: np.ndarray, child_vertex_sharpness: np.ndarray) -> np.ndarray:
    """Weight of the parent rule, per vertex of ``level``, where a vertex's rule changes during this step
    (:func:`warp_subdiv.rules.crease.fractional_weight` on the level's sharpness, with its crease method)."""
    return crease.fractional_weight(level.edge_verts, level.edge_sharpness, level.vert_sharpness, halves,
                                    child_vertex_sharpness, level.crease_method)
