"""The refinement hierarchy (numpy only, no Warp): the levels' topology and the per-step tables.

:class:`Hierarchy` is built once per (mesh, levels, options) by a short orchestrator of named phases, as
OpenSubdiv's ``Vtr::Refinement::refine`` is:

1. ``analyse``: the control mesh's topology, vertex classes and sectors (:func:`topology.base_level`);
2. ``guard``: the memory estimate of the whole refinement, checked before any refined level is allocated;
3. per step: ``step tables`` (the smooth rows as index tables, irregular rows as explicit stencils, from
   :mod:`warp_subdiv.tables`), ``refine topology`` (the child level by index arithmetic,
   :func:`topology.refine_level`), ``projections`` (flatness and normal-control displacement tables of the
   child level, :mod:`warp_subdiv.projections`).

What the evaluator needs per step is in :attr:`steps`, :attr:`flatness_tables` and :attr:`normal_tables`;
the last level's topology is :meth:`topology`; limit masks are built on demand by :meth:`limit_tables`.
"""
from __future__ import annotations

import numpy as np

from . import estimate, projections
from .mesh import Mesh
from .options import Options, Scheme
from .rules import edge_gamma_shift
from .tables import StencilTable, build_regular, build_stencils
from .topology import Level, base_level, refine_level, small_pages


