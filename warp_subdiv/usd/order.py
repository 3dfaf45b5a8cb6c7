"""Vertex orders of a refined mesh for writing: OpenSubdiv's, or a compact one whose indices compress well.

A refiner numbers the vertices of a level as OpenSubdiv does: [vertex children, face children, edge
children]. A refined face's corners then jump between those three ranges, and usdc's integer compression
(deltas, then LZ4) does poorly on such index arrays: saving one costs about 0.1-1 us per index, while an
array of small deltas costs a hundredth of that (BENCHMARKS.md, "USD bake"). The *compact* order keeps every
vertex that is a descendant of control vertex v at index v (so "refined vertex v is the child of control vertex
v" still holds, and point subsets keep their meaning) and numbers all other vertices in the order the refined
faces first use them (vertices no face uses last, in OpenSubdiv's order); face-varying values are numbered in
the order the refined faces first use them. Faces keep OpenSubdiv's order. The surface is the same; only the
numbering changes.

:class:`OrderedRefiner` wraps a :class:`~warp_subdiv.refiner.Refiner` so that everything it returns per refined
vertex (``topology``, ``evaluate``, ``limit_points``, ``limit_normals``, face-varying values and indices, the
last level's vertex parentage) uses the compact order, and takes per-vertex input in that order. The USD bake
uses it for ``vertex_order="compact"``.
"""
from __future__ import annotations

import warnings

import numpy as np

#: The vertex orders the USD bake writes: "opensubdiv" (the refiner's), "compact", or "auto" (compact where the
#: rule set is piecewise-smooth, OpenSubdiv's where it is "opensubdiv").
VERTEX_ORDERS = ("auto", "opensubdiv", "compact")


def check_vertex_order(value) -> str:
    from ..errors import SubdivInputError

    if value not in VERTEX_ORDERS:
        raise SubdivInputError(f"vertex_order must be one of {', '.join(VERTEX_ORDERS)}, got {value!r}",
                               option="vertex_order", value=value)
    return value


def resolved_vertex_order(vertex_order: str, options) -> str:
    """The order a mesh refined with ``options`` is written in: "compact" or "opensubdiv" ("auto": compact
    for the piecewise-smooth rules)."""
    if vertex_order == "compact" or (vertex_order == "auto" and options.piecewise_smooth):
        return "compact"
    return "opensubdiv"


def appearance_order(indices: np.ndarray, num: int, keep: int = 0):
    """(new id of every old id (num,), old id of every new id (num,)), int32 (int64 beyond its range): ids below
    ``keep`` keep their number; the others are numbered from ``keep`` in the order ``indices`` first uses them,
    unused ones last (in their old order). O(len(indices) + num), no sort.

    One pass over ``indices`` finds every id's first position (``np.minimum.at``: faster than a reversed
    scatter, and needs no "last write wins"); flagging those positions (num writes) then picks the first uses
    out of ``indices`` in order (``np.compress``: faster than a boolean index), without comparing every
    position with its id's first one (the refined indices are 4x the vertices)."""
    indices = np.asarray(indices)
    n = len(indices)
    kind = np.int32 if max(n, num) < 2**31 - 1 else np.int64
    if indices.dtype != kind:
        indices = indices.astype(kind)
    first_use = np.full(num, n, dtype=kind)  # n: unused
    np.minimum.at(first_use, indices, np.arange(n, dtype=kind))
    renumbered = first_use[keep:]
    first = np.zeros(n + 1, dtype=bool)  # first[n]: where the unused ids point
    first[renumbered] = True
    unused = np.flatnonzero(renumbered == n).astype(kind, copy=False)
    unused += keep
    old_id = np.concatenate([np.arange(keep, dtype=kind), np.compress(first[:n], indices), unused])
    new_id = np.empty(num, dtype=kind)
    new_id[old_id] = np.arange(num, dtype=kind)
    return new_id, old_id


