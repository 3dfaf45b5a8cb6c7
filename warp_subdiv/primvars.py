"""Face-level bookkeeping of a refinement: which control face every refined face comes from, and bilinear
refinement of per-face-corner data.

Both follow the refiner's child order (OpenSubdiv's, see :mod:`warp_subdiv.topology`):

* Catmull-Clark (and bilinear): control corner h of a face becomes child quad h. Its four corners hold, in
  cyclic order: the child of h's vertex, the child of the edge from h to the next corner, the face child, the
  child of the edge from the previous corner to h; children of a quad start at position j (the local index
  of h), as in OpenSubdiv, children of other polygons at 0 (OpenSubdiv) or at j mod 4 (earlier versions of
  the refiner: :func:`rotates_non_quads` asks the refiner which). Every later level splits quad f into quads
  4f..4f+3 by the same rule.
* Loop: polygons are fan-triangulated from their first corner, triangle t becomes triangles 4t..4t+3: child
  j < 3 holds corner j, the midpoint of edge j, the midpoint of edge j-1 (at positions j, j+1, j+2); child 3
  holds the midpoint of edge m+1 at position m.

Uniform primvars and face subsets are mapped through :attr:`FaceMap.parent`; face-varying primvars (and
varying primvars, and the points of bilinear meshes) are refined with :meth:`FaceMap.refine_corners`,
linearly inside every control face.
"""
from __future__ import annotations

import functools

import numpy as np

from .mesh import Mesh, face_offsets_of, next_corner_of
from .topology import triangulate


class FaceMap:
    """The refined faces of ``mesh`` after ``levels`` steps of ``scheme``, and where they come from.

    ``boundary`` matters only for "none", whose faces touching the boundary are left out (as holes are).
    ``parent[i]`` is the control face of refined face i, for the faces the refiner outputs.
    """

    def __init__(self, mesh: Mesh, levels: int, scheme: str, boundary: str = "edge-and-corner"):
        self.levels = int(levels)
        self.scheme = scheme
        counts = mesh.face_vertex_counts.astype(np.int64)
        indices = mesh.face_vertex_indices.astype(np.int64)
        self.control_counts = counts
        hole = np.zeros(len(counts), dtype=bool)
        hole[mesh.holes] = True

        # level 0 as the refiner sees it: Loop fan-triangulates polygons
        if scheme == "loop" and not np.all(counts == 3):
            # the refiner's fan triangulation, applied to corner ids instead of vertex ids
            _, tri_corners, parent0 = triangulate(counts, np.arange(len(indices)))
            self._tri_corners = tri_corners.astype(np.int64)
        else:
            parent0 = np.arange(len(counts))
            self._tri_corners = None
        level0_verts = indices if self._tri_corners is None else indices[self._tri_corners]
        level0_sizes = counts if self._tri_corners is None else np.full(len(parent0), 3, dtype=np.int64)
        drop0 = hole[parent0]
        if boundary == "none" and scheme != "bilinear":
            # OpenSubdiv's VTX_BOUNDARY_NONE: faces that touch a boundary vertex have no limit surface
            edge_faces = np.bincount(mesh.edges.corner_edge, minlength=mesh.num_edges)
            on_boundary = np.zeros(mesh.num_vertices, dtype=bool)
            on_boundary[mesh.edges.edge_verts[edge_faces == 1].reshape(-1)] = True
            level0_face = np.repeat(np.arange(len(level0_sizes)), level0_sizes)
            touches = np.bincount(level0_face[on_boundary[level0_verts]], minlength=len(level0_sizes)) > 0
            drop0 |= touches
        self._level0_sizes = level0_sizes

        # refined face -> level-0 face
        if self.levels == 0:
            origin = np.arange(len(level0_sizes))
        elif scheme == "loop":
            origin = np.repeat(np.arange(len(level0_sizes)), 4 ** self.levels)
        else:
            level1_origin = np.repeat(np.arange(len(level0_sizes)), level0_sizes)
            origin = np.repeat(level1_origin, 4 ** (self.levels - 1))
        self.keep = ~drop0[origin]
        self.parent = parent0[origin[self.keep]]

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
        sizes = self.control_counts
        if self._tri_corners is not None:
            vals = vals[self._tri_corners]
            sizes = self._level0_sizes
        for _ in range(self.levels):
            if self.scheme == "loop":
                vals = _split_triangles(vals)
            else:
                vals = _split_polygons(vals, sizes)
                sizes = np.full(len(vals) // 4, 4, dtype=np.int64)
        out = vals[np.repeat(self.keep, sizes if self.levels == 0 else (3 if self.scheme == "loop" else 4))]
        return out[:, 0] if squeeze else out


def _split_polygons(vals: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """One Catmull-Clark (bilinear) split of per-corner data: corner h -> child quad h."""
    offsets = face_offsets_of(sizes)
    nxt = next_corner_of(sizes, offsets)
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(len(nxt))
    face_mean = np.add.reduceat(vals, offsets[:-1], axis=0) / sizes[:, None]
    corner_face = np.repeat(np.arange(len(sizes)), sizes)
    local = np.arange(len(vals)) - offsets[:-1][corner_face]
    r = local % 4 if rotates_non_quads() else np.where(sizes[corner_face] == 4, local, 0)
    by_type = (vals, 0.5 * (vals + vals[nxt]), face_mean[corner_face], 0.5 * (vals[prv] + vals))
    out = np.empty((4 * len(vals), vals.shape[1]))
    base = 4 * np.arange(len(vals))
    for t, value in enumerate(by_type):
        out[base + (t + r) % 4] = value
    return out


@functools.lru_cache(maxsize=None)
def rotates_non_quads() -> bool:
    """Whether the refiner rotates the child quads of non-quad faces like those of quads (vertex child at
    position j mod 4) or leaves them unrotated (vertex child first, as OpenSubdiv does): one pentagon, one
    level, and where its corner 1's vertex child sits in child quad 1."""
    from .refiner import Refiner

    pentagon = Mesh(np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 5, endpoint=False)]),
                    [5], [0, 1, 2, 3, 4])
    _, indices = Refiner(pentagon, 1, device="cpu").topology()
    return bool(indices.reshape(-1, 4)[1, 1] == 1)


def _split_triangles(vals: np.ndarray) -> np.ndarray:
    """One Loop (linear) split of per-corner triangle data: triangle t -> triangles 4t..4t+3."""
    v = vals.reshape(-1, 3, vals.shape[1])
    mid = [0.5 * (v[:, j] + v[:, (j + 1) % 3]) for j in range(3)]  # edge j runs from corner j to j+1
    out = np.empty((len(v), 4, 3, vals.shape[1]))
    for j in range(3):
        out[:, j, j] = v[:, j]
        out[:, j, (j + 1) % 3] = mid[j]
        out[:, j, (j + 2) % 3] = mid[(j + 2) % 3]
        out[:, 3, j] = mid[(j + 1) % 3]
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
