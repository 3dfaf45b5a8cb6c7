"""The device records of a hierarchy's tables, and their upload.

:func:`upload` turns the hierarchy's tables into device records once per evaluator: per step a
:class:`StepRecord` holding a :class:`QuadStep` or :class:`TriangleStep` (smooth rows by index arithmetic,
irregular rows as :class:`ExplicitRows`) or a :class:`StencilStep` (every row an explicit stencil), and the step's
:class:`Displacement` (flatness) and :class:`Projection` (normal control) when it has them; :func:`upload_limit`
makes the :class:`LimitMasks`. An :class:`Uploader` makes the device arrays (on the CPU sharing the host tables'
memory); the gradients upload their transposed tables with it too.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..tables import RegularTables

#: Per evaluation precision: (numpy scalar, Warp scalar, Warp vec3).
PRECISIONS = {"float32": (np.float32, wp.float32, wp.vec3f), "float64": (np.float64, wp.float64, wp.vec3d)}

#: Quad steps of at least this many rows get expanded tables from a CPU refiner's third evaluation on (with
#: ``Evaluator.expand_tables`` None): smaller steps evaluate about as fast from the compact ones, so building
#: expanded tables for them is pure cost (``bench/bench_expand.py``, later evaluations: no faster at 208,000 rows,
#: 0-20% faster at 832,000, 25-30% at 3.3 million).
EXPAND_MIN_ROWS = 1 << 19


@dataclass(frozen=True)
class ExplicitRows:
    """Rows of a uniform step that the index kernels leave out: dst[rows[i]] = CSR row i over the source."""

    rows: wp.array
    offsets: wp.array
    indices: wp.array
    weights: wp.array
    count: int


@dataclass(frozen=True)
class QuadStep:
    """One Catmull-Clark step over a level of quads: face, smooth edge and smooth vertex points from index
    tables, then the explicit rows. Child layout [V vertex points, F face points, E edge points]."""

    num_vertices: int
    num_faces: int
    num_edges: int
    num_rows: int
    corner_vert: wp.array
    edge_neighbours: wp.array  # (E, 2) int32: the edge's two corners
    ring_offsets: wp.array
    ring: wp.array  # each vertex's corners
    vertex_regular: wp.array  # empty: every row regular
    edge_regular: wp.array
    ring_weights: wp.array  # (max valence + 1, 2)
    edge_weights: wp.array  # (2,)
    quarter: wp.array  # (1,): the face-point weight in the evaluation precision
    explicit: ExplicitRows
    # expanded tables (the CPU's choice, see kernels.regular): (E, 4) endpoints and faces, ring vertices, faces
    edge_ends: wp.array | None = None
    ring_vertices: wp.array | None = None
    ring_faces: wp.array | None = None


@dataclass(frozen=True)
class TriangleStep:
    """One Loop step over a level of triangles: smooth edge and vertex points from index tables, then the
    explicit rows. Child layout [V vertex points, E edge points]."""

    num_vertices: int
    num_edges: int
    num_rows: int
    edge_neighbours: wp.array  # (E, 4) int32: a, b, opposite 0, opposite 1
    ring_offsets: wp.array
    ring: wp.array
    vertex_regular: wp.array
    edge_regular: wp.array
    ring_weights: wp.array
    edge_weights: wp.array
    explicit: ExplicitRows


@dataclass(frozen=True)
class StencilStep:
    """Rows that are all explicit stencils: dst[i] = CSR row i over the source (non-uniform steps, limit
    masks)."""

    offsets: wp.array
    indices: wp.array
    weights: wp.array
    num_rows: int


@dataclass(frozen=True)
class Displacement:
    """Flatness: out[targets[i]] = p[targets[i]] + sum_j w_j p[indices[j]] (data of any width)."""

    targets: wp.array
    offsets: wp.array
    indices: wp.array
    weights: wp.array
    count: int


@dataclass(frozen=True)
class Projection:
    """Normal control: out[targets[i]] = p[targets[i]] + sum_j w_j n_j (n_j . p[indices[j]]) (positions)."""

    targets: wp.array
    offsets: wp.array
    indices: wp.array
    weights: wp.array
    normal_ids: wp.array
    normals: wp.array  # vec3 of the evaluation precision
    count: int


@dataclass(frozen=True)
class StepRecord:
    """Everything one refinement step does: the child rows, then flatness, then normal control."""

    rows: QuadStep | TriangleStep | StencilStep
    flatness: Displacement | None
    normals: Projection | None

    @property
    def num_rows(self) -> int:
        return self.rows.num_rows

    @property
    def num_moved(self) -> int:
        """Rows of the scratch buffer the step's displacements need."""
        return max([0] + [d.count for d in (self.flatness, self.normals) if d is not None])


