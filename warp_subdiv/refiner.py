"""The public entry points: :class:`Refiner` (topology and tables once, evaluate many times) and :func:`refine`.

A :class:`Refiner` is a thin facade: a :class:`~warp_subdiv.tables.hierarchy.Hierarchy` (numpy: levels, step tables,
parent maps) evaluated by an :class:`~warp_subdiv.evaluator.Evaluator` (Warp kernels), plus what it owns for other
units: its face-varying channels and the gradients' state (:attr:`Refiner.adjoint`), and, where limit masks are read
one level deeper, the refiner of that level (:meth:`Refiner.limit_source`).
"""
from __future__ import annotations

import numbers
import threading
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .errors import SubdivInputError
from .runtime import estimate
from .evaluator import Evaluated, Evaluator, default_device, device_rows, normal_control_for, vertex_rows
from .tables import FaceVaryingChannel, Hierarchy, StencilTable, check_value_indices
from .mesh import Mesh
from .options import FaceVaryingMode, Options
from .runtime.threads import resolve as resolve_threads

_adjoint_lock = threading.Lock()  # one refiner's adjoint is made once, whichever thread asks first


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
        """The number of refined vertices."""
        return len(self.points)

    @property
    def num_faces(self) -> int:
        """The number of refined faces."""
        return len(self.face_vertex_counts)


class _GradientMethods:
    """The gradient entry points of a :class:`Refiner` (one of its bases): each hands the refiner to
    :mod:`warp_subdiv.gradients`, whose state for the refiner (:attr:`adjoint`) the refiner keeps."""

    @property
    def adjoint(self):
        """The forward and backward passes of this refiner's gradients with their transposed tables
        (:class:`warp_subdiv.gradients.Adjoint`), made on first use and kept with the refiner."""
        if self._adjoint is None:
            from . import gradients

            with _adjoint_lock:
                if self._adjoint is None:
                    self._adjoint = gradients.Adjoint(self)
        return self._adjoint

    def _recorded(self, data):
        """:mod:`warp_subdiv.gradients` where work on ``data`` is recorded now, by Warp's convention (a Warp array
        that requires grad, under an active ``wp.Tape``): the device entry points then hand the work to it (fresh
        arrays, their backward recorded); else None."""
        if not (isinstance(data, wp.array) and data.requires_grad):
            return None
        from . import gradients

        return gradients if gradients.recording(data) else None

    def matrix(self, level=None, *, normal_control: bool = False, with_offset: bool = False):
        """The sparse map from control data to ``level``'s data (None: the last level; ``"limit"``: limit
        positions): a ``scipy.sparse.csr_matrix`` (a :class:`~warp_subdiv.gradients.CSRMatrix` of the same CSR
        arrays without scipy), ``evaluate(data, normal_control=False) == M @ data``; with ``normal_control`` the
        (3N, 3n) map of positions flattened row by row; ``with_offset``: (M, affine offset). See
        :func:`warp_subdiv.gradients.matrix`."""
        from . import gradients

        return gradients.matrix(self, level, normal_control=normal_control, with_offset=with_offset)

    def evaluate_vjp(self, grad, normal_control=None) -> np.ndarray:
        """Gradient with respect to the control data of ``grad``, a gradient of :meth:`evaluate`'s result (the
        transposed tables applied; deterministic). See :func:`warp_subdiv.gradients.evaluate_vjp`."""
        from . import gradients

        return gradients.evaluate_vjp(self, grad, normal_control)

    def limit_points_vjp(self, grad, *, normal_control=None) -> np.ndarray:
        """Gradient with respect to the refined data of ``grad``, a gradient of :meth:`limit_points`' result with
        the same ``normal_control`` (None: on for width 3; False for data that is not a position). See
        :func:`warp_subdiv.gradients.limit_points_vjp`."""
        from . import gradients

        return gradients.limit_points_vjp(self, grad, normal_control)

    def limit_normals_vjp(self, refined_points, grad, *, normal_control=None) -> np.ndarray:
        """Gradient with respect to ``refined_points`` of ``grad``, a gradient of :meth:`limit_normals`' result
        with the same ``normal_control`` (the true derivative of the unit normals; None: prescribed normals
        substituted, their rows pass none; False: positions refined without normal control). See
        :func:`warp_subdiv.gradients.limit_normals_vjp`."""
        from . import gradients

        return gradients.limit_normals_vjp(self, refined_points, grad, normal_control)


