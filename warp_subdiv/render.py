"""Shaded previews of USD (or OBJ) meshes: Warp ray casting (``wp.Mesh`` + ``mesh_query_ray``) on the CPU or
CUDA, written as PNG with the standard library. No OpenGL.

Every visible ``UsdGeom.Mesh`` a renderer draws (of the default purpose, and of the render purpose or, when
asked, the proxy purpose: :data:`PURPOSES`) is fan-triangulated into one triangle soup in world space, with
per-corner colours (a bound UsdPreviewSurface ``diffuseColor``, per face subset too, else ``displayColor``, else
grey) and per-corner normals (authored ``normals``, else face normals averaged over the faces around a vertex that turn
less than 40 degrees, so creases stay sharp). The camera is a ``UsdGeom.Camera`` or frames the meshes from
an azimuth and elevation around the stage's up axis. Optionally the control meshes of another file (the
input of a refinement) are drawn on top as lines, dark where visible and faint where hidden.

Subdivision meshes refined for the preview (``levels``) get their refiner from
:func:`warp_subdiv.usd.make_refiner`, as ``warp-subdiv refine`` does, so a preview shows what a bake makes.
"""
from __future__ import annotations

import math
import os
import struct
import tempfile
import warnings
import zlib
from dataclasses import dataclass

import numpy as np

from .errors import SubdivInputError
from .mesh import face_offsets_of, next_corner_of
from .io.files import publish
from .io.usd_write import make_folders, remove_folders

BACKGROUND_TOP = np.array([0.93, 0.94, 0.96])
BACKGROUND_BOTTOM = np.array([0.78, 0.80, 0.84])
DEFAULT_COLOR = (0.7, 0.7, 0.7)
SMOOTH_ANGLE = 40.0  # degrees
#: The purposes a preview chooses between, as a renderer does (UsdGeom): geometry of the "default" purpose is
#: always drawn, with that of "render" purpose (final frames: what a bake refines) or of "proxy" purpose (the
#: light stand-ins of interactive views), never both, since a proxy stands in the place of its render geometry
#: and would hide it; "guide" geometry (rigs, helpers) is drawn by no renderer.
PURPOSES = ("render", "proxy")


class OptionWarning(UserWarning):
    """A warning about an option, named by its keyword in the message and in ``option`` (the command line
    names it by its flag)."""

    def __init__(self, message: str, option: str | None = None):
        super().__init__(message)
        self.option = option


@dataclass
class Soup:
    """Triangles in world space: corners (3T, 3), per-corner normals and colours (3T, 3)."""

    corners: np.ndarray
    normals: np.ndarray
    colors: np.ndarray

    @staticmethod
    def join(parts) -> "Soup":
        parts = list(parts)
        if not parts:
            return Soup(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
        return Soup(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("corners", "normals", "colors")))


@dataclass
class Camera:
    eye: np.ndarray
    forward: np.ndarray  # unit
    right: np.ndarray  # unit
    up: np.ndarray  # unit
    tan_x: float  # half-width of the image plane at distance 1 (perspective) or in scene units (ortho)
    tan_y: float
    ortho: bool = False

    def project(self, pts: np.ndarray, width: int, height: int):
        """World points -> (pixel x, pixel y, distance along the ray); NaN behind the camera."""
        v = pts - self.eye
        z = v @ self.forward
        sx = v @ self.right
        sy = v @ self.up
        if self.ortho:
            x, y, dist = sx / self.tan_x, sy / self.tan_y, z
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                x, y = sx / (z * self.tan_x), sy / (z * self.tan_y)
            dist = np.linalg.norm(v, axis=1)
            bad = z <= 1e-9
            x, y = np.where(bad, np.nan, x), np.where(bad, np.nan, y)
        return (x + 1.0) * 0.5 * width, (1.0 - y) * 0.5 * height, dist


