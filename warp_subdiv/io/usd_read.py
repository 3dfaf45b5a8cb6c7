"""Reading one subdivision mesh from USD: a ``UsdGeom.Mesh`` prim with a subdivision scheme becomes a tagged
:class:`warp_subdiv.Mesh`, with its options, time samples and primvars (:func:`read_mesh`). Which prims are read,
and where their refined data goes, is the scene's business (:mod:`.usd_scene`).

USD attributes read (``UsdGeom.Mesh``): ``points``, ``faceVertexCounts``, ``faceVertexIndices``,
``subdivisionScheme``, ``interpolateBoundary``, ``orientation``, ``holeIndices``, ``creaseIndices`` /
``creaseLengths`` / ``creaseSharpnesses`` (one sharpness per crease or per crease edge), ``cornerIndices`` /
``cornerSharpnesses``, ``triangleSubdivisionRule``, ``faceVaryingLinearInterpolation``, ``velocities``,
``accelerations``, ``normals`` and the primvars; and warp-subdiv's own tags in the ``subdiv:`` namespace
(see :data:`SUBDIV_ATTRIBUTES`). Errors are :class:`SubdivInputError` naming the prim and the attribute:
errors of the library underneath (:class:`Mesh`, the refiner) are put in USD terms by :func:`usd_error`, from
their structured fields.
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field, replace

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from ..errors import SubdivInputError
from ..mesh import INFINITE_SHARPNESS, Mesh, expand_counts
from ..options import FaceVaryingMode, RuleSet
from .usd_stage import DEFAULT, format_frames, in_frames, times_for_frames

#: USD subdivisionScheme -> the scheme warp-subdiv refines with ("none" meshes are left alone).
USD_SCHEMES = {"catmullClark": "catmull-clark", "loop": "loop", "bilinear": "bilinear"}
#: USD interpolateBoundary -> Refiner boundary option.
USD_BOUNDARY = {"none": "none", "edgeOnly": "edge-only", "edgeAndCorner": "edge-and-corner"}
#: USD faceVaryingLinearInterpolation -> the mode of the refiner's face-varying channels.
USD_FVAR_MODES = {"none": FaceVaryingMode.NONE, "cornersOnly": FaceVaryingMode.CORNERS_ONLY,
                  "cornersPlus1": FaceVaryingMode.CORNERS_PLUS1, "cornersPlus2": FaceVaryingMode.CORNERS_PLUS2,
                  "boundaries": FaceVaryingMode.BOUNDARIES, "all": FaceVaryingMode.ALL}
#: The faceVaryingLinearInterpolation of a mesh that does not author one (USD's fallback).
USD_FVAR_DEFAULT = "cornersPlus1"

#: Where an error of the library underneath is in a USD mesh, by the error's ``option``: the arguments of
#: :class:`Mesh` (what the reader made of the attributes), then the refiner's options a mesh sets.
MESH_ARGUMENT_ATTRIBUTES = {
    "points": "points", "face_vertex_counts": "faceVertexCounts", "face_vertex_indices": "faceVertexIndices",
    "creases": "creaseIndices", "crease_sharpness": "creaseSharpnesses", "corners": "cornerIndices",
    "corner_sharpness": "cornerSharpnesses", "concave": "subdiv:concave", "normals": "subdiv:normalIndices",
    "holes": "holeIndices",
}
OPTION_ATTRIBUTES = {
    "scheme": "subdivisionScheme", "rules": "subdiv:rules", "boundary": "interpolateBoundary",
    "flatness": "subdiv:flatness", "normal_strength": "subdiv:normalStrength",
    "triangle_subdivision": "triangleSubdivisionRule",
}
#: ... and by the error's ``element``, where its option says nothing more.
ELEMENT_ATTRIBUTES = {"face": "faceVertexIndices", "crease": "creaseIndices", "corner": "cornerIndices",
                      "hole": "holeIndices", "concave": "subdiv:concave", "normal": "subdiv:normalIndices"}

#: warp-subdiv's own per-mesh attributes: name -> (accepted USD types, meaning).
SUBDIV_ATTRIBUTES = {
    "subdiv:rules": (("token", "string"), "rule set: piecewise-smooth (default) or opensubdiv"),
    "subdiv:concave": (("int2[]",), "concave sectors: (corner vertex, neighbour vertex) pairs; the sector of the "
                                    "corner that contains the edge to the neighbour is concave"),
    "subdiv:normalIndices": (("int[]",), "vertices with a prescribed normal"),
    "subdiv:normals": (("normal3f[]", "vector3f[]", "float3[]"), "the prescribed unit normals, one per "
                                                                 "subdiv:normalIndices entry"),
    "subdiv:flatness": (("float", "double", "float[]", "double[]"), "flatness s in [0, 1] of the crease and "
                        "corner sectors: one value for the mesh, or one per control point (NaN: the optimal s*); "
                        "unset: s* everywhere"),
    "subdiv:normalStrength": (("float", "double"), "normal control strength s in [0, 1]"),
    "subdiv:levels": (("int",), "the refinement level of the mesh, >= 0 (on an ancestor prim too: of every mesh "
                                "under it; the nearest wins); read by the USD bake (warp_subdiv.usd.levels)"),
}

#: Attributes whose values define the control mesh's topology and tags: where any of them is time-sampled and
#: changes, the mesh has one control mesh per distinct value (:attr:`SubdivPrim.topologies`).
TOPOLOGY_ATTRIBUTES = ("faceVertexCounts", "faceVertexIndices", "holeIndices", "creaseIndices", "creaseLengths",
                       "creaseSharpnesses", "cornerIndices", "cornerSharpnesses", "subdiv:concave",
                       "subdiv:normalIndices", "subdiv:normals")

#: Subdivision attributes of UsdGeom.Mesh: the writer blocks them all on the refined mesh.
SUBDIVISION_ATTRIBUTES = ("interpolateBoundary", "faceVaryingLinearInterpolation", "triangleSubdivisionRule",
                          "creaseIndices", "creaseLengths", "creaseSharpnesses", "cornerIndices",
                          "cornerSharpnesses", "holeIndices")

#: Value types that interpolate linearly (the primvar's scalar type name).
_LINEAR_SCALARS = re.compile(r"^(half|float|double)[234]?$|^(color|normal|point|vector)[34][hfd]$|^texCoord[23][hfd]$")


@dataclass
class Primvar:
    """A primvar of a subdivision mesh that the refined mesh needs (its size depends on the topology)."""

    name: str  # e.g. "primvars:st"
    interpolation: str
    type_name: Sdf.ValueTypeName
    element_size: int
    indexed: bool
    times: list  # selected time samples of values and indices ([] = static)
    primvar: UsdGeom.Primvar
    default_time: float | None = None  # the sample that stands in for a default that does not fit the mesh

    @property
    def linear(self) -> bool:
        """Values that can be interpolated (floating point vectors; not ints, strings, quaternions, matrices)."""
        return bool(_LINEAR_SCALARS.match(str(self.type_name.scalarType)))

    def raw(self, time):
        """(values, indices or None) at ``time``, as USD holds them. At the default time of a time-sampled
        primvar, the first selected sample stands in for values without a default (or an empty one, or one
        that does not fit the mesh: :attr:`default_time`), and for indices authored only as time samples."""
        if time == DEFAULT and self.times:
            if self.default_time is not None:
                time = self.default_time
            else:
                values = self.primvar.Get(DEFAULT)
                if values is None or len(values) == 0:
                    time = self.times[0]
        values = self.primvar.Get(time)
        indices = None
        if self.indexed:
            # the indices attribute, not Primvar.GetIndices: that returns an empty array, not None, where the
            # indices have no value at the default time (only time samples)
            attr = self.primvar.GetIndicesAttr()
            indices = attr.Get(time)
            if indices is None and time == DEFAULT and self.times:
                indices = attr.Get(self.times[0])
        return values, indices

    def elements(self, time, where: str):
        """(element rows (n, elementSize * components), indices or None) at ``time``, checked; SubdivInputError
        if malformed."""
        values, indices = self.raw(time)
        if values is None:
            raise SubdivInputError(f"{where}: {self.name} has no value")
        arr = np.asarray(values)
        es = self.element_size
        rows = arr.reshape(len(arr), -1)
        if len(rows) % es:
            raise SubdivInputError(f"{where}: {self.name} has {len(rows)} values, not a multiple of elementSize {es}")
        rows = rows.reshape(len(rows) // es, -1)
        if indices is None:
            return rows, None
        idx = np.asarray(indices, dtype=np.int64)
        bad = np.flatnonzero((idx < 0) | (idx >= len(rows)))
        if len(bad):
            raise SubdivInputError(
                f"{where}: {self.name}:indices[{bad[0]}] = {idx[bad[0]]} is outside the {len(rows)} values")
        return rows, idx

    def flattened(self, time, where: str) -> np.ndarray:
        """Element rows (n, elementSize * components) with indices applied; SubdivInputError if malformed."""
        rows, idx = self.elements(time, where)
        return rows if idx is None else rows[idx]


@dataclass
class FaceSubset:
    """A GeomSubset of faces (material bindings use them) or edges (pairs of point indices) under the mesh:
    its indices are remapped to the refined faces, or to the child edges of its edges."""

    path: str
    attr: Usd.Attribute
    times: list
    element: str = "face"  # "face" or "edge"


@dataclass
class Topology:
    """One control mesh of a mesh whose topology changes over time, and the written times that use it."""

    mesh: Mesh
    crease_of_edge: np.ndarray | None
    key: str
    times: list = field(default_factory=list)


@dataclass
class SubdivPrim:
    """One subdivision mesh of the stage, read and validated."""

    path: str
    prim: Usd.Prim
    usd_scheme: str
    scheme: str  # "catmull-clark", "loop" or "bilinear"
    mesh: Mesh
    boundary: str
    rules: str
    flatness: object = None  # None, a float, or one float per control point
    normal_strength: float | None = None
    orientation: str = "rightHanded"
    point_times: list = field(default_factory=list)  # selected time samples of points ([] = static)
    points_default: np.ndarray | None = None
    point_arrays: dict = field(default_factory=dict)  # "velocities"/"accelerations" -> times ([] = static)
    stand_in_defaults: set = field(default_factory=set)  # point arrays whose default does not fit the mesh
    primvars: list = field(default_factory=list)
    dropped: list = field(default_factory=list)  # (attribute name, reason): blocked on the output
    subsets: list = field(default_factory=list)
    authored_normals: list = field(default_factory=list)  # "normals", "primvars:normals" when authored
    subdiv_attributes: list = field(default_factory=list)  # authored subdiv:* attribute names
    warnings: list = field(default_factory=list)
    semi_sharp: int = 0  # finite sharpness tags left as they are (the refiner may refuse them)
    smooth_triangles: bool = False  # triangleSubdivisionRule "smooth" on a Catmull-Clark mesh with triangles
    face_varying_mode: FaceVaryingMode = FaceVaryingMode.CORNERS_PLUS1  # faceVaryingLinearInterpolation
    crease_of_edge: np.ndarray | None = None  # the USD crease (creaseLengths entry) of each of mesh.creases
    # time-varying topology: one control mesh per distinct topology ([] when it never changes); the one of the
    # default time; the times where the topology differs from the previous written time
    topologies: list = field(default_factory=list)
    default_topology: int = 0
    topology_changes: list = field(default_factory=list)
    _topology_keys: dict = field(default_factory=dict, repr=False)
    _build_topology: object = field(default=None, repr=False)

    def topology_index(self, time) -> int:
        """The control mesh (an index into :attr:`topologies`) at ``time``; 0 for a constant topology."""
        if not self.topologies:
            return 0
        if time == DEFAULT:
            return self.default_topology
        return self._build_topology(time)

    def mesh_at(self, time) -> Mesh:
        """The control mesh at ``time`` (:attr:`mesh` unless the topology changes over time)."""
        if not self.topologies:
            return self.mesh
        return self.topologies[self.topology_index(time)].mesh

    def with_topology(self, index: int) -> "SubdivPrim":
        """This mesh with control mesh ``index`` as its :attr:`mesh` (for the refiner of that topology)."""
        if not self.topologies:
            return self
        top = self.topologies[index]
        return replace(self, mesh=top.mesh, crease_of_edge=top.crease_of_edge)

    def error(self, exc: SubdivInputError) -> SubdivInputError:
        """``exc``, an error of the library about this mesh, in USD terms (see :func:`usd_error`)."""
        return usd_error(self.path, exc, self.crease_of_edge)

    def points_at(self, time) -> np.ndarray:
        """Control points at ``time`` (float64 (n, 3)), checked against the topology."""
        if time == DEFAULT:
            pts = self.points_default
        else:
            value = self.prim.GetAttribute("points").Get(time)
            pts = None if value is None else np.asarray(value, dtype=np.float64)
        return self._check_rows(pts, "points", time)

    def vector_array_at(self, name: str, time) -> np.ndarray:
        """velocities / accelerations at ``time`` (float64 (n, 3))."""
        attr = self.prim.GetAttribute(name)
        value = attr.Get(time)
        if time == DEFAULT and self.point_arrays.get(name) and (value is None or name in self.stand_in_defaults):
            value = attr.Get(self.point_arrays[name][0])  # the first selected sample stands in for the default
        pts = None if value is None else np.asarray(value, dtype=np.float64)
        return self._check_rows(pts, name, time)

    def _check_rows(self, pts, name, time):
        when = "" if time == DEFAULT else f" at time {time:g}"
        if pts is None:
            raise SubdivInputError(f"{self.path}: {name} has no value{when}")
        pts = pts.reshape(len(pts), -1) if pts.size else pts.reshape(0, 3)
        n = self.mesh_at(time).num_vertices
        if pts.shape != (n, 3):
            raise SubdivInputError(f"{self.path}: {name}{when} has {len(pts)} entries, the mesh has {n} points")
        bad = np.flatnonzero(~np.all(np.isfinite(pts), axis=1))
        if len(bad):
            raise SubdivInputError(f"{self.path}: {name}[{bad[0]}]{when} is not finite")
        return pts


def usd_error(path: str, exc: SubdivInputError, crease_of_edge=None) -> SubdivInputError:
    """An error of the library about the mesh at ``path`` (from :class:`Mesh` or the refiner), its message
    prefixed with the prim and the USD attribute at fault, which its structured fields name: ``option`` (a
    Mesh argument or a refiner option), else ``element``. A crease edge's index is turned into its USD crease
    (``crease_of_edge``). The fields are kept."""
    message = str(exc)
    option, element, index = exc.option, exc.element, exc.index
    if option == "normals" and element == "normal":
        attr = "subdiv:normals"  # the vectors themselves
    elif option in MESH_ARGUMENT_ATTRIBUTES:
        attr = MESH_ARGUMENT_ATTRIBUTES[option]
    elif element in ELEMENT_ATTRIBUTES:
        attr = ELEMENT_ATTRIBUTES[element]
    else:
        attr = OPTION_ATTRIBUTES.get(option)
    if (element == "crease" and index is not None and crease_of_edge is not None and 0 <= index < len(crease_of_edge)
            and message.startswith(f"crease {index} ")):
        message = f"crease {int(crease_of_edge[index])} edge {message[len(f'crease {index} '):]}"
    text = f"{path}: {attr}: {message}" if attr else f"{path}: {message}"
    return SubdivInputError(text, option=option, element=element, index=index, value=exc.value)


def _get(attr: Usd.Attribute, time):
    """The attribute's value at ``time``; at the default time, its first time sample if it has no default."""
    if not attr or not attr.IsValid():
        return None
    value = attr.Get(time)
    if value is None and time == DEFAULT and attr.GetNumTimeSamples() > 0:
        value = attr.Get(attr.GetTimeSamples()[0])
    return value