@dataclass(frozen=True)
class LimitMasks:
    """Limit position masks (one row per vertex) and tangent masks (one row per (vertex, sector))."""

    position: StencilStep
    tangent_u: StencilStep
    tangent_v: StencilStep
    vertex_offsets: wp.array  # (V+1,): the tangent pairs of each vertex
    num_vertices: int
    num_tangents: int
    host_vertex_offsets: np.ndarray | None = None  # the same offsets on the host (for :meth:`first`)

    def first(self, rows: int) -> "LimitMasks":
        """The masks of vertices 0..rows only (views: the rows of a deeper level's vertex children, which come
        first; each row is computed by the same code as in the full masks)."""
        if rows >= self.num_vertices:
            return self
        tangents = int(self.host_vertex_offsets[rows])

        def cut(step: StencilStep, n: int) -> StencilStep:
            return StencilStep(step.offsets[: n + 1], step.indices, step.weights, n)

        return LimitMasks(cut(self.position, rows), cut(self.tangent_u, tangents), cut(self.tangent_v, tangents),
                          self.vertex_offsets[: rows + 1], rows, tangents, self.host_vertex_offsets[: rows + 1])


class Uploader:
    """Device arrays of host tables on ``device`` (the evaluator's records, the gradients' transposed tables); on
    the CPU they share the numpy arrays' memory instead of copying them (the device array holds the numpy one).
    ``expand``, ``min_rows``: quad steps of at least ``min_rows`` rows get expanded tables (None: on the CPU)."""

    def __init__(self, device, precision: str, expand: bool | None = None, min_rows: int = 0):
        self.device = wp.get_device(device)
        self.scalar, _, self.vec = PRECISIONS[precision]
        self.expand = self.device.is_cpu if expand is None else bool(expand)
        self.min_rows = int(min_rows)  # quad steps of fewer rows keep their compact tables

    def __call__(self, values, dtype=None):
        host = np.ascontiguousarray(values, dtype=self.scalar if dtype is None else dtype)
        if self.device.is_cpu:
            return wp.array(host, device=self.device, copy=False)
        return wp.array(host, device=self.device)

    def csr(self, t):
        i32 = np.int32
        return self(t.offsets, i32), self(t.indices, i32), self(t.weights)

    def stencil(self, t) -> StencilStep:
        return StencilStep(*self.csr(t), num_rows=t.num_rows)

    def explicit(self, t) -> ExplicitRows:
        rows = np.zeros(0, np.int32) if t.rows is None else t.rows
        return ExplicitRows(self(rows, np.int32), *self.csr(t), count=t.num_rows)

    def regular(self, t: RegularTables):
        i32, u8 = np.int32, np.uint8
        common = dict(num_vertices=t.num_vertices, num_edges=len(t.edge_neighbours), num_rows=t.num_rows,
                      edge_neighbours=self(t.edge_neighbours, i32), ring_offsets=self(t.vert_corner_offsets, i32),
                      ring=self(t.ring, i32), vertex_regular=self(t.vertex_regular, u8),
                      edge_regular=self(t.edge_regular, u8), ring_weights=self(t.ring_weights),
                      edge_weights=self(t.edge_weights), explicit=self.explicit(t.explicit))
        if t.face_size == 4:
            return QuadStep(num_faces=t.num_faces, corner_vert=self(t.corner_vert, i32), quarter=self([0.25]),
                            **common, **(self.expanded(t) if self.expand and t.num_rows >= self.min_rows else {}))
        return TriangleStep(**common)

    def expanded(self, t: RegularTables) -> dict:
        """The expanded tables of a quad step (the lookups of index arithmetic done once): per edge its
        endpoints and faces, per vertex its ring vertices and faces."""
        cv = np.asarray(t.corner_vert)
        h0, h1 = t.edge_neighbours[:, 0], t.edge_neighbours[:, 1]  # int32 arithmetic: corners fit int32
        ends = np.empty((len(h0), 4), dtype=np.int32)
        ends[:, 0], ends[:, 1] = cv[h0], cv[(h0 & ~3) | ((h0 + 1) & 3)]
        ends[:, 2], ends[:, 3] = h0 >> 2, h1 >> 2
        ring = np.asarray(t.ring)
        return dict(edge_ends=self(ends, np.int32), ring_vertices=self(cv[(ring & ~3) | ((ring + 1) & 3)], np.int32),
                    ring_faces=self(ring >> 2, np.int32))

    def displacement(self, t) -> Displacement | None:
        if t is None:
            return None
        return Displacement(self(t.targets, np.int32), *self.csr(t), count=t.num_rows)

    def projection(self, t) -> Projection | None:
        if t is None:
            return None
        normals = wp.array(np.ascontiguousarray(t.normals, dtype=self.scalar), dtype=self.vec, device=self.device)
        offsets, indices, weights = self.csr(t)
        return Projection(self(t.targets, np.int32), offsets, indices, weights, self(t.normal_ids, np.int32),
                          normals, count=t.num_rows)


