"""Level 0's faces as the refiner sees them, before any analysis, and the sharpness the mesh's tags give them.

Loop fan-triangulates polygons (:func:`triangulate`); under boundary "none" the faces without a limit surface
join the holes. :func:`base_faces` is cheap (no fans, classes or sectors): the analysis of the control mesh
(:mod:`.analysis`) starts from it, and so do the parentage rules of level 0 (:mod:`.parentage`) and the face
bookkeeping of :mod:`warp_subdiv.tables.face_map`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SubdivInputError
from ..mesh import INFINITE_SHARPNESS, Mesh, MeshEdges, expand_counts, face_offsets_of, find_edges
from ..options import Boundary
from ..rules import LOOP


def triangulate(counts: np.ndarray, indices: np.ndarray):
    """Fan-triangulate every polygon from its first corner: (v0, v_i, v_i+1), i = 1..n-2.

    Returns (counts, indices, parent face of each triangle). Polygon edges stay edges, so crease and
    concave tags given as vertex pairs keep their meaning; the diagonals are new smooth edges.
    """
    counts = np.asarray(counts, dtype=np.int64)
    offsets = face_offsets_of(counts)
    parent, i = expand_counts(counts - 2)
    start = offsets[parent]
    tri = np.stack([indices[start], indices[start + i + 1], indices[start + i + 2]], axis=1)
    return np.full(len(parent), 3, dtype=np.int32), tri.reshape(-1).astype(np.int32), parent


@dataclass
class BaseFaces:
    """Level 0's faces as the refiner sees them, before any analysis: Loop fan-triangulates polygons, and
    under boundary "none" the faces without a limit surface join the holes."""

    counts: np.ndarray  # (F,) corners per face
    indices: np.ndarray  # (C,) vertex of every corner
    edges: MeshEdges  # the mesh's own edges, or those of its triangulation
    control_face: np.ndarray | None  # (F,) control polygon of each triangle; None: face f is control face f
    face_hole: np.ndarray  # (F,) bool

    @property
    def face_size(self) -> int:
        """3 or 4 when every face has that size, else 0 (:attr:`Level.face_size`)."""
        counts = self.counts
        return int(counts[0]) if np.all(counts == counts[0]) and int(counts[0]) in (3, 4) else 0


def base_faces(mesh: Mesh, scheme: str, boundary: str = "edge-and-corner",
               triangulate_polygons: bool = True) -> BaseFaces:
    """The faces, edges and holes of level 0 (cheap: no fans, classes or sectors), shared by
    :func:`~.analysis.base_level` and the face bookkeeping of :mod:`warp_subdiv.tables.face_map`."""
    nv = mesh.num_vertices
    counts = mesh.face_vertex_counts
    indices = mesh.face_vertex_indices
    edges: MeshEdges = mesh.edges
    control_face = None
    if scheme == LOOP and not mesh.is_all(3):
        if not triangulate_polygons:
            bad = int(np.flatnonzero(counts != 3)[0])
            raise SubdivInputError(
                f"Loop subdivision needs triangles: face {bad} has {counts[bad]} vertices "
                "(pass triangulate=True to fan-triangulate polygons)"
            )
        counts, indices, control_face = triangulate(counts, indices)
        edges = find_edges(counts, indices, nv)
    face_hole = np.zeros(mesh.num_faces, dtype=bool)
    face_hole[mesh.holes] = True
    if control_face is not None:
        face_hole = face_hole[control_face]
    if boundary == Boundary.NONE:
        # OpenSubdiv's VTX_BOUNDARY_NONE: a face touching a vertex with an untagged boundary edge has no
        # limit surface and is left out (boundaries tagged infinitely sharp keep their faces)
        E = len(edges.edge_verts)
        boundary_edge = np.bincount(edges.corner_edge, minlength=E) == 1
        untagged = boundary_edge & (tagged_edge_sharpness(mesh, edges) < INFINITE_SHARPNESS)
        open_vertex = np.zeros(nv, dtype=bool)
        open_vertex[edges.edge_verts[untagged].reshape(-1)] = True
        F = len(counts)
        touches = open_vertex[indices]
        face_hole |= np.bincount(np.repeat(np.arange(F), counts)[touches], minlength=F) > 0
    return BaseFaces(counts, indices, edges, control_face, face_hole)


def last_tag_values(size: int, ids: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(size,) float64: ``values[i]`` at ``ids[i]``, 0 where untagged; where an id is tagged more than once
    the last tag wins, as in OpenSubdiv's and USD's tag lists."""
    out = np.zeros(size, dtype=np.float64)
    if len(ids):
        ids = np.asarray(ids, dtype=np.int64)
        uniq, first_from_end = np.unique(ids[::-1], return_index=True)
        out[uniq] = np.asarray(values, dtype=np.float64)[len(ids) - 1 - first_from_end]
    return out


def tagged_edge_sharpness(mesh: Mesh, edges: MeshEdges) -> np.ndarray:
    """(E,) float64: the sharpness the mesh's crease tags give ``edges`` (the mesh's own or a triangulation's),
    0 elsewhere; the last tag's where an edge is tagged twice (either orientation), as in OpenSubdiv."""
    if not len(mesh.creases):
        return np.zeros(len(edges.edge_verts), dtype=np.float64)
    tagged = edges.find(mesh.creases, mesh.num_vertices) if edges is not mesh.edges else mesh.crease_edges
    return last_tag_values(len(edges.edge_verts), tagged, mesh.crease_sharpness)
