"""Small meshes of a bake evaluated together (:class:`Batches`): one evaluation of the disjoint union of meshes
that share their options, levels and time samples per written time (:class:`warp_subdiv.batch.MeshBatch`),
instead of one per mesh. The layer written is the same either way (values bitwise, the same specs).
"""
from __future__ import annotations

import numpy as np
from pxr import Usd

from ..batch import MeshBatch, batch_key
from ..errors import SubdivInputError
from ..io.usd_read import SubdivPrim
from ..io.usd_stage import DEFAULT
from ..runtime import phases as _phases

#: Prims whose refined vertex count (the plan's prediction) is at most this are batched with others of the same
#: options, levels and time samples (:class:`Batches`). A small prim's evaluation costs less than the fixed
#: costs of its own evaluator (the first call's buffers and recorded launches, limit masks, tens of microseconds
#: per later call), which a batch pays once for all its members; measured over 25 samples of 20 equal props at
#: level 2 (CPU), the batch is 14x faster per member at 98 refined vertices, 2.3x at 1,538, 1.4x at 3,458 and
#: slower from about 6,000 on (its gathers and larger buffers).
BATCH_VERTICES = 4096
#: The same bound where only points are written (no limit points or normals): a small prim's own evaluation is
#: then only its recorded launches, and the batch's extra costs (the union's build, reading the points for it)
#: outweigh what it saves sooner. Measured end to end (bench/bench_batch.py, quiet machine): 200 props of 1,538
#: refined vertices x 24 samples baked 0.88x as fast batched (points only) and 1.15x as fast with normals;
#: 1,000 cubes of 98 refined vertices 1.42x and 1.45x.
BATCH_VERTICES_POINTS = 1024
#: The most refined rows x written samples one batch holds at once (its results, kept until each member is
#: written): about 24 MiB of float32 points (and as much again for normals or limit points).
BATCH_ROWS = 1 << 21


