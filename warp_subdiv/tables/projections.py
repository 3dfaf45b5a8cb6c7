"""Tables for the paper's projections on one level: flatness, normal control and limit masks.

Flatness follows docs/rules.md section 6, normal control section 7, and limit masks sections 8 and 9.

Each table is built from a level's sector and ring tables plus the pure masks of :mod:`warp_subdiv.rules.limit_masks`;
the Warp kernels in ``kernels/projection.py`` apply them without knowing what a sector is.

* Flatness and normal control are *displacement* tables: rows are the points that move; a row holds
  (source point, weight) entries, and for normal control also the normal each entry projects onto. Where
  several sectors or constrained vertices move the same point, their displacements are averaged.
* Limit tables: one CSR row per vertex for the limit position (l^0), and per (vertex, sector) pair the two
  tangent masks whose cross product is the outward normal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rules import limit_masks as M
from ..errors import SubdivInputError
from ..runtime.estimate import check_int32
from ..rules import CATMULL_CLARK, CORNER, CREASE, DART, SECTOR_CONCAVE, SECTOR_CONVEX, SECTOR_CREASE, SMOOTH
from ..mesh import INFINITE_SHARPNESS, face_offsets_of
from .stencil_builder import crease_neighbours
from .stencil_table import StencilTable
from ..topology import Level


@dataclass
class DisplacementTable:
    """dst[targets[i]] = src[targets[i]] + sum_j w_j (n_j n_j^T if normals else 1) src[indices[j]], j in row i."""

    targets: np.ndarray  # (R,) int32
    offsets: np.ndarray  # (R+1,) int32
    indices: np.ndarray  # int32
    weights: np.ndarray  # float64
    normal_ids: np.ndarray | None = None  # int32 per entry, into the normals array
    normals: np.ndarray | None = None  # (m, 3) float64

    @property
    def num_rows(self) -> int:
        return len(self.targets)


def _group_by_target(targets, sources, weights, normal_ids=None, normals=None) -> DisplacementTable | None:
    """Lay updates out as rows per target point, averaging the updates that hit the same point.

    Lists of blocks: block b has targets (U_b,), sources and weights (U_b, n_b), and optionally normal ids
    (U_b,). One update moves one point."""
    if not targets or sum(len(t) for t in targets) == 0:
        return None
    all_targets = np.concatenate(targets)
    uniq, hits = np.unique(all_targets, return_counts=True)
    entry_target = np.concatenate([np.repeat(t, src.shape[1]) for t, src in zip(targets, sources)])
    row = np.searchsorted(uniq, entry_target)
    entry_w = np.concatenate([w.reshape(-1) for w in weights]) / hits[row]
    order = np.argsort(row, kind="stable")
    table = DisplacementTable(
        targets=uniq.astype(np.int32),
        offsets=face_offsets_of(np.bincount(row, minlength=len(uniq))).astype(np.int32),
        indices=np.concatenate([src.reshape(-1) for src in sources])[order].astype(np.int32),
        weights=entry_w[order],
    )
    if normal_ids is not None:
        ids = np.concatenate([np.repeat(i, src.shape[1]) for i, src in zip(normal_ids, sources)])
        table.normal_ids = ids[order].astype(np.int32)
        table.normals = normals
    return table


def sector_local_vectors(level: Level, sectors: np.ndarray, k: int) -> np.ndarray:
    """(S, n) vertex ids of the local vectors [c, p_0..p_k, (q_0..q_{k-1})] of sectors with crease degree k."""
    corners = level.sector_corners[level.sector_offsets[sectors][:, None] + np.arange(k)]
    return _local_vector(level, level.sector_vertex[sectors], corners, sector=True)


def ring_local_vectors(level: Level, vertices: np.ndarray, k: int, start_at_sharp: bool = False) -> np.ndarray:
    """(V, n) vertex ids of the local vectors [c, p_0..p_{k-1}, (q_0..q_{k-1})] of closed rings of valence k.

    ``start_at_sharp``: the ring starts at the vertex's first sharp edge (p_0 is its far end; a dart's crease)."""
    corners = level.vert_corners[level.vert_corner_offsets[vertices][:, None] + np.arange(k)]
    if start_at_sharp and len(corners):
        first = np.argmax(level.edge_sharp[level.corner_edge[corners]], axis=1)
        corners = np.take_along_axis(corners, (first[:, None] + np.arange(k)) % k, axis=1)
    return _local_vector(level, vertices, corners, sector=False)


def exact_darts(level: Level, rule_set: str) -> np.ndarray:
    """(V,) bool: darts whose masks are the dart's own (docs/rules.md section 8.8): piecewise-smooth rules, a
    closed ring and an infinitely sharp crease edge. Darts of a semi-sharp edge, whose rule changes when the edge
    decays, and every dart under ``rule_set="opensubdiv"`` (as OpenSubdiv) keep the interior masks."""
    darts = level.vert_class == DART
    if rule_set == "opensubdiv" or not np.any(darts):
        return np.zeros(level.num_vertices, bool)
    infinite = level.edge_sharpness >= INFINITE_SHARPNESS
    ends = level.edge_verts[infinite].reshape(-1)
    on_infinite = np.zeros(level.num_vertices, bool)
    on_infinite[ends] = True
    return darts & on_infinite


def ring_masks(level: Level, vertices: np.ndarray, k: int, beta_variant: str, darts: np.ndarray):
    """Local vectors and masks of closed rings of valence k: interior masks (docs/rules.md sections 8.1, 8.4),
    dart masks where ``darts[v]`` (section 8.8; the ring starts at the crease). Yields (vertices, local, masks)
    per group."""
    is_dart = darts[vertices]
    for dart in (False, True):
        vs = vertices[is_dart == dart]
        if len(vs) == 0:
            continue
        local = ring_local_vectors(level, vs, k, start_at_sharp=dart)
        if dart:
            yield vs, local, M.dart_masks(level.scheme, k, len(vs), beta_variant)
        else:
            yield vs, local, M.interior_masks(level.scheme, k, len(vs), beta_variant)


def _local_vector(level, centre, corners, sector):
    """(S, n) int32 vertex ids of the local vectors whose rings start at ``corners`` (S, k)."""
    cv = level.corner_vert
    nxt = level.corner_next(corners)
    parts = [np.asarray(centre, dtype=np.int32)[:, None], cv[nxt]]
    if sector:
        parts.append(cv[level.corner_prev(corners[:, -1:])])
    if level.scheme == CATMULL_CLARK:
        parts.append(cv[level.corner_next(nxt)])
    return np.concatenate(parts, axis=1)


def resolve_flatness(level: Level) -> np.ndarray:
    """Per-sector s: the user's value, or the optimal s* where none was given; checked against [0, 1] and s_min."""
    k = level.sector_k()
    s = level.sector_flatness.copy()
    default = np.isnan(s)
    s[default] = M.optimal_flatness(level.scheme, level.sector_kind[default], k[default], level.sector_theta[default])
    bad = np.flatnonzero(~default & ((s < 0) | (s > 1)))
    if len(bad):
        raise SubdivInputError(f"flatness {s[bad[0]]} at vertex {level.sector_vertex[bad[0]]} is outside [0, 1]")
    concave = level.sector_kind == SECTOR_CONCAVE
    s_min = M.concave_min_flatness(level.scheme, np.maximum(k, 2), level.sector_theta)
    bad = np.flatnonzero(concave & (s <= s_min))
    if len(bad):
        i = bad[0]
        raise SubdivInputError(
            f"flatness {s[i]:.6g} at concave corner vertex {level.sector_vertex[i]} must exceed "
            f"s_min = {s_min[i]:.6g} for a C1 surface (docs/rules.md section 6)"
        )
    return s


