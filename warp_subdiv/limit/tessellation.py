"""Watertight tessellation of a :class:`~warp_subdiv.limit.LimitSurface`.

Every control face is tessellated in its own parameterisation (:mod:`warp_subdiv.limit`): a quad or triangle as
one *cell*, a Catmull-Clark n-gon as its n quad sub-faces, a Loop polygon as its fan triangles. A cell's sides
lie on *lines*: the control edges, the n-gon's spokes (from an edge's middle to the face centre) and a fan's
diagonals. Every line has one rate (number of segments) and its points are shared by the cells on both sides,
so the output has no T-junctions whatever the rates of neighbouring faces:

* a cell whose opposite sides have equal rates is a uniform grid (quads, or triangles under Loop or
  ``quads=False``);
* otherwise an inner grid (rates: the larger of opposite sides; a triangle: the largest side) is joined to the
  sides by a ring of triangles (each side zipped to the inner grid's boundary row in parameter order); a cell
  too coarse for an inner grid is a fan around its centre (:mod:`warp_subdiv.limit.cell_patterns`).

Rates: ``rate`` an integer (every line), one integer per control face (an edge gets the larger rate of its
faces), or one per control edge (``LimitSurface.edges`` order; a face's inner rate is its largest edge rate);
or ``edge_length``, a target length in object space: each control edge gets ceil(length of its limit curve /
edge_length), the curve measured at 16 points. A Catmull-Clark n-gon's edges get even rates (each half is a
side of a sub-face) and its spokes half its inner rate. Diagonals of a Loop fan get the polygon's inner rate.

Output (:class:`Tessellation`): ``points`` and unit ``normals`` of the limit surface (float64), faces
(``face_vertex_counts``, ``face_vertex_indices``, int32), and for every vertex the control face and (u, v) it
was evaluated at (``base_face``, ``uv``); face-varying: ``face_base_face`` (per output face) and ``face_uv``
(per face corner: the (u, v) of that corner in the face's own control face, which differs from ``uv`` for
vertices on an edge between control faces). Face-varying data (UVs) at the output corners:
``LimitSurface.evaluate_face_varying(values, indices, face_base_face repeated per corner, face_uv[:, 0],
face_uv[:, 1], mode=...)``, which the ``tessellate`` command does with the mesh's interpolation mode.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from ..errors import SubdivInputError
from ..mesh import face_offsets_of
from .cell_patterns import QUAD, TRI, cell_pattern
from .parameterisation import FAN, SUBFACES


#: Refuse tessellations with more vertices than this (before any allocation of their size).
MAX_VERTICES = 50_000_000
#: Largest rate of one line.
MAX_RATE = 4096



@dataclass
class Tessellation:
    """A tessellated limit surface (see the module docstring)."""

    points: np.ndarray
    normals: np.ndarray
    face_vertex_counts: np.ndarray
    face_vertex_indices: np.ndarray
    base_face: np.ndarray
    uv: np.ndarray
    face_base_face: np.ndarray
    face_uv: np.ndarray
    edge_rates: np.ndarray

    @property
    def num_vertices(self) -> int:
        """The number of output vertices."""
        return len(self.points)

    @property
    def num_faces(self) -> int:
        """The number of output faces."""
        return len(self.face_vertex_counts)


# ----------------------------------------------------------------------------------------- cells and lines
@dataclass
class _Cells:
    """Cells (one row each): kind, control face, transform (u, v) = offset + scale (s, t), and per side the
    line it lies on, its start index on the line, its direction (+1 / -1) and its rate."""

    kind: np.ndarray
    face: np.ndarray
    offset: np.ndarray  # (C, 2)
    scale: np.ndarray  # (C,)
    line: np.ndarray  # (C, 4)
    start: np.ndarray  # (C, 4)
    step: np.ndarray  # (C, 4)
    rate: np.ndarray  # (C, 4)


def segment_rates(surface, rate, edge_length, lengths=None) -> tuple:
    """(edge rates (E,), face inner rates (F,)) from the arguments; ``lengths``: the edges' limit curve lengths
    where known (else measured on ``surface``)."""
    mesh = surface.mesh
    counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
    F = len(counts)
    E = len(mesh.edges.edge_verts)
    corner_edge = np.asarray(mesh.edges.corner_edge, dtype=np.int64)
    corner_face = np.repeat(np.arange(F), counts)
    if (rate is None) == (edge_length is None):
        raise SubdivInputError("give either rate or edge_length", option="rate")
    if edge_length is not None:
        if isinstance(edge_length, bool) or not isinstance(edge_length, numbers.Real) or not edge_length > 0 \
                or not np.isfinite(edge_length):
            raise SubdivInputError(f"edge_length must be a positive number, got {edge_length!r}",
                                   option="edge_length", value=edge_length)
        lengths = edge_curve_lengths(surface) if lengths is None else lengths
        edge = np.clip(np.ceil(lengths / float(edge_length)), 1, MAX_RATE).astype(np.int64)
        face = _max_per_face(edge[corner_edge], corner_face, F)
        return edge, face
    if isinstance(rate, dict):
        if set(rate) - {"faces", "edges"} or len(rate) != 1:
            raise SubdivInputError("rate as a dict must be {'faces': [...]} or {'edges': [...]}", option="rate")
        which, values = next(iter(rate.items()))
    else:
        which, values = None, rate
    arr = np.asarray(values)
    if arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
        arr = arr.astype(np.int64)
    if arr.dtype.kind not in "iu" or arr.ndim > 1:
        raise SubdivInputError(f"rate must be an integer or a 1-D array of integers, got {values!r}", option="rate")
    if np.any(arr < 1) or np.any(arr > MAX_RATE):
        raise SubdivInputError(f"rates must lie in [1, {MAX_RATE}]", option="rate")
    arr = arr.astype(np.int64)
    if arr.ndim == 0:
        return np.full(E, int(arr)), np.full(F, int(arr))
    if which is None:
        if len(arr) == F and len(arr) == E:
            raise SubdivInputError(f"{len(arr)} rates: this mesh has as many faces as edges; pass "
                                   "rate={'faces': ...} or rate={'edges': ...}", option="rate")
        which = "faces" if len(arr) == F else "edges" if len(arr) == E else None
    if which == "faces" and len(arr) == F:
        edge = np.zeros(E, dtype=np.int64)
        np.maximum.at(edge, corner_edge, arr[corner_face])
        return edge, arr
    if which == "edges" and len(arr) == E:
        return arr, _max_per_face(arr[corner_edge], corner_face, F)
    raise SubdivInputError(f"rate has {len(arr)} entries; give one per face ({F}) or per edge ({E})", option="rate")


def _max_per_face(values, corner_face, F):
    out = np.zeros(F, dtype=np.int64)
    np.maximum.at(out, corner_face, values)
    return out


def _edge_points(surface, faces, corners, t) -> tuple:
    """(u, v) at fraction ``t`` along edge ``corners`` (corner j to j + 1) of control ``faces``."""
    n = surface.face_size[faces].astype(np.int64)
    j = np.asarray(corners, dtype=np.int64)
    a = surface.vertex_uv(faces, j)
    b = surface.vertex_uv(faces, (j + 1) % n)
    uv = a + (b - a) * t[:, None]
    kind = surface.face_kind[faces]
    sub = kind == SUBFACES
    if sub.any():  # n-gon: first half in sub-face j (side a), second half in sub-face j + 1 (side d)
        w = surface.face_tiles[faces]
        jn = (j + 1) % n
        first = t < 0.5
        tile_j = np.stack([j % w, j // w], 1).astype(np.float64)
        tile_n = np.stack([jn % w, jn // w], 1).astype(np.float64)
        uv_sub = np.where(first[:, None], tile_j + np.stack([t, 0 * t], 1),
                          tile_n + np.stack([0 * t, 1.0 - t], 1))
        uv[sub] = uv_sub[sub]
    fan = kind == FAN
    if fan.any():  # Loop polygon: edge 0 in triangle 0, edge j in triangle j - 1, the last in triangle n - 3
        k = np.clip(j - 1, 0, n - 3).astype(np.float64)
        st = np.where((j == 0)[:, None], np.stack([t, 0 * t], 1),
                      np.where((j == n - 1)[:, None], np.stack([0 * t, 1.0 - t], 1), np.stack([1.0 - t, t], 1)))
        uv[fan] = (0.5 * st + np.stack([k, 0 * k], 1))[fan]
    return uv


def edge_curve_lengths(surface, edges=None) -> np.ndarray:
    """Length of every control edge's limit curve, from 16 segments evaluated on one of its faces (``edges``: a
    mask of the edges to measure; the others get 0)."""
    has, p = edge_curves(surface, edges=edges)
    lengths = np.zeros(len(has))
    lengths[has] = np.linalg.norm(np.diff(p, axis=1), axis=2).sum(axis=1)
    return lengths


def edge_curves(surface, samples: int = 17, edges=None):
    """The limit curve of every control edge, sampled: (has (E,) bool: the edge lies on a face that is not a
    hole, points (has.sum(), samples, 3): ``samples`` points evenly spaced in the parameter of one of its
    faces). The edge-length rates measure these polylines (object space); a camera's rates project them
    (:class:`warp_subdiv.usd.levels.CameraLevels`). ``edges``: a mask of the edges to sample (the others have
    ``has`` False)."""
    mesh = surface.mesh
    counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
    corner_edge = np.asarray(mesh.edges.corner_edge, dtype=np.int64)
    E = len(mesh.edges.edge_verts)
    corner_face = np.repeat(np.arange(len(counts)), counts)
    corner_index = np.arange(len(corner_face)) - np.repeat(face_offsets_of(counts)[:-1], counts)
    usable = ~surface.holes[corner_face]
    owner = np.full(E, -1, dtype=np.int64)
    order = np.flatnonzero(usable)[::-1]
    owner[corner_edge[order]] = order  # the first usable corner of each edge
    has = owner >= 0
    if edges is not None:
        has &= np.asarray(edges, dtype=bool)
    h = owner[has]
    t = np.tile(np.linspace(0.0, 1.0, samples), len(h))
    hh = np.repeat(h, samples)
    uv = _edge_points(surface, corner_face[hh], corner_index[hh], t)
    return has, surface.evaluate(corner_face[hh], uv[:, 0], uv[:, 1]).points.reshape(len(h), samples, 3)


class _Lines:
    """The lines the cells' sides lie on (control edges, then n-gon spokes and fan diagonals) and the ids of their
    inner points: line l runs from vertex ``start[l]`` to ``end[l]`` in ``rate[l]`` segments, its inner points
    numbered ``base[l]`` .. ``base[l] + rate[l] - 2``. New vertices (inner points, n-gon centres) are numbered
    from ``next_id`` on, in the order they are added."""

    def __init__(self, next_id: int):
        self.start, self.end, self.rate, self.base = [], [], [], []
        self.count = 0
        self.next_id = next_id

    def add(self, start, end, rate) -> tuple:
        """Append lines; returns (their line ids, the id of each one's first inner point)."""
        base = self.next_id + np.concatenate([[0], np.cumsum(rate - 1)[:-1]]).astype(np.int64)
        self.start.append(start)
        self.end.append(end)
        self.rate.append(rate)
        self.base.append(base)
        self.next_id += int(np.sum(rate - 1))
        ids = self.count + np.arange(len(rate))
        self.count += len(rate)
        return ids, base

    def new_vertices(self, n: int) -> np.ndarray:
        """Ids of ``n`` new vertices that lie on no line (n-gon centres)."""
        ids = self.next_id + np.arange(n)
        self.next_id += n
        return ids

    def arrays(self) -> tuple:
        """(start vertex, end vertex, rate, first inner point id) of every line."""
        return (np.concatenate(self.start), np.concatenate(self.end), np.concatenate(self.rate),
                np.concatenate(self.base))


@dataclass
class _Corners:
    """The control mesh's face corners: face sizes, each corner's vertex and edge, each face's first corner, and
    the edges' vertices."""

    counts: np.ndarray
    indices: np.ndarray
    offsets: np.ndarray
    corner_edge: np.ndarray
    edge_verts: np.ndarray

    @classmethod
    def of(cls, mesh) -> _Corners:
        counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
        return cls(counts, np.asarray(mesh.face_vertex_indices, dtype=np.int64), face_offsets_of(counts),
                   np.asarray(mesh.edges.corner_edge, dtype=np.int64), np.asarray(mesh.edges.edge_verts,
                                                                                 dtype=np.int64))

    def forward(self, h):
        """Whether corner h's edge runs from its vertex to the next corner's (the edge's own direction)."""
        return self.edge_verts[self.corner_edge[h], 0] == self.indices[h]

    def side(self, h, edge_rate) -> tuple:
        """(line, start, step, rate) of the cell side along corner h's edge, from corner h on."""
        e = self.corner_edge[h]
        fwd = self.forward(h)
        r = edge_rate[e]
        return e, np.where(fwd, 0, r), np.where(fwd, 1, -1), r


def tessellation_cells(surface, edge_rate, face_rate) -> tuple:
    """The cells of every non-hole face, and the lines (start vertex, end vertex, rate, first interior id)."""
    corners = _Corners.of(surface.mesh)
    loop = surface.triangles
    keep = ~surface.holes
    polygon = keep & (corners.counts != (3 if loop else 4))
    edge_rate = edge_rate.copy()
    if not loop and polygon.any():  # n-gons (Catmull-Clark): even rates on their edges
        pc = np.repeat(polygon, corners.counts)
        edge_rate[corners.corner_edge[pc]] += edge_rate[corners.corner_edge[pc]] % 2
    lines = _Lines(surface.mesh.num_vertices)
    _, edge_base = lines.add(corners.edge_verts[:, 0], corners.edge_verts[:, 1], edge_rate)  # control edges first
    rows = []  # per cell: kind, face, offset (2), scale, then per side line, start, step, rate
    plain = np.flatnonzero(keep & ~polygon)
    if len(plain):  # quads (Catmull-Clark) or triangles (Loop)
        n = TRI if loop else QUAD
        e, start, step, r = corners.side(corners.offsets[plain][:, None] + np.arange(n), edge_rate)
        rows.append((np.full(len(plain), n), plain, np.zeros((len(plain), 2)), np.ones(len(plain)),
                     _pad(e), _pad(start), _pad(step), _pad(r)))
    polys = np.flatnonzero(polygon)
    if len(polys) and not loop:
        rows.append(_subface_cells(surface, corners, polys, edge_rate, edge_base, face_rate, lines))
    if len(polys) and loop:
        rows.append(_fan_cells(corners, polys, edge_rate, face_rate, lines))
    cells = _Cells(*(np.concatenate([r[i] for r in rows]) if rows else None for i in range(8)))
    return cells, lines.arrays(), lines.next_id, edge_rate


def _subface_cells(surface, corners: _Corners, polys, edge_rate, edge_base, face_rate, lines: _Lines) -> tuple:
    """The cells of Catmull-Clark n-gons ``polys``: sub-face j is a quad on the half-unit tile j, its sides
    a = the first half of edge j, b = spoke j (the edge's middle to the face's centre), c = spoke j - 1 reversed,
    d = the second half of edge j - 1; spokes get half the face's inner rate."""
    centre = lines.new_vertices(len(polys))
    cnt = corners.counts[polys]
    face = np.repeat(polys, cnt)
    j = np.arange(int(cnt.sum())) - np.repeat(np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt)
    h = corners.offsets[face] + j
    e = corners.corner_edge[h]
    fwd = corners.forward(h)
    R = edge_rate[e]
    middle = edge_base[e] + R // 2 - 1  # the edge's point R/2
    spoke_rate = np.maximum(1, -(-face_rate[face] // 2))
    spoke, _ = lines.add(middle, np.repeat(centre, cnt), spoke_rate)
    first = np.repeat(np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt)
    prev = first + (j - 1) % np.repeat(cnt, cnt)  # row of sub-face j - 1
    half = R // 2
    a_start = np.where(fwd, 0, R)
    a_step = np.where(fwd, 1, -1)
    e_prev, R_prev, fwd_prev = e[prev], R[prev], fwd[prev]
    d_start = np.where(fwd_prev, R_prev // 2, R_prev // 2)
    d_step = np.where(fwd_prev, 1, -1)
    w = surface.face_tiles[face].astype(np.int64)
    offset = np.stack([j % w, j // w], 1).astype(np.float64)
    return (np.full(len(face), QUAD), face, offset, np.full(len(face), 0.5),
            np.stack([e, spoke, spoke[prev], e_prev], 1),
            np.stack([a_start, np.zeros_like(j), spoke_rate[prev], d_start], 1),
            np.stack([a_step, np.ones_like(j), -np.ones_like(j), d_step], 1),
            np.stack([half, spoke_rate, spoke_rate[prev], R_prev // 2], 1))


def _fan_cells(corners: _Corners, polys, edge_rate, face_rate, lines: _Lines) -> tuple:
    """The cells of Loop polygons ``polys``: fan triangle k = (v0, v_k+1, v_k+2) on the half-unit tile k, its
    sides edge 0 or diagonal k - 1, edge k + 1, diagonal k or the last edge; diagonals run from v0 to v_k+2 with
    the face's inner rate."""
    cnt = corners.counts[polys]
    ntri = cnt - 2
    face = np.repeat(polys, ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.concatenate([[0], np.cumsum(ntri)[:-1]]), ntri)
    nf = corners.counts[face]
    ndiag = cnt - 3
    dface = np.repeat(polys, ndiag)
    dk = np.arange(int(ndiag.sum())) - np.repeat(np.concatenate([[0], np.cumsum(ndiag)[:-1]]), ndiag)
    diag_first = lines.count + np.concatenate([[0], np.cumsum(ndiag)[:-1]])
    dbase = dict(zip(polys.tolist(), diag_first.tolist()))
    drate = np.maximum(face_rate[dface], 1)
    lines.add(corners.indices[corners.offsets[dface]], corners.indices[corners.offsets[dface] + dk + 2], drate)
    diag0 = np.array([dbase[f] for f in face.tolist()], dtype=np.int64)

    def edge_side(corner):
        return corners.side(corners.offsets[face] + corner, edge_rate)

    e0, s0, t0, r0 = edge_side(np.zeros_like(k))
    d_prev = diag0 + k - 1
    side0 = (np.where(k == 0, e0, d_prev), np.where(k == 0, s0, 0), np.where(k == 0, t0, 1),
             np.where(k == 0, r0, face_rate[face]))
    side1 = edge_side(k + 1)
    el, sl, tl, rl = edge_side(nf - 1)
    last = k == nf - 3
    d_here = diag0 + k
    side2 = (np.where(last, el, d_here), np.where(last, sl, face_rate[face]), np.where(last, tl, -1),
             np.where(last, rl, face_rate[face]))
    return (np.full(len(face), TRI), face, np.stack([k, 0 * k], 1).astype(np.float64), np.full(len(face), 0.5),
            *(_pad(np.stack([s[i] for s in (side0, side1, side2)], 1)) for i in range(4)))


def _pad(a):
    a = np.asarray(a)
    if a.shape[1] == 4:
        return a
    return np.concatenate([a, np.zeros((len(a), 4 - a.shape[1]), a.dtype)], 1)


@dataclass
class CellGroups:
    """Cells grouped by their pattern (kind and side rates), in the order :func:`tessellate` emits them: the
    ``patterns`` (one per group, in sorted key order) and the ``group`` of every cell."""

    patterns: list
    group: np.ndarray


def cell_groups(cells: _Cells, quad_cells: bool) -> CellGroups:
    """The cells' groups (:class:`CellGroups`): one :func:`cell_pattern` per distinct (kind, side rates)."""
    n_sides = np.where(cells.kind == QUAD, QUAD, TRI)
    key = np.concatenate([cells.kind[:, None], cells.rate * (np.arange(4) < n_sides[:, None])], 1)
    keys, group = np.unique(key, axis=0, return_inverse=True)
    patterns = [cell_pattern(int(k[0]), tuple(int(x) for x in k[1:1 + int(k[0])]), quad_cells) for k in keys]
    return CellGroups(patterns, group.reshape(-1))


def emit_cells(cells: _Cells, sel: np.ndarray, pat, lines: tuple, interior_base: np.ndarray) -> tuple:
    """The vertices and faces of cells ``sel`` (all of one pattern ``pat``): (vertex ids (G, local), their
    (u, v) (G, local, 2), faces as vertex ids (G, m, 4; -1 pads a triangle), the faces' corner (u, v)
    (G, m, 4, 2)). Vertices on the cells' sides get the ids of their lines' points (``lines``: start vertex,
    end vertex, rate and first inner id of every line), the interior vertices of cell i the ids
    ``interior_base[i]`` on."""
    l_start, l_end, l_rate, l_base = lines
    side = pat.boundary[:, 0]
    idx = pat.boundary[:, 1]
    line = cells.line[sel][:, side]
    x = cells.start[sel][:, side] + cells.step[sel][:, side] * idx
    R = l_rate[line]
    bid = np.where(x == 0, l_start[line], np.where(x == R, l_end[line], l_base[line] + x - 1))
    iid = np.asarray(interior_base, dtype=np.int64)[:, None] + np.arange(len(pat.interior_st))
    gid = np.concatenate([bid, iid], 1)
    st = np.concatenate([pat.boundary_st, pat.interior_st], 0)
    uv = cells.offset[sel][:, None, :] + cells.scale[sel][:, None, None] * st[None]
    f = pat.faces
    fg = np.where((f >= 0)[None], gid[:, np.maximum(f, 0)], -1)
    return gid, uv, fg, uv[:, np.maximum(f, 0)]


# ----------------------------------------------------------------------------------------- tessellate
def tessellate(surface, *, rate=None, edge_length=None, quads: bool = True) -> Tessellation:
    """A watertight tessellation of ``surface`` (a :class:`~warp_subdiv.limit.LimitSurface`); see the module
    docstring for ``rate``, ``edge_length`` and the output. ``quads``: uniform cells of Catmull-Clark faces as
    quads (else every face a triangle)."""
    edge_rate, face_rate = segment_rates(surface, rate, edge_length)
    cells, lines, next_id, edge_rate = tessellation_cells(surface, edge_rate, face_rate)
    if cells.kind is None:
        empty = np.zeros((0, 3))
        return Tessellation(empty, empty.copy(), np.zeros(0, np.int32), np.zeros(0, np.int32),
                            np.zeros(0, np.int32), np.zeros((0, 2)), np.zeros(0, np.int32), np.zeros((0, 2)),
                            edge_rate)
    estimate = int(np.sum(np.where(cells.kind == QUAD, 1, 0.5) * np.max(cells.rate, axis=1) ** 2)) + next_id
    if estimate > MAX_VERTICES:
        raise SubdivInputError(f"the tessellation would have about {estimate} vertices (more than {MAX_VERTICES}); "
                               "use a lower rate or a longer edge_length", option="rate", value=estimate)
    groups = cell_groups(cells, bool(quads) and not surface.triangles)
    all_faces, all_face_cell, all_corner_uv = [], [], []
    emit_id, emit_face, emit_uv = [], [], []
    interior_next = next_id
    for g, pat in enumerate(groups.patterns):
        sel = np.flatnonzero(groups.group == g)
        n_int = len(pat.interior_st)
        gid, uv, fg, fuv = emit_cells(cells, sel, pat, lines, interior_next + n_int * np.arange(len(sel)))
        interior_next += len(sel) * n_int
        emit_id.append(gid.reshape(-1))
        emit_face.append(np.repeat(cells.face[sel], pat.num_local))
        emit_uv.append(uv.reshape(-1, 2))
        all_faces.append(fg.reshape(-1, 4))
        all_face_cell.append(np.repeat(cells.face[sel], len(pat.faces)))
        all_corner_uv.append(fuv.reshape(-1, 4, 2))
    faces = np.concatenate(all_faces)
    face_base = np.concatenate(all_face_cell)
    corner_uv = np.concatenate(all_corner_uv)
    ids = np.concatenate(emit_id)
    used, first = np.unique(ids, return_index=True)
    remap = np.full(interior_next, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    vface = np.concatenate(emit_face)[first]
    vuv = np.concatenate(emit_uv)[first]
    ev = surface.evaluate(vface, vuv[:, 0], vuv[:, 1])
    valid = faces >= 0
    counts = valid.sum(axis=1).astype(np.int32)
    fvi = remap[faces[valid]].astype(np.int32)
    return Tessellation(points=ev.points, normals=ev.normals, face_vertex_counts=counts, face_vertex_indices=fvi,
                        base_face=vface.astype(np.int32), uv=vuv, face_base_face=face_base.astype(np.int32),
                        face_uv=corner_uv[valid], edge_rates=edge_rate)
