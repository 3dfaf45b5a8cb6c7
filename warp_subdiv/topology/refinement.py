"""Topology: flat index tables for one subdivision level, and their refinement by index arithmetic.

A :class:`Level` stores faces as corners (a corner is a face's use of a vertex, and also the half-edge from
that vertex to the next corner's vertex), edges with their corners, vertices with their corners, the vertex
classes of docs/rules.md section 1, and the sector angle theta of every corner at a crease or corner vertex.

The control mesh (level 0) is analysed once, with sorting (edges, rings, fans, sectors). Every later level
is derived from its parent's tables by index arithmetic, as OpenSubdiv's Vtr does, in OpenSubdiv's order:
child vertices are [one per parent vertex, one per parent face (Catmull-Clark), one per parent edge];
child faces follow parent corners; child edges are [edges inside parent faces, two halves per parent edge].
Because that order is closed-form index arithmetic, a step's child-to-parent maps need no stored tables:
:class:`Refinement` states them as rules over the parent level's counts and materialises arrays on demand
(the conventions are documented in :mod:`warp_subdiv.tables.hierarchy`, which keeps one per step).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..rules import weights as rules
from ..errors import NonManifoldWarning, SubdivInputError
from ..mesh import INFINITE_SHARPNESS, Mesh, MeshEdges, expand_counts, face_offsets_of, find_edges
from ..options import Boundary, CreaseMethod, RuleSet, Scheme
from ..rules import CATMULL_CLARK, CORNER, CREASE, LOOP, SMOOTH
from ..runtime.pages import small_pages


def _face_sizes(faces) -> np.ndarray:
    """(F,) int64: corners of every face of ``faces`` (a level, or the parent of a step: ``face_size``, 0 for
    mixed polygons, ``num_faces``, ``face_offsets``)."""
    if faces.face_size:
        return np.full(faces.num_faces, faces.face_size, dtype=np.int64)
    return np.diff(faces.face_offsets)


def _face_starts(faces) -> np.ndarray:
    """(F,) int64: the first corner of every face of ``faces`` (as :func:`_face_sizes`)."""
    if faces.face_size:
        return np.arange(faces.num_faces, dtype=np.int64) * faces.face_size
    return faces.face_offsets[:-1]


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
    # sectors of crease and corner vertices (docs/rules.md section 0): corners listed counter-clockwise from
    # the face after the first crease edge; theta and kind per docs/rules.md section 2; flatness s (NaN:
    # optimal s*)
    sector_vertex: np.ndarray | None = None  # (S,)
    sector_offsets: np.ndarray | None = None  # (S+1,) int64
    sector_corners: np.ndarray | None = None  # (sum k,)
    sector_theta: np.ndarray | None = None  # (S,) float64
    sector_kind: np.ndarray | None = None  # (S,) int8, rules.SECTOR_*
    sector_flatness: np.ndarray | None = None  # (S,) float64
    # (S,) bool: the sector's limit normal is reversed (two opposite corner sectors, docs/rules.md section 9)
    sector_flip: np.ndarray | None = None
    new_sector_flatness: float = float("nan")  # s of the regular crease sectors that later levels create
    degenerate_edges: bool = False  # some edge has one vertex at both ends (level 0 only)
    # level 0 of a fan-triangulated polygon mesh (Loop) only: the control polygon of each triangle
    control_face: np.ndarray | None = None  # (F,) int64; None: face f is control face f

    @property
    def num_corners(self) -> int:
        return len(self.corner_vert)

    @property
    def num_edges(self) -> int:
        return len(self.edge_verts)

    def face_sizes(self) -> np.ndarray:
        return _face_sizes(self)

    def face_starts(self) -> np.ndarray:
        return _face_starts(self)

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
# sharpness (OpenSubdiv's Sdc::Crease semantics; DeRose, Kass, Truong 1998). The arithmetic on sharpness
# values lives in warp_subdiv/crease.py; these wrappers read its inputs off a Level.

from ..rules import crease  # noqa: E402  (imported inside this block; base_level uses the two names below)
from ..rules import semi_sharp_vertices, vertex_rule  # noqa: E402


def has_semi_sharpness(level: Level) -> bool:
    """True when some edge or vertex of the level has a finite, non-zero sharpness (cached on the level)."""
    if level.semi_sharp is None:
        level.semi_sharp = crease.any_semi_sharp(level.edge_sharpness, level.vert_sharpness)
    return level.semi_sharp


def child_sharpness(level: Level):
    """Sharpness after one step: (halves (E, 2) -- the child of edge e at its end j --, vertex children (V,)).

    Uniform creasing decrements by one. Chaikin creasing (OpenSubdiv's CREASE_CHAIKIN) gives the child at
    vertex v 3/4 of the edge's sharpness plus 1/4 of the mean of v's other semi-sharp edges, minus one.
    Without semi-sharp features nothing changes (0 stays 0, infinite stays infinite)."""
    if not has_semi_sharpness(level):
        return np.repeat(level.edge_sharpness[:, None], 2, axis=1), level.vert_sharpness
    halves = crease.child_edge_sharpness(level.edge_sharpness, level.edge_verts, level.num_vertices,
                                         level.crease_method)
    return halves, crease.decrement_sharpness(level.vert_sharpness)


def child_rules(level: Level, halves: np.ndarray, child_vertex_sharpness: np.ndarray):
    """Classes of the vertex children (V,) and edge children (E,) after one step (see crease.child_rules)."""
    if not has_semi_sharpness(level):  # rules do not change: vertex children keep theirs
        return level.vert_class, np.where(level.edge_sharp, CREASE, SMOOTH).astype(np.int8)
    return crease.child_rules(level.edge_verts, halves, child_vertex_sharpness)


def fractional_weight(level: Level, halves: np.ndarray, child_vertex_sharpness: np.ndarray) -> np.ndarray:
    """Weight of the parent rule where a vertex's rule changes during this step (see crease.fractional_weight)."""
    return crease.fractional_weight(level.edge_verts, level.edge_sharpness, level.vert_sharpness, halves,
                                    child_vertex_sharpness, level.crease_method)


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


def _check_choice(value, kind, name: str) -> None:
    """ValueError unless ``value`` is a member of the option enum ``kind`` or exactly its string value (the
    level functions are also called directly, with strings; :class:`~warp_subdiv.options.Options` is the
    lenient front door)."""
    if value not in kind.values():
        raise ValueError(f"{name} must be one of {kind.values()}, got {value!r}")


@dataclass
class BaseFaces:
    """Level 0's faces as the refiner sees them, before any analysis: Loop fan-triangulates polygons, and
    under boundary "none" the faces without a limit surface join the holes."""

    counts: np.ndarray  # (F,) corners per face
    indices: np.ndarray  # (C,) vertex of every corner
    edges: MeshEdges  # the mesh's own edges, or those of its triangulation
    control_face: np.ndarray | None  # (F,) control polygon of each triangle; None: face f is control face f
    face_hole: np.ndarray  # (F,) bool

    @property
    def face_size(self) -> int:
        """3 or 4 when every face has that size, else 0 (:attr:`Level.face_size`)."""
        counts = self.counts
        return int(counts[0]) if np.all(counts == counts[0]) and int(counts[0]) in (3, 4) else 0


def base_faces(mesh: Mesh, scheme: str, boundary: str = "edge-and-corner",
               triangulate_polygons: bool = True) -> BaseFaces:
    """The faces, edges and holes of level 0 (cheap: no fans, classes or sectors), shared by
    :func:`base_level` and the face bookkeeping of :mod:`warp_subdiv.tables.face_map`."""
    nv = mesh.num_vertices
    counts = mesh.face_vertex_counts
    indices = mesh.face_vertex_indices
    edges: MeshEdges = mesh.edges
    control_face = None
    if scheme == LOOP and not mesh.is_all(3):
        if not triangulate_polygons:
            bad = int(np.flatnonzero(counts != 3)[0])
            raise SubdivInputError(
                f"Loop subdivision needs triangles: face {bad} has {counts[bad]} vertices "
                "(pass triangulate=True to fan-triangulate polygons)"
            )
        counts, indices, control_face = triangulate(counts, indices)
        edges = find_edges(counts, indices, nv)
    face_hole = np.zeros(mesh.num_faces, dtype=bool)
    face_hole[mesh.holes] = True
    if control_face is not None:
        face_hole = face_hole[control_face]
    if boundary == Boundary.NONE:
        # OpenSubdiv's VTX_BOUNDARY_NONE: a face touching a vertex with an untagged boundary edge has no
        # limit surface and is left out (boundaries tagged infinitely sharp keep their faces)
        E = len(edges.edge_verts)
        boundary_edge = np.bincount(edges.corner_edge, minlength=E) == 1
        untagged = boundary_edge & (tagged_edge_sharpness(mesh, edges) < INFINITE_SHARPNESS)
        open_vertex = np.zeros(nv, dtype=bool)
        open_vertex[edges.edge_verts[untagged].reshape(-1)] = True
        F = len(counts)
        touches = open_vertex[indices]
        face_hole |= np.bincount(np.repeat(np.arange(F), counts)[touches], minlength=F) > 0
    return BaseFaces(counts, indices, edges, control_face, face_hole)


def last_tag_values(size: int, ids: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(size,) float64: ``values[i]`` at ``ids[i]``, 0 where untagged; where an id is tagged more than once
    the last tag wins, as in OpenSubdiv's and USD's tag lists."""
    out = np.zeros(size, dtype=np.float64)
    if len(ids):
        ids = np.asarray(ids, dtype=np.int64)
        uniq, first_from_end = np.unique(ids[::-1], return_index=True)
        out[uniq] = np.asarray(values, dtype=np.float64)[len(ids) - 1 - first_from_end]
    return out


def tagged_edge_sharpness(mesh: Mesh, edges: MeshEdges) -> np.ndarray:
    """(E,) float64: the sharpness the mesh's crease tags give ``edges`` (the mesh's own or a triangulation's),
    0 elsewhere; the last tag's where an edge is tagged twice (either orientation), as in OpenSubdiv."""
    if not len(mesh.creases):
        return np.zeros(len(edges.edge_verts), dtype=np.float64)
    tagged = edges.find(mesh.creases, mesh.num_vertices) if edges is not mesh.edges else mesh.crease_edges
    return last_tag_values(len(edges.edge_verts), tagged, mesh.crease_sharpness)


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
    """Analyse the control mesh: edges, fans, manifoldness, vertex classes and sectors.

    ``scheme``, ``boundary``, ``rule_set`` and ``crease_method`` are members of the option enums or their exact
    string values (ValueError otherwise)."""
    _check_choice(scheme, Scheme, "scheme")
    _check_choice(boundary, Boundary, "boundary")
    _check_choice(rule_set, RuleSet, "rules")
    _check_choice(crease_method, CreaseMethod, "crease_method")

    nv = mesh.num_vertices
    faces = base_faces(mesh, scheme, boundary, triangulate_polygons)
    counts, indices, edges, face_hole = faces.counts, faces.indices, faces.edges, faces.face_hole

    offsets = face_offsets_of(counts)
    C = len(indices)
    corner_vert = indices.astype(np.int64)
    nxt = edges.corner_next.astype(np.int64)
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(C)
    corner_edge = edges.corner_edge.astype(np.int64)
    edge_verts = edges.edge_verts.astype(np.int64)
    E = len(edge_verts)

    # edge -> corners
    ecount = np.bincount(corner_edge, minlength=E)
    eoff = face_offsets_of(ecount)
    ecorners = np.argsort(corner_edge, kind="stable")
    first = ecorners[eoff[:-1]]
    second = ecorners[np.minimum(eoff[:-1] + 1, C - 1)]
    two = ecount == 2
    built_nonmanifold = edges.nonmanifold if edges.nonmanifold is not None else np.zeros(E, dtype=bool)
    opposite = two & (corner_vert[first] == corner_vert[nxt[second]]) & ~built_nonmanifold
    boundary_edge = ecount == 1
    # non-manifold: more than two faces, two faces that agree on orientation, degenerate edges and repeated
    # vertex pairs (as built by find_edges), as OpenSubdiv tags them
    nonmanifold_edge = (ecount > 2) | (two & ~opposite) | built_nonmanifold
    twin = np.full(C, -1, dtype=np.int64)
    twin[first[opposite]] = second[opposite]
    twin[second[opposite]] = first[opposite]

    # fans: the faces around a vertex joined through shared edges (one per vertex unless non-manifold)
    vcount = np.bincount(corner_vert, minlength=nv)
    voff = face_offsets_of(vcount)
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
    if fans.max(initial=0) <= 1:  # one fan per vertex: ring_pos ranks its corners 0..k-1, so place them
        vcorners = np.empty(C, dtype=np.int64)
        vcorners[voff[corner_vert] + ring_pos] = idx
    else:
        vcorners = np.lexsort((ring_pos, label, corner_vert))
    nonmanifold_vert = fans > 1
    nonmanifold_vert[edge_verts[nonmanifold_edge].reshape(-1)] = True

    # edge sharpness: boundary and non-manifold edges are infinitely sharp, tagged creases as given
    edge_sharpness = tagged_edge_sharpness(mesh, edges)
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
    vert_sharpness = last_tag_values(nv, mesh.corners, mesh.corner_sharpness)  # the last tag of a vertex wins
    sharp_count = np.bincount(edge_verts[edge_sharpness > 0].reshape(-1), minlength=nv)
    # non-manifold vertices are corners, except a "fin" inside the mesh (two non-manifold edges, no boundary
    # edge, more faces than edges), which OpenSubdiv keeps a crease
    ends = edge_verts.reshape(-1)
    edges_at = np.bincount(ends, minlength=nv)
    if nonmanifold_edge.any():
        nonmanifold_edges_at = np.bincount(ends, weights=np.repeat(nonmanifold_edge, 2), minlength=nv)
        boundary_edges_at = np.bincount(ends, weights=np.repeat(boundary_edge, 2), minlength=nv)
        fin = (nonmanifold_edges_at == 2) & (boundary_edges_at == 0) & (vcount > edges_at)
    else:  # no non-manifold edge: no fin
        fin = np.zeros(nv, dtype=bool)
    forced = nonmanifold_vert & ~fin
    if boundary == Boundary.EDGE_AND_CORNER:  # a topological corner: one face, two edges
        forced |= (vcount == 1) & (edges_at == 2)
    forced |= vcount == 0  # unused vertices keep their position
    vert_sharpness[forced] = INFINITE_SHARPNESS
    if linear:  # bilinear refinement (face-varying "all"): corners and sharp edges everywhere
        vert_sharpness[:] = INFINITE_SHARPNESS
        edge_sharpness[:] = INFINITE_SHARPNESS
    vclass = vertex_rule(vert_sharpness, sharp_count)
    edge_sharp = edge_sharpness > 0

    # sectors and their angles: at crease and corner vertices whose sharp edges and own sharpness are all
    # infinite (semi-sharp features follow OpenSubdiv's rules in both rule sets)
    semi_vertex = semi_sharp_vertices(edge_verts, edge_sharpness, vert_sharpness)
    sectors = _sectors(
        mesh, scheme, rule_set, corner_vert, nxt, prv, twin, corner_edge, edge_sharp, ecount, eoff, ecorners,
        edges, vclass, np.where(semi_vertex, 0, sharp_count), max_valence,
    )
    sector_flatness, new_flatness = _sector_flatness(flatness, sectors[0], nv)

    uniform = faces.face_size
    level = _full_level(
        scheme, nv, uniform, corner_vert, face_hole,
        face_offsets=None if uniform else offsets, corner_next_table=None if uniform else nxt,
        corner_edge=corner_edge, edge_verts=edge_verts, edge_corner_offsets=eoff, edge_corners=ecorners,
        vert_corner_offsets=voff, vert_corners=vcorners, vert_class=vclass, edge_sharpness=edge_sharpness,
        vert_sharpness=vert_sharpness, sectors=Sectors(*sectors[:5], sector_flatness, sectors[5]),
        crease_method=crease_method,
        linear=linear, new_sector_flatness=new_flatness, control_face=faces.control_face,
    )
    level.degenerate_edges = bool(np.any(edge_verts[:, 0] == edge_verts[:, 1]))
    return level


class Sectors(NamedTuple):
    """The sector tables of a level (the ``sector_*`` fields of :class:`Level`)."""

    vertex: np.ndarray  # (S,)
    offsets: np.ndarray  # (S+1,) int64
    corners: np.ndarray  # (sum k,)
    theta: np.ndarray  # (S,) float64
    kind: np.ndarray  # (S,) int8
    flatness: np.ndarray  # (S,) float64
    flip: np.ndarray | None = None  # (S,) bool; None: no sector is flipped


def _full_level(scheme, num_vertices: int, face_size: int, corner_vert, face_hole, *, corner_edge, edge_verts,
                edge_corner_offsets, edge_corners, vert_corner_offsets, vert_corners, vert_class, edge_sharpness,
                vert_sharpness, sectors: Sectors, crease_method, linear: bool, new_sector_flatness: float,
                face_offsets=None, corner_next_table=None, control_face=None) -> Level:
    """A level with all its tables: the one constructor of full levels, for the control mesh's analysis and
    every refinement step alike. Index arrays become int32 (no copy when they already are); the face count
    and ``edge_sharp`` follow from the other tables."""
    return Level(
        scheme=scheme,
        num_vertices=num_vertices,
        num_faces=len(face_hole),
        face_size=face_size,
        corner_vert=_i32(corner_vert),
        face_hole=face_hole,
        face_offsets=face_offsets,
        corner_next_table=None if corner_next_table is None else _i32(corner_next_table),
        corner_edge=_i32(corner_edge),
        edge_verts=_i32(edge_verts),
        edge_corner_offsets=edge_corner_offsets,
        edge_corners=_i32(edge_corners),
        vert_corner_offsets=vert_corner_offsets,
        vert_corners=_i32(vert_corners),
        edge_sharp=edge_sharpness > 0,
        vert_class=vert_class,
        edge_sharpness=edge_sharpness,
        vert_sharpness=vert_sharpness,
        crease_method=crease_method,
        linear=linear,
        sector_vertex=_i32(sectors.vertex),
        sector_offsets=sectors.offsets,
        sector_corners=_i32(sectors.corners),
        sector_theta=sectors.theta,
        sector_kind=sectors.kind,
        sector_flatness=sectors.flatness,
        sector_flip=np.zeros(len(sectors.vertex), bool) if sectors.flip is None else sectors.flip,
        new_sector_flatness=new_sector_flatness,
        control_face=control_face,
    )


def _sectors(mesh, scheme, rule_set, corner_vert, nxt, prv, twin, corner_edge, edge_sharp, ecount, eoff,
             ecorners, edges, vclass, sharp_count, max_valence):
    """Sectors of crease and corner vertices with two or more crease edges (docs/rules.md sections 0 and 2).

    A sector is a run of faces around a vertex between two crease edges; its corners are found by walking
    clockwise to the first face (whose outgoing edge is a crease) with pointer jumping. alpha is measured
    here, once, and so is which corner sectors are straight (docs/rules.md section 2.1) and which limit normals are
    reversed (section 9). Returns (vertex, offsets, ordered corners, theta, kind, flip) per sector.
    """
    C = len(corner_vert)
    tagged_vertex = ((vclass == CREASE) | (vclass == CORNER)) & (sharp_count >= 2)
    # only the corners at those vertices are walked (a walk stays at its vertex): ``at`` lists them, and
    # ``local`` numbers them
    at = np.flatnonzero(tagged_vertex[corner_vert])
    local = np.full(C, -1, dtype=np.int64)
    local[at] = np.arange(len(at))
    twin_at = twin[at]
    cw_at = np.where(~edge_sharp[corner_edge[at]] & (twin_at >= 0), nxt[np.maximum(twin_at, 0)], at)
    head_local, pos_at = _list_rank(local[cw_at], max_valence)
    head_at = at[head_local]
    # a fan without a crease edge (a closed fan of a non-manifold vertex) walks in a circle: it has no head
    # and belongs to no sector
    sel = cw_at[head_local] == head_at
    members = at[sel]
    member_head, member_pos = head_at[sel], pos_at[sel]
    k_of_head = np.bincount(member_head, minlength=C)
    heads = members[member_pos == 0]
    sector_of_head = np.full(C, -1, dtype=np.int64)
    sector_of_head[heads] = np.arange(len(heads))
    k = k_of_head[heads]
    offsets = face_offsets_of(k)
    ordered = np.empty(len(members), dtype=np.int64)
    ordered[offsets[sector_of_head[member_head]] + member_pos] = members
    tails = ordered[offsets[1:] - 1] if len(heads) else np.zeros(0, np.int64)

    pts = mesh.points
    c = corner_vert[heads]
    u = pts[corner_vert[nxt[heads]]] - pts[c]  # toward p_0
    w = pts[corner_vert[prv[tails]]] - pts[c]  # toward p_k
    crease_cross = np.cross(u, w)
    alpha = np.arctan2(np.linalg.norm(crease_cross, axis=1), np.einsum("ij,ij->i", u, w))

    kind = np.where(vclass[c] == CREASE, rules.SECTOR_CREASE, rules.SECTOR_CONVEX).astype(np.int8)
    if len(mesh.concave):  # checked under both rule sets; only the piecewise-smooth rules use them
        head = np.arange(C, dtype=np.int64)  # every corner's sector head (itself outside sectors)
        head[at] = head_at
        concave_heads = _concave_sector_heads(mesh, corner_vert, nxt, corner_edge, edge_sharp, ecount, eoff,
                                              ecorners, edges, vclass, sharp_count, head, k_of_head[head])
        if rule_set == RuleSet.PIECEWISE_SMOOTH:
            kind[sector_of_head[concave_heads]] = rules.SECTOR_CONCAVE
    # straight sectors: corner sectors of k >= 2 faces whose crease edges are nearly collinear, in space and
    # in the plane of the sector's own faces (the sum of the face normals at c, (p_i - c) x (p_{i+1} - c)); the
    # plane is summed only for the sectors nearly straight in space (usually none), over their own members
    candidate = (kind != rules.SECTOR_CREASE) & (k >= 2) & (np.pi - alpha < rules.STRAIGHT_EPSILON_3D)
    if candidate.any():
        sector_of_member = sector_of_head[member_head]
        take = candidate[sector_of_member]
        mine, at = members[take], sector_of_member[take]
        fan = np.cross(pts[corner_vert[nxt[mine]]] - pts[corner_vert[mine]],
                       pts[corner_vert[prv[mine]]] - pts[corner_vert[mine]])
        plane = np.stack([np.bincount(at, weights=fan[:, j], minlength=len(heads)) for j in range(3)], 1)
        sel = np.flatnonzero(candidate)
        straight = np.zeros(len(heads), dtype=bool)
        straight[sel] = _in_plane_gap(u[sel], w[sel], plane[sel], alpha[sel]) < rules.STRAIGHT_EPSILON
        kind[straight] = rules.SECTOR_STRAIGHT
    theta = rules.sector_theta(kind, np.maximum(k, 1), alpha)
    flip = _opposite_corner_normals(mesh, corner_vert, nxt, prv, c, kind, crease_cross)
    return c, offsets, ordered, theta, kind, flip


def _in_plane_gap(u, w, normal, alpha):
    """pi minus the angle between u and w seen along ``normal`` (all (S, 3)); pi - alpha where the projection
    is degenerate (no normal, or u or w along it)."""
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    n = normal / np.where(length > 0, length, 1.0)
    up = u - np.einsum("ij,ij->i", u, n)[:, None] * n
    wp = w - np.einsum("ij,ij->i", w, n)[:, None] * n
    scale = np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1)
    ok = (length[:, 0] > 0) & (np.linalg.norm(up, axis=1) * np.linalg.norm(wp, axis=1) > 1e-6 * scale)
    seen = np.arctan2(np.linalg.norm(np.cross(up, wp), axis=1), np.einsum("ij,ij->i", up, wp))
    return np.pi - np.where(ok, seen, alpha)


def _opposite_corner_normals(mesh, corner_vert, nxt, prv, c, kind, crease_cross):
    """(S,) bool: sectors whose limit normal is reversed (docs/rules.md section 9).

    A vertex with exactly two sectors, both convex or both concave corners, has two sectors bounded by the same
    two creases, and their corner normals (p_0 - c) x (p_k - c) (reversed when concave) are exact opposites:
    one sector folds onto the other (paper Fig. 2). Each is turned to the side the vertex's faces face (the sum
    of its faces' normals at c on the control mesh); where that does not decide, the second takes the first's."""
    flip = np.zeros(len(c), bool)
    corner_kind = (kind == rules.SECTOR_CONVEX) | (kind == rules.SECTOR_CONCAVE)
    per_vertex = np.bincount(c, minlength=mesh.num_vertices)
    corner_sectors = np.bincount(c, weights=corner_kind, minlength=mesh.num_vertices)
    pairs = np.flatnonzero((per_vertex[c] == 2) & (corner_sectors[c] == 2))
    if len(pairs) == 0:
        return flip
    order = pairs[np.lexsort((pairs, c[pairs]))]
    first, second = order[0::2], order[1::2]
    sign = np.where(kind == rules.SECTOR_CONCAVE, -1.0, 1.0)[:, None]
    normal = sign * crease_cross
    opposite = np.einsum("ij,ij->i", normal[first], normal[second]) < 0
    first, second = first[opposite], second[opposite]
    if len(first) == 0:
        return flip
    pts = mesh.points
    at = np.isin(corner_vert, c[first])
    h = np.flatnonzero(at)
    fan = np.cross(pts[corner_vert[nxt[h]]] - pts[corner_vert[h]], pts[corner_vert[prv[h]]] - pts[corner_vert[h]])
    side = np.stack([np.bincount(corner_vert[h], weights=fan[:, j], minlength=mesh.num_vertices)
                     for j in range(3)], 1)[c[first]]
    d1 = np.einsum("ij,ij->i", normal[first], side)
    d2 = np.einsum("ij,ij->i", normal[second], side)
    flip[first[d1 < 0]] = True
    flip[second[(d2 < 0) | ((d1 == 0) & (d2 == 0))]] = True
    return flip


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
    def refuse(i, reason):
        raise SubdivInputError(f"concave tag {i} ({c[i]}, {tags[i, 1]}): {reason}", option="concave",
                               element="concave", index=int(i))

    for i in np.flatnonzero(vclass[c] != CORNER)[:1]:
        name = rules.VERTEX_CLASS_NAMES[int(vclass[c[i]])]
        refuse(i, f"vertex {c[i]} is not a corner (it is a vertex of class '{name}'); tag it in corners")
    for i in np.flatnonzero(sharp_count[c] < 2)[:1]:  # (semi-sharp corners count no crease edges)
        refuse(i, _too_few_creases(mesh, edges, ecount, int(c[i]), int(sharp_count[c[i]])))
    for i in np.flatnonzero(edge_sharp[e] & (ecount[e] != 1))[:1]:
        refuse(i, "the edge is a crease between two sectors; name a non-crease edge inside the concave sector")
    h0 = ecorners[eoff[e]]
    h1 = ecorners[np.minimum(eoff[e] + 1, len(ecorners) - 1)]
    # the corner at c in a face containing edge e: the edge's corner if it starts at c, else the next one
    at_c0 = np.where(corner_vert[h0] == c, h0, nxt[h0])
    at_c1 = np.where(corner_vert[h1] == c, h1, nxt[h1])
    corner_at_c = np.where(corner_vert[at_c0] == c, at_c0, at_c1)
    heads = head[corner_at_c]
    for i in np.flatnonzero(k[corner_at_c] < 2)[:1]:
        refuse(i, f"that sector of corner {c[i]} has one face; a concave sector needs at least two")
    return heads


def _too_few_creases(mesh, edges, ecount, vertex: int, count: int) -> str:
    """Why a concave-tagged corner has no sector bounded by two infinitely sharp creases: it is semi-sharp,
    some of its creases are, or it has fewer than two."""
    need = "concave tags need an infinitely sharp corner (sharpness >= 10) between infinitely sharp creases"
    edge_s = tagged_edge_sharpness(mesh, edges)
    semi = np.flatnonzero((edge_s > 0) & (edge_s < INFINITE_SHARPNESS) & (ecount == 2)
                          & np.any(edges.edge_verts == vertex, axis=1))
    if len(semi):
        other = edges.edge_verts[semi].sum(axis=1) - vertex
        names = ", ".join(f"({vertex}, {int(o)}) sharpness {edge_s[j]:g}" for j, o in zip(semi, other))
        return f"the creases of corner {vertex} are semi-sharp ({names}); {need}"
    own = last_tag_values(mesh.num_vertices, mesh.corners, mesh.corner_sharpness)[vertex]
    if 0 < own < INFINITE_SHARPNESS:
        return f"corner {vertex} is semi-sharp (sharpness {own:g}); {need}"
    return (f"corner {vertex} has {count} crease edge{'' if count == 1 else 's'}, so no sector bounded by two "
            "creases")


# --------------------------------------------------------------------------------------------------------
# refinement by index arithmetic


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
    ``threads`` contiguous ranges (:func:`warp_subdiv.runtime.threads.map_ranges`)."""
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


def _put_quads(d: np.ndarray, t: int, values: np.ndarray) -> None:
    """_QuadChildren.put on a block ``d`` (n, 4, 4) of child corners of n quads: values (n, 4) or (n,)."""
    for j in range(4):
        d[:, j, (j + t) & 3] = values[:, j] if values.ndim == 2 else values


def _prev_in_quads(v: np.ndarray) -> np.ndarray:
    """Level.at_prev on a block (n, 4) of per-corner values of quads."""
    out = np.empty_like(v)
    out[:, 1:] = v[:, :-1]
    out[:, 0] = v[:, -1]
    return out


def _quad_index(a: int, b: int, t: int, of_next: bool = False) -> np.ndarray:
    """_QuadChildren.index for the corners of quads a..b, (b - a, 4) int32."""
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
    # corners at the child of edge h, counter-clockwise: the face after the half at v_next, then the one
    # before the half at v_h
    return _assemble(level, num_vertices=nV, face_size=4, corner_vert=out["cv"], corner_edge=out["ce"],
                     face_hole=child_hole, interior_verts=out["interior_verts"],
                     interior_corners=out["interior_corners"], near=out["near"], far=out["far"],
                     vertex_child_corner=out["near"], face_child_corners=out["face_child_corners"],
                     edge_child_corners=out["edge_child_corners"], edge_child_base=V + F, threads=threads)


def _refine_catmull_clark(level: Level, faces_only: bool, threads: int = 1) -> Level:
    if level.face_size == 4:
        return _refine_catmull_clark_quads(level, faces_only, threads)
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
    children.put(ce, 3, per_corner(C + 2 * e_prev + _side_all(level, e_prev, entering=True)))
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
    return _assemble(level, num_vertices=nV, face_size=4, corner_vert=cv, corner_edge=ce, face_hole=child_hole,
                     interior_verts=interior_verts, interior_corners=interior_corners, near=near, far=far,
                     vertex_child_corner=near, face_child_corners=children.index(2),
                     edge_child_corners=edge_child_corners, edge_child_base=V + F, threads=threads)


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
    return _assemble(level, num_vertices=nV, face_size=3, corner_vert=out["cv"], corner_edge=out["ce"],
                     face_hole=child_hole, interior_verts=out["interior_verts"],
                     interior_corners=out["interior_corners"], near=out["near"], far=out["far"],
                     vertex_child_corner=out["near"], face_child_corners=None,
                     edge_child_corners=out["edge_child_corners"], edge_child_base=V, threads=threads)


def _assemble(level: Level, *, num_vertices: int, face_size: int, corner_vert, corner_edge, face_hole,
              interior_verts, interior_corners, near, far, vertex_child_corner, face_child_corners,
              edge_child_corners, edge_child_base: int, threads: int = 1) -> Level:
    """Shared tail of both schemes: child edges, edge->corner and vertex->corner tables, classes, thetas.

    What the scheme's split hands over (C = the parent's corners; every array int32):
    ``num_vertices``, ``face_size``, ``corner_vert`` / ``corner_edge`` (4C,) and ``face_hole`` of the child
    level; ``interior_verts`` / ``interior_corners`` (C, 2): the child edge inside the parent face at each
    parent corner (child edges 0..C-1), its two end vertices and its two corners; ``near`` / ``far`` (C,):
    the child corner on the half of edge h at v_h's side and at the next vertex's side; ``vertex_child_corner``
    (C,): the child corner of each parent corner's vertex child; ``face_child_corners`` (C,) or None (Loop):
    the child corner at the face child; ``edge_child_corners`` (C, m): the child corners at the child of edge
    h, counter-clockwise; ``edge_child_base``: the first edge child's vertex index. ``threads``: the edge
    tables, the vertex-corner lists and the classes are built as three jobs on up to that many threads (the
    same arrays whatever the count).
    """
    nV, nI, cv, ce, child_hole = num_vertices, level.num_corners, corner_vert, corner_edge, face_hole
    V, E, C = level.num_vertices, level.num_edges, level.num_corners
    nC = 4 * C
    ev = level.edge_verts
    eoff = level.edge_corner_offsets
    ecount = np.diff(eoff)
    slot_edge = np.repeat(np.arange(E, dtype=np.int32), ecount)
    slot_corner = level.edge_corners

    def edges():
        """Child edges (nI interior ones, then halves (child of v0, child of e) and (child of v1, child of e))
        and their corners: interior edges have two, each half as many as its parent edge."""
        child_edge_verts = np.empty((nI + 2 * E, 2), dtype=np.int32)
        child_edge_verts[:nI] = interior_verts
        halves = child_edge_verts[nI:].reshape(E, 2, 2)
        halves[:, :, 0] = (edge_child_base + np.arange(E, dtype=np.int32))[:, None]
        halves[:, :, 1] = ev
        half_off = np.empty((E, 2), dtype=np.int64)
        half_off[:, 0] = 2 * nI + 2 * eoff[:-1]
        half_off[:, 1] = half_off[:, 0] + ecount
        child_eoff = np.concatenate([2 * np.arange(nI, dtype=np.int64), half_off.reshape(-1), [nC]])
        child_ecorners = np.empty(nC, dtype=np.int32)
        child_ecorners[: 2 * nI] = interior_corners.reshape(-1)
        t = np.arange(C, dtype=np.int64) - eoff[slot_edge]
        s0 = _side(level, slot_corner, slot_edge)
        child_ecorners[half_off[slot_edge, s0] + t] = near[slot_corner]
        child_ecorners[half_off[slot_edge, 1 - s0] + t] = far[slot_corner]
        return child_edge_verts, child_eoff, child_ecorners

    def vertices():
        """Vertex -> corners: vertex children keep their ring, face children get their face's corners, edge
        children get m corners per parent corner on the edge."""
        vcount = np.diff(level.vert_corner_offsets)
        m = edge_child_corners.shape[1]
        count_blocks = [vcount]
        corner_blocks = [vertex_child_corner[level.vert_corners]]
        if face_child_corners is not None:
            count_blocks.append(level.face_sizes())
            corner_blocks.append(face_child_corners)
        count_blocks.append(m * ecount)
        corner_blocks.append(edge_child_corners[slot_corner].reshape(-1))
        return face_offsets_of(np.concatenate(count_blocks)), np.concatenate(corner_blocks)

    def classes():
        """Sharpness and classes: halves decay (uniform or Chaikin), edges inside faces are smooth; vertex
        children decay; classes follow from the decayed sharpness. Sectors: a vertex child keeps its sectors
        (theta is fixed on all levels); every corner of a parent edge that is sharp makes one regular crease
        sector at the edge's child, its corners counter-clockwise."""
        halves_sharpness, vertex_sharpness = child_sharpness(level)
        vertex_children_class, edge_child_class = child_rules(level, halves_sharpness, vertex_sharpness)
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
        infinitely_sharp = level.edge_sharpness >= INFINITE_SHARPNESS
        sharp_slots = infinitely_sharp[slot_edge] if infinitely_sharp.any() else np.zeros(len(slot_edge), dtype=bool)
        new_corners = edge_child_corners[slot_corner[sharp_slots]]
        k_new = new_corners.shape[1]
        n_new = len(new_corners)
        sectors = Sectors(
            np.concatenate([level.sector_vertex, edge_child_base + slot_edge[sharp_slots]]),
            np.concatenate([level.sector_offsets, level.sector_offsets[-1] + k_new * np.arange(1, n_new + 1)]),
            np.concatenate([vertex_child_corner[level.sector_corners], new_corners.reshape(-1)]),
            np.concatenate([level.sector_theta, np.full(n_new, np.pi / k_new)]),
            np.concatenate([level.sector_kind, np.full(n_new, rules.SECTOR_CREASE, np.int8)]),
            np.concatenate([level.sector_flatness, np.full(n_new, level.new_sector_flatness)]),
            np.concatenate([level.sector_flip, np.zeros(n_new, bool)]))
        return child_class, child_edge_sharpness, child_vert_sharpness, sectors

    # the three read the parent level and the step's tables only: with threads, at once (numpy releases the
    # GIL inside large gathers and scatters; the results do not depend on it)
    from ..runtime.threads import run as run_jobs

    (child_edge_verts, child_eoff, child_ecorners), (child_voff, child_vcorners), \
        (child_class, child_edge_sharpness, child_vert_sharpness, sectors) = \
        run_jobs([edges, vertices, classes], max(1, min(int(threads), 3)))
    return _full_level(
        level.scheme, nV, face_size, cv, child_hole,
        corner_edge=ce, edge_verts=child_edge_verts, edge_corner_offsets=child_eoff, edge_corners=child_ecorners,
        vert_corner_offsets=child_voff, vert_corners=child_vcorners, vert_class=child_class,
        edge_sharpness=child_edge_sharpness, vert_sharpness=child_vert_sharpness, sectors=sectors,
        crease_method=level.crease_method, linear=level.linear, new_sector_flatness=level.new_sector_flatness,
    )