def flatness_table(level: Level, flatness: np.ndarray) -> DisplacementTable | None:
    """Flatness (docs/rules.md section 6) on ``level``: non-crease ring points move toward the tangent plane.

    A ring point that lies on a crease itself (a crease or corner vertex, e.g. a q point of a sector next to
    a corner) is never moved: every crease stays a B-spline of its own points, so meshes that share a
    boundary still meet (docs/rules.md section 6 excludes c, p_0, p_k for the same reason).
    """
    on_crease = np.isin(level.vert_class, [CREASE, CORNER])
    k_all = level.sector_k()
    targets, sources, weights = [], [], []
    for k in np.unique(k_all):
        sel = np.flatnonzero((k_all == k) & (flatness > 0))
        if len(sel) == 0 or k < 2 and level.scheme != CATMULL_CLARK:
            continue
        local = sector_local_vectors(level, sel, int(k))
        m = M.sector_masks(level.scheme, level.sector_kind[sel], int(k), level.sector_theta[sel])
        s = flatness[sel][:, None]
        for r in M.flattened_points(level.scheme, int(k)):
            row = m.projector_row(r)  # (P p)_r
            row[:, r] -= 1.0
            free = ~on_crease[local[:, r]]
            targets.append(local[free, r])
            sources.append(local[free])
            weights.append((s * row)[free])
    return _group_by_target(targets, sources, weights)


