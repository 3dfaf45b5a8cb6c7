"""Sharpness arithmetic of semi-sharp creases and corners, on sharpness values only.

The counterpart of OpenSubdiv's ``sdc/crease.h`` (DeRose, Kass, Truong 1998; docs/rules.md section 15.2):
which rule a vertex follows given its sharpness and its number of sharp edges, how sharpness decays from
one level to the next (uniformly or by Chaikin's rule), and the fractional weight that blends a vertex's
rules where they change during a step. Nothing here reads a mesh level or knows stencil weights: inputs are
numpy arrays of sharpness values (edge sharpness (E,), vertex sharpness (V,)), counts, the crease method
and, where a vertex's edges matter, the edges' two end vertices (E, 2) to sum over.
:mod:`warp_subdiv.topology.sharpness` reads these arrays off a level; :mod:`warp_subdiv.rules` turns the chosen rules
and weights into masks.

Sharpness 0 is smooth; :data:`~warp_subdiv.mesh.INFINITE_SHARPNESS` (10) and above is infinitely sharp;
anything in between is semi-sharp.
"""
from __future__ import annotations

import numpy as np

from ..mesh import INFINITE_SHARPNESS
from .weights import CORNER, CREASE, DART, SMOOTH


def is_semi_sharp(sharpness) -> np.ndarray:
    """Whether each sharpness is finite and non-zero (it decays as the levels go)."""
    s = np.asarray(sharpness)
    return (s > 0) & (s < INFINITE_SHARPNESS)


def any_semi_sharp(edge_sharpness, vert_sharpness) -> bool:
    """True when some edge or vertex sharpness is semi-sharp: only then can rules change between levels."""
    return bool(np.any(is_semi_sharp(edge_sharpness)) or np.any(is_semi_sharp(vert_sharpness)))


def vertex_rule(vert_sharpness: np.ndarray, sharp_count: np.ndarray) -> np.ndarray:
    """Vertex class (rules.SMOOTH/DART/CREASE/CORNER, int8) from its sharpness and its number of sharp edges.

    A sharp vertex or one with more than two sharp edges is a corner, two sharp edges make a crease, one a
    dart, none an interior vertex (Sdc::Crease::DetermineVertexVertexRule; docs/rules.md sections 1, 15.2). Also the
    class of an edge's child vertex, with sharpness 0 and the count of its sharp halves."""
    out = np.choose(np.minimum(sharp_count, 3), [SMOOTH, DART, CREASE, CORNER]).astype(np.int8)
    out[vert_sharpness > 0] = CORNER
    return out


def decrement_sharpness(s: np.ndarray) -> np.ndarray:
    """One level of uniform decay: infinite stays infinite, s > 1 becomes s - 1, the rest 0."""
    return np.where(s >= INFINITE_SHARPNESS, INFINITE_SHARPNESS, np.where(s > 1.0, s - 1.0, 0.0))


def semi_sharp_vertices(edge_verts, edge_sharpness, vert_sharpness) -> np.ndarray:
    """Vertices with a semi-sharp (finite, non-zero) sharpness or a semi-sharp incident edge."""
    semi_edge = is_semi_sharp(edge_sharpness)
    out = is_semi_sharp(vert_sharpness)
    out[edge_verts[semi_edge].reshape(-1)] = True
    return out