class Batches:
    """The USD writer's batching of small meshes (:mod:`warp_subdiv.batch`): which prims are evaluated together,
    and their results, prepared before the first of them is written.

    A prim is a candidate when its refinement is small (:data:`BATCH_VERTICES`; :data:`BATCH_VERTICES_POINTS`
    where neither limit points nor normals are written), its topology does not change
    over time, it is not bilinear, its options have no per-vertex flatness and no ``shipped`` hierarchy (a
    distributed task's) fits it. Candidates with equal options and selected time samples
    form chunks in the plan's order, each of at most :data:`BATCH_ROWS` refined rows x samples. When the first
    prim of a chunk is written, :meth:`prepare` builds every member's refiner (``refiner(i, sp)``: the one the
    bake would build for it), groups the members by :func:`warp_subdiv.batch.batch_key` (those whose union
    refines them bitwise as they refine alone), and evaluates each group of two or more as one
    :class:`MeshBatch` at every written time (the default unless ``defaults`` is False, then each selected
    sample): points, and limit points and normals where asked.
    Each member's refinement then takes its refiner and results (:meth:`take`) instead of building and
    evaluating its own; a result is found by the control points it was computed from, so a time whose points
    the writer reads differently (or not at all) is evaluated as without batching. Any input error while
    preparing leaves the chunk (or that sample) to the unbatched path, which reports it as it would."""

    def __init__(self, p, device, limit, normals, *, refiner, defaults: bool = True, shipped=()):
        self.levels, self.device, self.limit, self.normals = p.levels, device, limit, normals
        self.refiner = refiner  # (prim index, prim) -> the prim's refiner, as the bake builds it
        self.defaults = defaults  # whether default values are written (not with samples_only)
        self.prims, self.options = p.prims, p.options
        small = BATCH_VERTICES if (limit or normals) else BATCH_VERTICES_POINTS
        self.chunk_of: dict = {}  # prim index -> its chunk (a list of prim indices)
        self.ready: dict = {}  # prim index -> (refiner, {control points bytes: (points, normals)})
        open_chunks: dict = {}  # key -> (chunk, rows x samples so far)
        for i, (sp, options, e) in enumerate(zip(p.prims, p.options, p.estimates)):
            rows = e.final.vertices
            if (sp.topologies or sp.scheme == "bilinear" or rows > small
                    or isinstance(options.flatness, np.ndarray) or any(h.fits(sp.mesh, options) for h in shipped)):
                continue
            key = (options, p.levels[i], tuple(sp.point_times))
            cost = rows * (len(sp.point_times) + 1)
            chunk, held = open_chunks.get(key, (None, 0))
            if chunk is None or held + cost > BATCH_ROWS:
                chunk, held = [], 0
            chunk.append(i)
            open_chunks[key] = (chunk, held + cost)
            self.chunk_of[i] = chunk

    def prepare(self, i: int) -> None:
        """Evaluate the chunk of prim ``i`` when ``i`` is its first member (and the chunk has two or more)."""
        chunk = self.chunk_of.pop(i, None)
        if chunk is None or chunk[0] != i or len(chunk) < 2:
            return
        for j in chunk[1:]:
            self.chunk_of.pop(j, None)
        try:
            with _phases.phase("analyse"):
                refiners = [self.refiner(j, self.prims[j]) for j in chunk]
        except SubdivInputError:
            return  # the unbatched path reports it, prim by prim
        groups: dict = {}
        for j, refiner in zip(chunk, refiners):
            groups.setdefault(batch_key(refiner), []).append((j, refiner))
        for members in groups.values():
            for j, refiner in members:
                self.ready[j] = (refiner, {})
            if len(members) >= 2:
                self._evaluate(members)

    def _evaluate(self, members) -> None:
        """Every time sample of one group of members as one union (see the class docstring)."""
        sps = [self.prims[j] for j, _ in members]
        with _phases.phase("analyse"):
            first = members[0][0]
            batch = MeshBatch([sp.mesh for sp in sps], self.levels[first], options=self.options[first],
                              device=self.device, check=False)
        with_limits = self.limit or self.normals
        queries = [Usd.AttributeQuery(sp.prim.GetAttribute("points")) for sp in sps]
        for t in ([DEFAULT] if self.defaults else []) + list(sps[0].point_times):
            data, read = [], []
            for sp, query in zip(sps, queries):
                pts = _read_points(sp, query, t)
                read.append(pts is not None)  # else left to the unbatched path; the control points fill its rows
                data.append(sp.mesh.points if pts is None else pts)
            try:
                with _phases.phase("refine"):
                    if with_limits:
                        res = batch.evaluate_with_limits(data, limit_points=self.limit, limit_normals=self.normals)
                        out = [(r.limit_points if self.limit else r.points, r.limit_normals) for r in res]
                    else:
                        out = [(r, None) for r in batch.evaluate(data)]
            except SubdivInputError:
                continue  # (data beyond the precision's bound) each member evaluates this time alone
            for (j, _), pts, ok, (pos, nrm) in zip(members, data, read, out):
                if ok:
                    self.ready[j][1][points_key(pts)] = (pos, nrm)

    def take(self, i: int):
        """(refiner, results by control points) prepared for prim ``i``, or None; each prim takes its own once."""
        return self.ready.pop(i, None)


def _read_points(sp: SubdivPrim, query, t):
    """The control points of ``sp`` at ``t`` as :meth:`SubdivPrim.points_at` reads them (float64 (n, 3)), read
    through an attribute query and without its checks (the batch's evaluation checks finite values and their
    bound); None where they do not fit the mesh or points_at would refuse them. Results are found by these
    points' bytes (:func:`points_key`), so points read otherwise are merely not found. A skinned mesh's points
    (:class:`~warp_subdiv.usd.skinning.SkinnedPrim`) are its own ``points_at``'s: its pose, not the attribute."""
    try:
        if t == DEFAULT or getattr(sp, "skin", None) is not None:
            return sp.points_at(t)
        value = query.Get(t)
    except SubdivInputError:
        return None
    if value is None:
        return None
    pts = np.asarray(value, dtype=np.float64)
    return pts if pts.shape == (sp.mesh.num_vertices, 3) else None


def points_key(pts) -> tuple:
    """What identifies control points exactly (their shape, type and bytes): the key of a prepared result."""
    pts = np.ascontiguousarray(pts)
    return pts.shape, pts.dtype.str, pts.tobytes()