def check_normal_vertices(level: Level, vertices: np.ndarray) -> None:
    """Normal control needs an interior ring or a crease/corner sector with at least two faces."""
    cls = level.vert_class[vertices]
    has_sector = np.zeros(level.num_vertices, dtype=bool)
    has_sector[level.sector_vertex[level.sector_k() >= 2]] = True
    ok = np.isin(cls, [SMOOTH, DART]) | has_sector[vertices]
    bad = np.flatnonzero(~ok)
    if len(bad):
        v = vertices[bad[0]]
        raise SubdivInputError(
            f"prescribed normal at vertex {v}: normal control needs an interior vertex or a crease/corner "
            "sector with at least two faces (docs/rules.md section 7)"
        )


def normal_table(level: Level, vertices: np.ndarray, normals: np.ndarray, strength: float,
                 flatness: np.ndarray, beta_variant: str, rule_set: str = "piecewise-smooth"
                 ) -> DisplacementTable | None:
    """Normal control (docs/rules.md section 7, corrected: no x^0 term, q points too) on ``level``.

    Darts use their own masks (section 8.8), straight sectors their three 1/2-modes (section 8.7)."""
    targets, sources, weights, nids = [], [], [], []
    normal_of = np.full(level.num_vertices, -1, dtype=np.int64)
    normal_of[vertices] = np.arange(len(vertices))

    def add(local, m, ids):
        n = local.shape[1]
        for r in range(1, n):
            coeff = m.x1[:, r:r + 1] * m.l1 + m.x2[:, r:r + 1] * m.l2
            if m.l3 is not None:
                coeff = coeff + m.x3[:, r:r + 1] * m.l3
            coeff = -strength * coeff
            if not np.any(coeff):
                continue
            targets.append(local[:, r])
            sources.append(local)
            weights.append(coeff)
            nids.append(ids)

    # interior and dart vertices: their whole ring
    inner = vertices[np.isin(level.vert_class[vertices], [SMOOTH, DART])]
    valence = np.diff(level.vert_corner_offsets)[inner]
    darts = exact_darts(level, rule_set)
    for k in np.unique(valence):
        for vs, local, m in ring_masks(level, inner[valence == k], int(k), beta_variant, darts):
            add(local, m, normal_of[vs])
    # crease and corner vertices: each sector with k >= 2 (l_cross(s) where flatness is on)
    owner = normal_of[level.sector_vertex]
    k_all = level.sector_k()
    for k in np.unique(k_all[(owner >= 0) & (k_all >= 2)]):
        sel = np.flatnonzero((owner >= 0) & (k_all == k))
        m = M.sector_masks(level.scheme, level.sector_kind[sel], int(k), level.sector_theta[sel], flatness[sel])
        add(sector_local_vectors(level, sel, int(k)), m, owner[sel])
    return _group_by_target(targets, sources, weights, nids, np.asarray(normals, dtype=np.float64))


@dataclass
class LimitTables:
    """Limit positions (one row per vertex) and tangent pairs (one row per (vertex, sector) contribution)."""

    position: StencilTable
    tangent_u: StencilTable
    tangent_v: StencilTable
    contribution_vertex: np.ndarray  # (T,) int32: the vertex each tangent pair belongs to
    vertex_offsets: np.ndarray  # (V+1,) int32: contributions of vertex v, contiguous


