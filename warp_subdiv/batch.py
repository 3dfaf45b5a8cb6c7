"""Many small meshes refined as one: the disjoint union of their control meshes, one refiner, one launch per step.

Refining a tiny mesh (a cube, a prop of a few hundred faces) costs little arithmetic and a fixed overhead per
call (the evaluator's recorded launches, the host-side checks and copies: tens of microseconds). A scene of
thousands of such meshes, each evaluated at every time sample, pays that overhead per mesh and sample.
:class:`MeshBatch` pays it once per sample for all of them: it refines the disjoint union of the members'
control meshes (:func:`union_mesh`: vertices, faces and every tag of member ``i`` offset by the members before
it) with one :class:`~warp_subdiv.refiner.Refiner`, and splits each result into the members' rows.

Where each member's rows are
-------------------------------
A refinement step numbers the child vertices [vertex children | face children (Catmull-Clark) | edge
children], each block in the order of its parents; child faces follow their parent faces (and so their parent
corners), child edges are [one per parent corner | two halves per parent edge] (see
:mod:`warp_subdiv.tables.hierarchy`). The union's level 0 lists the members one after the other in every element kind
(vertices and faces by construction; edges, which :func:`~warp_subdiv.mesh.find_edges` numbers in the order of
the corners that make them, and a Loop fan triangulation likewise), and every step keeps each member's elements
in its own relative order inside each block. So the member of every element of every level follows from the
members of the level above by concatenation and repetition (numpy, a few arrays per level, no per-element
loop), and a stable sort of the last level's vertex members gives, for every member, the union rows of its
refined vertices in its own vertex order (:meth:`MeshBatch.rows`). A member's rows are not one range in general
(from level 2 on its edges lie in two blocks), so a split is a gather.

Bitwise equality
----------------
Every refined row is a weighted sum over its own member's rows, with the weights computed from the member's
own neighbourhood, so a member's rows of the union equal, bitwise, what refining the member alone gives,
provided the evaluator refines both with the same kind of record on every step and the same limit masks.
Three properties of a refiner decide that, and :func:`batch_key` lists them (members of one batch must share
it; :class:`MeshBatch` checks):

* the options and the level count;
* whether level 0 is uniform (Catmull-Clark: all quads; Loop: always, after its fan triangulation): a uniform
  level is refined by index tables, a mixed one by explicit stencils, which sum in another order; after step
  one every level is uniform;
* whether flatness or normal control act (:attr:`Refiner.projects`: the last level keeps its full topology and
  displacement tables apply on every level) and whether limit masks are read one level deeper
  (:meth:`Refiner.limit_reads_deeper`).

``tests/test_batch.py`` checks the equality on quads, triangles, n-gons, creases, corners, holes, boundaries,
prescribed normals, both schemes and both rule sets, for points, limit points and limit normals.
"""
from __future__ import annotations

import numbers

import numpy as np

from .errors import SubdivInputError
from .mesh import Mesh
from .options import Options, Scheme
from .refiner import Refiner
from .topology import base_faces


