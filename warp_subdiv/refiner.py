"""The public entry points: :class:`Refiner` (topology and tables once, evaluate many times) and :func:`refine`."""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import projections, rules
from . import rules as rules_module
from .errors import SubdivInputError
from .mesh import Mesh
from .rules import edge_gamma_shift
from .tables import RegularTables, StencilTable, build_regular, build_stencils
from .topology import BOUNDARY_MODES, RULE_SETS, Level, base_level, refine_level, small_pages

SCHEME_ALIASES = {"catmull-clark": rules.CATMULL_CLARK, "catmullclark": rules.CATMULL_CLARK,
                  "catmark": rules.CATMULL_CLARK, "loop": rules.LOOP}
PRECISIONS = {"float32": (np.float32, wp.float32, wp.vec3f), "float64": (np.float64, wp.float64, wp.vec3d)}


def default_device() -> str:
    """CUDA when a CUDA device is present, else the CPU."""
    return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"


def _kernels():
    from . import kernels  # noqa: WPS433 (imported late: building a Refiner needs no Warp module)

    return kernels


@dataclass
class Refined:
    """A refined mesh: numpy ``points`` (N, 3), ``face_vertex_counts``, ``face_vertex_indices`` (int32)."""

    points: np.ndarray
    face_vertex_counts: np.ndarray
    face_vertex_indices: np.ndarray
    level: int
    scheme: str
    rules: str = "piecewise-smooth"
    options: dict = field(default_factory=dict)
    refiner: "Refiner | None" = field(default=None, repr=False, compare=False)

    def limit_points(self) -> np.ndarray:
        """Limit positions of this level's vertices (N, 3)."""
        return self.refiner.limit_points(self.points)

    def limit_normals(self) -> np.ndarray:
        """Unit outward limit normals of this level's vertices (N, 3); the prescribed normal where one is given."""
        return self.refiner.limit_normals(self.points)

    @property
    def num_vertices(self) -> int:
        return len(self.points)

    @property
    def num_faces(self) -> int:
        return len(self.face_vertex_counts)


