"""The public entry points: :class:`Refiner` (topology and tables once, evaluate many times) and :func:`refine`."""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import rules
from .errors import SubdivInputError
from .mesh import Mesh
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
        if len(mesh.normal_vertices):
            raise NotImplementedError(
                "prescribed normals are not applied yet (normal control is the projections issue); "
                "refine without normals"
            )
        self.mesh = mesh
        self.levels = int(levels)
        self.scheme = SCHEME_ALIASES[key]
        self.rules = rules
        self.boundary = boundary
        self.precision = precision
        self.loop_beta = loop_beta
        self.device = wp.get_device(device if device is not None else default_device())

        level = base_level(mesh, self.scheme, boundary, rules, triangulate)
        self.base_num_vertices = level.num_vertices
        self.tables: list[StencilTable] = []
        for step in range(self.levels):
            self.tables.append(build_stencils(level, rules, loop_beta))
            level = refine_level(level, faces_only=(step == self.levels - 1))
        self._final: Level = level
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

    def _upload(self):
        if self._device_tables is None:
            np_dtype = PRECISIONS[self.precision][0]
            self._device_tables = [
                (
                    wp.array(t.offsets, dtype=wp.int32, device=self.device),
                    wp.array(t.indices, dtype=wp.int32, device=self.device),
                    wp.array(t.weights.astype(np_dtype), device=self.device),
                )
                for t in self.tables
            ]
        return self._device_tables

    def _level_buffers(self, width: int):
        """Per-level device arrays for data of the given width, created once and reused for every frame."""
        key = width
        if key not in self._buffers:
            np_dtype, scalar, vec = PRECISIONS[self.precision]
            sizes = [self.base_num_vertices] + [t.num_rows for t in self.tables]
            if width == 3:
                bufs = [wp.empty(n, dtype=vec, device=self.device) for n in sizes]
            else:
                bufs = [wp.empty((n, width), dtype=scalar, device=self.device) for n in sizes]
            self._buffers[key] = bufs
        return self._buffers[key]

    def evaluate_device(self, data) -> wp.array:
        """Refine vertex data already in the right layout; returns the final level's device array."""
        tables = self._upload()
        np_dtype = PRECISIONS[self.precision][0]
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
        bufs = self._level_buffers(width)
        host = np.ascontiguousarray(arr, dtype=np_dtype)
        if width == 3:
            wp.copy(bufs[0], wp.array(host, dtype=PRECISIONS[self.precision][2], device="cpu"))
        else:
            wp.copy(bufs[0], wp.array(host, device="cpu"))
        k = _kernels()
        for (offsets, indices, weights), t, src, dst in zip(tables, self.tables, bufs[:-1], bufs[1:]):
            if width == 3:
                wp.launch(k.apply_stencils_vec, dim=t.num_rows, inputs=[offsets, indices, weights, src, dst],
                          device=self.device)
            else:
                wp.launch(k.apply_stencils_rows, dim=(t.num_rows, width),
                          inputs=[offsets, indices, weights, src, dst], device=self.device)
        return bufs[-1]

    def evaluate(self, points) -> np.ndarray:
        """Refine (n, 3) or (n, d) vertex data (n = control vertices); returns a numpy array (N, d)."""
        # vec3 arrays come back as (N, 3), others as (N, d); copy, because on the CPU .numpy() is a view of
        # a buffer that the next call overwrites
        out = np.array(self.evaluate_device(points).numpy(), copy=True)
        return out[:, 0] if np.ndim(points) == 1 else out

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
) -> Refined:
    """Refine ``mesh`` uniformly ``levels`` times.

    ``scheme``: "catmull-clark" (any polygons) or "loop" (triangles; other polygons are fan-triangulated
    unless ``triangulate=False``). ``rules``: "piecewise-smooth" (Biermann, Levin, Zorin 2000) or
    "opensubdiv" (OpenSubdiv 3.6 uniform refinement). ``boundary``: "edge-and-corner", "edge-only" or "none".
    ``device``: a Warp device ("cpu", "cuda", "cuda:1"); None picks CUDA when present, else the CPU.
    ``precision``: "float32" (default) or "float64" evaluation; weights are always computed in float64.
    ``loop_beta``: "loop" (Loop's original beta, default) or "warren" (the paper's 3/(8k)).
    """
    return Refiner(
        mesh, levels, scheme=scheme, rules=rules, boundary=boundary, device=device, precision=precision,
        loop_beta=loop_beta, triangulate=triangulate,
    ).refine()
