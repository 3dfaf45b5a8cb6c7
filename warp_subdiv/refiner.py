"""The public entry points: :class:`Refiner` (topology and tables once, evaluate many times) and :func:`refine`."""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import projections, rules
from .errors import SubdivInputError
from .mesh import Mesh
from .rules import edge_gamma_shift
from .tables import StencilTable, build_stencils
from .topology import BOUNDARY_MODES, RULE_SETS, Level, base_level, refine_level

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
        strength = float(normal_strength)
        if not 0.0 <= strength <= 1.0:
            raise ValueError(f"normal_strength must lie in [0, 1], got {normal_strength!r}")
        paper = rules == "piecewise-smooth"
        if not paper and flatness is not None:
            raise ValueError("flatness is a piecewise-smooth rule; rules='opensubdiv' has none")
        if not paper and len(mesh.normal_vertices):
            raise ValueError("prescribed normals need rules='piecewise-smooth' (OpenSubdiv has no normal control)")
        self.mesh = mesh
        self.levels = int(levels)
        self.scheme = SCHEME_ALIASES[key]
        self.rules = rules
        self.boundary = boundary
        self.precision = precision
        self.loop_beta = loop_beta
        self.normal_strength = strength
        self.device = wp.get_device(device if device is not None else default_device())

        level = base_level(mesh, self.scheme, boundary, rules, triangulate, flatness=flatness if paper else None)
        self.base_num_vertices = level.num_vertices
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
        self.tables: list[StencilTable] = []
        self.flatness_tables: list = []
        self.normal_tables: list = []
        penultimate = level
        for step in range(self.levels):
            self.tables.append(build_stencils(level, rules, loop_beta))
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
        self.num_vertices = level.num_vertices
        self._device_tables = None
        self._buffers: dict = {}

    # ---------------------------------------------------------------------------------------------
    def topology(self):
        """(face_vertex_counts, face_vertex_indices) of the refined mesh, int32, hole faces left out."""
        lvl = self._final
        sizes = lvl.face_sizes()
        keep = ~lvl.face_hole
        if lvl.face_size:
            idx = lvl.corner_vert.reshape(-1, lvl.face_size)[keep].reshape(-1)
        else:
            idx = lvl.corner_vert[np.repeat(keep, sizes)]
        return sizes[keep].astype(np.int32), np.ascontiguousarray(idx, dtype=np.int32)

    def table_bytes(self) -> int:
        """Bytes of all stencil tables on the device (weights at the evaluation precision)."""
        wbytes = np.dtype(PRECISIONS[self.precision][0]).itemsize
        return sum(t.nbytes(wbytes) for t in self.tables)

    def _array(self, values, dtype=None):
        return wp.array(np.ascontiguousarray(values, dtype=dtype), device=self.device)

    def _upload(self):
        if self._device_tables is None:
            np_dtype, _, vec = PRECISIONS[self.precision]
            i32 = np.int32
            steps = []
            for t, flat, norm in zip(self.tables, self.flatness_tables, self.normal_tables):
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

    def _level_buffers(self, width: int):
        """Per-level device arrays for data of the given width, created once and reused for every frame."""
        if width not in self._buffers:
            np_dtype, scalar, vec = PRECISIONS[self.precision]
            sizes = [self.base_num_vertices] + [t.num_rows for t in self.tables]
            moved = [max([0] + [len(t.targets) for t in (f, n) if t is not None])
                     for f, n in zip(self.flatness_tables, self.normal_tables)]
            if width == 3:
                make = lambda n: wp.empty(n, dtype=vec, device=self.device)
            else:
                make = lambda n: wp.empty((n, width), dtype=scalar, device=self.device)
            self._buffers[width] = ([make(n) for n in sizes], [make(n) if n else None for n in moved])
        return self._buffers[width]

    def evaluate_device(self, data, normal_control=None) -> wp.array:
        """Refine vertex data already in the right layout; returns the final level's device array.

        ``normal_control``: apply prescribed normals (positions only); default: when the data is (n, 3).
        """
        tables = self._upload()
        np_dtype, _, vec = PRECISIONS[self.precision]
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
        width = arr.shape[1]
        if normal_control is None:
            normal_control = width == 3
        if normal_control and width != 3:
            raise ValueError("normal control applies to (n, 3) positions only")
        bufs, scratch = self._level_buffers(width)
        host = np.ascontiguousarray(arr, dtype=np_dtype)
        staged = wp.array(host, dtype=vec, device="cpu") if width == 3 else wp.array(host, device="cpu")
        wp.copy(bufs[0], staged)
        k = _kernels()
        dev = self.device
        for step, src, dst, tmp in zip(tables, bufs[:-1], bufs[1:], scratch):
            rows = dst.shape[0]
            if width == 3:
                wp.launch(k.apply_stencils_vec, dim=rows, inputs=[*step["stencil"], src, dst], device=dev)
            else:
                wp.launch(k.apply_stencils_rows, dim=(rows, width), inputs=[*step["stencil"], src, dst], device=dev)
            if "flatness" in step:
                targets = step["flatness"][0]
                n = targets.shape[0]
                if width == 3:
                    wp.launch(k.displace_rows, dim=n, inputs=[*step["flatness"], dst, tmp], device=dev)
                    wp.launch(k.scatter_rows, dim=n, inputs=[targets, tmp, dst], device=dev)
                else:
                    wp.launch(k.displace_rows_2d, dim=(n, width), inputs=[*step["flatness"], dst, tmp], device=dev)
                    wp.launch(k.scatter_rows_2d, dim=(n, width), inputs=[targets, tmp, dst], device=dev)
            if "normals" in step and normal_control:
                targets = step["normals"][0]
                n = targets.shape[0]
                wp.launch(k.project_rows, dim=n, inputs=[*step["normals"], dst, tmp], device=dev)
                wp.launch(k.scatter_rows, dim=n, inputs=[targets, tmp, dst], device=dev)
        return bufs[-1]

    def evaluate(self, points, normal_control=None) -> np.ndarray:
        """Refine (n, 3) or (n, d) vertex data (n = control vertices); returns a numpy array (N, d).

        Flatness applies to all data (it is part of the subdivision matrix); prescribed normals only to
        positions, i.e. (n, 3) data unless ``normal_control=False``.
        """
        # vec3 arrays come back as (N, 3), others as (N, d); copy, because on the CPU .numpy() is a view of
        # a buffer that the next call overwrites
        out = np.array(self.evaluate_device(points, normal_control).numpy(), copy=True)
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
            tables = projections.limit_tables(level, s, self.loop_beta)
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

    def _needs_extra_level(self) -> bool:
        """Limit masks are read one level deeper where this level's masks are not exact.

        Flatness and normal control move the ring points of their sectors on every level, and the crease- and
        corner-neighbour edge rules differ from the smooth rule next to extraordinary crease and corner
        vertices, so the standard masks of a vertex next to such a vertex are exact only one level later, once
        its neighbourhood follows the standard rules; a control mesh with non-quads has no Catmull-Clark masks.
        """
        polygons = self.levels == 0 and self.scheme == rules.CATMULL_CLARK and self._final.face_size != 4
        return polygons or self._projecting or self._modified_edge_rules

    def limit_points(self, refined_points, _direct=False) -> np.ndarray:
        """Limit positions of the refined vertices (RULES.md section 9): l^0 applied to each vertex's ring."""
        if not _direct and self._needs_extra_level():
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
        if not _direct and self._needs_extra_level():
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
        """A refiner one level deeper, with the same options, for limit masks (see _needs_extra_level)."""
        if self._deeper is None:
            self._deeper = Refiner(
                self.mesh, self.levels + 1, scheme=self.scheme, rules=self.rules, boundary=self.boundary,
                device=self.device, precision=self.precision, loop_beta=self.loop_beta,
                triangulate=True, flatness=self._flatness, normal_strength=self.normal_strength,
            )
        return self._deeper

    def _evaluate_from_level(self, points_one_level_up) -> np.ndarray:
        """Refine points of this refiner's second-to-last level through its last step only."""
        np_dtype, _, vec = PRECISIONS[self.precision]
        tables = self._upload()
        step = tables[-1]
        src = self._final_points_of(points_one_level_up, self.tables[-1].num_sources)
        bufs, scratch = self._level_buffers(3)
        dst, tmp = bufs[-1], scratch[-1]
        k = _kernels()
        dev = self.device
        wp.launch(k.apply_stencils_vec, dim=dst.shape[0], inputs=[*step["stencil"], src, dst], device=dev)
        for name, kernel in (("flatness", k.displace_rows), ("normals", k.project_rows)):
            if name in step:
                n = step[name][0].shape[0]
                wp.launch(kernel, dim=n, inputs=[*step[name], dst, tmp], device=dev)
                wp.launch(k.scatter_rows, dim=n, inputs=[step[name][0], tmp, dst], device=dev)
        return np.array(dst.numpy(), copy=True)

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
            options={"boundary": self.boundary, "precision": self.precision, "loop_beta": self.loop_beta},
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
    """
    return Refiner(
        mesh, levels, scheme=scheme, rules=rules, boundary=boundary, device=device, precision=precision,
        loop_beta=loop_beta, triangulate=triangulate, flatness=flatness, normal_strength=normal_strength,
    ).refine()
