"""The patch tree of a :class:`~warp_subdiv.limit.LimitSurface` on a Warp device, and the launches of the
evaluation kernel (:mod:`warp_subdiv.kernels.limit`) over it: points and derivatives of the surface, or columns of
data carried through the same tree, three at a time.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from .parameterisation import DIRECT, FaceParameterisation
from .exact_caps import evaluate_exact
from .patches import PatchTree
from .results import DataEvaluation, LimitEvaluation, scale_free_normals


class DeviceEvaluator:
    """Evaluates ``tree`` (rooted per control face as ``faces`` says) on ``device``; the tree's arrays are
    uploaded on the first evaluation and kept."""

    def __init__(self, tree: PatchTree, faces: FaceParameterisation, device):
        self.tree = tree
        self.faces = faces
        self.device = device
        self._arrays = None

    def arrays(self) -> dict:
        """The tree's arrays on the device, and one record per face: kind, root node, size * 256 + tiles, and
        the patch of a face that is one patch (2 patch + 1 for a Bezier patch; -1 otherwise)."""
        if self._arrays is None:
            t, dev, faces = self.tree, self.device, self.faces

            def up(a, dtype):
                a = np.ascontiguousarray(a)
                return wp.array(a, dtype=dtype, device=dev, copy=not dev.is_cpu)

            index = t.patch_index if len(t.patch_index) else np.zeros((1, 16), np.int32)
            basis = t.patch_basis if len(t.patch_basis) else np.zeros(1, np.int32)
            root_patch = t.node_patch[faces.root]
            leaf = np.where((faces.kind == DIRECT) & (root_patch >= 0),
                            2 * root_patch + (t.patch_basis[np.maximum(root_patch, 0)] if len(t.patch_basis) else 0),
                            -1)
            info = np.stack([faces.kind, faces.root, faces.size.astype(np.int64) * 256 +
                             np.minimum(faces.tiles, 255), leaf], axis=1).astype(np.int32)
            exact = np.full(max(t.num_patches, 1), -1, dtype=np.int32)
            if t.exact is not None:
                exact[t.exact.patches] = np.arange(t.exact.num_caps, dtype=np.int32)
            self._patch_exact = exact
            self._arrays = dict(
                face_info=wp.array(info, dtype=wp.vec4i, device=dev),
                patch_exact=up(exact, wp.int32),
                node_child=up(t.node_child.astype(np.int32), wp.int32),
                node_patch=up(t.node_patch.astype(np.int32), wp.int32),
                patch_index=up(index.astype(np.int32), wp.int32), patch_basis=up(basis.astype(np.int32), wp.int32),
                points=wp.array(np.ascontiguousarray(t.points, dtype=np.float64), dtype=wp.vec3d, device=dev))
        return self._arrays

    def queries(self, faces_a, u_a, v_a) -> tuple:
        """Checked queries (face, u, v) as device arrays."""
        dev = self.device

        def query(x, dtype):
            x = np.ascontiguousarray(x, dtype=dtype)
            return wp.array(x, device=dev, copy=not dev.is_cpu)

        return query(faces_a, np.int32), query(u_a, np.float64), query(v_a, np.float64)

    def launch(self, queries, n: int, second: bool, points):
        """One run of the evaluation kernel over the tree's nodes and patches with control ``points`` (a Warp
        vec3d array: the tree's points, or three columns of data carried through the same tree)."""
        from .. import kernels
        from ..evaluator import load_kernels

        dev = self.device
        load_kernels(dev, (kernels.limit,))  # a shipped binary where it fits: no compile on a first run
        a = self.arrays()

        def empty(rows, dtype):
            if dev.is_cpu:  # numpy's memory, wrapped: large blocks come on huge pages (a few page faults where
                # Warp's host allocation faults every 4 KiB page of fresh output, 10-20% of a large evaluation)
                host = np.empty((rows, 3) if dtype is wp.vec3d else rows, dtype=np.float64 if dtype is wp.vec3d
                                else np.int32)
                return wp.array(host, dtype=dtype, device=dev, copy=False)
            return wp.empty(rows, dtype=dtype, device=dev)

        p, du, dv, nrm = (empty(n, wp.vec3d) for _ in range(4))
        duu, duv, dvv = (empty(n, wp.vec3d) for _ in range(3)) if second else (empty(1, wp.vec3d),) * 3
        patch = empty(n, wp.int32)
        exact = self.tree.exact is not None
        local = wp.empty(n if exact else 1, dtype=wp.vec4d, device=dev)
        wp.launch(kernels.limit_evaluate, dim=n,
                  inputs=[a["face_info"], *queries,
                          a["node_child"], a["node_patch"], a["patch_index"], a["patch_basis"], points,
                          a["patch_exact"], int(exact), int(self.tree.triangles),
                          int(second), p, du, dv, duu, duv, dvv, nrm, patch, local], device=dev)
        return p, du, dv, nrm, duu, duv, dvv, patch, local

    def exact_rows(self, patch, local, second: bool, ring=None):
        """The queries inside exact end caps (:mod:`~warp_subdiv.limit.exact_caps`), evaluated on the host from
        the kernel's patches and local coordinates: (rows, [value, du, dv (, duu, duv, dvv)]), or None."""
        exact = self.tree.exact
        if exact is None:
            return None
        patch_h = patch.numpy()
        cap = self._patch_exact[np.maximum(patch_h, 0)]
        rows = np.flatnonzero((cap >= 0) & (patch_h >= 0))
        if not len(rows):
            return None
        loc = local.numpy()[rows]
        sub, values = evaluate_exact(exact, cap[rows].astype(np.int64), loc[:, 0], loc[:, 1], loc[:, 2], loc[:, 3],
                                     second, ring)
        return rows[sub], values

    def evaluate(self, faces_a, u_a, v_a, second: bool) -> LimitEvaluation:
        """Points, derivatives and normals of the surface at checked queries (second derivatives with
        ``second``)."""
        n = len(faces_a)
        if n == 0:
            empty = np.zeros((0, 3))
            return LimitEvaluation(empty, empty.copy(), empty.copy(), empty.copy(),
                                   *((empty.copy(),) * 3 if second else (None,) * 3), np.zeros(0, np.int32))
        p, du, dv, nrm, duu, duv, dvv, patch, local = self.launch(self.queries(faces_a, u_a, v_a), n, second,
                                                                  self.arrays()["points"])

        def host(x):
            return x.numpy().reshape(n, 3)

        out = [host(x) for x in ((p, du, dv, nrm) + ((duu, duv, dvv) if second else ()))]
        ring = None if self.tree.exact is None else self.tree.exact.ring[..., :3]
        exact = self.exact_rows(patch, local, second, ring)
        if exact is not None:  # queries inside exact end caps: the host's values replace the caps'
            rows, values = exact
            out[0][rows], out[1][rows], out[2][rows] = values[:3]
            out[3][rows] = np.cross(values[1], values[2])
            if second:
                out[4][rows], out[5][rows], out[6][rows] = values[3:]
        p_h, du_h, dv_h, nrm_h = out[:4]
        # the kernel's unit du x dv overflows or underflows for points of extreme scale: those rows are redone
        if exact is not None:
            length = np.linalg.norm(nrm_h[exact[0]], axis=1, keepdims=True)
            nrm_h[exact[0]] = np.divide(nrm_h[exact[0]], length, out=np.zeros_like(nrm_h[exact[0]]), where=length > 0)
        nrm_h = scale_free_normals(du_h, dv_h, nrm_h)
        return LimitEvaluation(p_h, du_h, dv_h, nrm_h, *(out[4:] if second else (None,) * 3), patch.numpy())

    def evaluate_columns(self, columns, faces_a, u_a, v_a, derivatives, one_d, ring=None) -> DataEvaluation:
        """Evaluate tree control values ``columns`` (num points, k), three columns per kernel run; ``ring``: the
        exact end caps' two-ring values of the same columns (:attr:`ExactCaps.ring
        <warp_subdiv.limit.exact_caps.ExactCaps.ring>` of the tree built with the data)."""
        n, k = len(faces_a), columns.shape[1]
        values = np.zeros((n, k))
        du = np.zeros((n, k)) if derivatives else None
        dv = np.zeros((n, k)) if derivatives else None
        if n:
            queries = self.queries(faces_a, u_a, v_a)
            for c in range(0, k, 3):
                w = min(3, k - c)
                block = np.zeros((len(columns), 3))
                block[:, :w] = columns[:, c:c + w]
                pts = wp.array(block, dtype=wp.vec3d, device=self.device)
                p, pu, pv, _, _, _, _, patch, local = self.launch(queries, n, False, pts)
                values[:, c:c + w] = p.numpy().reshape(n, 3)[:, :w]
                if derivatives:
                    du[:, c:c + w] = pu.numpy().reshape(n, 3)[:, :w]
                    dv[:, c:c + w] = pv.numpy().reshape(n, 3)[:, :w]
            exact = None if ring is None else self.exact_rows(patch, local, False, ring)
            if exact is not None:  # queries inside exact end caps: every column at once
                rows, (v_rows, du_rows, dv_rows) = exact
                values[rows] = v_rows
                if derivatives:
                    du[rows], dv[rows] = du_rows, dv_rows

        def shape(x):
            return x[:, 0] if one_d and x is not None else x

        return DataEvaluation(shape(values), shape(du), shape(dv))