class _FaceVaryingMethods:
    """The face-varying channels of a :class:`Refiner` (one of its bases): the refiner owns its latest channel
    and passes itself in."""

    def evaluate_face_varying(self, values, indices, mode: str = FaceVaryingMode.CORNERS_PLUS1):
        """Refine a face-varying channel (UVs): ``values`` (m,) or (m, d), ``indices`` one per face corner.

        Returns (refined values, refined indices int32, one per corner of the refined faces as in
        :meth:`topology`). ``mode``: OpenSubdiv's FVarLinearInterpolation, a
        :class:`~warp_subdiv.options.FaceVaryingMode` or its value ("none", "corners-only", "corners-plus1"
        (USD's default), "corners-plus2", "boundaries", "all"); see :mod:`warp_subdiv.tables.facevarying`. The
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
        this type and these options (:class:`~warp_subdiv.tables.facevarying.FaceVaryingChannel`)."""

        mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        indices = check_value_indices(indices, len(self.mesh.face_vertex_indices))  # before the cache: 1-D int64
        key = (mode, indices.tobytes())
        if self._face_varying.get("key") != key:
            self._face_varying = {"key": key, "channel": FaceVaryingChannel(self, indices, mode)}
        return self._face_varying["channel"]


class _Views:
    """Read-only views of a refiner's options and of its hierarchy's tables, as plain attributes."""

    scheme = property(lambda self: self.options.scheme, doc="The options' subdivision scheme.")
    rules = property(lambda self: self.options.rules, doc="The options' rule set.")
    boundary = property(lambda self: self.options.boundary, doc="The options' boundary interpolation.")
    precision = property(lambda self: self.options.precision, doc="The options' evaluation precision.")
    loop_beta = property(lambda self: self.options.loop_beta, doc="The options' Loop vertex weight variant.")
    normal_strength = property(lambda self: self.options.normal_strength, doc="The options' normal control strength.")
    crease_method = property(lambda self: self.options.crease_method, doc="The options' semi-sharp crease decay.")
    triangle_subdivision = property(lambda self: self.options.triangle_subdivision, doc="The options' triangle rule.")
    # the hierarchy's step records, for inspection
    steps = property(lambda self: self.hierarchy.steps, doc="The stencil tables of each refinement step.")
    flatness_tables = property(lambda self: self.hierarchy.flatness_tables, doc="Each level's flatness table.")
    normal_tables = property(lambda self: self.hierarchy.normal_tables, doc="Each level's normal-control table.")