def _rows(data, old_id):
    """Rows of ``data`` (refined, in the refiner's order) in the compact order; 1-D data stays 1-D. ``np.take``
    along the rows: a fancy index copies rows of a 2-D array several times slower."""
    return np.take(np.asarray(data), old_id, axis=0)


class _OrderedHierarchy:
    """A hierarchy whose last level's vertex parentage is listed in the compact order."""

    def __init__(self, hierarchy, old_id):
        self._h = hierarchy
        self._old_id = old_id

    def vertex_parent(self, level: int):
        kind, parent = self._h.vertex_parent(level)
        if level == self._h.levels:
            return _rows(kind, self._old_id), _rows(parent, self._old_id)
        return kind, parent

    def __getattr__(self, name):
        return getattr(self._h, name)


class OrderedRefiner:
    """A refiner's results in the compact vertex order (see the module docstring); everything else is the
    wrapped refiner's (``refiner`` attribute)."""

    def __init__(self, refiner):
        self.refiner = refiner
        counts, indices = refiner.topology()
        self.new_id, self.old_id = appearance_order(indices, refiner.num_vertices, refiner.mesh.num_vertices)
        self._counts = counts
        # (indices as intp first: np.take converts int32 indices itself, more slowly)
        self._indices = np.take(self.new_id, np.asarray(indices, dtype=np.intp)).astype(np.int32, copy=False)
        self.hierarchy = _OrderedHierarchy(refiner.hierarchy, self.old_id)
        self._fast_plan: dict = {}  # the last face-varying channel's _FastPlan (see _fast_parts)

    def topology(self):
        return self._counts, self._indices

    def compact(self, refined):
        """Rows of per-vertex data refined in the wrapped refiner's order, in the compact order."""
        return _rows(refined, self.old_id)

    def evaluate(self, points, normal_control=None):
        return self._evaluate_rows(points, None, normal_control)

    def _evaluate_rows(self, points, rows, normal_control=None):
        """:meth:`Refiner._evaluate_rows` in the compact order (``rows``: compact ids, None: all): gathered
        from the wrapped refiner's level buffer in one pass."""
        own = self.old_id if rows is None else self.old_id[np.asarray(rows)]
        return self.refiner._evaluate_rows(points, own, normal_control)

    def _own(self, refined):
        """Refined data in the compact order back in the refiner's order."""
        return _rows(refined, self.new_id)

    def limit_points(self, refined_points, *, normal_control=None):
        return self.compact(self.refiner.limit_points(self._own(refined_points), normal_control=normal_control))

    def limit_normals(self, refined_points):
        return self.compact(self.refiner.limit_normals(self._own(refined_points)))

    def evaluate_with_limits(self, points, **kwargs):
        """The wrapped refiner's one pass (:meth:`~warp_subdiv.refiner.Refiner.evaluate_with_limits`), each
        result in the compact order."""
        res = self.refiner.evaluate_with_limits(points, **kwargs)
        for name in ("points", "limit_points", "limit_normals"):
            if getattr(res, name) is not None:
                setattr(res, name, self.compact(getattr(res, name)))
        return res

    def _face_varying(self, values, indices):
        """Values numbered in the order the refined faces first use them; values no face uses are dropped."""
        new_id, old_id = appearance_order(indices, len(values))
        indices = np.asarray(indices)
        used = np.zeros(len(values), dtype=bool)
        used[indices] = True
        return _rows(values, old_id[: int(used.sum())]), new_id[indices].astype(np.int32, copy=False)

    def evaluate_face_varying(self, values, indices, mode="corners-plus1"):
        fast = _fast_parts(self.refiner, values, indices, mode, self._fast_plan, rows=self.old_id)
        if fast is None:
            channel = self.refiner.face_varying_channel(indices, mode)
            if channel.first_use_capable:  # (islands refined apart: numbered in first-use order by the channel)
                refined, at = channel.evaluate(values, first_use=True)
                return refined, at.astype(np.int32, copy=False)
            return self._face_varying(*channel.evaluate(values))
        # values away from the seams are the vertices' (ids below N): numbered as the vertices are (the rows
        # come in the compact order), so no second renumbering pass; the values near the seams follow (a vertex
        # only the faces near a seam use keeps a value that no corner uses). The indices are the compact
        # topology's, the near faces' replaced.
        refined, sub = fast.refined, fast.sub_values
        n = len(refined)
        if fast.squeeze:
            refined, sub = refined[:, 0], (None if sub is None else sub[:, 0])
        out = np.ascontiguousarray(refined) if sub is None else np.concatenate([refined, sub])
        value_of = self._indices.copy()
        if fast.near_values is not None:
            value_of.reshape(-1, fast.plan.size)[fast.plan.near_face] = n + fast.near_values
        return out, value_of

    def limit_face_varying(self, values, indices, mode="corners-plus1"):
        return self._face_varying(*self.refiner.limit_face_varying(values, indices, mode=mode))

    def __getattr__(self, name):
        return getattr(self.refiner, name)


