"""GeomSubsets of a refined mesh: face subsets (material bindings) get their ``indices`` remapped to the
refined faces, edge subsets to the child edges of their edges (:class:`EdgeMap`). A tessellated mesh's subsets
are remapped by the same code, from its own face map and :class:`ControlEdgeMap`.
"""
from __future__ import annotations

import numpy as np
from pxr import Sdf

from ..io.usd_stage import DEFAULT
from ..io.usd_write import int_array
from ..refiner import Refiner
from .primvars import default_or_sample

T = Sdf.ValueTypeNames


class ControlEdgeMap:
    """The edges of a mesh made from a control mesh (refined, or tessellated) that lie on the control mesh's
    edges, for edge subsets: ``pairs`` (k, 2), the edges of the made mesh as (low, high) vertex pairs, once
    each; ``edge_of_pair`` (k,), the edge of ``base_edges`` (the control mesh's edges, or those of the faces it
    is refined as: a Loop mesh's triangulation adds edges inside polygons) each lies on, or -1."""

    def __init__(self, mesh, base_edges, pairs, edge_of_pair):
        self.mesh, self.base_edges = mesh, base_edges
        self.pairs, self.edge_of_pair = pairs, edge_of_pair

    def children(self, pairs) -> tuple:
        """(made edges (k, 2) on the control edges ``pairs`` (m, 2), index of the first pair that is not an
        edge of the control mesh or None)."""
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        nv = self.mesh.num_vertices
        bad = np.flatnonzero((pairs < 0).any(axis=1) | (pairs >= nv).any(axis=1))
        if len(bad):
            return None, int(bad[0])
        own = self.mesh.edges.find(pairs, nv)  # the control polygons' edges (not a triangulation's)
        bad = np.flatnonzero(own < 0)
        if len(bad):
            return None, int(bad[0])
        chosen = np.zeros(len(self.base_edges.edge_verts), dtype=bool)
        chosen[self.base_edges.find(pairs, nv)] = True
        on = self.edge_of_pair >= 0
        keep = np.zeros(len(self.pairs), dtype=bool)
        keep[on] = chosen[self.edge_of_pair[on]]
        return self.pairs[keep], None


class EdgeMap(ControlEdgeMap):
    """The edges of the refined mesh (``refiner.topology()``: ``indices``, ``counts``) that lie on each edge of
    the control mesh, from the refiner's parentage (:meth:`Hierarchy.vertex_parent`,
    :meth:`Hierarchy.edge_parent`): a refined vertex lies inside a level-0 edge when it is the edge child of
    an edge that lies on it (or the vertex child of such a vertex), and a refined edge lies on the level-0
    edge that holds both its ends (or one end and the other at that edge's control vertex)."""

    def __init__(self, mesh, refiner: Refiner, indices, counts):
        from ..mesh import face_offsets_of, next_corner_of
        from ..topology import EDGE, VERTEX, base_faces

        options = refiner.options
        base = base_faces(mesh, options.scheme.value, options.boundary.value)
        base_edges = base.edges  # level 0 (a Loop mesh's triangulation adds edges inside polygons)
        ends = base_edges.edge_verts.astype(np.int64)
        nv = mesh.num_vertices
        ctrl = np.arange(nv, dtype=np.int64)  # the control vertex a vertex is the child of, or -1
        inside = np.full(nv, -1, dtype=np.int64)  # the level-0 edge a vertex lies inside, or -1
        edge_on = np.arange(len(ends), dtype=np.int64)  # the level-0 edge an edge lies on, or -1
        h = refiner.hierarchy
        for level in range(1, refiner.levels + 1):
            kind, parent = h.vertex_parent(level)
            is_v, is_e = kind == VERTEX, kind == EDGE
            ctrl_next = np.full(len(kind), -1, dtype=np.int64)
            ctrl_next[is_v] = ctrl[parent[is_v]]
            inside_next = np.full(len(kind), -1, dtype=np.int64)
            inside_next[is_v] = inside[parent[is_v]]
            inside_next[is_e] = edge_on[parent[is_e]]
            ctrl, inside = ctrl_next, inside_next
            if level < refiner.levels:
                ekind, eparent, _ = h.edge_parent(level)
                on = ekind == EDGE
                edge_on_next = np.full(len(ekind), -1, dtype=np.int64)
                edge_on_next[on] = edge_on[eparent[on]]
                edge_on = edge_on_next
        # the refined edges, once each, as (low, high) vertex pairs
        counts = np.asarray(counts, dtype=np.int64)
        a = np.asarray(indices, dtype=np.int64)
        b = a[next_corner_of(counts, face_offsets_of(counts))]
        pairs = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1), axis=0)
        u, w = pairs[:, 0], pairs[:, 1]
        cu, cw = ctrl[u], ctrl[w]
        eu, ew = inside[u], inside[w]

        def at_end(e, v):  # whether control vertex v is an end of level-0 edge e (e >= 0)
            safe = np.maximum(e, 0)
            return (e >= 0) & (v >= 0) & ((ends[safe, 0] == v) | (ends[safe, 1] == v))

        edge = np.full(len(pairs), -1, dtype=np.int64)
        both = (eu >= 0) & (eu == ew)
        edge[both] = eu[both]
        one = (eu >= 0) & (ew < 0) & at_end(eu, cw)
        edge[one] = eu[one]
        other = (ew >= 0) & (eu < 0) & at_end(ew, cu)
        edge[other] = ew[other]
        corners = (cu >= 0) & (cw >= 0)  # level 0 only: the control edge itself
        edge[corners] = base_edges.find(np.stack([cu[corners], cw[corners]], axis=1), nv)
        super().__init__(mesh, base_edges, pairs, edge)


