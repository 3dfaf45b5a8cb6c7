"""Face-level bookkeeping of a refinement: which control face every refined face comes from, and bilinear
refinement of per-face-corner data.

Both read the refinement's recorded parentage (:class:`warp_subdiv.tables.hierarchy.Parentage`: child faces, their
parents and the rotation of their corners; conventions in :mod:`warp_subdiv.tables.hierarchy`), either a refiner's
own (``FaceMap(..., hierarchy=refiner.hierarchy)``) or one built from the mesh's faces alone, without analysing
it. Bilinear meshes follow Catmull-Clark's child order, and Loop fan-triangulates polygons first.

Uniform primvars and face subsets are mapped through :attr:`FaceMap.parent`; face-varying primvars (and
varying primvars, and the points of bilinear meshes) are refined with :meth:`FaceMap.refine_corners`,
linearly inside every control face.
"""
from __future__ import annotations

import numpy as np

from .hierarchy import Parentage
from ..mesh import Mesh
from ..options import Boundary, Scheme
from ..rules import CATMULL_CLARK
from ..topology import Refinement, triangulate


class FaceMap:
    """The refined faces of ``mesh`` after ``levels`` steps of ``scheme`` ("catmull-clark", "loop" or
    "bilinear"), and where they come from.

    ``boundary`` matters only for "none", whose faces touching an untagged boundary are left out (as holes
    are). ``parent[i]`` is the control face of refined face i, for the faces the refiner outputs; ``keep``
    says which of all refined faces (holes included) those are. ``hierarchy``: the refiner's
    :class:`~warp_subdiv.tables.hierarchy.Hierarchy` of at least ``levels`` levels, whose recorded parentage is read
    instead of being derived from the mesh's faces (same result, no second pass over the mesh).
    """

    def __init__(self, mesh: Mesh, levels: int, scheme: str, boundary: str = "edge-and-corner", *,
                 hierarchy=None):
        self.levels = int(levels)
        self.scheme = scheme
        split = Scheme.LOOP if scheme == Scheme.LOOP else Scheme.CATMULL_CLARK  # bilinear: Catmull-Clark's order
        if hierarchy is None:
            if scheme == "bilinear":
                boundary = Boundary.EDGE_AND_CORNER  # every face of a bilinear mesh has a limit surface
            parentage = Parentage.of_mesh(mesh, self.levels, split, boundary)
        else:
            if hierarchy.options.scheme != split or hierarchy.levels < self.levels:
                raise ValueError(f"the hierarchy ({hierarchy.options.scheme}, {hierarchy.levels} levels) does not "
                                 f"hold {self.levels} levels of {scheme}")
            parentage = hierarchy.parentage
        self.parentage = parentage
        counts = mesh.face_vertex_counts.astype(np.int64)
        self.control_counts = counts
        if parentage.control_face is not None:  # Loop's fan triangulation, applied to corner ids
            _, tri_corners, _ = triangulate(counts, np.arange(int(counts.sum())))
            self._tri_corners = tri_corners.astype(np.int64)
            self._level0_sizes = np.full(len(parentage.control_face), 3, dtype=np.int64)
        else:
            self._tri_corners = None
            self._level0_sizes = counts

        origin = parentage.base_face_of(self.levels)  # refined face -> level-0 face
        self.keep = ~parentage.base_face_hole[origin]
        self.parent = parentage.to_control(origin[self.keep])

    @property
    def num_faces(self) -> int:
        return len(self.parent)

    def check(self, refined_counts) -> None:
        """Raise RuntimeError if the refiner's output has a different number of faces than this map."""
        if len(refined_counts) != self.num_faces:
            raise RuntimeError(
                f"internal error: the face map predicts {self.num_faces} refined faces, the refiner made "
                f"{len(refined_counts)}"
            )

    def refine_corners(self, values: np.ndarray) -> np.ndarray:
        """Per-corner data of the control faces (C, d) -> per-corner data of the refined faces (C_L, d).

        Linear inside every control face: the child of a vertex keeps its value, the child of an edge takes
        the mean of the edge's two corners, a face child the mean of the face's corners.
        """
        vals = np.asarray(values, dtype=np.float64)
        squeeze = vals.ndim == 1
        if squeeze:
            vals = vals[:, None]
        if len(vals) != int(self.control_counts.sum()):
            raise ValueError(f"need one value per face corner ({int(self.control_counts.sum())}), got {len(vals)}")
        if self._tri_corners is not None:
            vals = vals[self._tri_corners]
        sizes = self._level0_sizes
        for level in range(1, self.levels + 1):
            step = self.parentage.refinement(level)
            if step.scheme == CATMULL_CLARK:
                vals = _split_polygons(vals, step)
            else:
                vals = _split_triangles(vals, step)
            sizes = 4 if step.scheme == CATMULL_CLARK else 3
        out = vals[np.repeat(self.keep, sizes)]
        return out[:, 0] if squeeze else out


