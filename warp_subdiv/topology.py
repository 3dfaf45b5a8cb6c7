"""Topology: flat index tables for one subdivision level, and their refinement by index arithmetic.

A :class:`Level` stores faces as corners (a corner is a face's use of a vertex, and also the half-edge from
that vertex to the next corner's vertex), edges with their corners, vertices with their corners, the vertex
classes of RULES.md section 1, and the sector angle theta of every corner at a crease or corner vertex.

The control mesh (level 0) is analysed once, with sorting (edges, rings, fans, sectors). Every later level
is derived from its parent's tables by index arithmetic, as OpenSubdiv's Vtr does, in OpenSubdiv's order:
child vertices are [one per parent vertex, one per parent face (Catmull-Clark), one per parent edge];
child faces follow parent corners; child edges are [edges inside parent faces, two halves per parent edge].
"""
from __future__ import annotations

import contextlib
import threading
import warnings
from dataclasses import dataclass

import numpy as np

from . import rules
from .errors import NonManifoldWarning, SubdivInputError
from .mesh import INFINITE_SHARPNESS, Mesh, MeshEdges, face_offsets_of, find_edges
from .rules import CATMULL_CLARK, CORNER, CREASE, DART, LOOP, SMOOTH

BOUNDARY_MODES = ("edge-and-corner", "edge-only", "none")
RULE_SETS = ("piecewise-smooth", "opensubdiv")
CREASE_METHODS = ("uniform", "chaikin")


def _offsets(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=out[1:])
    return out


def _rows_of(offsets: np.ndarray) -> np.ndarray:
    """Row id of every entry of a CSR layout."""
    return np.repeat(np.arange(len(offsets) - 1, dtype=np.int64), np.diff(offsets))


def expand_counts(counts: np.ndarray):
    """For a list of groups of the given sizes: (group of each item, rank of the item inside its group)."""
    counts = np.asarray(counts, dtype=np.int64)
    group = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    rank = np.arange(len(group), dtype=np.int64) - np.repeat(_offsets(counts)[:-1], counts)
    return group, rank


def _i32(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int32)


@dataclass
class Level:
    """Topology of one level. Arrays are int32 unless noted; C = number of corners."""

    scheme: str
    num_vertices: int
    num_faces: int
    face_size: int  # 3 or 4 when every face has that size, 0 for mixed polygons (control mesh only)
    corner_vert: np.ndarray  # (C,)
    face_hole: np.ndarray  # (F,) bool
    # the rest is absent on a "faces only" level (the last one, which nothing refines further)
    face_offsets: np.ndarray | None = None  # (F+1,) int64, only for mixed polygons
    corner_next_table: np.ndarray | None = None  # (C,), only for mixed polygons
    corner_edge: np.ndarray | None = None  # (C,) edge from this corner to the next one
    edge_verts: np.ndarray | None = None  # (E, 2)
    edge_corner_offsets: np.ndarray | None = None  # (E+1,) int64
    edge_corners: np.ndarray | None = None  # (C,) corners whose edge is e
    vert_corner_offsets: np.ndarray | None = None  # (V+1,) int64
    vert_corners: np.ndarray | None = None  # (C,) corners at v
    edge_sharp: np.ndarray | None = None  # (E,) bool: sharpness > 0
    vert_class: np.ndarray | None = None  # (V,) int8, rules.SMOOTH/DART/CREASE/CORNER
    edge_sharpness: np.ndarray | None = None  # (E,) float64: 0 smooth, >= 10 infinitely sharp
    vert_sharpness: np.ndarray | None = None  # (V,) float64
    crease_method: str = "uniform"  # how semi-sharp edges decay: "uniform" (by 1) or "chaikin"
    linear: bool = False  # every vertex a corner and every edge sharp on every level: bilinear refinement
    semi_sharp: bool | None = None  # cached: does any edge or vertex have a finite, non-zero sharpness?
    # sectors of crease and corner vertices (RULES.md section 0): corners listed counter-clockwise from the
    # face after the first crease edge; theta and kind per RULES.md section 2; flatness s (NaN: optimal s*)
    sector_vertex: np.ndarray | None = None  # (S,)
    sector_offsets: np.ndarray | None = None  # (S+1,) int64
    sector_corners: np.ndarray | None = None  # (sum k,)
    sector_theta: np.ndarray | None = None  # (S,) float64
    sector_kind: np.ndarray | None = None  # (S,) int8, rules.SECTOR_*
    sector_flatness: np.ndarray | None = None  # (S,) float64
    new_sector_flatness: float = float("nan")  # s of the regular crease sectors that later levels create

    @property
    def num_corners(self) -> int:
        return len(self.corner_vert)

    @property
    def num_edges(self) -> int:
        return len(self.edge_verts)

    def face_sizes(self) -> np.ndarray:
        if self.face_size:
            return np.full(self.num_faces, self.face_size, dtype=np.int64)
        return np.diff(self.face_offsets)

    def face_starts(self) -> np.ndarray:
        if self.face_size:
            return np.arange(self.num_faces, dtype=np.int64) * self.face_size
        return self.face_offsets[:-1]

    def corner_face(self, h=None) -> np.ndarray:
        if h is None:
            h = np.arange(self.num_corners, dtype=np.int64)
        if self.face_size:
            return h // self.face_size
        return np.searchsorted(self.face_offsets, h, side="right") - 1

    def corner_next(self, h: np.ndarray) -> np.ndarray:
        if self.face_size:
            n = self.face_size
            j = h % n
            return h - j + (j + 1) % n
        return self.corner_next_table[h]

    def corner_prev(self, h: np.ndarray) -> np.ndarray:
        if self.face_size:
            n = self.face_size
            j = h % n
            return h - j + (j + n - 1) % n
        f = self.corner_face(h)
        start = self.face_offsets[f]
        end = self.face_offsets[f + 1]
        return np.where(h == start, end - 1, h - 1)

    def at_next(self, values: np.ndarray) -> np.ndarray:
        """``values[corner_next(h)]`` for every corner h (``values``: one per corner). On a level of one face
        size this is a rotation inside each face: no index array, one output array."""
        if self.face_size:
            v = values.reshape(-1, self.face_size)
            out = np.empty_like(v)
            out[:, :-1] = v[:, 1:]
            out[:, -1] = v[:, 0]
            return out.reshape(-1)
        return values[self.corner_next_table]

    def at_prev(self, values: np.ndarray) -> np.ndarray:
        """``values[corner_prev(h)]`` for every corner h, as :meth:`at_next`."""
        if self.face_size:
            v = values.reshape(-1, self.face_size)
            out = np.empty_like(v)
            out[:, 1:] = v[:, :-1]
            out[:, 0] = v[:, -1]
            return out.reshape(-1)
        return values[self.corner_prev(np.arange(self.num_corners, dtype=np.int64))]

    @property
    def num_sectors(self) -> int:
        return 0 if self.sector_vertex is None else len(self.sector_vertex)

    def sector_k(self) -> np.ndarray:
        """Crease degree k (number of faces) of every sector."""
        return np.diff(self.sector_offsets)

    def corner_theta(self, corners=None) -> np.ndarray:
        """theta of the sector that holds each of ``corners`` (default: all), NaN at corners outside sectors.

        Looked up among the (few) sector corners, so asking for some corners costs no per-corner array."""
        query = np.arange(self.num_corners) if corners is None else np.asarray(corners, dtype=np.int64)
        members = self.sector_corners.astype(np.int64)
        if len(members) == 0:
            return np.full(len(query), np.nan)
        order = np.argsort(members)
        sorted_members = members[order]
        theta = np.repeat(self.sector_theta, self.sector_k())[order]
        pos = np.minimum(np.searchsorted(sorted_members, query), len(members) - 1)
        return np.where(sorted_members[pos] == query, theta[pos], np.nan)

    def edge_corner_pair(self):
        """(h0, h1): the first and second corner of every edge (h1 = h0 on boundary edges), int32."""
        eoff = self.edge_corner_offsets
        h0 = self.edge_corners[eoff[:-1]]
        h1 = self.edge_corners[np.minimum(eoff[:-1] + 1, len(self.edge_corners) - 1)]
        return h0, h1

    def face_vertex_counts(self) -> np.ndarray:
        return self.face_sizes().astype(np.int32)

    def nbytes(self) -> int:
        total = 0
        for value in self.__dict__.values():
            if isinstance(value, np.ndarray):
                total += value.nbytes
        return total