def limit_tables(level: Level, flatness: np.ndarray, beta_variant: str,
                 rule_set: str = "piecewise-smooth") -> LimitTables:
    """Limit position and tangent masks of every vertex of ``level`` (docs/rules.md sections 8 and 9).

    With ``rule_set="opensubdiv"`` the tangent masks are OpenSubdiv's where they differ in direction from the
    paper's (a corner's second tangent runs along its first interior edge; Loop's cross-crease tangent of a
    sector of four or more faces), so that normals equal OpenSubdiv's T1 x T2.

    Each class of vertex adds its rows in turn (:class:`_LimitRows`): closed rings, pillows, sectors, boundary
    fans without sectors, then the vertices left without tangents and without a position mask."""
    V = level.num_vertices
    cls = level.vert_class
    sectored = np.zeros(V, dtype=bool)
    sectored[level.sector_vertex] = True
    valence = np.diff(level.vert_corner_offsets)
    counts = np.diff(level.edge_corner_offsets)
    boundary_vertex = np.zeros(V, dtype=bool)
    boundary_vertex[level.edge_verts[counts != 2].reshape(-1)] = True
    out = _LimitRows()
    closed = ~boundary_vertex & (valence >= 3)
    _add_rings(out, level, np.flatnonzero(~sectored & closed), valence, beta_variant, exact_darts(level, rule_set))
    _add_pillows(out, level, np.flatnonzero(~sectored & ~boundary_vertex & (valence == 2)
                                            & np.isin(cls, [SMOOTH, DART])), beta_variant)
    neighbours = crease_neighbours(level)
    _add_sectors(out, level, flatness, rule_set, neighbours)
    fan = np.flatnonzero(~sectored & boundary_vertex & np.isin(cls, [CREASE, CORNER]) & (valence >= 1))
    _add_boundary_fans(out, level, fan, valence, counts)
    _add_bare_vertices(out, level, valence)
    _add_remaining_positions(out, level, neighbours)
    return out.tables(V)


class _LimitRows:
    """The rows of a level's limit tables, gathered block by block: position rows (``position``: each vertex
    from one block) and tangent pairs (``tangents``: one per (vertex, sector) contribution, in the order added).
    A block is its rows' vertices (S,), their local vectors and weights (S, n)."""

    def __init__(self):
        self.pos_rows, self.pos_local, self.pos_w = [], [], []
        self.tan_rows, self.tan_local, self.tan_u, self.tan_v = [], [], [], []

    def position(self, rows, local, weights):
        self.pos_rows.append(rows), self.pos_local.append(local), self.pos_w.append(weights)

    def tangents(self, rows, local, tu, tv):
        self.tan_rows.append(rows), self.tan_local.append(local), self.tan_u.append(tu), self.tan_v.append(tv)

    def with_position(self, num_vertices: int) -> np.ndarray:
        """(V,) bool: the vertices some position block covers."""
        covered = np.zeros(num_vertices, dtype=bool)
        for r in self.pos_rows:
            covered[r] = True
        return covered

    def with_tangents(self, num_vertices: int) -> np.ndarray:
        """(V,) bool: the vertices with a tangent pair."""
        has_pair = np.zeros(num_vertices, dtype=bool)
        for r in self.tan_rows:
            has_pair[r] = True
        return has_pair

    def tables(self, num_vertices: int) -> LimitTables:
        """The gathered rows as tables: one position row per vertex; the tangent pairs ordered by vertex (a
        vertex's contributions contiguous, in the order added)."""
        V = num_vertices
        position = _merge_rows(self.pos_rows, self.pos_local, self.pos_w, V, V)
        tan_rows = self.tan_rows
        vertex_of = np.concatenate(tan_rows) if tan_rows else np.zeros(0, np.int64)
        order = np.argsort(vertex_of, kind="stable")
        rank = np.empty(len(order), dtype=np.int64)
        rank[order] = np.arange(len(order))
        bounds = face_offsets_of(np.array([len(r) for r in tan_rows], dtype=np.int64))
        rank_parts = [rank[bounds[i]:bounds[i + 1]] for i in range(len(tan_rows))]
        tu = _merge_rows(rank_parts, self.tan_local, self.tan_u, len(order), V)
        tv = _merge_rows(rank_parts, self.tan_local, self.tan_v, len(order), V)
        contribution_vertex = vertex_of[order]
        vertex_offsets = face_offsets_of(np.bincount(contribution_vertex, minlength=V)).astype(np.int32)
        return LimitTables(position, tu, tv, contribution_vertex.astype(np.int32), vertex_offsets)


