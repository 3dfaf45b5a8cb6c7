"""Face-varying data (UVs): refinement on its own topology, with OpenSubdiv's FVarLinearInterpolation modes.

A face-varying channel gives every face corner a value index. Its values form their own mesh (the "value
mesh"): the faces the vertex refiner refines (under Loop, a polygon's fan triangles) with the value indices
as vertices, so a seam (an edge whose two faces use different values) is a boundary of the value mesh. The
value mesh is refined by the same engine with OpenSubdiv's rules, edge-only boundaries, the vertex mesh's
creases and corners, and extra corners chosen by the linear-interpolation mode, as OpenSubdiv's
Vtr::FVarLevel chooses them:

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

from ..errors import NonManifoldWarning, SubdivInputError
from ..mesh import INFINITE_SHARPNESS, Mesh, check_rows
from ..options import FaceVaryingMode, Scheme
from ..topology import base_level, triangulate


def check_value_indices(indices, num_corners: int) -> np.ndarray:
    """A channel's value indices as a read-only int64 array, one per face corner (``num_corners``), or
    :class:`SubdivInputError` (``option`` "indices"): not 1-D of that length, not integers, or negative."""
    idx = np.asarray(indices)
    if idx.ndim != 1 or len(idx) != num_corners:
        raise SubdivInputError(
            f"face-varying indices need one entry per face corner ({num_corners}), got shape {idx.shape}",
            option="indices", value=idx.shape,
        )
    if idx.dtype.kind not in "iu" and len(idx):
        raise SubdivInputError(f"face-varying indices must be integers, got dtype {idx.dtype}", option="indices")
    if len(idx) and idx.dtype.kind == "u" and int(idx.max()) > np.iinfo(np.int64).max:
        h = int(np.argmax(idx))
        raise SubdivInputError(f"face-varying index {int(idx[h])} at face corner {h} is too large",
                               option="indices", index=h, value=int(idx[h]))
    idx = idx.astype(np.int64)
    if len(idx) and idx.min() < 0:
        h = int(np.flatnonzero(idx < 0)[0])
        raise SubdivInputError(f"face-varying index {idx[h]} at face corner {h} is negative", option="indices",
                               index=h, value=int(idx[h]))
    idx.flags.writeable = False
    return idx


def value_mesh(mesh: Mesh, indices: np.ndarray, mode: str, boundary: str, scheme: str = Scheme.CATMULL_CLARK):
    """The value mesh of a face-varying channel and, for each of its vertices, the source value index.

    Each (vertex, value) pair becomes one value-mesh vertex, so a value index used at two different vertices
    is two vertices of the value mesh (as OpenSubdiv keeps values per vertex). ``mode``: a
    :class:`~warp_subdiv.options.FaceVaryingMode` or its value. Under ``scheme`` "loop" a polygon mesh is
    analysed (and its value mesh built) on its fan triangles (:func:`~warp_subdiv.topology.triangulate`),
    which is what the Loop refiner refines: vertices and values then follow the same faces.
    """
    mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
    scheme = Scheme.parse(scheme, "scheme")
    idx = check_value_indices(indices, len(mesh.face_vertex_indices))
    if scheme == Scheme.LOOP and not mesh.is_all(3):
        mesh, idx = _fan_triangles(mesh, idx)
    # vertex-level analysis of the control mesh (edges, fans, sharpness) with the geometry's options
    level = base_level(mesh, "catmull-clark", boundary, "opensubdiv")
    cv = mesh.face_vertex_indices.astype(np.int64)
    pid, source, pair_vertex = _value_vertices(level, cv, idx)
    nxt = mesh.edges.corner_next.astype(np.int64)
    value_sharp = _sharp_values(level, mesh.num_vertices, cv, nxt, pid, pair_vertex, mode, boundary)
    return _tagged_value_mesh(mesh, level, pid, nxt, pair_vertex, value_sharp, mode), source


def _value_vertices(level, cv: np.ndarray, idx: np.ndarray):
    """(pid, source, pair_vertex): the value-mesh vertex of every face corner (its (vertex, value) pair), and
    per value-mesh vertex its source value index and its vertex."""
    base = int(idx.max()) + 1 if len(idx) else 1
    pairs, pid = np.unique(cv * base + idx, return_inverse=True)
    pid = pid.reshape(-1)
    source, pair_vertex = pairs % base, pairs // base
    # OpenSubdiv gives a value a second sibling (a vertex of its own) in one pattern, see _repeated_sibling
    again = _repeated_sibling(level, cv, idx)
    if len(again):
        extra, at = np.unique(pid[again], return_inverse=True)
        pid[again] = len(pairs) + at.reshape(-1)
        source = np.concatenate([source, source[extra]])
        pair_vertex = np.concatenate([pair_vertex, pair_vertex[extra]])
    return pid, source, pair_vertex


def _seams(level, cv: np.ndarray, nxt: np.ndarray, pid: np.ndarray):
    """(seam, at_a, at_b): per edge whether it is a seam (an interior edge whose two faces disagree on the
    value at either end), and the value-mesh vertices at its two ends in its first face."""
    ecount = np.diff(level.edge_corner_offsets)
    h0, h1 = level.edge_corner_pair()
    two = ecount == 2
    same_dir = cv[h0] == cv[h1]
    at_a0, at_b0 = pid[h0], pid[nxt[h0]]
    at_a1 = np.where(same_dir, pid[h1], pid[nxt[h1]])
    at_b1 = np.where(same_dir, pid[nxt[h1]], pid[h1])
    return two & ((at_a0 != at_a1) | (at_b0 != at_b1)), at_a0, at_b0


def _sharp_values(level, nv: int, cv: np.ndarray, nxt: np.ndarray, pid: np.ndarray, pair_vertex: np.ndarray,
                  mode: str, boundary: str) -> np.ndarray:
    """(value-mesh vertices,) bool: the values made sharp (interpolated) besides the vertex mesh's corners, as
    Vtr::FVarLevel chooses them for ``mode`` (the module's table). ``nv``: vertices of the mesh."""
    ecount = np.diff(level.edge_corner_offsets)
    ev = level.edge_verts.astype(np.int64)
    seam, at_a0, at_b0 = _seams(level, cv, nxt, pid)
    two = ecount == 2
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

    npairs = len(pair_vertex)
    span = np.bincount(pid, minlength=npairs)  # faces of each value at its vertex
    # A value is "disjoint" (Vtr::FVarLevel's ValueSpan) when its faces around its vertex are not one run
    # joined by unbroken edges: an edge joining two of its faces is broken when it is a seam (its values differ
    # at the other end) or infinitely sharp. Its faces then number more than its unbroken joints plus one.
    # A disjoint value is sharp (in the value mesh it is a non-manifold vertex or a corner anyway), and with
    # dependent sharpness (corners-plus1/2) it makes the other value of its vertex sharp too.
    joined = two & ~seam & (level.edge_sharpness < INFINITE_SHARPNESS)
    joints = np.bincount(np.concatenate([at_a0[joined], at_b0[joined]]), minlength=npairs)
    pv = pair_vertex
    disjoint = mismatch[pv] & (joints < span - 1)
    inf_sharp_vertex = level.vert_sharpness >= INFINITE_SHARPNESS
    all_sharp = mismatch & (linear_boundaries | inf_sharp_vertex | nonmanifold | (dependent & (values_at > 2))
                            | (sharpen_darts & (values_at == 1) & ~vertex_boundary))
    value_sharp = all_sharp[pv] | disjoint | (mismatch[pv] & (span == 1) & corners_sharp)
    if dependent:
        two_values = mismatch & (values_at == 2) & ~all_sharp
        value_sharp |= (two_values & (np.bincount(pv, weights=disjoint, minlength=nv) > 0))[pv]
        if mode == FaceVaryingMode.CORNERS_PLUS2:
            one_face = np.bincount(pv, weights=(span == 1), minlength=nv) > 0
            value_sharp |= (two_values & one_face)[pv]
    if mode == FaceVaryingMode.ALL:
        value_sharp[:] = True
    return value_sharp


def _tagged_value_mesh(mesh: Mesh, level, pid: np.ndarray, nxt: np.ndarray, pair_vertex: np.ndarray,
                       value_sharp: np.ndarray, mode: str) -> Mesh:
    """The value mesh: ``mesh``'s faces over the value-mesh vertices ``pid``, the vertex mesh's creases on the
    corresponding value edges, its corners on all values, the sharp values as corners, its holes."""
    npairs = len(pair_vertex)
    counts = mesh.face_vertex_counts
    edge_of_corner = mesh.edges.corner_edge.astype(np.int64)
    crease_pairs = np.stack([pid, pid[nxt]], axis=1)
    crease_sharp = level.edge_sharpness[edge_of_corner]
    keep = crease_sharp > 0
    corner_ids = np.arange(npairs)
    corner_sharp = np.maximum(level.vert_sharpness[pair_vertex], np.where(value_sharp, INFINITE_SHARPNESS, 0.0))
    keep_c = corner_sharp > 0
    holes = np.flatnonzero(level.face_hole) if level.face_hole is not None else None
    if mode == FaceVaryingMode.ALL:
        crease_sharp = np.full(len(crease_pairs), INFINITE_SHARPNESS)
        keep = np.ones(len(crease_pairs), dtype=bool)
    return Mesh(
        np.zeros((npairs, 3)), counts, pid,
        creases=crease_pairs[keep], crease_sharpness=crease_sharp[keep],
        corners=corner_ids[keep_c], corner_sharpness=corner_sharp[keep_c],
        holes=holes if holes is not None and len(holes) else None,
    )


def _repeated_sibling(level, cv: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Face corners whose value OpenSubdiv counts as a new value of their vertex although the vertex has it.

    Vtr::FVarLevel numbers the values ("siblings") around a vertex in its face order (from its first face, or
    the face after a boundary, across each face's incoming edge: ``level.vert_corners``), run by run, and
    while it has seen two values it adds any run whose value differs from the first value without comparing
    it with the second: where the runs start A, B, A, B the fourth run becomes a third value B (later runs
    find their value). The two B's then refine as separate values (and the vertex has three)."""
    vc = level.vert_corners.astype(np.int64)
    if len(vc) < 4:
        return np.zeros(0, dtype=np.int64)
    verts, vals = cv[vc], idx[vc]
    start = np.ones(len(vc), dtype=bool)
    start[1:] = (verts[1:] != verts[:-1]) | (vals[1:] != vals[:-1])
    first = np.flatnonzero(start)  # first position of every run
    vertex_start = np.ones(len(first), dtype=bool)
    vertex_start[1:] = verts[first[1:]] != verts[first[:-1]]
    rank = np.arange(len(first)) - np.maximum.accumulate(np.where(vertex_start, np.arange(len(first)), 0))
    r = np.flatnonzero(rank == 3)
    r = r[(vals[first[r - 3]] == vals[first[r - 1]]) & (vals[first[r - 2]] == vals[first[r]])]
    if not len(r):
        return np.zeros(0, dtype=np.int64)
    end = np.append(first[1:], len(vc))
    lengths = end[r] - first[r]
    positions = np.repeat(first[r] - np.cumsum(lengths) + lengths, lengths) + np.arange(int(lengths.sum()))
    return vc[positions]


def _fan_triangles(mesh: Mesh, idx: np.ndarray):
    """``mesh`` fan-triangulated as the Loop refiner triangulates it (its tags and holes kept), and the channel's
    indices on the triangles' corners."""
    counts, tri_vertices, parent = triangulate(mesh.face_vertex_counts, mesh.face_vertex_indices)
    _, tri_values, _ = triangulate(mesh.face_vertex_counts, idx)
    holes = np.flatnonzero(np.isin(parent, mesh.holes)) if len(mesh.holes) else None
    tris = Mesh(mesh.points, counts, tri_vertices,
                creases=mesh.creases if len(mesh.creases) else None,
                crease_sharpness=mesh.crease_sharpness if len(mesh.creases) else None,
                corners=mesh.corners, corner_sharpness=mesh.corner_sharpness, holes=holes)
    return tris, tri_values.astype(np.int64)


class FaceVaryingChannel:
    """One face-varying channel (its value indices fixed) of a vertex :class:`~warp_subdiv.refiner.Refiner`,
    which owns it: the value mesh refined with the vertex refiner's options and OpenSubdiv's rules.

    The owning refiner passes itself in (:meth:`Refiner.face_varying_channel`); the value mesh is refined by
    a refiner of the same type, so this module needs no import of :mod:`warp_subdiv.refiner`."""

    def __init__(self, refiner, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        self.mode = mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        mesh, self.source = value_mesh(refiner.mesh, indices, mode, refiner.boundary, refiner.scheme)
        options = refiner.options.replace(rules="opensubdiv", boundary="edge-only", flatness=None,
                                          loop_beta="loop", linear=(mode == FaceVaryingMode.ALL))
        with warnings.catch_warnings():  # disjoint value fans are expected (they become sharp values)
            warnings.simplefilter("ignore", NonManifoldWarning)
            self.refiner = type(refiner)(mesh, refiner.levels, options=options, device=refiner.device)
        self.num_source_values = int(self.source.max()) + 1 if len(self.source) else 0

    def evaluate(self, values):
        """(refined values (M, d), refined face-varying indices int32 aligned with the refined faces)."""
        squeeze = np.ndim(values) == 1
        if np.ndim(values) in (1, 2) and len(values) < self.num_source_values:
            raise SubdivInputError(
                f"face-varying indices refer to value {self.num_source_values - 1} but only {len(values)} values "
                "were given", option="values", element="data", value=len(values),
            )
        vals = check_rows(values, self.num_source_values, "face-varying values", at_least=True)
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