class Refiner:
    """Builds the topology and stencil tables of ``levels`` refinement steps once.

    :meth:`evaluate` then refines any per-vertex data (positions of animation frames, vertex primvars) of
    shape (n, 3) or (n, d) with Warp kernels, with no topology work. Options as in :func:`refine`.
    """

    def __init__(
        self,
        mesh: Mesh,
        levels: int,
        *,
        scheme: str = "catmull-clark",
        rules: str = "piecewise-smooth",
        boundary: str = "edge-and-corner",
        device=None,
        precision: str = "float32",
        loop_beta: str = "loop",
        triangulate: bool = True,
        flatness=None,
        normal_strength: float = 1.0,
        crease_method: str = "uniform",
        triangle_subdivision: str = "catmark",
        max_memory: int | None = None,
        _linear: bool = False,
    ):
        if not isinstance(mesh, Mesh):
            raise TypeError(f"mesh must be a warp_subdiv.Mesh, got {type(mesh).__name__}")
        if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 0:
            raise ValueError(f"levels must be an integer >= 0, got {levels!r}")
        key = str(scheme).lower()
        if key not in SCHEME_ALIASES:
            raise ValueError(f"scheme must be 'catmull-clark' or 'loop', got {scheme!r}")
        if rules not in RULE_SETS:
            raise ValueError(f"rules must be one of {RULE_SETS}, got {rules!r}")
        if boundary not in BOUNDARY_MODES:
            raise ValueError(f"boundary must be one of {BOUNDARY_MODES}, got {boundary!r}")
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be 'float32' or 'float64', got {precision!r}")
        if loop_beta not in ("loop", "warren"):
            raise ValueError(f"loop_beta must be 'loop' or 'warren', got {loop_beta!r}")
        if triangle_subdivision not in ("catmark", "smooth"):
            raise ValueError(f"triangle_subdivision must be 'catmark' or 'smooth', got {triangle_subdivision!r}")
        strength = float(normal_strength)
        if not 0.0 <= strength <= 1.0:
            raise ValueError(f"normal_strength must lie in [0, 1], got {normal_strength!r}")
        paper = rules == "piecewise-smooth"
        if not paper and flatness is not None:
            raise ValueError("flatness is a piecewise-smooth rule; rules='opensubdiv' has none")
        if not paper and len(mesh.normal_vertices):
            raise ValueError("prescribed normals need rules='piecewise-smooth' (OpenSubdiv has no normal control)")
        from . import estimate as est

        est.check_indices([self._estimate(mesh, int(levels), SCHEME_ALIASES[key], precision, False)], int(levels))
        self.mesh = mesh
        self.levels = int(levels)
        self.scheme = SCHEME_ALIASES[key]
        self.rules = rules
        self.boundary = boundary
        self.precision = precision
        self.loop_beta = loop_beta
        self.normal_strength = strength
        self.device = wp.get_device(device if device is not None else default_device())

        self.crease_method = crease_method
        self.triangle_subdivision = triangle_subdivision
        smooth_triangles = triangle_subdivision == "smooth" and SCHEME_ALIASES[key] == rules_module.CATMULL_CLARK
        self._linear = _linear  # bilinear refinement, for face-varying data in mode "all"
        level = base_level(mesh, self.scheme, boundary, rules, triangulate, flatness=flatness if paper else None,
                           crease_method=crease_method, linear=_linear)
        self.base_num_vertices = level.num_vertices
        self._base_face_size = level.face_size
        normal_vertices = mesh.normal_vertices.astype(np.int64)
        self._normals = (normal_vertices, mesh.normal_vectors)
        base_s = projections.resolve_flatness(level) if paper else np.zeros(level.num_sectors)
        if len(normal_vertices):
            projections.check_normal_vertices(level, normal_vertices)
        # the last level needs its full topology only when a projection acts on it
        # extraordinary crease/corner sectors: their edge rules move weight (gamma(theta) != 3/8)
        shift = edge_gamma_shift(self.scheme, level.sector_theta)
        self._modified_edge_rules = paper and bool(np.any((level.sector_k() >= 2) & (np.abs(shift) > 1e-15)))
        self._projecting = paper and (
            bool(np.any(base_s > 0)) or level.new_sector_flatness > 0 or len(normal_vertices) > 0
        )
        # before any refined level is allocated (the control-mesh analysis above is the size of the input)
        est.check_memory([self._estimate(mesh, self.levels, self.scheme, precision, self._projecting)], max_memory,
                         self.levels)
        self.steps: list = []  # per step: RegularTables (uniform levels) or a full StencilTable
        self.flatness_tables: list = []
        self.normal_tables: list = []
        self._triangulate = triangulate
        self._full_tables = None
        penultimate = level
        for step in range(self.levels):
            if level.face_size == (4 if self.scheme == rules_module.CATMULL_CLARK else 3):
                self.steps.append(build_regular(level, rules, loop_beta))
            else:
                self.steps.append(build_stencils(level, rules, loop_beta, smooth_triangles=smooth_triangles))
            penultimate = level
            level = refine_level(level, faces_only=(step == self.levels - 1) and not self._projecting)
            flat = norm = None
            if self._projecting:
                s = projections.resolve_flatness(level)
                flat = projections.flatness_table(level, s)
                if len(normal_vertices) and strength > 0:
                    norm = projections.normal_table(level, normal_vertices, mesh.normal_vectors, strength, s,
                                                    loop_beta)
            self.flatness_tables.append(flat)
            self.normal_tables.append(norm)
        self._final: Level = level
        self._penultimate: Level = penultimate
        self._limit = None
        self._deeper = None
        self._flatness = flatness
        self._face_varying: dict = {}
        self.num_vertices = level.num_vertices
        self._device_tables = None
        self._buffers = None

    @staticmethod
    def _estimate(mesh, levels, scheme, precision, projecting):
        from . import estimate as est

        return est.estimate("mesh", mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, levels, scheme,
                            precision=precision, projecting=projecting)

    @property
    def projects(self) -> bool:
        """Whether flatness or normal control act on every level (piecewise-smooth rules at extraordinary crease
        or corner sectors, explicit flatness, prescribed normals): the last level then keeps its full topology."""
        return self._projecting

    def limit_reads_deeper(self, levels: int | None = None) -> bool:
        """Whether limit points and normals of ``levels`` (default: this refiner's) read their masks one level
        deeper, because the masks of that level are not exact.

        Flatness and normal control move the ring points of their sectors on every level, and the crease- and
        corner-neighbour edge rules differ from the smooth rule next to extraordinary crease and corner
        vertices, so the standard masks of a vertex next to such a vertex are exact only one level later, once
        its neighbourhood follows the standard rules; a control mesh with non-quads has no Catmull-Clark masks.
        """
        levels = self.levels if levels is None else levels
        polygons = levels == 0 and self.scheme == rules.CATMULL_CLARK and self._base_face_size != 4
        return polygons or self._projecting or self._modified_edge_rules

    # ---------------------------------------------------------------------------------------------
    def topology(self):
        """(face_vertex_counts, face_vertex_indices) of the refined mesh, int32, hole faces left out."""
        lvl = self._final
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

    @property
    def tables(self) -> list[StencilTable]:
        """Full stencil tables of every step (rows over the previous level), for inspection and tests.

        Evaluation does not use them on uniform levels, where kernels compute the smooth rows from the index
        tables; they are rebuilt here on first use."""
        if self._full_tables is None:
            level = base_level(self.mesh, self.scheme, self.boundary, self.rules, self._triangulate,
                               flatness=self._flatness if self.rules == "piecewise-smooth" else None,
                               crease_method=self.crease_method, linear=self._linear)
            self._full_tables = []
            smooth_triangles = self.triangle_subdivision == "smooth" and self.scheme == rules_module.CATMULL_CLARK
            for _ in range(self.levels):
                self._full_tables.append(build_stencils(level, self.rules, self.loop_beta,
                                                        smooth_triangles=smooth_triangles))
                level = refine_level(level)
        return self._full_tables

    def table_bytes(self) -> int:
        """Bytes of everything a step keeps on the device (index tables, masks, explicit stencils)."""
        wbytes = np.dtype(PRECISIONS[self.precision][0]).itemsize
        return sum(t.nbytes(wbytes) for t in self.steps)

    def _array(self, values, dtype=None):
        """A device array of ``values``; on the CPU it shares the numpy array's memory instead of copying it
        (the refiner keeps its tables, so the memory stays alive)."""
        host = np.ascontiguousarray(values, dtype=dtype)
        if self.device.is_cpu:
            return wp.array(host, device=self.device, copy=False)
        return wp.array(host, device=self.device)

    def _upload(self):
        if self._device_tables is None:
            np_dtype, _, vec = PRECISIONS[self.precision]
            i32 = np.int32
            steps = []
            for t, flat, norm in zip(self.steps, self.flatness_tables, self.normal_tables):
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
            sizes = [self.base_num_vertices] + [t.num_rows for t in self.steps]
            moved = [max([0] + [len(t.targets) for t in (f, n) if t is not None])
                     for f, n in zip(self.flatness_tables, self.normal_tables)]
            make = lambda n: wp.empty(n, dtype=vec, device=self.device)
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

    def _check_data(self, data) -> np.ndarray:
        arr = np.asarray(data)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] != self.base_num_vertices:
            raise SubdivInputError(
                f"vertex data must have shape ({self.base_num_vertices}, d), got {np.shape(data)}"
            )
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
            raise SubdivInputError(f"vertex data row {bad} is not finite")
        return arr

    def evaluate_device(self, points, normal_control: bool = True) -> wp.array:
        """Refine (n, 3) positions; returns the final level's device array of vec3 (no copy to the host).

        The array is reused by the next call."""
        arr = self._check_data(points)
        if arr.shape[1] != 3:
            raise SubdivInputError(f"evaluate_device takes (n, 3) positions, got {arr.shape}")
        return self._run(arr, normal_control)

    def _run(self, triple: np.ndarray, normal_control: bool) -> wp.array:
        tables = self._upload()
        np_dtype, _, vec = PRECISIONS[self.precision]
        bufs, scratch = self._level_buffers()
        host = np.ascontiguousarray(triple, dtype=np_dtype)
        wp.copy(bufs[0], wp.array(host, dtype=vec, device="cpu"))
        for step, src, dst, tmp in zip(tables, bufs[:-1], bufs[1:], scratch):
            self._apply_step(step, src, dst, tmp, normal_control)
        return bufs[-1]

    def evaluate(self, points, normal_control=None) -> np.ndarray:
        """Refine (n, 3) or (n, d) vertex data (n = control vertices); returns a numpy array (N, d).

        Flatness applies to all data (it is part of the subdivision matrix); prescribed normals only to
        positions, i.e. (n, 3) data unless ``normal_control=False``. Data of other widths is refined three
        columns at a time through the same kernels.
        """
        arr = self._check_data(points)
        width = arr.shape[1]
        if normal_control is None:
            normal_control = width == 3
        if normal_control and width != 3:
            raise ValueError("normal control applies to (n, 3) positions only")
        # copies: on the CPU .numpy() is a view of a buffer that the next call overwrites; the copies are
        # written once and read in order (small pages, see topology.small_pages)
        if width == 3:
            result = self._run(arr, normal_control)
            with small_pages():
                out = np.array(result.numpy(), copy=True)
        else:
            padded = np.zeros((arr.shape[0], -(-width // 3) * 3))
            padded[:, :width] = arr
            blocks = []
            for c in range(0, padded.shape[1], 3):
                result = self._run(padded[:, c:c + 3], False)
                with small_pages():
                    blocks.append(np.array(result.numpy(), copy=True))
            with small_pages():
                out = np.concatenate(blocks, axis=1)[:, :width]
        return out[:, 0] if np.ndim(points) == 1 else out

    # ---------------------------------------------------------------------------------------------
    def _limit_tables(self):
        if self._limit is None:
            level = self._final
            if level.edge_verts is None:  # built faces-only: derive the full last level now
                level = refine_level(self._penultimate)
            if level.face_size == 0 or (self.scheme == rules.CATMULL_CLARK and level.face_size != 4):
                raise NotImplementedError("limit masks need a level of quads (Catmull-Clark) or triangles")
            s = projections.resolve_flatness(level) if self.rules == "piecewise-smooth" else np.zeros(
                level.num_sectors)
            tables = projections.limit_tables(level, s, self.loop_beta, self.rules)
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

    def _final_points(self, points) -> wp.array:
        return self._final_points_of(points, self.num_vertices)

    def _final_points_of(self, points, count) -> wp.array:
        np_dtype, _, vec = PRECISIONS[self.precision]
        pts = np.ascontiguousarray(points, dtype=np_dtype)
        if pts.shape != (count, 3):
            raise SubdivInputError(f"refined points must have shape ({count}, 3), got {pts.shape}")
        return wp.array(pts, dtype=vec, device=self.device)

    def limit_points(self, refined_points, _direct=False) -> np.ndarray:
        """Limit positions of the refined vertices (RULES.md section 9): l^0 applied to each vertex's ring."""
        if not _direct and self.limit_reads_deeper():
            extra = self._one_more_level()
            return extra.limit_points(extra._evaluate_from_level(refined_points), True)[: self.num_vertices]
        lim = self._limit_tables()
        _, _, vec = PRECISIONS[self.precision]
        src = self._final_points(refined_points)
        out = wp.empty(self.num_vertices, dtype=vec, device=self.device)
        wp.launch(_kernels().apply_stencils_vec, dim=self.num_vertices, inputs=[*lim["position"], src, out],
                  device=self.device)
        return np.array(out.numpy(), copy=True)

    def limit_normals(self, refined_points, _direct=False) -> np.ndarray:
        """Unit outward limit normals of the refined vertices (RULES.md section 9); prescribed normals as given.

        A crease or corner vertex has one tangent plane per sector; its normal is the normalised sum of the
        sectors' unit normals (exact where there is one sector, e.g. on a boundary).
        """
        if not _direct and self.limit_reads_deeper():
            extra = self._one_more_level()
            return extra.limit_normals(extra._evaluate_from_level(refined_points), True)[: self.num_vertices]
        lim = self._limit_tables()
        np_dtype, _, vec = PRECISIONS[self.precision]
        k = _kernels()
        src = self._final_points(refined_points)
        nt = lim["num_tangents"]
        tu = wp.empty(nt, dtype=vec, device=self.device)
        tv = wp.empty(nt, dtype=vec, device=self.device)
        out = wp.empty(self.num_vertices, dtype=vec, device=self.device)
        if nt:
            wp.launch(k.apply_stencils_vec, dim=nt, inputs=[*lim["u"], src, tu], device=self.device)
            wp.launch(k.apply_stencils_vec, dim=nt, inputs=[*lim["v"], src, tv], device=self.device)
        wp.launch(k.vertex_normals, dim=self.num_vertices, inputs=[lim["vertex_offsets"], tu, tv, vec(), out],
                  device=self.device)
        ids, normals = self._normals
        if len(ids) and self.normal_strength > 0:
            wp.launch(k.scatter_rows, dim=len(ids),
                      inputs=[self._array(ids, np.int32), wp.array(normals.astype(np_dtype), dtype=vec,
                                                                   device=self.device), out], device=self.device)
        return np.array(out.numpy(), copy=True)

    def _one_more_level(self) -> "Refiner":
        """A refiner one level deeper, with the same options, for limit masks (see limit_reads_deeper)."""
        if self._deeper is None:
            self._deeper = Refiner(
                self.mesh, self.levels + 1, scheme=self.scheme, rules=self.rules, boundary=self.boundary,
                device=self.device, precision=self.precision, loop_beta=self.loop_beta,
                triangulate=self._triangulate, flatness=self._flatness, normal_strength=self.normal_strength,
                crease_method=self.crease_method, triangle_subdivision=self.triangle_subdivision,
                _linear=self._linear,
            )
        return self._deeper

    def _evaluate_from_level(self, points_one_level_up) -> np.ndarray:
        """Refine points of this refiner's second-to-last level through its last step only."""
        tables = self._upload()
        bufs, scratch = self._level_buffers()
        src = self._final_points_of(points_one_level_up, bufs[-2].shape[0])
        self._apply_step(tables[-1], src, bufs[-1], scratch[-1], True)
        return np.array(bufs[-1].numpy(), copy=True)

    def evaluate_face_varying(self, values, indices, mode: str = "corners-plus1"):
        """Refine a face-varying channel (UVs): ``values`` (m,) or (m, d), ``indices`` one per face corner.

        Returns (refined values, refined indices int32, one per corner of the refined faces as in
        :meth:`topology`). ``mode``: OpenSubdiv's FVarLinearInterpolation ("none", "corners-only",
        "corners-plus1" (USD's default), "corners-plus2", "boundaries", "all"); see
        :mod:`warp_subdiv.facevarying`. The channel's topology is built on the first call for given indices
        and mode and reused, so later frames cost one evaluation.
        """
        return self._face_varying_refiner(indices, mode).evaluate(values)

    def limit_face_varying(self, values, indices, mode: str = "corners-plus1"):
        """Limit values of a face-varying channel at the refined face corners (OpenSubdiv's
        LimitFaceVarying); same arguments and results as :meth:`evaluate_face_varying`."""
        return self._face_varying_refiner(indices, mode).limit(values)

    def _face_varying_refiner(self, indices, mode):
        from .facevarying import FaceVaryingRefiner

        key = (mode, np.asarray(indices).tobytes())
        if self._face_varying.get("key") != key:
            self._face_varying = {"key": key, "refiner": FaceVaryingRefiner(self, indices, mode)}
        return self._face_varying["refiner"]

    def refine(self, points=None) -> Refined:
        """The refined mesh of ``points`` (default: the mesh's own points)."""
        pts = self.mesh.points if points is None else points
        counts, indices = self.topology()
        return Refined(
            points=self.evaluate(pts),
            face_vertex_counts=counts,
            face_vertex_indices=indices,
            level=self.levels,
            scheme=self.scheme,
            rules=self.rules,
            options={"boundary": self.boundary, "precision": self.precision, "loop_beta": self.loop_beta,
                     "crease_method": self.crease_method, "triangle_subdivision": self.triangle_subdivision},
            refiner=self,
        )


def refine(
    mesh: Mesh,
    levels: int,
    *,
    scheme: str = "catmull-clark",
    rules: str = "piecewise-smooth",
    boundary: str = "edge-and-corner",
    device=None,
    precision: str = "float32",
    loop_beta: str = "loop",
    triangulate: bool = True,
    flatness=None,
    normal_strength: float = 1.0,
    crease_method: str = "uniform",
    triangle_subdivision: str = "catmark",
    max_memory: int | None = None,
) -> Refined:
    """Refine ``mesh`` uniformly ``levels`` times.

    ``scheme``: "catmull-clark" (any polygons) or "loop" (triangles; other polygons are fan-triangulated
    unless ``triangulate=False``). ``rules``: "piecewise-smooth" (Biermann, Levin, Zorin 2000) or
    "opensubdiv" (OpenSubdiv 3.6 uniform refinement). ``boundary``: "edge-and-corner", "edge-only" or "none".
    ``device``: a Warp device ("cpu", "cuda", "cuda:1"); None picks CUDA when present, else the CPU.
    ``precision``: "float32" (default) or "float64" evaluation; weights are always computed in float64.
    ``loop_beta``: "loop" (Loop's original beta, default) or "warren" (the paper's 3/(8k)).
    ``flatness`` (piecewise-smooth only): None for the optimal s* of every crease/corner sector, a number in
    [0, 1] for all sectors, or one value per control vertex (NaN: s*) for the sectors of that vertex.
    ``normal_strength``: s in [0, 1] of normal control at vertices with prescribed normals (``Mesh(normals=)``).
    ``crease_method``: how semi-sharp creases (finite sharpness) decay per level: "uniform" (by 1, OpenSubdiv's
    default) or "chaikin" (OpenSubdiv's CREASE_CHAIKIN).
    ``triangle_subdivision``: "catmark" (default) or "smooth" (OpenSubdiv's TRI_SUB_SMOOTH, USD's
    triangleSubdivisionRule "smooth": Catmull-Clark edge weights next to triangles of the control mesh).
    ``max_memory``: bytes; refuse (``SubdivInputError``) before any work when the predicted memory is above it.
    Requests whose last level would not fit 32-bit indices are always refused.
    """
    return Refiner(
        mesh, levels, scheme=scheme, rules=rules, boundary=boundary, device=device, precision=precision,
        loop_beta=loop_beta, triangulate=triangulate, flatness=flatness, normal_strength=normal_strength,
        crease_method=crease_method, triangle_subdivision=triangle_subdivision, max_memory=max_memory,
    ).refine()