def child_edge_sharpness(edge_sharpness: np.ndarray, edge_verts: np.ndarray, num_vertices: int,
                         method: str = "uniform") -> np.ndarray:
    """Sharpness of the two child edges of every edge after one step: (E, 2), column j the half at end j.

    ``"uniform"`` decrements by one (both halves alike). ``"chaikin"`` (OpenSubdiv's CREASE_CHAIKIN) gives
    the half at vertex v 3/4 of the edge's sharpness plus 1/4 of the mean of v's other semi-sharp edges,
    minus one, where v has at least two edges and another semi-sharp one; otherwise the uniform value."""
    es = edge_sharpness
    ev = np.asarray(edge_verts, dtype=np.int64)
    decremented = decrement_sharpness(es)
    halves = np.stack([decremented, decremented], axis=1)
    semi = is_semi_sharp(es)
    if method == "chaikin" and np.any(semi):
        ends = ev.reshape(-1)
        valence = np.bincount(ends, minlength=num_vertices)
        semi_sum = np.bincount(ends, weights=np.repeat(np.where(semi, es, 0.0), 2), minlength=num_vertices)
        semi_count = np.bincount(ends, weights=np.repeat(semi.astype(np.float64), 2), minlength=num_vertices)
        for j in (0, 1):
            v = ev[:, j]
            others = semi_count[v] - 1
            chaikin = semi & (valence[v] >= 2) & (others >= 1)
            mean_other = (semi_sum[v] - es) / np.maximum(others, 1)
            value = 0.75 * es + 0.25 * mean_other - 1.0
            halves[:, j] = np.where(chaikin, np.where(value > 0, value, 0.0), halves[:, j])
    return halves


def child_rules(edge_verts: np.ndarray, halves: np.ndarray, child_vertex_sharpness: np.ndarray):
    """Classes after one step: of the vertex children (V,) and of the edge children (E,).

    A vertex child counts the sharp halves ending at it (``halves`` from :func:`child_edge_sharpness`,
    ``child_vertex_sharpness`` from :func:`decrement_sharpness`); an edge child has its two halves as its
    only possibly sharp edges and no sharpness of its own."""
    ev = np.asarray(edge_verts, dtype=np.int64)
    V = len(child_vertex_sharpness)
    count = np.bincount(ev[:, 0], weights=(halves[:, 0] > 0), minlength=V) + np.bincount(
        ev[:, 1], weights=(halves[:, 1] > 0), minlength=V)
    vertex_children = vertex_rule(child_vertex_sharpness, count.astype(np.int64))
    edge_children = vertex_rule(np.zeros(len(ev)), (halves > 0).sum(axis=1))
    return vertex_children, edge_children


def vertex_transitions(parent_rule: np.ndarray, child_rule: np.ndarray) -> np.ndarray:
    """Vertices whose crease or corner rule gives way to another during the step: their child blends the
    parent's and the child's rule with :func:`fractional_weight` (Sdc::Scheme's transitional masks)."""
    return np.isin(parent_rule, [CREASE, CORNER]) & (child_rule != parent_rule)


def edge_transitions(edge_sharp: np.ndarray, edge_child_rule: np.ndarray) -> np.ndarray:
    """Sharp edges whose children are not both sharp: their child point blends the crease and smooth edge
    rules with the edge's sharpness (:func:`warp_subdiv.rules.semi_sharp_edge_weights`)."""
    return edge_sharp & (edge_child_rule != CREASE)


def fractional_weight(edge_verts: np.ndarray, edge_sharpness: np.ndarray, vert_sharpness: np.ndarray,
                      halves: np.ndarray, child_vertex_sharpness: np.ndarray,
                      method: str = "uniform") -> np.ndarray:
    """Weight of the parent rule where a vertex's rule changes during the step (Sdc ComputeFractionalWeight).

    The mean sharpness of the vertex's features that become smooth in this step (its own sharpness, its
    edges whose sharpness ends), at most 1; 0 where none does. Per vertex, (V,)."""
    V = len(vert_sharpness)
    es = edge_sharpness
    ev = np.asarray(edge_verts, dtype=np.int64)
    pv = vert_sharpness
    total = np.where((pv > 0) & (child_vertex_sharpness <= 0), pv, 0.0)
    count = ((pv > 0) & (child_vertex_sharpness <= 0)).astype(np.float64)
    for j in (0, 1):
        if method == "uniform":
            ending = (es > 0) & (es <= 1.0)
        else:
            ending = (es > 0) & (halves[:, j] <= 0)
        total = total + np.bincount(ev[:, j], weights=np.where(ending, es, 0.0), minlength=V)
        count = count + np.bincount(ev[:, j], weights=ending.astype(np.float64), minlength=V)
    return np.where(count > 0, np.minimum(total / np.maximum(count, 1), 1.0), 0.0)
