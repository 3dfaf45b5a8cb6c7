"""The analysis of the control mesh (level 0): its edges, fans and manifoldness, the sharpness of its edges and
vertices, their classes (docs/rules.md section 1) and its sectors.

Level 0 is analysed once, with sorting (edges, rings, fans, sectors); every later level is derived from its
parent's tables by index arithmetic (:mod:`.refinement`).
"""
from __future__ import annotations

import warnings

import numpy as np

from ..errors import NonManifoldWarning
from ..mesh import INFINITE_SHARPNESS, Mesh, face_offsets_of
from ..options import Boundary, CreaseMethod, RuleSet, Scheme
from ..rules import semi_sharp_vertices, vertex_rule
from .connectivity import Connectivity, connectivity
from .control_faces import base_faces, last_tag_values, tagged_edge_sharpness
from .level import Level, Sectors, full_level
from .sectors import find_sectors, sector_flatness


def _check_choice(value, kind, name: str) -> None:
    """ValueError unless ``value`` is a member of the option enum ``kind`` or exactly its string value (the
    level functions are also called directly, with strings; :class:`~warp_subdiv.options.Options` is the
    lenient front door)."""
    if value not in kind.values():
        raise ValueError(f"{name} must be one of {kind.values()}, got {value!r}")


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
    conn = connectivity(faces, nv)
    edge_verts = conn.edge_verts

    # edge sharpness: boundary and non-manifold edges are infinitely sharp, tagged creases as given
    edge_sharpness = tagged_edge_sharpness(mesh, faces.edges)
    edge_sharpness[conn.boundary_edge | conn.nonmanifold_edge] = INFINITE_SHARPNESS
    _warn_nonmanifold(conn)
    vert_sharpness = _vertex_sharpness(mesh, conn, boundary)
    sharp_count = np.bincount(edge_verts[edge_sharpness > 0].reshape(-1), minlength=nv)
    if linear:  # bilinear refinement (face-varying "all"): corners and sharp edges everywhere
        vert_sharpness[:] = INFINITE_SHARPNESS
        edge_sharpness[:] = INFINITE_SHARPNESS
    vclass = vertex_rule(vert_sharpness, sharp_count)
    edge_sharp = edge_sharpness > 0

    # sectors and their angles: at crease and corner vertices whose sharp edges and own sharpness are all
    # infinite (semi-sharp features follow OpenSubdiv's rules in both rule sets)
    semi_vertex = semi_sharp_vertices(edge_verts, edge_sharpness, vert_sharpness)
    sectors = find_sectors(mesh, rule_set, conn, faces.edges, vclass, edge_sharp,
                           np.where(semi_vertex, 0, sharp_count))
    flatness_of_sectors = sector_flatness(flatness, sectors[0], nv)

    uniform = faces.face_size
    level = full_level(
        scheme, nv, uniform, conn.corner_vert, faces.face_hole,
        face_offsets=None if uniform else face_offsets_of(faces.counts),
        corner_next_table=None if uniform else conn.next_corner,
        corner_edge=conn.corner_edge, edge_verts=edge_verts, edge_corner_offsets=conn.edge_offsets,
        edge_corners=conn.edge_corners, vert_corner_offsets=conn.vert_offsets, vert_corners=conn.vert_corners,
        vert_class=vclass, edge_sharpness=edge_sharpness, vert_sharpness=vert_sharpness,
        sectors=Sectors(*sectors[:5], flatness_of_sectors, sectors[5]), crease_method=crease_method,
        linear=linear, control_face=faces.control_face,
    )
    level.degenerate_edges = bool(np.any(edge_verts[:, 0] == edge_verts[:, 1]))
    return level


def _warn_nonmanifold(conn: Connectivity) -> None:
    """A :class:`NonManifoldWarning` naming the non-manifold edges and the vertices joining separate fans, if
    any (attributed to the caller of :func:`base_level`'s caller, as when :func:`base_level` warned itself)."""
    nonmanifold_edge, fans = conn.nonmanifold_edge, conn.fans
    if np.any(nonmanifold_edge) or np.any(fans > 1):
        ne = np.flatnonzero(nonmanifold_edge)
        nmv = np.flatnonzero(fans > 1)
        parts = []
        if len(ne):
            parts.append(f"{len(ne)} non-manifold edges (first: {conn.edge_verts[ne[0]].tolist()})")
        if len(nmv):
            parts.append(f"{len(nmv)} vertices joining separate fans (first: vertex {int(nmv[0])})")
        warnings.warn(
            "non-manifold mesh: " + ", ".join(parts) + "; their edges are made sharp and their vertices corners "
            "or creases, as OpenSubdiv does",
            NonManifoldWarning,
            stacklevel=4,
        )


def _vertex_sharpness(mesh: Mesh, conn: Connectivity, boundary: str) -> np.ndarray:
    """(V,) float64: tagged corners as given (the last tag of a vertex wins); one-face boundary vertices
    (edge-and-corner), non-manifold vertices that are not creases and unused vertices are infinitely sharp, as
    in OpenSubdiv."""
    nv = mesh.num_vertices
    vcount, boundary_edge, nonmanifold_edge = conn.vert_count, conn.boundary_edge, conn.nonmanifold_edge
    vert_sharpness = last_tag_values(nv, mesh.corners, mesh.corner_sharpness)
    # non-manifold vertices are corners, except a "fin" inside the mesh (two non-manifold edges, no boundary
    # edge, more faces than edges), which OpenSubdiv keeps a crease
    ends = conn.edge_verts.reshape(-1)
    edges_at = np.bincount(ends, minlength=nv)
    if nonmanifold_edge.any():
        nonmanifold_edges_at = np.bincount(ends, weights=np.repeat(nonmanifold_edge, 2), minlength=nv)
        boundary_edges_at = np.bincount(ends, weights=np.repeat(boundary_edge, 2), minlength=nv)
        fin = (nonmanifold_edges_at == 2) & (boundary_edges_at == 0) & (vcount > edges_at)
    else:  # no non-manifold edge: no fin
        fin = np.zeros(nv, dtype=bool)
    forced = conn.nonmanifold_vert & ~fin
    if boundary == Boundary.EDGE_AND_CORNER:  # a topological corner: one face, two edges
        forced |= (vcount == 1) & (edges_at == 2)
    forced |= vcount == 0  # unused vertices keep their position
    vert_sharpness[forced] = INFINITE_SHARPNESS
    return vert_sharpness
