"""Tiled tessellation: the watertight tessellation of a mesh's limit surface in bounded memory, bitwise equal to
the in-core one (:func:`warp_subdiv.limit.tessellate`).

Tiles
    Runs of control faces along a Morton curve of their centres (:class:`warp_subdiv.tiled.FaceGroups`, as
    :func:`warp_subdiv.refine_tiled` cuts them). Each tile is tessellated from a
    :class:`~warp_subdiv.limit.LimitSurface` of its faces with a halo (:class:`warp_subdiv.tiled.Submesh`: tags,
    holes and flatness restricted as tiled refinement restricts them). The patches of a face depend on the
    control mesh near it only (its local refinement and end caps are refinement with the library's rules, whose
    reach :mod:`warp_subdiv.tiled` bounds by two rings of faces, four where the paper's projections act), so
    with that halo the faces of the tile and of the ring around it have the whole mesh's patches. The extra ring
    is there because a vertex on a tile's border may be evaluated, in the in-core tessellation, in a face of the
    next tile (the first cell that emits it).

Global numbering
    The in-core tessellation numbers its vertices as raw ids: the control vertices, then the inner points of
    the control edges (in edge order, ``rate - 1`` each), the n-gons' centres and the inner points of their
    spokes (Catmull-Clark) or of the fans' diagonals (Loop), then the interior points of the cells, group by
    group (cells grouped by pattern, in sorted pattern order; within a group in cell order). Raw ids that no
    face uses (control vertices and edges only on holes) are dropped and the rest renumbered in order. All of
    this depends on the rates and the topology only, so it is computed once for the whole mesh (arrays the size
    of the control mesh) and each tile's ids follow by index arithmetic (:class:`_Numbering`). Output faces are
    numbered group by group, cell by cell, in each cell's pattern order. A vertex's point is evaluated at the
    (face, u, v) of the first cell that emits it; a tile emits its cells and those of the ring around it in the
    in-core order, so it finds the same first cell.

Rates
    Integer rates (uniform, per face, per edge) are the whole mesh's from the topology. With ``edge_length`` an
    edge's rate depends on its limit curve, evaluated on the first face (in corner order) that has the edge:
    a first pass over the tiles measures the curves of the tiles' edges on the tiles' surfaces (the same
    patches, the same face), and the tiles are tessellated in a second pass.

Memory
    A tile's peak is predicted from its surface (per control corner of the tile and its halo, far more per corner
    of a face the surface refines locally), the ring's emitted vertices, its output (per emitted vertex and per
    output face) and the previous tile held by the caller: :func:`predict`, calibrated against measured peaks
    (``bench/bench_tiled_tessellate.py --calibrate``). Non-manifold meshes are refused (their limit surface's local
    refinement works on the whole level where it can).
"""
from __future__ import annotations

import numbers
import warnings
from types import SimpleNamespace
from typing import Iterator

import numpy as np

from .errors import NonManifoldWarning, SubdivInputError
from .limit import DEFAULT_DEPTH, LimitSurface
from .limit.patches import is_manifold
from .limit.tessellation import (MAX_VERTICES, cell_groups, edge_curve_lengths, emit_cells, segment_rates,
                                 tessellation_cells)
from .mesh import Mesh
from .options import Options, Scheme
from .runtime import estimate
from .tables import Hierarchy
from .tiled import HALO_RINGS, HALO_RINGS_PROJECTING, FaceGroups, Tile, Submesh, corners_of, resident_bytes
from .topology import base_faces

#: Bytes per control face corner of a limit surface (its patch tree, parameterisation and the level-0 analysis)
#: where the face's limit is a polynomial patch, and where it is refined locally (:func:`irregular_faces`: n-gons,
#: extraordinary and boundary vertices, tags; at the default depth 8), per emitted vertex of a tessellation (ids,
#: (u, v), their sort, the evaluation's points, derivatives and normals) and per output face (corner ids and
#: (u, v), the faces' arrays); measured peaks above the baseline (``bench/bench_tiled_tessellate.py
#: --calibrate``, BENCHMARKS.md "Beyond memory").
SURFACE_BYTES_PER_CORNER = 1000
SURFACE_BYTES_PER_IRREGULAR_CORNER = 256 * 1024
TESSELLATION_BYTES_PER_VERTEX = 320
TESSELLATION_BYTES_PER_FACE = 320
#: Bytes per vertex that a tile emits for the ring of faces around it only to find its border vertices' first
#: cells (ids and (u, v), concatenated and sorted; not evaluated).
RING_BYTES_PER_VERTEX = 80
#: Bytes per vertex and per face of a tile held by the caller (points, normals, ids; faces, ids).
TILE_BYTES_PER_VERTEX = 3 * 24 + 8 + 1
TILE_BYTES_PER_FACE = 4 + 4 * 4 + 8
#: Bytes per control corner that a tiled tessellation holds for the whole mesh (cells, lines, numbering).
GLOBAL_BYTES_PER_CORNER = 400


