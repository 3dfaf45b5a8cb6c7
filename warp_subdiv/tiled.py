"""Tiled refinement: any level in bounded memory, bitwise equal to refining the whole mesh at once.

The children of a control face at every level depend only on the control mesh near that face, so a group of
control faces (a *tile*) refined together with a halo of the faces around it gives its own children exactly.
:func:`refine_tiled` cuts the control mesh into spatially coherent tiles (runs of faces along a Morton curve of
their centres), refines each tile with its halo as a mesh of its own, keeps the children of the tile's faces and
maps their ids to the ids they have in ``refine(mesh, levels)``.

The halo
    Two rings of faces (faces sharing a vertex with the tile, then with those). The faces of the halo's outer
    ring have vertices whose rings the submesh cuts off: their rules are not the whole mesh's (a boundary where
    there is none, and under the piecewise-smooth rules crease sectors whose edge rules and flatness move their
    neighbours), so their children are wrong. What is wrong spreads one ring of the current level per step,
    half a ring of the control mesh at level 1, a quarter at level 2, ..., less than two control rings in all;
    the paper's projections (flatness, normal control) spread one more ring of the current level per step, so a
    mesh they act on gets four rings. The tests check the claim bitwise on the test meshes.

Global ids
    OpenSubdiv's order is a closed form in the parent's ids and the per-level counts (docs/architecture.md,
    "Topology"): child vertices are [vertex children | face children (Catmull-Clark) | edge children], child
    faces follow parent corners (Catmull-Clark) or come four per triangle (Loop), child edges are [one inside the
    face per parent corner | two halves per parent edge, the half at the edge's first vertex first]. So a map of
    the submesh's vertices, faces, corners and edges to the whole mesh's at one level gives the next level's by
    index arithmetic; level 0's comes from the control mesh's own edges (whose first vertex may be the other
    end of the submesh's edge: then the halves swap). Refined faces are numbered as ``refine`` numbers them,
    hole faces left out.

Memory
    A tile's peak is the refinement estimate of :mod:`warp_subdiv.runtime.estimate` for its faces and halo, plus
    its id maps and the previous tile's arrays (held by the caller while the next tile is refined); tiles are
    sized so that this stays under ``max_memory``.
"""
from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .errors import NonManifoldWarning, SubdivInputError
from .mesh import Mesh, check_rows, face_offsets_of, find_edges
from .options import FaceVaryingMode, Options, Scheme
from .refiner import Refiner
from .runtime import estimate
from .runtime.threads import resolve as resolve_threads
from .tables import Hierarchy, check_value_indices, value_mesh
from .topology import base_faces


@dataclass
class Tile:
    """One tile of a tiled refinement (:func:`refine_tiled`).

    ``points`` (n, 3) of the evaluation precision, ``face_vertex_counts`` and ``face_vertex_indices`` (int32,
    indices into ``points``): the refined faces of the tile's control faces, hole faces left out. ``vertex_ids``
    and ``face_ids``: the rows these vertices and faces are in ``refine(mesh, levels)`` (int32, int64 where the
    refined mesh's counts pass 2^31); vertices are sorted by id, faces are in the order of their ids.
    ``border``: (n,) bool, the vertices that faces of other tiles use too.
    ``control_faces``: the level-0 faces of the tile (Loop: triangles of the fan triangulation).
    ``face_parent``: the face of the mesh as given (a polygon, not a triangle of its fan) each refined face comes
    from, as :attr:`~warp_subdiv.tables.FaceMap.parent` says of ``refine``'s faces: per-face data (uniform
    primvars, face subsets) follows it.
    ``limit_points`` and ``limit_normals``: of ``points``, where asked for; ``face_varying``: the tile's
    face-varying channel (a list of them where a list of channels was asked for); ``vertex_data``: the tile's
    rows of each array of ``vertex_data`` (refined as the points, without normal control), their limit values
    with ``limit_points`` (``limit_vertex_data``)."""

    index: int
    control_faces: np.ndarray
    points: np.ndarray
    face_vertex_counts: np.ndarray
    face_vertex_indices: np.ndarray
    vertex_ids: np.ndarray
    face_ids: np.ndarray
    border: np.ndarray
    face_parent: np.ndarray | None = None
    limit_points: np.ndarray | None = None
    limit_normals: np.ndarray | None = None
    face_varying: "TileFaceVarying | None" = None
    vertex_data: list | None = None
    limit_vertex_data: list | None = None

    @property
    def num_vertices(self) -> int:
        """The number of vertices of the tile (border vertices included)."""
        return len(self.points)

    @property
    def num_faces(self) -> int:
        """The number of refined faces of the tile."""
        return len(self.face_vertex_counts)


