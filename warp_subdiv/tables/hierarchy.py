"""The refinement hierarchy (numpy only, no Warp): the levels' topology and the per-step tables.

:class:`Hierarchy` is built once per (mesh, levels, options) by a short orchestrator of named phases, as
OpenSubdiv's ``Vtr::Refinement::refine`` is:

1. ``analyse``: the control mesh's topology, vertex classes and sectors (:func:`topology.base_level`);
2. ``guard``: the memory estimate of the whole refinement, checked before any refined level is allocated;
3. per step: ``step tables`` (the smooth rows as index tables, irregular rows as explicit stencils, from
   :mod:`warp_subdiv.tables`), ``refine topology`` (the child level by index arithmetic,
   :func:`topology.refine_level`, and the step's parentage rules, :class:`topology.Refinement`),
   ``projections`` (flatness and normal-control displacement tables of the child level,
   :mod:`warp_subdiv.tables.projections`).

What the evaluator needs per step is in :attr:`steps`, :attr:`flatness_tables` and :attr:`normal_tables`;
the last level's topology is :meth:`topology`; limit masks are built on demand by :meth:`limit_tables`.

Parentage
---------
The hierarchy also records where every element of every level comes from (:class:`Parentage`, one
:class:`~warp_subdiv.topology.Refinement` per step), as OpenSubdiv's ``Vtr::Refinement`` records
``_childFaceParentIndex``, ``_childEdgeParentIndex``, ``_childVertexParentIndex`` and its child tags. Level 0 is
the analysed control mesh; under Loop a polygon mesh is fan-triangulated first (triangle t of level 0 comes
from control face :attr:`Parentage.control_face` ``[t]``, corners (v0, v_i, v_i+1)). Step k refines level
k - 1 into level k; ``level`` arguments name the child level (1..levels). With V, F, E, C the parent level's
vertices, faces, edges and corners:

* child vertices are [V vertex children | F face children (Catmull-Clark only) | E edge children]:
  :meth:`Hierarchy.vertex_parent` gives (kind, index), kind ``topology.VERTEX``, ``FACE`` or ``EDGE``;
* child faces: Catmull-Clark makes one per parent corner (child face h belongs to parent corner h; on a level
  of quads child c has parent face c // 4 and corner c % 4), Loop four per triangle (child 4f + s: s < 3 at
  corner s, s = 3 the middle one). :meth:`Hierarchy.face_parent` gives (face, slot);
* child corners: the child face of parent corner j holds, in cyclic order, the child of j's vertex, the child
  of edge j (from corner j to j + 1), the face child (Catmull-Clark only) and the child of edge j - 1,
  starting at position r (:meth:`Hierarchy.face_rotation`): Catmull-Clark rotates the children of quads
  (r = j) and not those of other polygons (r = 0), as OpenSubdiv does; Loop's corner children have r = j,
  and its middle child holds the child of edge m + 1 at position m (r = 0);
* child edges are [C edges inside parent faces, one per parent corner | 2E halves]: edge h < C lies in the
  face of parent corner h (Catmull-Clark: face child to the child of edge h; Loop: children of edges h and
  h - 1), edge C + 2e + s is the half of edge e at its end s. :meth:`Hierarchy.edge_parent` gives (kind,
  index, slot).

Compositions: :meth:`Hierarchy.base_face_of` (the level-0 face of every face of a level) and
:meth:`Hierarchy.control_face_of` (the control mesh face). Only rules are kept (counts, and the face offsets
of a level 0 of mixed polygons, the triangulation's parents and level 0's holes, all of control size);
arrays of a refined level's size are materialised when asked for and not kept.
"""
from __future__ import annotations

import numpy as np

from ..runtime import estimate
from . import projections
from ..mesh import Mesh
from ..options import Options, Scheme
from ..rules import edge_gamma_shift
from .stencil_builder import build_regular, build_stencils
from .stencil_table import StencilTable
from ..runtime.threads import run as run_jobs
from ..runtime.pages import small_pages
from ..topology import Level, Refinement, base_faces, base_level, refine_level