def parse_resolution(text: str):
    """An image resolution: 'WIDTHxHEIGHT' -> (width, height) in pixels, each 1 to 8192."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise SubdivInputError(f"size {text!r}: give WIDTHxHEIGHT, e.g. 800x600", option="size", value=text) from None
    if not (1 <= w <= 8192 and 1 <= h <= 8192):
        raise SubdivInputError(f"size {text!r}: width and height must be 1 to 8192", option="size", value=text)
    return w, h


def check_view(view):
    """(azimuth, elevation) in degrees; the elevation strictly between -90 and 90."""
    az, el = (float(v) for v in view)
    if not (-90.0 < el < 90.0) or not math.isfinite(az):
        raise SubdivInputError(f"view {az:g} {el:g}: the elevation must lie strictly between -90 and 90 degrees",
                               option="view", value=(az, el))
    return az, el


# -- geometry ------------------------------------------------------------------------------------------

def face_normals(points, counts, indices) -> np.ndarray:
    """Unit face normals of polygons (Newell's method), (F, 3); zero for degenerate faces."""
    counts = np.asarray(counts, dtype=np.int64)
    p = points[indices]
    corner_face = np.repeat(np.arange(len(counts)), counts)
    q = p[next_corner_of(counts, face_offsets_of(counts))]
    terms = np.stack([(p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2]), (p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0]),
                      (p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])], axis=1)
    n = np.zeros((len(counts), 3))
    np.add.at(n, corner_face, terms)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def corner_normals(points, counts, indices, angle: float = SMOOTH_ANGLE) -> np.ndarray:
    """Per-corner normals: the face normals around the corner's vertex that turn less than ``angle`` from the
    corner's own face, averaged (weighted by the faces' corner angles would be nicer; equal weights suffice)."""
    counts = np.asarray(counts, dtype=np.int64)
    idx = np.asarray(indices, dtype=np.int64)
    fn = face_normals(points, counts, idx)
    corner_face = np.repeat(np.arange(len(counts)), counts)
    if len(idx) > 3_000_000:  # large meshes: plain smooth normals
        vn = np.zeros((len(points), 3))
        np.add.at(vn, idx, fn[corner_face])
        out = vn[idx]
    else:
        order = np.argsort(idx, kind="stable")
        vstart = np.searchsorted(idx[order], idx, side="left")
        vcount = np.bincount(idx, minlength=len(points))[idx]
        pair_corner = np.repeat(np.arange(len(idx)), vcount)
        pair_other = order[np.repeat(vstart, vcount) + (np.arange(len(pair_corner))
                                                          - np.repeat(np.cumsum(vcount) - vcount, vcount))]
        own = fn[corner_face[pair_corner]]
        other = fn[corner_face[pair_other]]
        keep = np.sum(own * other, axis=1) >= math.cos(math.radians(angle))
        out = np.zeros((len(idx), 3))
        np.add.at(out, pair_corner[keep], other[keep])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    fallback = fn[corner_face]
    return np.where(length > 1e-12, out / np.maximum(length, 1e-300), fallback)


def _world(points: np.ndarray, matrix) -> np.ndarray:
    m = np.array(matrix, dtype=np.float64).reshape(4, 4)  # row-vector convention: p' = p M
    return points @ m[:3, :3] + m[3, :3]


def _world_normals(normals: np.ndarray, matrix) -> np.ndarray:
    m = np.array(matrix, dtype=np.float64).reshape(4, 4)[:3, :3]
    n = normals @ np.linalg.inv(m).T
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _per_corner(values, interpolation, counts, indices):
    """Primvar values (n, k) -> per face-vertex corner (C, k), by interpolation; None if the sizes disagree."""
    values = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    n_corners = len(indices)
    if interpolation == "constant" and len(values) >= 1:
        return np.repeat(values[:1], n_corners, axis=0)
    if interpolation == "uniform" and len(values) == len(counts):
        return np.repeat(values, counts, axis=0)
    if interpolation in ("vertex", "varying") and len(values) > int(np.max(indices, initial=-1)):
        return values[indices]
    if interpolation == "faceVarying" and len(values) == n_corners:
        return values
    return None


def _material_color(material):
    """diffuseColor of a material's UsdPreviewSurface (when it is a constant), else None."""
    if not material:
        return None
    shader = material.ComputeSurfaceSource()[0] if material.GetSurfaceOutput() else None
    if not shader:
        return None
    inp = shader.GetInput("diffuseColor")
    if not inp:
        return None
    value = inp.Get()
    return None if value is None else np.array(value, dtype=np.float64)


def _mesh_colors(prim, counts, indices, time) -> np.ndarray:
    """Per-corner colours in [0, 1]: the bound material's diffuseColor (per face subset too), else
    displayColor, else grey."""
    from pxr import UsdGeom, UsdShade

    n = len(indices)
    colors = None
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if pv and pv.HasValue():
        values = pv.ComputeFlattened(time)
        if values is not None and len(values):
            colors = _per_corner(np.asarray(values), pv.GetInterpolation(), counts, indices)
    if colors is None:
        colors = np.tile(DEFAULT_COLOR, (n, 1))
    binding = UsdShade.MaterialBindingAPI(prim)
    whole = _material_color(binding.ComputeBoundMaterial()[0])
    if whole is not None:
        colors[:] = whole
    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    for subset in binding.GetMaterialBindSubsets():
        color = _material_color(UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0])
        ids = subset.GetIndicesAttr().Get(time)
        if color is None or ids is None:
            continue
        member = np.zeros(len(counts), dtype=bool)
        ids = np.asarray(ids, dtype=np.int64)
        member[ids[(ids >= 0) & (ids < len(counts))]] = True
        colors[member[face_of_corner]] = color
    return np.clip(colors, 0.0, 1.0)