def union_mesh(meshes) -> tuple:
    """(the disjoint union of ``meshes`` as one :class:`~warp_subdiv.mesh.Mesh`, vertex offsets (M + 1,),
    face offsets (M + 1,)), int64 offsets: member ``i``'s vertices are ``offsets[i]:offsets[i + 1]`` of the
    union, its faces likewise. Creases, corners, concave tags and prescribed normals (vertex ids) and holes
    (face ids) are offset with their member; sharpness values and normals are copied."""
    meshes = list(meshes)
    if not meshes:
        raise SubdivInputError("a batch needs at least one mesh", option="meshes")
    for i, m in enumerate(meshes):
        if not isinstance(m, Mesh):
            raise SubdivInputError(f"batch member {i} must be a warp_subdiv.Mesh, got {type(m).__name__}",
                                   option="meshes", index=i)
    nv = np.array([m.num_vertices for m in meshes], dtype=np.int64)
    nf = np.array([m.num_faces for m in meshes], dtype=np.int64)
    voff = np.concatenate([[0], np.cumsum(nv)])
    foff = np.concatenate([[0], np.cumsum(nf)])

    def cat(name, offsets=None, shape_tail=()):
        """Member arrays ``name`` concatenated, each plus its member's offset (ids) or as they are."""
        parts = [np.asarray(getattr(m, name)) for m in meshes]
        if offsets is not None:
            parts = [p.astype(np.int64) + offsets[i] for i, p in enumerate(parts)]
        if not any(len(p) for p in parts):
            return np.zeros((0,) + shape_tail, dtype=np.int64 if offsets is not None else np.float64)
        return np.concatenate([p.reshape((-1,) + shape_tail) for p in parts])

    normal_ids = cat("normal_vertices", voff)
    union = Mesh(
        cat("points", shape_tail=(3,)),
        cat("face_vertex_counts"),
        cat("face_vertex_indices", voff),
        creases=cat("creases", voff, (2,)),
        crease_sharpness=cat("crease_sharpness"),
        corners=cat("corners", voff),
        corner_sharpness=cat("corner_sharpness"),
        concave=cat("concave", voff, (2,)),
        normals=(normal_ids, cat("normal_vectors", shape_tail=(3,))) if len(normal_ids) else None,
        holes=cat("holes", foff),
    )
    return union, voff, foff


def batch_key(refiner: Refiner, levels: int | None = None) -> tuple:
    """What members of one batch must share for the union's rows to equal each member's own refinement
    bitwise (see the module docstring): (options, levels, uniform level 0, projects, limit masks one level
    deeper). ``refiner``: the member's own refiner, or any refiner of its control mesh and options (a level-0
    one is analysis only) with ``levels`` the batch's level count (default: the refiner's)."""
    h = refiner.hierarchy
    levels = refiner.levels if levels is None else int(levels)
    uniform = h.base_face_size == (4 if refiner.options.scheme == Scheme.CATMULL_CLARK else 3)
    return (refiner.options, levels, bool(uniform), bool(h.projects), bool(h.limit_reads_deeper(levels)))