def _ints(value) -> np.ndarray:
    return np.zeros(0, dtype=np.int64) if value is None else np.asarray(value, dtype=np.int64).reshape(-1)


def _floats(value) -> np.ndarray:
    return np.zeros(0, dtype=np.float64) if value is None else np.asarray(value, dtype=np.float64).reshape(-1)


def _type_of(attr: Usd.Attribute) -> str:
    return str(attr.GetTypeName())


def read_mesh(prim: Usd.Prim, *, frames=None, semi_sharp: str = "keep", scheme: str = "auto",
              rules: str | None = None, boundary: str | None = None, force: bool = False) -> SubdivPrim | None:
    """Read one UsdGeom.Mesh; None when its subdivisionScheme is "none" (or it is empty).

    ``scheme``: "auto" (the mesh's subdivisionScheme), "catmull-clark" or "loop" (forced); ``rules`` and
    ``boundary`` override the mesh's ``subdiv:rules`` and ``interpolateBoundary`` when given. ``force``: with
    an explicit ``scheme``, a mesh whose subdivisionScheme is "none" (a polygonal mesh) is refined too.
    ``semi_sharp``: "keep" (finite sharpness is semi-sharp) or "sharp" (treat finite sharpness as infinite, with
    a warning).

    Topology and tags that are time-sampled (:data:`TOPOLOGY_ATTRIBUTES`) make a mesh with several control
    meshes (:attr:`SubdivPrim.topologies`): one per distinct topology, each with the times it holds.
    """
    path = str(prim.GetPath())
    geom = UsdGeom.Mesh(prim)
    warn: list = []
    usd_scheme = geom.GetSubdivisionSchemeAttr().Get() or "catmullClark"
    if usd_scheme == "none" and not (force and scheme != "auto"):
        return None
    if usd_scheme not in USD_SCHEMES and usd_scheme != "none":
        raise SubdivInputError(
            f"{path}: subdivisionScheme {usd_scheme!r} is not one of catmullClark, loop, bilinear, none",
            value=usd_scheme,
        )
    chosen = USD_SCHEMES[usd_scheme] if scheme == "auto" else scheme

    points_attr = geom.GetPointsAttr()
    point_times, topology_times, ref_time = _sample_times(prim, points_attr, frames, warn)
    counts = _get(geom.GetFaceVertexCountsAttr(), ref_time)
    indices = _get(geom.GetFaceVertexIndicesAttr(), ref_time)
    pts = _get(points_attr, ref_time) if point_times else _get(points_attr, DEFAULT)
    if counts is None or indices is None or len(counts) == 0:
        if pts is None or len(pts) == 0:
            return None  # an empty mesh: nothing to refine
        raise SubdivInputError(f"{path}: faceVertexCounts / faceVertexIndices have no value")
    if pts is None:
        raise SubdivInputError(f"{path}: points has no value")
    points = np.asarray(pts, dtype=np.float64).reshape(-1, 3)

    # boundary, orientation, rules
    if boundary is None:
        ib = geom.GetInterpolateBoundaryAttr().Get() or "edgeAndCorner"
        if ib not in USD_BOUNDARY:
            raise SubdivInputError(f"{path}: interpolateBoundary {ib!r} is not one of none, edgeOnly, edgeAndCorner",
                                   value=ib)
        boundary = USD_BOUNDARY[ib]
    orientation = geom.GetOrientationAttr().Get() or "rightHanded"
    if orientation not in ("rightHanded", "leftHanded"):
        raise SubdivInputError(f"{path}: orientation {orientation!r} is not rightHanded or leftHanded")

    control = _control_mesh(prim, geom, path, ref_time, points, chosen, semi_sharp, orientation, warn)
    subdiv = control.subdiv
    if rules is None:
        rules = subdiv.get("rules", "piecewise-smooth")
    counts = control.mesh.face_vertex_counts

    tri_rule = geom.GetTriangleSubdivisionRuleAttr().Get() or "catmullClark"
    if tri_rule not in ("catmullClark", "smooth"):
        raise SubdivInputError(f"{path}: triangleSubdivisionRule {tri_rule!r} is not catmullClark or smooth",
                               value=tri_rule)
    fvar = prim.GetAttribute("faceVaryingLinearInterpolation").Get() or USD_FVAR_DEFAULT
    if fvar not in USD_FVAR_MODES:
        raise SubdivInputError(f"{path}: faceVaryingLinearInterpolation {fvar!r} is not one of "
                               f"{', '.join(USD_FVAR_MODES)}", value=fvar)
    if chosen == "loop" and not np.all(counts == 3):
        warn.append(f"{int(np.count_nonzero(counts != 3))} non-triangle faces are fan-triangulated for Loop")

    sp = SubdivPrim(
        path=path, prim=prim, usd_scheme=usd_scheme, scheme=chosen, mesh=control.mesh, boundary=boundary,
        rules=rules, flatness=subdiv.get("flatness"), normal_strength=subdiv.get("normalStrength"),
        orientation=orientation, point_times=point_times, warnings=warn,
        semi_sharp=control.semi if semi_sharp != "sharp" else 0, subdiv_attributes=subdiv.get("_names", []),
        smooth_triangles=chosen == "catmull-clark" and tri_rule == "smooth" and bool(np.any(counts == 3)),
        face_varying_mode=USD_FVAR_MODES[fvar], crease_of_edge=control.crease_of_edge,
    )
    if topology_times:
        _read_topologies(sp, geom, control, ref_time, topology_times, semi_sharp)
    _read_point_defaults(sp, points_attr, pts)
    _read_point_arrays(sp, frames)
    for name in ("normals", "primvars:normals"):
        attr = prim.GetAttribute(name)
        if attr and attr.HasAuthoredValue():
            sp.authored_normals.append(name)
    _read_primvars(sp, frames)
    _read_subsets(sp, geom, frames)
    return sp


