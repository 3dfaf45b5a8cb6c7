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
from ..mesh import INFINITE_SHARPNESS, Mesh, check_rows, faces_with_repeats
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
    tags = _ValueTags(mesh, indices, mode, boundary, scheme)
    return tags.mesh(), tags.source


class _ValueTags:
    """What a value mesh is built from: the analysed mesh (the fan triangles of a polygon mesh under Loop), its
    value-mesh vertex per face corner (``pid``), and per value-mesh vertex its source value index, its vertex
    and its corner sharpness (the vertex mesh's, infinite for the values the mode makes sharp)."""

    def __init__(self, mesh: Mesh, indices, mode: str, boundary: str, scheme: str, control_level=None):
        self.mode = mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        scheme = Scheme.parse(scheme, "scheme")
        idx = check_value_indices(indices, len(mesh.face_vertex_indices))
        if scheme == Scheme.LOOP and not mesh.is_all(3):
            mesh, idx = _fan_triangles(mesh, idx)
        self.analysed = mesh
        # vertex-level analysis of the control mesh (edges, fans, sharpness) with the geometry's options: the
        # vertex refiner's own (``control_level``) where it has one; the rule set changes only its sectors
        level = control_level
        if level is None:
            level = base_level(mesh, "catmull-clark", boundary, "opensubdiv")
        self.level = level
        cv = mesh.face_vertex_indices.astype(np.int64)
        self.nxt = mesh.edges.corner_next.astype(np.int64)
        self.unshared = _unshared(idx)
        if self.unshared:  # every value used by one corner only (unindexed UVs): the tags in closed form
            self.pid, self.source, self.pair_vertex = _unshared_value_vertices(cv, idx)
            value_sharp = _unshared_sharp_values(level, mesh.num_vertices, cv, self.nxt, self.pid,
                                                 self.pair_vertex, mode, boundary)
        else:
            self.pid, self.source, self.pair_vertex = _value_vertices(level, cv, idx)
            value_sharp = _sharp_values(level, mesh.num_vertices, cv, self.nxt, self.pid, self.pair_vertex, mode,
                                        boundary)
        self.corner_sharp = np.maximum(level.vert_sharpness[self.pair_vertex],
                                       np.where(value_sharp, INFINITE_SHARPNESS, 0.0))

    def mesh(self, faces: np.ndarray | None = None) -> Mesh:
        """The value mesh (of the control faces ``faces`` only, a bool mask, their values numbered in the
        order of the whole value mesh's; None: every face)."""
        return _tagged_value_mesh(self.analysed, self.level, self.pid, self.nxt, self.corner_sharp, self.mode,
                                  faces)

    def islands(self) -> np.ndarray:
        """(F,) bool: the faces that are a value-mesh island of their own with every corner sharp (each of its
        values used by no other face at its vertex, none of its vertices repeated, not a hole). Such a face
        refines alone, as a single face with infinitely sharp corners and boundary edges: its refined values
        depend on its own corner values only, and on the order of its value-mesh vertices (see
        :class:`_Islands`)."""
        mesh = self.analysed
        lonely = self.corner_sharp[self.pid] >= INFINITE_SHARPNESS
        if not self.unshared:  # (unshared: every value-mesh vertex has one corner)
            lonely &= np.bincount(self.pid, minlength=len(self.source))[self.pid] == 1
        counts = mesh.face_vertex_counts
        face_of = np.repeat(np.arange(len(counts)), counts)
        island = np.bincount(face_of, weights=~lonely, minlength=len(counts)) == 0
        repeats = mesh.edges.repeat_faces  # (found with the edges, which the tags needed)
        if repeats is None:
            repeats = np.flatnonzero(faces_with_repeats(counts, mesh.face_vertex_indices))
        island[repeats] = False
        if self.level.face_hole is not None:
            island &= ~self.level.face_hole
        return island


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


#: Value indices per corner from which :func:`_unshared` counts uses with a bincount only when the largest index
#: is below this many times the corners (a sparse numbering is left to the general path).
UNSHARED_SPAN = 4


