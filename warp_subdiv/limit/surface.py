"""Evaluation of the limit surface at arbitrary (face, u, v): :class:`LimitSurface`.

Parameterisation (as OpenSubdiv's ``Bfr::Parameterization``):

* a quad (Catmull-Clark) is the unit square, corner i at (0,0), (1,0), (1,1), (0,1);
* a triangle (Loop) is barycentric: corner 0 at (0,0), corner 1 at (1,0), corner 2 at (0,1), the point
  (1 - u - v) c0 + u c1 + v c2;
* a Catmull-Clark n-gon (n != 4, triangles included) is partitioned into its n quad sub-faces (the level-1 quad
  at each corner), laid out as tiles: sub-face i occupies the half-unit square with corner (i mod W, i div W),
  W = ceil(sqrt(n)); inside it, 2 (u - i mod W, v - i div W) is the sub-face's own unit square, with the
  n-gon's corner i at (0,0), the middle of edge i (toward corner i + 1) at (1,0), the face's centre at (1,1)
  and the middle of edge i - 1 at (0,1). This is Bfr's QUAD_SUBFACES parameterisation; as in Bfr, a (u, v)
  within a quarter tile beyond a sub-face's square belongs to the nearest sub-face (coordinates are clamped
  to it);
* a Loop polygon (n > 3; Loop fan-triangulates polygons into (v0, v_k+1, v_k+2)) is its fan triangles laid out
  as tiles in the same way: triangle k occupies the half-unit square with corner (k, 0), and 2 (u - k, v) is its
  own barycentric (u, v). (OpenSubdiv's Loop has no polygons; this mirrors its sub-face tiles.)

Derivatives ``du``, ``dv`` (and ``duu``, ``duv``, ``dvv``) are with respect to these (u, v); normals are the unit
``du x dv`` (outward for counter-clockwise faces).

Data on the surface: :meth:`LimitSurface.evaluate_data` evaluates per-vertex data (vertex primvars) as the limit
of the same subdivision, with the weights of the positions (sector angles, flatness and end caps' tangent
planes from the geometry), so the result is linear in the data and data equal to the points gives the points;
:meth:`LimitSurface.evaluate_face_varying` evaluates a face-varying channel (UVs) on the limit surface of its
value mesh under OpenSubdiv's face-varying interpolation mode (as Bfr builds a face-varying surface per face).

How it is computed and how exact it is: :mod:`warp_subdiv.limit.patches` (a tree of Bezier patches per face:
exact polynomial patches wherever the surface is one, local refinement with the library's own rules and
projections near irregular features down to ``depth`` levels, end caps below that). The tree is built once;
:meth:`LimitSurface.evaluate` runs one Warp kernel (:mod:`warp_subdiv.kernels.limit`) on the CPU or CUDA.
"""
from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp

from . import patches as limit_patches
from .parameterisation import DIRECT, FAN, SUBFACES, corner_weights
from .tessellation import tessellate
from ..errors import NonManifoldWarning, SubdivInputError
from ..evaluator import default_device
from ..mesh import Mesh, check_rows
from ..options import FaceVaryingMode, Options, Scheme

#: Default depth of local refinement below a base face before end caps (see README "Limit surface").
DEFAULT_DEPTH = 8



@dataclass
class LimitEvaluation:
    """Results of :meth:`LimitSurface.evaluate`, numpy float64 arrays of shape (n, 3): ``points``, first
    derivatives ``du``, ``dv``, unit ``normals``, and with ``derivatives=2`` the second derivatives ``duu``,
    ``duv``, ``dvv`` (None otherwise). ``patch``: the leaf patch each point was evaluated on (internal)."""

    points: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    normals: np.ndarray
    duu: np.ndarray | None = None
    duv: np.ndarray | None = None
    dvv: np.ndarray | None = None
    patch: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class DataEvaluation:
    """Results of :meth:`LimitSurface.evaluate_data` and :meth:`LimitSurface.evaluate_face_varying`: numpy
    float64 ``values`` (n, k), or (n,) for 1-D data, and with ``derivatives=1`` their first derivatives ``du``,
    ``dv`` with respect to the face's (u, v), of the same shape (None otherwise)."""

    values: np.ndarray
    du: np.ndarray | None = None
    dv: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.values)