class _ChannelOwner:
    """What a :class:`~warp_subdiv.tables.facevarying.FaceVaryingChannel` reads of the refiner that owns it (mesh,
    options, levels, device), without building that refiner's vertex tables. The channel refines its value mesh
    with ``type(owner)(mesh, levels, options=, device=)``, which here builds a ``refiner_type``."""

    _refiner_type = None
    _owner_types: dict = {}

    def __new__(cls, mesh, levels, *, options, device, refiner_type=None):
        if refiner_type is None:  # called by the channel for its value mesh
            return cls._refiner_type(mesh, levels, options=options, device=device)
        owner_type = cls._owner_types.get(refiner_type)
        if owner_type is None:  # one owner type per refiner type: channels cache what they build by owner type
            owner_type = cls._owner_types[refiner_type] = type("_Owner", (cls,), {"_refiner_type": refiner_type})
        owner = object.__new__(owner_type)
        owner.mesh, owner.levels, owner.options, owner.device = mesh, levels, options, device
        return owner

    def __init__(self, *args, **kwargs):
        pass

    boundary = property(lambda self: self.options.boundary)
    scheme = property(lambda self: self.options.scheme)


def fast_face_varying(refiner, values, indices, mode="corners-plus1"):
    """A face-varying channel refined on the vertex topology where its seams allow, as (values (M, d),
    value index per refined face corner), or None where this path does not apply.

    Where a control vertex has one value (no seam) and the smooth rule (interior, manifold, no sharp edge, no
    tag), the channel's value mesh has the same neighbourhood and rules there as the vertex mesh. A refined face
    inside a control face whose 1-ring (the faces sharing a vertex with it) has only such vertices depends on
    nothing else, so its values are the vertex refinement of the values (one :meth:`Refiner.evaluate`, on the
    topology already built). The other control faces ("near a seam") and their 1-rings form a small mesh
    whose own face-varying channel gives their values (its outer ring only completes the neighbourhoods).
    The values equal those of :meth:`Refiner.evaluate_face_varying` at every refined corner (up to float
    rounding); their numbering differs (the compact order renumbers them anyway). Applies to Catmull-Clark
    and to Loop on triangles, with Loop's beta, and not to the "all" mode."""
    fast = _fast_parts(refiner, values, indices, mode)
    if fast is None:
        return None
    refined, near = fast.refined, fast.near_values
    _, indices_out = refiner.topology()
    value_of = np.array(indices_out, dtype=np.int32 if len(refined) < 2**30 else np.int64)
    if near is None:
        out = refined
    else:
        value_of.reshape(-1, fast.plan.size)[fast.plan.near_face] = len(refined) + near
        out = np.concatenate([refined, fast.sub_values])
    return (out[:, 0] if fast.squeeze else out), value_of