# --------------------------------------------------------------------------------------------------------
# sharpness (OpenSubdiv's Sdc::Crease semantics; DeRose, Kass, Truong 1998)


def vertex_rule(vert_sharpness: np.ndarray, sharp_count: np.ndarray) -> np.ndarray:
    """Vertex class from its sharpness and its number of sharp edges: a sharp vertex or more than two sharp
    edges is a corner, two a crease, one a dart, none interior."""
    out = np.choose(np.minimum(sharp_count, 3), [SMOOTH, DART, CREASE, CORNER]).astype(np.int8)
    out[vert_sharpness > 0] = CORNER
    return out


def decrement_sharpness(s: np.ndarray) -> np.ndarray:
    """One level of uniform decay: infinite stays infinite, s > 1 becomes s - 1, the rest 0."""
    return np.where(s >= INFINITE_SHARPNESS, INFINITE_SHARPNESS, np.where(s > 1.0, s - 1.0, 0.0))


def semi_sharp_vertices(edge_verts, edge_sharpness, vert_sharpness) -> np.ndarray:
    """Vertices with a semi-sharp (finite, non-zero) sharpness or a semi-sharp incident edge."""
    semi_edge = (edge_sharpness > 0) & (edge_sharpness < INFINITE_SHARPNESS)
    out = (vert_sharpness > 0) & (vert_sharpness < INFINITE_SHARPNESS)
    out[edge_verts[semi_edge].reshape(-1)] = True
    return out


def has_semi_sharpness(level: Level) -> bool:
    """True when some edge or vertex of the level has a finite, non-zero sharpness."""
    if level.semi_sharp is None:
        es, vs = level.edge_sharpness, level.vert_sharpness
        level.semi_sharp = bool(np.any((es > 0) & (es < INFINITE_SHARPNESS)) or
                                np.any((vs > 0) & (vs < INFINITE_SHARPNESS)))
    return level.semi_sharp


def child_sharpness(level: Level):
    """Sharpness after one step: (halves (E, 2) -- the child of edge e at its end j --, vertex children (V,)).

    Uniform creasing decrements by one. Chaikin creasing (OpenSubdiv's CREASE_CHAIKIN) gives the child at
    vertex v 3/4 of the edge's sharpness plus 1/4 of the mean of v's other semi-sharp edges, minus one.
    Without semi-sharp features nothing changes (0 stays 0, infinite stays infinite)."""
    if not has_semi_sharpness(level):
        return np.repeat(level.edge_sharpness[:, None], 2, axis=1), level.vert_sharpness
    es = level.edge_sharpness
    ev = level.edge_verts.astype(np.int64)
    decremented = decrement_sharpness(es)
    halves = np.stack([decremented, decremented], axis=1)
    semi = (es > 0) & (es < INFINITE_SHARPNESS)
    if level.crease_method == "chaikin" and np.any(semi):
        V = level.num_vertices
        ends = ev.reshape(-1)
        valence = np.bincount(ends, minlength=V)
        semi_sum = np.bincount(ends, weights=np.repeat(np.where(semi, es, 0.0), 2), minlength=V)
        semi_count = np.bincount(ends, weights=np.repeat(semi.astype(np.float64), 2), minlength=V)
        for j in (0, 1):
            v = ev[:, j]
            others = semi_count[v] - 1
            chaikin = semi & (valence[v] >= 2) & (others >= 1)
            mean_other = (semi_sum[v] - es) / np.maximum(others, 1)
            value = 0.75 * es + 0.25 * mean_other - 1.0
            halves[:, j] = np.where(chaikin, np.where(value > 0, value, 0.0), halves[:, j])
    return halves, decrement_sharpness(level.vert_sharpness)