def _sample_times(prim: Usd.Prim, points_attr: Usd.Attribute, frames, warn: list):
    """(point times, topology times, reference time): the selected time samples of points, those of the
    topology where it changes over time (:func:`_topology_times`), and the time the control mesh is first
    read at (the first of them, else the default). The samples of points in the selected frames decide what
    is written; a range that holds none of them is warned about."""
    all_times = points_attr.GetTimeSamples()
    point_times = times_for_frames(all_times, frames)
    if all_times and frames is not None and not any(in_frames(t, frames) for t in all_times):
        warn.append(f"frames {format_frames(frames)} hold no time sample of points (its {len(all_times)} samples run "
                    f"from {all_times[0]:g} to {all_times[-1]:g}): the value USD holds there is refined")
    topology_times = _topology_times(prim, frames)
    ref_time = point_times[0] if point_times else (topology_times[0] if topology_times else DEFAULT)
    return point_times, topology_times, ref_time


def _read_point_defaults(sp: SubdivPrim, points_attr: Usd.Attribute, pts) -> None:
    """The points written at the default time: the input's default, unless it is missing or does not fit the
    mesh beside time samples (an empty default is common in exports): then the first selected sample stands
    in for it, and with a time-varying topology, that sample's control mesh is the default one. ``pts``: the
    points read at the reference time."""
    default_mesh = sp.mesh_at(DEFAULT)
    default = (None if _stands_in(points_attr, sp.point_times, default_mesh.num_vertices, sp.warnings)
               else points_attr.Get(DEFAULT))
    if default is None and sp.topologies:
        sp.default_topology = sp.topology_index(sp.point_times[0])  # the stand-in's topology
        sp.mesh = sp.topologies[sp.default_topology].mesh
        sp.crease_of_edge = sp.topologies[sp.default_topology].crease_of_edge
    sp.points_default = np.asarray(pts if default is None and not sp.topologies else
                                   (points_attr.Get(sp.point_times[0]) if default is None else default),
                                   dtype=np.float64).reshape(-1, 3)


