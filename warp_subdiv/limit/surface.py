"""Evaluation of the limit surface at arbitrary (face, u, v): :class:`LimitSurface`.

Parameterisation (as OpenSubdiv's ``Bfr::Parameterization``):

* a quad (Catmull-Clark) is the unit square, corner i at (0,0), (1,0), (1,1), (0,1);
* a triangle (Loop) is barycentric: corner 0 at (0,0), corner 1 at (1,0), corner 2 at (0,1), the point
  (1 - u - v) c0 + u c1 + v c2;
* a Catmull-Clark n-gon (n != 4, triangles included) is partitioned into its n quad sub-faces (the level-1 quad
  at each corner), laid out as tiles: sub-face i occupies the half-unit square with corner (i mod W, i div W),
  W = ceil(sqrt(n)); inside it, 2 (u - i mod W, v - i div W) is the sub-face's own unit square, with the
  n-gon's corner i at (0,0), the middle of edge i (toward corner i + 1) at (1,0), the face's centre at (1,1)
  and the middle of edge i - 1 at (0,1). This is Bfr's QUAD_SUBFACES parameterisation;
* a Loop polygon (n > 3; Loop fan-triangulates polygons into (v0, v_k+1, v_k+2)) is its fan triangles laid out
  as tiles in the same way: triangle k occupies the half-unit square with corner (k, 0), and 2 (u - k, v) is its
  own barycentric (u, v). (OpenSubdiv's Loop has no polygons; this mirrors its sub-face tiles.)

A query outside its face's domain (the unit square, the triangle, the sub-face squares or the fan triangles)
is refused (``SubdivInputError`` naming the query, its face and (u, v)), except for round-off: up to
:data:`~warp_subdiv.limit.parameterisation.DOMAIN_TOLERANCE` (1e-6) outside, a query is evaluated on the
domain's side (clamped onto the square, scaled toward the triangle's corner 0).

Derivatives ``du``, ``dv`` (and ``duu``, ``duv``, ``dvv``) are with respect to these (u, v); normals are the unit
``du x dv`` (outward for counter-clockwise faces), of unit length whatever the scale of the points (where
``du x dv`` would overflow or underflow float64 it is taken of the tangents scaled by powers of two:
:func:`~warp_subdiv.limit.results.scale_free_normals`).

Data on the surface: :meth:`LimitSurface.evaluate_data` evaluates per-vertex data (vertex primvars) as the limit
of the same subdivision, with the weights of the positions (sector angles, flatness and end caps' tangent
planes from the geometry), so the result is linear in the data and data equal to the points gives the points;
:meth:`LimitSurface.evaluate_face_varying` evaluates a face-varying channel (UVs) on the limit surface of its
value mesh under OpenSubdiv's face-varying interpolation mode (as Bfr builds a face-varying surface per face).

How it is computed and how exact it is: :mod:`warp_subdiv.limit.patches` (a tree of Bezier patches per face:
exact polynomial patches wherever the surface is one, local refinement with the library's own rules and
projections near irregular features down to ``depth`` levels, end caps below that, evaluated exactly at
extraordinary boundary and crease vertices: :mod:`warp_subdiv.limit.exact_caps`). The tree is built once;
:meth:`LimitSurface.evaluate` runs one Warp kernel (:mod:`warp_subdiv.kernels.limit`) on the CPU or CUDA
(:mod:`warp_subdiv.limit.device`). The faces' parameterisation and linear surfaces:
:mod:`warp_subdiv.limit.parameterisation`; face-varying channels: :mod:`warp_subdiv.limit.face_varying`.
"""
from __future__ import annotations

import numbers

import numpy as np
import warp as wp

from . import patches as limit_patches
from .device import DeviceEvaluator
from .face_varying import FaceVaryingChannel
from .parameterisation import FaceParameterisation, linear_data, linear_evaluation
from .results import DataEvaluation, LimitEvaluation
from .tessellation import tessellate
from ..errors import SubdivInputError
from ..evaluator import default_device
from ..mesh import Mesh, check_rows
from ..options import FaceVaryingMode, Options, Scheme