class LimitSurface:
    """The limit surface of ``mesh`` under ``options`` (or the option keywords of :func:`warp_subdiv.refine`),
    evaluable at any (face, u, v) of the control faces.

    ``depth`` (>= 1): how many levels below a control face the surface near irregular features (extraordinary
    vertices, irregular creases and corners, semi-sharp tags, flatness and normal control, n-gons) is refined
    locally before end caps take over; the surface is exact everywhere except inside the end caps, which cover
    the sub-faces of size 2^-depth at the irregular points (README "Limit surface" gives the error).
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
        self._parameterisation()
        self._device_arrays = None
        self._fv_cache = None

    scheme = property(lambda self: self.options.scheme)
    rules = property(lambda self: self.options.rules)

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

    # ------------------------------------------------------------------------------------------ faces
    def _parameterisation(self) -> None:
        mesh, tree = self.mesh, self.tree
        counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
        F = len(counts)
        if tree is None:  # linear: faces as the parameterisation says, holes as the mesh says
            loop = self.options.scheme == Scheme.LOOP
            self.face_kind = np.where(counts == (3 if loop else 4), DIRECT, FAN if loop else SUBFACES).astype(np.int32)
            self.face_root = np.zeros(F, np.int32)
            self.face_size = counts.astype(np.int32)
            self.face_tiles = np.ceil(np.sqrt(counts)).astype(np.int32)
            self.holes = np.zeros(F, bool)
            self.holes[np.asarray(mesh.holes, dtype=np.int64)] = True
            return
        roots = tree.root_offsets
        if self.options.scheme == Scheme.LOOP:
            tris = counts - 2
            first = np.concatenate([[0], np.cumsum(tris)[:-1]]).astype(np.int64)
            kind = np.where(counts == 3, DIRECT, FAN)
            root = roots[first]
        else:
            kind = np.where(counts == 4, DIRECT, SUBFACES)
            root = roots[:F]
        self.face_kind = kind.astype(np.int32)
        self.face_root = root.astype(np.int32)
        self.face_size = counts.astype(np.int32)
        self.face_tiles = np.ceil(np.sqrt(counts)).astype(np.int32)
        # a control face is a hole when its (first) root is
        self.holes = tree.node_patch[root] == limit_patches.HOLE
        self.holes |= self._all_holes(kind, root, counts)

    def _all_holes(self, kind, root, counts) -> np.ndarray:
        out = np.zeros(len(kind), bool)
        multi = np.flatnonzero(kind != DIRECT)
        patch = self.tree.node_patch
        for f in multi:
            n = counts[f] if kind[f] == SUBFACES else counts[f] - 2
            out[f] = bool(np.all(patch[root[f]:root[f] + n] == limit_patches.HOLE))
        return out

    @property
    def num_faces(self) -> int:
        return len(self.face_kind)

    @property
    def edges(self) -> np.ndarray:
        """(E, 2) int32 vertex pairs of the control mesh's edges: the order of per-edge tessellation rates."""
        return self.mesh.edges.edge_verts

    def vertex_uv(self, faces, corners) -> np.ndarray:
        """(n, 2) parametric coordinates of corner ``corners[i]`` of face ``faces[i]`` (Bfr's GetVertexCoord)."""
        faces = np.asarray(faces, dtype=np.int64).reshape(-1)
        corners = np.asarray(corners, dtype=np.int64).reshape(-1)
        kind = self.face_kind[faces]
        out = np.zeros((len(faces), 2))
        quad = (kind == DIRECT) & (self.face_size[faces] == 4)
        tri = (kind == DIRECT) & (self.face_size[faces] == 3)
        out[quad] = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], float)[corners[quad]]
        out[tri] = np.array([(0, 0), (1, 0), (0, 1)], float)[corners[tri]]
        sub = kind == SUBFACES
        w = self.face_tiles[faces]
        out[sub, 0] = (corners % w)[sub]
        out[sub, 1] = (corners // w)[sub]
        fan = kind == FAN  # corner 0 at (0, 0); corner i < n - 1: triangle i - 1's second corner; the last corner:
        last = corners == self.face_size[faces] - 1  # triangle n - 3's third
        out[fan, 0] = np.where(last, corners - 2, np.where(corners == 0, 0.0, corners - 0.5))[fan]
        out[fan, 1] = np.where(last, 0.5, 0.0)[fan]
        return out

    # ------------------------------------------------------------------------------------------ evaluation
    def _arrays(self):
        if self._device_arrays is None:
            t, dev = self.tree, self.device

            def up(a, dtype):
                a = np.ascontiguousarray(a)
                return wp.array(a, dtype=dtype, device=dev, copy=not dev.is_cpu)

            index = t.patch_index if len(t.patch_index) else np.zeros((1, 16), np.int32)
            basis = t.patch_basis if len(t.patch_basis) else np.zeros(1, np.int32)
            # one record per face: kind, root node, size * 256 + tiles, and the patch of a face that is one
            # patch (2 patch + 1 for a Bezier patch; -1 otherwise)
            root_patch = t.node_patch[self.face_root]
            leaf = np.where((self.face_kind == DIRECT) & (root_patch >= 0),
                            2 * root_patch + (t.patch_basis[np.maximum(root_patch, 0)] if len(t.patch_basis) else 0),
                            -1)
            info = np.stack([self.face_kind, self.face_root, self.face_size.astype(np.int64) * 256 +
                             np.minimum(self.face_tiles, 255), leaf], axis=1).astype(np.int32)
            self._device_arrays = dict(
                face_info=wp.array(info, dtype=wp.vec4i, device=dev),
                node_child=up(t.node_child.astype(np.int32), wp.int32),
                node_patch=up(t.node_patch.astype(np.int32), wp.int32),
                patch_index=up(index.astype(np.int32), wp.int32), patch_basis=up(basis.astype(np.int32), wp.int32),
                points=wp.array(np.ascontiguousarray(t.points, dtype=np.float64), dtype=wp.vec3d, device=dev))
        return self._device_arrays

    def _queries(self, faces, u, v):
        try:
            faces_a = np.asarray(faces)
            u_a = np.asarray(u, dtype=np.float64)
            v_a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise SubdivInputError("u and v must be numbers", option="uv") from None
        if faces_a.size and faces_a.dtype.kind not in "iu":
            if faces_a.dtype.kind == "f" and np.all(faces_a == np.round(faces_a)):
                faces_a = faces_a.astype(np.int64)
            else:
                raise SubdivInputError(f"faces must be integer face ids, got dtype {faces_a.dtype}", option="faces")
        try:
            faces_a, u_a, v_a = np.broadcast_arrays(faces_a, u_a, v_a)
        except ValueError:
            raise SubdivInputError(f"faces, u and v have incompatible shapes {np.shape(faces)}, {np.shape(u)}, "
                                   f"{np.shape(v)}", option="faces") from None
        faces_a = faces_a.reshape(-1).astype(np.int64)
        u_a = u_a.reshape(-1)
        v_a = v_a.reshape(-1)
        bad = np.flatnonzero((faces_a < 0) | (faces_a >= self.num_faces))
        if len(bad):
            raise SubdivInputError(f"face {faces_a[bad[0]]} (query {bad[0]}) is outside [0, {self.num_faces})",
                                   option="faces", element="face", index=int(bad[0]), value=int(faces_a[bad[0]]))
        bad = np.flatnonzero(~(np.isfinite(u_a) & np.isfinite(v_a)))
        if len(bad):
            raise SubdivInputError(f"(u, v) of query {bad[0]} is not finite", option="uv", index=int(bad[0]))
        hole = np.flatnonzero(self.holes[faces_a])
        if len(hole):
            f = int(faces_a[hole[0]])
            raise SubdivInputError(f"face {f} (query {hole[0]}) is a hole: it has no limit surface", option="faces",
                                   element="face", index=f)
        return faces_a, u_a, v_a

    def evaluate(self, faces, u, v, *, derivatives: int = 1) -> LimitEvaluation:
        """The limit surface at control faces ``faces`` and parameters ``u``, ``v`` (arrays broadcast together;
        see the module docstring for the parameterisation). ``derivatives``: 1 (points, first derivatives,
        normals) or 2 (also second derivatives). Hole faces are refused (:attr:`holes` says which)."""
        if derivatives not in (1, 2):
            raise SubdivInputError(f"derivatives must be 1 or 2, got {derivatives!r}", option="derivatives",
                                   value=derivatives)
        faces_a, u_a, v_a = self._queries(faces, u, v)
        n = len(faces_a)
        second = derivatives == 2
        if self.tree is None:
            return self._evaluate_linear(faces_a, u_a, v_a, second)
        if n == 0:
            empty = np.zeros((0, 3))
            return LimitEvaluation(empty, empty.copy(), empty.copy(), empty.copy(),
                                   *((empty.copy(),) * 3 if second else (None,) * 3), np.zeros(0, np.int32))
        queries = self._device_queries(faces_a, u_a, v_a)
        p, du, dv, nrm, duu, duv, dvv, patch = self._launch(queries, n, second, self._arrays()["points"])

        def host(x):
            return x.numpy().reshape(n, 3)

        return LimitEvaluation(host(p), host(du), host(dv), host(nrm),
                               host(duu) if second else None, host(duv) if second else None,
                               host(dvv) if second else None, patch.numpy())

    def _linear_weights(self, faces_a, u_a, v_a):
        corners, w, wu, wv, wuv = corner_weights(self, faces_a, np.stack([u_a, v_a], 1), derivatives=True)
        valid = corners >= 0
        return np.maximum(corners, 0), [x * valid for x in (w, wu, wv, wuv)]

    def _evaluate_linear(self, faces_a, u_a, v_a, second) -> LimitEvaluation:
        """A linear surface: weighted sums of the face's corner points (numpy; derivatives of the weights)."""
        corners, (w, wu, wv, wuv) = self._linear_weights(faces_a, u_a, v_a)
        P = np.asarray(self.mesh.points, dtype=np.float64)[np.asarray(self.mesh.face_vertex_indices,
                                                                       dtype=np.int64)[corners]]

        def mix(weights):
            return np.einsum("nm,nmk->nk", weights, P)

        p, du, dv = mix(w), mix(wu), mix(wv)
        nrm = np.cross(du, dv)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > 0)
        zero = np.zeros_like(p)
        return LimitEvaluation(p, du, dv, nrm, zero if second else None, mix(wuv) if second else None,
                               zero.copy() if second else None, np.full(len(p), -1, np.int32))

    def _device_queries(self, faces_a, u_a, v_a):
        dev = self.device

        def query(x, dtype):
            x = np.ascontiguousarray(x, dtype=dtype)
            return wp.array(x, device=dev, copy=not dev.is_cpu)

        return query(faces_a, np.int32), query(u_a, np.float64), query(v_a, np.float64)

    def _launch(self, queries, n: int, second: bool, points):
        """One run of the evaluation kernel over the tree's nodes and patches with control ``points`` (a Warp
        vec3d array: the tree's points, or three columns of data carried through the same tree)."""
        from .. import kernels

        dev = self.device
        a = self._arrays()

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
        wp.launch(kernels.limit_evaluate, dim=n,
                  inputs=[a["face_info"], *queries,
                          a["node_child"], a["node_patch"], a["patch_index"], a["patch_basis"], points,
                          int(self.tree.triangles),
                          int(second), p, du, dv, duu, duv, dvv, nrm, patch], device=dev)
        return p, du, dv, nrm, duu, duv, dvv, patch

    # ------------------------------------------------------------------------------------------ data
    def evaluate_data(self, data, faces, u, v, *, derivatives: int = 0) -> DataEvaluation:
        """The limit of per-control-vertex ``data`` ((V,) or (V, k): vertex primvars) at ``faces``, ``u``, ``v``.

        The data is subdivided with the subdivision of the positions (as ``Refiner.evaluate`` refines
        primvars): sector angles of the piecewise-smooth rules, flatness, and the tangent planes of the end caps
        come from the mesh's points, never from the data, so the result is a linear function of ``data`` (the
        positions' weights) and equals ``Refined.limit_points()`` of the refined data at refined vertices.
        ``data`` equal to the points gives :meth:`evaluate`'s points bit for bit, except where prescribed normals
        move the positions (normal control acts on positions only, as in ``refine``). The patch tree of the
        data is built on each call (the cost of constructing this surface); ``derivatives``: 0 or 1 (also
        ``du``, ``dv``)."""
        if derivatives not in (0, 1):
            raise SubdivInputError(f"derivatives must be 0 or 1, got {derivatives!r}", option="derivatives",
                                   value=derivatives)
        one_d = np.ndim(data) == 1
        arr = check_rows(data, self.mesh.num_vertices, "vertex data").astype(np.float64)
        faces_a, u_a, v_a = self._queries(faces, u, v)
        if self.tree is None:
            corners, (w, wu, wv, _) = self._linear_weights(faces_a, u_a, v_a)
            per = arr[np.asarray(self.mesh.face_vertex_indices, dtype=np.int64)[corners]]
            res = [np.einsum("nm,nmk->nk", x, per) for x in (w, wu, wv)]
            res = [x[:, 0] if one_d else x for x in res]
            return DataEvaluation(res[0], res[1] if derivatives else None, res[2] if derivatives else None)
        tree = limit_patches.build(self.mesh, self.options, self.depth, data=arr)
        if tree.num_nodes != self.tree.num_nodes or tree.num_patches != self.tree.num_patches:
            raise AssertionError("the data's patch tree differs from the surface's")
        return self._evaluate_columns(tree.points[:, 3:], faces_a, u_a, v_a, derivatives, one_d)

    def _evaluate_columns(self, columns, faces_a, u_a, v_a, derivatives, one_d) -> DataEvaluation:
        """Evaluate tree control values ``columns`` (num points, k), three columns per kernel run."""
        n, k = len(faces_a), columns.shape[1]
        values = np.zeros((n, k))
        du = np.zeros((n, k)) if derivatives else None
        dv = np.zeros((n, k)) if derivatives else None
        if n:
            queries = self._device_queries(faces_a, u_a, v_a)
            for c in range(0, k, 3):
                w = min(3, k - c)
                block = np.zeros((len(columns), 3))
                block[:, :w] = columns[:, c:c + w]
                pts = wp.array(block, dtype=wp.vec3d, device=self.device)
                p, pu, pv = self._launch(queries, n, False, pts)[:3]
                values[:, c:c + w] = p.numpy().reshape(n, 3)[:, :w]
                if derivatives:
                    du[:, c:c + w] = pu.numpy().reshape(n, 3)[:, :w]
                    dv[:, c:c + w] = pv.numpy().reshape(n, 3)[:, :w]

        def shape(x):
            return x[:, 0] if one_d and x is not None else x

        return DataEvaluation(shape(values), shape(du), shape(dv))

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
        reused. ``derivatives``: 0 or 1 (also ``du``, ``dv``)."""
        mode = FaceVaryingMode.parse(mode, "mode", "face-varying mode")
        if derivatives not in (0, 1):
            raise SubdivInputError(f"derivatives must be 0 or 1, got {derivatives!r}", option="derivatives",
                                   value=derivatives)
        if self.linear:  # a linear surface carries its face-varying data linearly too (as refine does)
            mode = FaceVaryingMode.ALL
        channel = self._face_varying_channel(indices, mode)
        one_d = np.ndim(values) == 1
        if np.ndim(values) in (1, 2) and len(values) < channel["num_values"]:
            raise SubdivInputError(f"face-varying indices refer to value {channel['num_values'] - 1} but only "
                                   f"{len(values)} values were given", option="values", element="data",
                                   value=len(values))
        vals = check_rows(values, channel["num_values"], "face-varying values", at_least=True).astype(np.float64)
        faces_a, u_a, v_a = self._queries(faces, u, v)
        if mode == FaceVaryingMode.ALL:
            corners, (w, wu, wv, _) = self._linear_weights(faces_a, u_a, v_a)
            per = vals[channel["indices"]][corners]
            res = [np.einsum("nm,nmk->nk", x, per) for x in (w, wu, wv)]
            res = [x[:, 0] if one_d else x for x in res]
            return DataEvaluation(res[0], res[1] if derivatives else None, res[2] if derivatives else None)
        surface = channel["surface"]
        f2, u2, v2, scale = self._to_value_faces(faces_a, u_a, v_a)
        with warnings.catch_warnings():  # disjoint value fans are expected (they become sharp values)
            warnings.simplefilter("ignore", NonManifoldWarning)
            res = surface.evaluate_data(vals[channel["source"]], f2, u2, v2, derivatives=derivatives)
        if derivatives:
            res.du = res.du * (scale if res.du.ndim == 1 else scale[:, None])
            res.dv = res.dv * (scale if res.dv.ndim == 1 else scale[:, None])
        if one_d:
            res.values = res.values[:, 0]
            if derivatives:
                res.du, res.dv = res.du[:, 0], res.dv[:, 0]
        return res

    def _to_value_faces(self, faces_a, u_a, v_a):
        """(face, u, v, derivative scale) on the value mesh: the same faces, except that a Loop polygon's value
        mesh holds its fan triangles (the kernel's tile choice: triangle k at u in [k, k + 1), nearest beyond)."""
        scale = np.ones(len(faces_a))
        fan = self.face_kind[faces_a] == FAN
        if not fan.any():
            return faces_a, u_a, v_a, scale
        counts = np.asarray(self.mesh.face_vertex_counts, dtype=np.int64)
        first = np.concatenate([[0], np.cumsum(counts - 2)[:-1]])
        tu = np.floor(u_a)
        tu = np.where(u_a - tu > 0.75, tu + 1, tu)
        k = np.where(fan, np.clip(tu.astype(np.int64), 0, np.maximum(counts[faces_a] - 3, 0)), 0)
        f2 = first[faces_a] + k
        u2 = np.where(fan, 2.0 * (u_a - k), u_a)
        v2 = np.where(fan, 2.0 * v_a, v_a)
        scale[fan] = 2.0
        return f2, u2, v2, scale

    def _face_varying_channel(self, indices, mode) -> dict:
        """The value mesh of a channel as a limit surface (cached for the last indices and mode)."""
        from ..tables import check_indices, value_mesh
        from ..topology import triangulate

        idx = check_indices(indices, len(self.mesh.face_vertex_indices))
        key = (mode, idx.tobytes())
        cache = self._fv_cache
        if cache is not None and cache["key"] == key:
            return cache
        o = self.options
        num_values = int(idx.max()) + 1 if len(idx) else 0
        cache = {"key": key, "indices": idx, "num_values": num_values}
        if mode != FaceVaryingMode.ALL:
            vm, source = value_mesh(self.mesh, idx, mode, o.boundary, o.scheme)
            verts = np.asarray(self.mesh.face_vertex_indices, dtype=np.int64)
            if len(vm.face_vertex_indices) != len(verts):  # Loop polygons: the value mesh is on fan triangles
                verts = triangulate(self.mesh.face_vertex_counts, verts)[1].reshape(-1).astype(np.int64)
            geometry = np.zeros((vm.num_vertices, 3))
            # the geometry of each value vertex is its vertex's: the end caps' tangent planes use it (the value
            # mesh's rules are OpenSubdiv's, which no geometry changes)
            geometry[np.asarray(vm.face_vertex_indices, dtype=np.int64)] = np.asarray(self.mesh.points)[verts]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NonManifoldWarning)
                mesh = Mesh(geometry, vm.face_vertex_counts, vm.face_vertex_indices,
                            creases=vm.creases if len(vm.creases) else None,
                            crease_sharpness=vm.crease_sharpness if len(vm.creases) else None,
                            corners=vm.corners if len(vm.corners) else None,
                            corner_sharpness=vm.corner_sharpness if len(vm.corners) else None,
                            holes=vm.holes if len(vm.holes) else None)
                options = o.replace(rules="opensubdiv", boundary="edge-only", flatness=None, loop_beta="loop")
                cache["surface"] = LimitSurface(mesh, depth=self.depth, options=options, device=self.device)
            cache["source"] = source
        self._fv_cache = cache
        return cache

    def tessellate(self, *, rate=None, edge_length=None, quads: bool = True):
        """A watertight tessellation of the limit surface (see :func:`warp_subdiv.limit.tessellate`)."""
        return tessellate(self, rate=rate, edge_length=edge_length, quads=quads)

    def __repr__(self) -> str:
        t = self.tree
        if t is None:
            return f"LimitSurface({self.num_faces} faces, {self.options.scheme.value}, linear)"
        return (f"LimitSurface({self.num_faces} faces, {self.options.scheme.value}, {self.options.rules.value}, "
                f"depth {self.depth}: {t.num_patches} patches, {int(np.sum(t.patch_kind == 1))} end caps)")

