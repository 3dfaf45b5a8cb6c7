"""How a control face is parameterised by the limit surface: directly (a quad, a Loop triangle), by its quad
sub-faces (a Catmull-Clark n-gon, as Bfr's QUAD_SUBFACES) or by its fan triangles (a Loop polygon)
(:class:`FaceParameterisation`, which also checks queries against it), and linear interpolation of face-corner
data inside it in those coordinates (varying primvars, bilinear meshes, linear surfaces).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import SubdivInputError
from ..mesh import Mesh, face_offsets_of
from ..options import Options, Scheme
from .patches import HOLE, PatchTree
from .results import DataEvaluation, LimitEvaluation, scale_free_normals

#: How a control face is parameterised (``LimitSurface.face_kind``).
DIRECT, SUBFACES, FAN = 0, 1, 2
#: The domains of faces parameterised directly: a quad's unit square, a Loop triangle's triangle (the other
#: kinds of domain are SUBFACES' tiles and FAN's triangles; ``FaceParameterisation.domain``).
SQUARE, TRIANGLE = 3, 4

#: How far, in the face's (u, v), a query may lie outside its face's domain and still be evaluated (on the
#: domain's side, where the evaluation clamps it: onto a square, toward a triangle's corner 0): round-off of
#: computed parameters, those computed in float32 included (Warp's mesh queries return float32 barycentrics,
#: whose u + v may exceed 1 by about 1e-7). A query farther outside is refused: clamping it would evaluate a
#: point it does not name.
DOMAIN_TOLERANCE = 1e-6


@dataclass
class FaceParameterisation:
    """Per control face: ``kind`` (DIRECT, SUBFACES or FAN), ``root`` (its first root node in the patch tree; 0
    without a tree), ``size`` (its number of corners), ``tiles`` (W = ceil(sqrt(size)): tiles per row of its
    sub-faces) and ``holes`` (whether it has no limit surface), int32 / bool arrays."""

    kind: np.ndarray
    root: np.ndarray
    size: np.ndarray
    tiles: np.ndarray
    holes: np.ndarray

    @classmethod
    def of(cls, mesh: Mesh, options: Options, tree: PatchTree | None) -> FaceParameterisation:
        """The faces of ``mesh`` under ``options``, rooted in ``tree`` (None for a linear surface: holes as the
        mesh says)."""
        counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
        F = len(counts)
        loop = options.scheme == Scheme.LOOP
        size = counts.astype(np.int32)
        tiles = np.ceil(np.sqrt(counts)).astype(np.int32)
        if tree is None:  # linear: faces as the parameterisation says, holes as the mesh says
            kind = np.where(counts == (3 if loop else 4), DIRECT, FAN if loop else SUBFACES).astype(np.int32)
            holes = np.zeros(F, bool)
            holes[np.asarray(mesh.holes, dtype=np.int64)] = True
            return cls(kind, np.zeros(F, np.int32), size, tiles, holes)
        roots = tree.root_offsets
        if loop:
            tris = counts - 2
            first = np.concatenate([[0], np.cumsum(tris)[:-1]]).astype(np.int64)
            kind = np.where(counts == 3, DIRECT, FAN)
            root = roots[first]
        else:
            kind = np.where(counts == 4, DIRECT, SUBFACES)
            root = roots[:F]
        # a control face is a hole when its (first) root is, or all its roots are
        holes = tree.node_patch[root] == HOLE
        holes |= _all_roots_holes(tree, kind, root, counts)
        return cls(kind.astype(np.int32), root.astype(np.int32), size, tiles, holes)

    def vertex_uv(self, faces, corners) -> np.ndarray:
        """(n, 2) parametric coordinates of corner ``corners[i]`` of face ``faces[i]`` (Bfr's GetVertexCoord)."""
        faces = np.asarray(faces, dtype=np.int64).reshape(-1)
        corners = np.asarray(corners, dtype=np.int64).reshape(-1)
        kind = self.kind[faces]
        out = np.zeros((len(faces), 2))
        quad = (kind == DIRECT) & (self.size[faces] == 4)
        tri = (kind == DIRECT) & (self.size[faces] == 3)
        out[quad] = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], float)[corners[quad]]
        out[tri] = np.array([(0, 0), (1, 0), (0, 1)], float)[corners[tri]]
        sub = kind == SUBFACES
        w = self.tiles[faces]
        out[sub, 0] = (corners % w)[sub]
        out[sub, 1] = (corners // w)[sub]
        fan = kind == FAN  # corner 0 at (0, 0); corner i < n - 1: triangle i - 1's second corner; the last corner:
        last = corners == self.size[faces] - 1  # triangle n - 3's third
        out[fan, 0] = np.where(last, corners - 2, np.where(corners == 0, 0.0, corners - 0.5))[fan]
        out[fan, 1] = np.where(last, 0.5, 0.0)[fan]
        return out

    def check_queries(self, faces, u, v) -> tuple:
        """(faces int64, u, v float64, shape) checked: integer faces inside the mesh, not holes, finite (u, v)
        inside the face's domain (up to ``DOMAIN_TOLERANCE``); broadcast together and flattened, ``shape`` their
        broadcast shape (the shape of the results), at least 1-D (three scalars are one query)."""
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
        shape = faces_a.shape if faces_a.ndim else (1,)
        faces_a = faces_a.reshape(-1).astype(np.int64)
        u_a = u_a.reshape(-1)
        v_a = v_a.reshape(-1)
        num_faces = len(self.kind)
        bad = np.flatnonzero((faces_a < 0) | (faces_a >= num_faces))
        if len(bad):
            raise SubdivInputError(f"face {faces_a[bad[0]]} (query {bad[0]}) is outside [0, {num_faces})",
                                   option="faces", element="face", index=int(bad[0]), value=int(faces_a[bad[0]]))
        bad = np.flatnonzero(~(np.isfinite(u_a) & np.isfinite(v_a)))
        if len(bad):
            raise SubdivInputError(f"(u, v) of query {bad[0]} is not finite", option="uv", index=int(bad[0]))
        hole = np.flatnonzero(self.holes[faces_a])
        if len(hole):
            f = int(faces_a[hole[0]])
            raise SubdivInputError(f"face {f} (query {hole[0]}) is a hole: it has no limit surface", option="faces",
                                   element="face", index=f)
        outside = np.flatnonzero(self.outside_domain(faces_a, u_a, v_a, DOMAIN_TOLERANCE))
        if len(outside):
            i = int(outside[0])
            f, u, v = int(faces_a[i]), float(u_a[i]), float(v_a[i])
            more = f" ({len(outside)} of {len(faces_a)} queries are outside)" if len(outside) > 1 else ""
            raise SubdivInputError(f"query {i} (face {f}, u={u!r}, v={v!r}) is outside the domain of its face, "
                                   f"{self.domain_of(f)}, by more than the round-off tolerance "
                                   f"{DOMAIN_TOLERANCE:g}{more}", option="uv", element="face", index=i,
                                   value=(f, u, v))
        return faces_a, u_a, v_a, shape

    def outside_domain(self, faces_a, u_a, v_a, tolerance: float) -> np.ndarray:
        """Whether each (face, u, v) lies farther than ``tolerance`` outside its face's domain: the unit square
        (a quad), the triangle u, v >= 0, u + v <= 1 (a Loop triangle), the sub-face tiles (a Catmull-Clark
        n-gon) or the fan triangles' tiles (a Loop polygon), each tile taken as the evaluation kernel picks it.
        Each kind of domain is tested on its own queries only (all of them, ungathered, in a mesh of one kind:
        the common case costs a few passes over u and v)."""
        domain, present = self.domain, self.domains_present
        if len(present) == 1:
            return _outside(int(present[0]), faces_a, u_a, v_a, self, tolerance)
        out = np.zeros(len(faces_a), bool)
        of_query = domain[faces_a]
        for d in present:
            rows = np.flatnonzero(of_query == d)
            out[rows] = _outside(int(d), faces_a[rows], u_a[rows], v_a[rows], self, tolerance)
        return out

    @cached_property
    def domain(self) -> np.ndarray:
        """Per face its kind of domain: ``SQUARE`` or ``TRIANGLE`` (a face parameterised directly), ``SUBFACES``
        or ``FAN``."""
        return np.where(self.kind == DIRECT, np.where(self.size == 4, SQUARE, TRIANGLE), self.kind)

    @cached_property
    def domains_present(self) -> np.ndarray:
        """The kinds of domain among the faces."""
        return np.unique(self.domain)

    def domain_of(self, face: int) -> str:
        """The domain of control face ``face`` in words (for messages)."""
        n, w = int(self.size[face]), int(self.tiles[face])
        if self.kind[face] == SUBFACES:
            return (f"a {n}-gon's {n} sub-face tiles [i mod {w}, i mod {w} + 1/2] x [i div {w}, i div {w} + 1/2], "
                    f"i = 0..{n - 1}")
        if self.kind[face] == FAN:
            return f"a {n}-gon's {n - 2} fan triangles u - k, v >= 0, (u - k) + v <= 1/2, k = 0..{n - 3}"
        return "the quad's unit square [0, 1]^2" if n == 4 else "the triangle's u, v >= 0, u + v <= 1"

    def onto_domain(self, faces_a, u_a, v_a) -> tuple:
        """(u, v) of checked queries moved onto their faces' domains as the evaluation kernel clamps them (onto
        the tile's square, or toward the triangle's origin); queries inside are returned unchanged, bit for
        bit. For the evaluations on the host (linear surfaces) and the fan triangles of face-varying data."""
        outside = self.outside_domain(faces_a, u_a, v_a, 0.0)
        if not outside.any():
            return u_a, v_a
        kind, size = self.kind[faces_a], self.size[faces_a]
        tiled = kind != DIRECT
        tu = np.where(tiled, kernel_tile(u_a), 0.0)
        tv = np.where(kind == SUBFACES, kernel_tile(v_a), 0.0)
        scale = np.where(tiled, 2.0, 1.0)  # a tile's own coordinates
        s, t = np.clip(scale * (u_a - tu), 0, 1), np.clip(scale * (v_a - tv), 0, 1)
        triangle = (kind == FAN) | ((kind == DIRECT) & (size != 4))
        total = np.where(triangle & (s + t > 1), s + t, 1.0)
        s, t = s / total, t / total
        return np.where(outside, tu + s / scale, u_a), np.where(outside, tv + t / scale, v_a)


def _outside(domain: int, faces_a, u, v, faces: FaceParameterisation, tolerance: float) -> np.ndarray:
    """Whether each (u, v) of faces ``faces_a``, all of kind of domain ``domain``, lies farther than
    ``tolerance`` outside it (see :meth:`FaceParameterisation.outside_domain`)."""
    if domain == SQUARE:
        return (np.minimum(u, v) < -tolerance) | (np.maximum(u, v) > 1 + tolerance)
    if domain == TRIANGLE:
        return (np.minimum(u, v) < -tolerance) | (u + v > 1 + tolerance)
    size = faces.size[faces_a]
    tu = kernel_tile(u)
    s = u - tu  # inside the tile: [0, 1/2]
    if domain == FAN:
        return (tu < 0) | (tu > size - 3) | (np.minimum(s, v) < -tolerance) | (s + v > 0.5 + tolerance)
    tv = kernel_tile(v)
    t = v - tv
    w = faces.tiles[faces_a]
    no_tile = (tu < 0) | (tu >= w) | (tv < 0) | (tv * w + tu >= size)
    return no_tile | (np.minimum(s, t) < -tolerance) | (np.maximum(s, t) > 0.5 + tolerance)


def kernel_tile(x: np.ndarray) -> np.ndarray:
    """The tile coordinate the evaluation kernel takes for a face coordinate ``x`` (float64): its integer part,
    or the next integer when the fraction is above 3/4 (a point just below a tile's lower side belongs to it)."""
    tile = np.floor(x)
    return np.where(x - tile > 0.75, tile + 1, tile)


def _all_roots_holes(tree: PatchTree, kind, root, counts) -> np.ndarray:
    """Whether every root of each sub-face or fan face is a hole."""
    out = np.zeros(len(kind), bool)
    multi = np.flatnonzero(kind != DIRECT)
    patch = tree.node_patch
    for f in multi:
        n = counts[f] if kind[f] == SUBFACES else counts[f] - 2
        out[f] = bool(np.all(patch[root[f]:root[f] + n] == HOLE))
    return out


def corner_weights(surface, faces, uv, *, derivatives: bool = False) -> tuple:
    """Linear interpolation inside control faces (refine's varying primvars, bilinear meshes): (corners (n, m)
    int64 into the face-vertex list, -1 padded; weights (n, m)) such that a value at (face, u, v) is the
    weighted sum of the face's corner values. A quad: bilinear; a Loop triangle: barycentric; a Catmull-Clark
    n-gon: bilinear in the sub-face (corner, edge middles, centre = mean of the corners); a Loop polygon:
    barycentric in its fan triangle (v0, v_k+1, v_k+2). ``derivatives``: also the weights' derivatives
    d/du, d/dv and d2/dudv (each (n, m)): (corners, weights, du, dv, duv)."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    counts = np.asarray(surface.mesh.face_vertex_counts, dtype=np.int64)
    offsets = face_offsets_of(counts)
    n = counts[faces]
    m = max(int(n.max()), 4) if len(n) else 4  # room for a quad's four weights in any case
    W = np.zeros((4, len(faces), m))  # value, d/du, d/dv, d2/dudv
    kind = surface.face_kind[faces]
    u, v = uv[:, 0], uv[:, 1]
    rows = np.arange(len(faces))
    one, zero = np.ones(len(faces)), np.zeros(len(faces))
    quad = (kind == DIRECT) & (n == 4)
    for c, terms in enumerate(([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], [v - 1, 1 - v, v, -v],
                               [u - 1, -u, u, 1 - u], [one, -one, one, -one])):
        for j in range(4):
            W[c, quad, j] = terms[j][quad]
    tri = (kind == DIRECT) & (n == 3)
    for c, terms in enumerate(([1 - u - v, u, v], [-one, one, zero], [-one, zero, one], [zero, zero, zero])):
        for j in range(3):
            W[c, tri, j] = terms[j][tri]
    sub = kind == SUBFACES
    if sub.any():
        w = surface.face_tiles[faces].astype(np.int64)
        tx, ty = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        i = np.clip(ty * w + tx, 0, n - 1)
        s = np.clip(2 * (u - tx), 0, 1)
        t = np.clip(2 * (v - ty), 0, 1)
        # (w00, w10, w11, w01) of the sub-face's own square and their derivatives (ds/du = dt/dv = 2)
        parts = ([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t],
                 [2 * (t - 1), 2 * (1 - t), 2 * t, -2 * t], [2 * (s - 1), -2 * s, 2 * s, 2 * (1 - s)],
                 [4 * one, -4 * one, 4 * one, -4 * one])
        r = rows[sub]
        for c, (w00, w10, w11, w01) in enumerate(parts):
            Wn = np.zeros((len(faces), m))
            Wn[r] += (w11 / np.maximum(n, 1))[sub][:, None] * (np.arange(m)[None] < n[sub][:, None])
            np.add.at(Wn, (r, i[sub]), (w00 + 0.5 * w10 + 0.5 * w01)[sub])
            np.add.at(Wn, (r, ((i + 1) % n)[sub]), (0.5 * w10)[sub])
            np.add.at(Wn, (r, ((i - 1) % n)[sub]), (0.5 * w01)[sub])
            W[c, sub] = Wn[sub]
    fan = kind == FAN
    if fan.any():
        k = np.clip(np.floor(u).astype(np.int64), 0, n - 3)
        s, t = 2 * (u - k), 2 * v
        r = rows[fan]
        for c, (a, b, d) in enumerate(((1 - s - t, s, t), (-2 * one, 2 * one, zero), (-2 * one, zero, 2 * one))):
            np.add.at(W[c], (r, np.zeros(len(r), np.int64)), a[fan])
            np.add.at(W[c], (r, (k + 1)[fan]), b[fan])
            np.add.at(W[c], (r, (k + 2)[fan]), d[fan])
    j = np.arange(m)[None]
    corners = np.where(j < n[:, None], offsets[faces][:, None] + j, -1)
    if derivatives:
        return corners, W[0], W[1], W[2], W[3]
    return corners, W[0]


def _linear_weights(surface, faces_a, u_a, v_a):
    """corner_weights and its derivatives at checked queries (round-off outside a face moved onto it, as the
    kernel evaluates it), padded corners at 0 with zero weights."""
    u_a, v_a = surface._parameterisation.onto_domain(faces_a, u_a, v_a)
    corners, w, wu, wv, wuv = corner_weights(surface, faces_a, np.stack([u_a, v_a], 1), derivatives=True)
    valid = corners >= 0
    return np.maximum(corners, 0), [x * valid for x in (w, wu, wv, wuv)]


def linear_evaluation(surface, faces_a, u_a, v_a, second: bool) -> LimitEvaluation:
    """A linear surface at checked queries: weighted sums of the face's corner points (numpy; derivatives of the
    weights)."""
    corners, (w, wu, wv, wuv) = _linear_weights(surface, faces_a, u_a, v_a)
    P = np.asarray(surface.mesh.points, dtype=np.float64)[np.asarray(surface.mesh.face_vertex_indices,
                                                                      dtype=np.int64)[corners]]

    def mix(weights):
        return np.einsum("nm,nmk->nk", weights, P)

    p, du, dv = mix(w), mix(wu), mix(wv)
    with np.errstate(over="ignore", invalid="ignore"):  # points of extreme scale: redone scale-free below
        nrm = np.cross(du, dv)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > 0)
    nrm = scale_free_normals(du, dv, nrm)
    zero = np.zeros_like(p)
    return LimitEvaluation(p, du, dv, nrm, zero if second else None, mix(wuv) if second else None,
                           zero.copy() if second else None, np.full(len(p), -1, np.int32))


def linear_data(surface, corner_values, faces_a, u_a, v_a, derivatives: int, one_d: bool) -> DataEvaluation:
    """Per-face-corner values (C, k) interpolated linearly inside the faces at checked queries (and their
    derivatives with ``derivatives``); ``one_d``: 1-D results."""
    corners, (w, wu, wv, _) = _linear_weights(surface, faces_a, u_a, v_a)
    per = corner_values[corners]
    res = [np.einsum("nm,nmk->nk", x, per) for x in (w, wu, wv)]
    res = [x[:, 0] if one_d else x for x in res]
    return DataEvaluation(res[0], res[1] if derivatives else None, res[2] if derivatives else None)