def _unshared(idx: np.ndarray) -> bool:
    """Whether every value index of ``idx`` (checked) is used by one face corner only (UVs authored without
    indices), where the value mesh's tags have a closed form (:func:`_unshared_value_vertices`,
    :func:`_unshared_sharp_values`)."""
    if not len(idx):
        return False
    top = int(idx.max())
    if top >= UNSHARED_SPAN * len(idx):
        return False
    return top + 1 >= len(idx) and int(np.bincount(idx, minlength=top + 1).max()) == 1


def _unshared_value_vertices(cv: np.ndarray, idx: np.ndarray):
    """:func:`_value_vertices` where every value is used by one corner only: every corner is a (vertex, value)
    pair of its own, numbered in the order of (vertex, value), as ``np.unique`` of the pairs numbers them, with a
    sort of the corners by vertex (stable: by value within a vertex where the values increase with the
    corners, as unindexed UVs' do) instead of ``np.unique``'s of the pairs. OpenSubdiv's repeated sibling
    (:func:`_repeated_sibling`) needs a value used at two corners of a vertex: there is none."""
    if len(idx) < 2 or bool((idx[1:] > idx[:-1]).all()):
        order = np.argsort(cv, kind="stable")
    else:
        order = np.lexsort((idx, cv))
    pid = np.empty(len(cv), dtype=np.int64)
    pid[order] = np.arange(len(cv), dtype=np.int64)
    return pid, idx[order], cv[order]


def _unshared_sharp_values(level, nv: int, cv: np.ndarray, nxt: np.ndarray, pid: np.ndarray,
                           pair_vertex: np.ndarray, mode: str, boundary: str) -> np.ndarray:
    """:func:`_sharp_values` where every value is used by one corner only (each value-mesh vertex has one face):
    no value is disjoint (its one face is one run), a vertex has as many values as corners, so that a value is
    sharp exactly where its vertex mismatches (a seam or a boundary the mode makes sharp) and the mode makes
    corners sharp (all but ``none``) or the vertex is sharp anyway (the module's table); the same tags, without
    the per-value counts."""
    if mode == FaceVaryingMode.ALL:
        return np.ones(len(pair_vertex), dtype=bool)
    ecount = np.diff(level.edge_corner_offsets)
    ev = level.edge_verts.astype(np.int64)
    seam, _, _ = _seams(level, cv, nxt, pid)
    vertex_boundary = np.zeros(nv, dtype=bool)
    vertex_boundary[ev[ecount == 1].reshape(-1)] = True
    faces_at = np.bincount(cv, minlength=nv)  # (the values at each vertex too)
    nonmanifold = np.zeros(nv, dtype=bool)
    nonmanifold[ev[ecount > 2].reshape(-1)] = True
    linear_boundaries = mode == FaceVaryingMode.BOUNDARIES
    corners_sharp = mode != FaceVaryingMode.NONE
    mismatch = np.zeros(nv, dtype=bool)
    mismatch[ev[seam].reshape(-1)] = True
    mismatch |= vertex_boundary & linear_boundaries & (faces_at > 0)
    mismatch |= vertex_boundary & (faces_at == 1) & (boundary != "edge-and-corner") & corners_sharp
    if corners_sharp:
        return mismatch[pair_vertex]
    # mode none: only the values that the vertex's own sharpness or a non-manifold vertex make sharp
    return (mismatch & ((level.vert_sharpness >= INFINITE_SHARPNESS) | nonmanifold))[pair_vertex]


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


