"""The tessellation of one cell (a quad or a triangle of a control face's parameterisation) in its own (s, t),
given the rate (number of segments) of each side: a uniform grid where opposite sides agree, else an inner grid
joined to the sides by a ring of triangles, or a fan around the centre of a cell too coarse for an inner grid
(see :mod:`warp_subdiv.limit.tessellation`). Patterns depend on the rates only and are cached.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: Cell kinds: their number of sides.
QUAD, TRI = 4, 3


@dataclass(frozen=True)
class CellPattern:
    """A cell's tessellation in its own (s, t): local vertices are the boundary points (side k, index i;
    i = 0 is corner k), then interior points; faces index them (-1 pads triangles)."""

    boundary: np.ndarray  # (B, 2) int: (side, index)
    interior_st: np.ndarray  # (I, 2)
    boundary_st: np.ndarray  # (B, 2)
    faces: np.ndarray  # (m, 4) int, -1 padded

    @property
    def num_local(self) -> int:
        return len(self.boundary) + len(self.interior_st)


def _side_st(kind: int, k: int, x: float) -> tuple:
    """(s, t) of the point at fraction x along side k of a cell (counter-clockwise sides from corner k)."""
    if kind == QUAD:
        return [(x, 0.0), (1.0, x), (1.0 - x, 1.0), (0.0, 1.0 - x)][k]
    return [(x, 0.0), (1.0 - x, x), (0.0, 1.0 - x)][k]


def _zip(outer: list, inner: list, t_outer: list, t_inner: list) -> list:
    """Triangles joining a side (outer points, parameters along it) to the inner grid's row beside it, both in
    the side's direction; counter-clockwise when the inner row lies to the left."""
    tris = []
    i = j = 0
    while i < len(outer) - 1 or j < len(inner) - 1:
        take_outer = j == len(inner) - 1 or (
            i < len(outer) - 1 and 0.5 * (t_outer[i] + t_outer[i + 1]) <= 0.5 * (t_inner[j] + t_inner[j + 1]))
        if take_outer:
            tris.append((outer[i], outer[i + 1], inner[j]))
            i += 1
        else:
            tris.append((outer[i], inner[j + 1], inner[j]))
            j += 1
    return tris


class _LocalVertices:
    """The local vertices of a cell's pattern: its boundary points (side k, index i < rates[k]), numbered first,
    then interior points numbered as the faces first use them."""

    def __init__(self, kind: int, rates: tuple):
        self.kind = kind
        self.rates = rates
        self.boundary = [(k, i) for k in range(kind) for i in range(rates[k])]
        self.index = {key: m for m, key in enumerate(self.boundary)}
        self.boundary_st = [_side_st(kind, k, i / rates[k]) for k, i in self.boundary]
        self.interior: dict = {}
        self.interior_st: list = []

    def inner(self, key, st) -> int:
        """The interior point ``key`` (at ``st``), numbered on first use."""
        if key not in self.interior:
            self.interior[key] = len(self.boundary) + len(self.interior_st)
            self.interior_st.append(st)
        return self.interior[key]

    def side_point(self, k: int, i: int) -> int:
        """Point i of side k; i may equal rates[k]: the next corner."""
        return self.index[((k + 1) % self.kind, 0)] if i == self.rates[k] else self.index[(k, i)]


def _quad_faces(vertices: _LocalVertices, rates: tuple) -> list:
    """The faces of a quad cell with side rates ``rates``: a uniform grid (quads) where opposite sides agree,
    else the inner grid of the larger rates zipped to the sides, or a fan around the centre."""
    side_point, inner = vertices.side_point, vertices.inner
    faces = []
    r0, r1, r2, r3 = rates
    ru, rv = max(r0, r2), max(r1, r3)

    def grid(a, b, R_u, R_v):  # a point of the uniform (R_u, R_v) grid
        if b == 0:
            return side_point(0, a)
        if a == R_u:
            return side_point(1, b)
        if b == R_v:
            return side_point(2, R_u - a)
        if a == 0:
            return side_point(3, R_v - b)
        return inner((a, b), (a / R_u, b / R_v))

    if r0 == r2 and r1 == r3:
        for b in range(rv):
            for a in range(ru):
                faces.append((grid(a, b, ru, rv), grid(a + 1, b, ru, rv), grid(a + 1, b + 1, ru, rv),
                              grid(a, b + 1, ru, rv)))
    elif ru >= 2 and rv >= 2:
        for b in range(1, rv - 1):
            for a in range(1, ru - 1):
                faces.append((grid(a, b, ru, rv), grid(a + 1, b, ru, rv), grid(a + 1, b + 1, ru, rv),
                              grid(a, b + 1, ru, rv)))
        rows = [[(a, 1) for a in range(1, ru)], [(ru - 1, b) for b in range(1, rv)],
                [(a, rv - 1) for a in range(ru - 1, 0, -1)], [(1, b) for b in range(rv - 1, 0, -1)]]
        along = [lambda a, b: a / ru, lambda a, b: b / rv, lambda a, b: 1 - a / ru, lambda a, b: 1 - b / rv]
        for k in range(4):
            outer = [side_point(k, i) for i in range(rates[k] + 1)]
            t_outer = [i / rates[k] for i in range(rates[k] + 1)]
            row = [grid(a, b, ru, rv) for a, b in rows[k]]
            t_row = [along[k](a, b) for a, b in rows[k]]
            faces.extend(_zip(outer, row, t_outer, t_row))
    else:
        centre = inner("centre", (0.5, 0.5))
        ring = [side_point(k, i) for k in range(4) for i in range(rates[k])]
        faces.extend((ring[m], ring[(m + 1) % len(ring)], centre) for m in range(len(ring)))
    return faces