def child_rules(level: Level, halves: np.ndarray, child_vertex_sharpness: np.ndarray):
    """Classes of the vertex children (V,) and edge children (E,) after one step."""
    if not has_semi_sharpness(level):  # rules do not change: vertex children keep theirs
        return level.vert_class, np.where(level.edge_sharp, CREASE, SMOOTH).astype(np.int8)
    V = level.num_vertices
    ev = level.edge_verts.astype(np.int64)
    count = np.bincount(ev[:, 0], weights=(halves[:, 0] > 0), minlength=V) + np.bincount(
        ev[:, 1], weights=(halves[:, 1] > 0), minlength=V)
    vertex_children = vertex_rule(child_vertex_sharpness, count.astype(np.int64))
    edge_children = vertex_rule(np.zeros(len(ev)), (halves > 0).sum(axis=1))
    return vertex_children, edge_children


def fractional_weight(level: Level, halves: np.ndarray, child_vertex_sharpness: np.ndarray) -> np.ndarray:
    """Weight of the parent rule where a vertex's rule changes during this step (Sdc ComputeFractionalWeight):
    the mean sharpness of the features that become smooth, at most 1."""
    V = level.num_vertices
    es = level.edge_sharpness
    ev = level.edge_verts.astype(np.int64)
    pv = level.vert_sharpness
    total = np.where((pv > 0) & (child_vertex_sharpness <= 0), pv, 0.0)
    count = ((pv > 0) & (child_vertex_sharpness <= 0)).astype(np.float64)
    for j in (0, 1):
        if level.crease_method == "uniform":
            ending = (es > 0) & (es <= 1.0)
        else:
            ending = (es > 0) & (halves[:, j] <= 0)
        total = total + np.bincount(ev[:, j], weights=np.where(ending, es, 0.0), minlength=V)
        count = count + np.bincount(ev[:, j], weights=ending.astype(np.float64), minlength=V)
    return np.where(count > 0, np.minimum(total / np.maximum(count, 1), 1.0), 0.0)


# --------------------------------------------------------------------------------------------------------
# level 0


def triangulate(counts: np.ndarray, indices: np.ndarray):
    """Fan-triangulate every polygon from its first corner: (v0, v_i, v_i+1), i = 1..n-2.

    Returns (counts, indices, parent face of each triangle). Polygon edges stay edges, so crease and
    concave tags given as vertex pairs keep their meaning; the diagonals are new smooth edges.
    """
    counts = np.asarray(counts, dtype=np.int64)
    offsets = face_offsets_of(counts)
    parent, i = expand_counts(counts - 2)
    start = offsets[parent]
    tri = np.stack([indices[start], indices[start + i + 1], indices[start + i + 2]], axis=1)
    return np.full(len(parent), 3, dtype=np.int32), tri.reshape(-1).astype(np.int32), parent


def _fan_labels(corner_vert, cw, ccw, max_valence):
    """Label every corner with the smallest corner of its fan (faces around a vertex joined through edges)."""
    label = np.arange(len(corner_vert), dtype=np.int64)
    a, b = cw.copy(), ccw.copy()
    steps = int(np.ceil(np.log2(max(max_valence, 2)))) + 1
    for _ in range(steps):
        label = np.minimum(label, np.minimum(label[a], label[b]))
        a, b = a[a], b[b]
    return label


def _list_rank(link: np.ndarray, max_valence: int):
    """Follow ``link`` to its fixed point (pointer jumping): returns (head, distance to head)."""
    idx = np.arange(len(link), dtype=np.int64)
    link = link.astype(np.int64)
    dist = (link != idx).astype(np.int64)
    steps = int(np.ceil(np.log2(max(max_valence, 2)))) + 1
    for _ in range(steps):
        dist = dist + dist[link]
        link = link[link]
    return link, dist


