"""The topology of one subdivision level as flat index tables, and the one constructor of complete levels.

A :class:`Level` stores faces as corners (a corner is a face's use of a vertex, and also the half-edge from
that vertex to the next corner's vertex), edges with their corners, vertices with their corners, the vertex
classes of docs/rules.md section 1, and the sectors of crease and corner vertices with their angle theta.
The control mesh's analysis (:mod:`.analysis`) and every refinement step (:mod:`.refinement`) build their
levels with :func:`full_level`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


def face_sizes_of(faces) -> np.ndarray:
    """(F,) int64: corners of every face of ``faces`` (a level, or the parent of a step: ``face_size``, 0 for
    mixed polygons, ``num_faces``, ``face_offsets``)."""
    if faces.face_size:
        return np.full(faces.num_faces, faces.face_size, dtype=np.int64)
    return np.diff(faces.face_offsets)


def face_starts_of(faces) -> np.ndarray:
    """(F,) int64: the first corner of every face of ``faces`` (as :func:`face_sizes_of`)."""
    if faces.face_size:
        return np.arange(faces.num_faces, dtype=np.int64) * faces.face_size
    return faces.face_offsets[:-1]


def _i32(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int32)


@dataclass
class Level:
    """Topology of one level. Arrays are int32 unless noted; C = number of corners."""

    scheme: str
    num_vertices: int
    num_faces: int
    face_size: int  # 3 or 4 when every face has that size, 0 for mixed polygons (control mesh only)
    corner_vert: np.ndarray  # (C,)
    face_hole: np.ndarray  # (F,) bool
    # the rest is absent on a "faces only" level (the last one, which nothing refines further)
    face_offsets: np.ndarray | None = None  # (F+1,) int64, only for mixed polygons
    corner_next_table: np.ndarray | None = None  # (C,), only for mixed polygons
    corner_edge: np.ndarray | None = None  # (C,) edge from this corner to the next one
    edge_verts: np.ndarray | None = None  # (E, 2)
    edge_corner_offsets: np.ndarray | None = None  # (E+1,) int64
    edge_corners: np.ndarray | None = None  # (C,) corners whose edge is e
    vert_corner_offsets: np.ndarray | None = None  # (V+1,) int64
    vert_corners: np.ndarray | None = None  # (C,) corners at v
    edge_sharp: np.ndarray | None = None  # (E,) bool: sharpness > 0
    vert_class: np.ndarray | None = None  # (V,) int8, rules.SMOOTH/DART/CREASE/CORNER
    edge_sharpness: np.ndarray | None = None  # (E,) float64: 0 smooth, >= 10 infinitely sharp
    vert_sharpness: np.ndarray | None = None  # (V,) float64
    crease_method: str = "uniform"  # how semi-sharp edges decay: "uniform" (by 1) or "chaikin"
    linear: bool = False  # every vertex a corner and every edge sharp on every level: bilinear refinement
    semi_sharp: bool | None = None  # cached: does any edge or vertex have a finite, non-zero sharpness?
    # sectors of crease and corner vertices (docs/rules.md section 0): corners listed counter-clockwise from
    # the face after the first crease edge; theta and kind per docs/rules.md section 2; flatness s (NaN:
    # optimal s*)
    sector_vertex: np.ndarray | None = None  # (S,)
    sector_offsets: np.ndarray | None = None  # (S+1,) int64
    sector_corners: np.ndarray | None = None  # (sum k,)
    sector_theta: np.ndarray | None = None  # (S,) float64
    sector_kind: np.ndarray | None = None  # (S,) int8, rules.SECTOR_*
    sector_flatness: np.ndarray | None = None  # (S,) float64
    # (S,) bool: the sector's limit normal is reversed (two opposite corner sectors, docs/rules.md section 9)
    sector_flip: np.ndarray | None = None
    degenerate_edges: bool = False  # some edge has one vertex at both ends (level 0 only)
    # level 0 of a fan-triangulated polygon mesh (Loop) only: the control polygon of each triangle
    control_face: np.ndarray | None = None  # (F,) int64; None: face f is control face f

    @property
    def num_corners(self) -> int:
        return len(self.corner_vert)

    @property
    def num_edges(self) -> int:
        return len(self.edge_verts)

    def face_sizes(self) -> np.ndarray:
        return face_sizes_of(self)

    def face_starts(self) -> np.ndarray:
        return face_starts_of(self)

    def corner_face(self, h=None) -> np.ndarray:
        if self.face_size:
            if h is None:
                h = np.arange(self.num_corners, dtype=np.int64)
            return h // self.face_size
        # mixed polygons: every corner's face, found once (a repeat, not a search per call) and kept
        every = self.__dict__.get("_corner_face")
        if every is None:
            every = np.repeat(np.arange(self.num_faces, dtype=np.int64), np.diff(self.face_offsets))
            every.flags.writeable = False
            self.__dict__["_corner_face"] = every
        return every if h is None else every[h]

    def corner_next(self, h: np.ndarray) -> np.ndarray:
        if self.face_size:
            n = self.face_size
            j = h % n
            return h - j + (j + 1) % n
        return self.corner_next_table[h]

    def corner_prev(self, h: np.ndarray) -> np.ndarray:
        if self.face_size:
            n = self.face_size
            j = h % n
            return h - j + (j + n - 1) % n
        f = self.corner_face(h)
        start = self.face_offsets[f]
        end = self.face_offsets[f + 1]
        return np.where(h == start, end - 1, h - 1)

    def at_next(self, values: np.ndarray) -> np.ndarray:
        """``values[corner_next(h)]`` for every corner h (``values``: one per corner). On a level of one face
        size this is a rotation inside each face: no index array, one output array."""
        if self.face_size:
            v = values.reshape(-1, self.face_size)
            out = np.empty_like(v)
            out[:, :-1] = v[:, 1:]
            out[:, -1] = v[:, 0]
            return out.reshape(-1)
        return values[self.corner_next_table]

    def at_prev(self, values: np.ndarray) -> np.ndarray:
        """``values[corner_prev(h)]`` for every corner h, as :meth:`at_next`."""
        if self.face_size:
            v = values.reshape(-1, self.face_size)
            out = np.empty_like(v)
            out[:, 1:] = v[:, :-1]
            out[:, 0] = v[:, -1]
            return out.reshape(-1)
        return values[self.corner_prev(np.arange(self.num_corners, dtype=np.int64))]

    @property
    def num_sectors(self) -> int:
        return 0 if self.sector_vertex is None else len(self.sector_vertex)

    def sector_k(self) -> np.ndarray:
        """Crease degree k (number of faces) of every sector."""
        return np.diff(self.sector_offsets)

    def corner_theta(self, corners=None) -> np.ndarray:
        """theta of the sector that holds each of ``corners`` (default: all), NaN at corners outside sectors.

        Looked up among the (few) sector corners, so asking for some corners costs no per-corner array."""
        query = np.arange(self.num_corners) if corners is None else np.asarray(corners, dtype=np.int64)
        members = self.sector_corners.astype(np.int64)
        if len(members) == 0:
            return np.full(len(query), np.nan)
        order = np.argsort(members)
        sorted_members = members[order]
        theta = np.repeat(self.sector_theta, self.sector_k())[order]
        pos = np.minimum(np.searchsorted(sorted_members, query), len(members) - 1)
        return np.where(sorted_members[pos] == query, theta[pos], np.nan)

    def edge_corner_pair(self, threads: int = 1):
        """(h0, h1): the first and second corner of every edge (h1 = h0 on boundary edges), int32; gathered on
        ``threads`` threads."""
        from ..runtime.threads import take

        eoff = self.edge_corner_offsets
        h0 = take(self.edge_corners, eoff[:-1], threads)
        h1 = take(self.edge_corners, np.minimum(eoff[:-1] + 1, len(self.edge_corners) - 1), threads)
        return h0, h1

    def face_vertex_counts(self) -> np.ndarray:
        return self.face_sizes().astype(np.int32)


class Sectors(NamedTuple):
    """The sector tables of a level (the ``sector_*`` fields of :class:`Level`)."""

    vertex: np.ndarray  # (S,)
    offsets: np.ndarray  # (S+1,) int64
    corners: np.ndarray  # (sum k,)
    theta: np.ndarray  # (S,) float64
    kind: np.ndarray  # (S,) int8
    flatness: np.ndarray  # (S,) float64
    flip: np.ndarray | None = None  # (S,) bool; None: no sector is flipped


def full_level(scheme, num_vertices: int, face_size: int, corner_vert, face_hole, *, corner_edge, edge_verts,
               edge_corner_offsets, edge_corners, vert_corner_offsets, vert_corners, vert_class, edge_sharpness,
               vert_sharpness, sectors: Sectors, crease_method, linear: bool,
               face_offsets=None, corner_next_table=None, control_face=None) -> Level:
    """A level with all its tables: the one constructor of full levels, for the control mesh's analysis and
    every refinement step alike. Index arrays become int32 (no copy when they already are); the face count
    and ``edge_sharp`` follow from the other tables."""
    return Level(
        scheme=scheme,
        num_vertices=num_vertices,
        num_faces=len(face_hole),
        face_size=face_size,
        corner_vert=_i32(corner_vert),
        face_hole=face_hole,
        face_offsets=face_offsets,
        corner_next_table=None if corner_next_table is None else _i32(corner_next_table),
        corner_edge=_i32(corner_edge),
        edge_verts=_i32(edge_verts),
        edge_corner_offsets=edge_corner_offsets,
        edge_corners=_i32(edge_corners),
        vert_corner_offsets=vert_corner_offsets,
        vert_corners=_i32(vert_corners),
        edge_sharp=edge_sharpness > 0,
        vert_class=vert_class,
        edge_sharpness=edge_sharpness,
        vert_sharpness=vert_sharpness,
        crease_method=crease_method,
        linear=linear,
        sector_vertex=_i32(sectors.vertex),
        sector_offsets=sectors.offsets,
        sector_corners=_i32(sectors.corners),
        sector_theta=sectors.theta,
        sector_kind=sectors.kind,
        sector_flatness=sectors.flatness,
        sector_flip=np.zeros(len(sectors.vertex), bool) if sectors.flip is None else sectors.flip,
        control_face=control_face,
    )
