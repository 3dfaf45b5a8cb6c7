"""Exact evaluation inside the end caps at extraordinary boundary and crease vertices.

Near a vertex whose structure no longer changes from level to level (its semi-sharp tags decayed), one
refinement step is a fixed linear map: the control points of the vertex's two-ring (the vertices of the faces
within two rings, in an order fixed by the topology) at level L + 1 are ``S`` times those of level L. A face
at the vertex one level above the tree's depth (an *anchor*; its four children are the tree's end caps) has
three children away from the vertex that still hold it among their control points, and their twelve children
are regular patches whose Bezier nets are fixed matrices ``B`` times the anchor level's two-ring. So the
surface anywhere in the end caps is exact (Stam's evaluation): a query in the anchor's corner child at the
vertex k times over lies in a regular patch with net ``B S^k P`` (P: the anchor level's two-ring). ``S`` and
``B`` are read off the library's own refinement step (:func:`~warp_subdiv.limit.local_refinement.refine_step`:
its tables, flatness and crease rules) applied to unit vectors, and accepted only where they reproduce the
library's refined points and patches and the step is the same one level further down (so the rules,
projections included, are exactly the library's).

Where it is used: anchors whose only irregular corner is a boundary or infinitely sharp crease vertex with a
sector of other than 2 (Catmull-Clark) or 3 (Loop) faces, without prescribed normals near it, in trees of depth
2 or more. There the end caps miss the accuracy of the others (under OpenSubdiv's rules such a vertex from 5
Catmull-Clark or 7 Loop faces on has no tangent plane, so no polynomial cap can be close). The tree keeps the
end caps (the corner of the one at the vertex is the exact limit position, and the normal exactly at the
vertex is the cap's); :func:`evaluate_exact` replaces the kernel's results at every other query inside them.
Powers of ``S`` are taken by repeated squaring of ``S - 1 l^T`` (``l``: the limit mask, ``S``'s left
eigenvector of eigenvalue 1) applied to ``P - 1 l^T P``, so deep levels keep their relative precision.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..options import Options
from ..rules import CATMULL_CLARK, CREASE
from ..topology import Level
from .bezier import TRI_BEZIER_INDEX, regular_bezier
from .local_refinement import LocalLevel, child_corners, child_faces, cut_out, face_corners, refine_step, region_around
from .regular import LevelLookups, _twin, phantom_points, regular_faces

#: Levels a query may lie below its end cap (float64 parameters reach 2^-1074).
MAX_LEVELS = 1100

#: Tolerances of the checks that accept a vertex: the extracted step against the library's refined points
#: (relative to the ring's size) and against the step one level down.
CHECK_TOLERANCE = 1e-10


@dataclass
class ExactCaps:
    """The exact end caps of a patch tree, grouped by their parent faces (the *anchors*, one level above the
    caps: the faces at the vertex, whose four children are all end caps).

    Per anchor a: ``anchor_node[a]`` its tree node, ``group[a]`` its vertex, ``corner[a]`` its corner at the
    vertex, ``nets[a]`` (12, G, m) the Bezier nets (G = 16 or 15 points) of the regular patches two levels below
    it, as matrices on the vertex's two-ring at the anchor's level: the children (slot order) of its three
    children away from the vertex (slot order, the corner's slot left out). Per vertex g: ``step[g]`` (m, m)
    ``S - 1 l^T``, ``limit[g]`` (m,) the limit mask l, ``ring[g]`` (m, D) the two-ring's control values at the
    anchors' level, ``sizes[g]`` the ring's size (zero rows and columns pad smaller rings to m). Per end cap e
    (:func:`link`): ``patches[e]`` its patch in the tree, ``cap_anchor[e]`` and ``cap_slot[e]`` its anchor and
    its slot there."""

    triangles: bool
    anchor_node: np.ndarray
    group: np.ndarray
    corner: np.ndarray
    nets: np.ndarray
    step: np.ndarray
    limit: np.ndarray
    ring: np.ndarray
    sizes: np.ndarray
    patches: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cap_anchor: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cap_slot: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def num_caps(self) -> int:
        """The number of end caps evaluated exactly."""
        return len(self.patches)


def link(exact: ExactCaps | None, node_child: np.ndarray, node_patch: np.ndarray, patch_kind: np.ndarray,
         end_cap: int) -> ExactCaps | None:
    """``exact`` with its end caps found in the finished tree: the children of the anchors that are end caps
    (None where there are none)."""
    if exact is None:
        return None
    kids = node_child[exact.anchor_node]                     # (A, 4)
    patch = np.where(kids >= 0, node_patch[np.maximum(kids, 0)], -1)
    cap = (patch >= 0) & (patch_kind[np.maximum(patch, 0)] == end_cap)
    anchor, slot = np.nonzero(cap)
    if not len(anchor):
        return None
    exact.patches = patch[anchor, slot].astype(np.int64)
    exact.cap_anchor, exact.cap_slot = anchor.astype(np.int64), slot.astype(np.int64)
    return exact


# ----------------------------------------------------------------------------------------- the two-ring
def _fans(level: Level, twin: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(G, n) the corners at each vertex, walking counter-clockwise from ``start`` (-1 pads)."""
    valence = np.diff(level.vert_corner_offsets)[level.corner_vert.astype(np.int64)[start]]
    width = int(valence.max()) if len(start) else 1
    fan = np.full((len(start), width), -1, dtype=np.int64)
    g = start.copy()
    alive = np.ones(len(start), bool)
    for i in range(width):
        fan[alive, i] = g[alive]
        t = twin[level.corner_prev(g)]
        alive &= (t >= 0) & (t != start)
        g = np.where(alive, t, g)
    return fan


def _quadrant(level: Level, twin: np.ndarray, g: np.ndarray, triangles: bool):
    """Vertices of the lattice wedge of the face of corner ``g`` at its vertex x (x at (0, 0), the face's next
    corner along the first axis): quads (0..2)^2, triangles a + b <= 2; and whether the walk was consistent."""
    cv = level.corner_vert.astype(np.int64)
    nxt, prv = level.corner_next, level.corner_prev
    ok = np.ones(len(g), bool)

    def across(h):
        t = twin[h]
        ok[t < 0] = False
        return np.maximum(t, 0)

    if triangles:
        t = across(nxt(g))            # across (1,0)-(0,1): t at (0,1), next (1,0), prev (1,1)
        t2 = across(nxt(t))           # across (1,0)-(1,1): t2 at (1,1), prev (2,0)
        t3 = across(prv(t))           # across (1,1)-(0,1): t3 at (0,1), prev (0,2)
        ok &= (cv[nxt(t)] == cv[nxt(g)]) & (cv[nxt(t2)] == cv[nxt(g)]) & (cv[nxt(t3)] == cv[prv(t)])
        return np.stack([cv[g], cv[nxt(g)], cv[prv(g)], cv[prv(t)], cv[prv(t2)], cv[prv(t3)]], 1), ok
    a10, a11 = nxt(g), nxt(nxt(g))
    ta = across(a10)                  # face A across (1,0)-(1,1): ta at (1,1); next (1,0), next next (2,0), prev (2,1)
    tb = across(a11)                  # face B across (1,1)-(0,1): tb at (0,1); next (1,1), next next (1,2), prev (0,2)
    tc = across(prv(ta))              # face C across (2,1)-(1,1): tc at (1,1); next (2,1), next next (2,2), prev (1,2)
    sizes = level.face_sizes()
    for h in (g, ta, tb, tc):
        ok &= sizes[level.corner_face(h)] == 4
    ok &= (cv[nxt(ta)] == cv[a10]) & (cv[nxt(tb)] == cv[a11]) & (cv[nxt(tc)] == cv[prv(ta)]) \
        & (cv[prv(tc)] == cv[nxt(nxt(tb))])
    return np.stack([cv[g], cv[a10], cv[a11], cv[prv(g)], cv[nxt(nxt(ta))], cv[prv(ta)], cv[nxt(nxt(tb))],
                     cv[prv(tb)], cv[nxt(nxt(tc))]], 1), ok


def _rings(level: Level, start: np.ndarray, triangles: bool, active: np.ndarray | None = None):
    """(rings (G, m) vertex ids in canonical order, -1 padded; ok (G,)): the two-ring of the vertex of each
    ``start`` corner, ordered by a walk that depends on the topology only (so a refined vertex, walked from the
    child of its start corner, has its ring in the same order)."""
    G = len(start)
    if G == 0:
        return np.zeros((0, 1), np.int64), np.zeros(0, bool)
    twin = _twin(level)
    fan = _fans(level, twin, start)
    x = level.corner_vert.astype(np.int64)[start]
    ok = (fan >= 0).sum(1) == np.diff(level.vert_corner_offsets)[x]
    valid = fan >= 0
    verts, walk_ok = _quadrant(level, twin, np.where(valid, fan, start[:, None]).reshape(-1), triangles)
    walk_ok = walk_ok.reshape(G, -1)
    ok &= np.all(walk_ok | ~valid, axis=1)
    verts = verts.reshape(G, -1)
    entry_ok = np.repeat(valid, verts.shape[1] // fan.shape[1], axis=1)
    rows = np.repeat(np.arange(G), verts.shape[1]).reshape(G, -1)
    order = np.broadcast_to(np.arange(verts.shape[1]), verts.shape)
    r, v, o = rows[entry_ok], verts[entry_ok], order[entry_ok]
    key = r * (level.num_vertices + 1) + v
    _, first = np.unique(key, return_index=True)
    first = first[np.lexsort((o[first], r[first]))]
    r, v = r[first], v[first]
    counts = np.bincount(r, minlength=G)
    m = int(counts.max())
    slot = np.arange(len(r)) - np.repeat(np.cumsum(counts) - counts, counts)
    rings = np.full((G, m), -1, dtype=np.int64)
    rings[r, slot] = v
    # rings of different vertices must not share vertices (each column is one ring's unit vector); rows not
    # ``active`` take no part
    counted = np.ones(G, bool) if active is None else active
    shared = np.bincount(v[counted[r]], minlength=level.num_vertices) > 1
    ok &= ~np.bincount(r[shared[v]], minlength=G).astype(bool)
    return rings, ok


def _coloured(num_vertices: int, rings: np.ndarray, use: np.ndarray, m: int) -> np.ndarray:
    """(V, 3 + m + 2) unit vectors of the rings: three zero columns (normal control acts there), the ring
    slots, a column of ones outside every ring and the ring's tag (its row + 1)."""
    X = np.zeros((num_vertices, 3 + m + 2))
    X[:, 3 + m] = 1.0
    rows, slots = np.nonzero((rings >= 0) & use[:, None])
    v = rings[rows, slots]
    X[v, 3 + slots] = 1.0
    X[v, 3 + m] = 0.0
    X[v, 4 + m] = rows + 1.0
    return X


def _read(Y: np.ndarray, ids: np.ndarray, tags: np.ndarray, m: int):
    """Rows ``ids`` (..., ) of a refined coloured array as matrices on the ring (..., m), and whether they read
    their own ring only (no weight outside it, the ring's tag, weights summing to one)."""
    rows = Y[np.maximum(ids, 0)]
    mat = rows[..., 3:3 + m]
    own = (np.abs(rows[..., 3 + m]) < 1e-12) & (np.abs(rows[..., 4 + m] - tags) < 1e-9) \
        & (np.abs(mat.sum(-1) - 1.0) < 1e-12)
    return mat, own | (ids < 0)


def _child_rings(level: Level, child: Level, start: np.ndarray, sizes: np.ndarray, m: int, scheme: str,
                 active: np.ndarray):
    """The rings of the same vertices one level down (walked from the children of ``start``), ``sizes[g]``
    vertices each (ok is False where the size changed): (start corners, rings padded to m columns, ok)."""
    child_start = child_corners(level, child, start, scheme)
    return (child_start,) + _fit(*_rings(child, child_start, scheme != CATMULL_CLARK, active), sizes, m)


def _fit(rings: np.ndarray, ok: np.ndarray, sizes: np.ndarray, m: int):
    """``rings`` padded (or cut) to ``m`` columns, and ``ok`` where each has its size ``sizes``."""
    ok = ok & ((rings >= 0).sum(1) == sizes)
    return np.pad(rings, ((0, 0), (0, max(m - rings.shape[1], 0))), constant_values=-1)[:, :m], ok


def _away_children(level: Level, faces: np.ndarray, corner: np.ndarray, scheme: str) -> np.ndarray:
    """(F, 3) the children of ``faces`` (of ``level``) away from their corner ``corner``, in slot order."""
    kids, _ = child_faces(level, faces, scheme)
    slots = np.array([[q for q in range(4) if q != j] for j in range(4)], dtype=np.int64)[corner]
    return np.take_along_axis(kids, slots, axis=1)


def _into_cut(level: Level, cut: Level, region_faces: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """The corners of a cut-out (:func:`~warp_subdiv.limit.local_refinement.cut_out` of the faces
    ``region_faces``, which keeps their order and their corners' order) that are ``corners`` of ``level``."""
    f = level.corner_face(corners)
    return cut.face_starts()[np.searchsorted(region_faces, f)] + (corners - level.face_starts()[f])


def _coloured_step(local: LocalLevel, seeds: np.ndarray, columns: np.ndarray, margin: int, options: Options):
    """The faces within ``margin`` rings of ``seeds`` cut out of ``local`` carrying ``columns`` (geometry first),
    refined one step: (the cut-out, its child level, the refined columns, a function taking corners of
    ``local`` to the cut-out's (0 for those outside it) and whether they are inside)."""
    region = region_around(local.level, seeds, margin)
    region_faces = np.flatnonzero(region)
    carried = LocalLevel(local.level, columns, local.face_node, local.normal_ids, local.normal_vectors, local.depth)
    cut = cut_out(carried, region, options)
    child, Y = refine_step(cut, options)

    def into(corners):
        inside = region[local.level.corner_face(corners)]
        return np.where(inside, _into_cut(local.level, cut.level, region_faces, np.where(inside, corners, 0)), 0), \
            inside

    return cut, child, Y, into


def build_exact_caps(sub: LocalLevel, faces: np.ndarray, options: Options, margin: int) -> ExactCaps | None:
    """The anchors among ``faces`` (faces of the cut-out ``sub`` at level d, one above the tree's depth, that
    the tree splits) whose only irregular corner is an extraordinary boundary or crease vertex, with the
    tables that evaluate their end caps exactly; None if there are none. End caps are linked to anchors by
    :func:`link`.

    Two coloured steps (unit vectors of each vertex's two-ring carried as data columns after the geometry,
    on cut-outs of ``margin`` rings around the vertices) give the step matrix at levels d and d + 1 and the nets
    of the twelve regular grandchildren of each anchor at level d + 2 (the anchor's three children away from
    the vertex still have the vertex among their control points: their children are the regular patches)."""
    o = options
    scheme = o.scheme
    triangles = scheme != CATMULL_CLARK
    n = 3 if triangles else 4
    level = sub.level
    found = _boundary_anchors(sub, faces, o, triangles, n)
    if found is None:
        return None
    anchors, anchor_corner, at_vertex, anchor_group, start, rings, use = found
    m = rings.shape[1]
    tags = np.arange(1, len(start) + 1, dtype=np.float64)
    D = sub.points.shape[1]
    # level d -> d + 1 on a cut-out around the vertices (all columns of the points, then the ring's colours):
    # the step matrix, checked against the step's own refined geometry (normal control, which moves the
    # geometry only, or rings reading beyond themselves show there)
    colours = _coloured(level.num_vertices, rings, use, m)[:, 3:]
    cut0, child1, Y1, into0 = _coloured_step(sub, level.corner_face(start[use]),
                                             np.concatenate([sub.points, colours], axis=1), margin, o)
    start0, inside = into0(start)
    use &= inside
    sizes = (rings >= 0).sum(1)
    rings0, ok = _fit(*_rings(cut0.level, start0, triangles, use), sizes, m)
    use &= ok
    P = np.where((rings0 >= 0)[..., None], cut0.points[np.maximum(rings0, 0), :D], 0.0)
    Y1 = np.concatenate([Y1[:, :3], Y1[:, D:]], axis=1)            # geometry and colours
    start1, rings1, ok = _child_rings(cut0.level, child1, start0, sizes, m, scheme, use)
    use &= ok
    step, own = _read(Y1, rings1, tags[:, None], m)
    use &= np.all(own, axis=1)
    geometry = P[..., :3]
    size = 1.0 + np.abs(geometry).max(axis=(1, 2))
    refined = np.where((rings1 >= 0)[..., None], Y1[np.maximum(rings1, 0), :3], 0.0)
    use &= np.abs(np.einsum("gij,gjc->gic", step, geometry) - refined).max(axis=(1, 2)) <= CHECK_TOLERANCE * size
    if not use.any():
        return None
    # level d + 1 -> d + 2, again on a cut-out: the geometry, the level-d colours (for the grandchildren's nets)
    # and the level-(d + 1) colours (for the step one level down)
    next_level = LocalLevel(child1, None, np.full(child1.num_faces, -1, dtype=np.int64), cut0.normal_ids,
                            cut0.normal_vectors, sub.depth + 1)
    columns = np.concatenate([Y1, _coloured(child1.num_vertices, rings1, use, m)[:, 3:]], axis=1)
    anchor_use = use[anchor_group]
    anchors0, inside = into0(at_vertex)
    anchor_use &= inside
    kids = _away_children(cut0.level, cut0.level.corner_face(anchors0), anchor_corner, scheme)  # faces of child1
    cut1, child2, Y2, into1 = _coloured_step(next_level, child1.corner_face(start1[use]), columns, margin, o)
    kids_corner, inside = into1(face_corners(child1, kids.reshape(-1), n)[:, 0])
    anchor_use &= inside.reshape(-1, 3).all(1)
    start1_cut, inside = into1(start1)
    use &= inside
    Y2_d, Y2_d1 = Y2[:, :3 + m + 2], np.concatenate([Y2[:, :3], Y2[:, 3 + m + 2:]], axis=1)
    _, rings2, ok = _child_rings(cut1.level, child2, start1_cut, sizes, m, scheme, use)
    use &= ok
    step1, own = _read(Y2_d1, rings2, tags[:, None], m)
    use &= np.all(own, axis=1) & (np.abs(step1 - step).max(axis=(1, 2)) <= CHECK_TOLERANCE)
    # the twelve grandchildren of every anchor: regular patches of level d + 2, nets on the level-d ring
    anchor_use &= use[anchor_group]
    kids_cut = cut1.level.corner_face(kids_corner).reshape(-1, 3)
    grand, _ = child_faces(cut1.level, kids_cut.reshape(-1), scheme)        # (3A, 4) faces of child2
    grand = grand[:, :4].reshape(len(anchors), 12)
    regular, ids, side_sharp = regular_faces(LevelLookups(child2, o, cut1.normal_ids[:0]), grand.reshape(-1), scheme)
    own = _read(Y2_d, ids, tags[np.repeat(anchor_group, 12)][:, None], m)[1]
    anchor_ok = anchor_use & regular.reshape(len(anchors), 12).all(1) & own.reshape(len(anchors), -1).all(1)
    control = phantom_points(Y2_d[:, 3:3 + m], ids, side_sharp, scheme)
    nets = regular_bezier(np.nan_to_num(control), scheme).reshape(len(anchors), 12, -1, m)
    actual = regular_bezier(np.nan_to_num(phantom_points(Y2[:, :3], ids, side_sharp, scheme)), scheme)
    predicted = np.einsum("cqgm,cmd->cqgd", nets, geometry[anchor_group])
    anchor_ok &= np.abs(predicted - actual.reshape(predicted.shape)).max(axis=(1, 2, 3)) \
        <= CHECK_TOLERANCE * size[anchor_group]
    if not anchor_ok.any():
        return None
    groups, anchor_group = np.unique(anchor_group[anchor_ok], return_inverse=True)
    step, P = step[groups], P[groups]
    valid = rings0[groups] >= 0
    limit, deflated = _limit_and_deflated(step, valid)
    return ExactCaps(triangles, sub.face_node[anchors[anchor_ok]].astype(np.int64), anchor_group.astype(np.int64),
                     anchor_corner[anchor_ok].astype(np.int64), nets[anchor_ok], deflated, limit, P, valid.sum(1))


def _boundary_anchors(sub: LocalLevel, faces: np.ndarray, o: Options, triangles: bool, n: int):
    """The anchors among ``faces`` whose only irregular corner is an extraordinary boundary or crease vertex
    (see :func:`build_exact_caps`), and per such vertex its sector's start corner and two-ring: (anchors, the
    corner of each at its vertex (position, corner), each anchor's vertex group, start corners, rings, which
    vertices can be used); None where there are none."""
    level = sub.level
    anchors = faces[sub.face_node[faces] >= 0]  # tree nodes (not n-gon base faces)
    if len(anchors) == 0:
        return None
    # extraordinary boundary and crease vertices: a sector of other than the regular number of faces, or (where
    # the level keeps no sector, as after a semi-sharp tag decayed) a boundary vertex with another number
    regular_k = 3 if triangles else 2
    odd = np.zeros(level.num_vertices, bool)
    odd[level.sector_vertex[level.sector_k() != regular_k]] = True
    boundary = np.zeros(level.num_vertices, bool)
    boundary[level.edge_verts.astype(np.int64)[np.diff(level.edge_corner_offsets) == 1].reshape(-1)] = True
    odd |= boundary & (np.diff(level.vert_corner_offsets) != regular_k)
    odd &= level.vert_class == CREASE
    corners = face_corners(level, anchors, n)
    hits = odd[level.corner_vert.astype(np.int64)[corners]]
    one = hits.sum(1) == 1
    if not one.any():
        return None
    anchors, corners, hits = anchors[one], corners[one], hits[one]
    anchor_corner = np.argmax(hits, axis=1)
    at_vertex = corners[np.arange(len(anchors)), anchor_corner]     # each anchor's corner at its vertex
    xs, anchor_group = np.unique(level.corner_vert.astype(np.int64)[at_vertex], return_inverse=True)
    # start corner of each vertex: a corner whose outgoing edge is a boundary or infinitely sharp (the first
    # face of a sector, counter-clockwise); the smallest such corner
    twin = _twin(level)
    lookups = LevelLookups(level, o, sub.normal_ids[:0])
    vc_off = level.vert_corner_offsets.astype(np.int64)
    counts = vc_off[xs + 1] - vc_off[xs]
    members = level.vert_corners.astype(np.int64)[np.repeat(vc_off[xs] - (np.cumsum(counts) - counts), counts)
                                                  + np.arange(int(counts.sum()))]
    member_group = np.repeat(np.arange(len(xs)), counts)
    first = (twin[members] < 0) | lookups.edge_inf[level.corner_edge.astype(np.int64)[members]]
    none = np.iinfo(np.int64).max
    start = np.full(len(xs), none)
    np.minimum.at(start, member_group[first], members[first])
    use = start < none
    start = np.where(use, start, members[np.searchsorted(member_group, np.arange(len(xs)))])
    rings, ok = _rings(level, start, triangles)
    use &= ok
    if len(sub.normal_ids) and o.piecewise_smooth and o.normal_strength > 0:
        near = np.zeros(level.num_vertices, bool)
        near[sub.normal_ids] = True
        use &= ~np.any(near[np.maximum(rings, 0)] & (rings >= 0), axis=1)
    if not use.any():
        return None
    return anchors, anchor_corner, at_vertex, anchor_group, start, rings, use


def _limit_and_deflated(step: np.ndarray, valid: np.ndarray):
    """The limit mask l of each step matrix S (S^T l = l, l . 1 = 1: S^T - I with its first row replaced by the
    ones of the ring, whose rows sum to zero so any one of them is redundant; padding solves to zero) and S
    minus its limit part (the ones column times l), whose powers keep relative precision at deep levels."""
    m = step.shape[1]
    A = np.swapaxes(step, 1, 2) - np.eye(m)
    A[:, 0, :] = valid
    rhs = np.zeros((len(step), m))
    rhs[:, 0] = 1.0
    limit = np.linalg.solve(A, rhs[..., None])[..., 0]
    return limit, step - np.where(valid[:, :, None], 1.0, 0.0) * limit[:, None, :]


# ----------------------------------------------------------------------------------------- evaluation
def _child(s: np.ndarray, t: np.ndarray, triangles: bool):
    """One step of the kernel's descent: (slot, the child's (s, t), the sign of its frame)."""
    if triangles:
        slot = np.where(s >= 0.5, 1, np.where(t >= 0.5, 2, np.where(s + t <= 0.5, 0, 3)))
        middle = slot == 3
        s2 = np.where(middle, 1.0 - 2.0 * s, np.where(slot == 1, 2.0 * s - 1.0, 2.0 * s))
        t2 = np.where(middle, 1.0 - 2.0 * t, np.where(slot == 2, 2.0 * t - 1.0, 2.0 * t))
        return slot, s2, t2, np.where(middle, -1.0, 1.0)
    bu, bv = s >= 0.5, t >= 0.5
    slot = np.where(bv, 3 - bu, bu.astype(np.int64))
    return slot, np.where(bu, 2.0 * s - 1.0, 2.0 * s), np.where(bv, 2.0 * t - 1.0, 2.0 * t), np.ones(len(s))


#: The (u, v) of the corners of a quad and a triangle in their own frame.
_CORNER_UV = {False: np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float), True: np.array([[0, 0], [1, 0], [0, 1]], float)}


def _bezier(net: np.ndarray, s: np.ndarray, t: np.ndarray, triangles: bool, second: bool):
    """Value and (s, t) derivatives (first, and second with ``second``) of Bezier nets (r, G, D) at (s, t)."""
    if not triangles:
        def basis(x):
            y = 1.0 - x
            b = np.stack([y ** 3, 3 * x * y * y, 3 * x * x * y, x ** 3], -1)
            d = np.stack([-3 * y * y, 3 * y * y - 6 * x * y, 6 * x * y - 3 * x * x, 3 * x * x], -1)
            dd = np.stack([6 * y, 18 * x - 12, 6 - 18 * x, 6 * x], -1)
            return b, d, dd
        (bs, ds, dds), (bt, dt, ddt) = basis(s), basis(t)
        g = net.reshape(len(net), 4, 4, -1)  # [b (t), a (s)]

        def tensor(x, y):
            return np.einsum("ra,rb,rbad->rd", x, y, g)
        out = [tensor(bs, bt), tensor(ds, bt), tensor(bs, dt)]
        out += [tensor(dds, bt), tensor(ds, dt), tensor(bs, ddt)] if second else [None] * 3
        return out
    w = np.stack([1.0 - s - t, s, t], -1)
    e = np.array(TRI_BEZIER_INDEX)
    coef = np.array([24.0 / np.prod([math.factorial(int(x)) for x in row]) for row in e])

    def partial(*axes):
        """sum over the net of coef * d^len(axes) w^e / dw_axes."""
        f = np.ones(len(e))
        ex = e.copy()
        for a in axes:
            f = f * ex[:, a]
            ex[:, a] -= 1
        ok = (ex >= 0).all(1)
        mono = np.prod(w[:, None, :] ** np.maximum(ex, 0)[None], axis=-1) * (f * coef * ok)[None]
        return np.einsum("rg,rgd->rd", mono, net)
    value = partial()
    d = [partial(i) for i in range(3)]
    out = [value, d[1] - d[0], d[2] - d[0]]
    if second:
        h = {(i, j): partial(i, j) for i in range(3) for j in range(i, 3)}
        out += [h[1, 1] - 2 * h[0, 1] + h[0, 0], h[1, 2] - h[0, 2] - h[0, 1] + h[0, 0],
                h[2, 2] - 2 * h[0, 2] + h[0, 0]]
    else:
        out += [None] * 3
    return out


def evaluate_exact(exact: ExactCaps, cap: np.ndarray, s: np.ndarray, t: np.ndarray, js: np.ndarray, jt: np.ndarray,
                   second: bool, ring: np.ndarray | None = None, chunk: int = 4096):
    """The surface inside exact end caps: queries in end cap ``cap`` (indices into ``exact.patches``) at the
    cap's own (s, t), with the kernel's scales (js, jt) of d(s, t)/d(u, v). ``ring``: the two-ring values
    (default: the tree's, positions and any data). Returns (rows: the queries not at the vertex itself, whose
    results follow; [value, du, dv and, with ``second``, duu, duv, dvv], each (len(rows), D))."""
    tri = exact.triangles
    ring = exact.ring if ring is None else ring
    # into the anchor's frame (the kernel's descent step undone: exact, as that step was)
    slot = exact.cap_slot[cap]
    cap = exact.cap_anchor[cap]
    s, t = np.asarray(s, dtype=np.float64), np.asarray(t, dtype=np.float64)
    if tri:
        turned = slot == 3
        s = np.where(turned, (1.0 - s) * 0.5, (s + (slot == 1)) * 0.5)
        t = np.where(turned, (1.0 - t) * 0.5, (t + (slot == 2)) * 0.5)
        js, jt = np.where(turned, -0.5, 0.5) * js, np.where(turned, -0.5, 0.5) * jt
    else:
        s = (s + ((slot == 1) | (slot == 2))) * 0.5
        t = (t + (slot >= 2)) * 0.5
        js, jt = 0.5 * js, 0.5 * jt
    j0 = exact.corner[cap]
    at_vertex = np.all(np.stack([s, t], -1) == _CORNER_UV[tri][j0], axis=1)
    rows = np.flatnonzero(~at_vertex)
    s, t, j0 = s[rows], t[rows], j0[rows]
    k = np.zeros(len(rows), dtype=np.int64)
    active = np.arange(len(rows))
    for _ in range(MAX_LEVELS):  # down through the corner child at the vertex
        if not len(active):
            break
        slot, s2, t2, _ = _child(s[active], t[active], tri)
        stay = slot == j0[active]
        active = active[stay]
        s[active], t[active] = s2[stay], t2[stay]
        k[active] += 1
    q, s, t, sign1 = _child(s, t, tri)   # the child away from the vertex
    r, s, t, sign2 = _child(s, t, tri)   # its child: a regular patch
    net_index = 4 * (q - (q > j0)) + r
    # S^k (P - 1 l^T P) = (S - 1 l^T)^k (P - 1 l^T P) by repeated squaring, once per (vertex, k)
    g = exact.group[cap[rows]]
    keys, inverse = np.unique(np.stack([g, k]), axis=1, return_inverse=True)
    inverse = inverse.reshape(-1)
    pair_group, pair_k = keys
    limit_values = np.einsum("gm,gmd->gd", exact.limit, ring)
    valid = np.arange(ring.shape[1]) < exact.sizes[pair_group][:, None]
    Q = (ring[pair_group] - limit_values[pair_group][:, None, :]) * valid[..., None]
    groups, local = np.unique(pair_group, return_inverse=True)
    power = exact.step[groups]
    for b in range(int(pair_k.max()).bit_length() if len(pair_k) else 0):
        use = ((pair_k >> b) & 1) == 1
        if use.any():
            Q[use] = np.einsum("pij,pjd->pid", power[local[use]], Q[use])
        power = power @ power
    D = ring.shape[-1]
    out = [np.empty((len(rows), D)) for _ in range(6 if second else 3)]
    for a in range(0, len(rows), chunk):
        z = slice(a, a + chunk)
        net = np.einsum("rgm,rmd->rgd", exact.nets[cap[rows][z], net_index[z]], Q[inverse[z]])
        res = _bezier(net, s[z], t[z], tri, second)
        # d/d(s, t) of the patch is 2^(k + 2) times its own (the sign of turned triangle frames); ldexp keeps
        # the tiny differences of deep levels and the large factor apart until the product
        sign = (sign1[z] * sign2[z])[:, None]
        e1, e2 = (k[z] + 2)[:, None], (2 * k[z] + 4)[:, None]
        a, b = js[rows][z][:, None], jt[rows][z][:, None]
        out[0][z] = limit_values[g[z]] + res[0]
        out[1][z] = np.ldexp(a * sign * res[1], e1)
        out[2][z] = np.ldexp(b * sign * res[2], e1)
        if second:
            out[3][z] = np.ldexp(a * a * res[3], e2)
            out[4][z] = np.ldexp(a * b * res[4], e2)
            out[5][z] = np.ldexp(b * b * res[5], e2)
    return rows, out
