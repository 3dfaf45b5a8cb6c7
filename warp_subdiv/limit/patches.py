"""The patch tree of a :class:`~warp_subdiv.limit.LimitSurface`: Bezier patches over a quadtree per base face.

How the limit surface over a base face is represented (README "Limit surface", docs in :mod:`warp_subdiv.limit`):

* A face whose limit surface is a polynomial patch is one leaf: a bicubic B-spline patch (Catmull-Clark) or a
  quartic box-spline patch (Loop), converted to Bezier form (16 or 15 control points). Regular creases,
  boundaries and Catmull-Clark corners are polynomial too (B-spline phantom points; Loop's boundary phantoms
  by the parallelogram rule).
* Every other face is split into its four children (its sub-faces one level finer) and each child is
  classified again, down to ``depth`` levels below the base face. The children are computed by *local*
  refinement: the faces still to refine and ``MARGIN`` rings of faces around them are cut out of the level
  (tags, sharpness and sector data carried over), refined one step with the library's own tables
  (:func:`~warp_subdiv.tables.build_stencils`, :func:`~warp_subdiv.topology.refine_level`, flatness and
  normal-control projections), and only the children of the cut-out's inner faces are kept. So the
  evaluated surface is the surface ``refine`` converges to, with either rule set.
* A face still irregular at ``depth`` becomes an *end cap*: a bicubic (Catmull-Clark) or quartic triangular
  (Loop) Bezier patch that interpolates the exact limit positions of its corners (limit masks, one level
  deeper as ``Refiner.limit_points``), their exact tangent planes, and per corner and edge a derivative
  along the edge: the exact one at regular corners (B-spline / box-spline masks), else the derivative of the
  parabola through the exact limit points at the edge's ends and middle, projected onto the tangent plane.

A face of the control mesh that is a hole (or that ``boundary="none"`` leaves out) is a hole leaf.

Parameterisation of the tree (``LimitSurface`` maps base-face (u, v) onto it): a quad node's children are its
quadrants in corner order (0: [0, 1/2]^2, 1: u >= 1/2, 2: both >= 1/2, 3: v >= 1/2); a triangle node's
children are its corner triangles 0..2 and the middle triangle 3, whose frame is turned by 180 degrees
(s = 1 - 2u, t = 1 - 2v).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields

import numpy as np

from ..rules import limit_masks as M
from ..tables import projections
from ..tables import Hierarchy
from ..mesh import INFINITE_SHARPNESS, Mesh
from ..options import Options, Scheme
from ..rules import CATMULL_CLARK, CORNER, CREASE, DART, SECTOR_CREASE, SMOOTH, edge_gamma_shift
from ..tables import build_stencils
from ..topology import Level, base_level, refine_level

#: Rings of context faces cut out around the faces refined locally. The artificial boundary of a cut-out
#: changes the rules of its outermost ring of faces; after one step its influence reaches less than one and a
#: half rings of the parent level inward (vertex, edge and flatness rules at the cut), so children of faces
#: three or more rings inside are exact, and a child's one-ring stays inside the exact region for the next
#: step. Four rings keep a ring of slack (tested against uniform refinement).
MARGIN = 4

#: Leaf markers in ``node_patch``.
SPLIT, HOLE = -1, -2

#: Patch kinds.
REGULAR, END_CAP = 0, 1

#: Patch bases: uniform cubic B-spline over 16 indexed points, or Bezier (bicubic / quartic triangular).
BSPLINE, BEZIER = 0, 1

# ----------------------------------------------------------------------------------------- Bezier forms
#: Uniform cubic B-spline to Bezier, one direction: Bezier b_a = sum_i QUAD_BEZIER[a, i] p_i.
QUAD_BEZIER = np.array([[1, 4, 1, 0], [0, 4, 2, 0], [0, 2, 4, 0], [0, 1, 4, 1]], dtype=np.float64) / 6.0

#: Lattice coordinates (i along u, j along v) of the 16 B-spline control points of a quad patch, in the order
#: (i + 1) + 4 (j + 1): the face is [0, 1]^2 with corners (0,0), (1,0), (1,1), (0,1).
QUAD_GRID = [(i, j) for j in range(-1, 3) for i in range(-1, 3)]

#: Lattice coordinates of the 12 box-spline control points of a triangle (corners (0,0), (1,0), (0,1)) on the
#: triangular lattice with edge directions (1,0), (0,1), (-1,1).
TRI_RING = [(0, 0), (1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1), (2, 0), (1, 1), (2, -1), (0, 2), (-1, 2)]

#: Exponents (a, b, c) of (w0, w1, w2) = (1 - u - v, u, v) of the 15 quartic Bezier control points, in order.
TRI_BEZIER_INDEX = [(a, b, 4 - a - b) for a in range(4, -1, -1) for b in range(4 - a, -1, -1)]

#: Quartic box spline (the regular Loop patch) to quartic Bezier: rows TRI_BEZIER_INDEX, columns TRI_RING,
#: times 1/24. Derived as the unique refinable solution of Loop's regular rules (tests/test_limit_surface.py
#: derives it again from the stencils and de Casteljau subdivision).
LOOP_BEZIER = np.array([
    [12, 2, 2, 2, 2, 2, 2, 0, 0, 0, 0, 0],
    [12, 4, 3, 1, 0, 1, 3, 0, 0, 0, 0, 0],
    [12, 3, 4, 3, 1, 0, 1, 0, 0, 0, 0, 0],
    [8, 8, 4, 0, 0, 0, 4, 0, 0, 0, 0, 0],
    [10, 6, 6, 1, 0, 0, 1, 0, 0, 0, 0, 0],
    [8, 4, 8, 4, 0, 0, 0, 0, 0, 0, 0, 0],
    [4, 12, 3, 0, 0, 0, 3, 0, 1, 1, 0, 0],
    [6, 10, 6, 0, 0, 0, 1, 0, 1, 0, 0, 0],
    [6, 6, 10, 1, 0, 0, 0, 0, 1, 0, 0, 0],
    [4, 3, 12, 3, 0, 0, 0, 0, 1, 0, 0, 1],
    [2, 12, 2, 0, 0, 0, 2, 2, 2, 2, 0, 0],
    [3, 12, 4, 0, 0, 0, 1, 1, 3, 0, 0, 0],
    [4, 8, 8, 0, 0, 0, 0, 0, 4, 0, 0, 0],
    [3, 4, 12, 1, 0, 0, 0, 0, 3, 0, 1, 0],
    [2, 2, 12, 2, 0, 0, 0, 0, 2, 0, 2, 2],
], dtype=np.float64) / 24.0


def _lattice_lookup(points) -> tuple:
    """(offset, size, table): table[(i + offset) * size + (j + offset)] = index of lattice point (i, j) or -1."""
    offset, size = 3, 8
    table = np.full(size * size, -1, dtype=np.int64)
    for n, (i, j) in enumerate(points):
        table[(i + offset) * size + (j + offset)] = n
    return offset, size, table


_QUAD_LOOKUP = _lattice_lookup(QUAD_GRID)
_TRI_LOOKUP = _lattice_lookup(TRI_RING)


# ----------------------------------------------------------------------------------------- the tree
@dataclass
class PatchTree:
    """Nodes (quadtree per base face or sub-face), leaves' patches, and the roots of every base face.

    ``node_child`` (N, 4) int32: children of split nodes (-1 for leaves); ``node_patch`` (N,) int32: the patch
    of a leaf, ``SPLIT`` or ``HOLE``. Patches: ``patch_basis`` (P,) int32, ``BSPLINE`` (patches without sharp
    sides: 16 uniform cubic B-spline control points under Catmull-Clark, 12 quartic box-spline control points in
    ``TRI_RING`` order under Loop) or ``BEZIER`` (16 bicubic or 15 quartic triangular Bezier control points);
    ``patch_index`` (P, 16) int32: the control points, rows of
    ``points`` (V, 3) float64 (the control mesh's points, then refined points and Bezier nets; 3 + k columns
    with :func:`build`'s ``data``), in the order
    of ``QUAD_GRID`` / ``TRI_BEZIER_INDEX`` (triangles use the first 15); ``patch_kind`` (P,) int8
    ``REGULAR`` or ``END_CAP``; ``patch_level`` (P,) int8: the level of the patch's face below its base face.
    Roots: base face f (a level-0 face) owns nodes ``root_offsets[f]`` .. ``root_offsets[f + 1] - 1``: one
    node, or its sub-faces (a Catmull-Clark n-gon: the level-1 quad at each corner, in corner order).
    """

    scheme: str
    triangles: bool
    node_child: np.ndarray
    node_patch: np.ndarray
    points: np.ndarray
    patch_index: np.ndarray
    patch_basis: np.ndarray
    patch_kind: np.ndarray
    patch_level: np.ndarray
    root_offsets: np.ndarray
    depth: int
    stats: dict = field(default_factory=dict)

    @property
    def num_nodes(self) -> int:
        return len(self.node_patch)

    @property
    def num_patches(self) -> int:
        return len(self.patch_kind)

    def bezier(self, patches) -> np.ndarray:
        """(n, 16 or 15, D) Bezier control points of ``patches`` (B-spline patches converted), for tests."""
        patches = np.asarray(patches, dtype=np.int64)
        pts = self.points[self.patch_index[patches]]
        out = pts.copy()
        bs = self.patch_basis[patches] == BSPLINE
        if bs.any():
            if self.triangles:
                out[bs, :15] = regular_bezier(pts[bs, :12], "loop")
            else:
                out[bs] = regular_bezier(pts[bs], CATMULL_CLARK)
        return out[:, :15] if self.triangles else out


class _Nodes:
    """Growable node arrays."""

    def __init__(self):
        self.child = [np.zeros((0, 4), np.int32)]
        self.patch = [np.zeros(0, np.int32)]
        self.count = 0

    def new(self, n: int) -> np.ndarray:
        ids = np.arange(self.count, self.count + n, dtype=np.int64)
        self.child.append(np.full((n, 4), -1, np.int32))
        self.patch.append(np.full(n, SPLIT, np.int32))
        self.count += n
        return ids

    def freeze(self):
        self.child = [np.concatenate(self.child)]
        self.patch = [np.concatenate(self.patch)]
        return self.child[0], self.patch[0]


class _Patches:
    """Growable patch arrays and the global point array their control points index."""

    def __init__(self, width: int = 3):
        self.width = width
        self.index, self.basis, self.kind, self.level = [], [], [], []
        self.points = []
        self.num_points = 0
        self.count = 0

    def add_points(self, points: np.ndarray) -> int:
        """Append points; returns the index of the first."""
        first = self.num_points
        self.points.append(np.asarray(points, dtype=np.float64).reshape(-1, self.width))
        self.num_points += len(self.points[-1])
        return first

    def add_indexed(self, index: np.ndarray, basis: int, kind: int, level: int) -> np.ndarray:
        n = len(index)
        full = np.zeros((n, 16), dtype=np.int64)
        full[:, :index.shape[1]] = index
        self.index.append(full)
        self.basis.append(np.full(n, basis, np.int32))
        self.kind.append(np.full(n, kind, np.int8))
        self.level.append(np.full(n, level, np.int8))
        ids = np.arange(self.count, self.count + n, dtype=np.int64)
        self.count += n
        return ids

    def add_bezier(self, nets: np.ndarray, kind: int, level: int) -> np.ndarray:
        """Patches whose Bezier nets (n, 16 or 15, width) are appended to the points."""
        n, m = nets.shape[:2]
        first = self.add_points(nets.reshape(-1, self.width))
        index = first + np.arange(n * m, dtype=np.int64).reshape(n, m)
        return self.add_indexed(index, BEZIER, kind, level)

    def arrays(self):
        def cat(parts, shape, dtype):
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)
        return (cat(self.points, (0, self.width), np.float64), cat(self.index, (0, 16), np.int32),
                cat(self.basis, (0,), np.int32), cat(self.kind, (0,), np.int8), cat(self.level, (0,), np.int8))


# ----------------------------------------------------------------------------------------- one local level
@dataclass
class _Local:
    """A (possibly cut-out) level: its full topology, exact points (inside the exact region), the tree node of
    each face (-1: context only), and the prescribed normals in its own vertex ids."""

    level: Level
    points: np.ndarray
    face_node: np.ndarray
    normal_ids: np.ndarray
    normal_vectors: np.ndarray
    depth: int


def _csr_apply(table, src: np.ndarray) -> np.ndarray:
    counts = np.diff(table.offsets.astype(np.int64))
    rows = np.repeat(np.arange(len(counts)), counts)
    idx = table.indices.astype(np.int64)
    w = table.weights
    out = np.empty((len(counts), src.shape[1]))
    for c in range(src.shape[1]):
        out[:, c] = np.bincount(rows, weights=w * src[idx, c], minlength=len(counts))
    return out


def _displace(table, points: np.ndarray) -> np.ndarray:
    """Apply a flatness or normal-control DisplacementTable (every row reads the unmoved points).

    A flatness table has scalar weights and moves every column (flatness is part of the subdivision matrix, as
    ``Refiner.evaluate`` applies it to primvars). A normal-control table moves positions only, the first three
    columns: data columns carried beside them (:func:`build`'s ``data``) are refined as ``Refiner.evaluate``
    refines primvars, without normal control."""
    if table is None or table.num_rows == 0:
        return points
    counts = np.diff(table.offsets.astype(np.int64))
    rows = np.repeat(np.arange(len(counts)), counts)
    idx = table.indices.astype(np.int64)
    if table.normal_ids is not None:
        geo = np.ascontiguousarray(points[idx, :3])
        n = table.normals[table.normal_ids.astype(np.int64)]
        src = n * np.einsum("ij,ij->i", n, geo)[:, None] * table.weights[:, None]
    else:
        src = points[idx] * table.weights[:, None]
    delta = np.empty((len(counts), src.shape[1]))
    for c in range(src.shape[1]):
        delta[:, c] = np.bincount(rows, weights=src[:, c], minlength=len(counts))
    out = points.copy()
    out[table.targets.astype(np.int64), :src.shape[1]] += delta
    return out


def _face_corners(level: Level, faces: np.ndarray, n: int) -> np.ndarray:
    """(len(faces), n) corner ids of faces with n corners."""
    start = level.face_starts()[faces] if level.face_size == 0 else faces * level.face_size
    return start[:, None] + np.arange(n)


def _twin(level: Level) -> np.ndarray:
    """(C,) the corner across each corner's edge (its other corner on a two-face edge), else -1."""
    C = level.num_corners
    twin = np.full(C, -1, dtype=np.int64)
    counts = np.diff(level.edge_corner_offsets)
    h0, h1 = level.edge_corner_pair()
    two = counts == 2
    twin[h0[two]] = h1[two]
    twin[h1[two]] = h0[two]
    return twin


class _Topo:
    """Per-level lookups the gathering and classification need (built once per level)."""

    def __init__(self, level: Level, options: Options, normal_ids: np.ndarray):
        self.level = level
        self.twin = _twin(level)
        self.sizes = level.face_sizes()
        V = level.num_vertices
        es = level.edge_sharpness
        ev = level.edge_verts.astype(np.int64)
        self.edge_inf = es >= INFINITE_SHARPNESS
        semi = (es > 0) & ~self.edge_inf
        self.vert_semi = np.zeros(V, bool)
        self.vert_semi[ev[semi].reshape(-1)] = True
        vs = level.vert_sharpness
        self.vert_semi |= (vs > 0) & (vs < INFINITE_SHARPNESS)
        self.sharp_count = np.bincount(ev[es > 0].reshape(-1), minlength=V)
        self.valence = np.diff(level.vert_corner_offsets)
        counts = np.diff(level.edge_corner_offsets)
        self.boundary = np.zeros(V, bool)
        self.boundary[ev[counts != 2].reshape(-1)] = True
        # vertices whose neighbourhood follows modified rules: flatness (s > 0), the paper's crease- and
        # corner-neighbour edge rules (gamma shift), prescribed normals, darts and non-standard sectors
        special = np.zeros(V, bool)
        if level.num_sectors:
            k = level.sector_k()
            if options.piecewise_smooth:
                s = projections.resolve_flatness(level)
                shift = np.abs(edge_gamma_shift(options.scheme, level.sector_theta)) > 1e-15
                moved = (s > 0) | ((k >= 2) & shift)
                special[level.sector_vertex[moved]] = True
            regular_k = 2 if options.scheme == CATMULL_CLARK else 3
            odd = ~(((level.sector_kind == SECTOR_CREASE) & (k == regular_k)) | (k == 1))
            special[level.sector_vertex[odd]] = True
        special[normal_ids] = True
        special[level.vert_class == DART] = True
        self.special = special


def _rotate(scheme: str, vec: np.ndarray, steps: int) -> np.ndarray:
    """Lattice vectors (..., 2) turned by ``steps`` face angles (90 degrees on quads, 60 on triangles)."""
    out = vec
    for _ in range(steps % (4 if scheme == CATMULL_CLARK else 6)):
        i, j = out[..., 0], out[..., 1]
        out = np.stack([-j, i], -1) if scheme == CATMULL_CLARK else np.stack([-j, i + j], -1)
    return out


def _gather(topo: _Topo, faces: np.ndarray, scheme: str):
    """Control point ids of the regular patch of ``faces`` (each with 4 or 3 corners), phantoms not yet made.

    Returns (ids (F, G) int64 with -1 where a point lies across a sharp side or is missing, side_sharp (F, n)
    bool, sector_faces (F, n): faces of the face's sector at each corner (or -1 when the walk around the
    corner closed), ok (F,) bool: consistent lattice and all faces of the right size)."""
    level = topo.level
    n = 4 if scheme == CATMULL_CLARK else 3
    offset, size, lookup = _QUAD_LOOKUP if n == 4 else _TRI_LOOKUP
    G = 16 if n == 4 else 12
    F = len(faces)
    ids = np.full((F, G), -1, dtype=np.int64)
    ok = np.ones(F, bool)
    corners = _face_corners(level, faces, n)
    cv = level.corner_vert.astype(np.int64)
    ce = level.corner_edge.astype(np.int64)
    lat = np.array([(0, 0), (1, 0), (1, 1), (0, 1)] if n == 4 else [(0, 0), (1, 0), (0, 1)], dtype=np.int64)
    side_sharp = topo.edge_inf[ce[corners]] | (topo.twin[corners] < 0)
    sector_faces = np.zeros((F, n), dtype=np.int64)
    rows = np.arange(F)

    def put(points_lat, vertex, valid):
        points_lat = np.broadcast_to(points_lat, (F, 2))
        key = (points_lat[:, 0] + offset) * size + (points_lat[:, 1] + offset)
        inside = (points_lat[:, 0] >= -offset) & (points_lat[:, 0] < size - offset) & \
                 (points_lat[:, 1] >= -offset) & (points_lat[:, 1] < size - offset)
        slot = np.where(inside, lookup[np.clip(key, 0, size * size - 1)], -1)
        use = valid & (slot >= 0)
        r, s, v = rows[use], slot[use], vertex[use]
        prev = ids[r, s]
        clash = (prev >= 0) & (prev != v)
        ok[r[clash]] = False
        ids[r, s] = v

    for j in range(n):
        h = corners[:, j]
        c = lat[j]
        e1 = lat[(j + 1) % n] - c
        e2 = lat[(j - 1) % n] - c
        put(np.broadcast_to(c, (F, 2)), cv[h], np.ones(F, bool))
        count = np.ones(F, dtype=np.int64)
        closed = np.zeros(F, bool)
        turns = 4 if n == 4 else 6
        # counter-clockwise: across the incoming edge (prev corner -> h)
        g = h.copy()
        alive = np.ones(F, bool)
        for step in range(1, turns + 1):
            inc = level.corner_prev(g)
            t = topo.twin[inc]
            alive &= (t >= 0) & ~topo.edge_inf[ce[inc]]
            g = np.where(alive, t, g)
            back = alive & (g == h)
            closed |= back
            alive &= ~back
            if not alive.any():
                break
            alive &= topo.sizes[level.corner_face(g)] == n
            if step >= turns:
                ok[alive] = False
                break
            a1 = _rotate(scheme, e1, step)
            a2 = _rotate(scheme, e2, step)
            put(c + a1, cv[level.corner_next(g)], alive)
            put(c + a2, cv[level.corner_prev(g)], alive)
            if n == 4:
                put(c + a1 + a2, cv[level.corner_next(level.corner_next(g))], alive)
            count += alive
        # clockwise: across the outgoing edge (h -> next)
        g = h.copy()
        alive = ~closed
        for step in range(1, turns + 1):
            t = topo.twin[g]
            alive &= (t >= 0) & ~topo.edge_inf[ce[g]]
            g = np.where(alive, level.corner_next(np.maximum(t, 0)), g)
            if not alive.any():
                break
            alive &= topo.sizes[level.corner_face(g)] == n
            if step >= turns:
                ok[alive] = False
                break
            a1 = _rotate(scheme, e1, -step)
            a2 = _rotate(scheme, e2, -step)
            put(c + a1, cv[level.corner_next(g)], alive)
            put(c + a2, cv[level.corner_prev(g)], alive)
            if n == 4:
                put(c + a1 + a2, cv[level.corner_next(level.corner_next(g))], alive)
            count += alive
        sector_faces[:, j] = np.where(closed, -1, count)
    return ids, side_sharp, sector_faces, ok


def _regular(topo: _Topo, faces: np.ndarray, scheme: str):
    """(ok (F,), ids (F, G)): which faces are polynomial patches, and their gathered control point ids."""
    level = topo.level
    n = 4 if scheme == CATMULL_CLARK else 3
    if len(faces) == 0:
        return np.zeros(0, bool), np.zeros((0, 16 if n == 4 else 12), np.int64), np.zeros((0, n), bool)
    ok = topo.sizes[faces] == n
    ids, side_sharp, sector_faces, gathered = _gather(topo, faces, scheme)
    ok &= gathered
    corners = _face_corners(level, faces, n)
    v = level.corner_vert.astype(np.int64)[corners]
    vclass = level.vert_class[v]
    vs = level.vert_sharpness[v]
    sharp_n = topo.sharp_count[v]
    semi = topo.vert_semi[v]
    regular_valence = 4 if n == 4 else 6
    regular_sector = 2 if n == 4 else 3
    interior = (vclass == SMOOTH) & (sharp_n == 0) & ~topo.boundary[v] & (topo.valence[v] == regular_valence) \
        & (vs == 0) & (sector_faces == -1)
    side_in = side_sharp  # side j leaves corner j; side j-1 enters it
    side_out = np.roll(side_sharp, 1, axis=1)
    one_side = side_in ^ side_out
    crease = (vclass == CREASE) & (sharp_n == 2) & (vs == 0) & one_side & (sector_faces == regular_sector)
    corner = np.zeros_like(crease)
    if n == 4:
        sharp_or_none = (vs == 0) | (vs >= INFINITE_SHARPNESS)
        corner = (vclass == CORNER) & side_in & side_out & (sector_faces == 1) & sharp_or_none
    ok &= np.all((interior | crease | corner) & ~semi, axis=1)
    # sharp sides must be infinitely sharp or boundary (checked by the corner rules) and no modified rule may
    # reach the patch's control points
    present = np.where(ids >= 0, ids, 0)
    ok &= ~np.any(topo.special[present] & (ids >= 0), axis=1)
    return ok, ids, side_sharp


def _phantoms(points: np.ndarray, ids: np.ndarray, side_sharp: np.ndarray, scheme: str) -> np.ndarray:
    """(F, G, D) control points with the phantom points across sharp sides made (B-spline: reflection;
    box spline: parallelograms); D: the columns of ``points``."""
    F = len(ids)
    D = points.shape[1]
    P = np.where((ids >= 0)[..., None], points[np.maximum(ids, 0)], np.nan)
    if scheme == CATMULL_CLARK:
        g = P.reshape(F, 4, 4, D)  # [j + 1, i + 1]

        def at(i, j):
            return g[:, j + 1, i + 1]

        def setp(i, j, value, mask):
            g[mask, j + 1, i + 1] = value[mask]
        bottom, right, top, left = (side_sharp[:, k] for k in range(4))
        for i in (0, 1):
            setp(i, -1, 2 * at(i, 0) - at(i, 1), bottom)
            setp(i, 2, 2 * at(i, 1) - at(i, 0), top)
        for j in (0, 1):
            setp(-1, j, 2 * at(0, j) - at(1, j), left)
            setp(2, j, 2 * at(1, j) - at(0, j), right)
        # grid corners: across a sharp side by rows, else across the other side by columns
        for (i, j, di, dj, row_side, col_side) in ((-1, -1, 1, 1, bottom, left), (2, -1, -1, 1, bottom, right),
                                                   (2, 2, -1, -1, top, right), (-1, 2, 1, -1, top, left)):
            setp(i, j, 2 * at(i, j + dj) - at(i, j + 2 * dj), row_side)
            setp(i, j, 2 * at(i + di, j) - at(i + 2 * di, j), col_side & ~row_side)
        return g.reshape(F, 16, D)
    idx = {p: n for n, p in enumerate(TRI_RING)}

    def at(p):
        return P[:, idx[p]]

    rules = (  # side 0 (c0 -> c1), side 1 (c1 -> c2), side 2 (c2 -> c0): phantom = a + b - c
        ((1, -1), (0, 0), (1, 0), (0, 1), 0), ((0, -1), (-1, 0), (0, 0), (-1, 1), 0),
        ((2, -1), (1, 0), (2, 0), (1, 1), 0), ((1, 1), (1, 0), (0, 1), (0, 0), 1),
        ((2, 0), (1, 0), (2, -1), (1, -1), 1), ((0, 2), (0, 1), (-1, 2), (-1, 1), 1),
        ((-1, 1), (0, 0), (0, 1), (1, 0), 2), ((-1, 0), (0, -1), (0, 0), (1, -1), 2),
        ((-1, 2), (0, 1), (0, 2), (1, 1), 2),
    )
    for target, a, b, c, side in rules:
        mask = side_sharp[:, side]
        P[mask, idx[target]] = (at(a) + at(b) - at(c))[mask]
    return P


def _combine(weights: np.ndarray, src: np.ndarray) -> np.ndarray:
    """out[:, k] = sum_i weights[k, i] src[:, i] for src (F, I, D), term by term in the order of i: every
    column is computed by the same operations whatever D is (a data column equal to a position column gives
    the same bits; a matrix product or einsum may sum differently for other widths)."""
    out = np.zeros((src.shape[0], weights.shape[0]) + src.shape[2:])
    for k in range(weights.shape[0]):
        for i in np.flatnonzero(weights[k]):
            out[:, k] += weights[k, i] * src[:, i]
    return out


def regular_bezier(control: np.ndarray, scheme: str) -> np.ndarray:
    """Bezier control points (F, 16 or 15, D) of regular patches from their B-spline / box-spline points."""
    D = control.shape[-1]
    if scheme == CATMULL_CLARK:
        g = control.reshape(-1, 4, 4, D)  # [j, i]
        rows = _combine(QUAD_BEZIER, np.ascontiguousarray(g.transpose(0, 2, 1, 3)))  # [a (u), j]
        b = _combine(QUAD_BEZIER, np.ascontiguousarray(rows.transpose(0, 2, 1, 3)))  # [b (v), a (u)]
        return b.reshape(-1, 16, D)
    return _combine(LOOP_BEZIER, control)


# ----------------------------------------------------------------------------------------- cut-outs
def _region(level: Level, seed_faces: np.ndarray, rings: int) -> np.ndarray:
    """(F,) bool: the seed faces and every face within ``rings`` vertex rings of them."""
    F = level.num_faces
    mark = np.zeros(F, bool)
    mark[seed_faces] = True
    if rings <= 0:
        return mark
    corner_face = level.corner_face()
    cv = level.corner_vert.astype(np.int64)
    for _ in range(rings):
        vmark = np.zeros(level.num_vertices, bool)
        vmark[cv[mark[corner_face]]] = True
        hit = vmark[cv]
        mark = mark | (np.bincount(corner_face[hit], minlength=F) > 0)
    return mark


def _filter_sectors(level: Level, keep: np.ndarray, source: Level | None = None, matched: np.ndarray | None = None):
    """Keep the sectors of ``level`` where ``keep``; with ``source``, copy every per-sector field of the source's
    sector ``matched[s]`` (theta, kind, flatness and any other per-sector data) onto the kept sectors."""
    S = level.num_sectors
    k = level.sector_k()
    kept = np.flatnonzero(keep)
    members = np.repeat(keep, k)
    level.sector_corners = level.sector_corners[members]
    level.sector_offsets = np.concatenate([[0], np.cumsum(k[kept])]).astype(level.sector_offsets.dtype)
    for f in fields(level):
        name = f.name
        if not name.startswith("sector_") or name in ("sector_offsets", "sector_corners"):
            continue
        value = getattr(level, name)
        if isinstance(value, np.ndarray) and len(value) == S:
            new = value[kept]
            if source is not None and name != "sector_vertex":
                src = getattr(source, name, None)
                if isinstance(src, np.ndarray) and len(src) == source.num_sectors:
                    new = src[matched[kept]].astype(value.dtype)
            setattr(level, name, new)


def _cut_out(cur: _Local, region: np.ndarray, options: Options) -> _Local:
    """The faces of ``region`` as a level of their own: tags, sharpness and sector data carried over."""
    level = cur.level
    faces = np.flatnonzero(region)
    sizes = level.face_sizes()[faces]
    starts = level.face_starts()[faces]
    corners = (np.repeat(starts - np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
               + np.arange(int(sizes.sum())))
    cv = level.corner_vert.astype(np.int64)[corners]
    verts, local = np.unique(cv, return_inverse=True)
    vmap = np.full(level.num_vertices, -1, dtype=np.int64)
    vmap[verts] = np.arange(len(verts))
    edges = np.unique(level.corner_edge.astype(np.int64)[corners])
    es = level.edge_sharpness[edges]
    tagged = edges[es > 0]
    creases = vmap[level.edge_verts.astype(np.int64)[tagged]]
    vsharp = level.vert_sharpness[verts]
    corner_ids = np.flatnonzero(vsharp > 0)
    holes = np.flatnonzero(level.face_hole[faces])
    nmask = vmap[cur.normal_ids] >= 0 if len(cur.normal_ids) else np.zeros(0, bool)
    normal_ids = vmap[cur.normal_ids[nmask]]
    normal_vectors = cur.normal_vectors[nmask]
    mesh = Mesh(cur.points[verts, :3], sizes, local, creases=creases,
                crease_sharpness=np.minimum(level.edge_sharpness[tagged], INFINITE_SHARPNESS),
                corners=corner_ids, corner_sharpness=np.minimum(vsharp[corner_ids], INFINITE_SHARPNESS),
                holes=holes)
    o = options
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sub = base_level(mesh, o.scheme, o.boundary, o.rules, True, flatness=None, crease_method=o.crease_method)
    # sectors: keep those that match a sector of the source level (by a corner), with the source's data
    source_sector = np.full(level.num_corners, -1, dtype=np.int64)
    if level.num_sectors:
        source_sector[level.sector_corners.astype(np.int64)] = np.repeat(np.arange(level.num_sectors),
                                                                         level.sector_k())
    if sub.num_sectors:
        first = sub.sector_corners.astype(np.int64)[sub.sector_offsets[:-1]]
        matched = source_sector[corners[first]]
        keep = matched >= 0
        keep[keep] &= level.sector_vertex[matched[keep]] == verts[sub.sector_vertex[keep]]
        keep[keep] &= level.sector_k()[matched[keep]] == sub.sector_k()[keep]
        _filter_sectors(sub, keep, level, matched)
    sub.new_sector_flatness = level.new_sector_flatness
    sub.face_hole = level.face_hole[faces].copy()
    face_node = cur.face_node[faces]
    return _Local(sub, cur.points[verts], face_node, normal_ids, normal_vectors, cur.depth)


def _step(sub: _Local, options: Options) -> tuple:
    """One refinement step of a (cut-out) level: (child level, child points), with flatness and normal control."""
    o = options
    table = build_stencils(sub.level, o.rules, o.loop_beta, smooth_triangles=o.smooth_triangles)
    child = refine_level(sub.level)
    points = _csr_apply(table, sub.points)
    if o.piecewise_smooth:
        s = projections.resolve_flatness(child)
        points = _displace(projections.flatness_table(child, s), points)
        if len(sub.normal_ids) and o.normal_strength > 0:
            points = _displace(projections.normal_table(child, sub.normal_ids, sub.normal_vectors,
                                                        o.normal_strength, s, o.loop_beta), points)
    return child, points


def _child_faces(level: Level, faces: np.ndarray, scheme: str):
    """(child face ids (F, m), valid (F, m)) of ``faces``: Catmull-Clark one per corner (m = largest face),
    Loop the corner children 0..2 and the middle one (m = 4)."""
    if scheme == CATMULL_CLARK:
        sizes = level.face_sizes()[faces]
        m = int(sizes.max()) if len(faces) else 4
        starts = level.face_starts()[faces]
        j = np.arange(m)
        return starts[:, None] + j, j[None, :] < sizes[:, None]
    return 4 * faces[:, None] + np.arange(4), np.ones((len(faces), 4), bool)


# ----------------------------------------------------------------------------------------- end caps
def _limit_data(level: Level, points: np.ndarray, options: Options):
    """Limit positions (V, D) of ``level``'s vertices, the two limit tangents of every tangent pair (T, D) each,
    the unit normal of every pair (T, 3, from the positions: the first three columns) and the pairs of each
    vertex (CSR offsets (V + 1,)): one pair per sector, one for other vertices."""
    o = options
    s = projections.resolve_flatness(level) if o.piecewise_smooth else np.zeros(level.num_sectors)
    tables = projections.limit_tables(level, s, o.loop_beta, o.rules)
    pos = _csr_apply(tables.position, points)
    tu = _csr_apply(tables.tangent_u, points)
    tv = _csr_apply(tables.tangent_v, points)
    normals = np.cross(tu[:, :3], tv[:, :3])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    return pos, tu, tv, normals, tables.vertex_offsets.astype(np.int64)


def _regular_derivatives(level: Level, points: np.ndarray, vertices: np.ndarray, toward: np.ndarray, options):
    """Exact derivatives at regular vertices (valence 4 / 6 interior) along the edge to ``toward``, per unit of
    this level's parameter; NaN where the vertex is not a regular interior vertex of this level."""
    out = np.full((len(vertices), points.shape[1]), np.nan)
    scheme = options.scheme
    k = 4 if scheme == CATMULL_CLARK else 6
    valence = np.diff(level.vert_corner_offsets)[vertices]
    counts = np.diff(level.edge_corner_offsets)
    boundary = np.zeros(level.num_vertices, bool)
    boundary[level.edge_verts[counts != 2].reshape(-1)] = True
    sharp = np.zeros(level.num_vertices, bool)
    sharp[level.edge_verts[level.edge_sharpness > 0].reshape(-1)] = True
    use = (valence == k) & (level.vert_class[vertices] == SMOOTH) & ~boundary[vertices] & ~sharp[vertices]
    if not use.any():
        return out
    vs = vertices[use]
    local = projections.ring_local_vectors(level, vs, k)
    m = M.interior_masks(scheme, k, len(vs), options.loop_beta)
    p = points[local]  # (n, L, D)
    t1 = np.zeros((len(vs), points.shape[1]))
    t2 = np.zeros((len(vs), points.shape[1]))
    for j in range(p.shape[1]):  # term by term: the same operations for every column (see _combine)
        t1 += m.l1[:, j, None] * p[:, j]
        t2 += m.l2[:, j, None] * p[:, j]
    ring = local[:, 1:1 + k]
    pos = np.argmax(ring == toward[use][:, None], axis=1)
    found = ring[np.arange(len(vs)), pos] == toward[use]
    x1 = m.x1[np.arange(len(vs)), 1 + pos][:, None]
    x2 = m.x2[np.arange(len(vs)), 1 + pos][:, None]
    d = x1 * t1 + x2 * t2
    d[~found] = np.nan
    out[use] = d
    return out


def end_cap_bezier(P: np.ndarray, D_next: np.ndarray, D_prev: np.ndarray, scheme: str) -> np.ndarray:
    """Bezier control points of end caps from corner positions P (F, n, D) and, per corner, the derivatives
    along the edge to the next corner and to the previous one (F, n, D), per unit of the cap's parameter."""
    F, D = len(P), P.shape[-1]
    if scheme == CATMULL_CLARK:
        b = np.zeros((F, 4, 4, D))  # [b (v), a (u)]
        corner_uv = [(0, 0), (3, 0), (3, 3), (0, 3)]
        # (d/du, d/dv) at each corner from its (next, prev) edge derivatives
        du = [D_next[:, 0], -D_prev[:, 1], -D_next[:, 2], D_prev[:, 3]]
        dv = [D_prev[:, 0], D_next[:, 1], -D_prev[:, 2], -D_next[:, 3]]
        for j, (a, bb) in enumerate(corner_uv):
            b[:, bb, a] = P[:, j]
            sa = 1 if a == 0 else -1
            sb = 1 if bb == 0 else -1
            b[:, bb, a + sa] = P[:, j] + sa * du[j] / 3.0
            b[:, bb + sb, a] = P[:, j] + sb * dv[j] / 3.0
            b[:, bb + sb, a + sa] = b[:, bb, a + sa] + b[:, bb + sb, a] - P[:, j]
        return b.reshape(F, 16, D)
    index = {e: n for n, e in enumerate(TRI_BEZIER_INDEX)}
    out = np.zeros((F, 15, D))
    unit = [(4, 0, 0), (0, 4, 0), (0, 0, 4)]
    for j in range(3):
        out[:, index[unit[j]]] = P[:, j]
    for j in range(3):  # edge j from corner j to corner j + 1: elevated cubic Hermite
        a, b_ = j, (j + 1) % 3
        c1 = P[:, a] + D_next[:, a] / 3.0
        c2 = P[:, b_] + D_prev[:, b_] / 3.0
        q = [P[:, a], (P[:, a] + 3 * c1) / 4.0, (c1 + c2) / 2.0, (3 * c2 + P[:, b_]) / 4.0, P[:, b_]]
        for t in range(1, 4):
            e = [0, 0, 0]
            e[a], e[b_] = 4 - t, t
            out[:, index[tuple(e)]] = q[t]
    for j in range(3):  # interior point next to corner j: parallelogram of its two edge neighbours
        e_next = [0, 0, 0]
        e_next[j], e_next[(j + 1) % 3] = 3, 1
        e_prev = [0, 0, 0]
        e_prev[j], e_prev[(j + 2) % 3] = 3, 1
        inner = [1, 1, 1]
        inner[j] = 2
        out[:, index[tuple(inner)]] = out[:, index[tuple(e_next)]] + out[:, index[tuple(e_prev)]] - P[:, j]
    return out


def _end_caps(sub: _Local, child: Level, child_points: np.ndarray, faces: np.ndarray, options: Options):
    """Bezier nets of end caps over ``faces`` of ``sub`` (local ids), from the limit masks of ``child`` (one
    level deeper, where the masks of the faces' corners are exact)."""
    scheme = options.scheme
    n = 4 if scheme == CATMULL_CLARK else 3
    level = sub.level
    pos, pair_tu, pair_tv, pair_normals, voff = _limit_data(child, child_points, options)
    corners = _face_corners(level, faces, n)
    c = level.corner_vert.astype(np.int64)[corners]  # vertex children keep their ids
    # the child corner of each face corner: the corner child face holds the vertex child; its next and previous
    # corners are the children of the face's edges at that corner
    kids, _ = _child_faces(level, faces, scheme)
    child_corner = np.empty_like(corners)
    for j in range(n):
        f = kids[:, j]
        cc = _face_corners(child, f, n)
        at = np.argmax(child.corner_vert.astype(np.int64)[cc] == c[:, j][:, None], axis=1)
        child_corner[:, j] = cc[np.arange(len(f)), at]
    ccv = child.corner_vert.astype(np.int64)
    mid_next = ccv[child.corner_next(child_corner)]
    mid_prev = ccv[child.corner_prev(child_corner)]
    P = pos[c]
    # tangent plane of each corner: the limit tangents; where a vertex has several sectors, the sector whose
    # normal is closest to the face's own normal at that corner (positions decide: the first three columns)
    geometry = child_points[:, :3]
    geo = np.cross(geometry[mid_next] - geometry[c], geometry[mid_prev] - geometry[c])
    count = voff[c + 1] - voff[c]
    pair = np.where(count > 0, np.minimum(voff[c], max(len(pair_normals) - 1, 0)), -1)
    multi = count > 1
    if multi.any():
        best = np.full(c.shape, -np.inf)
        for t in range(int(count.max())):
            has = multi & (count > t)
            candidate = np.where(has, voff[c] + t, 0)
            score = np.einsum("...c,...c->...", pair_normals[candidate], geo)
            better = has & (score > best)
            pair[better] = candidate[better]
            best = np.where(better, score, best)
    # derivatives along the face's edges, per unit of the face's parameter (twice the child level's), projected
    # onto the tangent plane. The positions' derivative d becomes its orthogonal projection written in the
    # plane's limit tangents, x t_u + y t_v (Gram-Schmidt on the positions' tangents); a data column gets the
    # same combination of its own limit tangents, so every column is a linear function of the control values
    # with the positions' weights. Where the positions' tangents are (nearly) parallel (a singular point, e.g.
    # under normal control) the positions are projected along the pair's normal and data columns are not.
    if not len(pair_tu):  # no tangent pairs at all: nothing to project on
        pair_tu = pair_tv = np.zeros((1, child_points.shape[1]))
        pair_normals = np.zeros((1, 3))
        pair[:] = -1
    t_u = pair_tu[np.maximum(pair, 0)]
    t_v = pair_tv[np.maximum(pair, 0)]
    N = pair_normals[np.maximum(pair, 0)] * (pair >= 0)[..., None]
    g_u, g_v = np.ascontiguousarray(t_u[..., :3]), np.ascontiguousarray(t_v[..., :3])
    len_u = np.sqrt(np.einsum("...c,...c->...", g_u, g_u))
    e1 = g_u / np.where(len_u > 0, len_u, 1.0)[..., None]
    along = np.einsum("...c,...c->...", g_v, e1)
    w = g_v - along[..., None] * e1
    len_w = np.sqrt(np.einsum("...c,...c->...", w, w))
    len_v = np.sqrt(np.einsum("...c,...c->...", g_v, g_v))
    plane = (pair >= 0) & (len_u > 0) & (len_w > 1e-6 * len_v)
    len_u = np.where(plane, len_u, 1.0)
    len_w = np.where(plane, len_w, 1.0)
    D = []
    far = [np.roll(c, -1, axis=1), np.roll(c, 1, axis=1)]
    for mid, end in ((mid_next, far[0]), (mid_prev, far[1])):
        exact = 2.0 * _regular_derivatives(child, child_points, c.reshape(-1), mid.reshape(-1),
                                           options).reshape(c.shape + (child_points.shape[1],))
        parabola = -3.0 * P + 4.0 * pos[mid] - pos[end]
        d = np.where(np.isnan(exact[..., :1]), parabola, exact)
        dg = np.ascontiguousarray(d[..., :3])
        alpha = np.einsum("...c,...c->...", dg, e1)
        beta = np.einsum("...c,...c->...", dg, w) / len_w
        x = (alpha / len_u - beta * along / (len_w * len_u))[..., None]
        y = (beta / len_w)[..., None]
        singular = d.copy()
        singular[..., :3] = dg - np.einsum("...c,...c->...", dg, N)[..., None] * N
        d = np.where(plane[..., None], x * t_u + y * t_v, singular)
        D.append(d)
    return end_cap_bezier(P, D[0], D[1], scheme)


# ----------------------------------------------------------------------------------------- building
def build(mesh: Mesh, options: Options, depth: int, *, data: np.ndarray | None = None) -> PatchTree:
    """The patch tree of ``mesh`` with ``options``: irregular faces refined locally down to ``depth`` levels
    below their base face (``depth`` >= 1), end caps below that.

    ``data`` (V, k) float64: per-vertex data carried beside the positions: the tree's ``points`` then have
    3 + k columns, the data's Bezier and B-spline control values after the positions'. Every decision that
    depends on geometry (sector angles, end caps' tangent planes, sectors of several-sector corners) is taken
    from the positions, and each data column goes through the same linear operations as a position column
    (flatness included, normal control not, as ``Refiner.evaluate`` refines primvars): the data's control
    values are a linear function of ``data`` with the positions' weights, and a data column equal to a position
    column gets the same bits where normal control is off."""
    o = options
    scheme = o.scheme.value if isinstance(o.scheme, Scheme) else str(o.scheme)
    triangles = o.scheme == Scheme.LOOP
    n = 3 if triangles else 4
    hierarchy = Hierarchy(mesh, 0, o)
    level0 = hierarchy.final
    normal_ids = hierarchy.normal_vertices.astype(np.int64)
    if o.normal_strength <= 0:
        normal_ids = normal_ids[:0]
    normal_vectors = np.asarray(hierarchy.normal_vectors, dtype=np.float64).reshape(-1, 3)[:len(normal_ids)]
    nodes = _Nodes()
    base_points = np.asarray(mesh.points, dtype=np.float64)
    if data is not None:
        base_points = np.concatenate([base_points, np.asarray(data, dtype=np.float64).reshape(len(base_points), -1)],
                                     axis=1)
    patches = _Patches(base_points.shape[1])
    patches.add_points(base_points)
    F0 = level0.num_faces
    sizes0 = level0.face_sizes()
    direct = sizes0 == n
    root_count = np.where(direct, 1, sizes0)
    root_offsets = np.concatenate([[0], np.cumsum(root_count)]).astype(np.int64)
    nodes.new(int(root_offsets[-1]))
    stats = {"levels": [], "end_caps": 0, "regular_base_faces": 0}
    face_node = np.full(F0, -1, dtype=np.int64)
    face_node[direct] = root_offsets[:-1][direct]
    cur = _Local(level0, base_points, face_node, normal_ids, normal_vectors, 0)

    def classify(local: _Local, faces: np.ndarray) -> np.ndarray:
        """Make leaves of the hole and regular faces among ``faces``; returns the others."""
        fnode = local.face_node[faces]
        hole = local.level.face_hole[faces]
        _set_patch(nodes, fnode[hole], HOLE)
        faces, fnode = faces[~hole], fnode[~hole]
        topo = _Topo(local.level, o, local.normal_ids)
        ok, ids, side_sharp = _regular(topo, faces, scheme)
        if ok.any():
            ids, side_sharp, fn = ids[ok], side_sharp[ok], fnode[ok]
            plain = ~side_sharp.any(axis=1)
            if plain.any():  # B-spline / box-spline patches over the level's own points
                if local.depth == 0:
                    index = ids[plain]
                else:
                    used, inverse = np.unique(ids[plain], return_inverse=True)
                    index = patches.add_points(local.points[used]) + inverse.reshape(-1, ids.shape[1])
                _set_patch(nodes, fn[plain], patches.add_indexed(index, BSPLINE, REGULAR, local.depth))
            rest = ~plain
            if rest.any():
                control = _phantoms(local.points, ids[rest], side_sharp[rest], scheme)
                _set_patch(nodes, fn[rest], patches.add_bezier(regular_bezier(control, scheme), REGULAR,
                                                                local.depth))
        return faces[~ok]

    todo = classify(cur, np.flatnonzero(direct))
    stats["regular_base_faces"] = int(direct.sum() - len(todo))
    # n-gons (Catmull-Clark): the face itself is refined; its sub-faces (level 1) are its roots
    polygon_faces = np.flatnonzero(~direct)
    todo = np.union1d(todo, polygon_faces).astype(np.int64)
    while len(todo):
        last = cur.depth >= depth
        region = _region(cur.level, todo, MARGIN)
        if region.all():
            sub, sub_todo, region_faces = cur, todo, None
        else:
            sub = _cut_out(cur, region, o)
            region_faces = np.flatnonzero(region)
            sub_todo = np.searchsorted(region_faces, todo)
        child, child_points = _step(sub, o)
        if last:
            caps = _end_caps(sub, child, child_points, sub_todo, o)
            _set_patch(nodes, sub.face_node[sub_todo], patches.add_bezier(caps, END_CAP, cur.depth))
            stats["end_caps"] = len(caps)
            break
        kids, valid = _child_faces(sub.level, sub_todo, scheme)
        child_node = np.full(child.num_faces, -1, dtype=np.int64)
        tn = sub.face_node[sub_todo]
        rows = np.flatnonzero(tn >= 0)
        new = nodes.new(4 * len(rows)).reshape(-1, 4)
        _set_children(nodes, tn[rows], new)
        for j in range(4):
            child_node[kids[rows, j]] = new[:, j]
        for r in np.flatnonzero(tn < 0):  # n-gon base faces (level 0 only): their roots
            f = int(sub_todo[r] if region_faces is None else region_faces[sub_todo[r]])
            for j in range(int(sizes0[f])):
                child_node[kids[r, j]] = root_offsets[f] + j
        nxt = _Local(child, child_points, child_node, sub.normal_ids, sub.normal_vectors, cur.depth + 1)
        todo = classify(nxt, np.flatnonzero(child_node >= 0))
        stats["levels"].append({"level": nxt.depth, "faces_refined": int(sub.level.num_faces),
                                "irregular": int(len(todo))})
        cur = nxt
    node_child, node_patch = nodes.freeze()
    left = np.flatnonzero((node_patch == SPLIT) & np.any(node_child < 0, axis=1))
    if len(left):
        raise AssertionError(f"{len(left)} patch tree nodes were left without a patch")
    points, index, basis, kind, plevel = patches.arrays()
    return PatchTree(scheme, triangles, node_child, node_patch, points, index, basis, kind, plevel, root_offsets,
                     depth, stats)


def _set_patch(nodes: _Nodes, node_ids, values) -> None:
    nodes.freeze()
    nodes.patch[0][np.asarray(node_ids, dtype=np.int64)] = values


def _set_children(nodes: _Nodes, node_ids, children) -> None:
    nodes.freeze()
    nodes.child[0][np.asarray(node_ids, dtype=np.int64)] = children


def _children_of(nodes: _Nodes, node_ids) -> np.ndarray:
    nodes.freeze()
    return nodes.child[0][np.asarray(node_ids, dtype=np.int64)].astype(np.int64)