def _read_point_arrays(sp: SubdivPrim, frames) -> None:
    """The authored velocities and accelerations: their selected time samples, and whether their first sample
    stands in for their default (as for points)."""
    for name in ("velocities", "accelerations"):
        attr = sp.prim.GetAttribute(name)
        if attr and attr.HasAuthoredValue():
            sp.point_arrays[name] = times_for_frames(attr.GetTimeSamples(), frames)
            if _stands_in(attr, sp.point_arrays[name], sp.mesh_at(DEFAULT).num_vertices, sp.warnings):
                sp.stand_in_defaults.add(name)


@dataclass
class ControlMesh:
    """The control mesh of a USD mesh at one time: the Mesh, the USD crease of each of its crease edges, the
    number of semi-sharp tags and the subdiv: attributes read with it."""

    mesh: Mesh
    crease_of_edge: np.ndarray | None
    semi: int
    subdiv: dict


def _control_mesh(prim, geom, path, time, points, chosen, semi_sharp, orientation, warn) -> ControlMesh:
    """The tagged :class:`Mesh` of ``prim`` at ``time`` (topology and tags there) with control ``points``."""
    counts = _ints(_get(geom.GetFaceVertexCountsAttr(), time))
    indices = _ints(_get(geom.GetFaceVertexIndicesAttr(), time))
    subdiv = _read_subdiv_attributes(prim, path, len(points), time, warn)

    # creases: one sharpness per crease or per crease edge; sharpness <= 0 means smooth (not tagged)
    c_idx = _ints(_get(geom.GetCreaseIndicesAttr(), time))
    c_len = _ints(_get(geom.GetCreaseLengthsAttr(), time))
    c_sharp = _floats(_get(geom.GetCreaseSharpnessesAttr(), time))
    pairs, pair_sharp, pair_crease = _crease_pairs(path, c_idx, c_len, c_sharp)
    k_idx = _ints(_get(geom.GetCornerIndicesAttr(), time))
    k_sharp = _floats(_get(geom.GetCornerSharpnessesAttr(), time))
    if len(k_sharp) != len(k_idx):
        raise SubdivInputError(
            f"{path}: cornerSharpnesses has {len(k_sharp)} values for {len(k_idx)} cornerIndices", element="corner"
        )
    holes = _ints(_get(geom.GetHoleIndicesAttr(), time))
    _check_range(path, "creaseIndices", c_idx, len(points), "crease")
    _check_range(path, "cornerIndices", k_idx, len(points), "corner")
    _check_range(path, "holeIndices", holes, len(counts), "hole", what="face")

    semi = int(np.count_nonzero((pair_sharp > 0) & (pair_sharp < INFINITE_SHARPNESS))
               + np.count_nonzero((k_sharp > 0) & (k_sharp < INFINITE_SHARPNESS)))
    if semi and semi_sharp == "sharp":
        pair_sharp = np.where(pair_sharp > 0, INFINITE_SHARPNESS, pair_sharp)
        k_sharp = np.where(k_sharp > 0, INFINITE_SHARPNESS, k_sharp)
        warn.append(f"{semi} semi-sharp crease edges / corners are treated as infinitely sharp, as requested")
    keep_c = pair_sharp > 0
    keep_k = k_sharp > 0

    normals = None
    if "normalIndices" in subdiv:
        ids, vecs = subdiv["normalIndices"], subdiv["normals"]
        if orientation == "leftHanded":
            vecs = -vecs  # the refiner's normals are right-handed; the writer flips its output back
        normals = (ids, vecs)

    kwargs = dict(
        creases=pairs[keep_c] if np.any(keep_c) else None,
        crease_sharpness=pair_sharp[keep_c] if np.any(keep_c) else None,
        corners=k_idx[keep_k] if np.any(keep_k) else None,
        corner_sharpness=k_sharp[keep_k] if np.any(keep_k) else None,
        concave=subdiv.get("concave"),
        normals=normals,
        holes=holes if len(holes) else None,
    )
    if chosen == "bilinear":
        kwargs.update(creases=None, crease_sharpness=None, corners=None, corner_sharpness=None, concave=None,
                      normals=None)
    crease_of_edge = pair_crease[keep_c] if chosen != "bilinear" else None
    try:
        mesh = Mesh(points, counts, indices, **kwargs)
    except SubdivInputError as exc:
        at = "" if time == DEFAULT else f" (at time {time:g})"
        raise usd_error(path + at, exc, crease_of_edge) from None
    return ControlMesh(mesh, crease_of_edge, semi, subdiv)