class Refiner(_Views, _GradientMethods, _FaceVaryingMethods):
    """Builds the topology and stencil tables of ``levels`` refinement steps once.

    :meth:`evaluate` then refines any per-vertex data (positions of animation frames, vertex primvars) of
    shape (n, 3) or (n, d) with Warp kernels, with no topology work. Options as in :func:`refine`: either
    ``options=`` (an :class:`~warp_subdiv.options.Options`) or the option keywords. ``threads`` (as in
    :func:`refine`) does not change results. ``reuse``: a hierarchy built before that the refiner's hierarchy
    starts from where it fits (see :class:`~warp_subdiv.tables.Hierarchy`).
    """

    def __init__(self, mesh: Mesh, levels: int, *, options: Options | None = None, device=None,
                 max_memory: int | None = None, threads: int | None = None, reuse: Hierarchy | None = None,
                 **option_keywords):
        if not isinstance(mesh, Mesh):
            raise TypeError(f"mesh must be a warp_subdiv.Mesh, got {type(mesh).__name__}")
        if isinstance(levels, bool) or not isinstance(levels, numbers.Integral) or levels < 0:
            raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels",
                                   value=levels)
        options = Options.given(options, option_keywords, caller=type(self).__name__)
        options.check_prescribed_normals(len(mesh.normal_vertices))
        self.mesh = mesh
        self.levels = int(levels)
        self.options = options
        self.device = wp.get_device(device if device is not None else default_device())
        self.threads = resolve_threads(threads)
        _device_guard(mesh, self.levels, options, self.device)
        self.hierarchy = Hierarchy(mesh, self.levels, options, max_memory=max_memory, threads=self.threads,
                                   reuse=reuse)
        self.evaluator = Evaluator(self.hierarchy, device=self.device, precision=options.precision,
                                   threads=self.threads)
        self.base_num_vertices = self.hierarchy.base_num_vertices
        self.num_vertices = self.hierarchy.num_vertices
        self._full_tables = None
        self._deeper = None
        self._adjoint = None
        self._face_varying: dict = {}

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

    def _rows_data(self, data, rows: int, what: str):
        """(data, one_d): host data or a device array checked as (rows, d)
        (:func:`warp_subdiv.evaluator.vertex_rows`)."""
        return vertex_rows(data, rows, what, self.device, self.precision.value)

    def _vertex_data(self, points):
        return self._rows_data(points, self.base_num_vertices, "vertex data")

    def evaluate_device(self, points, normal_control: bool = True, requires_grad: bool | None = None, *, out=None):
        """Refine (n, 3) positions; returns the final level's device array of vec3 (no copy to the host).

        ``points``: host data (numpy), or a device array used where it lies, with no copy to the host: a Warp
        array (vec3 (n,) or (n, 3), float32 or float64, any row stride) or any DLPack or
        ``__cuda_array_interface__`` producer (torch, JAX, CuPy tensors); on the refiner's device it is copied on
        the device into the level-0 buffer (an array on another device goes through the host). Device data is
        not checked for finite values. ``out``: a device array (N, 3) on the refiner's device (Warp, torch, ...,
        any float precision and stride) the result is written into, and which is returned.

        The array is a shared buffer of the evaluator, overwritten by the next call (from any thread).
        ``requires_grad=True``, or None for a Warp array that requires grad under an active ``wp.Tape`` (Warp's
        convention; False: never): ``points`` is a Warp array on the refiner's device (vec3 (n,) or (n, d) of its
        precision: any width; normal control, on by default, acts on width 3 only); the result is a fresh array
        with a gradient (or ``out``, a Warp array with one), and under an active ``wp.Tape`` its backward (the
        transposed tables, :mod:`warp_subdiv.gradients`) is recorded and adds to ``points.grad``."""
        if requires_grad or (requires_grad is None and self._recorded(points)):
            from . import gradients

            return gradients.evaluate(self, points, None if normal_control is True else normal_control,
                                      requires_grad=True, out=out)
        arr, _ = self._vertex_data(points)
        if arr.shape[1] != 3:
            raise SubdivInputError(f"evaluate_device takes (n, 3) positions, got {tuple(arr.shape)}", element="data",
                                   value=tuple(arr.shape))
        if out is None:
            return self.evaluator.evaluate_device(arr, normal_control)
        view = device_rows(out, self.num_vertices, "out", self.device)
        if view is None or view.device != self.device or view.shape[1] != 3:
            raise SubdivInputError(f"out must be a device array ({self.num_vertices}, 3) on {self.device}",
                                   element="data", value=type(out).__name__)
        self.evaluator.evaluate_device(arr, normal_control, out=view)
        return out

    def evaluate(self, points, normal_control=None) -> np.ndarray:
        """Refine (n, 3) or (n, d) vertex data (n = control vertices); returns a numpy array (N, d).

        Data of any width d is refined in one pass, each column as if it were refined alone. Flatness applies
        to all data (it is part of the subdivision matrix); prescribed normals only to positions, i.e. (n, 3)
        data unless ``normal_control=False``. Safe to call from several threads at once. ``points`` may also be a
        device array (as :meth:`evaluate_device` takes); the result is numpy either way (on CUDA one transfer,
        into a reused pinned buffer).
        """
        return self._evaluate_rows(points, None, normal_control)

    def _evaluate_rows(self, points, rows, normal_control=None) -> np.ndarray:
        """:meth:`evaluate`, or with ``rows`` (int array) only those rows of its result, in that order, without
        a full copy first (:class:`warp_subdiv.usd.order.OrderedRefiner` renumbers this way)."""
        arr, one_d = self._vertex_data(points)
        normal_control = normal_control_for(normal_control, arr.shape[1])
        out = self.evaluator.evaluate(arr, normal_control, rows)
        return out[:, 0] if one_d else out

    # ---------------------------------------------------------------------------------------------
    def limit_points(self, refined_points, *, normal_control=None, on_device: bool = False):
        """Limit positions of the refined vertices (docs/rules.md section 9): l^0 applied to each vertex's ring.

        ``refined_points`` (N,) or (N, d) of any width (positions, primvars, face-varying values); the result
        has the same shape. Where this level's masks are not exact (:meth:`limit_reads_deeper`) one more level
        is refined first, with prescribed normals as :meth:`evaluate` applies them: to (N, 3) data unless
        ``normal_control=False`` (pass it for data that is not a position, colours say: then the result is
        ``matrix("limit") @ data`` of the control data). ``refined_points`` may be a device array (as
        :meth:`evaluate_device` takes; its own result is read where it lies, with no copy); ``on_device``: return
        a device array (a view of a shared buffer, valid until the next call; recorded as by evaluate_device,
        its backward with the same ``normal_control``: :meth:`limit_points_vjp`)."""
        if on_device and (recorded := self._recorded(refined_points)):
            return recorded.limit_points(self, refined_points, normal_control=normal_control)
        points, one_d = self._rows_data(refined_points, self.num_vertices, "refined points")
        normal_control = normal_control_for(normal_control, points.shape[1])
        source, deeper = self._guarded_limit_source()
        out = source.evaluator.limit_points(points, last_step=deeper, normal_control=normal_control,
                                            rows=self.num_vertices if deeper else None, on_device=on_device)
        return out[:, 0] if one_d and not on_device else out

    def limit_normals(self, refined_points, *, normal_control=None, on_device: bool = False):
        """Unit outward limit normals of the refined vertices (docs/rules.md section 9); prescribed normals as
        given.

        A crease or corner vertex has one tangent plane per sector; its normal is the normalised sum of the
        sectors' unit normals (exact where there is one sector, e.g. on a boundary). ``refined_points`` and
        ``on_device`` as in :meth:`limit_points`; ``normal_control=False``: the normals of positions refined
        without normal control (``evaluate(points, normal_control=False)``): computed everywhere, prescribed
        normals neither applied in an extra step nor reported (recorded with the same switch: its backward is
        :meth:`limit_normals_vjp`'s).
        """
        if on_device and (recorded := self._recorded(refined_points)):
            return recorded.limit_normals(self, refined_points, normal_control=normal_control)
        points, _ = self._rows_data(refined_points, self.num_vertices, "refined points")
        if points.shape[1] != 3:
            raise SubdivInputError(f"limit normals take (N, 3) positions, got {tuple(np.shape(points))}",
                                   element="data", value=tuple(np.shape(points)))
        normal_control = normal_control_for(normal_control, 3)
        source, deeper = self._guarded_limit_source()
        return source.evaluator.limit_normals(points, source._prescribed(normal_control), last_step=deeper,
                                              normal_control=normal_control,
                                              rows=self.num_vertices if deeper else None, on_device=on_device)

    def _prescribed(self, normal_control: bool = True):
        """(ids, normals) of the prescribed normals that replace computed limit normals of positions refined
        with ``normal_control`` (none where normal control is off, in the options or for these positions)."""
        ids, normals = self.hierarchy.normal_vertices, self.hierarchy.normal_vectors
        if self.options.normal_strength <= 0 or not normal_control:
            ids, normals = ids[:0], normals[:0]
        return ids, normals

    def evaluate_with_limits(self, points, *, normal_control=None, limit_points: bool = True,
                             limit_normals: bool = True, on_device: bool = False) -> Evaluated:
        """Refine control data and take its limit points and unit limit normals in one pass, from the last
        level's device buffer with no copy between (a USD time sample: points, normals and limit points).

        Returns :class:`~warp_subdiv.evaluator.Evaluated` (``points``, ``limit_points``, ``limit_normals``):
        equal, bitwise, to :meth:`evaluate`, then :meth:`limit_points` and :meth:`limit_normals` of its result.
        Where the masks are read one level deeper (:meth:`limit_reads_deeper`), the refiner one level deeper
        refines the control data once and this level's points are its second-to-last level. ``points`` as
        :meth:`evaluate` takes (host data or a device array); normals need (n, 3) positions. ``normal_control`` as
        :meth:`evaluate` takes it, for every step (the deeper one too) and the normals. ``on_device``: the three are
        device arrays (views of shared buffers, valid until the next call; recorded as in limit_points)."""
        if on_device and (recorded := self._recorded(points)):
            return recorded.evaluate_with_limits(self, points, normal_control, limit_points, limit_normals)
        data, one_d = self._vertex_data(points)
        width = data.shape[1]
        normal_control = normal_control_for(normal_control, width)
        if limit_normals and width != 3:
            raise SubdivInputError(f"limit normals take (n, 3) positions, got width {width}", element="data",
                                   value=width)
        source, deeper = self._guarded_limit_source()
        res = source.evaluator.evaluate_with_limits(
            data, bool(normal_control), limit_points=limit_points, limit_normals=limit_normals,
            prescribed=source._prescribed(normal_control), level=-2 if deeper else -1,
            rows=self.num_vertices if deeper else None, on_device=on_device)
        if one_d and not on_device:
            res.points = res.points[:, 0]
            res.limit_points = None if res.limit_points is None else res.limit_points[:, 0]
        return res

    def limit_source(self) -> tuple["Refiner", bool]:
        """(the refiner whose limit masks serve this level's vertices, whether it is one level deeper): this
        refiner, or where this level's masks are not exact (:meth:`limit_reads_deeper`) a refiner one level
        deeper with the same options (made once), whose first vertices are this level's."""
        if not self.limit_reads_deeper():
            return self, False
        if self._deeper is None:
            self._deeper = Refiner(self.hierarchy.mesh, self.levels + 1, options=self.options, device=self.device,
                                   threads=self.threads)
        return self._deeper, True

    def _guarded_limit_source(self) -> tuple["Refiner", bool]:
        """:meth:`limit_source`, its limit masks refused before they are built where they would not fit."""
        source, deeper = self.limit_source()
        if not source.evaluator.has_limit_masks:
            _limit_guard(source)
        return source, deeper

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