@dataclass
class TileFaceVarying:
    """A face-varying channel of a tile: ``values`` (m, d), ``indices`` (int32, one per corner of the tile's
    faces, into ``values``) and ``value_ids``: the rows these values are in
    :meth:`Refiner.evaluate_face_varying`'s values (sorted; values on a tile border are in every tile that
    uses them)."""

    values: np.ndarray
    indices: np.ndarray
    value_ids: np.ndarray


#: Rings of faces around a tile: enough for the subdivision rules (see the module docstring), and where the
#: paper's projections act on the mesh.
HALO_RINGS = 2
HALO_RINGS_PROJECTING = 4
#: Bytes per control face corner that a tiled refinement allocates for the whole mesh after it reads the
#: process's resident memory (the Morton order of the faces and the tiles' face lists).
GLOBAL_BYTES_PER_CORNER = 16
#: Bytes per vertex of a tile's refined submesh for its id maps (the int64 maps of the last two levels).
ID_MAP_BYTES = 24


class FaceGroups:
    """Control faces (``counts``, ``indices`` over ``num_vertices`` vertices at ``points``) as tiles are cut from
    them: the faces at every vertex (to grow a halo of rings) and a Morton order of the faces' centres (runs of
    it are compact tiles). Shared by tiled refinement and tiled tessellation."""

    def __init__(self, points, counts, indices, num_vertices: int):
        self.points = points
        self.counts = np.asarray(counts, dtype=np.int64)
        self.indices = np.asarray(indices, dtype=np.int64)
        self.offsets = face_offsets_of(self.counts)
        self.corner_face = np.repeat(np.arange(len(self.counts), dtype=np.int64), self.counts)
        self.num_vertices = num_vertices
        # the faces at each vertex (for halos)
        self.vert_faces_order = np.argsort(self.indices, kind="stable")
        self.vert_offsets = face_offsets_of(np.bincount(self.indices, minlength=num_vertices))

    def grow(self, faces: np.ndarray, rings: int) -> np.ndarray:
        """``faces`` (sorted level-0 face ids) and ``rings`` rings of faces around them (sharing a vertex)."""
        for _ in range(rings):
            verts = _members(self.indices[corners_of(self.offsets, faces)], self.num_vertices)
            around = self.vert_faces_order[corners_of(self.vert_offsets, verts)]
            faces = _members(np.concatenate([faces, self.corner_face[around]]), len(self.counts))
        return faces

    def morton_order(self) -> np.ndarray:
        """Level-0 faces along a Morton (Z-order) curve of their centres: runs of it are compact tiles."""
        pts = self.points
        centres = np.add.reduceat(pts[self.indices], self.offsets[:-1], axis=0) / self.counts[:, None]
        lo, hi = centres.min(axis=0), centres.max(axis=0)
        extent = max(float(np.max(hi - lo)), 1e-300)  # one scale for all axes: a cube's cells
        cells = np.floor((centres - lo) / extent * (2**21 - 1)).astype(np.uint64)
        code = np.zeros(len(centres), dtype=np.uint64)
        for axis in range(3):
            code |= _spread_bits(cells[:, axis]) << np.uint64(axis)
        return np.argsort(code, kind="stable")

    def runs(self, size: int) -> Iterator[np.ndarray]:
        """Runs of ``size`` faces along the Morton order (sorted); all faces in one run where they fit."""
        F = len(self.counts)
        order = self.morton_order() if size < F else np.arange(F)
        for start in range(0, F, size):
            yield np.sort(order[start:start + size])

    def fitted_runs(self, size: int, fits, too_big) -> Iterator[np.ndarray]:
        """Runs of ``size`` faces along the Morton order (sorted), each halved until ``fits(faces)``; a face that
        does not fit alone raises ``too_big(faces)``."""
        F = len(self.counts)
        order = self.morton_order()
        stack = [order[start:start + size] for start in range(0, F, size)][::-1]
        while stack:
            faces = np.sort(stack.pop())
            if fits(faces):
                yield faces
                continue
            if len(faces) == 1:
                raise too_big(faces)
            half = len(faces) // 2
            stack.append(faces[half:])
            stack.append(faces[:half])