def topology_key(prim: Usd.Prim, time) -> str:
    """A digest of the topology and tags (:data:`TOPOLOGY_ATTRIBUTES`) of a mesh at ``time``: equal keys, equal
    control meshes."""
    h = hashlib.sha1()
    for name in TOPOLOGY_ATTRIBUTES:
        attr = prim.GetAttribute(name)
        value = _get(attr, time) if attr else None
        h.update(name.encode())
        h.update(b"-" if value is None else np.ascontiguousarray(np.asarray(value)).tobytes())
    return h.hexdigest()


def _topology_times(prim: Usd.Prim, frames) -> list:
    """The selected time samples of the topology and tags, where any of them is time-sampled and changes over
    time ([] when the topology is the same at every time: one control mesh)."""
    sampled = [prim.GetAttribute(n) for n in TOPOLOGY_ATTRIBUTES]
    sampled = [a for a in sampled if a and a.GetNumTimeSamples() > 0]
    if not sampled:
        return []
    times = set()
    for attr in sampled:
        times.update(times_for_frames(attr.GetTimeSamples(), frames))
    if frames is not None and frames[0] is not None and times and frames[0] not in times:
        times.add(float(frames[0]))  # the topology held at the start of the range
    times = sorted(t for t in times if frames is None or in_frames(t, frames))
    keys = {topology_key(prim, t) for t in times} | {topology_key(prim, DEFAULT)}
    return times if len(keys) > 1 else []