def _soup(points, counts, indices, normals_per_corner, colors_per_corner) -> Soup:
    from .topology import triangulate

    _, corners, _ = triangulate(counts, np.arange(len(indices)))  # fan triangles as corner ids
    corners = corners.astype(np.int64)
    return Soup(points[np.asarray(indices, dtype=np.int64)[corners]], normals_per_corner[corners],
                colors_per_corner[corners])


def drawn_purposes(purpose: str = "render") -> tuple:
    """The computed purposes (``UsdGeom.Imageable.ComputePurpose``) of the geometry a renderer draws when it
    draws ``purpose`` (one of :data:`PURPOSES`): "default" and ``purpose``."""
    if purpose not in PURPOSES:
        raise SubdivInputError(f"purpose {purpose!r}: give {' or '.join(map(repr, PURPOSES))}", option="purpose",
                               value=purpose)
    return "default", purpose


def mesh_placements(stage, prims=None, time=None, where: str = "render", purpose: str = "render"):
    """(mesh prim, local-to-world matrix) of every mesh at or under ``prims`` as a renderer draws it: meshes in
    place (inside scene-graph instances too, through their instance proxies), except the prototypes of
    PointInstancers, which are drawn once per instance instead: at the instance's position, orientation and
    scale (``ComputeInstanceTransformsAtTime``, the prototype root's own transform included) in the
    instancer's space, without the instances its ``invisibleIds`` / ``inactiveIds`` mask. Only meshes (and
    instancers) whose computed purpose, inherited as UsdGeom defines it, is among :func:`drawn_purposes` of
    ``purpose``."""
    return _placements(stage, prims, time, where, drawn_purposes(purpose))