class _FastPlan:
    """What :func:`fast_face_varying` derives from the mesh and the value indices alone (not the values), kept
    by :class:`OrderedRefiner` so that later samples of a channel (same indices and mode) only evaluate.

    ``vertices``, ``vertex_value``: the control vertices some face uses and the value index each takes (its last
    corner's: for a vertex with one value, that value); ``size``: corners per refined face; ``near_face``: per
    refined face, whether its control face is near a seam (None: no face is); ``channel``: the face-varying
    channel of the part mesh around those faces; ``sub_near``: per refined face of that channel, whether its
    control face is one of the near faces (the others only complete their neighbourhoods)."""

    __slots__ = ("vertices", "vertex_value", "size", "near_face", "channel", "sub_near")


class _FastParts:
    """One evaluation of a :class:`_FastPlan`: ``refined`` the vertex refinement of the values (N, d), in the
    refiner's order or the order of the rows asked for (:func:`_fast_parts`);
    ``sub_values`` the part channel's values (M, d) and ``near_values`` the value index (from N on) of every
    corner of the refined faces near a seam, in face order, shape (faces, size) (both None when no face is
    near a seam); ``squeeze``: the values were 1-D."""

    __slots__ = ("plan", "refined", "sub_values", "near_values", "squeeze")


def _fast_parts(refiner, values, indices, mode, cache: dict | None = None, rows=None):
    """The pieces of :func:`fast_face_varying`'s result (a :class:`_FastParts`), or None where the path does
    not apply. ``cache``: a dict that keeps the last :class:`_FastPlan` with its key (mode and indices);
    ``rows``: the rows of the vertex refinement to keep, in that order (None: all, in the refiner's order)."""
    from ..errors import SubdivInputError
    from ..tables import check_value_indices
    from ..mesh import check_rows
    from ..options import FaceVaryingMode

    h = refiner.hierarchy
    options = refiner.options
    mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
    mesh = refiner.mesh
    if (getattr(h, "base_vert_class", None) is None or refiner.levels < 1 or options.linear
            or mode == FaceVaryingMode.ALL or h.parentage.control_face is not None
            or options.loop_beta.value != "loop"):
        return None
    idx = check_value_indices(indices, len(mesh.face_vertex_indices))
    if len(idx) == 0:
        return None
    squeeze = np.ndim(values) == 1
    if np.ndim(values) in (1, 2) and len(values) <= int(idx.max()):
        raise SubdivInputError(f"face-varying indices refer to value {int(idx.max())} but only {len(values)} values "
                               "were given", option="values", element="data", value=len(values))
    if cache is None:
        plan = _fast_plan(refiner, idx, mode)
    else:
        key = (mode, idx.tobytes())
        if cache.get("key") != key:
            cache.clear()
            cache.update(key=key, plan=_fast_plan(refiner, idx, mode))
        plan = cache["plan"]
    if plan is None:
        return None  # (the channel checks the values)
    vals = check_rows(values, int(idx.max()) + 1, "face-varying values", at_least=True)

    parts = _FastParts()
    parts.plan, parts.squeeze = plan, squeeze
    # away from the seams: the vertex refinement of the values
    data = np.zeros((mesh.num_vertices, vals.shape[1]))
    data[plan.vertices] = vals[plan.vertex_value]
    parts.refined = refiner._evaluate_rows(data, rows, normal_control=False)
    parts.sub_values = parts.near_values = None
    # near the seams: the channel of the faces there and their 1-rings
    if plan.channel is not None:
        sub_values, sub_index = plan.channel.evaluate(vals)
        parts.near_values = np.asarray(sub_index).reshape(-1, plan.size)[plan.sub_near]
        parts.sub_values = np.asarray(sub_values).reshape(len(sub_values), -1)
    return parts