def predict(corners: int, irregular_corners: int, vertices: int, faces: int, depth: int = DEFAULT_DEPTH) -> int:
    """The predicted peak (bytes above the process's baseline) of tessellating control faces of ``corners``
    corners, ``irregular_corners`` of them on faces refined locally (``depth`` levels), into about ``vertices``
    emitted vertices and ``faces`` faces."""
    local = SURFACE_BYTES_PER_IRREGULAR_CORNER * min(1.0, 2.0 ** (depth - DEFAULT_DEPTH))
    return int(SURFACE_BYTES_PER_CORNER * corners + local * irregular_corners
               + TESSELLATION_BYTES_PER_VERTEX * vertices + TESSELLATION_BYTES_PER_FACE * faces)


def irregular_faces(mesh: Mesh, options: Options) -> np.ndarray:
    """(F,) bool: the control faces whose limit surface is refined locally, or may be (a conservative guess for
    the memory prediction): polygons other than the scheme's, faces at a vertex whose number of faces is not the
    regular one (4 Catmull-Clark, 6 Loop) or that is on a boundary, faces with a tagged edge or vertex."""
    counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
    indices = np.asarray(mesh.face_vertex_indices, dtype=np.int64)
    F, V = len(counts), mesh.num_vertices
    if options.linear:
        return np.zeros(F, dtype=bool)
    loop = options.scheme == Scheme.LOOP
    corner_face = np.repeat(np.arange(F), counts)
    corner_edge = np.asarray(mesh.edges.corner_edge, dtype=np.int64)
    edge_faces = np.bincount(corner_edge, minlength=len(mesh.edges.edge_verts))
    odd = np.bincount(indices, minlength=V) != (6 if loop else 4)
    ev = np.asarray(mesh.edges.edge_verts, dtype=np.int64)
    odd[ev[edge_faces != 2].reshape(-1)] = True
    if len(mesh.creases):
        odd[np.asarray(mesh.creases, dtype=np.int64).reshape(-1)] = True
    if len(mesh.corners):
        odd[np.asarray(mesh.corners, dtype=np.int64)] = True
    out = counts != (3 if loop else 4)
    out[corner_face[odd[indices]]] = True
    return out


class _SurfacePlan(FaceGroups):
    """The control mesh as its limit surface has it (Loop polygons stay polygons: the surface parameterises
    them itself), with what :class:`~warp_subdiv.tiled.Submesh` reads of a plan, the analysis of the whole
    mesh (whether the paper's projections act) and the limit surface's holes."""

    def __init__(self, mesh: Mesh, options: Options, tiles: bool = True):
        if tiles and not options.linear and not is_manifold(mesh, options):
            raise SubdivInputError("a tiled tessellation needs a manifold mesh (this one has non-manifold edges or "
                                   "vertices, whose limit surface is built from the whole mesh): tessellate it in "
                                   "core", option="max_memory")
        super().__init__(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, mesh.num_vertices)
        self.mesh, self.options = mesh, options
        self.edges = mesh.edges
        sizes = np.unique(self.counts)
        self.face_size = int(sizes[0]) if len(sizes) == 1 else 0
        F = len(self.counts)
        explicit = np.zeros(F, dtype=bool)
        explicit[np.asarray(mesh.holes, dtype=np.int64)] = True
        self.faces = SimpleNamespace(face_hole=explicit)  # the submeshes' holes: the mesh's own
        # whether the paper's projections act (a wider halo); a plan for the prediction only needs no halo
        self.projects = False if options.linear or not tiles else Hierarchy(mesh, 0, options).projects
        # the surface's holes (holes, and boundary="none"'s faces): those of its level 0, a Loop polygon's from
        # its first fan triangle (as LimitSurface reads them from the patch tree's roots)
        base = base_faces(mesh, options.scheme, options.boundary, True)
        hole = np.asarray(base.face_hole, dtype=bool)
        if options.scheme == Scheme.LOOP and len(hole) != F:
            first = np.concatenate([[0], np.cumsum(self.counts - 2)[:-1]]).astype(np.int64)
            hole = hole[first]
        self.holes = explicit if options.linear else hole
        self.irregular = irregular_faces(mesh, options)