def _tagged_value_mesh(mesh: Mesh, level, pid: np.ndarray, nxt: np.ndarray, corner_sharp: np.ndarray, mode: str,
                       faces: np.ndarray | None = None) -> Mesh:
    """The value mesh: ``mesh``'s faces over the value-mesh vertices ``pid``, the vertex mesh's creases on the
    corresponding value edges, ``corner_sharp`` on the values, its holes. ``faces`` (bool per face): only those
    faces, over the values they use (renumbered in their order); None: every face."""
    counts = mesh.face_vertex_counts
    edge_of_corner = mesh.edges.corner_edge.astype(np.int64)
    crease_pairs = np.stack([pid, pid[nxt]], axis=1)
    crease_sharp = level.edge_sharpness[edge_of_corner]
    if mode == FaceVaryingMode.ALL:
        crease_sharp = np.full(len(crease_pairs), INFINITE_SHARPNESS)
    face_hole = level.face_hole
    npairs = len(corner_sharp)
    if faces is not None:
        corner_in = np.repeat(faces, counts)
        used = np.zeros(npairs, dtype=bool)
        used[pid[corner_in]] = True
        new_id = np.cumsum(used) - 1
        counts, pid = counts[faces], new_id[pid[corner_in]]
        crease_pairs, crease_sharp = new_id[crease_pairs[corner_in]], crease_sharp[corner_in]
        corner_sharp = corner_sharp[used]
        face_hole = face_hole[faces] if face_hole is not None else None
        npairs = len(corner_sharp)
    keep = crease_sharp > 0
    keep_c = corner_sharp > 0
    holes = np.flatnonzero(face_hole) if face_hole is not None else None
    return Mesh(
        np.zeros((npairs, 3)), counts, pid,
        creases=crease_pairs[keep], crease_sharpness=crease_sharp[keep],
        corners=np.flatnonzero(keep_c), corner_sharpness=corner_sharp[keep_c],
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
    a refiner of the same type, so this module needs no import of :mod:`warp_subdiv.refiner`.

    Faces that are value-mesh islands with sharp corners (:meth:`_ValueTags.islands`: UVs authored per face
    corner, unindexed, make every face one) are not refined as part of the value mesh: each refines alone, so
    all islands of a size and vertex order share one small refiner (:class:`_Islands`), evaluated on all their
    values at once as columns; the rest of the value mesh gets a refiner of its own. The values are those of
    the whole value mesh's refiner, bit for bit (the same stencil rows, in the same order); only their
    numbering differs. :attr:`refiner` (the whole value mesh's refiner) is built when asked for. On the CPU only
    (a GPU runs the whole value mesh's rows in parallel, the islands' columns on one thread per row)."""

    def __init__(self, refiner, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        self.mode = mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        tags = _ValueTags(refiner.mesh, indices, mode, refiner.boundary, refiner.scheme, _control_level(refiner))
        self.source = tags.source
        self._options = refiner.options.replace(rules="opensubdiv", boundary="edge-only", flatness=None,
                                                loop_beta="loop", linear=(mode == FaceVaryingMode.ALL))
        self._factory, self._levels, self._device = type(refiner), refiner.levels, refiner.device
        self.num_source_values = int(self.source.max()) + 1 if len(self.source) else 0
        self._refiner = self._islands = None
        # (on the CPU only: a single face's refiner evaluates its islands as columns, one thread per row, which a
        # GPU would run on a few dozen threads; there the whole value mesh's rows run in parallel)
        on_cpu = bool(getattr(refiner.device, "is_cpu", True))
        island = tags.islands() if refiner.levels >= 1 and on_cpu else None
        if island is not None and island.any():
            self._islands = _Islands(self, tags, island)
            self._tags = tags  # for the whole value mesh's refiner, if asked for
        else:
            self._refiner = self._refine(tags.mesh())

    @property
    def first_use_order(self) -> bool:
        """Whether :meth:`evaluate`'s values come in the order its indices first use them, each used (where
        every face is an island)."""
        return self._islands is not None and self._islands.first_use_order

    @property
    def first_use_capable(self) -> bool:
        """Whether :meth:`evaluate` can number the values in first-use order itself (``first_use``)."""
        return self._islands is not None

    def _refine(self, mesh: Mesh):
        """A refiner of a value mesh (of the owner's type, with the channel's options)."""
        with warnings.catch_warnings():  # disjoint value fans are expected (they become sharp values)
            warnings.simplefilter("ignore", NonManifoldWarning)
            return self._factory(mesh, self._levels, options=self._options, device=self._device)

    @property
    def refiner(self):
        """The refiner of the whole value mesh (built on first use where the channel refines islands apart)."""
        if self._refiner is None:
            self._refiner = self._refine(self._tags.mesh())
            self._tags = None
        return self._refiner

    def _checked(self, values):
        if np.ndim(values) in (1, 2) and len(values) < self.num_source_values:
            raise SubdivInputError(
                f"face-varying indices refer to value {self.num_source_values - 1} but only {len(values)} values "
                "were given", option="values", element="data", value=len(values),
            )
        return check_rows(values, self.num_source_values, "face-varying values", at_least=True)

    def evaluate(self, values, first_use: bool = False):
        """(refined values (M, d), refined face-varying indices int32 aligned with the refined faces).
        ``first_use``: where the channel refines islands apart (:attr:`first_use_capable`), the values numbered in
        the order the refined faces first use them, values no face uses left out (as the compact vertex order
        numbers them: the same values at every corner)."""
        squeeze = np.ndim(values) == 1
        vals = self._checked(values)
        if self._islands is not None:
            out, indices = self._islands.evaluate(vals, first_use)
        else:
            out = self.refiner.evaluate(vals[self.source], normal_control=False)
            _, indices = self.refiner.topology()
        return (out[:, 0] if squeeze else out), indices

    def limit(self, values):
        """Limit values of the refined channel (OpenSubdiv's LimitFaceVarying): the limit masks of the value
        mesh, whose sharp values and seams are the channel's. Returns (values (M, d), indices)."""
        squeeze = np.ndim(values) == 1
        refined = self.refiner.evaluate(self._checked(values)[self.source], normal_control=False)
        _, indices = self.refiner.topology()
        flat = refined[:, None] if refined.ndim == 1 else refined
        columns = []
        for c in range(0, flat.shape[1], 3):  # limit masks act on 3 columns at a time
            block = np.zeros((len(flat), 3))
            block[:, :min(3, flat.shape[1] - c)] = flat[:, c:c + 3]
            columns.append(self.refiner.limit_points(block)[:, :min(3, flat.shape[1] - c)])
        out = np.concatenate(columns, axis=1)
        return (out[:, 0] if squeeze else out), indices


def _control_level(refiner):
    """The vertex refiner's analysis of its control mesh where it is the one a channel's value mesh needs (a
    Catmull-Clark refiner's, not linear: the same faces, edges, fans and sharpness), else None."""
    h = getattr(refiner, "hierarchy", None)
    level = getattr(h, "control_level", None)
    options = refiner.options
    if level is None or options.scheme != Scheme.CATMULL_CLARK or options.linear or h.mesh is not refiner.mesh:
        return None
    return level


#: Islands evaluated at once by a single face's refiner (one column group each): its level buffers hold
#: (values, islands x width) rows, so a larger group is evaluated in chunks of this many (a few MiB).
ISLANDS_PER_EVALUATION = 8192

#: Islands of one size and vertex order that make a single face's refiner worth building (~6 ms, once per
#: process): fewer refine with the rest of the value mesh.
MIN_ISLANDS = 64

#: Refiners of single faces with sharp corners (:class:`_Islands`), by owner type, face size, vertex order,
#: levels, options and device: the same few serve every channel of a bake.
_ISLAND_REFINERS: dict = {}


def _single_face(channel: FaceVaryingChannel, rank: np.ndarray):
    """(refiner, number of values, its values in the order its refined faces first use them, its refined
    corners' values in that numbering) of one face whose corners are value-mesh vertices ``rank``, with sharp
    corners (cached: :data:`_ISLAND_REFINERS`)."""
    key = (channel._factory, tuple(int(r) for r in rank), channel._levels, channel._options, str(channel._device))
    single = _ISLAND_REFINERS.get(key)
    if single is None:
        n = len(rank)
        refiner = channel._refine(Mesh(np.zeros((n, 3)), [n], rank, corners=np.arange(n),
                                       corner_sharpness=np.full(n, INFINITE_SHARPNESS)))
        own = np.asarray(refiner.topology()[1], dtype=np.int64)
        _, first = np.unique(own, return_index=True)
        old_id = np.argsort(first, kind="stable")
        new_id = np.empty_like(old_id)
        new_id[old_id] = np.arange(len(old_id))
        single = (refiner, refiner.num_vertices, old_id, new_id[own])
        if len(_ISLAND_REFINERS) > 256:
            _ISLAND_REFINERS.clear()
        _ISLAND_REFINERS[key] = single
    return single


#: Face sizes up to which :func:`_vertex_orders` ranks a face's corners by comparing them pairwise and finds
#: the vertex orders with a count per possible order (n ** n of them), not with sorts.
SMALL_FACE = 6


def _stable_order(labels: np.ndarray, num_labels: int) -> np.ndarray:
    """``np.argsort(labels, kind="stable")`` of labels in [0, num_labels): as 16-bit labels where they fit, which
    numpy sorts with a radix sort (linear time) rather than a merge sort."""
    small = np.int16 if num_labels <= np.iinfo(np.int16).max else np.int32
    return np.argsort(labels.astype(small, copy=False), kind="stable")


def _vertex_orders(ids: np.ndarray):
    """(order, rank, first, which, group_size) of islands' value-mesh vertices ``ids`` (K, n), distinct within
    each island: ``order`` sorts each island's corners by vertex (np.argsort along rows), ``rank`` is each
    corner's place in that order; the vertex orders (groups) in order of their key (the ranks as base-n
    digits), each one's first island and size, and each island's group (``which``): what ``np.unique`` of the
    keys gives. Faces of up to :data:`SMALL_FACE` corners: ranks by pairwise comparison and groups by a count per
    key, without sorts."""
    k, n = ids.shape
    if n > SMALL_FACE:
        order = np.argsort(ids, axis=1, kind="stable")
        rank = np.argsort(order, axis=1, kind="stable")
        key = (rank * n ** np.arange(n)).sum(axis=1)
        _, first, which, group_size = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        return order, rank, first, which.reshape(-1), group_size
    cols = np.ascontiguousarray(ids.T)  # (n, K): each corner's ids in a row
    rank_t = np.zeros((n, k), dtype=np.int64)
    key = np.zeros(k, dtype=np.int64)
    for i in range(n):
        for j in range(n):
            if i != j:
                rank_t[i] += cols[j] < cols[i]
        key += rank_t[i] * n ** i
    rank = np.ascontiguousarray(rank_t.T)
    order = np.empty_like(rank)
    np.put_along_axis(order, rank, np.arange(n), axis=1)
    counts = np.bincount(key, minlength=n ** n)
    present = np.flatnonzero(counts)
    group_of_key = np.zeros(len(counts), dtype=np.int64)
    group_of_key[present] = np.arange(len(present))
    which = group_of_key[key]
    group_size = counts[present]
    first = _stable_order(which, len(present))[np.cumsum(group_size) - group_size]
    return order, rank, first, which, group_size


#: Runs of consecutive blocks :func:`_put` writes one slice at a time at most (more: one scatter).
PUT_RUNS = 1024

#: Entries that one run costs :func:`_put` as much as scattering them (a few numpy calls, ~7 us, against ~6 ns an
#: entry, measured): short runs (islands of two sizes in turn) are scattered.
PUT_RUN_ENTRIES = 1024


def _put(out: np.ndarray, starts: np.ndarray, base: np.ndarray, table: np.ndarray, which: np.ndarray,
         scale: np.ndarray | None = None) -> None:
    """``out[starts[i] + j] = base[i] + table[which[i], j] * scale[i]`` (``scale`` None: 1) for j < the table's
    width: where the blocks run on from each other (islands of one size in face order, a few runs), each run is
    computed straight into its slice of ``out``, with no index array and no temporary of the whole."""
    width = table.shape[1]
    breaks = np.flatnonzero(np.diff(starts) != width) + 1
    if len(breaks) >= PUT_RUNS or len(breaks) * PUT_RUN_ENTRIES > len(starts) * width:
        rows = np.take(table, which, axis=0)
        if scale is not None:
            rows *= scale[:, None]
        rows += base[:, None]
        out[(starts[:, None] + np.arange(width)).reshape(-1)] = rows.reshape(-1)
        return
    bounds = np.concatenate([[0], breaks, [len(starts)]])
    # in the output's type (they fit: single faces' values, and places in ``out``), so that no loop casts
    table, base = table.astype(out.dtype, copy=False), base.astype(out.dtype, copy=False)
    scale = None if scale is None else scale.astype(out.dtype, copy=False)
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
        start = int(starts[a])
        rows = out[start:start + (b - a) * width].reshape(b - a, width)
        np.take(table, which[a:b], axis=0, out=rows, mode="clip")  # (valid: "raise" would buffer the out)
        if scale is not None:
            np.multiply(rows, scale[a:b, None], out=rows)
        np.add(rows, base[a:b, None], out=rows)


def _filled(faces: np.ndarray, base: np.ndarray, which: np.ndarray, slot: np.ndarray):
    """(slots, base, which): the islands ``faces`` (sorted) with their ``base`` and group ``which``, among all
    faces flagged ``slot`` (a superset), the others with group 0 and base 0 (rows written only to be written
    over)."""
    slots = np.flatnonzero(slot)
    if len(slots) == len(faces):
        return faces, base, which
    at = np.searchsorted(slots, faces)
    all_base = np.zeros(len(slots), dtype=base.dtype)
    all_base[at] = base
    all_which = np.zeros(len(slots), dtype=which.dtype)
    all_which[at] = which
    return slots, all_base, all_which


class _Islands:
    """The islands of a :class:`FaceVaryingChannel` (faces whose values no other face uses, with sharp
    corners) and the rest of its value mesh, refined apart and put back together in the value mesh's face
    order.

    An island's refined values depend on its corner values and on the order of its value-mesh vertices (which
    fixes the order of the stencil rows' terms: the whole value mesh numbers values by vertex, so an island's
    corners come in the order of their vertices' ids). Islands with the same size and that order share one
    refiner of a single face numbered the same way, whose stencils are the island's in the whole value mesh;
    it evaluates all their values at once, one island's values per group of columns."""

    def __init__(self, channel: FaceVaryingChannel, tags: _ValueTags, island: np.ndarray):
        mesh = tags.analysed
        counts = mesh.face_vertex_counts.astype(np.int64)
        levels = channel._levels
        loop = channel._options.scheme == Scheme.LOOP
        per_face = np.full(len(counts), 4 ** levels) if loop else counts * 4 ** (levels - 1)
        if tags.level.face_hole is not None:
            per_face[tags.level.face_hole] = 0  # a hole (of the value mesh: the analysis's) has no refined faces
        self.size = 3 if loop else 4
        first_out = np.concatenate([[0], np.cumsum(per_face)])
        self.num_out_faces = int(first_out[-1])
        # the islands of every size by the order of their value-mesh vertices; the islands of an order with
        # fewer than MIN_ISLANDS of them refine with the rest (a single face's refiner costs more to build)
        island = island.copy()
        orders = []
        for n in np.unique(counts[island]):
            faces = np.flatnonzero(island & (counts == n))
            ids = tags.pid[mesh.face_offsets[faces][:, None] + np.arange(n)]  # (K, n): their value-mesh vertices
            order, rank, first, which, group_size = _vertex_orders(ids)
            kept = group_size >= MIN_ISLANDS
            if not kept.all():  # whole groups leave: renumber the rest's groups and first islands
                common = kept[which]
                island[faces[~common]] = False
                first = (np.cumsum(common) - 1)[first[kept]]
                which = (np.cumsum(kept) - 1)[which[common]]
                faces, ids, order, rank = faces[common], ids[common], order[common], rank[common]
            if len(faces):
                orders.append((n, faces, ids, order, rank, first, which))
        rest = ~island
        self.rest = self.rest_source = self.rest_rows = None
        if rest.any():
            used = np.zeros(len(tags.source), dtype=bool)
            used[tags.pid[np.repeat(rest, counts)]] = True
            self.rest = channel._refine(tags.mesh(rest))
            self.rest_source = tags.source[used]
            self.rest_rows = np.flatnonzero(np.repeat(rest, per_face))
        self.groups = []  # (refiner, value indices (n, K) in its vertex order), by face size, then vertex order
        rest_values = 0 if self.rest is None else self.rest.num_vertices
        self.first_use_order = self.rest is None  # (of the channel's numbering: see evaluate)
        self._own_numbering = None  # (order, indices) of the channel's numbering, where it differs: see evaluate
        sizes, value_count = [], np.zeros(len(counts), dtype=np.int64)
        for n, faces, ids, order, rank, first, which in orders:
            singles = [_single_face(channel, rank[f]) for f in first]
            value_count[faces] = singles[0][1]  # (every single face of a size has as many values)
            sizes.append((faces, tags.source[np.take_along_axis(ids, order, axis=1)], which, singles))
        # values in the order the refined faces first use them: each island's block (numbered in that order) at
        # its place among the rest's values (those its faces use, first used where they are)
        value_start = np.cumsum(value_count) - value_count
        rest_first = self._rest_first_uses(first_out, value_start, per_face, rest) if self.rest is not None else None
        if rest_first is not None:
            value_start += np.searchsorted(rest_first[0], first_out[:-1] * self.size)
        self.num_values = int(value_count.sum()) + (len(rest_first[1]) if rest_first is not None else 0)
        kind = np.int32 if rest_values + int(value_count.sum()) < 2**31 - 1 else np.int64  # (either numbering)
        indices = np.empty(self.num_out_faces * self.size, dtype=kind)
        # the evaluation concatenates the rest's values and each group's (value i of island j of a group at
        # i K + j: the single face's values for K columns), and takes them out in this order
        self.order = np.empty(self.num_values, dtype=np.int64)
        block = rest_values
        for faces, values, which, singles in sizes:
            m = singles[0][1]
            group_size = np.bincount(which, minlength=len(singles))
            members = _stable_order(which, len(singles))  # the islands of each group, in face order
            group_first = np.cumsum(group_size) - group_size
            place = np.empty(len(faces), dtype=np.int64)  # each island's place in its group
            place[members] = np.arange(len(faces)) - np.repeat(group_first, group_size)
            group_block = block + group_first * m
            own = np.stack([s[3] for s in singles]).astype(np.int64)  # (groups, corners)
            old_id = np.stack([s[2] for s in singles]).astype(np.int64)  # (groups, m)
            starts = value_start[faces]
            # (every face of this size with refined faces gets rows, so that the rest's faces between islands
            # do not break the runs: theirs are written over below)
            slots, slot_base, slot_which = _filled(faces, starts, which,
                                                   (counts == counts[faces[0]]) & (per_face > 0))
            _put(indices, first_out[slots] * self.size, slot_base, own, slot_which)
            _put(self.order, starts, group_block[which] + place, old_id, which, group_size[which])
            for g, single in enumerate(singles):
                chosen = members[group_first[g]:group_first[g] + group_size[g]]
                self.groups.append((single[0], np.ascontiguousarray(values[chosen].T)))
            block += len(faces) * m
        if rest_first is not None:
            _, old_rest, new_rest = rest_first
            self.order[new_rest] = old_rest
            number = np.zeros(rest_values, dtype=kind)
            number[old_rest] = new_rest
            corner_rows = (self.rest_rows * self.size)[:, None] + np.arange(self.size)
            indices[corner_rows.reshape(-1)] = number[np.asarray(self.rest.topology()[1])]
        indices.flags.writeable = False  # (handed out by every evaluation, as a refiner's topology is)
        self.indices = indices

    def _rest_first_uses(self, first_out: np.ndarray, value_start: np.ndarray, per_face: np.ndarray,
                         rest: np.ndarray):
        """(where, old, new): the rest's values that its refined faces use, in the order they first use them:
        the position among all refined corners of each one's first use, its vertex in the rest's refiner, and its
        number among all the channel's values in first-use order (``value_start``: the island values before each
        face)."""
        rest_idx = np.asarray(self.rest.topology()[1], dtype=np.int64)
        first = np.full(self.rest.num_vertices, len(rest_idx), dtype=np.int64)
        np.minimum.at(first, rest_idx, np.arange(len(rest_idx), dtype=np.int64))
        used = np.flatnonzero(first < len(rest_idx))
        used = used[np.argsort(first[used], kind="stable")]
        at = first[used]  # (increasing) the rest's corner of each first use
        where = self.rest_rows[at // self.size] * self.size + at % self.size
        rest_faces = np.flatnonzero(rest & (per_face > 0))
        face = np.repeat(rest_faces, per_face[rest_faces])[at // self.size]  # (the rest's rows: its faces' in order)
        return where, used, np.arange(len(used)) + value_start[face]

    def _channel_numbering(self):
        """(order, indices) of the channel's own numbering, where a rest makes it differ from first use: the
        rest's values as its refiner numbers them (unused ones too), then each island's block in face order."""
        if self._own_numbering is None:
            rest_values = self.rest.num_vertices
            is_rest = self.order < rest_values
            number = np.where(is_rest, self.order, rest_values + np.cumsum(~is_rest) - 1)
            order = np.empty(rest_values + int((~is_rest).sum()), dtype=np.int64)
            order[:rest_values] = np.arange(rest_values)
            order[number[~is_rest]] = self.order[~is_rest]
            indices = number[self.indices].astype(self.indices.dtype)
            indices.flags.writeable = False
            self._own_numbering = (order, indices)
        return self._own_numbering

    def evaluate(self, vals: np.ndarray, first_use: bool = False):
        """(values (M, d), value index per refined face corner) of the channel's values ``vals`` (m, d), in the
        channel's numbering (the rest's values, then the islands'), or with ``first_use`` in the order the refined
        faces first use them, the rest's unused values left out (the compact vertex order's numbering)."""
        order, indices = (self.order, self.indices) if first_use or self.rest is None else self._channel_numbering()
        d = vals.shape[1]
        blocks = []
        if self.rest is not None:
            blocks.append(self.rest.evaluate(np.take(vals, self.rest_source, axis=0), normal_control=False))
        for single, value_ids in self.groups:
            n, k = value_ids.shape
            if k <= ISLANDS_PER_EVALUATION:
                columns = np.take(vals, value_ids, axis=0).reshape(n, k * d)  # island j: columns j d .. j d + d - 1
                blocks.append(single.evaluate(columns, normal_control=False).reshape(-1, d))
                continue
            # many islands: in chunks of a fixed width (the last one padded), so that the single face's refiner
            # keeps level buffers of a bounded width and records its launches for one width
            out = None
            columns = np.zeros((n, ISLANDS_PER_EVALUATION, d))
            for a in range(0, k, ISLANDS_PER_EVALUATION):
                b = min(k, a + ISLANDS_PER_EVALUATION)
                columns[:, :b - a] = np.take(vals, value_ids[:, a:b], axis=0)
                part = single.evaluate(columns.reshape(n, -1), normal_control=False)
                if out is None:
                    out = np.empty((len(part), k, d), dtype=part.dtype)
                out[:, a:b] = part.reshape(len(part), ISLANDS_PER_EVALUATION, d)[:, :b - a]
            blocks.append(out.reshape(-1, d))
        joined = blocks[0] if len(blocks) == 1 else np.concatenate(blocks)
        return np.take(joined, order, axis=0), indices
