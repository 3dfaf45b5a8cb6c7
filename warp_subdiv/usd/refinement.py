"""The refinement of one control mesh as the USD writer uses it (:class:`MeshRefinement`): the refiner (in the
vertex order written), the refined topology, the face map, and the evaluation of points, face-varying
channels and vectors, from results computed ahead or in a batch where there are any.
"""
from __future__ import annotations

import numpy as np

from ..errors import SubdivInputError
from ..io.usd_read import SubdivPrim
from ..io.usd_stage import DEFAULT
from ..options import Options
from ..refiner import Refiner
from ..runtime import phases as _phases
from ..tables import FaceMap, corners_to_vertices, vertices_used
from .batching import points_key
from .order import OrderedRefiner, resolved_vertex_order
from .primvars import face_varying_input
from .subsets import EdgeMap


def linear_vertex_data(refiner: Refiner, fmap: FaceMap, values, indices, complete: bool | None = None) -> np.ndarray:
    """Per-vertex ``values`` of the control mesh refined linearly inside each control face (bilinear meshes,
    varying primvars): the refined vertices of ``refiner`` (whose ``topology()`` indices are ``indices``)
    that no face uses (holes) get the refiner's values. ``complete``: whether every vertex is used (computed
    when None)."""
    mesh = refiner.mesh
    corners = fmap.refine_corners(np.asarray(values, dtype=np.float64)[mesh.face_vertex_indices])
    if complete is None:
        complete = vertices_used(indices, refiner.num_vertices)
    fill = None if complete else refiner.evaluate(values)
    return corners_to_vertices(corners, indices, refiner.num_vertices, fill)


class MeshRefinement:
    """The refiner of one control mesh of a prim (its only one, or one of a time-varying topology) and what the
    writer derives from it: refined topology, face map, linear refinement and edge map.

    ``refiner``: the control mesh's refiner, which the compact ``vertex_order`` wraps
    (:class:`~warp_subdiv.usd.order.OrderedRefiner`); ``prepared``: its results evaluated with a batch of small
    meshes (:class:`~warp_subdiv.usd.batching.Batches`), by control points, or None."""

    def __init__(self, sp: SubdivPrim, refiner: Refiner, options: Options, levels, limit, normals,
                 vertex_order="opensubdiv", prepared: dict | None = None):
        self.sp = sp
        self._prepared = prepared  # results by control points
        if resolved_vertex_order(vertex_order, options) == "compact":
            refiner = OrderedRefiner(refiner)  # the same results, numbered to compress well
        self.refiner = refiner
        self.counts, self.indices = refiner.topology()
        self.fmap = FaceMap(sp.mesh, levels, sp.scheme, options.boundary.value, hierarchy=refiner.hierarchy)
        self.fmap.check(self.counts)
        self._complete = None  # whether every refined vertex is used (linear_field), found on first use
        self.limit, self.normals = limit, normals
        self._edges = None
        self._ahead: dict = {}  # results a worker computed ahead of the writer (Ahead), by their inputs

    def run_ahead(self, fvar_mode, *, defaults: bool, budget: int) -> None:
        """Compute ahead (on a worker thread, :class:`~warp_subdiv.usd.ahead.Ahead`) what the writer will ask of
        this refinement: the positions at the default time (``defaults``) and every selected time sample, and
        the channel of every face-varying primvar (``fvar_mode`` None: none) at those times, defaults first,
        until the results hold ``budget`` bytes. Each result is kept under its inputs and handed out once when
        the writer asks with the same inputs (:meth:`positions`, :meth:`face_varying`); an input that cannot be
        read or refined is left to the writer, which reports it where it belongs."""
        sp = self.sp
        channels = [pv for pv in sp.primvars if pv.interpolation == "faceVarying"] if fvar_mode is not None else []
        first = [DEFAULT] if defaults else []
        jobs = [(t, None) for t in first] + [(t, pv) for pv in channels for t in first]
        jobs += [(t, None) for t in sp.point_times] + [(t, pv) for pv in channels for t in pv.times]
        held = 0
        for t, pv in jobs:
            if held > budget:
                return
            try:
                if pv is None:
                    pts = sp.points_at(t)
                    result = self.positions(pts)
                    key = ("points", points_key(pts))
                else:
                    rows, idx = face_varying_input(sp, pv, t)
                    result = self.face_varying(rows, idx, fvar_mode)
                    key = ("face-varying", fvar_mode, points_key(rows), points_key(idx))
            except SubdivInputError:
                continue
            self._ahead[key] = result
            held += sum(np.asarray(r).nbytes for r in result if r is not None)

    def linear_field(self, values):
        """Bilinear refinement of per-vertex data (varying primvars, bilinear meshes)."""
        if self._complete is None:
            self._complete = vertices_used(self.indices, self.refiner.num_vertices)
        return linear_vertex_data(self.refiner, self.fmap, values, self.indices, self._complete)

    @_phases.timed("refine")
    def positions(self, pts):
        """Refined (or limit) points and limit normals (or None) of control points ``pts``."""
        sp, refiner = self.sp, self.refiner
        if self._ahead:
            found = self._ahead.pop(("points", points_key(pts)), None)
            if found is not None:
                return found
        if sp.scheme == "bilinear":
            return self.linear_field(pts), None
        if self._prepared:  # evaluated with a batch of small meshes (Batches), in the refiner's order
            found = self._prepared.get(points_key(pts))
            if found is not None:
                pos, nrm = found
                if isinstance(refiner, OrderedRefiner):
                    pos = refiner.compact(pos)
                    nrm = None if nrm is None else refiner.compact(nrm)
                if nrm is not None and sp.orientation == "leftHanded":
                    nrm = -nrm
                return pos, nrm
        if not (self.limit or self.normals):
            return refiner.evaluate(pts), None
        # points, limit points and normals in one pass from the last level's buffer (no round trip)
        res = refiner.evaluate_with_limits(pts, limit_points=self.limit, limit_normals=self.normals)
        nrm = res.limit_normals
        if nrm is not None and sp.orientation == "leftHanded":
            nrm = -nrm  # refined as right-handed: the front of a left-handed mesh is the other side
        return (res.limit_points if self.limit else res.points), nrm

    @_phases.timed("face-varying")
    def face_varying(self, rows, idx, mode):
        """(values, indices) of a face-varying primvar's refined channel (limit values with ``limit``)."""
        if self._ahead:
            found = self._ahead.pop(("face-varying", mode, points_key(rows), points_key(idx)), None)
            if found is not None:
                return found
        channel = self.refiner.limit_face_varying if self.limit else self.refiner.evaluate_face_varying
        return channel(rows, idx, mode=mode)

    @_phases.timed("refine")
    def vectors(self, data):
        """Velocities / accelerations: the derivatives of the points, so the same linear maps."""
        if self.sp.scheme == "bilinear":
            return self.linear_field(data)
        refined = self.refiner.evaluate(data)
        return self.refiner.limit_points(refined) if self.limit else refined

    @property
    @_phases.timed("analyse")
    def edges(self):
        """The :class:`~warp_subdiv.usd.subsets.EdgeMap` of the refined mesh (built on first use)."""
        if self._edges is None:
            self._edges = EdgeMap(self.sp.mesh, self.refiner, self.indices, self.counts)
        return self._edges
