"""The tables one refinement step is evaluated from: :class:`StencilTable` (explicit CSR rows over the parent
level's vertices) and :class:`RegularTables` (the smooth rows of a uniform level as index tables, the others as
a :class:`StencilTable`).

Data only, as OpenSubdiv's ``far/stencilTable.h``: :mod:`warp_subdiv.tables.stencil_builder` builds them from a
level's topology and the rules. Rows follow the child vertex order of :mod:`warp_subdiv.topology` (vertex
children, face children for Catmull-Clark, edge children). Weights are float64.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class StencilTable:
    """Child vertex i = sum_j weights[j] * parent[indices[j]] for j in offsets[i]..offsets[i+1]."""

    offsets: np.ndarray  # (rows+1,) int32
    indices: np.ndarray  # (entries,) int32
    weights: np.ndarray  # (entries,) float64
    num_sources: int
    rows: np.ndarray | None = None  # the child vertices the rows are for, when not all of them in order

    @property
    def num_rows(self) -> int:
        return len(self.offsets) - 1

    def nbytes(self, weight_bytes: int = 4) -> int:
        """Bytes of the table on the device with weights of ``weight_bytes`` each."""
        extra = 0 if self.rows is None else self.rows.nbytes
        return self.offsets.nbytes + self.indices.nbytes + len(self.weights) * weight_bytes + extra

    def row(self, i: int) -> dict:
        """Row i as {parent vertex: total weight} (duplicates merged); for tests and debugging."""
        out: dict = {}
        for j in range(int(self.offsets[i]), int(self.offsets[i + 1])):
            key = int(self.indices[j])
            out[key] = out.get(key, 0.0) + float(self.weights[j])
        return out


def rows_of(offsets: np.ndarray) -> np.ndarray:
    """Row id of every entry of CSR rows with the given offsets."""
    return np.repeat(np.arange(len(offsets) - 1, dtype=np.int64), np.diff(offsets))


@dataclass
class RegularTables:
    """What the regular kernels need to compute the smooth rows of one step from the level's index tables.

    Uniform levels only (all quads or all triangles). Only what index arithmetic cannot give is stored: on a
    level of quads corner h belongs to face h // 4 and its next corner is h - h % 4 + (h + 1) % 4, so an edge
    is its two corners (its endpoints, the corner vertex and the next one, and its faces follow) and a
    vertex's ring is its corners (each one's next vertex and its face's face point); triangles keep each
    edge's four vertices and each vertex's ring vertices. ``vertex_regular`` and ``edge_regular`` (uint8)
    mark the rows the kernels compute, and are empty where every row is regular; every other row is in
    ``explicit``. ``ring_weights`` are per-valence weights (centre, each ring term) from
    :mod:`warp_subdiv.rules`; ``edge_weights`` are the smooth edge weights (each endpoint, each wing term).
    """

    face_size: int
    num_vertices: int
    num_faces: int
    corner_vert: np.ndarray  # quads: the level's face corners (empty for triangles: their kernels never read it)
    edge_neighbours: np.ndarray  # quads (E, 2): the edge's two corners; triangles (E, 4): a, b, opposite 0, 1
    vert_corner_offsets: np.ndarray
    ring: np.ndarray  # per vertex (CSR by vert_corner_offsets): quads its corners, triangles its ring vertices
    vertex_regular: np.ndarray  # (V,) uint8, or (0,): every vertex row is regular
    edge_regular: np.ndarray  # (E,) uint8, or (0,): every edge row is regular
    ring_weights: np.ndarray  # (max valence + 1, 2)
    edge_weights: np.ndarray  # (2,)
    explicit: StencilTable
    num_rows: int  # child vertices of the step

    @property
    def num_edges(self) -> int:
        return len(self.edge_neighbours)

    def nbytes(self, weight_bytes: int = 4) -> int:
        """Bytes of the tables the kernels read on the device (the weights per valence aside)."""
        arrays = (self.corner_vert, self.edge_neighbours, self.vert_corner_offsets, self.ring,
                  self.vertex_regular, self.edge_regular)
        return sum(a.nbytes for a in arrays) + self.explicit.nbytes(weight_bytes)