def _add_rings(out: _LimitRows, level: Level, ring_vertices: np.ndarray, valence: np.ndarray, beta_variant: str,
               darts: np.ndarray):
    """Closed rings of three faces or more without sectors: interior and dart vertices (position and tangents
    of their ring masks), and corner-tagged vertices without sectors (tangents of their ring only)."""
    cls = level.vert_class
    for k in np.unique(valence[ring_vertices]):
        for vs, local, m in ring_masks(level, ring_vertices[valence[ring_vertices] == k], int(k), beta_variant,
                                       darts):
            smooth = np.isin(cls[vs], [SMOOTH, DART])
            out.position(vs[smooth], local[smooth], m.l0[smooth])
            out.tangents(vs, local, m.tu, m.tv)


def _add_pillows(out: _LimitRows, level: Level, pillow: np.ndarray, beta_variant: str):
    """Closed rings of two faces (a "pillow" of two faces, which OpenSubdiv accepts): Loop's smooth limit mask
    of valence 2; Catmull-Clark's is its corner mask (the point itself, left to :func:`_add_remaining_positions`),
    as OpenSubdiv's. Tangents as at the bare vertices (:func:`_add_bare_vertices`: the ring's own tangent masks
    degenerate at valence 2)."""
    if len(pillow) and level.scheme != CATMULL_CLARK:
        ring = 8.0 * float(M.loop_beta(2, beta_variant)) / 3.0
        row = np.array([1.0, ring, ring]) / (1.0 + 2.0 * ring)
        out.position(pillow, ring_local_vectors(level, pillow, 2, start_at_sharp=False),
                     np.broadcast_to(row, (len(pillow), 3)))


def _add_sectors(out: _LimitRows, level: Level, flatness: np.ndarray, rule_set: str, neighbours: np.ndarray):
    """Crease and corner vertices: tangents of every sector, the position mask of each vertex's first sector.
    ``neighbours``: the level's :func:`crease_neighbours`."""
    cls = level.vert_class
    k_all = level.sector_k()
    first_sector = np.zeros(level.num_sectors, dtype=bool)
    if level.num_sectors:
        _, first = np.unique(level.sector_vertex, return_index=True)
        first_sector[first] = True
    for k in np.unique(k_all):
        sel = np.flatnonzero(k_all == k)
        local = sector_local_vectors(level, sel, int(k))
        m = M.sector_masks(level.scheme, level.sector_kind[sel], int(k), level.sector_theta[sel], flatness[sel])
        if rule_set == "opensubdiv":
            M.use_opensubdiv_tangents(m, level.scheme, level.sector_kind[sel], int(k))
            tu, tv = m.tu, m.tv
        else:  # two opposite corner sectors: both turned to the side the vertex's faces face (section 9)
            flip = level.sector_flip[sel][:, None]
            tu, tv = np.where(flip, m.tv, m.tu), np.where(flip, m.tu, m.tv)
        once = first_sector[sel]
        vs = level.sector_vertex[sel].astype(np.int64)
        # a non-manifold crease vertex (a fin) can have a sector whose ends are not its two crease neighbours:
        # its position takes the crease limit mask (_add_remaining_positions) instead
        ends = np.sort(local[:, [1, k + 1]], axis=1)
        once &= (cls[vs] != CREASE) | np.all(ends == np.sort(neighbours[vs], axis=1), axis=1)
        out.position(vs[once], local[once], m.l0[once])
        out.tangents(vs, local, tu, tv)