class _Numbering:
    """The whole mesh's tessellation layout without its points: rates, cells, lines, cell groups, and the
    arithmetic of the in-core ids (see the module docstring)."""

    def __init__(self, plan: _SurfacePlan, edge_rate: np.ndarray, face_rate: np.ndarray, quads: bool):
        mesh = plan.mesh
        loop = plan.options.scheme == Scheme.LOOP
        layout = SimpleNamespace(mesh=mesh, triangles=loop, holes=plan.holes,
                                 face_tiles=np.ceil(np.sqrt(plan.counts)).astype(np.int32))
        self.cells, self.lines, next_id, self.edge_rate = tessellation_cells(layout, edge_rate, face_rate)
        F = len(plan.counts)
        if self.cells.kind is None:
            self.groups, self.face_cells = None, np.zeros(F + 1, np.int64)
            self.num_vertices = self.num_faces = 0
            self.id_dtype = np.int32
            return
        self.groups = cell_groups(self.cells, bool(quads) and not loop)
        pats = self.groups.patterns
        group = self.groups.group
        n_cells = np.bincount(group, minlength=len(pats))
        self.n_int = np.array([len(p.interior_st) for p in pats], dtype=np.int64)
        self.n_faces = np.array([len(p.faces) for p in pats], dtype=np.int64)
        self.n_local = np.array([p.num_local for p in pats], dtype=np.int64)
        self.interior_start = next_id + np.concatenate([[0], np.cumsum(n_cells * self.n_int)[:-1]])
        self.face_start = np.concatenate([[0], np.cumsum(n_cells * self.n_faces)])
        order = np.argsort(group, kind="stable")
        self.emit_pos = np.empty(len(group), dtype=np.int64)
        self.emit_pos[order] = np.arange(len(group))
        self.rank = self.emit_pos - np.concatenate([[0], np.cumsum(n_cells)[:-1]])[group]
        # the cells of every control face (CSR, in cell order)
        by_face = np.argsort(self.cells.face, kind="stable")
        self.face_cell_order = by_face
        self.face_cells = np.concatenate([[0], np.cumsum(np.bincount(self.cells.face, minlength=F))])
        # raw ids no face uses: control vertices and inner points of edges that only holes have
        live = np.repeat(~plan.holes, plan.counts)
        used_v = np.zeros(plan.num_vertices, dtype=bool)
        used_v[plan.indices[live]] = True
        corner_edge = np.asarray(mesh.edges.corner_edge, dtype=np.int64)
        used_e = np.zeros(len(self.edge_rate), dtype=bool)
        used_e[corner_edge[live]] = True
        self.V = plan.num_vertices
        self.vertex_number = np.cumsum(used_v) - 1
        inner = self.edge_rate - 1
        self.edge_base = self.lines[3][:len(inner)]
        self.edge_end = self.V + int(inner.sum())
        self.edge_number = int(used_v.sum()) + np.concatenate([[0], np.cumsum(inner * used_e)[:-1]])
        self.dropped = (self.V - int(used_v.sum())) + int((inner * ~used_e).sum())
        total_raw = int(self.interior_start[-1] + n_cells[-1] * self.n_int[-1])
        self.num_vertices = total_raw - self.dropped
        self.num_faces = int(self.face_start[-1])
        self.id_dtype = np.int64 if max(self.num_vertices, self.num_faces) >= 2**31 else np.int32

    def vertex_ids(self, raw: np.ndarray) -> np.ndarray:
        """The in-core ids of raw ids ``raw`` (used ones)."""
        raw = np.asarray(raw, dtype=np.int64)
        out = raw - self.dropped
        control = raw < self.V
        out[control] = self.vertex_number[raw[control]]
        on_edge = ~control & (raw < self.edge_end)
        r = raw[on_edge]
        e = np.searchsorted(self.edge_base, r, side="right") - 1
        out[on_edge] = self.edge_number[e] + r - self.edge_base[e]
        return out

    def cells_of(self, faces: np.ndarray) -> np.ndarray:
        """The cells of control ``faces``, in the order the in-core tessellation emits them."""
        cells = self.face_cell_order[corners_of(self.face_cells, np.asarray(faces, dtype=np.int64))]
        return cells[np.argsort(self.emit_pos[cells], kind="stable")]

    def size_of(self, faces: np.ndarray) -> tuple:
        """(emitted vertices, output faces) of control ``faces``."""
        cells = self.face_cell_order[corners_of(self.face_cells, np.asarray(faces, dtype=np.int64))]
        g = self.groups.group[cells]
        return int(self.n_local[g].sum()), int(self.n_faces[g].sum())