def _device_guard(mesh: Mesh, levels: int, o: Options, device) -> None:
    """On CUDA, refuse before any work when the step tables and the level buffers of positions would not fit the
    device's free memory (:func:`warp_subdiv.runtime.estimate.check_device_memory`; nothing on the CPU)."""
    counts = estimate.level_counts(mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, levels,
                                   "loop" if o.scheme.value == "loop" else "catmull-clark")
    tagged = 0 if mesh.creases is None else len(mesh.creases)
    need = sum(estimate.device_bytes(counts, o.scheme.value, o.precision.value, tagged_edges=tagged).values())
    estimate.check_device_memory(need, device, f"refining to level {levels}")


def _limit_guard(refiner: Refiner) -> None:
    """Refuse the limit masks of ``refiner`` whose 32-bit table offsets would wrap, or (CUDA) that would not fit
    the device's free memory, before they are built."""
    level = refiner.hierarchy.final
    scheme = "loop" if refiner.options.scheme.value == "loop" else "catmull-clark"
    estimate.check_limit_tables(level.num_vertices, level.num_corners, scheme, refiner.levels)
    # (the last level may be built faces-only, without edges: the limit items read vertices and corners)
    counts = [estimate.LevelCounts(refiner.levels, level.num_vertices, level.num_faces, 0, level.num_corners)]
    items = estimate.device_bytes(counts, scheme, refiner.precision.value, limit=True)
    estimate.check_device_memory(items["limit masks"] + items["limit outputs"], refiner.device,
                                 f"limit masks of level {refiner.levels}")


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
    :func:`warp_subdiv.runtime.threads.default_threads`); results are bitwise the same for any value.
    """
    return Refiner(mesh, levels, options=options, device=device, max_memory=max_memory, threads=threads,
                   **option_keywords).refine()