#: Default depth of local refinement below a base face before end caps (see docs/limit-surface.md).
DEFAULT_DEPTH = 8


class LimitSurface:
    """The limit surface of ``mesh`` under ``options`` (or the option keywords of :func:`warp_subdiv.refine`),
    evaluable at any (face, u, v) of the control faces.

    ``depth`` (>= 1): how many levels below a control face the surface near irregular features (extraordinary
    vertices, irregular creases and corners, semi-sharp tags, flatness and normal control, n-gons) is refined
    locally before end caps take over; the surface is exact everywhere except inside the end caps, which cover
    the sub-faces of size 2^-depth at the irregular points (docs/limit-surface.md gives the error; at
    extraordinary boundary and crease vertices they are evaluated exactly too, for ``depth`` >= 2).
    ``device``: a Warp device for :meth:`evaluate` (None: CUDA when present, else the CPU). The patch tree is
    built in float64 and evaluated in float64 whatever the ``precision`` option says. With ``linear=True``
    (bilinear meshes) the surface is the linear interpolation inside each face (:attr:`linear`; no patch tree,
    evaluated with numpy).
    """

    def __init__(self, mesh: Mesh, *, depth: int = DEFAULT_DEPTH, options: Options | None = None, device=None,
                 **option_keywords):
        if not isinstance(mesh, Mesh):
            raise TypeError(f"mesh must be a warp_subdiv.Mesh, got {type(mesh).__name__}")
        if isinstance(depth, bool) or not isinstance(depth, numbers.Integral) or not 1 <= depth <= 30:
            raise SubdivInputError(f"depth must be an integer in [1, 30], got {depth!r}", option="depth",
                                   value=depth)
        options = Options.given(options, option_keywords, caller=type(self).__name__)
        options.check_prescribed_normals(len(mesh.normal_vertices))
        self.mesh = mesh
        self.options = options
        self.depth = int(depth)
        self.device = wp.get_device(device if device is not None else default_device())
        # a linear (bilinear) surface needs no patch tree: it is the linear interpolation inside each face
        self.tree = None if options.linear else limit_patches.build(mesh, options, self.depth)
        self._parameterisation = FaceParameterisation.of(mesh, options, self.tree)
        self._evaluator = None if self.tree is None else DeviceEvaluator(self.tree, self._parameterisation, self.device)
        self._face_varying = None  # the last face-varying channel evaluated

    scheme = property(lambda self: self.options.scheme,
                      doc="The subdivision scheme (:class:`~warp_subdiv.Scheme`) of the options.")
    rules = property(lambda self: self.options.rules,
                     doc="The rule set (:class:`~warp_subdiv.RuleSet`) of the options.")
    #: Per control face (see :class:`~warp_subdiv.limit.parameterisation.FaceParameterisation`): how it is
    #: parameterised, its first root node, its number of corners, its tiles per row, whether it is a hole.
    face_kind = property(lambda self: self._parameterisation.kind,
                         doc="How each control face is parameterised: DIRECT, SUBFACES (a Catmull-Clark n-gon) or "
                             "FAN (a Loop polygon).")
    face_root = property(lambda self: self._parameterisation.root,
                         doc="The root patch of each control face in the patch tree (-1 for a hole).")
    face_size = property(lambda self: self._parameterisation.size, doc="The number of corners of each control face.")
    face_tiles = property(lambda self: self._parameterisation.tiles,
                          doc="The width of the (u, v) domain of each control face: its sub-faces or fan triangles "
                              "side by side.")
    holes = property(lambda self: self._parameterisation.holes,
                     doc="Whether each control face is a hole (not evaluated).")

    @property
    def linear(self) -> bool:
        """Whether this is a linear surface (``options.linear``: bilinear meshes): the linear interpolation
        inside each control face that linear refinement converges to (bilinear on quads and on a polygon's quad
        sub-faces, barycentric on Loop triangles), with the same parameterisation."""
        return bool(self.options.linear)

    @property
    def triangles(self) -> bool:
        """Whether the faces are evaluated as triangles (Loop) rather than quads."""
        return self.options.scheme == Scheme.LOOP

    @property
    def num_faces(self) -> int:
        """The number of control faces."""
        return len(self.face_kind)

    @property
    def edges(self) -> np.ndarray:
        """(E, 2) int32 vertex pairs of the control mesh's edges: the order of per-edge tessellation rates."""
        return self.mesh.edges.edge_verts

    def vertex_uv(self, faces, corners) -> np.ndarray:
        """(n, 2) parametric coordinates of corner ``corners[i]`` of face ``faces[i]`` (Bfr's GetVertexCoord)."""
        return self._parameterisation.vertex_uv(faces, corners)

    def evaluate(self, faces, u, v, *, derivatives: int = 1) -> LimitEvaluation:
        """The limit surface at control faces ``faces`` and parameters ``u``, ``v`` (arrays broadcast together;
        the results take their broadcast shape: (n, 3) for n queries, (2, 2, 3) for (2, 2) queries, and three
        scalars are one query, (1, 3); see the module docstring for the parameterisation and its domains).
        ``derivatives``: 1 (points, first derivatives, normals) or 2 (also second derivatives). Hole faces, and
        (u, v) outside the face's domain by more than round-off, are refused (:attr:`holes` says which faces
        are holes)."""
        if derivatives not in (1, 2):
            raise SubdivInputError(f"derivatives must be 1 or 2, got {derivatives!r}", option="derivatives",
                                   value=derivatives)
        faces_a, u_a, v_a, shape = self._parameterisation.check_queries(faces, u, v)
        second = derivatives == 2
        if self.tree is None:
            return linear_evaluation(self, faces_a, u_a, v_a, second).reshaped(shape)
        return self._evaluator.evaluate(faces_a, u_a, v_a, second).reshaped(shape)

    def evaluate_data(self, data, faces, u, v, *, derivatives: int = 0) -> DataEvaluation:
        """The limit of per-control-vertex ``data`` ((V,) or (V, k): vertex primvars) at ``faces``, ``u``, ``v``.

        The data is subdivided with the subdivision of the positions (as ``Refiner.evaluate`` refines
        primvars): sector angles of the piecewise-smooth rules, flatness, and the tangent planes of the end caps
        come from the mesh's points, never from the data, so the result is a linear function of ``data`` (the
        positions' weights) and equals ``Refined.limit_points()`` of the refined data at refined vertices.
        ``data`` equal to the points gives :meth:`evaluate`'s points bit for bit, except where prescribed normals
        move the positions (normal control acts on positions only, as in ``refine``). The patch tree of the
        data is built on each call (the cost of constructing this surface); ``derivatives``: 0 or 1 (also
        ``du``, ``dv``). Queries as :meth:`evaluate` takes them; results of their shape (+ (k,))."""
        if derivatives not in (0, 1):
            raise SubdivInputError(f"derivatives must be 0 or 1, got {derivatives!r}", option="derivatives",
                                   value=derivatives)
        one_d = np.ndim(data) == 1
        arr = check_rows(data, self.mesh.num_vertices, "vertex data").astype(np.float64)
        faces_a, u_a, v_a, shape = self._parameterisation.check_queries(faces, u, v)
        if self.tree is None:
            corner_values = arr[np.asarray(self.mesh.face_vertex_indices, dtype=np.int64)]
            return linear_data(self, corner_values, faces_a, u_a, v_a, derivatives, one_d).reshaped(shape)
        tree = limit_patches.build(self.mesh, self.options, self.depth, data=arr)
        if tree.num_nodes != self.tree.num_nodes or tree.num_patches != self.tree.num_patches:
            raise AssertionError("the data's patch tree differs from the surface's")
        if (tree.exact is None) != (self.tree.exact is None) or (
                tree.exact is not None and not np.array_equal(tree.exact.patches, self.tree.exact.patches)):
            raise AssertionError("the data's exact end caps differ from the surface's")
        columns = tree.points[:, 3:]
        ring = None if tree.exact is None else tree.exact.ring[..., 3:]
        return self._evaluator.evaluate_columns(columns, faces_a, u_a, v_a, derivatives, one_d,
                                                ring).reshaped(shape)

    def evaluate_face_varying(self, values, indices, faces, u, v, *, mode=FaceVaryingMode.CORNERS_PLUS1,
                              derivatives: int = 0) -> DataEvaluation:
        """A face-varying channel (UVs) on the limit surface at ``faces``, ``u``, ``v``.

        ``values`` (m,) or (m, k), ``indices`` one value index per face corner (the order of the mesh's
        ``face_vertex_indices``), ``mode``: OpenSubdiv's FVarLinearInterpolation ("none", "corners-only",
        "corners-plus1" (USD's default), "corners-plus2", "boundaries", "all"; see
        :mod:`warp_subdiv.tables.facevarying`). As OpenSubdiv's Bfr evaluates face-varying data, the channel is the
        limit surface of its value mesh (:func:`~warp_subdiv.tables.facevarying.value_mesh`: the same faces in the same
        order, seams as boundaries, the mode's sharp values), subdivided with OpenSubdiv's rules as
        ``Refiner.limit_face_varying`` does, so at refined corners the two agree; (face, u, v) means the same
        point as in :meth:`evaluate`. Mode "all" (and any mode on a linear surface) is linear interpolation
        inside each face (bilinear on quads and sub-faces, barycentric on triangles), as bilinear refinement
        converges to. The value mesh's topology is built on the first call for given indices and mode and
        reused. ``derivatives``: 0 or 1 (also ``du``, ``dv``). Queries as :meth:`evaluate` takes them; results of
        their shape (+ (k,))."""
        mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        if derivatives not in (0, 1):
            raise SubdivInputError(f"derivatives must be 0 or 1, got {derivatives!r}", option="derivatives",
                                   value=derivatives)
        if self.linear:  # a linear surface carries its face-varying data linearly too (as refine does)
            mode = FaceVaryingMode.ALL
        channel = self._face_varying = FaceVaryingChannel.of(self, indices, mode, self._face_varying)
        one_d = np.ndim(values) == 1
        if np.ndim(values) in (1, 2) and len(values) < channel.num_values:
            raise SubdivInputError(f"face-varying indices refer to value {channel.num_values - 1} but only "
                                   f"{len(values)} values were given", option="values", element="data",
                                   value=len(values))
        vals = check_rows(values, channel.num_values, "face-varying values", at_least=True).astype(np.float64)
        faces_a, u_a, v_a, shape = self._parameterisation.check_queries(faces, u, v)
        if mode == FaceVaryingMode.ALL:
            return linear_data(self, vals[channel.indices], faces_a, u_a, v_a, derivatives, one_d).reshaped(shape)
        return channel.evaluate(self, vals, faces_a, u_a, v_a, derivatives, one_d).reshaped(shape)

    def tessellate(self, *, rate=None, edge_length=None, quads: bool = True):
        """A watertight tessellation of the limit surface (see :func:`warp_subdiv.limit.tessellate`)."""
        return tessellate(self, rate=rate, edge_length=edge_length, quads=quads)

    def __repr__(self) -> str:
        t = self.tree
        if t is None:
            return f"LimitSurface({self.num_faces} faces, {self.options.scheme.value}, linear)"
        return (f"LimitSurface({self.num_faces} faces, {self.options.scheme.value}, {self.options.rules.value}, "
                f"depth {self.depth}: {t.num_patches} patches, {int(np.sum(t.patch_kind == 1))} end caps)")
