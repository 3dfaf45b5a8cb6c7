"""Face-varying channels (UVs) on a :class:`~warp_subdiv.limit.LimitSurface`: as OpenSubdiv's Bfr builds a
face-varying surface per face, a channel is the limit surface of its value mesh (the same faces, seams as
boundaries, the interpolation mode's sharp values; :func:`~warp_subdiv.tables.value_mesh`), evaluated at the
same (face, u, v) as the surface.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import NonManifoldWarning
from ..mesh import Mesh
from ..options import FaceVaryingMode
from ..tables import check_value_indices, value_mesh
from ..topology import triangulate
from .parameterisation import FAN
from .results import DataEvaluation


@dataclass
class FaceVaryingChannel:
    """A channel's value indices (one per face corner) under ``mode``: ``num_values`` values, and except under
    mode "all" the value mesh's limit surface (``surface``) with the value of each of its vertices
    (``source``)."""

    mode: FaceVaryingMode
    indices: np.ndarray
    num_values: int
    surface: object | None = None
    source: np.ndarray | None = None

    @classmethod
    def of(cls, surface, indices, mode: FaceVaryingMode, cached: FaceVaryingChannel | None = None):
        """The channel of ``indices`` under ``mode`` on ``surface``: ``cached`` when it is the same channel,
        else built (the value mesh's topology and patch tree)."""
        idx = check_value_indices(indices, len(surface.mesh.face_vertex_indices))
        if cached is not None and cached.mode == mode and cached.indices.tobytes() == idx.tobytes():
            return cached
        num_values = int(idx.max()) + 1 if len(idx) else 0
        channel = cls(mode, idx, num_values)
        if mode != FaceVaryingMode.ALL:
            channel.surface, channel.source = _value_surface(surface, idx, mode)
        return channel

    def evaluate(self, surface, values, faces_a, u_a, v_a, derivatives: int, one_d: bool) -> DataEvaluation:
        """``values`` (num values, k) on the value mesh's limit surface at checked queries of ``surface``."""
        f2, u2, v2, scale = _to_value_faces(surface, faces_a, u_a, v_a)
        with warnings.catch_warnings():  # disjoint value fans are expected (they become sharp values)
            warnings.simplefilter("ignore", NonManifoldWarning)
            res = self.surface.evaluate_data(values[self.source], f2, u2, v2, derivatives=derivatives)
        if derivatives:
            res.du = res.du * (scale if res.du.ndim == 1 else scale[:, None])
            res.dv = res.dv * (scale if res.dv.ndim == 1 else scale[:, None])
        if one_d:
            res.values = res.values[:, 0]
            if derivatives:
                res.du, res.dv = res.du[:, 0], res.dv[:, 0]
        return res


def _value_surface(surface, idx: np.ndarray, mode: FaceVaryingMode) -> tuple:
    """(the limit surface of the value mesh of ``idx`` under ``mode``, the value of each of its vertices), of the
    same class, depth and device as ``surface``, under OpenSubdiv's rules."""
    o = surface.options
    vm, source = value_mesh(surface.mesh, idx, mode, o.boundary, o.scheme)
    verts = np.asarray(surface.mesh.face_vertex_indices, dtype=np.int64)
    if len(vm.face_vertex_indices) != len(verts):  # Loop polygons: the value mesh is on fan triangles
        verts = triangulate(surface.mesh.face_vertex_counts, verts)[1].reshape(-1).astype(np.int64)
    geometry = np.zeros((vm.num_vertices, 3))
    # the geometry of each value vertex is its vertex's: the end caps' tangent planes use it (the value
    # mesh's rules are OpenSubdiv's, which no geometry changes)
    geometry[np.asarray(vm.face_vertex_indices, dtype=np.int64)] = np.asarray(surface.mesh.points)[verts]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        mesh = Mesh(geometry, vm.face_vertex_counts, vm.face_vertex_indices,
                    creases=vm.creases if len(vm.creases) else None,
                    crease_sharpness=vm.crease_sharpness if len(vm.creases) else None,
                    corners=vm.corners if len(vm.corners) else None,
                    corner_sharpness=vm.corner_sharpness if len(vm.corners) else None,
                    holes=vm.holes if len(vm.holes) else None)
        options = o.replace(rules="opensubdiv", boundary="edge-only", flatness=None, loop_beta="loop")
        value_surface = type(surface)(mesh, depth=surface.depth, options=options, device=surface.device)
    return value_surface, source


def _to_value_faces(surface, faces_a, u_a, v_a):
    """(face, u, v, derivative scale) on the value mesh: the same faces, except that a Loop polygon's value
    mesh holds its fan triangles (the kernel's tile choice: triangle k at u in [k, k + 1), nearest beyond). A
    fan triangle's own coordinates are twice the face's, and so would be a query's round-off outside it: such
    queries are moved onto the domain first (as the kernel clamps them), so that the value mesh accepts them."""
    scale = np.ones(len(faces_a))
    fan = surface.face_kind[faces_a] == FAN
    if not fan.any():
        return faces_a, u_a, v_a, scale
    u_a, v_a = surface._parameterisation.onto_domain(faces_a, u_a, v_a)
    counts = np.asarray(surface.mesh.face_vertex_counts, dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts - 2)[:-1]])
    tu = np.floor(u_a)
    tu = np.where(u_a - tu > 0.75, tu + 1, tu)
    k = np.where(fan, np.clip(tu.astype(np.int64), 0, np.maximum(counts[faces_a] - 3, 0)), 0)
    f2 = first[faces_a] + k
    u2 = np.where(fan, 2.0 * (u_a - k), u_a)
    v2 = np.where(fan, 2.0 * v_a, v_a)
    scale[fan] = 2.0
    return f2, u2, v2, scale