# --------------------------------------------------------------------------------------------------------
# child-to-parent maps of one step

#: kinds of parent element a child comes from (the parent type of OpenSubdiv's Vtr::Refinement child tags)
VERTEX, EDGE, FACE = 0, 1, 2


@dataclass(frozen=True, eq=False)
class Refinement:
    """Where the children of one refinement step come from, as rules over the parent level's counts.

    OpenSubdiv's ``Vtr::Refinement`` stores ``_childFaceParentIndex``, ``_childEdgeParentIndex``,
    ``_childVertexParentIndex`` and a tag per child. Here the child order of :func:`refine_level` makes them
    closed-form index arithmetic, so a step keeps its parent's counts and materialises arrays only when asked.
    The one stored array is ``face_offsets`` of a parent with mixed polygons (only the control mesh has them),
    of control size. The conventions are listed in :mod:`warp_subdiv.tables.hierarchy`.
    """

    scheme: str
    num_vertices: int  # of the parent level
    num_faces: int
    num_edges: int
    num_corners: int
    face_size: int  # 3 or 4 when every parent face has that size, 0 for mixed polygons
    face_offsets: np.ndarray | None = None  # (F+1,) int64, mixed polygons only

    @classmethod
    def of_level(cls, level: Level) -> "Refinement":
        """The step that refines ``level`` (which needs its edges: not a faces-only level)."""
        return cls(level.scheme, level.num_vertices, level.num_faces, level.num_edges, level.num_corners,
                   level.face_size, None if level.face_size else level.face_offsets)

    @classmethod
    def of_faces(cls, scheme: str, num_vertices: int, faces: BaseFaces) -> "Refinement":
        """The step that refines level 0, from :func:`base_faces` alone (no analysis)."""
        size = faces.face_size
        return cls(scheme, num_vertices, len(faces.counts), len(faces.edges.edge_verts), len(faces.indices), size,
                   None if size else face_offsets_of(faces.counts))

    def next(self) -> "Refinement":
        """The step after this one (its parent is this step's child level: all quads or all triangles)."""
        return Refinement(self.scheme, self.child_vertices, self.child_faces, self.child_edges, self.child_corners,
                          4 if self.scheme == CATMULL_CLARK else 3)

    # ---------------------------------------------------------------------------------------- child counts
    @property
    def child_vertices(self) -> int:
        """[vertex children V, face children F (Catmull-Clark only), edge children E]."""
        face_children = self.num_faces if self.scheme == CATMULL_CLARK else 0
        return self.num_vertices + face_children + self.num_edges

    @property
    def child_faces(self) -> int:
        """One per parent corner (Catmull-Clark: C) or four per triangle (Loop: 4F)."""
        return self.num_corners if self.scheme == CATMULL_CLARK else 4 * self.num_faces

    @property
    def child_edges(self) -> int:
        """[one inside a parent face per parent corner (C), two halves per parent edge (2E)]."""
        return self.num_corners + 2 * self.num_edges

    @property
    def child_corners(self) -> int:
        return 4 * self.num_corners

    @property
    def children_per_face(self) -> int:
        """Child faces per parent face where that number is fixed (4 for Loop and quads, 3 for a Catmull-Clark
        step over triangles), else 0: then ``child // children_per_face`` is the parent face."""
        return 4 if self.scheme != CATMULL_CLARK else self.face_size

    # ---------------------------------------------------------------------------------------- parent faces
    def face_sizes(self) -> np.ndarray:
        """(F,) int64: corners of every parent face."""
        return _face_sizes(self)

    def face_starts(self) -> np.ndarray:
        """(F,) int64: first corner of every parent face."""
        return _face_starts(self)

    def corner_faces(self) -> np.ndarray:
        """(C,) int64: the parent face of every parent corner."""
        if self.face_size:
            return np.arange(self.num_corners, dtype=np.int64) // self.face_size
        return np.repeat(np.arange(self.num_faces, dtype=np.int64), np.diff(self.face_offsets))

    def parent_face_of(self, child_faces: np.ndarray) -> np.ndarray:
        """The parent face of each of ``child_faces`` (int64), without the slot arrays of :meth:`face_parent`."""
        child_faces = np.asarray(child_faces, dtype=np.int64)
        n = self.children_per_face
        return child_faces // n if n else self.corner_faces()[child_faces]

    # ---------------------------------------------------------------------------------------- maps
    def vertex_ranges(self) -> tuple:
        """((kind, first child, number of children), ...) in the child vertex order: the rule behind
        :meth:`vertex_parent` (child ``first + i`` of a range comes from parent element ``i`` of ``kind``)."""
        V, F, E = self.num_vertices, self.num_faces, self.num_edges
        if self.scheme == CATMULL_CLARK:
            return (VERTEX, 0, V), (FACE, V, F), (EDGE, V + F, E)
        return (VERTEX, 0, V), (EDGE, V, E)

    def vertex_parent(self):
        """(kind int8, index int64) of every child vertex: the parent vertex, face or edge it comes from."""
        ranges = self.vertex_ranges()
        kind = np.concatenate([np.full(n, k, dtype=np.int8) for k, _, n in ranges])
        index = np.concatenate([np.arange(n, dtype=np.int64) for _, _, n in ranges])
        return kind, index

    def face_parent(self):
        """(face, slot) int64 of every child face: its parent face, and which of that face's children it is.

        Catmull-Clark: child face h is the child of parent corner h, ``slot`` that corner's place in its face.
        Loop: child 4f + s of triangle f; s < 3 is the child at corner s, s = 3 the middle triangle."""
        if self.scheme != CATMULL_CLARK or self.face_size:
            n = self.children_per_face
            c = np.arange(self.child_faces, dtype=np.int64)
            return c // n, c % n
        face = self.corner_faces()
        return face, np.arange(self.num_corners, dtype=np.int64) - self.face_offsets[face]

    def face_rotation(self) -> np.ndarray:
        """(child faces,) int64: the position r in each child face of its parent corner's vertex child.

        Catmull-Clark (OpenSubdiv's order): children of a quad are rotated, r = slot; children of other
        polygons are not, r = 0. Loop: r = s for the corner children; the middle child has r = 0."""
        face, slot = self.face_parent()
        if self.scheme == CATMULL_CLARK:
            if self.face_size:
                return slot if self.face_size == 4 else np.zeros_like(slot)
            return np.where(self.face_sizes()[face] == 4, slot, 0)
        return np.where(slot < 3, slot, 0)

    def edge_parent(self):
        """(kind int8, index int64, slot int64) of every child edge.

        Child edge h < C lies inside parent face ``index`` (kind FACE) at its corner ``slot`` (parent corner h:
        Catmull-Clark joins the face child to the child of the edge leaving h, Loop the children of the edges
        leaving and entering h). Child edge C + 2e + s (kind EDGE) is the half of parent edge e at its end s,
        joining the child of that end vertex to the child of e."""
        C, E = self.num_corners, self.num_edges
        face = self.corner_faces()
        inner_slot = np.arange(C, dtype=np.int64) - self.face_starts()[face]
        halves = np.arange(2 * E, dtype=np.int64)
        kind = np.concatenate([np.full(C, FACE, dtype=np.int8), np.full(2 * E, EDGE, dtype=np.int8)])
        return kind, np.concatenate([face, halves // 2]), np.concatenate([inner_slot, halves % 2])
