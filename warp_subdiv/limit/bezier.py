"""Bezier forms of the patch tree's patches: the lattices of the regular patches' control points, and the
conversion of regular patches (uniform bicubic B-spline under Catmull-Clark, quartic box spline under Loop) to
Bezier control points (16 bicubic, 15 quartic triangular).
"""
from __future__ import annotations

import numpy as np

from ..rules import CATMULL_CLARK

#: Uniform cubic B-spline to Bezier, one direction: Bezier b_a = sum_i QUAD_BEZIER[a, i] p_i.
QUAD_BEZIER = np.array([[1, 4, 1, 0], [0, 4, 2, 0], [0, 2, 4, 0], [0, 1, 4, 1]], dtype=np.float64) / 6.0

#: Lattice coordinates (i along u, j along v) of the 16 B-spline control points of a quad patch, in the order
#: (i + 1) + 4 (j + 1): the face is [0, 1]^2 with corners (0,0), (1,0), (1,1), (0,1).
QUAD_GRID = [(i, j) for j in range(-1, 3) for i in range(-1, 3)]

#: Lattice coordinates of the 12 box-spline control points of a triangle (corners (0,0), (1,0), (0,1)) on the
#: triangular lattice with edge directions (1,0), (0,1), (-1,1).
TRI_RING = [(0, 0), (1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1), (2, 0), (1, 1), (2, -1), (0, 2), (-1, 2)]

#: Exponents (a, b, c) of (w0, w1, w2) = (1 - u - v, u, v) of the 15 quartic Bezier control points, in order.
TRI_BEZIER_INDEX = [(a, b, 4 - a - b) for a in range(4, -1, -1) for b in range(4 - a, -1, -1)]

#: Quartic box spline (the regular Loop patch) to quartic Bezier: rows TRI_BEZIER_INDEX, columns TRI_RING,
#: times 1/24. Derived as the unique refinable solution of Loop's regular rules (tests/test_limit_surface.py
#: derives it again from the stencils and de Casteljau subdivision).
LOOP_BEZIER = np.array([
    [12, 2, 2, 2, 2, 2, 2, 0, 0, 0, 0, 0],
    [12, 4, 3, 1, 0, 1, 3, 0, 0, 0, 0, 0],
    [12, 3, 4, 3, 1, 0, 1, 0, 0, 0, 0, 0],
    [8, 8, 4, 0, 0, 0, 4, 0, 0, 0, 0, 0],
    [10, 6, 6, 1, 0, 0, 1, 0, 0, 0, 0, 0],
    [8, 4, 8, 4, 0, 0, 0, 0, 0, 0, 0, 0],
    [4, 12, 3, 0, 0, 0, 3, 0, 1, 1, 0, 0],
    [6, 10, 6, 0, 0, 0, 1, 0, 1, 0, 0, 0],
    [6, 6, 10, 1, 0, 0, 0, 0, 1, 0, 0, 0],
    [4, 3, 12, 3, 0, 0, 0, 0, 1, 0, 0, 1],
    [2, 12, 2, 0, 0, 0, 2, 2, 2, 2, 0, 0],
    [3, 12, 4, 0, 0, 0, 1, 1, 3, 0, 0, 0],
    [4, 8, 8, 0, 0, 0, 0, 0, 4, 0, 0, 0],
    [3, 4, 12, 1, 0, 0, 0, 0, 3, 0, 1, 0],
    [2, 2, 12, 2, 0, 0, 0, 0, 2, 0, 2, 2],
], dtype=np.float64) / 24.0


def _lattice_lookup(points) -> tuple:
    """(offset, size, table): table[(i + offset) * size + (j + offset)] = index of lattice point (i, j) or -1."""
    offset, size = 3, 8
    table = np.full(size * size, -1, dtype=np.int64)
    for n, (i, j) in enumerate(points):
        table[(i + offset) * size + (j + offset)] = n
    return offset, size, table


QUAD_LOOKUP = _lattice_lookup(QUAD_GRID)
TRI_LOOKUP = _lattice_lookup(TRI_RING)


def _combine(weights: np.ndarray, src: np.ndarray) -> np.ndarray:
    """out[:, k] = sum_i weights[k, i] src[:, i] for src (F, I, D), term by term in the order of i: every
    column is computed by the same operations whatever D is (a data column equal to a position column gives
    the same bits; a matrix product or einsum may sum differently for other widths)."""
    out = np.zeros((src.shape[0], weights.shape[0]) + src.shape[2:])
    for k in range(weights.shape[0]):
        for i in np.flatnonzero(weights[k]):
            out[:, k] += weights[k, i] * src[:, i]
    return out


def regular_bezier(control: np.ndarray, scheme: str) -> np.ndarray:
    """Bezier control points (F, 16 or 15, D) of regular patches from their B-spline / box-spline points."""
    D = control.shape[-1]
    if scheme == CATMULL_CLARK:
        g = control.reshape(-1, 4, 4, D)  # [j, i]
        rows = _combine(QUAD_BEZIER, np.ascontiguousarray(g.transpose(0, 2, 1, 3)))  # [a (u), j]
        b = _combine(QUAD_BEZIER, np.ascontiguousarray(rows.transpose(0, 2, 1, 3)))  # [b (v), a (u)]
        return b.reshape(-1, 16, D)
    return _combine(LOOP_BEZIER, control)