def _read_topologies(sp: SubdivPrim, geom, base: ControlMesh, ref_time, topology_times, semi_sharp) -> None:
    """Time-varying topology: every selected time sample of points or topology is written, each with the
    control mesh of its time; control meshes are built once per distinct topology."""
    prim, path = sp.prim, sp.path
    times = sorted(set(sp.point_times) | set(topology_times))
    sp.point_times = times
    points_attr = geom.GetPointsAttr()
    sp.topologies = []
    sp._topology_keys = {}

    def build(time):
        key = topology_key(prim, time)
        if key in sp._topology_keys:
            return sp._topology_keys[key]
        if time == ref_time:
            control = base
        else:
            value = _get(points_attr, time)
            if value is None:
                raise SubdivInputError(f"{path}: points has no value at time {time:g}")
            control = _control_mesh(prim, geom, path, time, np.asarray(value, dtype=np.float64).reshape(-1, 3),
                                    sp.scheme, semi_sharp, sp.orientation, [])
        sp.topologies.append(Topology(control.mesh, control.crease_of_edge, key))
        sp._topology_keys[key] = len(sp.topologies) - 1
        return sp._topology_keys[key]

    sp._build_topology = build
    for t in times:
        sp.topologies[build(t)].times.append(t)
    sp.default_topology = build(DEFAULT)
    sp.mesh = sp.topologies[sp.default_topology].mesh
    sp.crease_of_edge = sp.topologies[sp.default_topology].crease_of_edge
    changes = [t for i, t in enumerate(times) if i == 0 or sp.topology_index(t) != sp.topology_index(times[i - 1])]
    sp.topology_changes = changes