def base_level(
    mesh: Mesh,
    scheme: str,
    boundary: str = "edge-and-corner",
    rule_set: str = "piecewise-smooth",
    triangulate_polygons: bool = True,
    flatness=None,
    crease_method: str = "uniform",
    linear: bool = False,
) -> Level:
    """Analyse the control mesh: edges, fans, manifoldness, vertex classes and sectors."""
    if scheme not in rules.SCHEMES:
        raise ValueError(f"scheme must be one of {rules.SCHEMES}, got {scheme!r}")
    if boundary not in BOUNDARY_MODES:
        raise ValueError(f"boundary must be one of {BOUNDARY_MODES}, got {boundary!r}")
    if rule_set not in RULE_SETS:
        raise ValueError(f"rules must be one of {RULE_SETS}, got {rule_set!r}")
    if crease_method not in CREASE_METHODS:
        raise ValueError(f"crease_method must be one of {CREASE_METHODS}, got {crease_method!r}")

    nv = mesh.num_vertices
    counts = mesh.face_vertex_counts
    indices = mesh.face_vertex_indices
    edges: MeshEdges = mesh.edges
    face_hole = np.zeros(len(counts), dtype=bool)
    face_hole[mesh.holes] = True
    if scheme == LOOP and not mesh.is_all(3):
        if not triangulate_polygons:
            bad = int(np.flatnonzero(counts != 3)[0])
            raise SubdivInputError(
                f"Loop subdivision needs triangles: face {bad} has {counts[bad]} vertices "
                "(pass triangulate=True to fan-triangulate polygons)"
            )
        counts, indices, parent = triangulate(counts, indices)
        edges = find_edges(counts, indices, nv)
        face_hole = face_hole[parent]

    offsets = face_offsets_of(counts)
    C = len(indices)
    F = len(counts)
    corner_vert = indices.astype(np.int64)
    nxt = edges.corner_next.astype(np.int64)
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(C)
    corner_edge = edges.corner_edge.astype(np.int64)
    edge_verts = edges.edge_verts.astype(np.int64)
    E = len(edge_verts)

    # edge -> corners
    ecount = np.bincount(corner_edge, minlength=E)
    eoff = _offsets(ecount)
    ecorners = np.argsort(corner_edge, kind="stable")
    first = ecorners[eoff[:-1]]
    second = ecorners[np.minimum(eoff[:-1] + 1, C - 1)]
    two = ecount == 2
    opposite = two & (corner_vert[first] == corner_vert[nxt[second]])
    boundary_edge = ecount == 1
    nonmanifold_edge = (ecount > 2) | (two & ~opposite)
    twin = np.full(C, -1, dtype=np.int64)
    twin[first[opposite]] = second[opposite]
    twin[second[opposite]] = first[opposite]

    # fans: the faces around a vertex joined through shared edges (one per vertex unless non-manifold)
    vcount = np.bincount(corner_vert, minlength=nv)
    voff = _offsets(vcount)
    max_valence = int(vcount.max())
    idx = np.arange(C, dtype=np.int64)
    cw = np.where(twin >= 0, nxt[np.maximum(twin, 0)], idx)
    ccw_src = twin[prv]
    ccw = np.where(ccw_src >= 0, ccw_src, idx)
    label = _fan_labels(corner_vert, cw, ccw, max_valence)
    fans = np.bincount(corner_vert[label == idx], minlength=nv)

    # vertex -> corners, counter-clockwise within each fan: a boundary fan starts at its face after the
    # boundary, a closed fan at its smallest corner
    has_start = np.zeros(C, dtype=bool)
    has_start[label[twin < 0]] = True
    link = np.where((label == idx) & ~has_start[label], idx, cw)
    _, ring_pos = _list_rank(link, max_valence)
    vcorners = np.lexsort((ring_pos, label, corner_vert))
    nonmanifold_vert = fans > 1
    nonmanifold_vert[edge_verts[nonmanifold_edge].reshape(-1)] = True

    # edge sharpness: boundary and non-manifold edges are infinitely sharp, tagged creases as given
    edge_sharpness = np.zeros(E, dtype=np.float64)
    if len(mesh.creases):
        tagged = edges.find(mesh.creases, nv) if edges is not mesh.edges else mesh.crease_edges
        np.maximum.at(edge_sharpness, tagged, mesh.crease_sharpness)
    untagged_boundary = boundary_edge & (edge_sharpness < INFINITE_SHARPNESS)  # not tagged infinitely sharp
    edge_sharpness[boundary_edge | nonmanifold_edge] = INFINITE_SHARPNESS
    if np.any(nonmanifold_edge) or np.any(fans > 1):
        ne = np.flatnonzero(nonmanifold_edge)
        nmv = np.flatnonzero(fans > 1)
        parts = []
        if len(ne):
            parts.append(f"{len(ne)} non-manifold edges (first: {edge_verts[ne[0]].tolist()})")
        if len(nmv):
            parts.append(f"{len(nmv)} vertices joining separate fans (first: vertex {int(nmv[0])})")
        warnings.warn(
            "non-manifold mesh: " + ", ".join(parts) + "; their edges are made sharp and their vertices corners "
            "or creases, as OpenSubdiv does",
            NonManifoldWarning,
            stacklevel=3,
        )

    # vertex sharpness: tagged corners as given; one-face boundary vertices (edge-and-corner), non-manifold
    # vertices that are not creases and unused vertices are infinitely sharp, as in OpenSubdiv
    on_boundary = np.zeros(nv, dtype=bool)
    on_boundary[edge_verts[boundary_edge].reshape(-1)] = True
    vert_sharpness = np.zeros(nv, dtype=np.float64)
    np.maximum.at(vert_sharpness, mesh.corners.astype(np.int64), mesh.corner_sharpness)
    sharp_count = np.bincount(edge_verts[edge_sharpness > 0].reshape(-1), minlength=nv)
    # non-manifold vertices are corners, except a "fin" inside the mesh (two non-manifold edges, no boundary
    # edge, more faces than edges), which OpenSubdiv keeps a crease
    ends = edge_verts.reshape(-1)
    nonmanifold_edges_at = np.bincount(ends, weights=np.repeat(nonmanifold_edge, 2), minlength=nv)
    boundary_edges_at = np.bincount(ends, weights=np.repeat(boundary_edge, 2), minlength=nv)
    edges_at = np.bincount(ends, minlength=nv)
    fin = (nonmanifold_edges_at == 2) & (boundary_edges_at == 0) & (vcount > edges_at)
    forced = nonmanifold_vert & ~fin
    if boundary == "edge-and-corner":
        forced |= on_boundary & (vcount == 1)
    forced |= vcount == 0  # unused vertices keep their position
    vert_sharpness[forced] = INFINITE_SHARPNESS
    if linear:  # bilinear refinement (face-varying "all"): corners and sharp edges everywhere
        vert_sharpness[:] = INFINITE_SHARPNESS
        edge_sharpness[:] = INFINITE_SHARPNESS
    vclass = vertex_rule(vert_sharpness, sharp_count)
    edge_sharp = edge_sharpness > 0
    if boundary == "none":
        # OpenSubdiv's VTX_BOUNDARY_NONE: a face touching a vertex with an untagged boundary edge has no
        # limit surface and is left out (boundaries tagged as creases keep their faces)
        open_vertex = np.zeros(nv, dtype=bool)
        open_vertex[edge_verts[untagged_boundary].reshape(-1)] = True
        touches = open_vertex[corner_vert]
        face_hole |= np.bincount(np.repeat(np.arange(F), counts)[touches], minlength=F) > 0

    # sectors and their angles: at crease and corner vertices whose sharp edges and own sharpness are all
    # infinite (semi-sharp features follow OpenSubdiv's rules in both rule sets)
    semi_vertex = semi_sharp_vertices(edge_verts, edge_sharpness, vert_sharpness)
    sectors = _sectors(
        mesh, scheme, rule_set, corner_vert, nxt, prv, twin, corner_edge, edge_sharp, ecount, eoff, ecorners,
        edges, vclass, np.where(semi_vertex, 0, sharp_count), max_valence,
    )
    sector_flatness, new_flatness = _sector_flatness(flatness, sectors[0], nv)

    uniform = int(counts[0]) if np.all(counts == counts[0]) and int(counts[0]) in (3, 4) else 0
    return Level(
        scheme=scheme,
        num_vertices=nv,
        num_faces=F,
        face_size=uniform,
        corner_vert=_i32(corner_vert),
        face_hole=face_hole,
        face_offsets=None if uniform else offsets,
        corner_next_table=None if uniform else _i32(nxt),
        corner_edge=_i32(corner_edge),
        edge_verts=_i32(edge_verts),
        edge_corner_offsets=eoff,
        edge_corners=_i32(ecorners),
        vert_corner_offsets=voff,
        vert_corners=_i32(vcorners),
        edge_sharp=edge_sharp,
        vert_class=vclass,
        edge_sharpness=edge_sharpness,
        vert_sharpness=vert_sharpness,
        crease_method=crease_method,
        linear=linear,
        sector_vertex=_i32(sectors[0]),
        sector_offsets=sectors[1],
        sector_corners=_i32(sectors[2]),
        sector_theta=sectors[3],
        sector_kind=sectors[4],
        sector_flatness=sector_flatness,
        new_sector_flatness=new_flatness,
    )