def tessellate_tiled(mesh: Mesh, *, rate=None, edge_length=None, quads: bool = True, max_memory=None,
                     tile_faces: int | None = None, depth: int = DEFAULT_DEPTH, options: Options | None = None,
                     device=None, **option_keywords) -> Iterator[Tile]:
    """Tessellate the limit surface of ``mesh`` in tiles: an iterator of :class:`~warp_subdiv.Tile`.

    Gathered by their ids, the tiles are ``LimitSurface(mesh, ...).tessellate(rate=..., edge_length=...,
    quads=...)`` bitwise: ``points`` (float64) and ``limit_normals`` (the tessellation's unit normals) of the
    tile's vertices, ``vertex_ids`` their rows in the in-core tessellation (sorted), ``face_vertex_counts`` and
    ``face_vertex_indices`` (int32, tile-local) its faces, ``face_ids`` their rows (ascending), ``border`` the
    vertices that faces of other tiles use too (in every such tile, with the same id and bits), and
    ``control_faces`` the tile's control faces. Ids are int64 where the tessellation's counts pass 2^31 (the
    in-core guard of 50M vertices does not apply to tiles).

    ``rate`` and ``edge_length`` as :func:`warp_subdiv.limit.tessellate` takes them (with ``edge_length`` the
    tiles are visited twice: once to measure the edges' limit curves, once to tessellate). ``tile_faces``:
    control faces per tile; else tiles are sized so that the predicted peak of one (and the previous one, held
    by the caller) stays under ``max_memory`` (bytes or a size such as "4G"; default: half the physical memory),
    and a mesh that fits is one tile. ``depth``, ``options`` (or option keywords) and ``device`` as
    :class:`~warp_subdiv.LimitSurface` takes them."""
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a warp_subdiv.Mesh, got {type(mesh).__name__}")
    if tile_faces is not None and (isinstance(tile_faces, bool) or not isinstance(tile_faces, numbers.Integral)
                                   or tile_faces < 1):
        raise SubdivInputError(f"tile_faces must be an integer >= 1, got {tile_faces!r}", option="tile_faces",
                               value=tile_faces)
    if isinstance(depth, bool) or not isinstance(depth, numbers.Integral) or not 1 <= depth <= 30:
        raise SubdivInputError(f"depth must be an integer in [1, 30], got {depth!r}", option="depth", value=depth)
    options = Options.given(options, option_keywords, caller="tessellate_tiled")
    options.check_prescribed_normals(len(mesh.normal_vertices))
    budget = estimate.memory_limit(max_memory)
    if budget is None and tile_faces is None:
        budget = estimate.default_max_memory()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)  # (a non-manifold mesh is refused)
        plan = _SurfacePlan(mesh, options)
    lite = SimpleNamespace(mesh=mesh)
    if edge_length is None:
        edge_rate, face_rate = segment_rates(lite, rate, None)
    else:
        segment_rates(lite, rate, edge_length, lengths=np.zeros(len(mesh.edges.edge_verts)))  # the arguments' checks
    return _tiles(plan, rate, edge_length, quads, budget, tile_faces, int(depth), device,
                  None if edge_length is not None else (edge_rate, face_rate))