def upload(hierarchy, device, precision: str, expand: bool | None = None, min_rows: int = 0) -> list[StepRecord]:
    """The device records of every step of ``hierarchy`` (index tables, explicit stencils, displacements);
    ``expand``: quad steps of at least ``min_rows`` rows also get their expanded tables (None: on the CPU, see
    :mod:`warp_subdiv.kernels.regular`)."""
    up = Uploader(device, precision, expand, min_rows)
    records = []
    for t, flat, norm in zip(hierarchy.steps, hierarchy.flatness_tables, hierarchy.normal_tables):
        rows = up.regular(t) if isinstance(t, RegularTables) else up.stencil(t)
        records.append(StepRecord(rows, up.displacement(flat), up.projection(norm)))
    return records


def upload_limit(tables, device, precision: str) -> LimitMasks:
    """The device records of a :class:`~warp_subdiv.tables.projections.LimitTables`."""
    up = Uploader(device, precision)
    return LimitMasks(up.stencil(tables.position), up.stencil(tables.tangent_u), up.stencil(tables.tangent_v),
                      up(tables.vertex_offsets, np.int32), num_vertices=tables.position.num_rows,
                      num_tangents=tables.tangent_u.num_rows,
                      host_vertex_offsets=np.asarray(tables.vertex_offsets))


class StepRecords:
    """The step records of ``hierarchy`` on ``device``, uploaded on first use, and which quad tables they hold.

    ``expand`` (the evaluator's ``expand_tables``): quad steps read expanded tables (True), the compact ones
    (False), or (None) the compact ones first and, on the CPU, from the third evaluation on the expanded ones
    for quad steps of :data:`EXPAND_MIN_ROWS` rows or more: they make an evaluation of a large step up to a
    third faster (none of a small one) but cost two or three evaluations' gain to build, which a refiner
    evaluated once or twice (a mesh and its UVs baked at one time) never gets back. On CUDA the compact ones
    (half the bytes, see :mod:`warp_subdiv.kernels.regular`)."""

    def __init__(self, hierarchy, device, precision: str):
        self.hierarchy, self.device, self.precision = hierarchy, wp.get_device(device), precision
        self.records: list[StepRecord] | None = None
        self.expanded = False  # whether the records hold expanded quad tables
        self.evaluations = 0

    def get(self, expand: bool | None) -> list[StepRecord]:
        """The records (uploaded on the first call, with expanded quad tables where ``expand`` is True)."""
        if self.records is None:
            self.expanded = bool(expand)
            self.records = upload(self.hierarchy, self.device, self.precision, self.expanded)
        return self.records

    def count_evaluation(self, expand: bool | None) -> bool:
        """Note one evaluation; True where the quad steps' records were just uploaded again with expanded
        tables (before the third evaluation: the launches recorded over the old ones are stale)."""
        self.evaluations += 1
        if (self.evaluations == 3 and expand is None and self.device.is_cpu and not self.expanded
                and self.records is not None
                and any(isinstance(t, RegularTables) and t.face_size == 4 and t.num_rows >= EXPAND_MIN_ROWS
                        for t in self.hierarchy.steps)):
            self.expanded = True
            self.records = upload(self.hierarchy, self.device, self.precision, True, EXPAND_MIN_ROWS)
            return True
        return False
