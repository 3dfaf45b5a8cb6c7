"""Level 0's sectors: the runs of faces around crease and corner vertices between two crease edges, with their
angles, kinds (crease, convex, concave, straight), reversed normals and flatness (docs/rules.md sections 0, 2, 6
and 9).

Measured once, on the control mesh: refined levels keep their parents' sectors (theta is fixed on all levels)
and add the regular crease sectors of their edge children (:mod:`.refinement`).
"""
from __future__ import annotations

import numpy as np

from ..errors import SubdivInputError
from ..mesh import INFINITE_SHARPNESS, face_offsets_of
from ..options import RuleSet
from ..rules import CORNER, CREASE
from ..rules import weights as rules
from .connectivity import Connectivity, list_rank
from .control_faces import last_tag_values, tagged_edge_sharpness


def find_sectors(mesh, rule_set, conn: Connectivity, edges, vclass, edge_sharp, sharp_count):
    """Sectors of crease and corner vertices with two or more crease edges (docs/rules.md sections 0 and 2).

    A sector is a run of faces around a vertex between two crease edges; its corners are found by walking
    clockwise to the first face (whose outgoing edge is a crease) with pointer jumping. alpha is measured
    here, once, and so is which corner sectors are straight (docs/rules.md section 2.1) and which limit normals are
    reversed (section 9). ``edges``: level 0's :class:`~warp_subdiv.mesh.MeshEdges`, where concave tags are
    looked up. Returns (vertex, offsets, ordered corners, theta, kind, flip) per sector.
    """
    corner_vert, nxt, prv, twin = conn.corner_vert, conn.next_corner, conn.prev_corner, conn.twin
    C = len(corner_vert)
    tagged_vertex = ((vclass == CREASE) | (vclass == CORNER)) & (sharp_count >= 2)
    # only the corners at those vertices are walked (a walk stays at its vertex): ``at`` lists them, and
    # ``local`` numbers them
    at = np.flatnonzero(tagged_vertex[corner_vert])
    local = np.full(C, -1, dtype=np.int64)
    local[at] = np.arange(len(at))
    twin_at = twin[at]
    cw_at = np.where(~edge_sharp[conn.corner_edge[at]] & (twin_at >= 0), nxt[np.maximum(twin_at, 0)], at)
    head_local, pos_at = list_rank(local[cw_at], conn.max_valence)
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
        concave_heads = _concave_sector_heads(mesh, conn, edge_sharp, edges, vclass, sharp_count, head,
                                              k_of_head[head])
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


def sector_flatness(flatness, sector_vertex, num_vertices):
    """Per-sector flatness s of the control vertices' sectors (NaN: the optimal s*). The regular crease sectors
    refinement makes later keep s* = 0 (``topology.refinement``), whatever ``flatness`` is: a number is the
    flatness of every control sector, as an array of that number would be. Were the new crease vertices
    flattened too, their modified rings would overlap their neighbours' on every level (the averaged
    modifications of rules section 6), and no limit or tangent mask would be an eigenvector of the resulting
    subdivision matrix at crease vertices and darts (limit points would only converge to the surface)."""
    if flatness is None:
        return np.full(len(sector_vertex), np.nan)
    arr = np.asarray(flatness, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(len(sector_vertex), float(arr))
    if arr.shape != (num_vertices,):
        raise SubdivInputError(f"flatness must be a number or one value per vertex ({num_vertices}), got {arr.shape}")
    return arr[sector_vertex]


def _concave_sector_heads(mesh, conn: Connectivity, edge_sharp, edges, vclass, sharp_count, head, k):
    """The first corner of each sector named by a concave tag (corner vertex, neighbour vertex)."""
    corner_vert, nxt = conn.corner_vert, conn.next_corner
    ecount, eoff, ecorners = conn.edge_count, conn.edge_offsets, conn.edge_corners
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
