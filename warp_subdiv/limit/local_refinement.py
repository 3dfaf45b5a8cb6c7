"""Local refinement for the patch tree: a level (or the cut-out of a level around the faces still to refine)
refined one step with the library's own tables and projections, and the lookups on a level's faces that the
tree's classification and end caps share.

A cut-out holds the faces still to refine and rings of context faces around them (``MARGIN`` in
:mod:`warp_subdiv.limit.patches`), with their tags, sharpness and sector data; only the children of its inner
faces are kept, so the refined points are those ``refine`` computes.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, fields

import numpy as np

from ..mesh import INFINITE_SHARPNESS, Mesh
from ..options import Options
from ..rules import CATMULL_CLARK
from ..tables import build_stencils, projections
from ..topology import Level, base_level, refine_level


# ----------------------------------------------------------------------------------------- one local level
@dataclass
class LocalLevel:
    """A (possibly cut-out) level: its full topology, exact points (inside the exact region), the tree node of
    each face (-1: context only), and the prescribed normals in its own vertex ids."""

    level: Level
    points: np.ndarray
    face_node: np.ndarray
    normal_ids: np.ndarray
    normal_vectors: np.ndarray
    depth: int


def csr_apply(table, src: np.ndarray) -> np.ndarray:
    counts = np.diff(table.offsets.astype(np.int64))
    rows = np.repeat(np.arange(len(counts)), counts)
    idx = table.indices.astype(np.int64)
    w = table.weights
    out = np.empty((len(counts), src.shape[1]))
    for c in range(src.shape[1]):
        out[:, c] = np.bincount(rows, weights=w * src[idx, c], minlength=len(counts))
    return out


def displace(table, points: np.ndarray) -> np.ndarray:
    """Apply a flatness or normal-control DisplacementTable (every row reads the unmoved points).

    A flatness table has scalar weights and moves every column (flatness is part of the subdivision matrix, as
    ``Refiner.evaluate`` applies it to primvars). A normal-control table moves positions only, the first three
    columns: data columns carried beside them (:func:`~warp_subdiv.limit.patches.build`'s ``data``) are refined
    as ``Refiner.evaluate`` refines primvars, without normal control."""
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


def face_corners(level: Level, faces: np.ndarray, n: int) -> np.ndarray:
    """(len(faces), n) corner ids of faces with n corners."""
    start = level.face_starts()[faces] if level.face_size == 0 else faces * level.face_size
    return start[:, None] + np.arange(n)


def region_around(level: Level, seed_faces: np.ndarray, rings: int) -> np.ndarray:
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


def cut_out(cur: LocalLevel, region: np.ndarray, options: Options) -> LocalLevel:
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
    sub.face_hole = level.face_hole[faces].copy()
    face_node = cur.face_node[faces]
    return LocalLevel(sub, cur.points[verts], face_node, normal_ids, normal_vectors, cur.depth)


def refine_step(sub: LocalLevel, options: Options) -> tuple:
    """One refinement step of a (cut-out) level: (child level, child points), with flatness and normal control."""
    o = options
    table = build_stencils(sub.level, o.rules, o.loop_beta, smooth_triangles=o.smooth_triangles)
    child = refine_level(sub.level)
    points = csr_apply(table, sub.points)
    if o.piecewise_smooth:
        s = projections.resolve_flatness(child)
        points = displace(projections.flatness_table(child, s), points)
        if len(sub.normal_ids) and o.normal_strength > 0:
            points = displace(projections.normal_table(child, sub.normal_ids, sub.normal_vectors,
                                                        o.normal_strength, s, o.loop_beta), points)
    return child, points


def child_faces(level: Level, faces: np.ndarray, scheme: str):
    """(child face ids (F, m), valid (F, m)) of ``faces``: Catmull-Clark one per corner (m = largest face),
    Loop the corner children 0..2 and the middle one (m = 4)."""
    if scheme == CATMULL_CLARK:
        sizes = level.face_sizes()[faces]
        m = int(sizes.max()) if len(faces) else 4
        starts = level.face_starts()[faces]
        j = np.arange(m)
        return starts[:, None] + j, j[None, :] < sizes[:, None]
    return 4 * faces[:, None] + np.arange(4), np.ones((len(faces), 4), bool)


def child_corners(level: Level, child: Level, corners: np.ndarray, scheme: str) -> np.ndarray:
    """The corner of ``child`` (``level`` refined one step) at the vertex of each of ``corners``: in the child
    face at that corner, the corner holding the vertex's child (vertex children keep their ids)."""
    corners = np.asarray(corners, dtype=np.int64)
    faces = level.corner_face(corners)
    j = corners - level.face_starts()[faces]
    kids, _ = child_faces(level, faces, scheme)
    kid = kids[np.arange(len(faces)), j]
    n = 4 if scheme == CATMULL_CLARK else 3
    cc = face_corners(child, kid, n)
    at = np.argmax(child.corner_vert.astype(np.int64)[cc] == level.corner_vert.astype(np.int64)[corners][:, None],
                   axis=1)
    return cc[np.arange(len(kid)), at]
