"""Face-varying data (UVs): refinement on its own topology, with OpenSubdiv's FVarLinearInterpolation modes.

A face-varying channel gives every face corner a value index. Its values form their own mesh (the "value
mesh"): faces as in the vertex mesh, with the value indices as vertices, so a seam (an edge whose two faces
use different values) is a boundary of the value mesh. The value mesh is refined by the same engine with
OpenSubdiv's rules, edge-only boundaries, the vertex mesh's creases and corners, and extra corners chosen by
the linear-interpolation mode, as OpenSubdiv's Vtr::FVarLevel chooses them:

=================  ===================================================================================
mode               values made sharp (interpolated) besides the vertex mesh's own corners
=================  ===================================================================================
``none``           none: seams and boundaries are smooth B-spline curves of their values
``corners-only``   values whose faces around their vertex number one (corners of a UV island)
``corners-plus1``  also every value of a vertex with more than two values (USD's default)
``corners-plus2``  also seam ends inside the mesh (darts) and both values where one is a corner
``boundaries``     every value on a seam or on the mesh boundary (boundaries are linear)
``all``            everything: bilinear interpolation
=================  ===================================================================================
"""
from __future__ import annotations

import warnings

import numpy as np

from .errors import NonManifoldWarning, SubdivInputError
from .mesh import INFINITE_SHARPNESS, Mesh
from .options import FaceVaryingMode
from .topology import base_level


def value_mesh(mesh: Mesh, indices: np.ndarray, mode: str, boundary: str):
    """The value mesh of a face-varying channel and, for each of its vertices, the source value index.

    Each (vertex, value) pair becomes one value-mesh vertex, so a value index used at two different vertices
    is two vertices of the value mesh (as OpenSubdiv keeps values per vertex). ``mode``: a
    :class:`~warp_subdiv.options.FaceVaryingMode` or its value.
    """
    mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
    idx = np.asarray(indices)
    if idx.ndim != 1 or len(idx) != len(mesh.face_vertex_indices):
        raise SubdivInputError(
            f"face-varying indices need one entry per face corner ({len(mesh.face_vertex_indices)}), got "
            f"{np.shape(indices)}"
        )
    if idx.dtype.kind not in "iu":
        raise SubdivInputError("face-varying indices must be integers")
    if len(idx) and idx.min() < 0:
        h = int(np.flatnonzero(idx < 0)[0])
        raise SubdivInputError(f"face-varying index {idx[h]} at face corner {h} is negative")
    idx = idx.astype(np.int64)
    # vertex-level analysis of the control mesh (edges, fans, sharpness) with the geometry's options
    level = base_level(mesh, "catmull-clark", boundary, "opensubdiv")
    cv = mesh.face_vertex_indices.astype(np.int64)
    nv = mesh.num_vertices
    base = int(idx.max()) + 1 if len(idx) else 1
    pairs, pid = np.unique(cv * base + idx, return_inverse=True)
    pid = pid.reshape(-1)
    source, pair_vertex = pairs % base, pairs // base
    npairs = len(pairs)

    nxt = mesh.edges.corner_next.astype(np.int64)
    ecount = np.diff(level.edge_corner_offsets)
    h0, h1 = level.edge_corner_pair()
    ev = level.edge_verts.astype(np.int64)
    # seams: an interior edge whose two faces disagree on the value at either end
    two = ecount == 2
    same_dir = cv[h0] == cv[h1]
    at_a0, at_b0 = pid[h0], pid[nxt[h0]]
    at_a1 = np.where(same_dir, pid[h1], pid[nxt[h1]])
    at_b1 = np.where(same_dir, pid[nxt[h1]], pid[h1])
    seam = two & ((at_a0 != at_a1) | (at_b0 != at_b1))
    boundary_edge = ecount == 1
    vertex_boundary = np.zeros(nv, dtype=bool)
    vertex_boundary[ev[boundary_edge].reshape(-1)] = True
    faces_at = np.bincount(cv, minlength=nv)
    values_at = np.bincount(pair_vertex, minlength=nv)
    nonmanifold = np.zeros(nv, dtype=bool)
    nonmanifold[ev[ecount > 2].reshape(-1)] = True

    linear_boundaries = mode in (FaceVaryingMode.BOUNDARIES, FaceVaryingMode.ALL)
    dependent = mode in (FaceVaryingMode.CORNERS_PLUS1, FaceVaryingMode.CORNERS_PLUS2)
    corners_sharp = mode != FaceVaryingMode.NONE
    smooth_geometry_corners = boundary != "edge-and-corner"
    sharpen_darts = mode == FaceVaryingMode.CORNERS_PLUS2 or linear_boundaries

    mismatch = np.zeros(nv, dtype=bool)
    mismatch[ev[seam].reshape(-1)] = True
    mismatch |= vertex_boundary & linear_boundaries & (faces_at > 0)
    mismatch |= vertex_boundary & (faces_at == 1) & smooth_geometry_corners & corners_sharp

    span = np.bincount(pid, minlength=npairs)  # faces of each value at its vertex
    # (a value whose faces around its vertex are not one fan, "disjoint", is a non-manifold vertex of the
    # value mesh, which the refiner makes a corner)
    inf_sharp_vertex = level.vert_sharpness >= INFINITE_SHARPNESS
    all_sharp = mismatch & (linear_boundaries | inf_sharp_vertex | nonmanifold | (dependent & (values_at > 2))
                            | (sharpen_darts & (values_at == 1) & ~vertex_boundary))
    pv = pair_vertex
    value_sharp = all_sharp[pv] | (mismatch[pv] & (span == 1) & corners_sharp)
    if dependent:
        two_values = mismatch & (values_at == 2) & ~all_sharp
        if mode == FaceVaryingMode.CORNERS_PLUS2:
            one_face = np.bincount(pv, weights=(span == 1), minlength=nv) > 0
            value_sharp |= (two_values & one_face)[pv]
    if mode == FaceVaryingMode.ALL:
        value_sharp[:] = True

    # the value mesh: the vertex mesh's creases on the corresponding value edges, its corners on all values
    counts = mesh.face_vertex_counts
    edge_of_corner = mesh.edges.corner_edge.astype(np.int64)
    crease_pairs = np.stack([pid, pid[nxt]], axis=1)
    crease_sharp = level.edge_sharpness[edge_of_corner]
    keep = crease_sharp > 0
    corner_ids = np.arange(npairs)
    corner_sharp = np.maximum(level.vert_sharpness[pv], np.where(value_sharp, INFINITE_SHARPNESS, 0.0))
    keep_c = corner_sharp > 0
    holes = np.flatnonzero(level.face_hole) if level.face_hole is not None else None
    if mode == FaceVaryingMode.ALL:
        crease_sharp = np.full(len(crease_pairs), INFINITE_SHARPNESS)
        keep = np.ones(len(crease_pairs), dtype=bool)
    vm = Mesh(
        np.zeros((npairs, 3)), counts, pid,
        creases=crease_pairs[keep], crease_sharpness=crease_sharp[keep],
        corners=corner_ids[keep_c], corner_sharpness=corner_sharp[keep_c],
        holes=holes if holes is not None and len(holes) else None,
    )
    return vm, source