def _tiles(plan: _SurfacePlan, rate, edge_length, quads, budget, tile_faces, depth, device, rates):
    """The tiles (``rates``: (edge rates, face rates), or None to measure the edges' curves for ``edge_length``)."""
    rings = (HALO_RINGS_PROJECTING if plan.projects else HALO_RINGS) + 1
    if rates is None:  # edge lengths: the edges' curves measured on the tiles' surfaces
        lengths = np.zeros(len(plan.mesh.edges.edge_verts))
        rough = _Numbering(plan, *segment_rates(SimpleNamespace(mesh=plan.mesh), 1, None), quads)
        for faces in _tile_faces(plan, rough, tile_faces, budget, rings, depth):
            _measure_edges(plan, faces, rings, depth, device, lengths)
        rates = segment_rates(SimpleNamespace(mesh=plan.mesh), None, edge_length, lengths=lengths)
    numbering = _Numbering(plan, rates[0], rates[1], quads)
    if numbering.groups is None:
        return
    index = 0
    for faces in _tile_faces(plan, numbering, tile_faces, budget, rings, depth):
        if plan.holes[faces].all():  # nothing to tessellate: no tile
            continue
        yield _tessellate_tile(plan, numbering, index, faces, rings, depth, device)
        index += 1


def _surface(plan: _SurfacePlan, faces: np.ndarray, rings: int, depth: int, device) -> tuple:
    """(the tile's submesh, the limit surface of the tile's ``faces`` with their halo)."""
    sub = Submesh(plan, faces, rings)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        surface = LimitSurface(sub.mesh, options=sub.options(plan.options), depth=depth, device=device)
    ring = plan.grow(faces, 1)
    if not np.array_equal(surface.holes[np.searchsorted(sub.faces, ring)], plan.holes[ring]):
        raise AssertionError("a tile's limit surface has other holes than the whole mesh's")
    return sub, surface


def _measure_edges(plan: _SurfacePlan, faces: np.ndarray, rings: int, depth: int, device,
                   lengths: np.ndarray) -> None:
    """The limit curve lengths of the edges of the tile's ``faces`` into ``lengths`` (the whole mesh's edges)."""
    sub, surface = _surface(plan, faces, rings, depth, device)
    corner_edge = np.asarray(sub.mesh.edges.corner_edge, dtype=np.int64)
    counts = np.asarray(sub.mesh.face_vertex_counts, dtype=np.int64)
    mine = np.zeros(len(sub.mesh.edges.edge_verts), dtype=bool)
    mine[corner_edge[np.repeat(sub.in_tile, counts)]] = True
    local = edge_curve_lengths(surface, edges=mine)
    lengths[sub.edge_map[mine]] = local[mine]


def _tessellate_tile(plan: _SurfacePlan, numbering: _Numbering, index: int, faces: np.ndarray, rings: int,
                     depth: int, device) -> Tile:
    """Tessellate one tile: the cells of its faces and of the ring around them emitted in the in-core order (the
    ring's cells find each shared vertex's first cell), the tile's faces and vertices kept."""
    sub, surface = _surface(plan, faces, rings, depth, device)
    ring = plan.grow(faces, 1)
    cells = numbering.cells_of(ring)
    in_tile = np.zeros(len(plan.counts), dtype=bool)
    in_tile[faces] = True
    own = in_tile[numbering.cells.face[cells]]
    group = numbering.groups.group[cells]
    emit_id, emit_cell, emit_uv, other_ids = [], [], [], []
    face_rows, face_ids = [], []
    for g in np.unique(group):
        sel = cells[group == g]  # in emission order
        pat = numbering.groups.patterns[g]
        rank = numbering.rank[sel]
        gid, uv, fg, _ = emit_cells(numbering.cells, sel, pat, numbering.lines,
                                    numbering.interior_start[g] + numbering.n_int[g] * rank)
        emit_id.append(gid.reshape(-1))
        emit_cell.append(np.repeat(sel, pat.num_local))
        emit_uv.append(uv.reshape(-1, 2))
        mine = own[group == g]
        other_ids.append(gid[~mine].reshape(-1))
        m = len(pat.faces)
        face_rows.append(fg[mine].reshape(-1, 4))
        face_ids.append((numbering.face_start[g] + m * rank[mine][:, None] + np.arange(m)).reshape(-1))
    ids = np.concatenate(emit_id)
    rows = np.concatenate(face_rows)
    valid = rows >= 0
    raw = np.unique(rows[valid])  # the tile's vertices, in the in-core order
    first_raw, first = np.unique(ids, return_index=True)
    at = first[np.searchsorted(first_raw, raw)]
    vcell = np.concatenate(emit_cell)[at]
    vuv = np.concatenate(emit_uv)[at]
    local_face = np.searchsorted(sub.faces, numbering.cells.face[vcell])
    ev = surface.evaluate(local_face, vuv[:, 0], vuv[:, 1])
    border = np.isin(raw, np.concatenate(other_ids))
    return Tile(index=index, control_faces=faces, points=ev.points, face_vertex_counts=valid.sum(1).astype(np.int32),
                face_vertex_indices=np.searchsorted(raw, rows[valid]).astype(np.int32),
                vertex_ids=numbering.vertex_ids(raw).astype(numbering.id_dtype),
                face_ids=np.concatenate(face_ids).astype(numbering.id_dtype), border=border,
                limit_normals=ev.normals)