class Hierarchy:
    """Levels 0..``levels`` of ``mesh`` refined with ``options``, as step tables and the last level's topology.

    ``max_memory``: bytes; the predicted peak of the refinement is checked against it after the control mesh
    is analysed and before any refined level is allocated (``None``: no limit). Requests whose last level
    would not fit 32-bit indices are refused whatever the limit.
    """

    def __init__(self, mesh: Mesh, levels: int, options: Options, *, max_memory: int | None = None):
        self.mesh = mesh
        self.levels = levels
        self.options = options
        estimate.check_indices([self._estimate(projecting=False)], levels)
        level = self._analyse()
        self._guard(max_memory)
        self.steps: list = []  # per step: RegularTables (uniform levels) or a full StencilTable
        self.flatness_tables: list = []
        self.normal_tables: list = []
        penultimate = level
        for step in range(levels):
            self.steps.append(self._step_tables(level))
            penultimate = level
            level = refine_level(level, faces_only=(step == levels - 1) and not self.projects)
            flat, norm = self._projections(level)
            self.flatness_tables.append(flat)
            self.normal_tables.append(norm)
        self.final: Level = level
        self.penultimate: Level = penultimate
        self.num_vertices = level.num_vertices

    # ------------------------------------------------------------------------------------------ phases
    def _analyse(self) -> Level:
        """Phase 1: the control mesh's topology, classes and sectors; what the later phases ask of it."""
        o = self.options
        mesh = self.mesh
        level = base_level(mesh, o.scheme, o.boundary, o.rules, o.triangulate,
                           flatness=o.flatness if o.piecewise_smooth else None,
                           crease_method=o.crease_method, linear=o.linear)
        self.base_num_vertices = level.num_vertices
        self.base_face_size = level.face_size
        self.normal_vertices = mesh.normal_vertices.astype(np.int64)
        self.normal_vectors = mesh.normal_vectors
        base_s = projections.resolve_flatness(level) if o.piecewise_smooth else np.zeros(level.num_sectors)
        if len(self.normal_vertices):
            projections.check_normal_vertices(level, self.normal_vertices)
        # extraordinary crease/corner sectors: their edge rules move weight (gamma(theta) != 3/8)
        shift = edge_gamma_shift(o.scheme, level.sector_theta)
        self.modified_edge_rules = o.piecewise_smooth and bool(
            np.any((level.sector_k() >= 2) & (np.abs(shift) > 1e-15)))
        self.projects = o.piecewise_smooth and (
            bool(np.any(base_s > 0)) or level.new_sector_flatness > 0 or len(self.normal_vertices) > 0)
        return level

    def _guard(self, max_memory: int | None) -> None:
        """Phase 2: refuse before any refined level is allocated when the predicted peak is above the limit."""
        estimate.check_memory([self._estimate(projecting=self.projects)], max_memory, self.levels)

    def _step_tables(self, level: Level):
        """Phase 3a: the tables of one step over ``level``: index tables on uniform levels, else stencils."""
        o = self.options
        if level.face_size == (4 if o.scheme == Scheme.CATMULL_CLARK else 3):
            return build_regular(level, o.rules, o.loop_beta)
        return build_stencils(level, o.rules, o.loop_beta, smooth_triangles=o.smooth_triangles)

    def _projections(self, level: Level):
        """Phase 3c: flatness and normal-control displacement tables of a refined ``level`` (or None)."""
        if not self.projects:
            return None, None
        s = projections.resolve_flatness(level)
        flat = projections.flatness_table(level, s)
        norm = None
        if len(self.normal_vertices) and self.options.normal_strength > 0:
            norm = projections.normal_table(level, self.normal_vertices, self.normal_vectors,
                                            self.options.normal_strength, s, self.options.loop_beta)
        return flat, norm

    def _estimate(self, projecting: bool):
        mesh, o = self.mesh, self.options
        return estimate.estimate("mesh", mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, self.levels,
                                 o.scheme, precision=o.precision, projecting=projecting)

    # ------------------------------------------------------------------------------------------ queries
    def limit_reads_deeper(self, levels: int | None = None) -> bool:
        """Whether limit points and normals of ``levels`` (default: this hierarchy's) read their masks one level
        deeper, because the masks of that level are not exact.

        Flatness and normal control move the ring points of their sectors on every level, and the crease- and
        corner-neighbour edge rules differ from the smooth rule next to extraordinary crease and corner
        vertices, so the standard masks of a vertex next to such a vertex are exact only one level later, once
        its neighbourhood follows the standard rules; a control mesh with non-quads has no Catmull-Clark masks.
        """
        levels = self.levels if levels is None else levels
        polygons = levels == 0 and self.options.scheme == Scheme.CATMULL_CLARK and self.base_face_size != 4
        return polygons or self.projects or self.modified_edge_rules

    def topology(self):
        """(face_vertex_counts, face_vertex_indices) of the last level, int32, hole faces left out."""
        lvl = self.final
        if lvl.face_size and not lvl.face_hole.any():  # no holes: the corner table is the face list (a view)
            view = lvl.corner_vert.view()
            view.flags.writeable = False
            with small_pages():
                return np.full(lvl.num_faces, lvl.face_size, dtype=np.int32), view
        sizes = lvl.face_sizes()
        keep = ~lvl.face_hole
        if lvl.face_size:
            idx = lvl.corner_vert.reshape(-1, lvl.face_size)[keep].reshape(-1)
        else:
            idx = lvl.corner_vert[np.repeat(keep, sizes)]
        return sizes[keep].astype(np.int32), np.ascontiguousarray(idx, dtype=np.int32)

    def full_stencils(self) -> list[StencilTable]:
        """Full stencil tables of every step (rows over the previous level), rebuilt from the control mesh."""
        o = self.options
        level = base_level(self.mesh, o.scheme, o.boundary, o.rules, o.triangulate,
                           flatness=o.flatness if o.piecewise_smooth else None,
                           crease_method=o.crease_method, linear=o.linear)
        tables = []
        for _ in range(self.levels):
            tables.append(build_stencils(level, o.rules, o.loop_beta, smooth_triangles=o.smooth_triangles))
            level = refine_level(level)
        return tables

    def limit_tables(self) -> projections.LimitTables:
        """Limit position and tangent masks of the last level's vertices (docs/rules.md sections 8 and 9)."""
        level = self.final
        if level.edge_verts is None:  # built faces-only: derive the full last level now
            level = refine_level(self.penultimate)
        o = self.options
        if level.face_size == 0 or (o.scheme == Scheme.CATMULL_CLARK and level.face_size != 4):
            raise NotImplementedError("limit masks need a level of quads (Catmull-Clark) or triangles")
        s = projections.resolve_flatness(level) if o.piecewise_smooth else np.zeros(level.num_sectors)
        return projections.limit_tables(level, s, o.loop_beta, o.rules)
