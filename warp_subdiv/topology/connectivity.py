"""Level 0's connectivity: which corners share each edge, and the fans and rings of corners around each vertex.

The control mesh is the one level whose tables are found by sorting and walking rather than by index arithmetic.
Walks around a vertex (a fan's corners, a sector's corners) are done for all vertices at once by pointer
jumping: every corner follows a link to its clockwise neighbour, and log2(valence) doubling steps reach the
end of every walk.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import face_offsets_of
from .control_faces import BaseFaces


def fan_labels(cw: np.ndarray, ccw: np.ndarray, max_valence: int) -> np.ndarray:
    """Label every corner with the smallest corner of its fan (faces around a vertex joined through edges),
    given each corner's clockwise and counter-clockwise neighbour around its vertex (itself where there is
    none)."""
    label = np.arange(len(cw), dtype=np.int64)
    a, b = cw.copy(), ccw.copy()
    steps = int(np.ceil(np.log2(max(max_valence, 2)))) + 1
    for _ in range(steps):
        label = np.minimum(label, np.minimum(label[a], label[b]))
        a, b = a[a], b[b]
    return label


def list_rank(link: np.ndarray, max_valence: int):
    """Follow ``link`` to its fixed point (pointer jumping): returns (head, distance to head)."""
    idx = np.arange(len(link), dtype=np.int64)
    link = link.astype(np.int64)
    dist = (link != idx).astype(np.int64)
    steps = int(np.ceil(np.log2(max(max_valence, 2)))) + 1
    for _ in range(steps):
        dist = dist + dist[link]
        link = link[link]
    return link, dist


@dataclass
class Connectivity:
    """Level 0's corner, edge and vertex tables, int64, before any sharpness, class or sector."""

    corner_vert: np.ndarray  # (C,) vertex of every corner
    next_corner: np.ndarray  # (C,) the next corner of the same face
    prev_corner: np.ndarray  # (C,) the previous corner of the same face
    corner_edge: np.ndarray  # (C,) edge from this corner to the next one
    edge_verts: np.ndarray  # (E, 2)
    edge_count: np.ndarray  # (E,) corners per edge
    edge_offsets: np.ndarray  # (E+1,)
    edge_corners: np.ndarray  # (C,) corners by edge, in corner order
    twin: np.ndarray  # (C,) the other corner of the corner's edge where that edge is manifold, else -1
    boundary_edge: np.ndarray  # (E,) bool: one face
    nonmanifold_edge: np.ndarray  # (E,) bool
    vert_count: np.ndarray  # (V,) corners per vertex
    vert_offsets: np.ndarray  # (V+1,)
    vert_corners: np.ndarray  # (C,) corners by vertex, counter-clockwise within each fan
    fans: np.ndarray  # (V,) fans per vertex (one unless non-manifold)
    nonmanifold_vert: np.ndarray  # (V,) bool: several fans, or on a non-manifold edge
    max_valence: int


def connectivity(faces: BaseFaces, num_vertices: int) -> Connectivity:
    """The connectivity of level 0's ``faces`` (:func:`~.control_faces.base_faces`)."""
    edges = faces.edges
    C = len(faces.indices)
    corner_vert = faces.indices.astype(np.int64)
    nxt = edges.corner_next.astype(np.int64)
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(C)
    corner_edge = edges.corner_edge.astype(np.int64)
    edge_verts = edges.edge_verts.astype(np.int64)
    ecount, eoff, ecorners, twin, boundary_edge, nonmanifold_edge = _edge_corners(
        corner_vert, nxt, corner_edge, edges.nonmanifold, len(edge_verts))
    vcount, voff, vcorners, fans, max_valence = _vertex_rings(corner_vert, nxt, prv, twin, num_vertices)
    nonmanifold_vert = fans > 1
    nonmanifold_vert[edge_verts[nonmanifold_edge].reshape(-1)] = True
    return Connectivity(corner_vert, nxt, prv, corner_edge, edge_verts, ecount, eoff, ecorners, twin, boundary_edge,
                        nonmanifold_edge, vcount, voff, vcorners, fans, nonmanifold_vert, max_valence)


def _edge_corners(corner_vert, nxt, corner_edge, built_nonmanifold, E: int):
    """Edge -> corners (count, offsets, corners), every corner's twin, and the boundary and non-manifold edges.

    Non-manifold: more than two faces, two faces that agree on orientation, degenerate edges and repeated
    vertex pairs (``built_nonmanifold``, as :func:`~warp_subdiv.mesh.find_edges` flags them; None: none), as
    OpenSubdiv tags them."""
    C = len(corner_vert)
    ecount = np.bincount(corner_edge, minlength=E)
    eoff = face_offsets_of(ecount)
    ecorners = np.argsort(corner_edge, kind="stable")
    first = ecorners[eoff[:-1]]
    second = ecorners[np.minimum(eoff[:-1] + 1, C - 1)]
    two = ecount == 2
    if built_nonmanifold is None:
        built_nonmanifold = np.zeros(E, dtype=bool)
    opposite = two & (corner_vert[first] == corner_vert[nxt[second]]) & ~built_nonmanifold
    boundary_edge = ecount == 1
    nonmanifold_edge = (ecount > 2) | (two & ~opposite) | built_nonmanifold
    twin = np.full(C, -1, dtype=np.int64)
    twin[first[opposite]] = second[opposite]
    twin[second[opposite]] = first[opposite]
    return ecount, eoff, ecorners, twin, boundary_edge, nonmanifold_edge


def _vertex_rings(corner_vert, nxt, prv, twin, num_vertices: int):
    """Vertex -> corners (count, offsets, corners), the number of fans at every vertex and the largest valence.

    A fan is the faces around a vertex joined through shared edges (one per vertex unless non-manifold). The
    corners are listed counter-clockwise within each fan: a boundary fan starts at its face after the boundary,
    a closed fan at its smallest corner."""
    C = len(corner_vert)
    vcount = np.bincount(corner_vert, minlength=num_vertices)
    voff = face_offsets_of(vcount)
    max_valence = int(vcount.max())
    idx = np.arange(C, dtype=np.int64)
    cw = np.where(twin >= 0, nxt[np.maximum(twin, 0)], idx)
    ccw_src = twin[prv]
    ccw = np.where(ccw_src >= 0, ccw_src, idx)
    label = fan_labels(cw, ccw, max_valence)
    fans = np.bincount(corner_vert[label == idx], minlength=num_vertices)

    has_start = np.zeros(C, dtype=bool)
    has_start[label[twin < 0]] = True
    link = np.where((label == idx) & ~has_start[label], idx, cw)
    _, ring_pos = list_rank(link, max_valence)
    if fans.max(initial=0) <= 1:  # one fan per vertex: ring_pos ranks its corners 0..k-1, so place them
        vcorners = np.empty(C, dtype=np.int64)
        vcorners[voff[corner_vert] + ring_pos] = idx
    else:
        vcorners = np.lexsort((ring_pos, label, corner_vert))
    return vcount, voff, vcorners, fans, max_valence