def _stands_in(attr, times, num_points: int, warn: list) -> bool:
    """Whether the first selected sample (``times[0]``) stands in for the default of a time-sampled per-point
    attribute: a default that is empty (silently) or of another size (with a warning)."""
    if not times:
        return False
    default = attr.Get(DEFAULT)
    if default is None or len(default) == num_points:
        return False
    if len(default):
        warn.append(f"{attr.GetName()} default has {len(default)} entries, the mesh has {num_points} points: the "
                    f"sample at time {times[0]:g} stands in for it")
    return True


def _check_range(path, name, ids, n, element, what="vertex"):
    bad = np.flatnonzero((ids < 0) | (ids >= n))
    if len(bad):
        raise SubdivInputError(f"{path}: {name}[{bad[0]}] = {ids[bad[0]]} is not a {what} of the mesh "
                               f"(it has {n})", element=element, index=int(bad[0]), value=int(ids[bad[0]]))


def _crease_pairs(path, idx, lengths, sharp):
    """USD creases -> per-edge vertex pairs, their sharpness and the USD crease each came from."""
    if len(lengths) == 0 and len(idx) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, np.int64)
    bad = np.flatnonzero(lengths < 2)
    if len(bad):
        raise SubdivInputError(f"{path}: creaseLengths[{bad[0]}] = {lengths[bad[0]]}; a crease needs at least 2 "
                               "vertices",
                               element="crease", index=int(bad[0]), value=int(lengths[bad[0]]))
    if int(lengths.sum()) != len(idx):
        raise SubdivInputError(
            f"{path}: creaseLengths add up to {int(lengths.sum())} but creaseIndices has {len(idx)} entries",
            element="crease",
        )
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    crease, rank = expand_counts(lengths - 1)  # crease of each crease edge, and its place in the crease
    first = starts[crease] + rank
    pairs = np.stack([idx[first], idx[first + 1]], axis=1)
    if len(sharp) == len(lengths):
        per_edge = sharp[crease]
    elif len(sharp) == len(pairs):
        per_edge = sharp
    else:
        per_edge_text = f" or {len(pairs)} (one per crease edge)" if len(pairs) != len(lengths) else ""
        raise SubdivInputError(
            f"{path}: creaseSharpnesses has {len(sharp)} values; expected {len(lengths)} (one per crease)"
            + per_edge_text, element="crease",
        )
    bad = np.flatnonzero(~np.isfinite(per_edge))
    if len(bad):
        raise SubdivInputError(f"{path}: creaseSharpnesses has a value that is not finite (crease {crease[bad[0]]})",
                               element="crease", index=int(crease[bad[0]]))
    return pairs, per_edge, crease