def _add_boundary_fans(out: _LimitRows, level: Level, fan: np.ndarray, valence: np.ndarray, counts: np.ndarray):
    """Boundary crease/corner vertices without sectors (semi-sharp features, also a semi-sharp edge inside the
    fan): their one fan, from boundary to boundary, is their sector; tangents as OpenSubdiv's for that rule
    (the paper's tags are not involved). ``counts``: faces per edge."""
    first = level.vert_corners[level.vert_corner_offsets[fan]].astype(np.int64) if len(fan) else fan
    fan = fan[counts[level.corner_edge[first]] == 1] if len(fan) else fan  # the ring starts at the boundary
    cls = level.vert_class
    for k in np.unique(valence[fan]):
        vs = fan[valence[fan] == k]
        corners = level.vert_corners.astype(np.int64)[level.vert_corner_offsets[vs][:, None] + np.arange(k)]
        local = _local_vector(level, vs, corners, sector=True)
        kind = np.where(cls[vs] == CREASE, SECTOR_CREASE, SECTOR_CONVEX)
        theta = np.where(kind == SECTOR_CREASE, np.pi / k, np.pi / (2 * k))
        m = M.sector_masks(level.scheme, kind, int(k), theta)
        M.use_opensubdiv_tangents(m, level.scheme, kind, int(k))
        out.tangents(vs, local, m.tu, m.tv)


def _add_bare_vertices(out: _LimitRows, level: Level, valence: np.ndarray):
    """Tangents of any other vertex with a face (non-manifold leftovers, rings of fewer than three faces): the
    normal of its first face at it, so that every vertex of the surface has a unit normal."""
    bare = np.flatnonzero(~out.with_tangents(level.num_vertices) & (valence >= 1))
    if len(bare):
        h = level.vert_corners[level.vert_corner_offsets[bare]].astype(np.int64)
        cv = level.corner_vert
        local = np.column_stack([bare, cv[level.corner_next(h)], cv[level.corner_prev(h)]])
        one = np.tile([-1.0, 1.0, 0.0], (len(bare), 1))
        out.tangents(bare, local, one, one[:, [0, 2, 1]])


def _add_remaining_positions(out: _LimitRows, level: Level, neighbours: np.ndarray):
    """Positions of the vertices no block covers: crease vertices without sectors (semi-sharp features) take
    the crease limit mask of their rule on this level, as OpenSubdiv's PrimvarRefiner::Limit; everything else
    (corners without sectors, isolated vertices, non-manifold leftovers) keeps its position."""
    covered = out.with_position(level.num_vertices)
    crease = np.flatnonzero(~covered & (level.vert_class == CREASE))
    if len(crease):
        nb = neighbours[crease]
        ok = np.all(nb >= 0, axis=1)
        crease, nb = crease[ok], nb[ok]
        centre_w, neighbour_w = M.crease_limit_weights()
        out.position(crease, np.column_stack([crease, nb]),
                     np.tile([centre_w, neighbour_w, neighbour_w], (len(crease), 1)))
        covered[crease] = True
    rest = np.flatnonzero(~covered)
    out.position(rest, rest[:, None], np.ones((len(rest), 1)))


def _merge_rows(rows_parts, local_parts, weight_parts, num_rows, num_sources) -> StencilTable:
    """A CSR table from blocks of equal-width rows: block b gives row ids (S_b,), sources and weights (S_b, n_b).

    Every row comes from at most one block, so each block is written straight to its rows' slots (no sort
    over the entries: limit tables cover every vertex of a level, and a sort would hold several entry-sized
    int64 arrays at once)."""
    counts = np.zeros(num_rows, dtype=np.int64)
    for r, l in zip(rows_parts, local_parts):
        if np.any(counts[r]) or len(np.unique(r)) != len(r):
            raise AssertionError("limit table rows must come from one block each")
        counts[r] = l.shape[1]
    offsets = face_offsets_of(counts)
    check_int32(offsets[-1], "a limit mask table needs entries")  # its int32 offsets must not wrap
    indices = np.empty(offsets[-1], dtype=np.int32)
    weights = np.empty(offsets[-1], dtype=np.float64)
    for r, l, w in zip(rows_parts, local_parts, weight_parts):
        if len(r):
            slots = offsets[np.asarray(r, dtype=np.int64)][:, None] + np.arange(l.shape[1])
            indices[slots] = l
            weights[slots] = w
    return StencilTable(offsets.astype(np.int32), indices, weights, num_sources)