def _triangle_faces(vertices: _LocalVertices, rates: tuple) -> list:
    """The faces of a triangle cell with side rates ``rates``: the uniform triangle grid where all sides agree,
    else the inner grid of the largest rate zipped to the sides, or a fan around the centre."""
    side_point, inner = vertices.side_point, vertices.inner
    faces = []
    R = max(rates)

    def tri(a, b):  # a point of the uniform rate-R triangle grid, a along s, b along t
        if b == 0:
            return side_point(0, a)
        if a + b == R:
            return side_point(1, b)
        if a == 0:
            return side_point(2, R - b)
        return inner((a, b), (a / R, b / R))

    if rates[0] == rates[1] == rates[2]:
        for b in range(R):
            for a in range(R - b):
                faces.append((tri(a, b), tri(a + 1, b), tri(a, b + 1)))
                if a + b <= R - 2:
                    faces.append((tri(a + 1, b), tri(a + 1, b + 1), tri(a, b + 1)))
    elif R >= 3:
        for b in range(1, R):
            for a in range(1, R - b):
                if a + b <= R - 2:
                    faces.append((tri(a, b), tri(a + 1, b), tri(a, b + 1)))
                if a + b <= R - 3:
                    faces.append((tri(a + 1, b), tri(a + 1, b + 1), tri(a, b + 1)))
        rows = [[(a, 1) for a in range(1, R - 1)], [(R - 1 - b, b) for b in range(1, R - 1)],
                [(1, b) for b in range(R - 2, 0, -1)]]
        along = [lambda a, b: a / R, lambda a, b: b / R, lambda a, b: 1 - b / R]
        for k in range(3):
            outer = [side_point(k, i) for i in range(rates[k] + 1)]
            t_outer = [i / rates[k] for i in range(rates[k] + 1)]
            row = [tri(a, b) for a, b in rows[k]]
            t_row = [along[k](a, b) for a, b in rows[k]]
            faces.extend(_zip(outer, row, t_outer, t_row))
    else:
        centre = inner("centre", (1.0 / 3.0, 1.0 / 3.0))
        ring = [side_point(k, i) for k in range(3) for i in range(rates[k])]
        faces.extend((ring[m], ring[(m + 1) % len(ring)], centre) for m in range(len(ring)))
    return faces


@lru_cache(maxsize=4096)
def cell_pattern(kind: int, rates: tuple, quads: bool) -> CellPattern:
    """The pattern of a cell of ``kind`` (QUAD or TRI) with side rates ``rates``; ``quads``: a quad cell's
    uniform grid as quads (else every face a triangle, quads split along their diagonal (0, 2))."""
    vertices = _LocalVertices(kind, rates)
    faces = _quad_faces(vertices, rates) if kind == QUAD else _triangle_faces(vertices, rates)
    if not quads:  # quads split along their diagonal (0, 2)
        faces = [t for f in faces for t in ([(f[0], f[1], f[2]), (f[0], f[2], f[3])] if len(f) == 4 else [f])]
    out = np.full((len(faces), 4), -1, dtype=np.int64)
    for m, f in enumerate(faces):
        out[m, :len(f)] = f
    return CellPattern(np.array(vertices.boundary, dtype=np.int64).reshape(-1, 2),
                       np.array(vertices.interior_st, dtype=np.float64).reshape(-1, 2),
                       np.array(vertices.boundary_st, dtype=np.float64).reshape(-1, 2), out)