class FaceVaryingChannel:
    """One face-varying channel (its value indices fixed) of a vertex :class:`~warp_subdiv.refiner.Refiner`,
    which owns it: the value mesh refined with the vertex refiner's options and OpenSubdiv's rules.

    The owning refiner passes itself in (:meth:`Refiner.face_varying_channel`); the value mesh is refined by
    a refiner of the same type, so this module needs no import of :mod:`warp_subdiv.refiner`."""

    def __init__(self, refiner, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        self.mode = mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        mesh, self.source = value_mesh(refiner.mesh, indices, mode, refiner.boundary)
        options = refiner.options.replace(rules="opensubdiv", boundary="edge-only", flatness=None,
                                          loop_beta="loop", linear=(mode == FaceVaryingMode.ALL))
        with warnings.catch_warnings():  # disjoint value fans are expected (they become sharp values)
            warnings.simplefilter("ignore", NonManifoldWarning)
            self.refiner = type(refiner)(mesh, refiner.levels, options=options, device=refiner.device)
        self.num_source_values = int(self.source.max()) + 1 if len(self.source) else 0

    def evaluate(self, values):
        """(refined values (M, d), refined face-varying indices int32 aligned with the refined faces)."""
        vals = np.asarray(values, dtype=np.float64)
        squeeze = vals.ndim == 1
        if squeeze:
            vals = vals[:, None]
        if len(vals) < self.num_source_values:
            raise SubdivInputError(
                f"face-varying indices refer to value {self.num_source_values - 1} but only {len(vals)} values "
                "were given"
            )
        out = self.refiner.evaluate(vals[self.source], normal_control=False)
        _, indices = self.refiner.topology()
        return (out[:, 0] if squeeze else out), indices

    def limit(self, values):
        """Limit values of the refined channel (OpenSubdiv's LimitFaceVarying): the limit masks of the value
        mesh, whose sharp values and seams are the channel's. Returns (values (M, d), indices)."""
        refined, indices = self.evaluate(values)
        flat = refined[:, None] if refined.ndim == 1 else refined
        columns = []
        for c in range(0, flat.shape[1], 3):  # limit masks act on 3 columns at a time
            block = np.zeros((len(flat), 3))
            block[:, :min(3, flat.shape[1] - c)] = flat[:, c:c + 3]
            columns.append(self.refiner.limit_points(block)[:, :min(3, flat.shape[1] - c)])
        out = np.concatenate(columns, axis=1)
        return (out[:, 0] if refined.ndim == 1 else out), indices