def _read_subdiv_attributes(prim, path, num_points, time, warn) -> dict:
    out: dict = {"_names": []}
    for attr in prim.GetAuthoredPropertiesInNamespace("subdiv"):
        if not isinstance(attr, Usd.Attribute):
            continue
        name = attr.GetName()
        if not attr.HasAuthoredValue():
            continue
        out["_names"].append(name)
        if name not in SUBDIV_ATTRIBUTES:
            warn.append(f"unknown attribute {name} ignored (known: {', '.join(SUBDIV_ATTRIBUTES)})")
            continue
        types, _ = SUBDIV_ATTRIBUTES[name]
        if _type_of(attr) not in types:
            raise SubdivInputError(f"{path}: {name} must be {' or '.join(types)}, got {_type_of(attr)}")
    attr = prim.GetAttribute("subdiv:rules")
    if attr and attr.HasAuthoredValue():
        value = str(_get(attr, time))
        if value not in RuleSet.values():
            raise SubdivInputError(f"{path}: subdiv:rules {value!r} is not {' or '.join(RuleSet.values())}",
                                   value=value)
        out["rules"] = value
    attr = prim.GetAttribute("subdiv:concave")
    if attr and attr.HasAuthoredValue():
        out["concave"] = np.asarray(_get(attr, time), dtype=np.int64).reshape(-1, 2)
        _check_range(path, "subdiv:concave", out["concave"].reshape(-1), num_points, "concave")
    ids_attr, n_attr = prim.GetAttribute("subdiv:normalIndices"), prim.GetAttribute("subdiv:normals")
    has_ids = bool(ids_attr and ids_attr.HasAuthoredValue())
    has_n = bool(n_attr and n_attr.HasAuthoredValue())
    if has_ids != has_n:
        raise SubdivInputError(f"{path}: subdiv:normalIndices and subdiv:normals must be given together")
    if has_ids:
        ids = _ints(_get(ids_attr, time))
        vecs = np.asarray(_get(n_attr, time), dtype=np.float64).reshape(-1, 3)
        if len(ids) != len(vecs):
            raise SubdivInputError(
                f"{path}: subdiv:normals has {len(vecs)} normals for {len(ids)} subdiv:normalIndices"
            )
        _check_range(path, "subdiv:normalIndices", ids, num_points, "normal")
        if len(ids):
            out["normalIndices"], out["normals"] = ids, vecs
    attr = prim.GetAttribute("subdiv:flatness")
    if attr and attr.HasAuthoredValue():
        value = np.asarray(_get(attr, time), dtype=np.float64)
        if value.ndim == 1 and len(value) != num_points:
            raise SubdivInputError(
                f"{path}: subdiv:flatness has {len(value)} values; give one float, or one per point ({num_points})"
            )
        _check_unit_interval(path, "subdiv:flatness", value.reshape(-1), allow_nan=value.ndim == 1)
        out["flatness"] = float(value) if value.ndim == 0 else value
    attr = prim.GetAttribute("subdiv:normalStrength")
    if attr and attr.HasAuthoredValue():
        value = float(_get(attr, time))
        _check_unit_interval(path, "subdiv:normalStrength", np.array([value]))
        out["normalStrength"] = value
    return out


def _check_unit_interval(path, name, values, allow_nan=False):
    """Values in [0, 1]; NaN (the optimal s* of that vertex's sectors) where ``allow_nan``."""
    nan = np.isnan(values)
    bad = np.flatnonzero((nan & (not allow_nan)) | np.isinf(values) | (~nan & ((values < 0) | (values > 1))))
    if len(bad):
        where = f"[{bad[0]}]" if len(values) > 1 else ""
        raise SubdivInputError(f"{path}: {name}{where} = {values[bad[0]]:g} is not in [0, 1]",
                               element="vertex" if len(values) > 1 else None,
                               index=int(bad[0]) if len(values) > 1 else None, value=float(values[bad[0]]))


def _read_primvars(sp: SubdivPrim, frames) -> None:
    """The primvars the refined mesh needs (:attr:`SubdivPrim.primvars`), with their selected time samples;
    those that cannot be refined are listed in :attr:`SubdivPrim.dropped`, with the reason."""
    api = UsdGeom.PrimvarsAPI(sp.prim)
    for pv in api.GetPrimvarsWithAuthoredValues():
        name = pv.GetAttr().GetName()
        interp = pv.GetInterpolation()
        if interp == UsdGeom.Tokens.constant or name == "primvars:normals":
            continue  # constant: inherited as is; primvars:normals: see authored_normals
        type_name = pv.GetTypeName()
        if not type_name.isArray:
            sp.dropped.append((name, f"a {interp} primvar must be an array, it is {type_name}"))
            continue
        times = set(pv.GetAttr().GetTimeSamples())
        indexed = pv.IsIndexed()
        if indexed:
            times |= set(pv.GetIndicesAttr().GetTimeSamples())
        sel = times_for_frames(times, frames)
        es = pv.GetElementSize() or 1
        p = Primvar(name, str(interp), type_name, int(es), bool(indexed), sel, pv)
        if interp not in ("vertex", "varying", "uniform", "faceVarying"):
            sp.dropped.append((name, f"unknown interpolation {interp!r}"))
            continue
        if interp != "uniform" and not p.linear:
            sp.dropped.append((name, f"{interp} values of type {type_name} cannot be interpolated"))
            continue
        sp.primvars.append(p)


def _read_subsets(sp: SubdivPrim, geom: UsdGeom.Mesh, frames) -> None:
    """The face and edge GeomSubsets, whose indices the refined mesh remaps (:attr:`SubdivPrim.subsets`)."""
    for subset in UsdGeom.Subset.GetAllGeomSubsets(geom):
        et = subset.GetElementTypeAttr().Get()
        attr = subset.GetIndicesAttr()
        path = str(subset.GetPath())
        if et in (UsdGeom.Tokens.face, "edge"):
            times = times_for_frames(attr.GetTimeSamples(), frames)
            sp.subsets.append(FaceSubset(path, attr, times, str(et)))
        elif et == "point":
            continue  # refined vertex i is the child of control vertex i: point ids keep their meaning
        else:
            sp.warnings.append(f"GeomSubset {path} with elementType {et!r} is left as is (not remapped)")


__all__ = ["SubdivPrim", "Primvar", "FaceSubset", "Topology", "read_mesh", "topology_key", "usd_error",
           "SUBDIV_ATTRIBUTES", "SUBDIVISION_ATTRIBUTES", "TOPOLOGY_ATTRIBUTES", "USD_SCHEMES", "USD_BOUNDARY",
           "USD_FVAR_MODES", "USD_FVAR_DEFAULT"]