def _fast_plan(refiner, idx, mode):
    """The :class:`_FastPlan` of value indices ``idx`` (checked) and ``mode`` (parsed), or None where every
    control face is near a seam."""
    from ..errors import NonManifoldWarning
    from ..tables import FaceVaryingChannel
    from ..mesh import Mesh
    from ..rules import SMOOTH

    h = refiner.hierarchy
    options = refiner.options
    mesh = refiner.mesh
    cv = mesh.face_vertex_indices.astype(np.int64)
    counts = mesh.face_vertex_counts.astype(np.int64)
    nv, nf = mesh.num_vertices, mesh.num_faces
    face_of = np.repeat(np.arange(nf, dtype=np.int64), counts)
    one_value = np.empty(nv, dtype=np.int64)
    one_value[cv] = idx
    multi = np.bincount(cv, weights=one_value[cv] != idx, minlength=nv) > 0
    aligned = (h.base_vert_class == SMOOTH) & ~multi
    if not aligned.any():  # every face has a corner that is not aligned: every face is near a seam
        return None
    bad_face = np.bincount(face_of, weights=~aligned[cv], minlength=nf) > 0
    bad_vertex = np.bincount(cv, weights=bad_face[face_of], minlength=nv) > 0
    near_seam = np.bincount(face_of, weights=bad_vertex[cv], minlength=nf) > 0
    if near_seam.all():
        return None

    plan = _FastPlan()
    plan.vertices = np.flatnonzero(np.bincount(cv, minlength=nv) > 0)
    plan.vertex_value = one_value[plan.vertices]
    plan.size = size = h.final.face_size  # 4 or 3: every refined face has it

    def per_face(sizes):
        """Refined faces of each control face (children of a control face are consecutive: n 4^(L-1) of an
        n-gon for Catmull-Clark, 4^L of a triangle for Loop)."""
        levels = refiner.levels
        return sizes * 4 ** (levels - 1) if size == 4 else np.full(len(sizes), 4 ** levels)

    def near_faces(flags, sizes, hole):
        """Per output face: the flag of its control face; ``hole``: per refined face, whether it is a hole
        (holes are not output), or None."""
        out = np.repeat(flags, per_face(sizes))
        return out[~hole] if hole is not None and hole.any() else out

    plan.near_face = plan.channel = plan.sub_near = None
    if not near_seam.any():
        return plan
    plan.near_face = near_faces(near_seam, counts, h.final.face_hole)
    touch = np.bincount(cv, weights=near_seam[face_of], minlength=nv) > 0
    keep = np.bincount(face_of, weights=touch[cv], minlength=nf) > 0
    faces = np.flatnonzero(keep)
    corner_in = keep[face_of]
    used = np.flatnonzero(np.bincount(cv[corner_in], minlength=nv) > 0)
    vmap = np.full(nv, -1, dtype=np.int64)
    vmap[used] = np.arange(len(used))
    tags = {}
    if len(mesh.creases):
        on = np.bincount(mesh.edges.corner_edge[corner_in], minlength=mesh.num_edges) > 0
        take = on[mesh.crease_edges]
        if take.any():
            tags["creases"] = vmap[mesh.creases[take]]
            tags["crease_sharpness"] = mesh.crease_sharpness[take]
    if len(mesh.corners):
        take = vmap[mesh.corners] >= 0
        if take.any():
            tags["corners"] = vmap[mesh.corners[take]]
            tags["corner_sharpness"] = mesh.corner_sharpness[take]
    if len(mesh.holes):
        fmap = np.full(nf, -1, dtype=np.int64)
        fmap[faces] = np.arange(len(faces))
        holes = fmap[mesh.holes]
        if (holes >= 0).any():
            tags["holes"] = holes[holes >= 0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        part = Mesh(mesh.points[used], counts[faces], vmap[cv[corner_in]], **tags)
        owner = _ChannelOwner(part, refiner.levels, options=options.replace(rules="opensubdiv", flatness=None),
                              device=refiner.device, refiner_type=type(refiner))
        plan.channel = FaceVaryingChannel(owner, idx[corner_in], mode)
    # the channel's refined faces: the part's faces in order, but its holes (the value mesh's only holes: its
    # boundary is "edge-only")
    part_hole = np.zeros(len(faces), dtype=bool)
    part_hole[part.holes] = True
    plan.sub_near = near_faces(near_seam[faces], counts[faces], np.repeat(part_hole, per_face(counts[faces])))
    return plan
