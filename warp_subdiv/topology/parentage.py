"""Where the children of one refinement step come from: the parentage of every child vertex, face and edge.

The child order of :func:`~.refinement.refine_level` (OpenSubdiv's) makes a step's child-to-parent maps
closed-form index arithmetic over the parent level's counts: :class:`Refinement` states them as rules and
materialises arrays on demand (the conventions are documented in :mod:`warp_subdiv.tables.hierarchy`, which
keeps one per step).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import face_offsets_of
from ..rules import CATMULL_CLARK
from .control_faces import BaseFaces
from .level import Level, face_sizes_of, face_starts_of

#: kinds of parent element a child comes from (the parent type of OpenSubdiv's Vtr::Refinement child tags)
VERTEX, EDGE, FACE = 0, 1, 2


@dataclass(frozen=True, eq=False)
class Refinement:
    """Where the children of one refinement step come from, as rules over the parent level's counts.

    OpenSubdiv's ``Vtr::Refinement`` stores ``_childFaceParentIndex``, ``_childEdgeParentIndex``,
    ``_childVertexParentIndex`` and a tag per child. Here the child order of :func:`~.refinement.refine_level`
    makes them closed-form index arithmetic, so a step keeps its parent's counts and materialises arrays only when
    asked.
    The one stored array is ``face_offsets`` of a parent with mixed polygons (only the control mesh has them),
    of control size. The conventions are listed in :mod:`warp_subdiv.tables.hierarchy`.
    """

    scheme: str
    num_vertices: int  # of the parent level
    num_faces: int
    num_edges: int
    num_corners: int
    face_size: int  # 3 or 4 when every parent face has that size, 0 for mixed polygons
    face_offsets: np.ndarray | None = None  # (F+1,) int64, mixed polygons only

    @classmethod
    def of_level(cls, level: Level) -> "Refinement":
        """The step that refines ``level`` (which needs its edges: not a faces-only level)."""
        return cls(level.scheme, level.num_vertices, level.num_faces, level.num_edges, level.num_corners,
                   level.face_size, None if level.face_size else level.face_offsets)

    @classmethod
    def of_faces(cls, scheme: str, num_vertices: int, faces: BaseFaces) -> "Refinement":
        """The step that refines level 0, from :func:`base_faces` alone (no analysis)."""
        size = faces.face_size
        return cls(scheme, num_vertices, len(faces.counts), len(faces.edges.edge_verts), len(faces.indices), size,
                   None if size else face_offsets_of(faces.counts))

    def next(self) -> "Refinement":
        """The step after this one (its parent is this step's child level: all quads or all triangles)."""
        return Refinement(self.scheme, self.child_vertices, self.child_faces, self.child_edges, self.child_corners,
                          4 if self.scheme == CATMULL_CLARK else 3)

    # ---------------------------------------------------------------------------------------- child counts
    @property
    def child_vertices(self) -> int:
        """[vertex children V, face children F (Catmull-Clark only), edge children E]."""
        face_children = self.num_faces if self.scheme == CATMULL_CLARK else 0
        return self.num_vertices + face_children + self.num_edges

    @property
    def child_faces(self) -> int:
        """One per parent corner (Catmull-Clark: C) or four per triangle (Loop: 4F)."""
        return self.num_corners if self.scheme == CATMULL_CLARK else 4 * self.num_faces

    @property
    def child_edges(self) -> int:
        """[one inside a parent face per parent corner (C), two halves per parent edge (2E)]."""
        return self.num_corners + 2 * self.num_edges

    @property
    def child_corners(self) -> int:
        return 4 * self.num_corners

    @property
    def children_per_face(self) -> int:
        """Child faces per parent face where that number is fixed (4 for Loop and quads, 3 for a Catmull-Clark
        step over triangles), else 0: then ``child // children_per_face`` is the parent face."""
        return 4 if self.scheme != CATMULL_CLARK else self.face_size

    # ---------------------------------------------------------------------------------------- parent faces
    def face_sizes(self) -> np.ndarray:
        """(F,) int64: corners of every parent face."""
        return face_sizes_of(self)

    def face_starts(self) -> np.ndarray:
        """(F,) int64: first corner of every parent face."""
        return face_starts_of(self)

    def corner_faces(self) -> np.ndarray:
        """(C,) int64: the parent face of every parent corner."""
        if self.face_size:
            return np.arange(self.num_corners, dtype=np.int64) // self.face_size
        return np.repeat(np.arange(self.num_faces, dtype=np.int64), np.diff(self.face_offsets))

    def parent_face_of(self, child_faces: np.ndarray) -> np.ndarray:
        """The parent face of each of ``child_faces`` (int64), without the slot arrays of :meth:`face_parent`."""
        child_faces = np.asarray(child_faces, dtype=np.int64)
        n = self.children_per_face
        return child_faces // n if n else self.corner_faces()[child_faces]

    # ---------------------------------------------------------------------------------------- maps
    def vertex_ranges(self) -> tuple:
        """((kind, first child, number of children), ...) in the child vertex order: the rule behind
        :meth:`vertex_parent` (child ``first + i`` of a range comes from parent element ``i`` of ``kind``)."""
        V, F, E = self.num_vertices, self.num_faces, self.num_edges
        if self.scheme == CATMULL_CLARK:
            return (VERTEX, 0, V), (FACE, V, F), (EDGE, V + F, E)
        return (VERTEX, 0, V), (EDGE, V, E)

    def vertex_parent(self):
        """(kind int8, index int64) of every child vertex: the parent vertex, face or edge it comes from."""
        ranges = self.vertex_ranges()
        kind = np.concatenate([np.full(n, k, dtype=np.int8) for k, _, n in ranges])
        index = np.concatenate([np.arange(n, dtype=np.int64) for _, _, n in ranges])
        return kind, index

    def face_parent(self):
        """(face, slot) int64 of every child face: its parent face, and which of that face's children it is.

        Catmull-Clark: child face h is the child of parent corner h, ``slot`` that corner's place in its face.
        Loop: child 4f + s of triangle f; s < 3 is the child at corner s, s = 3 the middle triangle."""
        if self.scheme != CATMULL_CLARK or self.face_size:
            n = self.children_per_face
            c = np.arange(self.child_faces, dtype=np.int64)
            return c // n, c % n
        face = self.corner_faces()
        return face, np.arange(self.num_corners, dtype=np.int64) - self.face_offsets[face]

    def face_rotation(self) -> np.ndarray:
        """(child faces,) int64: the position r in each child face of its parent corner's vertex child.

        Catmull-Clark (OpenSubdiv's order): children of a quad are rotated, r = slot; children of other
        polygons are not, r = 0. Loop: r = s for the corner children; the middle child has r = 0."""
        face, slot = self.face_parent()
        if self.scheme == CATMULL_CLARK:
            if self.face_size:
                return slot if self.face_size == 4 else np.zeros_like(slot)
            return np.where(self.face_sizes()[face] == 4, slot, 0)
        return np.where(slot < 3, slot, 0)

    def edge_parent(self):
        """(kind int8, index int64, slot int64) of every child edge.

        Child edge h < C lies inside parent face ``index`` (kind FACE) at its corner ``slot`` (parent corner h:
        Catmull-Clark joins the face child to the child of the edge leaving h, Loop the children of the edges
        leaving and entering h). Child edge C + 2e + s (kind EDGE) is the half of parent edge e at its end s,
        joining the child of that end vertex to the child of e."""
        C, E = self.num_corners, self.num_edges
        face = self.corner_faces()
        inner_slot = np.arange(C, dtype=np.int64) - self.face_starts()[face]
        halves = np.arange(2 * E, dtype=np.int64)
        kind = np.concatenate([np.full(C, FACE, dtype=np.int8), np.full(2 * E, EDGE, dtype=np.int8)])
        return kind, np.concatenate([face, halves // 2]), np.concatenate([inner_slot, halves % 2])