def _tile_bytes(plan: _SurfacePlan, numbering: _Numbering, faces: np.ndarray, rings: int, depth: int) -> int:
    """The predicted peak of one tile: its surface (faces and halo), its tessellation (and its ring's cells,
    emitted too), and the previous tile held by the caller."""
    sub = plan.grow(faces, rings) if rings else faces
    corners = int(plan.counts[sub].sum())
    irregular = int(plan.counts[sub][plan.irregular[sub]].sum())
    vertices, out_faces = numbering.size_of(faces)
    ring_vertices, _ = numbering.size_of(plan.grow(faces, 1)) if rings else (vertices, 0)
    return (predict(corners, irregular, vertices, out_faces, depth) + RING_BYTES_PER_VERTEX * (ring_vertices - vertices)
            + 2 * (TILE_BYTES_PER_VERTEX * vertices + TILE_BYTES_PER_FACE * out_faces))


def _tile_faces(plan: _SurfacePlan, numbering: _Numbering, tile_faces, budget, rings,
                depth: int = DEFAULT_DEPTH) -> Iterator[np.ndarray]:
    """The control faces of every tile (sorted): runs of ``tile_faces`` faces along the Morton curve, or runs
    sized to ``budget``, halved until each one's prediction fits."""
    F = len(plan.counts)
    if tile_faces is not None:
        yield from plan.runs(tile_faces)
        return
    available = (budget - max(estimate.RUNTIME_BYTES, resident_bytes())
                 - GLOBAL_BYTES_PER_CORNER * int(plan.offsets[-1]))
    everything = np.arange(F, dtype=np.int64)
    whole = _tile_bytes(plan, numbering, everything, 0, depth)
    if whole <= available:
        yield everything
        return

    def too_big(faces):
        return SubdivInputError(
            f"tessellating one control face with its halo needs about "
            f"{estimate.format_bytes(_tile_bytes(plan, numbering, faces, rings, depth))} (with what the tiled "
            f"tessellation keeps), more than max_memory {estimate.format_bytes(budget)} allows; raise max_memory "
            "or lower the rate", option="max_memory", value=budget)

    yield from plan.fitted_runs(max(1, int(F * max(available, 0) / whole / 2)),
                                lambda f: _tile_bytes(plan, numbering, f, rings, depth) <= available, too_big)


def tessellation_fits(mesh: Mesh, *, rate=None, edge_length=None, quads: bool = True, max_memory=None,
                      depth: int = DEFAULT_DEPTH, options: Options | None = None, **option_keywords) -> tuple:
    """(whether the in-core tessellation's predicted peak fits ``max_memory`` (None: no limit), the prediction in
    bytes). With ``edge_length`` the output is sized with rates from the control polygon's edge lengths (the
    limit curves are not measured: that needs the surface); the in-core guard of 50M vertices counts as not
    fitting."""
    options = Options.given(options, option_keywords, caller="tessellation_fits")
    budget = estimate.memory_limit(max_memory)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonManifoldWarning)
        plan = _SurfacePlan(mesh, options, tiles=False)
    lite = SimpleNamespace(mesh=mesh)
    if edge_length is None:
        rates = segment_rates(lite, rate, None)
    else:
        ev = np.asarray(mesh.edges.edge_verts, dtype=np.int64)
        pts = np.asarray(mesh.points, dtype=np.float64)
        rates = segment_rates(lite, None, edge_length, lengths=np.linalg.norm(pts[ev[:, 1]] - pts[ev[:, 0]], axis=1))
    numbering = _Numbering(plan, *rates, quads)
    if numbering.groups is None:
        return True, 0
    F = len(plan.counts)
    need = _tile_bytes(plan, numbering, np.arange(F, dtype=np.int64), 0, depth)
    fits = (budget is None or need + max(estimate.RUNTIME_BYTES, resident_bytes()) <= budget) \
        and numbering.num_vertices <= MAX_VERTICES
    return fits, need