class Hierarchy:
    """Levels 0..``levels`` of ``mesh`` refined with ``options``, as step tables and the last level's topology.

    ``max_memory``: bytes; the predicted peak of the refinement is checked against it after the control mesh
    is analysed and before any refined level is allocated (``None``: no limit). Requests whose last level
    would not fit 32-bit indices are refused whatever the limit. ``threads``: CPU threads the build may use
    (the tables do not depend on it); ``concurrent_build``: build each step's tables and the next level on two
    of them at once (faster, but more peak memory than the memory guard predicts).

    ``reuse``: a hierarchy built before (the tables a distributed bake ships to the tasks that refine a mesh's
    frames, or the level-0 analysis a USD bake's plan made), taken where it :meth:`fits` the mesh and options:
    with the same levels this hierarchy takes its tables as they are; with other levels it is built from the
    control points ``reuse`` was built from, and from its analysis of the control mesh when ``reuse`` has level
    0 only. A task that reads the mesh at its own frames may see other control points than those the tables
    were built from (sector angles are measured on the control points): the reused tables are what keeps its
    result equal to the single-process bake's. A hierarchy that does not fit is ignored.
    """

    def __init__(self, mesh: Mesh, levels: int, options: Options, *, max_memory: int | None = None,
                 threads: int = 1, concurrent_build: bool = False, reuse: Hierarchy | None = None):
        source = reuse if reuse is not None and reuse.fits(mesh, options) else None
        analysed = None
        if source is not None:
            if source.levels == levels:  # the same mesh, levels and options: take its tables as they are
                self.__dict__.update(source.__dict__)
                return
            mesh = source.mesh  # another level count: build, from the control points it was built from
            analysed = source  # and from its analysis of the control mesh (level 0 is never modified)
        self.threads = max(1, int(threads))
        # Overlapping a step's tables with the next level's topology saved about 10% of a build on 2 cores
        # (cube64 level 4: 1.16 -> 1.05 s) but raised its peak memory by 8-25% (bench/bench_memory.py), beyond
        # the memory guard's model (warp_subdiv.runtime.estimate): off unless asked for.
        self.concurrent_build = bool(concurrent_build)
        self.mesh = mesh
        self.levels = levels
        self.options = options
        estimate.check_index_range([self._estimate(projecting=False)], levels)
        level = self._analyse(analysed)
        self._guard(max_memory)
        self.steps: list = []  # per step: RegularTables (uniform levels) or a full StencilTable
        self.flatness_tables: list = []
        self.normal_tables: list = []
        self.parentage = Parentage([], level.face_hole, level.control_face)
        penultimate = level
        for step in range(levels):
            faces_only = (step == levels - 1) and not self.projects
            # the step's tables and the next level both read only this level: with threads they are built at
            # once (numpy releases the GIL inside large array operations and page faults; the results do not
            # depend on it)
            tables, child = run_jobs([lambda lv=level: self._step_tables(lv),
                                      lambda lv=level, fo=faces_only: refine_level(lv, faces_only=fo,
                                                                                   threads=self.threads)],
                                     min(self.threads, 2) if self.concurrent_build else 1)
            self.steps.append(tables)
            self.parentage.steps.append(Refinement.of_level(level))
            penultimate = level
            level = child
            flat, norm = self._projections(level)
            self.flatness_tables.append(flat)
            self.normal_tables.append(norm)
        self.final: Level = level
        self.penultimate: Level = penultimate
        self.num_vertices = level.num_vertices

    def fits(self, mesh: Mesh, options: Options) -> bool:
        """Whether this hierarchy can stand in for one of ``mesh`` with ``options`` (see ``reuse``): the same
        options, and a control mesh with the same faces and tags (its points may differ)."""
        return self.options == options and same_topology(self.mesh, mesh)

    # ------------------------------------------------------------------------------------------ phases
    def _analyse(self, source: Hierarchy | None = None) -> Level:
        """Phase 1: the control mesh's topology, classes and sectors; what the later phases ask of it.
        ``source``: a hierarchy of the same control mesh and options whose analysed level 0 is taken as it is
        (a level-0 hierarchy keeps it as :attr:`final`; others do not keep it)."""
        o = self.options
        mesh = self.mesh
        if source is not None and source.levels == 0:
            level = source.final
        else:
            level = base_level(mesh, o.scheme, o.boundary, o.rules, o.triangulate,
                               flatness=o.flatness if o.piecewise_smooth else None,
                               crease_method=o.crease_method, linear=o.linear)
        self.base_num_vertices = level.num_vertices
        self.base_face_size = level.face_size
        self.base_vert_class = level.vert_class  # (V,) int8: the control vertices' rules (warp_subdiv.usd.order)
        # the analysed control mesh, kept for the face-varying channels (its edges, fans and sharpness are those
        # of their value meshes' analysis: warp_subdiv.tables.facevarying)
        self.control_level = level
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
            bool(np.any(base_s > 0)) or len(self.normal_vertices) > 0)
        return level

    def _guard(self, max_memory: int | None) -> None:
        """Phase 2: refuse before any refined level is allocated when the predicted peak is above the limit."""
        estimate.check_memory([self._estimate(projecting=self.projects)], max_memory, self.levels)

    def _step_tables(self, level: Level):
        """Phase 3a: the tables of one step over ``level``: index tables on uniform levels, else stencils."""
        o = self.options
        if level.face_size == (4 if o.scheme == Scheme.CATMULL_CLARK else 3):
            return build_regular(level, o.rules, o.loop_beta, threads=self.threads)
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

    # ------------------------------------------------------------------------------------------ parentage
    def refinement(self, level: int) -> Refinement:
        """The rules of the step that made ``level`` (1..levels) from level - 1."""
        return self.parentage.refinement(level)

    def vertex_parent(self, level: int):
        """(kind int8, index int64) of every vertex of ``level``: the vertex, edge or face of level - 1 it comes
        from (kinds ``topology.VERTEX``, ``EDGE``, ``FACE``)."""
        return self.parentage.vertex_parent(level)

    def edge_parent(self, level: int):
        """(kind int8, index int64, slot int64) of every edge of ``level``: the face (and its corner) it lies
        in, or the edge (and which end's half) it is part of."""
        return self.parentage.edge_parent(level)

    def face_parent(self, level: int):
        """(face, slot) int64 of every face of ``level``: its parent face and which child it is (the corner,
        or Loop's middle child, slot 3)."""
        return self.parentage.face_parent(level)

    def face_rotation(self, level: int):
        """(faces,) int64: the position in each face of ``level`` of its parent corner's vertex child."""
        return self.parentage.face_rotation(level)

    def base_face_of(self, level: int):
        """(faces,) int64: the level-0 face (Loop: triangle of the fan triangulation) of every face of ``level``."""
        return self.parentage.base_face_of(level)

    def control_face_of(self, level: int):
        """(faces,) int64: the control mesh face every face of ``level`` lies in (hole faces included)."""
        return self.parentage.control_face_of(level)

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
            level = refine_level(self.penultimate, threads=self.threads)
        o = self.options
        if level.face_size == 0 or (o.scheme == Scheme.CATMULL_CLARK and level.face_size != 4):
            raise NotImplementedError("limit masks need a level of quads (Catmull-Clark) or triangles")
        s = projections.resolve_flatness(level) if o.piecewise_smooth else np.zeros(level.num_sectors)
        return projections.limit_tables(level, s, o.loop_beta, o.rules)