def _sectors(mesh, scheme, rule_set, corner_vert, nxt, prv, twin, corner_edge, edge_sharp, ecount, eoff,
             ecorners, edges, vclass, sharp_count, max_valence):
    """Sectors of crease and corner vertices with two or more crease edges (RULES.md sections 0 and 2).

    A sector is a run of faces around a vertex between two crease edges; its corners are found by walking
    clockwise to the first face (whose outgoing edge is a crease) with pointer jumping. alpha is measured
    here, once. Returns (vertex, offsets, ordered corners, theta, kind) per sector.
    """
    C = len(corner_vert)
    idx = np.arange(C, dtype=np.int64)
    smooth_edge = ~edge_sharp[corner_edge]
    cw = np.where(smooth_edge & (twin >= 0), nxt[np.maximum(twin, 0)], idx)
    head, pos = _list_rank(cw, max_valence)
    tagged_vertex = ((vclass == CREASE) | (vclass == CORNER)) & (sharp_count >= 2)
    sel = tagged_vertex[corner_vert]
    k_of_head = np.bincount(head[sel], minlength=C)
    heads = np.flatnonzero(sel & (pos == 0))
    sector_of_head = np.full(C, -1, dtype=np.int64)
    sector_of_head[heads] = np.arange(len(heads))
    k = k_of_head[heads]
    offsets = _offsets(k)
    members = np.flatnonzero(sel)
    ordered = np.empty(len(members), dtype=np.int64)
    ordered[offsets[sector_of_head[head[members]]] + pos[members]] = members
    tails = ordered[offsets[1:] - 1] if len(heads) else np.zeros(0, np.int64)

    pts = mesh.points
    c = corner_vert[heads]
    u = pts[corner_vert[nxt[heads]]] - pts[c]  # toward p_0
    w = pts[corner_vert[prv[tails]]] - pts[c]  # toward p_k
    alpha = np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), np.einsum("ij,ij->i", u, w))

    kind = np.where(vclass[c] == CREASE, rules.SECTOR_CREASE, rules.SECTOR_CONVEX).astype(np.int8)
    if len(mesh.concave):  # checked under both rule sets; only the piecewise-smooth rules use them
        concave_heads = _concave_sector_heads(mesh, corner_vert, nxt, corner_edge, edge_sharp, ecount, eoff,
                                              ecorners, edges, vclass, sharp_count, head, k_of_head[head])
        if rule_set == "piecewise-smooth":
            kind[sector_of_head[concave_heads]] = rules.SECTOR_CONCAVE
    theta = rules.sector_theta(kind, np.maximum(k, 1), alpha)
    return c, offsets, ordered, theta, kind