def _split_polygons(vals: np.ndarray, step: Refinement) -> np.ndarray:
    """One Catmull-Clark (bilinear) split of per-corner data: parent corner h -> child quad h, its corners
    [vertex child, edge h's child, face child, edge h-1's child] starting at the step's rotation."""
    if step.face_size:  # faces of one size: neighbours by rolling, no index arrays
        n, d = step.face_size, vals.shape[1]
        v = vals.reshape(-1, n, d)
        at_next = np.roll(v, -1, axis=1).reshape(-1, d)
        at_prev = np.roll(v, 1, axis=1).reshape(-1, d)
        face_mean = np.repeat(np.add.reduceat(vals, step.face_starts(), axis=0) / n, n, axis=0)
    else:
        face, slot = step.face_parent()  # child quad h = parent corner h
        sizes = step.face_sizes()
        starts = step.face_starts()
        n = sizes[face]
        at_next = vals[starts[face] + (slot + 1) % n]
        at_prev = vals[starts[face] + (slot - 1) % n]
        face_mean = (np.add.reduceat(vals, starts, axis=0) / sizes[:, None])[face]
    r = step.face_rotation()
    by_type = (vals, 0.5 * (vals + at_next), face_mean, 0.5 * (at_prev + vals))
    out = np.empty((4 * len(vals), vals.shape[1]))
    base = 4 * np.arange(len(vals))
    for t, value in enumerate(by_type):
        out[base + (t + r) % 4] = value
    return out


def _split_triangles(vals: np.ndarray, step: Refinement) -> np.ndarray:
    """One Loop (linear) split of per-corner triangle data: triangle t -> triangles 4t..4t+3. Child s < 3
    holds [corner s, the midpoint of edge s, the midpoint of edge s-1] from the step's rotation on; the middle
    child holds the midpoint of edge m+1 at position m + its rotation."""
    v = vals.reshape(-1, 3, vals.shape[1])
    F = len(v)
    mid = [0.5 * (v[:, j] + v[:, (j + 1) % 3]) for j in range(3)]  # edge j runs from corner j to j+1
    r = step.face_rotation().reshape(F, 4)
    rows = np.arange(F)
    out = np.empty((F, 4, 3, vals.shape[1]))
    for s in range(3):
        for t, value in enumerate((v[:, s], mid[s], mid[(s + 2) % 3])):
            out[rows, s, (t + r[:, s]) % 3] = value
    for m in range(3):
        out[rows, 3, (m + r[:, 3]) % 3] = mid[(m + 1) % 3]
    return out.reshape(-1, vals.shape[1])


def corners_to_vertices(corner_values: np.ndarray, refined_indices: np.ndarray, num_vertices: int,
                        fill: np.ndarray | None = None) -> np.ndarray:
    """Scatter per-corner data of a continuous (linear) field to the refined vertices.

    Vertices no output face uses (those only hole faces touch) take their row of ``fill`` (or 0).
    """
    vals = np.asarray(corner_values)
    out = np.zeros((num_vertices,) + vals.shape[1:], dtype=np.float64) if fill is None else np.array(
        fill, dtype=np.float64, copy=True)
    out[np.asarray(refined_indices, dtype=np.int64)] = vals
    return out


def vertices_used(refined_indices: np.ndarray, num_vertices: int) -> bool:
    """True when every refined vertex is a corner of some output face."""
    used = np.zeros(num_vertices, dtype=bool)
    used[np.asarray(refined_indices, dtype=np.int64)] = True
    return bool(used.all())
