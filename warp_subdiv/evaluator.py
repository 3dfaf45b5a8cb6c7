"""Evaluation of a :class:`~warp_subdiv.hierarchy.Hierarchy`'s step tables with Warp kernels.

The evaluator knows nothing about creases or schemes: it uploads the step records (index tables, explicit
stencils, displacement tables, limit masks) once to its device and launches the kernels of
:mod:`warp_subdiv.kernels` over them.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from .errors import SubdivInputError
from .tables import RegularTables
from .topology import small_pages

PRECISIONS = {"float32": (np.float32, wp.float32, wp.vec3f), "float64": (np.float64, wp.float64, wp.vec3d)}


def default_device() -> str:
    """CUDA when a CUDA device is present, else the CPU."""
    return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"


def _kernels():
    from . import kernels  # imported late: building a hierarchy needs no Warp module

    return kernels


class Evaluator:
    """Applies a hierarchy's steps to vertex data on ``device`` in ``precision``.

    Device tables and level buffers are allocated on first use and reused by every later call.
    """

    def __init__(self, hierarchy, *, device, precision: str):
        self.hierarchy = hierarchy
        self.device = wp.get_device(device)
        self.precision = str(precision)
        self._device_tables = None
        self._buffers = None
        self._limit = None

    def _array(self, values, dtype=None):
        """A device array of ``values``; on the CPU it shares the numpy array's memory instead of copying it
        (the hierarchy keeps its tables, so the memory stays alive)."""
        host = np.ascontiguousarray(values, dtype=dtype)
        if self.device.is_cpu:
            return wp.array(host, device=self.device, copy=False)
        return wp.array(host, device=self.device)

    def _upload(self):
        if self._device_tables is None:
            np_dtype, _, vec = PRECISIONS[self.precision]
            i32 = np.int32
            h = self.hierarchy
            steps = []
            for t, flat, norm in zip(h.steps, h.flatness_tables, h.normal_tables):
                if isinstance(t, RegularTables):
                    ex = t.explicit
                    step = {
                        "regular": t,
                        "corner_vert": self._array(t.corner_vert, i32),
                        "edge_neighbours": self._array(t.edge_neighbours, i32),
                        "ring_offsets": self._array(t.vert_corner_offsets, i32),
                        "ring": self._array(t.ring, i32),
                        "ring_faces": self._array(t.ring_faces, i32),
                        "vertex_regular": self._array(t.vertex_regular, np.uint8),
                        "edge_regular": self._array(t.edge_regular, np.uint8),
                        "ring_weights": self._array(t.ring_weights, np_dtype),
                        "edge_weights": self._array(t.edge_weights, np_dtype),
                        "quarter": self._array([0.25], np_dtype),
                        "explicit": (self._array(ex.rows, i32), self._array(ex.offsets, i32),
                                     self._array(ex.indices, i32), self._array(ex.weights, np_dtype)),
                        "num_explicit": ex.num_rows,
                    }
                else:
                    step = {"stencil": (self._array(t.offsets, i32), self._array(t.indices, i32),
                                        self._array(t.weights, np_dtype))}
                if flat is not None:
                    step["flatness"] = (self._array(flat.targets, i32), self._array(flat.offsets, i32),
                                        self._array(flat.indices, i32), self._array(flat.weights, np_dtype))
                if norm is not None:
                    step["normals"] = (self._array(norm.targets, i32), self._array(norm.offsets, i32),
                                       self._array(norm.indices, i32), self._array(norm.weights, np_dtype),
                                       self._array(norm.normal_ids, i32),
                                       wp.array(norm.normals.astype(np_dtype), dtype=vec, device=self.device))
                steps.append(step)
            self._device_tables = steps
        return self._device_tables

    def _level_buffers(self):
        """Per-level device arrays of points, created once and reused for every frame and column triple."""
        if self._buffers is None:
            _, _, vec = PRECISIONS[self.precision]
            h = self.hierarchy
            sizes = [h.base_num_vertices] + [t.num_rows for t in h.steps]
            moved = [max([0] + [len(t.targets) for t in (f, n) if t is not None])
                     for f, n in zip(h.flatness_tables, h.normal_tables)]

            def make(n):
                return wp.empty(n, dtype=vec, device=self.device)

            self._buffers = ([make(n) for n in sizes], [make(n) if n else None for n in moved])
        return self._buffers

    def _apply_step(self, step, src, dst, tmp, normal_control: bool):
        """One refinement step on vec3 points: smooth rows by index arithmetic, the rest by explicit
        stencils, then flatness and normal control."""
        k = _kernels()
        dev = self.device
        if "regular" in step:
            t = step["regular"]
            V, F = t.num_vertices, t.num_faces
            if t.face_size == 4:
                wp.launch(k.quad_face_points, dim=F, inputs=[step["corner_vert"], src, dst, V, step["quarter"]],
                          device=dev)
                wp.launch(k.quad_edge_points, dim=len(t.edge_neighbours),
                          inputs=[step["edge_neighbours"], step["edge_regular"], src, dst, V, V + F,
                                  step["edge_weights"]], device=dev)
                wp.launch(k.quad_vertex_points, dim=V,
                          inputs=[step["ring_offsets"], step["ring"], step["ring_faces"], step["vertex_regular"],
                                  src, dst, V, step["ring_weights"]], device=dev)
            else:
                wp.launch(k.tri_edge_points, dim=len(t.edge_neighbours),
                          inputs=[step["edge_neighbours"], step["edge_regular"], src, dst, V, step["edge_weights"]],
                          device=dev)
                wp.launch(k.tri_vertex_points, dim=V,
                          inputs=[step["ring_offsets"], step["ring"], step["vertex_regular"], src, dst,
                                  step["ring_weights"]], device=dev)
            if step["num_explicit"]:
                wp.launch(k.explicit_rows, dim=step["num_explicit"], inputs=[*step["explicit"], src, dst],
                          device=dev)
        else:
            wp.launch(k.apply_stencils_vec, dim=dst.shape[0], inputs=[*step["stencil"], src, dst], device=dev)
        for name, kernel, active in (("flatness", k.displace_rows, True), ("normals", k.project_rows,
                                                                            normal_control)):
            if name in step and active:
                n = step[name][0].shape[0]
                wp.launch(kernel, dim=n, inputs=[*step[name], dst, tmp], device=dev)
                wp.launch(k.scatter_rows, dim=n, inputs=[step[name][0], tmp, dst], device=dev)

    def run(self, triple: np.ndarray, normal_control: bool) -> wp.array:
        """Refine (n, 3) data through every step; returns the last level's device array (reused next call)."""
        tables = self._upload()
        np_dtype, _, vec = PRECISIONS[self.precision]
        bufs, scratch = self._level_buffers()
        host = np.ascontiguousarray(triple, dtype=np_dtype)
        wp.copy(bufs[0], wp.array(host, dtype=vec, device="cpu"))
        for step, src, dst, tmp in zip(tables, bufs[:-1], bufs[1:], scratch):
            self._apply_step(step, src, dst, tmp, normal_control)
        return bufs[-1]

    def evaluate(self, arr: np.ndarray, normal_control: bool) -> np.ndarray:
        """Refine checked (n, d) data; returns a new numpy array (N, d).

        Data of other widths than 3 is refined three columns at a time through the same kernels."""
        width = arr.shape[1]
        # copies: on the CPU .numpy() is a view of a buffer that the next call overwrites; the copies are
        # written once and read in order (small pages, see topology.small_pages)
        if width == 3:
            result = self.run(arr, normal_control)
            with small_pages():
                return np.array(result.numpy(), copy=True)
        padded = np.zeros((arr.shape[0], -(-width // 3) * 3))
        padded[:, :width] = arr
        blocks = []
        for c in range(0, padded.shape[1], 3):
            result = self.run(padded[:, c:c + 3], False)
            with small_pages():
                blocks.append(np.array(result.numpy(), copy=True))
        with small_pages():
            return np.concatenate(blocks, axis=1)[:, :width]

    def evaluate_last_step(self, points_one_level_up) -> np.ndarray:
        """Refine points of the second-to-last level through the last step only."""
        tables = self._upload()
        bufs, scratch = self._level_buffers()
        src = self._points(points_one_level_up, bufs[-2].shape[0])
        self._apply_step(tables[-1], src, bufs[-1], scratch[-1], True)
        return np.array(bufs[-1].numpy(), copy=True)

    # ------------------------------------------------------------------------------------------ limits
    def _limit_tables(self):
        if self._limit is None:
            tables = self.hierarchy.limit_tables()
            np_dtype, _, vec = PRECISIONS[self.precision]
            i32 = np.int32
            dev = {
                name: (self._array(t.offsets, i32), self._array(t.indices, i32), self._array(t.weights, np_dtype))
                for name, t in (("position", tables.position), ("u", tables.tangent_u), ("v", tables.tangent_v))
            }
            dev["vertex_offsets"] = self._array(tables.vertex_offsets, i32)
            dev["num_tangents"] = tables.tangent_u.num_rows
            self._limit = dev
        return self._limit

    def _points(self, points, count) -> wp.array:
        np_dtype, _, vec = PRECISIONS[self.precision]
        pts = np.ascontiguousarray(points, dtype=np_dtype)
        if pts.shape != (count, 3):
            raise SubdivInputError(f"refined points must have shape ({count}, 3), got {pts.shape}",
                                   element="data", value=pts.shape)
        return wp.array(pts, dtype=vec, device=self.device)

    def limit_points(self, refined_points) -> np.ndarray:
        """Limit positions of the last level's vertices: the position mask applied to each vertex's ring."""
        lim = self._limit_tables()
        _, _, vec = PRECISIONS[self.precision]
        n = self.hierarchy.num_vertices
        src = self._points(refined_points, n)
        out = wp.empty(n, dtype=vec, device=self.device)
        wp.launch(_kernels().apply_stencils_vec, dim=n, inputs=[*lim["position"], src, out], device=self.device)
        return np.array(out.numpy(), copy=True)

    def limit_normals(self, refined_points, prescribed) -> np.ndarray:
        """Unit limit normals of the last level's vertices; ``prescribed`` (ids, normals) replace theirs."""
        lim = self._limit_tables()
        np_dtype, _, vec = PRECISIONS[self.precision]
        k = _kernels()
        n = self.hierarchy.num_vertices
        src = self._points(refined_points, n)
        nt = lim["num_tangents"]
        tu = wp.empty(nt, dtype=vec, device=self.device)
        tv = wp.empty(nt, dtype=vec, device=self.device)
        out = wp.empty(n, dtype=vec, device=self.device)
        if nt:
            wp.launch(k.apply_stencils_vec, dim=nt, inputs=[*lim["u"], src, tu], device=self.device)
            wp.launch(k.apply_stencils_vec, dim=nt, inputs=[*lim["v"], src, tv], device=self.device)
        wp.launch(k.vertex_normals, dim=n, inputs=[lim["vertex_offsets"], tu, tv, vec(), out], device=self.device)
        ids, normals = prescribed
        if len(ids):
            wp.launch(k.scatter_rows, dim=len(ids),
                      inputs=[self._array(ids, np.int32), wp.array(normals.astype(np_dtype), dtype=vec,
                                                                   device=self.device), out], device=self.device)
        return np.array(out.numpy(), copy=True)

    def table_bytes(self) -> int:
        """Bytes of everything a step keeps on the device (index tables, masks, explicit stencils)."""
        wbytes = np.dtype(PRECISIONS[self.precision][0]).itemsize
        return sum(t.nbytes(wbytes) for t in self.hierarchy.steps)