def _sector_flatness(flatness, sector_vertex, num_vertices):
    """Per-sector flatness s (NaN: the optimal s*) and the s of regular crease sectors made later."""
    if flatness is None:
        return np.full(len(sector_vertex), np.nan), float("nan")
    arr = np.asarray(flatness, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(len(sector_vertex), float(arr)), float(arr)
    if arr.shape != (num_vertices,):
        raise SubdivInputError(f"flatness must be a number or one value per vertex ({num_vertices}), got {arr.shape}")
    return arr[sector_vertex], float("nan")


def _concave_sector_heads(mesh, corner_vert, nxt, corner_edge, edge_sharp, ecount, eoff, ecorners, edges,
                          vclass, sharp_count, head, k):
    """The first corner of each sector named by a concave tag (corner vertex, neighbour vertex)."""
    tags = mesh.concave.astype(np.int64)
    nv = mesh.num_vertices
    e = edges.find(tags, nv) if edges is not mesh.edges else mesh.concave_edges
    c = tags[:, 0]
    for i in np.flatnonzero(vclass[c] != CORNER)[:1]:
        name = rules.VERTEX_CLASS_NAMES[int(vclass[c[i]])]
        raise SubdivInputError(
            f"concave tag {i} ({c[i]}, {tags[i, 1]}): vertex {c[i]} is not a corner (it is a vertex of class "
            f"'{name}'); "
            "tag it in corners"
        )
    for i in np.flatnonzero(sharp_count[c] < 2)[:1]:
        raise SubdivInputError(
            f"concave tag {i} ({c[i]}, {tags[i, 1]}): corner {c[i]} has {sharp_count[c[i]]} crease edges, so no "
            "sector bounded by two creases"
        )
    for i in np.flatnonzero(edge_sharp[e] & (ecount[e] != 1))[:1]:
        raise SubdivInputError(
            f"concave tag {i} ({c[i]}, {tags[i, 1]}): the edge is a crease between two sectors; name a "
            "non-crease edge inside the concave sector"
        )
    h0 = ecorners[eoff[e]]
    h1 = ecorners[np.minimum(eoff[e] + 1, len(ecorners) - 1)]
    # the corner at c in a face containing edge e: the edge's corner if it starts at c, else the next one
    at_c0 = np.where(corner_vert[h0] == c, h0, nxt[h0])
    at_c1 = np.where(corner_vert[h1] == c, h1, nxt[h1])
    corner_at_c = np.where(corner_vert[at_c0] == c, at_c0, at_c1)
    heads = head[corner_at_c]
    for i in np.flatnonzero(k[corner_at_c] < 2)[:1]:
        raise SubdivInputError(
            f"concave tag {i} ({c[i]}, {tags[i, 1]}): that sector of corner {c[i]} has one face; a concave "
            "sector needs at least two"
        )
    return heads


# --------------------------------------------------------------------------------------------------------
# refinement by index arithmetic


def refine_level(level: Level, faces_only: bool = False) -> Level:
    """The next level's topology, derived from ``level`` by index arithmetic (no sorting, no hashing).

    ``faces_only`` builds just the child faces (for the last level, which nothing refines further).
    """
    with small_pages():
        if level.scheme == CATMULL_CLARK:
            return _refine_catmull_clark(level, faces_only)
        return _refine_loop(level, faces_only)


_pages_lock = threading.Lock()
_pages_state = {"depth": 0, "previous": None}


@contextlib.contextmanager
def small_pages():
    """Let numpy skip its transparent-huge-page hint for arrays written once and read in order.

    A refinement step writes many large temporaries once each; with the hint the kernel zeroes (and on a
    fragmented machine first compacts) 2 MiB pages at every first touch (BENCHMARKS.md, "Where the build
    time goes"). Used for topology steps and output copies; everything else keeps the host's setting.
    numpy's switch is private: without it, nothing changes.
    """
    switch = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        yield
        return
    with _pages_lock:  # nested or concurrent users: the first switches off, the last restores
        if _pages_state["depth"] == 0:
            _pages_state["previous"] = switch(False)
        _pages_state["depth"] += 1
    try:
        yield
    finally:
        with _pages_lock:
            _pages_state["depth"] -= 1
            if _pages_state["depth"] == 0:
                switch(_pages_state["previous"])


def _side(level: Level, h: np.ndarray, e: np.ndarray) -> np.ndarray:
    """0 where corner h's vertex is edge e's first vertex, else 1 (int32, like every index array below: the
    refiner refuses levels whose corners do not fit int32, and half-width temporaries halve the fresh memory
    a level touches, which is what a refinement step spends most of its time on)."""
    return (level.corner_vert[h] != level.edge_verts[e, 0]).astype(np.int32)


def _side_all(level: Level, e: np.ndarray) -> np.ndarray:
    """``_side(level, h, e[h])`` for every corner h (no gather of the corners' own vertices)."""
    return (level.corner_vert != level.edge_verts[e, 0]).astype(np.int32)


class _QuadChildren:
    """Child corners of a Catmull-Clark step. Child face h (one per parent corner) holds, in this cyclic
    order: the child of v_h, the child of edge h, the face child, the child of edge prev(h). As in
    OpenSubdiv, children of a quad are rotated so that the vertex child sits at the parent corner's position
    j (children of other polygons are not): type t of corner h is child corner 4h + (t + r) % 4, r = j for
    quads and 0 otherwise. On a level of quads (h = 4f + j) that is 16f + 4j + (j + t) % 4: closed forms,
    so the tables are built by broadcasting and strided copies instead of index arrays."""

    def __init__(self, level: Level):
        self.level = level
        self.quads = level.face_size == 4
        C = level.num_corners
        if self.quads:
            self.base = (16 * np.arange(level.num_faces, dtype=np.int32))[:, None]
        else:
            h = np.arange(C, dtype=np.int64)
            face = level.corner_face(h)
            r = np.where(level.face_sizes()[face] == 4, h - level.face_starts()[face], 0)
            self.h, self.r = h, r

    def index(self, t: int, of_next: bool = False) -> np.ndarray:
        """Child corner of type t of every corner h (of corner_next(h) with ``of_next``), int32."""
        if self.quads:
            j = (np.arange(4) + (1 if of_next else 0)) & 3
            return (self.base + (4 * j + ((j + t) & 3)).astype(np.int32)).reshape(-1)
        out = (4 * self.h + (self.r + t) % 4).astype(np.int32)
        return self.level.at_next(out) if of_next else out

    def put(self, dst: np.ndarray, t: int, values) -> None:
        """dst[child corner of type t of h] = values[h] for every corner h. On quads ``values`` is (F, 4) per
        corner or (F,) per face; otherwise (C,)."""
        if self.quads:
            d = dst.reshape(-1, 4, 4)
            for j in range(4):
                d[:, j, (j + t) & 3] = values[:, j] if values.ndim == 2 else values
        else:
            dst[self.index(t)] = values


def _refine_catmull_clark(level: Level, faces_only: bool) -> Level:
    V, F, C, E = level.num_vertices, level.num_faces, level.num_corners, level.num_edges
    children = _QuadChildren(level)
    quads = children.quads

    def per_corner(values):  # a (C,) table as (F, 4) on quads, so that put() copies columns
        return values.reshape(F, 4) if quads else values

    face_ids = V + np.arange(F, dtype=np.int32)
    face_child = face_ids if quads else face_ids[level.corner_face(np.arange(C))]  # V + face of every corner
    e_h = level.corner_edge
    e_prev = level.at_prev(e_h)
    cv = np.empty(4 * C, dtype=np.int32)
    children.put(cv, 0, per_corner(level.corner_vert))
    children.put(cv, 1, per_corner(V + F + e_h))
    children.put(cv, 2, face_child)
    children.put(cv, 3, per_corner(V + F + e_prev))
    child_hole = np.repeat(level.face_hole, 4) if quads else level.face_hole[level.corner_face(np.arange(C))]
    nV = V + F + E
    if faces_only:
        return Level(level.scheme, nV, C, 4, cv, child_hole)

    ce = np.empty(4 * C, dtype=np.int32)
    h = np.arange(C, dtype=np.int32)
    children.put(ce, 0, per_corner(C + 2 * e_h + _side_all(level, e_h)))
    children.put(ce, 1, per_corner(h))
    children.put(ce, 2, per_corner(level.at_prev(h)))
    children.put(ce, 3, per_corner(C + 2 * e_prev + _side_all(level, e_prev)))
    interior_verts = np.empty((C, 2), dtype=np.int32)
    interior_verts[:, 0] = np.repeat(face_ids, 4) if quads else face_child
    interior_verts[:, 1] = V + F + e_h
    child_of_edge = children.index(1)
    interior_corners = np.stack([child_of_edge, children.index(2, of_next=True)], axis=1)
    near = children.index(0)  # child corner on the half of edge h at v_h's side
    far = children.index(3, of_next=True)  # child corner on the half at v_next's side
    # corners at the child of edge h, counter-clockwise: the face after the half at v_next, then the one
    # before the half at v_h
    edge_child_corners = np.stack([far, child_of_edge], axis=1)
    return _assemble(level, nV, C, 4, cv, ce, interior_verts, interior_corners, near, far,
                     near, children.index(2), edge_child_corners, child_hole, V + F)


def _refine_loop(level: Level, faces_only: bool) -> Level:
    V, F, C, E = level.num_vertices, level.num_faces, level.num_corners, level.num_edges
    if level.face_size != 3:
        raise ValueError("Loop refinement needs a triangle level")
    vt = level.corner_vert.reshape(F, 3)
    et = V + level.corner_edge.reshape(F, 3)
    # child 4f+j (j < 3): vertex child at position j, then edge j, then edge j-1; child 4f+3: edge m+1 at m
    cv = np.empty((F, 4, 3), dtype=np.int32)
    for j in range(3):
        cv[:, j, j] = vt[:, j]
        cv[:, j, (j + 1) % 3] = et[:, j]
        cv[:, j, (j + 2) % 3] = et[:, (j + 2) % 3]
        cv[:, 3, j] = et[:, (j + 1) % 3]
    child_hole = np.repeat(level.face_hole, 4)
    nV = V + E
    if faces_only:
        return Level(level.scheme, nV, 4 * F, 3, _i32(cv.reshape(-1)), child_hole)

    # corner h = 3f + j; every per-corner table below is a (F, 3) block of closed forms in f and j
    e_h = level.corner_edge
    e_prev = level.at_prev(e_h)
    half_at_h = (C + 2 * e_h + _side_all(level, e_h)).reshape(F, 3)  # half of edge h at v_h
    half_at_prev = (C + 2 * e_prev + _side_all(level, e_prev)).reshape(F, 3)  # half of edge prev(h) at v_h
    h3 = np.arange(C, dtype=np.int32).reshape(F, 3)
    ce = np.empty((F, 4, 3), dtype=np.int32)
    for jj in range(3):
        ce[:, jj, jj] = half_at_h[:, jj]
        ce[:, jj, (jj + 1) % 3] = h3[:, jj]
        ce[:, jj, (jj + 2) % 3] = half_at_prev[:, jj]
        ce[:, 3, jj] = h3[:, (jj + 2) % 3]
    del half_at_h, half_at_prev, h3
    base = (12 * np.arange(F, dtype=np.int32))[:, None]  # first child corner of face f

    def block(*columns_of_j):
        """(C, n) array whose column i is base + columns_of_j[i][j] for corner 3f + j."""
        offsets = np.array(columns_of_j, dtype=np.int32).T  # (3, n)
        return (base[:, :, None] + offsets[None]).reshape(C, len(columns_of_j))

    j = np.arange(3)
    jn, jp = (j + 1) % 3, (j + 2) % 3
    # interior edge 3f+j joins the children of edges j and j-1
    interior_verts = np.stack([V + e_h, V + e_prev], axis=1)
    interior_corners = block(3 * j + jn, 9 + jn)
    near = block(4 * j).reshape(-1)
    far = block(3 * jn + j).reshape(-1)
    vertex_child_corner = near
    # counter-clockwise around the child of edge j: child j+1, the middle child, child j
    edge_child_corners = block(3 * jn + j, 9 + jp, 3 * j + jn)
    return _assemble(level, nV, C, 3, cv.reshape(-1, 3), ce.reshape(-1, 3), interior_verts, interior_corners,
                     near, far, vertex_child_corner, None, edge_child_corners, child_hole, V)


def _assemble(level, nV, nI, face_size, cv, ce, interior_verts, interior_corners, near, far,
              vertex_child_corner, face_child_corners, edge_child_corners, child_hole, edge_child_base):
    """Shared tail of both schemes: child edges, edge->corner and vertex->corner tables, classes, thetas."""
    V, E, C = level.num_vertices, level.num_edges, level.num_corners
    nC = 4 * C
    ev = level.edge_verts
    # child edges: nI interior ones, then halves (child of v0, child of e) and (child of v1, child of e)
    child_edge_verts = np.empty((nI + 2 * E, 2), dtype=np.int32)
    child_edge_verts[:nI] = interior_verts
    halves = child_edge_verts[nI:].reshape(E, 2, 2)
    halves[:, :, 0] = (edge_child_base + np.arange(E, dtype=np.int32))[:, None]
    halves[:, :, 1] = ev

    # edge -> corners: interior edges have two corners; each half has as many as its parent edge
    eoff = level.edge_corner_offsets
    ecount = np.diff(eoff)
    half_off = np.empty((E, 2), dtype=np.int64)
    half_off[:, 0] = 2 * nI + 2 * eoff[:-1]
    half_off[:, 1] = half_off[:, 0] + ecount
    child_eoff = np.concatenate([2 * np.arange(nI, dtype=np.int64), half_off.reshape(-1), [nC]])
    child_ecorners = np.empty(nC, dtype=np.int32)
    child_ecorners[: 2 * nI] = interior_corners.reshape(-1)
    slot_edge = np.repeat(np.arange(E, dtype=np.int32), ecount)
    slot_corner = level.edge_corners
    t = np.arange(C, dtype=np.int64) - eoff[slot_edge]
    s0 = _side(level, slot_corner, slot_edge)
    child_ecorners[half_off[slot_edge, s0] + t] = near[slot_corner]
    child_ecorners[half_off[slot_edge, 1 - s0] + t] = far[slot_corner]
    del t, s0, half_off

    # vertex -> corners: vertex children keep their ring, face children get their face's corners,
    # edge children get m corners per parent corner on the edge
    voff = level.vert_corner_offsets
    vcount = np.diff(voff)
    m = edge_child_corners.shape[1]
    count_blocks = [vcount]
    corner_blocks = [vertex_child_corner[level.vert_corners]]
    if face_child_corners is not None:
        count_blocks.append(level.face_sizes())
        corner_blocks.append(face_child_corners)
    count_blocks.append(m * ecount)
    corner_blocks.append(edge_child_corners[slot_corner].reshape(-1))
    child_voff = _offsets(np.concatenate(count_blocks))
    child_vcorners = np.concatenate(corner_blocks)
    del corner_blocks

    # sharpness and classes: halves decay (uniform or Chaikin), edges inside faces are smooth; vertex children
    # decay; classes follow from the decayed sharpness
    halves_sharpness, vertex_sharpness = child_sharpness(level)
    vertex_children_class, edge_child_class = child_rules(level, halves_sharpness, vertex_sharpness)
    child_edge_sharpness = np.concatenate([np.zeros(nI), halves_sharpness.reshape(-1)])
    n_face_children = nV - V - E
    child_vert_sharpness = np.concatenate([vertex_sharpness, np.zeros(nV - V)])
    child_class = np.concatenate([vertex_children_class, np.full(n_face_children, SMOOTH, np.int8),
                                  edge_child_class])
    if level.linear:
        child_edge_sharpness[:] = INFINITE_SHARPNESS
        child_vert_sharpness[:] = INFINITE_SHARPNESS
        child_class[:] = CORNER
    # sectors: a vertex child keeps its sectors (theta is fixed on all levels); every corner of a parent
    # edge that is sharp makes one regular crease sector at the edge's child, its corners counter-clockwise
    sharp_slots = level.edge_sharpness[slot_edge] >= INFINITE_SHARPNESS
    new_corners = edge_child_corners[slot_corner[sharp_slots]]
    k_new = new_corners.shape[1]
    n_new = len(new_corners)
    sector_vertex = np.concatenate([level.sector_vertex, edge_child_base + slot_edge[sharp_slots]])
    sector_offsets = np.concatenate([level.sector_offsets, level.sector_offsets[-1] + k_new * np.arange(1, n_new + 1)])
    sector_corners = np.concatenate([vertex_child_corner[level.sector_corners], new_corners.reshape(-1)])
    regular = np.pi / k_new
    sector_theta = np.concatenate([level.sector_theta, np.full(n_new, regular)])
    sector_kind = np.concatenate([level.sector_kind, np.full(n_new, rules.SECTOR_CREASE, np.int8)])
    sector_flatness = np.concatenate([level.sector_flatness, np.full(n_new, level.new_sector_flatness)])
    return Level(
        scheme=level.scheme,
        num_vertices=nV,
        num_faces=nC // face_size,
        face_size=face_size,
        corner_vert=_i32(cv.reshape(-1)),
        face_hole=child_hole,
        corner_edge=_i32(ce.reshape(-1)),
        edge_verts=_i32(child_edge_verts),
        edge_corner_offsets=child_eoff,
        edge_corners=_i32(child_ecorners),
        vert_corner_offsets=child_voff,
        vert_corners=_i32(child_vcorners),
        edge_sharp=child_edge_sharpness > 0,
        vert_class=child_class,
        edge_sharpness=child_edge_sharpness,
        vert_sharpness=child_vert_sharpness,
        crease_method=level.crease_method,
        linear=level.linear,
        sector_vertex=_i32(sector_vertex),
        sector_offsets=sector_offsets,
        sector_corners=_i32(sector_corners),
        sector_theta=sector_theta,
        sector_kind=sector_kind,
        sector_flatness=sector_flatness,
        new_sector_flatness=level.new_sector_flatness,
    )
