"""The refinement of a level into the next by index arithmetic (no sorting, no hashing), as OpenSubdiv's Vtr does.

The child level follows OpenSubdiv's order: child vertices are [one per parent vertex, one per parent face
(Catmull-Clark), one per parent edge]; child faces follow parent corners; child edges are [edges inside parent
faces, two halves per parent edge]. Each scheme lays out its child corners and the step's per-corner tables
(on levels of one face size from closed forms in the face and corner position, written in blocks of faces on
the thread pool); the tail shared by both schemes assembles the child level's edge and vertex tables, its
sharpness, classes and sectors. Where each child comes from is :mod:`.parentage`'s.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..mesh import INFINITE_SHARPNESS, face_offsets_of
from ..rules import CATMULL_CLARK, CORNER, SMOOTH
from ..rules import weights as rules
from ..runtime.pages import small_pages
from .level import Level, Sectors, full_level
from .sharpness import child_sharpness, level_child_rules


def refine_level(level: Level, faces_only: bool = False, *, threads: int = 1) -> Level:
    """The next level's topology, derived from ``level`` by index arithmetic (no sorting, no hashing).

    ``faces_only`` builds just the child faces (for the last level, which nothing refines further).
    ``threads``: the per-face tables of a level of one face size (child corners, edges inside faces) are
    written in blocks of :data:`BLOCK_FACES` faces, the blocks split into that many contiguous ranges on the
    thread pool of :mod:`warp_subdiv.runtime.threads`, and the step's edge tables, vertex-corner lists and classes are
    three jobs on it (:func:`_assemble`); every block and job is computed by the same code whatever the split,
    so the result is bitwise the one-thread result.
    """
    with small_pages():
        if level.scheme == CATMULL_CLARK:
            return _refine_catmull_clark(level, faces_only, threads)
        return _refine_loop(level, faces_only, threads)


#: Faces per block of the per-face tables of a refinement step: the block's inputs and outputs stay in the
#: cache while its strided column copies run (about 1 MiB of output for a block of quads).
BLOCK_FACES = 16384


def _blocks(num_faces: int, threads: int, fill) -> None:
    """``fill(a, b)`` over the faces 0..num_faces in blocks of :data:`BLOCK_FACES`, the blocks split into
    ``threads`` contiguous ranges (:func:`warp_subdiv.runtime.threads.map_ranges`, looked up on each call, so
    that a replaced ``map_ranges`` of the threads module is the one used)."""
    from ..runtime.threads import map_ranges

    def blocks(a, b):
        for s in range(a, b, BLOCK_FACES):
            fill(s, min(b, s + BLOCK_FACES))

    map_ranges(blocks, num_faces, max(1, int(threads)), min_rows=BLOCK_FACES)


def _side(level: Level, h: np.ndarray, e: np.ndarray) -> np.ndarray:
    """0 where corner h's vertex is edge e's first vertex, else 1 (int32, like every index array below: the
    refiner refuses levels whose corners do not fit int32, and half-width temporaries halve the fresh memory
    a level touches, which is what a refinement step spends most of its time on)."""
    return (level.corner_vert[h] != level.edge_verts[e, 0]).astype(np.int32)


def _side_all(level: Level, e: np.ndarray, entering: bool = False, corner_vert=None) -> np.ndarray:
    """``_side(level, h, e[h])`` for every corner h (no gather of the corners' own vertices). ``entering``:
    ``e[h]`` is the edge that enters corner h; a degenerate edge (one vertex at both ends, level 0 only) has
    the corner it leaves at its end 0 and the corner it enters at its end 1, as OpenSubdiv's refinements.
    ``corner_vert``: the vertices of the corners ``e`` belongs to (default: every corner's)."""
    side = (level.corner_vert if corner_vert is None else corner_vert) != level.edge_verts[e, 0]
    if entering and level.degenerate_edges:
        ev = level.edge_verts
        side |= (ev[:, 0] == ev[:, 1])[e]
    return side.astype(np.int32)


class _CornerChildren:
    """Child corners of a Catmull-Clark step over a level that is not all quads (the control mesh). Child face
    h (one per parent corner) holds, in this cyclic order: the child of v_h, the child of edge h, the face
    child, the child of edge prev(h). As in OpenSubdiv, children of a quad are rotated so that the vertex child
    sits at the parent corner's position j (children of other polygons are not): type t of corner h is child
    corner 4h + (t + r) % 4, r = j for quads and 0 otherwise. (On a level of quads, h = 4f + j, that is
    16f + 4j + (j + t) % 4: :func:`_quad_index`.)"""

    def __init__(self, level: Level):
        self.level = level
        h = np.arange(level.num_corners, dtype=np.int64)
        face = level.corner_face(h)
        self.h = h
        self.r = np.where(level.face_sizes()[face] == 4, h - level.face_starts()[face], 0)

    def index(self, t: int, of_next: bool = False) -> np.ndarray:
        """Child corner of type t of every corner h (of corner_next(h) with ``of_next``), int32."""
        out = (4 * self.h + (self.r + t) % 4).astype(np.int32)
        return self.level.at_next(out) if of_next else out

    def put(self, dst: np.ndarray, t: int, values) -> None:
        """dst[child corner of type t of h] = values[h] for every corner h."""
        dst[self.index(t)] = values


def _put_quads(d: np.ndarray, t: int, values: np.ndarray) -> None:
    """d[child corner of type t of h] = values[h] for the corners h of a block of n quads (``d``: their child
    corners, (n, 4, 4)): values (n, 4) per corner or (n,) per face."""
    for j in range(4):
        d[:, j, (j + t) & 3] = values[:, j] if values.ndim == 2 else values


def _prev_in_quads(v: np.ndarray) -> np.ndarray:
    """Level.at_prev on a block (n, 4) of per-corner values of quads."""
    out = np.empty_like(v)
    out[:, 1:] = v[:, :-1]
    out[:, 0] = v[:, -1]
    return out


def _quad_index(a: int, b: int, t: int, of_next: bool = False) -> np.ndarray:
    """Child corner of type t of every corner of quads a..b (of its next corner with ``of_next``), (b - a, 4)
    int32 (:class:`_CornerChildren` on a level of quads)."""
    j = (np.arange(4) + (1 if of_next else 0)) & 3
    return (16 * np.arange(a, b, dtype=np.int32))[:, None] + (4 * j + ((j + t) & 3)).astype(np.int32)


def _catmull_clark_quad_rows(level: Level, out: dict, a: int, b: int) -> None:
    """Rows of quads a..b (parent corners 4a..4b, child corners 16a..16b) of the per-face tables of a
    Catmull-Clark step over a level of quads: what :func:`_refine_catmull_clark` computes for other levels
    from whole arrays, here from closed forms in the face and corner position (the same integer arithmetic,
    so the same values)."""
    V, F, C = level.num_vertices, level.num_faces, level.num_corners
    vert = level.corner_vert.reshape(F, 4)[a:b]
    e_h = level.corner_edge.reshape(F, 4)[a:b]
    e_prev = _prev_in_quads(e_h)
    d = out["cv"].reshape(F, 4, 4)[a:b]
    _put_quads(d, 0, vert)
    _put_quads(d, 1, V + F + e_h)
    _put_quads(d, 2, V + np.arange(a, b, dtype=np.int32))
    _put_quads(d, 3, V + F + e_prev)
    if "ce" not in out:
        return
    d = out["ce"].reshape(F, 4, 4)[a:b]
    h = np.arange(4 * a, 4 * b, dtype=np.int32).reshape(-1, 4)
    _put_quads(d, 0, C + 2 * e_h + _side_all(level, e_h, corner_vert=vert))
    _put_quads(d, 1, h)
    _put_quads(d, 2, _prev_in_quads(h))
    _put_quads(d, 3, C + 2 * e_prev + _side_all(level, e_prev, entering=True, corner_vert=vert))
    rows = slice(4 * a, 4 * b)
    iv = out["interior_verts"][rows].reshape(-1, 4, 2)
    iv[:, :, 0] = (V + np.arange(a, b, dtype=np.int32))[:, None]
    iv[:, :, 1] = V + F + e_h
    child_of_edge = _quad_index(a, b, 1)
    ic = out["interior_corners"][rows].reshape(-1, 4, 2)
    ic[:, :, 0] = child_of_edge
    ic[:, :, 1] = _quad_index(a, b, 2, of_next=True)
    out["near"][rows] = _quad_index(a, b, 0).reshape(-1)
    far = _quad_index(a, b, 3, of_next=True)
    out["far"][rows] = far.reshape(-1)
    out["face_child_corners"][rows] = _quad_index(a, b, 2).reshape(-1)
    # corners at the child of edge h, counter-clockwise: the face after the half at v_next, then the one
    # before the half at v_h
    ec = out["edge_child_corners"][rows].reshape(-1, 4, 2)
    ec[:, :, 0] = far
    ec[:, :, 1] = child_of_edge


def _refine_catmull_clark_quads(level: Level, faces_only: bool, threads: int) -> Level:
    """A Catmull-Clark step over a level of quads (every level after the first): its per-face tables
    written in blocks of faces (:func:`_catmull_clark_quad_rows`), on ``threads`` threads."""
    V, F, C, E = level.num_vertices, level.num_faces, level.num_corners, level.num_edges
    nV = V + F + E
    out = {"cv": np.empty(4 * C, dtype=np.int32)}
    if not faces_only:
        out["ce"] = np.empty(4 * C, dtype=np.int32)
        for name in ("interior_verts", "interior_corners", "edge_child_corners"):
            out[name] = np.empty((C, 2), dtype=np.int32)
        for name in ("near", "far", "face_child_corners"):
            out[name] = np.empty(C, dtype=np.int32)
    _blocks(F, threads, lambda a, b: _catmull_clark_quad_rows(level, out, a, b))
    child_hole = np.repeat(level.face_hole, 4)
    if faces_only:
        return Level(level.scheme, nV, C, 4, out["cv"], child_hole)
    return _assemble(level, _ChildSplit(
        num_vertices=nV, face_size=4, corner_vert=out["cv"], corner_edge=out["ce"], face_hole=child_hole,
        interior_verts=out["interior_verts"], interior_corners=out["interior_corners"], near=out["near"],
        far=out["far"], vertex_child_corner=out["near"], face_child_corners=out["face_child_corners"],
        edge_child_corners=out["edge_child_corners"], edge_child_base=V + F), threads)


def _refine_catmull_clark(level: Level, faces_only: bool, threads: int = 1) -> Level:
    """A Catmull-Clark step: over a level of quads in blocks of faces (:func:`_refine_catmull_clark_quads`),
    over the control mesh's polygons from whole per-corner arrays (:class:`_CornerChildren`)."""
    if level.face_size == 4:
        return _refine_catmull_clark_quads(level, faces_only, threads)
    V, F, C, E = level.num_vertices, level.num_faces, level.num_corners, level.num_edges
    children = _CornerChildren(level)
    face_ids = V + np.arange(F, dtype=np.int32)
    face_child = face_ids[level.corner_face(np.arange(C))]  # V + face of every corner
    e_h = level.corner_edge
    e_prev = level.at_prev(e_h)
    cv = np.empty(4 * C, dtype=np.int32)
    children.put(cv, 0, level.corner_vert)
    children.put(cv, 1, V + F + e_h)
    children.put(cv, 2, face_child)
    children.put(cv, 3, V + F + e_prev)
    child_hole = level.face_hole[level.corner_face(np.arange(C))]
    nV = V + F + E
    if faces_only:
        return Level(level.scheme, nV, C, 4, cv, child_hole)

    ce = np.empty(4 * C, dtype=np.int32)
    h = np.arange(C, dtype=np.int32)
    children.put(ce, 0, C + 2 * e_h + _side_all(level, e_h))
    children.put(ce, 1, h)
    children.put(ce, 2, level.at_prev(h))
    children.put(ce, 3, C + 2 * e_prev + _side_all(level, e_prev, entering=True))
    interior_verts = np.empty((C, 2), dtype=np.int32)
    interior_verts[:, 0] = face_child
    interior_verts[:, 1] = V + F + e_h
    child_of_edge = children.index(1)
    interior_corners = np.stack([child_of_edge, children.index(2, of_next=True)], axis=1)
    near = children.index(0)  # child corner on the half of edge h at v_h's side
    far = children.index(3, of_next=True)  # child corner on the half at v_next's side
    # corners at the child of edge h, counter-clockwise: the face after the half at v_next, then the one
    # before the half at v_h
    edge_child_corners = np.stack([far, child_of_edge], axis=1)
    return _assemble(level, _ChildSplit(
        num_vertices=nV, face_size=4, corner_vert=cv, corner_edge=ce, face_hole=child_hole,
        interior_verts=interior_verts, interior_corners=interior_corners, near=near, far=far,
        vertex_child_corner=near, face_child_corners=children.index(2), edge_child_corners=edge_child_corners,
        edge_child_base=V + F), threads)


def _loop_rows(level: Level, out: dict, a: int, b: int) -> None:
    """Rows of triangles a..b (parent corners 3a..3b, child corners 12a..12b) of the per-face tables of a Loop
    step: closed forms in the face f and corner position j of corner h = 3f + j."""
    V, F, C = level.num_vertices, level.num_faces, level.num_corners
    vt = level.corner_vert.reshape(F, 3)[a:b]
    e3 = level.corner_edge.reshape(F, 3)[a:b]
    et = V + e3
    # child 4f+j (j < 3): vertex child at position j, then edge j, then edge j-1; child 4f+3: edge m+1 at m
    cv = out["cv"].reshape(F, 4, 3)[a:b]
    for j in range(3):
        cv[:, j, j] = vt[:, j]
        cv[:, j, (j + 1) % 3] = et[:, j]
        cv[:, j, (j + 2) % 3] = et[:, (j + 2) % 3]
        cv[:, 3, j] = et[:, (j + 1) % 3]
    if "ce" not in out:
        return
    e_prev = np.empty_like(e3)  # Level.at_prev: a rotation inside each triangle
    e_prev[:, 1:] = e3[:, :-1]
    e_prev[:, 0] = e3[:, -1]
    half_at_h = C + 2 * e3 + _side_all(level, e3, corner_vert=vt)  # half of edge h at v_h
    half_at_prev = C + 2 * e_prev + _side_all(level, e_prev, entering=True, corner_vert=vt)  # of edge prev(h)
    h3 = np.arange(3 * a, 3 * b, dtype=np.int32).reshape(-1, 3)
    ce = out["ce"].reshape(F, 4, 3)[a:b]
    for jj in range(3):
        ce[:, jj, jj] = half_at_h[:, jj]
        ce[:, jj, (jj + 1) % 3] = h3[:, jj]
        ce[:, jj, (jj + 2) % 3] = half_at_prev[:, jj]
        ce[:, 3, jj] = h3[:, (jj + 2) % 3]
    rows = slice(3 * a, 3 * b)
    base = (12 * np.arange(a, b, dtype=np.int32))[:, None, None]  # first child corner of face f

    def block(name, *columns_of_j):
        """out[name] rows: column i is base + columns_of_j[i][j] for corner 3f + j."""
        offsets = np.array(columns_of_j, dtype=np.int32).T  # (3, n)
        out[name][rows] = (base + offsets[None]).reshape(out[name][rows].shape)

    j = np.arange(3)
    jn, jp = (j + 1) % 3, (j + 2) % 3
    # interior edge 3f+j joins the children of edges j and j-1
    iv = out["interior_verts"][rows].reshape(-1, 3, 2)
    iv[:, :, 0] = et
    iv[:, :, 1] = V + e_prev
    block("interior_corners", 3 * j + jn, 9 + jn)
    block("near", 4 * j)
    block("far", 3 * jn + j)
    # counter-clockwise around the child of edge j: child j+1, the middle child, child j
    block("edge_child_corners", 3 * jn + j, 9 + jp, 3 * j + jn)


def _refine_loop(level: Level, faces_only: bool, threads: int = 1) -> Level:
    """A Loop step over a level of triangles: its per-face tables written in blocks of faces
    (:func:`_loop_rows`), on ``threads`` threads."""
    V, F, C, E = level.num_vertices, level.num_faces, level.num_corners, level.num_edges
    if level.face_size != 3:
        raise ValueError("Loop refinement needs a triangle level")
    out = {"cv": np.empty(4 * C, dtype=np.int32)}
    if not faces_only:
        out["ce"] = np.empty(4 * C, dtype=np.int32)
        for name, width in (("interior_verts", 2), ("interior_corners", 2), ("edge_child_corners", 3)):
            out[name] = np.empty((C, width), dtype=np.int32)
        for name in ("near", "far"):
            out[name] = np.empty(C, dtype=np.int32)
    _blocks(F, threads, lambda a, b: _loop_rows(level, out, a, b))
    child_hole = np.repeat(level.face_hole, 4)
    nV = V + E
    if faces_only:
        return Level(level.scheme, nV, 4 * F, 3, out["cv"], child_hole)
    return _assemble(level, _ChildSplit(
        num_vertices=nV, face_size=3, corner_vert=out["cv"], corner_edge=out["ce"], face_hole=child_hole,
        interior_verts=out["interior_verts"], interior_corners=out["interior_corners"], near=out["near"],
        far=out["far"], vertex_child_corner=out["near"], face_child_corners=None,
        edge_child_corners=out["edge_child_corners"], edge_child_base=V), threads)


@dataclass
class _ChildSplit:
    """What a scheme's split of the parent faces hands over to :func:`_assemble`. C = the parent's corners;
    every array int32. Child edge h < C is the edge inside the parent face at parent corner h."""

    num_vertices: int  # of the child level
    face_size: int  # of the child level
    corner_vert: np.ndarray  # (4C,) of the child level
    corner_edge: np.ndarray  # (4C,) of the child level
    face_hole: np.ndarray  # of the child level
    interior_verts: np.ndarray  # (C, 2): the two end vertices of child edge h < C
    interior_corners: np.ndarray  # (C, 2): its two corners
    near: np.ndarray  # (C,): the child corner on the half of edge h at v_h's side
    far: np.ndarray  # (C,): the child corner on the half of edge h at the next vertex's side
    vertex_child_corner: np.ndarray  # (C,): the child corner of each parent corner's vertex child
    face_child_corners: np.ndarray | None  # (C,): the child corner at the face child; None (Loop)
    edge_child_corners: np.ndarray  # (C, m): the child corners at the child of edge h, counter-clockwise
    edge_child_base: int  # the first edge child's vertex index


class _EdgeSlots(NamedTuple):
    """The parent's edge -> corner lists as slots: the corners of every edge, the edge of every slot and the
    corner in it."""

    count: np.ndarray  # (E,) corners per edge
    edge: np.ndarray  # (C,) int32
    corner: np.ndarray  # (C,) the parent's edge_corners


def _assemble(level: Level, split: _ChildSplit, threads: int = 1) -> Level:
    """Shared tail of both schemes: child edges, edge->corner and vertex->corner tables, classes, thetas.

    ``threads``: the edge tables (their corner lists in ranges of the parent's edge slots), the vertex-corner lists
    and the classes are built as jobs taken from one queue by up to that many threads (the same arrays whatever
    the count)."""
    ecount = np.diff(level.edge_corner_offsets)
    slots = _EdgeSlots(ecount, np.repeat(np.arange(level.num_edges, dtype=np.int32), ecount), level.edge_corners)

    # the jobs read the parent level and the step's tables only, and write apart: with threads, at once (numpy
    # releases the GIL inside large gathers and scatters; the results do not depend on it)
    from ..runtime import threads as _threads

    edges = _ChildEdges(level, split, slots)
    done: dict = {}
    jobs = [lambda a=a, b=b: edges.fill_halves(a, b) for a, b in _threads.chunks(len(slots.edge), max(1, int(threads)))]
    jobs[:0] = [lambda: done.update(vertex=_child_vertex_corners(level, split, slots)),
                lambda: done.update(classes=_child_classes(level, split, slots))]
    _threads.run_shared(jobs, max(1, int(threads)))
    child_edge_verts, child_eoff, child_ecorners = edges.verts, edges.offsets, edges.corners
    child_voff, child_vcorners = done["vertex"]
    child_class, child_edge_sharpness, child_vert_sharpness, sectors = done["classes"]
    return full_level(
        level.scheme, split.num_vertices, split.face_size, split.corner_vert, split.face_hole,
        corner_edge=split.corner_edge, edge_verts=child_edge_verts, edge_corner_offsets=child_eoff,
        edge_corners=child_ecorners, vert_corner_offsets=child_voff, vert_corners=child_vcorners,
        vert_class=child_class, edge_sharpness=child_edge_sharpness, vert_sharpness=child_vert_sharpness,
        sectors=sectors, crease_method=level.crease_method, linear=level.linear,
    )


class _ChildEdges:
    """Child edges (nI interior ones, then halves (child of v0, child of e) and (child of v1, child of e)) and
    their corners: interior edges have two, each half as many as its parent edge. The interior edges and every
    edge's vertices are written here; the halves' corners by :meth:`fill_halves`, over ranges of the parent's
    edge slots (each range writes its own entries)."""

    def __init__(self, level: Level, split: _ChildSplit, slots: _EdgeSlots):
        self.level, self.split, self.slots = level, split, slots
        nI, E, C = level.num_corners, level.num_edges, level.num_corners
        eoff, ecount = level.edge_corner_offsets, slots.count
        self.verts = np.empty((nI + 2 * E, 2), dtype=np.int32)
        self.verts[:nI] = split.interior_verts
        halves = self.verts[nI:].reshape(E, 2, 2)
        halves[:, :, 0] = (split.edge_child_base + np.arange(E, dtype=np.int32))[:, None]
        halves[:, :, 1] = level.edge_verts
        # offsets: 2 per interior edge, then each parent edge's two halves (its corner count each), written
        # in place (no concatenation)
        self.offsets = np.empty(nI + 2 * E + 1, dtype=np.int64)
        self.offsets[:nI] = np.arange(0, 2 * nI, 2, dtype=np.int64)
        half_off = self.offsets[nI: nI + 2 * E].reshape(E, 2)
        half_off[:, 0] = 2 * nI + 2 * eoff[:-1]
        np.add(half_off[:, 0], ecount, out=half_off[:, 1])
        self.offsets[-1] = 4 * C
        self.corners = np.empty(4 * C, dtype=np.int32)
        self.corners[: 2 * nI] = split.interior_corners.reshape(-1)

    def fill_halves(self, a: int, b: int) -> None:
        """The halves' corners of the parent's edge slots a..b (slot t of edge e: its t-th corner)."""
        level, slots = self.level, self.slots
        edge, corner = slots.edge[a:b], slots.corner[a:b]
        # slot t of edge e goes to 2 nI + 2 eoff[e] + s * count[e] + t = 2 nI + eoff[e] + slot + s * count[e]
        # (s: the half; the offsets of __init__): two gathers per slot, no 2-D fancy indexing
        count = slots.count[edge]
        side = _side(level, corner, edge) * count
        base = level.edge_corner_offsets[edge] + np.arange(a + 2 * level.num_corners, b + 2 * level.num_corners,
                                                           dtype=np.int64)
        base += side
        self.corners[base] = self.split.near[corner]
        base += count
        base -= side
        base -= side
        self.corners[base] = self.split.far[corner]


def _child_vertex_corners(level: Level, split: _ChildSplit, slots: _EdgeSlots):
    """Vertex -> corners: vertex children keep their ring, face children get their face's corners, edge
    children get m corners per parent corner on the edge.

    The three blocks are gathered straight into the output, and the offsets follow from the parent's own
    offsets (vertex rings, faces, edge slots) shifted by each block's start: no per-vertex counts, no
    concatenation and no running sum over every child vertex (the same values as summing the counts)."""
    m = split.edge_child_corners.shape[1]
    V, F, E, C = level.num_vertices, level.num_faces, level.num_edges, level.num_corners
    faces = split.face_child_corners is not None
    blocks = [split.vertex_child_corner, split.edge_child_corners] + ([split.face_child_corners] if faces else [])
    kind = np.result_type(*blocks)
    ring = len(level.vert_corners)
    face_corners = C if faces else 0
    corners = np.empty(ring + face_corners + m * len(slots.corner), dtype=kind)
    if any(b.dtype != kind for b in blocks):  # mixed index types: gathered and converted as before
        corners[:ring] = split.vertex_child_corner[level.vert_corners]
        corners[ring + face_corners:] = split.edge_child_corners[slots.corner].reshape(-1)
    else:  # mode="clip": np.take buffers its output in the default mode (the indices are in range)
        np.take(split.vertex_child_corner, level.vert_corners, out=corners[:ring], mode="clip")
        np.take(split.edge_child_corners, slots.corner, axis=0, mode="clip",
                out=corners[ring + face_corners:].reshape(-1, m))
    n_face = F if faces else 0
    offsets = np.empty(V + n_face + E + 1, dtype=np.int64)
    offsets[: V + 1] = level.vert_corner_offsets
    if faces:
        corners[ring: ring + C] = split.face_child_corners
        offsets[V + 1: V + F + 1] = face_offsets_of(level.face_sizes())[1:]
        offsets[V + 1: V + F + 1] += ring
    edge_offsets = offsets[V + n_face + 1:]
    np.multiply(level.edge_corner_offsets[1:], m, out=edge_offsets)
    edge_offsets += ring + face_corners
    return offsets, corners


def _child_classes(level: Level, split: _ChildSplit, slots: _EdgeSlots):
    """Sharpness and classes: halves decay (uniform or Chaikin), edges inside faces are smooth; vertex
    children decay; classes follow from the decayed sharpness. Sectors: :func:`_child_sectors`."""
    nV, nI, V, E = split.num_vertices, level.num_corners, level.num_vertices, level.num_edges
    halves_sharpness, vertex_sharpness = child_sharpness(level)
    vertex_children_class, edge_child_class = level_child_rules(level, halves_sharpness, vertex_sharpness)
    child_edge_sharpness = np.zeros(nI + 2 * E)  # edges inside faces are smooth (zeros: no pass over memory)
    if level.edge_sharpness.any():
        child_edge_sharpness[nI:] = halves_sharpness.reshape(-1)
    n_face_children = nV - V - E
    child_vert_sharpness = np.concatenate([vertex_sharpness, np.zeros(nV - V)])
    child_class = np.concatenate([vertex_children_class, np.full(n_face_children, SMOOTH, np.int8),
                                  edge_child_class])
    if level.linear:
        child_edge_sharpness[:] = INFINITE_SHARPNESS
        child_vert_sharpness[:] = INFINITE_SHARPNESS
        child_class[:] = CORNER
    return child_class, child_edge_sharpness, child_vert_sharpness, _child_sectors(level, split, slots)


def _child_sectors(level: Level, split: _ChildSplit, slots: _EdgeSlots) -> Sectors:
    """A vertex child keeps its sectors (theta is fixed on all levels); every corner of a parent edge that is
    infinitely sharp makes one regular crease sector at the edge's child, its corners counter-clockwise."""
    infinitely_sharp = level.edge_sharpness >= INFINITE_SHARPNESS
    sharp_slots = infinitely_sharp[slots.edge] if infinitely_sharp.any() else np.zeros(len(slots.edge), dtype=bool)
    new_corners = split.edge_child_corners[slots.corner[sharp_slots]]
    k_new = new_corners.shape[1]
    n_new = len(new_corners)
    return Sectors(
        np.concatenate([level.sector_vertex, split.edge_child_base + slots.edge[sharp_slots]]),
        np.concatenate([level.sector_offsets, level.sector_offsets[-1] + k_new * np.arange(1, n_new + 1)]),
        np.concatenate([split.vertex_child_corner[level.sector_corners], new_corners.reshape(-1)]),
        np.concatenate([level.sector_theta, np.full(n_new, np.pi / k_new)]),
        np.concatenate([level.sector_kind, np.full(n_new, rules.SECTOR_CREASE, np.int8)]),
        np.concatenate([level.sector_flatness, np.full(n_new, np.nan)]),  # regular: s* = 0 (sector_flatness)
        np.concatenate([level.sector_flip, np.zeros(n_new, bool)]))