# ------------------------------------------------------------------------------------------------ reuse
_TOPOLOGY_FIELDS = ("face_vertex_counts", "face_vertex_indices", "creases", "crease_sharpness", "corners",
                    "corner_sharpness", "concave", "normal_vertices", "normal_vectors", "holes")


def same_topology(a: Mesh, b: Mesh) -> bool:
    """Whether two control meshes have the same faces and tags (their points may differ)."""
    if a is b:
        return True
    if a.num_vertices != b.num_vertices:
        return False
    for name in _TOPOLOGY_FIELDS:
        x, y = getattr(a, name, None), getattr(b, name, None)
        if (x is None) != (y is None) or (x is not None and not np.array_equal(x, y)):
            return False
    return True


class Parentage:
    """Where the elements of every level come from: one :class:`~warp_subdiv.topology.Refinement` per step
    (rules, no refined-size arrays), plus what level 0 adds: ``control_face`` (the control polygon of each
    triangle of a fan-triangulated mesh, or None) and ``base_face_hole`` (holes of level 0, with the faces
    boundary "none" leaves out). See the module docstring for the conventions.
    """

    def __init__(self, steps: list, base_face_hole: np.ndarray, control_face: np.ndarray | None = None):
        self.steps: list = list(steps)
        self.base_face_hole = base_face_hole
        self.control_face = control_face

    @classmethod
    def of_mesh(cls, mesh: Mesh, levels: int, scheme: str, boundary: str = "edge-and-corner") -> "Parentage":
        """The parentage of ``levels`` steps of ``scheme`` over ``mesh`` without analysing it (no fans, classes
        or sectors): level 0's faces from :func:`topology.base_faces`, each later step by the closed-form rule."""
        faces = base_faces(mesh, scheme, boundary)
        steps = [Refinement.of_faces(scheme, mesh.num_vertices, faces)] if levels > 0 else []
        while len(steps) < levels:
            steps.append(steps[-1].next())
        return cls(steps, faces.face_hole, faces.control_face)

    @property
    def levels(self) -> int:
        return len(self.steps)

    def refinement(self, level: int) -> Refinement:
        """The step that made ``level`` (1..levels)."""
        if not 1 <= level <= len(self.steps):
            raise ValueError(f"level must be in 1..{len(self.steps)} (the refined levels), got {level}")
        return self.steps[level - 1]

    def num_faces(self, level: int) -> int:
        """Faces of ``level`` (0..levels), hole faces included."""
        return len(self.base_face_hole) if level == 0 else self.refinement(level).child_faces

    def vertex_parent(self, level: int):
        return self.refinement(level).vertex_parent()

    def edge_parent(self, level: int):
        return self.refinement(level).edge_parent()

    def face_parent(self, level: int):
        return self.refinement(level).face_parent()

    def face_rotation(self, level: int):
        return self.refinement(level).face_rotation()

    def base_face_of(self, level: int) -> np.ndarray:
        """(faces of ``level``,) int64: the level-0 face each one descends from. Runs of steps whose parent is
        a fixed number of children per face compose into one integer division."""
        faces = np.arange(self.num_faces(level), dtype=np.int64)
        divisor = 1
        for step in reversed(self.steps[:level]):
            if step.children_per_face:
                divisor *= step.children_per_face
                continue
            faces = step.parent_face_of(faces // divisor)
            divisor = 1
        return faces // divisor if divisor > 1 else faces

    def to_control(self, base_faces_: np.ndarray) -> np.ndarray:
        """The control mesh face of level-0 faces (the identity unless Loop fan-triangulated polygons)."""
        return base_faces_ if self.control_face is None else np.asarray(self.control_face, np.int64)[base_faces_]

    def control_face_of(self, level: int) -> np.ndarray:
        """(faces of ``level``,) int64: the control mesh face each one lies in."""
        return self.to_control(self.base_face_of(level))