def write_subsets(sp, target, layer, refinement, warnings, times_of, dropped: set) -> None:
    """Remap every subset of ``sp`` not in ``dropped`` at its written times (``times_of(subset.times)``) with
    ``refinement`` (a :class:`~warp_subdiv.usd.refinement.MeshRefinement`), under ``target``, the mesh's path in
    the output layer. A subset whose indices do not fit is dropped (blocked, named in ``warnings``) and added
    to ``dropped``, where it stays for the mesh's other topologies."""
    for subset in sp.subsets:
        if subset.path in dropped:
            continue
        if not write_subset(sp, target, subset, layer, refinement.fmap, warnings,
                            refinement if subset.element == "edge" else None, times_of(subset.times)):
            dropped.add(subset.path)


def write_subset(sp, target, subset, layer, fmap, warnings, refinement=None, times=None) -> bool:
    """Remap the indices of a face or edge subset at ``times`` (default: the default time and its samples),
    written under ``target`` (the mesh's path in the output layer); False (the subset blocked, with a warning)
    when they do not fit. ``refinement``: the mesh's refinement, whose :class:`ControlEdgeMap` (``edges``, built on
    first use) edge subsets take."""
    prim = layer.prim(target + subset.path[len(sp.path):])
    spec = layer.attr(prim, "indices", T.IntArray)
    n = sp.mesh.num_faces
    for t in ([DEFAULT] + list(subset.times)) if times is None else times:
        value = subset.attr.Get(t)
        if value is None and t == DEFAULT and subset.times:
            value = subset.attr.Get(subset.times[0])  # no default: the first selected sample stands in
        if value is None:
            continue
        ids = np.asarray(value, dtype=np.int64)
        if subset.element == "edge":
            refined, bad = refinement.edges.children(ids) if len(ids) % 2 == 0 else (None, None)
            if refined is None:
                layer.block(prim, "indices", T.IntArray)
                why = (f"edge {bad} ({ids[2 * bad]}, {ids[2 * bad + 1]}) is not an edge of the mesh" if bad is not None
                       else f"has {len(ids)} indices, not pairs of points")
                warnings.append(f"{subset.path}: {why}; the subset is dropped")
                return False
            layer.set(spec, *default_or_sample(t, int_array(refined.reshape(-1))))
            continue
        bad = np.flatnonzero((ids < 0) | (ids >= n))
        if len(bad):
            layer.block(prim, "indices", T.IntArray)
            warnings.append(f"{subset.path}: indices[{bad[0]}] = {ids[bad[0]]} is not a face of the mesh; the subset "
                            "is dropped")
            return False
        member = np.zeros(n, dtype=bool)
        member[ids] = True
        layer.set(spec, *default_or_sample(t, int_array(np.flatnonzero(member[fmap.parent]))))
    return True