class MeshBatch:
    """Several control meshes with the same options and level count, refined as one (see the module docstring).

    ``meshes``: a sequence of :class:`~warp_subdiv.mesh.Mesh`; ``levels``, ``options`` (or option keywords),
    ``device``, ``max_memory`` and ``threads`` as :class:`~warp_subdiv.refiner.Refiner` takes them (a
    per-vertex ``flatness`` belongs to one mesh and is refused). ``check``: compare the members'
    :func:`batch_key` (each member analysed at level 0, then refused with :class:`SubdivInputError` where they
    differ); pass False where the caller has grouped them by key already (the USD writer does).

    :attr:`refiner` is the union's refiner; :meth:`evaluate` and :meth:`evaluate_with_limits` take one array
    per member and return one per member, equal bitwise to each member's own refiner's.
    """

    def __init__(self, meshes, levels: int, *, options: Options | None = None, device=None,
                 max_memory: int | None = None, threads: int | None = None, check: bool = True, **option_keywords):
        meshes = list(meshes)
        options = Options.given(options, option_keywords, caller=type(self).__name__)
        if isinstance(options.flatness, np.ndarray):
            raise SubdivInputError("a per-vertex flatness belongs to one mesh; a batch takes None or one number",
                                   option="flatness")
        if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 0:
            raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels", value=levels)
        union, self.vertex_offsets, self.face_offsets = union_mesh(meshes)
        if check and len(meshes) > 1:
            keys = [batch_key(Refiner(m, 0, options=options, device="cpu"), levels) for m in meshes]
            bad = next((i for i, k in enumerate(keys) if k != keys[0]), None)
            if bad is not None:
                raise SubdivInputError(
                    f"batch member {bad} does not refine like member 0 in a union (uniform level 0, projections, "
                    f"limit masks: {keys[bad][2:]} against {keys[0][2:]}); batch them apart", option="meshes",
                    index=bad)
        self.meshes = meshes
        self.levels = int(levels)
        self.options = options
        self.refiner = Refiner(union, levels, options=options, device=device, max_memory=max_memory,
                               threads=threads)
        self._index_rows(union)

    # ------------------------------------------------------------------------------------------ rows
    def _index_rows(self, union: Mesh) -> None:
        """Every member's refined rows (:meth:`rows`) and last-level faces: the member of every face, corner,
        edge and vertex, level by level (the module docstring's rule)."""
        M = len(self.meshes)
        cc = self.options.scheme == Scheme.CATMULL_CLARK
        faces = base_faces(union, self.options.scheme.value, self.options.boundary.value,
                           self.options.triangulate)
        members = np.arange(M, dtype=np.int32)
        # the member of every face, corner, edge and vertex of the current level
        face_label = np.repeat(members, np.diff(self.face_offsets))
        if faces.control_face is not None:
            face_label = face_label[faces.control_face]
        corner_label = np.repeat(face_label, faces.counts)
        label = np.repeat(members, np.diff(self.vertex_offsets))
        edge_label = label[faces.edges.edge_verts[:, 0]]
        for _ in range(self.levels):
            label = np.concatenate([label] + ([face_label] if cc else []) + [edge_label])
            edge_label = np.concatenate([corner_label, np.repeat(edge_label, 2)])
            face_label = corner_label if cc else np.repeat(face_label, 4)
            corner_label = np.repeat(face_label, 4 if cc else 3)
        F = np.bincount(face_label, minlength=M).astype(np.int64)
        if len(label) != self.refiner.num_vertices or int(F.sum()) != self.refiner.hierarchy.final.num_faces:
            raise RuntimeError("batch: the union's refined counts do not follow the members' (a bug)")
        order = np.argsort(label, kind="stable")  # member by member, each in its own order
        self._order = order
        self._row_offsets = np.concatenate([[0], np.cumsum(np.bincount(label, minlength=M))])
        self._face_offsets_last = np.concatenate([[0], np.cumsum(F)])
        self._contiguous = bool(np.all(order == np.arange(len(order))))
        self._starts = self._local = None  # made by the first topology() call

    def member(self, i) -> int:
        """Member index ``i`` as a Python sequence takes it (negative counts from the end) as 0..M-1: every
        member-indexed method reads it so. Out of range: ``IndexError``; not an integer: ``TypeError`` (slicing the
        offsets with either would give another member's rows or none, without a word)."""
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, numbers.Integral):
            raise TypeError(f"a batch member index must be an integer, got {i!r}")
        count = len(self.meshes)
        if not -count <= i < count:
            raise IndexError(f"batch member {i} is out of range: the batch has {count} members")
        return int(i) % count

    def rows(self, i: int) -> np.ndarray:
        """(refined vertices of member ``i``,) int64: the union's refined rows of member ``i``'s refined
        vertices, in the order of the member's own refiner. ``i`` as :meth:`member` takes it (-1: the last)."""
        i = self.member(i)
        return self._order[self._row_offsets[i]:self._row_offsets[i + 1]]

    def num_vertices(self, i: int) -> int:
        """Refined vertices of member ``i`` (as :meth:`member` takes it)."""
        i = self.member(i)
        return int(self._row_offsets[i + 1] - self._row_offsets[i])

    def split(self, refined) -> list:
        """Rows (N, ...) of the union's last level as one array per member (copies, in each member's order)."""
        refined = np.asarray(refined)
        if len(refined) != len(self._order):
            raise SubdivInputError(f"split takes the union's {len(self._order)} refined rows, got {len(refined)}",
                                   element="data", value=len(refined))
        gathered = refined.copy() if self._contiguous else refined[self._order]
        return np.split(gathered, self._row_offsets[1:-1])

    def member_arrays(self, data) -> list:
        """One array per member from ``data``, any iterable (read once, so a generator counts right), checked:
        one per member, each with its own mesh's vertex count of rows and all of one width (columns; (n,) is one)."""
        arrays = [np.asarray(d) for d in data]
        if len(arrays) != len(self.meshes):
            raise SubdivInputError(f"a batch of {len(self.meshes)} meshes takes {len(self.meshes)} arrays, got "
                                   f"{len(arrays)}", element="data")
        widths = []
        for i, a in enumerate(arrays):
            n = self.meshes[i].num_vertices
            if a.shape[:1] != (n,):
                raise SubdivInputError(f"batch member {i} has {n} vertices, its data has shape {a.shape}",
                                       element="data", index=i, value=a.shape)
            widths.append(int(np.prod(a.shape[1:], dtype=np.int64)))
            if widths[i] != widths[0]:
                raise SubdivInputError(f"batch member {i} has data of width {widths[i]}, member 0 of width "
                                       f"{widths[0]}: every member's data needs the same columns", element="data",
                                       index=i, value=widths[i])
        return arrays

    def stack(self, data) -> np.ndarray:
        """One control-data array per member (:meth:`member_arrays`) stacked into the union's control rows
        ((n, d))."""
        return np.concatenate([a.reshape(len(a), -1) if a.ndim != 2 else a for a in self.member_arrays(data)])

    # ------------------------------------------------------------------------------------------ evaluation
    def evaluate(self, data, normal_control=None) -> list:
        """Refined data of every member: ``data`` one (n_i, d) array per member (n_i its control vertices);
        returns one (N_i, d) array per member, as each member's ``Refiner.evaluate`` gives it (1-D data of
        every member gives 1-D results)."""
        data = self.member_arrays(data)
        one_d = all(d.ndim == 1 for d in data)
        out = self.split(self.refiner.evaluate(self.stack(data), normal_control=normal_control))
        return [o[:, 0] for o in out] if one_d else out

    def evaluate_with_limits(self, points, *, normal_control=None, limit_points: bool = True,
                             limit_normals: bool = True) -> list:
        """:meth:`Refiner.evaluate_with_limits` of every member in one pass: one
        :class:`~warp_subdiv.evaluator.Evaluated` per member (numpy ``points``, ``limit_points``,
        ``limit_normals``; None where not asked for)."""
        from .evaluator import Evaluated

        res = self.refiner.evaluate_with_limits(self.stack(points), normal_control=normal_control,
                                                limit_points=limit_points, limit_normals=limit_normals)
        parts = [self.split(getattr(res, name)) if getattr(res, name) is not None else [None] * len(self.meshes)
                 for name in ("points", "limit_points", "limit_normals")]
        return [Evaluated(p, lp, ln) for p, lp, ln in zip(*parts)]

    # ------------------------------------------------------------------------------------------ topology
    def topology(self, i: int) -> tuple:
        """(face_vertex_counts, face_vertex_indices) int32 of member ``i``'s refined mesh in its own vertex
        numbering, hole faces left out: what the member's own ``Refiner.topology()`` gives. ``i`` as
        :meth:`member` takes it."""
        i = self.member(i)
        lvl = self.refiner.hierarchy.final
        lo, hi = int(self._face_offsets_last[i]), int(self._face_offsets_last[i + 1])
        if self._starts is None:  # once for all members: face starts, and every union row's member-local id
            self._starts = np.concatenate([[0], np.cumsum(lvl.face_sizes())])
            self._local = np.empty(len(self._order), dtype=np.int64)
            self._local[self._order] = (np.arange(len(self._order), dtype=np.int64)
                                        - np.repeat(self._row_offsets[:-1], np.diff(self._row_offsets)))
        starts = self._starts
        keep = ~np.asarray(lvl.face_hole[lo:hi], dtype=bool)
        corners = np.asarray(lvl.corner_vert[starts[lo]:starts[hi]], dtype=np.int64)
        counts = np.diff(starts[lo:hi + 1])
        idx = self._local[corners][np.repeat(keep, counts)]
        return counts[keep].astype(np.int32), idx.astype(np.int32)


__all__ = ["MeshBatch", "union_mesh", "batch_key"]
