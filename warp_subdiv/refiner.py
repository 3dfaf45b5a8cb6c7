"""The public entry points: :class:`Refiner` (topology and tables once, evaluate many times) and :func:`refine`.

A :class:`Refiner` is a thin facade: a :class:`~warp_subdiv.hierarchy.Hierarchy` (numpy: levels, step tables,
parent maps) evaluated by an :class:`~warp_subdiv.evaluator.Evaluator` (Warp kernels), plus the face-varying
channels it owns.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .errors import SubdivInputError
from .evaluator import Evaluator, default_device
from .facevarying import FaceVaryingChannel, check_indices
from .hierarchy import Hierarchy
from .mesh import DATA_BOUND, Mesh, check_rows
from .options import FaceVaryingMode, Options
from .tables import StencilTable
from .threads import resolve as resolve_threads


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
    shape (n, 3) or (n, d) with Warp kernels, with no topology work. Options as in :func:`refine`: either
    ``options=`` (an :class:`~warp_subdiv.options.Options`) or the option keywords. ``threads`` (as in
    :func:`refine`) does not change results.
    """

    def __init__(self, mesh: Mesh, levels: int, *, options: Options | None = None, device=None,
                 max_memory: int | None = None, threads: int | None = None, **option_keywords):
        if not isinstance(mesh, Mesh):
            raise TypeError(f"mesh must be a warp_subdiv.Mesh, got {type(mesh).__name__}")
        if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 0:
            raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels",
                                   value=levels)
        if options is None:
            options = Options(**option_keywords)
        elif option_keywords:
            raise TypeError(f"pass either options= or option keywords, not both ({', '.join(option_keywords)})")
        if not options.piecewise_smooth and len(mesh.normal_vertices):
            raise SubdivInputError("prescribed normals need rules='piecewise-smooth' (OpenSubdiv has no normal "
                                   "control)", option="rules", element="normal")
        self.mesh = mesh
        self.levels = int(levels)
        self.options = options
        self.device = wp.get_device(device if device is not None else default_device())
        self.threads = resolve_threads(threads)
        self.hierarchy = Hierarchy(mesh, self.levels, options, max_memory=max_memory, threads=self.threads)
        self.evaluator = Evaluator(self.hierarchy, device=self.device, precision=options.precision,
                                   threads=self.threads)
        self.base_num_vertices = self.hierarchy.base_num_vertices
        self.num_vertices = self.hierarchy.num_vertices
        self._full_tables = None
        self._deeper = None
        self._face_varying: dict = {}

    # option values, as plain attributes (read-only views of self.options)
    scheme = property(lambda self: self.options.scheme)
    rules = property(lambda self: self.options.rules)
    boundary = property(lambda self: self.options.boundary)
    precision = property(lambda self: self.options.precision)
    loop_beta = property(lambda self: self.options.loop_beta)
    normal_strength = property(lambda self: self.options.normal_strength)
    crease_method = property(lambda self: self.options.crease_method)
    triangle_subdivision = property(lambda self: self.options.triangle_subdivision)
    # the hierarchy's step records, for inspection
    steps = property(lambda self: self.hierarchy.steps)
    flatness_tables = property(lambda self: self.hierarchy.flatness_tables)
    normal_tables = property(lambda self: self.hierarchy.normal_tables)

    @property
    def projects(self) -> bool:
        """Whether flatness or normal control act on every level (piecewise-smooth rules at extraordinary crease
        or corner sectors, explicit flatness, prescribed normals): the last level then keeps its full topology."""
        return self.hierarchy.projects

    def limit_reads_deeper(self, levels: int | None = None) -> bool:
        """Whether limit points and normals of ``levels`` (default: this refiner's) read their masks one level
        deeper (see :meth:`Hierarchy.limit_reads_deeper`)."""
        return self.hierarchy.limit_reads_deeper(levels)

    # ---------------------------------------------------------------------------------------------
    def topology(self):
        """(face_vertex_counts, face_vertex_indices) of the refined mesh, int32, hole faces left out."""
        return self.hierarchy.topology()

    @property
    def tables(self) -> list[StencilTable]:
        """Full stencil tables of every step (rows over the previous level), for inspection and tests.

        Evaluation does not use them on uniform levels, where kernels compute the smooth rows from the index
        tables; they are rebuilt here on first use."""
        if self._full_tables is None:
            self._full_tables = self.hierarchy.full_stencils()
        return self._full_tables

    def table_bytes(self) -> int:
        """Bytes of everything a step keeps on the device (index tables, masks, explicit stencils)."""
        return self.evaluator.table_bytes()

    def _check_data(self, data) -> np.ndarray:
        return check_rows(data, self.base_num_vertices, "vertex data", bound=DATA_BOUND[self.precision.value])

    def evaluate_device(self, points, normal_control: bool = True) -> wp.array:
        """Refine (n, 3) positions; returns the final level's device array of vec3 (no copy to the host).

        The array is a shared buffer of the evaluator, overwritten by the next call (from any thread)."""
        arr = self._check_data(points)
        if arr.shape[1] != 3:
            raise SubdivInputError(f"evaluate_device takes (n, 3) positions, got {arr.shape}", element="data",
                                   value=arr.shape)
        return self.evaluator.evaluate_device(arr, normal_control)

    def evaluate(self, points, normal_control=None) -> np.ndarray:
        """Refine (n, 3) or (n, d) vertex data (n = control vertices); returns a numpy array (N, d).

        Data of any width d is refined in one pass, each column as if it were refined alone. Flatness applies
        to all data (it is part of the subdivision matrix); prescribed normals only to positions, i.e. (n, 3)
        data unless ``normal_control=False``. Safe to call from several threads at once.
        """
        arr = self._check_data(points)
        width = arr.shape[1]
        if normal_control is None:
            normal_control = width == 3
        if normal_control and width != 3:
            raise SubdivInputError("normal control applies to (n, 3) positions only", option="normal_control")
        out = self.evaluator.evaluate(arr, normal_control)
        return out[:, 0] if np.ndim(points) == 1 else out

    # ---------------------------------------------------------------------------------------------
    def limit_points(self, refined_points) -> np.ndarray:
        """Limit positions of the refined vertices (docs/rules.md section 9): l^0 applied to each vertex's ring.

        ``refined_points`` (N,) or (N, d) of any width (positions, primvars, face-varying values); the result
        has the same shape. Where this level's masks are not exact (:meth:`limit_reads_deeper`) one more level
        is refined first (with normal control for (N, 3) data)."""
        points = check_rows(refined_points, self.num_vertices, "refined points",
                            bound=DATA_BOUND[self.precision.value])
        if self.limit_reads_deeper():
            deeper = self._one_more_level()
            out = deeper.evaluator.limit_points(points, last_step=True)[: self.num_vertices]
        else:
            out = self.evaluator.limit_points(points)
        return out[:, 0] if np.ndim(refined_points) == 1 else out

    def limit_normals(self, refined_points) -> np.ndarray:
        """Unit outward limit normals of the refined vertices (docs/rules.md section 9); prescribed normals as
        given.

        A crease or corner vertex has one tangent plane per sector; its normal is the normalised sum of the
        sectors' unit normals (exact where there is one sector, e.g. on a boundary).
        """
        refined_points = check_rows(refined_points, self.num_vertices, "refined points",
                                    bound=DATA_BOUND[self.precision.value])
        if refined_points.shape[1] != 3:
            raise SubdivInputError(f"limit normals take (N, 3) positions, got {np.shape(refined_points)}",
                                   element="data", value=np.shape(refined_points))
        if self.limit_reads_deeper():
            deeper = self._one_more_level()
            return deeper._limit_normals_here(refined_points, last_step=True)[: self.num_vertices]
        return self._limit_normals_here(refined_points)

    def _limit_normals_here(self, refined_points, last_step: bool = False) -> np.ndarray:
        """Limit normals from this level's masks, without refining deeper; ``last_step``: the points are of the
        level before this refiner's last and go through its last step first."""
        ids, normals = self.hierarchy.normal_vertices, self.hierarchy.normal_vectors
        if self.options.normal_strength <= 0:
            ids, normals = ids[:0], normals[:0]
        return self.evaluator.limit_normals(refined_points, (ids, normals), last_step=last_step)

    def _one_more_level(self) -> "Refiner":
        """A refiner one level deeper, with the same options, for limit masks (see limit_reads_deeper)."""
        if self._deeper is None:
            self._deeper = Refiner(self.mesh, self.levels + 1, options=self.options, device=self.device,
                                   threads=self.threads)
        return self._deeper

    # ---------------------------------------------------------------------------------------------
    def evaluate_face_varying(self, values, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        """Refine a face-varying channel (UVs): ``values`` (m,) or (m, d), ``indices`` one per face corner.

        Returns (refined values, refined indices int32, one per corner of the refined faces as in
        :meth:`topology`). ``mode``: OpenSubdiv's FVarLinearInterpolation, a
        :class:`~warp_subdiv.options.FaceVaryingMode` or its value ("none", "corners-only", "corners-plus1"
        (USD's default), "corners-plus2", "boundaries", "all"); see :mod:`warp_subdiv.facevarying`. The
        channel's topology is built on the first call for given indices and mode and reused, so later frames
        cost one evaluation.
        """
        return self.face_varying_channel(indices, mode).evaluate(values)

    def limit_face_varying(self, values, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        """Limit values of a face-varying channel at the refined face corners (OpenSubdiv's
        LimitFaceVarying); same arguments and results as :meth:`evaluate_face_varying`."""
        return self.face_varying_channel(indices, mode).limit(values)

    def face_varying_channel(self, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        """The refiner's face-varying channel for ``indices`` and ``mode`` (built once, then reused).

        The refiner owns its channel and passes itself in: the channel refines its value mesh with a refiner of
        this type and these options (:class:`~warp_subdiv.facevarying.FaceVaryingChannel`)."""

        mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        indices = check_indices(indices, len(self.mesh.face_vertex_indices))  # before the cache: 1-D int64
        key = (mode, indices.tobytes())
        if self._face_varying.get("key") != key:
            self._face_varying = {"key": key, "channel": FaceVaryingChannel(self, indices, mode)}
        return self._face_varying["channel"]

    def refine(self, points=None) -> Refined:
        """The refined mesh of ``points`` (default: the mesh's own points)."""
        pts = self.mesh.points if points is None else points
        counts, indices = self.topology()
        o = self.options
        return Refined(
            points=self.evaluate(pts),
            face_vertex_counts=counts,
            face_vertex_indices=indices,
            level=self.levels,
            scheme=o.scheme.value,
            rules=o.rules.value,
            options={"boundary": o.boundary.value, "precision": o.precision.value, "loop_beta": o.loop_beta.value,
                     "crease_method": o.crease_method.value,
                     "triangle_subdivision": o.triangle_subdivision.value},
            refiner=self,
        )


def refine(mesh: Mesh, levels: int, *, options: Options | None = None, device=None,
           max_memory: int | None = None, threads: int | None = None, **option_keywords) -> Refined:
    """Refine ``mesh`` uniformly ``levels`` times.

    Options (keywords, or ``options=`` an :class:`~warp_subdiv.options.Options`):
    ``scheme``: "catmull-clark" (any polygons) or "loop" (triangles; other polygons are fan-triangulated
    unless ``triangulate=False``). ``rules``: "piecewise-smooth" (Biermann, Levin, Zorin 2000) or
    "opensubdiv" (OpenSubdiv 3.6 uniform refinement). ``boundary``: "edge-and-corner", "edge-only" or "none".
    ``precision``: "float32" (default) or "float64" evaluation; weights are always computed in float64.
    ``loop_beta``: "loop" (Loop's original beta, default) or "warren" (the paper's 3/(8k)).
    ``flatness`` (piecewise-smooth only): None for the optimal s* of every crease/corner sector, a number in
    [0, 1] for all sectors, or one value per control vertex (NaN: s*) for the sectors of that vertex.
    ``normal_strength``: s in [0, 1] of normal control at vertices with prescribed normals (``Mesh(normals=)``).
    ``crease_method``: how semi-sharp creases (finite sharpness) decay per level: "uniform" (by 1, OpenSubdiv's
    default) or "chaikin" (OpenSubdiv's CREASE_CHAIKIN).
    ``triangle_subdivision``: "catmark" (default) or "smooth" (OpenSubdiv's TRI_SUB_SMOOTH, USD's
    triangleSubdivisionRule "smooth": Catmull-Clark edge weights next to triangles of the control mesh).

    ``device``: a Warp device ("cpu", "cuda", "cuda:1"); None picks CUDA when present, else the CPU.
    ``max_memory``: bytes; refuse (``SubdivInputError``) before any work when the predicted memory is above it.
    Requests whose last level would not fit 32-bit indices are always refused.
    ``threads``: CPU threads for evaluation and the table build (None: the cores this process may use, see
    :func:`warp_subdiv.threads.default_threads`); results are bitwise the same for any value.
    """
    return Refiner(mesh, levels, options=options, device=device, max_memory=max_memory, threads=threads,
                   **option_keywords).refine()
