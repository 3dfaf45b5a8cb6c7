"""The limit passes of a refiner on Warp arrays: limit positions and unit limit normals of the last level's data,
forward and backward (:class:`LimitPasses`, an :class:`~.passes.Adjoint`'s ``limits``).

Where the limit masks are read one level deeper (:meth:`Refiner.limit_source`), the passes run the deeper
refiner's last step first (and its adjoint last), as :meth:`Refiner.limit_points` and
:meth:`Refiner.limit_normals` do.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..evaluator import apply, limit_normals, limit_positions, normal_control_for
from .checks import check_data, check_positions
from .records import _kernels


class LimitPasses:
    """Limit positions and normals of one refiner's last level, forward and backward, on Warp arrays in the
    kernels' view (fresh arrays, as :class:`~.passes.Adjoint` returns them). ``adjoint``: the refiner's."""

    def __init__(self, adjoint):
        self.adjoint = adjoint

    def _at_source(self, x: wp.array, normal_control: bool):
        """(the refiner whose limit masks serve, whether they are read one level deeper, the points they read:
        ``x``, or ``x`` through that refiner's last step with ``normal_control``)."""
        source, deeper = self.adjoint.refiner.limit_source()
        return source, deeper, source.adjoint.last_step_forward(x, normal_control) if deeper else x

    def points_forward(self, x: wp.array, normal_control=None) -> wp.array:
        """Limit values of the last level's data ``x`` (kernel view). Where the masks are read one level deeper
        the extra step applies prescribed normals as :meth:`Refiner.limit_points` does: ``normal_control`` None
        on width 3 only, False never (data that is not a position), True to width 3 (refused on other widths)."""
        adj = self.adjoint
        check_data(adj, x)
        width = adj.width(x)
        normal_control = normal_control_for(normal_control, width)
        source, _, x = self._at_source(x, normal_control)
        sa = source.adjoint
        run = adj.launcher
        masks = source.evaluator.limit_masks()
        full = sa.empty(masks.num_vertices, width)
        limit_positions(masks, x, full, run)
        out = adj.empty(adj.refiner.num_vertices, width)
        wp.copy(out, full, count=adj.refiner.num_vertices)
        return out

    def points_backward(self, grad: wp.array, normal_control=None) -> wp.array:
        """The gradient with respect to the last level's data of a gradient of :meth:`points_forward` with
        the same ``normal_control``."""
        adj = self.adjoint
        check_data(adj, grad)
        width = adj.width(grad)
        normal_control = normal_control_for(normal_control, width)
        source, deeper = adj.refiner.limit_source()
        sa = source.adjoint
        rec = sa.tables.limit(adj.refiner.num_vertices)
        g = sa.empty(source.num_vertices, width)
        apply(rec.position, grad, g, adj.launcher)
        return sa.last_step_backward(g, normal_control) if deeper else g

    def _prescribed(self, normal_control: bool = True):
        """Ids (of this level's vertices) and vectors of the prescribed normals that replace computed limit normals
        of positions refined with ``normal_control`` (none where it is off, in the options or for these)."""
        adj = self.adjoint
        h = adj.hierarchy
        ids = np.asarray(h.normal_vertices, np.int64)
        if adj.refiner.options.normal_strength <= 0 or not normal_control:
            ids = ids[:0]
        return ids[ids < adj.refiner.num_vertices], h.normal_vectors

    def normals_forward(self, x: wp.array, normal_control=None) -> wp.array:
        """Unit limit normals of the last level's positions ``x`` (vec3), as :meth:`Refiner.limit_normals` with
        the same ``normal_control``: None or True substitute the prescribed normals (as given) and apply them in
        the extra step where the masks are read one level deeper; False (positions refined without normal
        control) does neither: computed normals everywhere."""
        adj = self.adjoint
        check_data(adj, x)
        check_positions(x)
        normal_control = normal_control_for(normal_control, 3)
        source, _, x = self._at_source(x, normal_control)
        sa = source.adjoint
        run = adj.launcher
        masks = source.evaluator.limit_masks()
        tu, tv = sa.empty(masks.num_tangents, 3), sa.empty(masks.num_tangents, 3)
        full = sa.empty(masks.num_vertices, 3)
        limit_normals(masks, x, tu, tv, full, run)
        h = sa.hierarchy
        if normal_control and len(h.normal_vertices) and adj.refiner.options.normal_strength > 0:
            ids = np.asarray(h.normal_vertices, np.int32)  # prescribed: as given
            values = np.asarray(h.normal_vectors, dtype=adj.scalar_np).reshape(-1, 3)
            wp.launch(_kernels().scatter_rows, dim=len(ids),
                      inputs=[wp.array(ids, device=adj.device), wp.array(values, dtype=adj.vec, device=adj.device),
                              full], device=adj.device)
        out = adj.empty(adj.refiner.num_vertices, 3)
        wp.copy(out, full, count=adj.refiner.num_vertices)
        return out

    def normals_backward(self, x: wp.array, grad: wp.array, normal_control=None) -> wp.array:
        """The gradient with respect to the last level's positions ``x`` of a gradient ``grad`` of the limit
        normals (vec3 arrays) of :meth:`normals_forward` with the same ``normal_control``; recomputes the
        tangents from ``x``."""
        adj = self.adjoint
        check_data(adj, x, grad)
        check_positions(x)
        check_positions(grad)
        normal_control = normal_control_for(normal_control, 3)
        source, deeper, xs = self._at_source(x, normal_control)
        sa = source.adjoint
        run = adj.launcher
        k = _kernels()
        N = adj.refiner.num_vertices
        masks = source.evaluator.limit_masks()
        rec = sa.tables.limit(N)
        T = rec.num_tangents
        tu, tv = sa.empty(masks.num_tangents, 3), sa.empty(masks.num_tangents, 3)
        apply(masks.tangent_u, xs, tu, run)
        apply(masks.tangent_v, xs, tv, run)
        g = grad
        ids, _ = self._prescribed(normal_control)
        if len(ids):  # prescribed normals are constants
            g = adj.empty(N, 3)
            wp.copy(g, grad)
            wp.launch(k.zero_rows, dim=len(ids), inputs=[wp.array(ids.astype(np.int32), device=adj.device),
                                                        adj.vec(), g], device=adj.device)
        guv = sa.empty(2 * T, 3)
        run.rows(k.vertex_normals_adjoint, N, [rec.vertex_offsets, tu, tv, g, adj.vec(), T, guv])
        gx = sa.empty(source.num_vertices, 3)
        apply(rec.tangents, guv, gx, run)
        return sa.last_step_backward(gx, normal_control) if deeper else gx