def _placements(stage, prims, time, where: str, purposes) -> list:
    """:func:`mesh_placements` of the meshes whose computed purpose is among ``purposes``."""
    from pxr import Gf, Usd, UsdGeom

    from .io.usd_stage import check_roots

    def drawn(prim) -> bool:
        return UsdGeom.Imageable(prim).ComputePurpose() in purposes

    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    roots = check_roots(stage, prims, where) or [stage.GetPseudoRoot().GetPath()]
    cache = UsdGeom.XformCache(t)
    placed, instancers, proto_roots, seen = [], [], set(), set()
    for root in roots:
        for prim in Usd.PrimRange(stage.GetPrimAtPath(root), Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
            if prim.GetPath() in seen:
                continue
            seen.add(prim.GetPath())
            if prim.IsA(UsdGeom.PointInstancer):
                instancers.append(prim)
                proto_roots.update(UsdGeom.PointInstancer(prim).GetPrototypesRel().GetForwardedTargets())
            elif prim.IsA(UsdGeom.Mesh):
                placed.append(prim)
    out = [(prim, cache.GetLocalToWorldTransform(prim)) for prim in placed
           if not any(prim.GetPath().HasPrefix(p) for p in proto_roots) and drawn(prim)]
    for prim in instancers:
        if any(prim.GetPath().HasPrefix(p) for p in proto_roots):
            continue  # a PointInstancer inside another's prototype: not drawn on its own
        if not drawn(prim):
            continue
        pi = UsdGeom.PointInstancer(prim)
        protos = pi.GetPrototypesRel().GetForwardedTargets()
        ids = pi.GetProtoIndicesAttr().Get(t)
        if ids is None or not protos:
            continue
        xforms = pi.ComputeInstanceTransformsAtTime(t, t, UsdGeom.PointInstancer.IncludeProtoXform,
                                                    UsdGeom.PointInstancer.IgnoreMask)
        mask = pi.ComputeMaskAtTime(t)
        to_world = cache.GetLocalToWorldTransform(prim)
        for k, path in enumerate(protos):
            proto = stage.GetPrimAtPath(path)
            if not proto:
                continue
            members = []  # the prototype's meshes, relative to the prototype root (its own transform excluded)
            for mesh in Usd.PrimRange(proto, Usd.TraverseInstanceProxies(Usd.PrimIsActive & Usd.PrimIsLoaded)):
                if mesh.IsA(UsdGeom.Mesh) and drawn(mesh):
                    rel = (Gf.Matrix4d(1.0) if mesh == proto
                           else cache.ComputeRelativeTransform(mesh, proto)[0])
                    members.append((mesh, rel))
            for i, index in enumerate(ids):
                if index != k or i >= len(xforms) or (mask and not mask[i]):
                    continue
                for mesh, rel in members:
                    out.append((mesh, rel * xforms[i] * to_world))
    return out


def stage_soup(stage, prims=None, time=None, levels: int | None = None, device=None,
               purpose: str = "render") -> Soup:
    """Every visible mesh at or under ``prims`` of the default purpose or ``purpose`` as a world-space triangle
    soup (subdivision meshes refined first, each distinct mesh once per level: instances of one prototype share
    it), PointInstancer prototypes once per instance (:func:`mesh_placements`). ``levels``: None draws the
    meshes as stored; a level refines each subdivision mesh to the level ``refine`` gives it
    (:func:`mesh_level`: its ``subdiv:levels`` or its nearest ancestor's, else ``levels``)."""
    from pxr import Usd, UsdGeom

    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    parts = []
    made: dict = {}  # a mesh's local-space soup pieces, by prim (instance proxies: by their prototype's prim)
    for prim, matrix in mesh_placements(stage, prims, time, where="render", purpose=purpose):
        if UsdGeom.Imageable(prim).ComputeVisibility(t) == UsdGeom.Tokens.invisible:
            continue
        level = 0 if levels is None else mesh_level(prim, levels)
        key = (str(prim.GetPrimInPrototype().GetPath() if prim.IsInstanceProxy() else prim.GetPath()), level)
        if key not in made:
            made[key] = _local_mesh(prim, t, level, device)
        local = made[key]
        if local is None:
            continue
        pts, counts, indices, normals, colors = local
        world = _world(pts, matrix)
        normals = corner_normals(world, counts, indices) if normals is None else _world_normals(normals, matrix)
        parts.append(_soup(world, counts, indices, normals, colors))
    return Soup.join(parts)


def mesh_level(prim, levels: int) -> int:
    """The level ``refine`` gives mesh ``prim`` with ``--levels levels``: the ``subdiv:levels`` of the mesh or
    its nearest ancestor (through an instance proxy to the instance and above), else ``levels``
    (:func:`~warp_subdiv.usd.levels.nearest_level`), so that a preview shows what a bake writes."""
    from .usd.levels import nearest_level

    found = nearest_level(prim)
    return levels if found is None else found[0]


def _local_mesh(prim, t, levels, device):
    """(points, counts, indices, per-corner normals or None, per-corner colours) of a mesh in its own space,
    refined ``levels`` times when it is a subdivision mesh (as ``warp-subdiv refine`` refines it); None when
    it has nothing to draw."""
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    pts = mesh.GetPointsAttr().Get(t)
    counts = mesh.GetFaceVertexCountsAttr().Get(t)
    indices = mesh.GetFaceVertexIndicesAttr().Get(t)
    if pts is None or counts is None or indices is None or len(counts) == 0:
        return None
    from .io.usd_stage import DEFAULT
    from .usd.skinning import posed_points

    posed = posed_points(prim, DEFAULT if t.IsDefault() else t.GetValue())  # a skinned mesh: as UsdSkel poses it
    pts = np.asarray(pts if posed is None else posed, dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    valid, why = UsdGeom.Mesh.ValidateTopology(mesh.GetFaceVertexIndicesAttr().Get(t),
                                               mesh.GetFaceVertexCountsAttr().Get(t), len(pts))
    if not valid or np.any(counts < 3):
        raise SubdivInputError(f"{prim.GetPath()}: cannot render: {why or 'a face has fewer than 3 vertices'}")
    try:
        colors = _mesh_colors(prim, counts, indices, t)
    except Exception:  # noqa: BLE001 (a preview keeps going in grey)
        colors = np.tile(DEFAULT_COLOR, (len(indices), 1))
    normals = None
    scheme = mesh.GetSubdivisionSchemeAttr().Get()
    if levels > 0 and scheme in ("catmullClark", "loop", "bilinear"):
        # refine for the preview; each refined face takes the mean colour of its control face
        face_color = np.add.reduceat(colors, np.concatenate([[0], np.cumsum(counts)[:-1]])) / counts[:, None]
        pts, counts, indices, parent = _refined(prim, t, levels, device)
        colors = np.repeat(face_color[parent], counts, axis=0)
    elif scheme == "none":
        normals = _authored_normals(mesh, counts, indices, t)
    return pts, counts, indices, normals, colors


def _authored_normals(mesh, counts, indices, t):
    """Per-corner normals of a polygonal mesh from its primvars:normals or normals, else None."""
    from pxr import UsdGeom

    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("normals")
    if pv and pv.HasValue():
        values, interp = pv.ComputeFlattened(t), pv.GetInterpolation()
    else:
        attr = mesh.GetNormalsAttr()
        values, interp = attr.Get(t), mesh.GetNormalsInterpolation()
    if values is None or len(values) == 0:
        return None
    return _per_corner(np.asarray(values), interp, counts, indices)


def _refined(prim, t, levels, device):
    """(points, counts, indices, control face of each refined face) of a subdivision mesh at time ``t``,
    refined as ``warp-subdiv refine`` refines it (same options, same bilinear handling)."""
    from .tables import FaceMap
    from .usd import linear_vertex_data, make_refiner
    from .io.usd_read import read_mesh
    from .io.usd_stage import DEFAULT

    from .usd.skinning import Skinning

    sp = Skinning(pose_instances=True).attach(read_mesh(prim))  # a skinned mesh: its points as UsdSkel poses them
    time = DEFAULT if t.IsDefault() else t.GetValue()
    pts = sp.points_at(time)
    sp = sp.with_topology(sp.topology_index(time))  # the control mesh at that time (topology may change)
    refiner = make_refiner(sp, levels, device=device)
    counts, indices = refiner.topology()
    fmap = FaceMap(sp.mesh, levels, sp.scheme, refiner.options.boundary.value, hierarchy=refiner.hierarchy)
    if sp.scheme == "bilinear":
        refined = linear_vertex_data(refiner, fmap, pts, indices)
    else:
        refined = refiner.evaluate(pts)
    return refined.astype(np.float64), counts.astype(np.int64), indices.astype(np.int64), fmap.parent


def first_points_sample(stage, prims=None, purpose: str = "render"):
    """The earliest first time sample of the meshes drawn (at or under ``prims``, of the default purpose or
    ``purpose``) whose points have no default value (only time samples), or None: what to render when the
    stage has no start time and none is asked."""
    from pxr import Usd, UsdGeom

    first = []
    for prim, _ in mesh_placements(stage, prims, where="render", purpose=purpose):
        attr = UsdGeom.Mesh(prim).GetPointsAttr()
        if attr.GetNumTimeSamples() and attr.Get(Usd.TimeCode.Default()) is None:
            first.append(attr.GetTimeSamples()[0])
    return min(first) if first else None


def cage_edges(stage, time=None, prims=None, purpose: str = "render") -> np.ndarray:
    """World-space control-mesh edges of the subdivision meshes of ``stage`` drawn for ``purpose`` (those of
    the default purpose or ``purpose``, as :func:`stage_soup` draws them): (E, 2, 3)."""
    from pxr import Usd, UsdGeom

    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    out = []
    for prim, matrix in mesh_placements(stage, prims, time, where="cage", purpose=purpose):
        mesh = UsdGeom.Mesh(prim)
        if mesh.GetSubdivisionSchemeAttr().Get() == "none":
            continue
        pts, counts, indices = (mesh.GetPointsAttr().Get(t), mesh.GetFaceVertexCountsAttr().Get(t),
                                mesh.GetFaceVertexIndicesAttr().Get(t))
        if pts is None or counts is None or indices is None:
            continue
        pts = _world(np.asarray(pts, dtype=np.float64).reshape(-1, 3), matrix)
        counts = np.asarray(counts, dtype=np.int64)
        idx = np.asarray(indices, dtype=np.int64)
        if len(idx) == 0 or idx.max() >= len(pts):
            continue
        nxt = next_corner_of(counts, face_offsets_of(counts))
        pairs = np.unique(np.sort(np.stack([idx, idx[nxt]], axis=1), axis=1), axis=0)
        out.append(pts[pairs])
    return np.concatenate(out) if out else np.zeros((0, 2, 3))


# -- camera --------------------------------------------------------------------------------------------

def framing_camera(points, view, aspect: float, up_axis: str = "Y", fov_y: float = 30.0, fill: float = 0.9) -> Camera:
    """A perspective camera looking at ``points`` from azimuth/elevation ``view`` (degrees), placed so that
    they fill ``fill`` of the image."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    az, el = (math.radians(v) for v in view)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    if up_axis == "Z":
        world_up = np.array([0.0, 0.0, 1.0])
        back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    else:
        world_up = np.array([0.0, 1.0, 0.0])
        back = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    tan_y = math.tan(math.radians(fov_y) / 2)
    tan_x = tan_y * aspect
    forward = -back
    right = np.cross(forward, world_up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    if len(pts) > 20000:
        pts = pts[np.linspace(0, len(pts) - 1, 20000).astype(np.int64)]
    rel = pts - center
    u, v = rel @ right, rel @ up  # centre the points as a parallel projection would see them
    center = center + right * 0.5 * (u.max() + u.min()) + up * 0.5 * (v.max() + v.min())
    far = radius / math.sin(math.atan(min(tan_x, tan_y)))  # the bounding sphere fits from here

    def reach(dist, c):
        """How far the points reach from the image centre (1 = the border) with the eye at distance dist."""
        x, y, _ = Camera(c + back * dist, forward, right, up, tan_x, tan_y).project(pts, 2, 2)
        r = float(np.max(np.maximum(np.abs(x - 1.0), np.abs(1.0 - y))))
        return r if math.isfinite(r) else math.inf

    for step in range(3):  # fit the distance by bisection (reach falls as the eye moves back), re-centre, again
        near = float(-np.min((pts - center) @ forward)) + 0.05 * radius  # every point in front of the eye
        lo, hi = max(near, 1e-6), max(far + radius, near)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if reach(mid, center) > fill else (lo, mid)
        dist = hi
        if step == 2:
            break
        x, y, _ = Camera(center + back * dist, forward, right, up, tan_x, tan_y).project(pts, 2, 2)
        mx, my = 0.5 * ((x - 1.0).max() + (x - 1.0).min()), 0.5 * ((1.0 - y).max() + (1.0 - y).min())
        center = center + (right * mx * tan_x + up * my * tan_y) * dist
    return Camera(center + back * dist, forward, right, up, tan_x, tan_y)


def usd_camera(stage, path: str, time, aspect: float) -> Camera:
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(path) if path.startswith("/") else None
    if not prim or not prim.IsA(UsdGeom.Camera):
        raise SubdivInputError(f"camera {path}: no UsdGeom.Camera at that path", option="camera", value=path)
    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    cam = UsdGeom.Camera(prim).GetCamera(t)
    m = np.array(cam.transform, dtype=np.float64).reshape(4, 4)
    eye = m[3, :3]
    right, up, back = (m[i, :3] / np.linalg.norm(m[i, :3]) for i in range(3))
    hap = cam.horizontalAperture
    if cam.projection == cam.Orthographic:
        half_w = 0.5 * hap * 0.1  # apertures are in tenths of a scene unit
        return Camera(eye, -back, right, up, half_w, half_w / aspect, ortho=True)
    tan_x = 0.5 * hap / cam.focalLength
    return Camera(eye, -back, right, up, tan_x, tan_x / aspect)


# -- rendering -----------------------------------------------------------------------------------------

def render_soup(soup: Soup, camera: Camera, width: int, height: int, samples: int = 2, device=None,
                edges: np.ndarray | None = None) -> np.ndarray:
    """The image (height, width, 3) uint8 of a triangle soup seen by ``camera``."""
    import warp as wp

    from .kernels import render as kr
    from .evaluator import default_device, load_kernels

    dev = wp.get_device(device if device is not None else default_device())
    load_kernels(dev, (kr,))  # a shipped binary where it fits: no compile on a first run
    sw, sh = width * samples, height * samples
    if len(soup.corners):
        scale = float(np.max(np.ptp(np.concatenate([soup.corners, camera.eye[None]]), axis=0))) or 1.0
        max_t = 10.0 * scale
        points = wp.array(soup.corners.astype(np.float32), dtype=wp.vec3, device=dev)
        indices = wp.array(np.arange(len(soup.corners), dtype=np.int32), dtype=wp.int32, device=dev)
        mesh = wp.Mesh(points=points, indices=indices)
        nrm = wp.array(soup.normals.astype(np.float32), dtype=wp.vec3, device=dev)
        col = wp.array(soup.colors.astype(np.float32), dtype=wp.vec3, device=dev)
        color = wp.empty((sh, sw), dtype=wp.vec3, device=dev)
        cover = wp.empty((sh, sw), dtype=float, device=dev)
        depth = wp.empty((sh, sw), dtype=float, device=dev)
        key = -0.6 * camera.forward + 1.0 * camera.up - 0.5 * camera.right
        key /= np.linalg.norm(key)
        v3 = lambda a: wp.vec3(*[float(c) for c in a])  # noqa: E731
        wp.launch(kr.shade_samples, dim=(sh, sw),
                  inputs=[mesh.id, nrm, col, v3(camera.eye), v3(camera.forward), v3(camera.right * camera.tan_x),
                          v3(camera.up * camera.tan_y), int(camera.ortho), sw, sh, v3(key), v3(camera.up),
                          float(max_t), color, cover, depth], device=dev)
        rgb = color.numpy().astype(np.float64)
        alpha = cover.numpy().astype(np.float64)[..., None]
        dist = depth.numpy().astype(np.float64)
    else:
        rgb = np.zeros((sh, sw, 3))
        alpha = np.zeros((sh, sw, 1))
        dist = np.full((sh, sw), np.inf)
        max_t = np.inf
    rows = np.linspace(0.0, 1.0, sh)[:, None, None]
    background = BACKGROUND_TOP * (1 - rows) + BACKGROUND_BOTTOM * rows
    img = alpha * np.clip(rgb, 0, None) ** (1 / 2.2) + (1 - alpha) * background
    if edges is not None and len(edges):
        img = _draw_edges(img, edges, camera, dist, samples, max_t)
    img = img.reshape(height, samples, width, samples, 3).mean(axis=(1, 3))
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


def _draw_edges(img, edges, camera, dist, samples, max_t):
    """Lines over the image: dark where in front of the surface, faint where hidden behind it."""
    sh, sw = dist.shape
    a = edges[:, 0]
    b = edges[:, 1]
    ax, ay, _ = camera.project(a, sw, sh)
    bx, by, _ = camera.project(b, sw, sh)
    ok = np.isfinite(ax) & np.isfinite(bx) & np.isfinite(ay) & np.isfinite(by)
    a, b, ax, ay, bx, by = a[ok], b[ok], ax[ok], ay[ok], bx[ok], by[ok]
    steps = np.clip(np.ceil(np.hypot(bx - ax, by - ay) * 1.5).astype(np.int64), 2, 20000)
    edge = np.repeat(np.arange(len(a)), steps)
    frac = (np.arange(len(edge)) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
    pts = a[edge] + frac[:, None] * (b[edge] - a[edge])
    x, y, d = camera.project(pts, sw, sh)
    inside = np.isfinite(x) & (x >= 0) & (x < sw) & (y >= 0) & (y < sh)
    x, y, d = x[inside].astype(np.int64), y[inside].astype(np.int64), d[inside]
    surface = dist[y, x]
    tol = 2e-3 * max_t if np.isfinite(max_t) else 0.0
    visible = d <= surface + tol
    half = max((samples + 1) // 3, 1)
    out = img.copy()
    for shade, mask, strength in (((0.3, 0.3, 0.35), ~visible, 0.25), ((0.1, 0.1, 0.12), visible, 0.75)):
        xs, ys = x[mask], y[mask]
        for dx in range(-half + 1, half + 1) if samples > 1 else (0,):
            for dy in range(-half + 1, half + 1) if samples > 1 else (0,):
                xx = np.clip(xs + dx, 0, sw - 1)
                yy = np.clip(ys + dy, 0, sh - 1)
                out[yy, xx] = (1 - strength) * out[yy, xx] + strength * np.asarray(shade)
    return out


# -- PNG -----------------------------------------------------------------------------------------------

def png_bytes(rgb: np.ndarray) -> bytes:
    """An 8-bit RGB PNG of ``rgb`` (H, W, 3) uint8, each row filtered with the best of PNG's five filters."""
    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w, _ = img.shape
    x = img.reshape(h, w * 3).astype(np.int16)
    left = np.zeros_like(x)
    left[:, 3:] = x[:, :-3]
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    upleft = np.zeros_like(x)
    upleft[1:, 3:] = x[:-1, :-3]
    p = left + up - upleft
    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
    paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
    candidates = np.stack([x, x - left, x - up, x - (left + up) // 2, x - paeth]) % 256  # (5, h, w*3)
    signed = np.where(candidates > 127, 256 - candidates, candidates)
    best = np.argmin(signed.sum(axis=2), axis=0)  # per row
    rows = candidates[best, np.arange(h)].astype(np.uint8)
    raw = np.concatenate([best.astype(np.uint8)[:, None], rows], axis=1).tobytes()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")


def write_png(path: str, rgb: np.ndarray) -> None:
    """Write a PNG through a temporary file and a rename (no partial file on failure)."""
    folder = os.path.dirname(os.path.abspath(path))
    created = []
    try:
        created = make_folders(folder)
        fd, tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=".png", dir=folder)
    except OSError as exc:
        remove_folders(created)
        raise SubdivInputError(f"{path}: cannot write there: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(png_bytes(rgb))
        publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        remove_folders(created)
        raise


def read_png_size(path: str):
    """(width, height) from a PNG header."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path} is not a PNG")
    return struct.unpack(">II", head[16:24])


# -- entry point ---------------------------------------------------------------------------------------

def _nothing_to_render(path, stage, prims, time, purpose) -> SubdivInputError:
    """The error for a file with nothing to draw; where meshes of the other purpose were left out, it says how
    many and that the purpose option draws them."""
    from pxr import UsdGeom

    under = " under " + ", ".join(prims) if prims else ""
    message = f"{path}: nothing to render (no visible meshes{under})"
    if stage is None:
        return SubdivInputError(message)
    others = [p for p in (*PURPOSES, "guide") if p != purpose]
    left_out = {other: set() for other in others}
    for prim, _ in _placements(stage, prims, time, "render", others):
        left_out[UsdGeom.Imageable(prim).ComputePurpose()].add(prim.GetPath())
    why = {other: "the purpose option chooses " + other for other in PURPOSES}
    notes = [f"{len(paths)} {other}-purpose mesh{'es are' if len(paths) != 1 else ' is'} left out "
             f"({why.get(other, 'no renderer draws guides')})" for other, paths in left_out.items() if paths]
    if not notes:
        return SubdivInputError(message)
    return SubdivInputError("; ".join([message, *notes]), option="purpose", value=purpose)


def render_file(path: str, output: str, *, kind: str = "usd", prims=None, camera=None, view=(-60.0, 30.0),
                size=(800, 600), time=None, levels: int | None = None, cage=None, samples: int = 2, device=None,
                purpose: str = "render") -> np.ndarray:
    """Render ``path`` to the PNG ``output``; returns the image. Of a USD stage, the meshes of the default
    purpose are drawn with those of ``purpose``, "render" (as a final frame) or "proxy" (:data:`PURPOSES`).
    ``levels``: None draws the meshes as stored; a level refines every subdivision mesh first, a USD mesh to
    its ``subdiv:levels`` (or its nearest ancestor's) where one is authored, as ``refine`` does
    (:func:`mesh_level`), an OBJ to ``levels``."""
    width, height = size
    aspect = width / height
    drawn_purposes(purpose)
    if kind == "obj":
        from .io.obj import read_obj

        if camera:
            raise SubdivInputError("camera needs a USD file", option="camera", value=camera)
        if purpose != "render":
            raise SubdivInputError(f"purpose {purpose!r} needs a USD file", option="purpose", value=purpose)
        data = read_obj(path)
        mesh = data.mesh
        pts, counts, idx = mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices
        if levels:
            from .usd import make_refiner

            r = make_refiner(data, levels, device=device)
            counts, idx = r.topology()
            pts = r.evaluate(mesh.points).astype(np.float64)
        soup = _soup(pts, counts, idx, corner_normals(pts, counts, idx), np.tile(DEFAULT_COLOR, (len(idx), 1)))
        up_axis, stage = "Y", None
    else:
        from pxr import UsdGeom

        from .io.usd_stage import open_stage

        stage = open_stage(path)
        if time is None and stage.HasAuthoredTimeCodeRange():
            time = stage.GetStartTimeCode()
        elif time is None:
            time = first_points_sample(stage, prims, purpose)
            if time is not None:
                warnings.warn(OptionWarning(
                    f"{path}: the stage has no startTimeCode and some meshes have sampled points only: rendered "
                    f"at {time:g}, their first sample (the time option chooses another)", option="time"),
                    stacklevel=2)
        else:
            try:
                time = float(time)
            except ValueError:
                raise SubdivInputError(f"time {time!r} is not a number", option="time", value=time) from None
        soup = stage_soup(stage, prims, time, levels, device, purpose)
        up_axis = UsdGeom.GetStageUpAxis(stage)
    edges = None
    if cage:
        from .io.usd_stage import open_stage

        edges = cage_edges(open_stage(cage), time, prims, purpose)
    if not len(soup.corners):
        raise _nothing_to_render(path, stage, prims, time, purpose)
    if camera:
        cam = usd_camera(stage, camera, time, aspect)
    else:
        pts = soup.corners if edges is None or not len(edges) else np.concatenate([soup.corners, edges.reshape(-1, 3)])
        cam = framing_camera(pts, view, aspect, up_axis)
    img = render_soup(soup, cam, width, height, samples, device, edges)
    write_png(output, img)
    return img