class _Plan(FaceGroups):
    """What a tiled refinement knows of the whole mesh: level 0 as the refiner sees it, its edges, the counts of
    every level, the vertex-to-face lists the halos are grown with, and the ids of the refined faces."""

    def __init__(self, mesh: Mesh, levels: int, options: Options):
        self.mesh, self.levels, self.options = mesh, levels, options
        # the whole mesh's analysis (level 0 only; it warns of non-manifold input once): whether the paper's
        # projections act on it, and whether its limits read their masks one level deeper
        analysis = Hierarchy(mesh, 0, options)
        self.projects = analysis.projects
        self.limit_deeper = analysis.limit_reads_deeper(levels)
        del analysis
        self.loop = options.scheme == Scheme.LOOP
        faces = base_faces(mesh, options.scheme, options.boundary, options.triangulate)
        self.faces = faces
        super().__init__(mesh.points, faces.counts, faces.indices, mesh.num_vertices)
        self.edges = faces.edges
        self.face_size = faces.face_size
        # counts of every level (hole faces included): V, F, E, C
        F0 = len(self.counts)
        V, F, E, C = mesh.num_vertices, F0, len(self.edges.edge_verts), int(self.offsets[-1])
        self.level_counts = [(V, F, E, C)]
        for _ in range(levels):
            if self.loop:
                V, F, E, C = V + E, 4 * F, 2 * E + 3 * F, 12 * F
            else:
                V, F, E, C = V + F + E, C, 2 * E + C, 4 * C
            self.level_counts.append((V, F, E, C))
        wide = max(self.level_counts[-1][0], self.level_counts[-1][1]) >= 2**31
        self.id_dtype = np.int64 if wide else np.int32
        # refined faces: the descendants of level-0 face f are a run [first[f], first[f] + per_face[f]) of the
        # last level; refine() leaves hole faces out, so ids drop by the hole faces before
        if levels == 0:
            per_face, first = np.ones(F0, np.int64), np.arange(F0, dtype=np.int64)
        elif self.loop:
            per_face, first = np.full(F0, 4**levels, np.int64), np.arange(F0, dtype=np.int64) * 4**levels
        else:
            per_face, first = self.counts * 4 ** (levels - 1), self.offsets[:-1] * 4 ** (levels - 1)
        self.first_child = first
        holes_before = np.zeros(F0, np.int64)
        np.cumsum((per_face * faces.face_hole)[:-1], out=holes_before[1:])
        self.holes_before = holes_before

    def face_ids(self, base_face: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Ids in ``refine``'s faces of the child ``offset`` (in the run of its level-0 face) of ``base_face``."""
        return self.first_child[base_face] + offset - self.holes_before[base_face]


#: The vertices of the separate face a submesh of one face size gets (:class:`Submesh`).
_EXTRA_FACE_POINTS = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


def resident_bytes() -> int:
    """The process's resident memory now (Linux's ``/proc/self/status``; 0 where it cannot be read)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _mask(items: np.ndarray, size: int) -> np.ndarray:
    """(size,) bool: True at ``items`` (numpy's hashing ``unique`` and ``isin`` are many times slower on the
    refined levels' arrays than a pass over a mask)."""
    mask = np.zeros(size, dtype=bool)
    mask[items] = True
    return mask


def _members(items: np.ndarray, size: int) -> np.ndarray:
    """The distinct values of ``items`` (ids below ``size``), sorted, int64."""
    return np.flatnonzero(_mask(items, size))


def _renumbering(members: np.ndarray, size: int) -> np.ndarray:
    """(size,) int64: the position of every id in the sorted ``members`` (-1 for the others)."""
    out = np.full(size, -1, dtype=np.int64)
    out[members] = np.arange(len(members))
    return out


def corners_of(offsets: np.ndarray, items: np.ndarray) -> np.ndarray:
    """The flat positions offsets[i]..offsets[i+1] of every item i of ``items``, concatenated."""
    starts, ends = offsets[items], offsets[items + 1]
    sizes = ends - starts
    run_start = np.repeat(starts - face_offsets_of(sizes)[:-1], sizes)
    return run_start + np.arange(int(sizes.sum()), dtype=np.int64)


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """The 21 low bits of ``x`` (uint64) spread out to every third bit (a Morton code's interleave)."""
    x = x & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


class Submesh:
    """A tile's faces with their halo as a mesh of its own (vertices renumbered in increasing order, faces in
    the whole mesh's order), its tags restricted, and the maps of its level-0 elements to the whole mesh's."""

    def __init__(self, plan: _Plan, tile_faces: np.ndarray, rings: int):
        mesh = plan.mesh
        self.faces = plan.grow(tile_faces, rings)  # level-0 faces, sorted
        self.in_tile = _mask(tile_faces, len(plan.counts))[self.faces]
        global_corners = corners_of(plan.offsets, self.faces)
        corner_verts = plan.indices[global_corners]
        self.verts = _members(corner_verts, plan.num_vertices)
        local_indices = _renumbering(self.verts, plan.num_vertices)[corner_verts]
        counts = plan.counts[self.faces]
        self.global_corners = global_corners
        edges = find_edges(counts, local_indices, len(self.verts))
        self.edges = edges
        # vertices whose every face is in the submesh (their tags that need a whole ring are kept)
        corners_here = np.bincount(local_indices, minlength=len(self.verts))
        complete = corners_here == np.diff(plan.vert_offsets)[self.verts]
        self.complete = complete
        points = mesh.points[self.verts]
        # a mesh of mixed polygons has its first step evaluated from explicit stencils, a mesh of one face size
        # from index tables, summed in another order: a submesh of one face size cut from a mixed mesh gets a
        # separate face of another size (after everything else, so no id of the rest moves; no child of it is
        # kept) to be refined as the whole mesh is
        self.extra = 0
        if plan.face_size == 0 and len(np.unique(counts)) == 1 and int(counts[0]) in (3, 4):
            self.extra = 7 - int(counts[0])  # a quad next to triangles, a triangle next to quads
            points = np.concatenate([points, _EXTRA_FACE_POINTS[: self.extra]])
            local_indices = np.concatenate([local_indices, len(self.verts) + np.arange(self.extra)])
            counts = np.concatenate([counts, [self.extra]])
            self.in_tile = np.concatenate([self.in_tile, [False]])
        self.mesh = Mesh(points, counts, local_indices, **self._tags(mesh, edges, complete),
                         holes=np.flatnonzero(plan.faces.face_hole[self.faces]))
        # level 0's edges: the whole mesh's edge of each submesh edge (through a corner that makes it), and
        # whether the whole mesh's edge starts at the other vertex
        makers = np.zeros(len(edges.edge_verts), dtype=np.int64)
        makers[edges.corner_edge[::-1]] = np.arange(len(edges.corner_edge) - 1, -1, -1)
        self.edge_map = plan.edges.corner_edge[global_corners[makers]].astype(np.int64)
        first_vertex = self.verts[edges.edge_verts[:, 0]]
        self.edge_flip = (first_vertex != plan.edges.edge_verts[self.edge_map, 0]).astype(np.int64)

    def _tags(self, mesh: Mesh, edges, complete: np.ndarray) -> dict:
        """The mesh's tags on the submesh: creases on its edges, corners on its vertices, concave tags and
        prescribed normals at vertices whose whole ring it holds (else they would be refused, or act on a cut
        ring: either way only the discarded outer halo is concerned)."""
        nv = len(self.verts)

        def local(ids):
            ids = np.asarray(ids, dtype=np.int64)
            pos = np.minimum(np.searchsorted(self.verts, ids), nv - 1)
            return np.where(self.verts[pos] == ids, pos, -1)

        tags: dict = {}
        if len(mesh.creases):
            pairs = local(mesh.creases)
            keep = np.all(pairs >= 0, axis=1)
            keep[keep] = edges.find(pairs[keep], nv) >= 0
            tags.update(creases=pairs[keep], crease_sharpness=mesh.crease_sharpness[keep])
        if len(mesh.corners):
            ids = local(mesh.corners)
            keep = ids >= 0
            tags.update(corners=ids[keep], corner_sharpness=mesh.corner_sharpness[keep])
        if len(mesh.concave):
            pairs = local(mesh.concave)
            keep = np.all(pairs >= 0, axis=1)
            keep[keep] = complete[pairs[keep, 0]] & (edges.find(pairs[keep], nv) >= 0)
            tags.update(concave=pairs[keep])
        if len(mesh.normal_vertices):
            ids = local(mesh.normal_vertices)
            keep = ids >= 0
            keep[keep] = complete[ids[keep]]
            tags.update(normals=(ids[keep], mesh.normal_vectors[keep]))
        return tags

    def options(self, options: Options) -> Options:
        """``options`` for the submesh. Under the piecewise-smooth rules the flatness is per vertex: the
        mesh's (NaN: the optimal s*) at vertices whose whole ring the submesh holds, 0 at the vertices it cuts
        off, whose ring's crease sectors are the submesh's own boundary: no projection where the whole mesh has
        none (it would build every level's projection tables, and move the outer halo's points further in)."""
        if not options.piecewise_smooth:
            return options
        flat = options.flatness
        if flat is None:
            flat = np.full(len(self.verts), np.nan)
        elif isinstance(flat, numbers.Real):
            flat = np.full(len(self.verts), float(flat))
        else:
            flat = np.asarray(flat, dtype=np.float64)[self.verts]
        flat = np.where(self.complete, flat, 0.0)
        return options.replace(flatness=np.concatenate([flat, np.zeros(self.extra)]))

    def rows(self, data: np.ndarray) -> np.ndarray:
        """The submesh's rows of per-vertex ``data`` of the whole mesh (zeros for the separate face's vertices)."""
        return np.concatenate([data[self.verts], np.zeros((self.extra,) + data.shape[1:])])

    def vertex_ids(self, plan: _Plan, levels: int) -> np.ndarray:
        """(vertices of the submesh's level ``levels``,) int64: their ids in the whole mesh's level."""
        loop = plan.loop
        # the separate face of another size (``extra`` corners, vertices and edges) maps to -1: no child of it
        # is kept
        pad = np.full(self.extra, -1, dtype=np.int64)
        vmap = np.concatenate([self.verts, pad])
        fmap = np.concatenate([self.faces, pad[:1]])
        cmap = np.concatenate([self.global_corners, pad])
        emap, flip = np.concatenate([self.edge_map, pad]), np.concatenate([self.edge_flip, 0 * pad])
        for level in range(levels):
            GV, GF, _, GC = plan.level_counts[level]
            parts = [vmap] if loop else [vmap, GV + fmap]
            parts.append(GV + (0 if loop else GF) + emap)
            vmap = np.concatenate(parts)
            if level == levels - 1:
                break
            halves = GC + 2 * emap[:, None] + (np.arange(2)[None, :] ^ flip[:, None])
            emap = np.concatenate([cmap, halves.reshape(-1)])
            flip = np.zeros(len(emap), dtype=np.int64)
            if loop:
                fmap = (4 * fmap[:, None] + np.arange(4)).reshape(-1)
                cmap = (3 * fmap[:, None] + np.arange(3)).reshape(-1)
            else:
                fmap = cmap
                cmap = (4 * fmap[:, None] + np.arange(4)).reshape(-1)
        return vmap


def refine_tiled(mesh: Mesh, levels: int, *, max_memory=None, tile_faces: int | None = None,
                 options: Options | None = None, device=None, threads: int | None = None,
                 limit_points: bool = False, limit_normals: bool = False, face_varying=None, vertex_data=None,
                 **option_keywords) -> Iterator[Tile]:
    """Refine ``mesh`` uniformly ``levels`` times in tiles: an iterator of :class:`Tile`.

    Gathered by their ids, the tiles are ``refine(mesh, levels)`` bitwise: every refined face is in exactly one
    tile, a vertex on a tile border in every tile that uses it, with the same id and the same bits (control
    vertices no face uses are in no tile). Options as :func:`warp_subdiv.refine` takes them.

    ``tile_faces``: level-0 faces per tile (Loop: triangles of the fan triangulation); else tiles are sized so
    that the predicted peak of refining one (and holding the previous one) stays under ``max_memory`` (bytes or
    a size such as "4G"; default: half the physical memory), and a mesh that fits is one tile.
    ``limit_points`` / ``limit_normals``: also the limit positions and normals of each tile's vertices, bitwise
    those of :meth:`Refined.limit_points` and :meth:`Refined.limit_normals`. ``device`` and ``threads`` as
    :func:`warp_subdiv.refine` takes them. ``face_varying``: (values, indices, mode) of a face-varying channel (as
    :meth:`Refiner.evaluate_face_varying` takes them): each tile also carries :class:`TileFaceVarying`, bitwise
    that method's values and indices for the tile's faces (its value mesh is tiled with the same faces); or a
    list of such channels (UV sets, say): each tile carries a list of them, in that order.
    ``vertex_data``: a list of (n,) or (n, d) arrays of per-vertex data (vertex primvars) refined as
    :meth:`Refiner.evaluate` refines them with ``normal_control=False``, each on its own: each tile carries its
    rows of every one (``Tile.vertex_data``, bitwise those of refining the whole mesh), and with
    ``limit_points`` their limit values (``Tile.limit_vertex_data``, as :meth:`Refiner.limit_points` with
    ``normal_control=False``).
    """
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a warp_subdiv.Mesh, got {type(mesh).__name__}")
    if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 0:
        raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels", value=levels)
    if tile_faces is not None and (isinstance(tile_faces, bool) or not isinstance(tile_faces, numbers.Integral)
                                   or tile_faces < 1):
        raise SubdivInputError(f"tile_faces must be an integer >= 1, got {tile_faces!r}", option="tile_faces",
                               value=tile_faces)
    options = Options.given(options, option_keywords, caller="refine_tiled")
    options.check_prescribed_normals(len(mesh.normal_vertices))
    limit = bool(limit_points or limit_normals)
    budget = estimate.memory_limit(max_memory)
    if budget is None and tile_faces is None:
        budget = estimate.default_max_memory()
    several = isinstance(face_varying, list)
    channels = [_face_varying_plan(mesh, int(levels), options, c)
                for c in (face_varying if several else [] if face_varying is None else [face_varying])]
    extra = _vertex_data(mesh, vertex_data)
    return _tiles(mesh, int(levels), options, budget, tile_faces, device, resolve_threads(threads), limit,
                  bool(limit_points), bool(limit_normals), channels, several, extra)


def _vertex_data(mesh: Mesh, vertex_data) -> list:
    """``vertex_data`` checked: a list of float64 arrays of one row per control vertex ((n,) kept as (n, 1))."""
    if vertex_data is None:
        return []
    if isinstance(vertex_data, np.ndarray) or not isinstance(vertex_data, (list, tuple)):
        raise SubdivInputError("vertex_data must be a list of arrays (one per kind of vertex data)",
                               option="vertex_data")
    out = []
    for i, data in enumerate(vertex_data):
        rows = check_rows(data, mesh.num_vertices, f"vertex_data[{i}]")
        out.append(np.asarray(rows, dtype=np.float64).reshape(mesh.num_vertices, -1))
    return out


def _face_varying_plan(mesh, levels, options, face_varying):
    """(plan of the channel's value mesh, its values per value-mesh vertex): the value mesh and options of
    :class:`~warp_subdiv.tables.FaceVaryingChannel`, whose faces are the mesh's level-0 faces."""
    try:
        values, indices, mode = face_varying
    except (TypeError, ValueError):
        raise SubdivInputError("face_varying must be (values, indices, mode)", option="face_varying") from None
    mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
    indices = check_value_indices(indices, len(mesh.face_vertex_indices))
    vmesh, source = value_mesh(mesh, indices, mode, options.boundary, options.scheme)
    voptions = options.replace(rules="opensubdiv", boundary="edge-only", flatness=None, loop_beta="loop",
                               linear=(mode == FaceVaryingMode.ALL))
    count = int(source.max()) + 1 if len(source) else 0
    vals = check_rows(values, count, "face-varying values", at_least=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)  # disjoint value fans are expected
        return _Plan(vmesh, levels, voptions), vals[source]


def _tiles(mesh, levels, options, budget, tile_faces, device, threads, limit, want_points, want_normals, channels,
           several, extra):
    plan = _Plan(mesh, levels, options)
    rings = HALO_RINGS_PROJECTING if plan.projects else HALO_RINGS
    deeper = plan.limit_deeper if limit else False
    # the previous tile's arrays and this tile's, and this tile's channels as they are refined one by one; vertex
    # data: rows of the points' size per 3 columns
    held = 2 + len(channels) + sum(a.shape[1] for a in extra) / 3
    for index, faces in enumerate(_tile_faces(plan, tile_faces, budget, rings, limit, deeper, held)):
        tile = _refine_tile(plan, index, faces, rings, device, threads, want_points, want_normals, deeper,
                            extra=extra)
        fvs = [_refine_tile(c[0], index, faces, HALO_RINGS, device, threads, False, False, False, data=c[1])
               for c in channels]
        fvs = [TileFaceVarying(fv.points, fv.face_vertex_indices, fv.vertex_ids) for fv in fvs]
        if fvs:
            tile.face_varying = fvs if several else fvs[0]
        yield tile


def _tile_bytes(plan: _Plan, faces: np.ndarray, rings: int, limit: bool, deeper: bool, held: int = 2) -> int:
    """The predicted peak of refining the tile of ``faces`` with its halo, its output held ``held`` times (this
    tile's, the previous one's held by the caller, and where a face-varying channel is refined after the points,
    the tile's points meanwhile; the channel's own tile is about the points' size)."""
    sub = plan.grow(faces, rings)
    corners = corners_of(plan.offsets, sub)
    verts = _members(plan.indices[corners], plan.num_vertices)
    counts = plan.counts[sub]
    # edges of the submesh: (corners + boundary edges) / 2, bounded by the corners
    num_edges = len(corners)
    o = plan.options
    est = estimate.estimate("tile", len(verts), counts, num_edges, plan.levels, o.scheme, precision=o.precision,
                            projecting=plan.projects, limit=limit, limit_deeper=deeper)
    return int(est.working_bytes + held * est.output_bytes + ID_MAP_BYTES * est.final.vertices)


def _tile_faces(plan: _Plan, tile_faces, budget, rings, limit, deeper, held=2) -> Iterator[np.ndarray]:
    """The level-0 faces of every tile (sorted): runs of ``tile_faces`` faces along the Morton curve, or runs
    sized to ``budget``, halved until each one's prediction fits."""
    F = len(plan.counts)
    if tile_faces is not None:
        yield from plan.runs(tile_faces)
        return
    # what the process holds now (Warp's runtime, the mesh, the plan, the caller's data) is not the tiles'
    held_now = max(estimate.RUNTIME_BYTES, resident_bytes()) + GLOBAL_BYTES_PER_CORNER * int(plan.offsets[-1])
    available = budget - held_now
    everything = np.arange(F, dtype=np.int64)
    if _tile_bytes(plan, everything, 0, limit, deeper, held) <= available:
        yield everything
        return
    whole = _tile_bytes(plan, everything, 0, limit, deeper, held)

    def too_big(faces):
        return SubdivInputError(
            f"refining one control face with its halo to level {plan.levels} needs about "
            f"{estimate.format_bytes(_tile_bytes(plan, faces, rings, limit, deeper, held))} (with what the tiled "
            f"refinement keeps), more than max_memory {estimate.format_bytes(budget)} leaves beside the "
            f"{estimate.format_bytes(held_now)} the process and the whole mesh's plan already hold; raise "
            "max_memory or refine fewer levels", option="max_memory", value=budget)

    size = max(1, int(F * available / whole / 2))  # half the share: room for the halo
    yield from plan.fitted_runs(size, lambda faces: _tile_bytes(plan, faces, rings, limit, deeper, held) <= available,
                                too_big)


def _refine_tile(plan: _Plan, index: int, faces: np.ndarray, rings: int, device, threads, want_points: bool,
                 want_normals: bool, deeper: bool, data=None, extra=()) -> Tile:
    """Refine one tile with its halo and keep the children of its own faces, with their global ids. ``data``:
    rows per vertex of the plan's mesh refined instead of its points (no normal control); ``extra``: arrays of
    rows per vertex refined beside the points (no normal control), with their limits where ``want_points``."""
    levels = plan.levels
    sub = Submesh(plan, faces, rings)
    options = sub.options(plan.options)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)  # the whole mesh's analysis would warn once
        refiner = Refiner(sub.mesh, levels, options=options, device=device, threads=threads)
        if data is None:
            points = refiner.evaluate(sub.mesh.points)
        else:
            points = refiner.evaluate(sub.rows(data), normal_control=False)
        refined_data = [refiner.evaluate(sub.rows(a), normal_control=False) for a in extra]
        lp = ln = None
        limit_data = []
        if want_points or want_normals:
            source, last_step, rows = _limit_source(refiner, sub, options, device, threads, deeper)
            lp, ln = _limits(source, last_step, rows, points, options, want_points, want_normals)
            if want_points:
                limit_data = [source.evaluator.limit_points(a, last_step=last_step, normal_control=False, rows=rows)
                              for a in refined_data]
            del source
    final = refiner.hierarchy.final
    base_hole = refiner.hierarchy.parentage.base_face_hole  # the submesh's level-0 holes ("none" included)
    del refiner
    # the children of the submesh's level-0 face f are the run first[f]..first[f + 1] of the last level's faces
    # (holes inherited), as the whole mesh's are: kept, the runs of the tile's faces that are not holes
    sub_counts = np.asarray(sub.mesh.face_vertex_counts, dtype=np.int64)
    if levels == 0:
        per_face = np.ones(len(sub_counts), np.int64)
    elif plan.loop:
        per_face = np.full(len(sub_counts), 4**levels, np.int64)
    else:
        per_face = sub_counts * 4 ** (levels - 1)
    first = face_offsets_of(per_face)
    mine = np.flatnonzero(sub.in_tile & ~base_hole)
    kept = corners_of(first, mine)
    g = sub.faces[mine]
    parent = g if plan.faces.control_face is None else plan.faces.control_face[g]
    shift = plan.first_child[g] - plan.holes_before[g] - first[mine]
    face_ids = (kept + np.repeat(shift, per_face[mine])).astype(plan.id_dtype)
    F = final.num_faces
    sizes = final.face_sizes()[kept] if final.face_size == 0 else np.full(len(kept), final.face_size, np.int64)
    if final.face_size:
        corner_vert = final.corner_vert.reshape(F, final.face_size)[kept].reshape(-1)
    else:
        corner_vert = final.corner_vert[corners_of(final.face_offsets, kept)]
    used = _members(corner_vert, final.num_vertices)
    vertex_ids = sub.vertex_ids(plan, levels)[used]
    order = np.argsort(vertex_ids, kind="stable")
    used, vertex_ids = used[order], vertex_ids[order]
    # border vertices: also used by a face of another tile that refine() keeps (not a hole)
    others = corners_of(first, np.flatnonzero(~sub.in_tile & ~base_hole))
    if final.face_size:
        other_verts = final.corner_vert.reshape(F, final.face_size)[others].reshape(-1)
    else:
        other_verts = final.corner_vert[corners_of(final.face_offsets, others)]
    border = _mask(other_verts, final.num_vertices)[used]
    to_tile = np.full(final.num_vertices, -1, dtype=np.int64)
    to_tile[used] = np.arange(len(used))
    return Tile(
        index=index,
        control_faces=faces,
        points=np.ascontiguousarray(points[used]),
        face_vertex_counts=sizes.astype(np.int32),
        face_vertex_indices=to_tile[corner_vert].astype(np.int32),
        vertex_ids=vertex_ids.astype(plan.id_dtype),
        face_ids=face_ids,
        border=border,
        face_parent=np.repeat(parent, per_face[mine]).astype(plan.id_dtype),
        limit_points=None if lp is None else np.ascontiguousarray(lp[used]),
        limit_normals=None if ln is None else np.ascontiguousarray(ln[used]),
        vertex_data=[np.ascontiguousarray(a[used]) for a in refined_data] if extra else None,
        limit_vertex_data=[np.ascontiguousarray(a[used]) for a in limit_data] if extra and want_points else None,
    )


def _limit_source(refiner: Refiner, sub: Submesh, options, device, threads, deeper: bool):
    """(refiner whose limit masks serve, whether its last step is refined first, the rows kept): the submesh's
    refiner itself, or with the whole mesh's choice of masks one level deeper (a submesh's own choice can differ:
    its cut-off halo has crease sectors the whole mesh does not) a refiner of one more level."""
    if not deeper:
        return refiner, False, None
    return Refiner(sub.mesh, refiner.levels + 1, options=options, device=device, threads=threads), True, \
        refiner.num_vertices


def _limits(source: Refiner, last_step: bool, rows, points, options, want_points, want_normals):
    """Limit points and normals of the submesh's last level from ``source`` (:func:`_limit_source`)."""
    evaluator = source.evaluator
    lp = evaluator.limit_points(points, last_step=last_step, normal_control=True, rows=rows) if want_points else None
    ln = None
    if want_normals:
        prescribed = (source.hierarchy.normal_vertices, source.hierarchy.normal_vectors)
        if options.normal_strength <= 0:
            prescribed = (prescribed[0][:0], prescribed[1][:0])
        ln = evaluator.limit_normals(points, prescribed, last_step=last_step, normal_control=True,
                                     rows=rows)
    return lp, ln
