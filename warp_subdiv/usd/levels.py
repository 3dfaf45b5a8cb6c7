"""The level of each mesh of a bake: from the scene (``subdiv:levels`` on the mesh or an ancestor), the run's
default and cap, or a camera's pixel error (:class:`LevelChooser`, which :func:`~warp_subdiv.usd.plan` asks for
every composed mesh it reads).

* ``subdiv:levels`` (an ``int`` >= 0) on a mesh or any ancestor prim sets the mesh's level; the nearest wins,
  so an Xform over a group sets its meshes and a mesh's own attribute overrides it. It is read on the composed
  prims, so opinions inside instance prototypes, variants and references count like any other attribute.
* ``levels`` (``--levels``) is the level of a mesh without one.
* ``camera`` / ``pixel_error``: each mesh gets the smallest level whose longest refined edge projects to at
  most ``pixel_error`` pixels through the camera (:class:`CameraLevels`); its ``subdiv:levels``, else
  ``levels``, is then the most it gets. Meshes outside the camera's frustum get ``offscreen_level``.
* ``max_levels`` (``--max-levels``) caps every mesh, whatever set its level.

Meshes whose inputs are identical but whose levels differ are distinct units of the bake (refined and written
once per level); instances of one prototype whose meshes get different levels reference different refined
prototypes (one per distinct set of levels).
"""
from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdRender

from ..errors import SubdivInputError
from ..io.usd_read import SubdivPrim
from ..io.usd_stage import DEFAULT, times_for_frames
from ..mesh import face_offsets_of, next_corner_of
from ..refiner import Refiner
from ..runtime.estimate import MemoryGuardError
from .refinement import MeshRefinement

#: The attribute that sets the level of a mesh and of every mesh under a prim.
LEVELS_ATTRIBUTE = "subdiv:levels"
#: Bytes of tables a camera keeps from its measurements for the bake (the chosen level's, mesh by mesh in the
#: plan's order), so that the bake does not build them again; beyond it the bake builds its own.
KEPT_TABLES_BYTES = 256 * 2**20
#: The resolution a camera's pixel error is measured at when the stage has no render settings.
DEFAULT_RESOLUTION = (1920, 1080)
_INT_TYPES = {Sdf.ValueTypeNames.Int, Sdf.ValueTypeNames.UInt, Sdf.ValueTypeNames.Int64,
              Sdf.ValueTypeNames.UInt64, Sdf.ValueTypeNames.UChar}


def check_level(value, option: str) -> int:
    """``value`` as a level (an integer >= 0); SubdivInputError naming ``option`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise SubdivInputError(f"{option} must be an integer >= 0, got {value!r}", option=option, value=value)
    return int(value)


def authored_level(prim: Usd.Prim) -> int | None:
    """The ``subdiv:levels`` of ``prim`` (None when it has no value); an error naming the prim when it is not an
    integer >= 0."""
    attr = prim.GetAttribute(LEVELS_ATTRIBUTE)
    if not attr or not attr.HasValue():
        return None
    value = attr.Get()
    where = f"{prim.GetPath()}.{LEVELS_ATTRIBUTE}"
    if attr.GetTypeName() not in _INT_TYPES:
        raise SubdivInputError(f"{where} must be an int >= 0, got a {attr.GetTypeName()} ({value!r})",
                               option="levels", value=value)
    if attr.GetNumTimeSamples():
        raise SubdivInputError(f"{where}: a level cannot change over time (it has time samples)",
                               option="levels", value=value)
    if value is None or int(value) < 0:
        raise SubdivInputError(f"{where} must be an int >= 0, got {value!r}", option="levels", value=value)
    return int(value)


def nearest_level(prim: Usd.Prim):
    """(level, path of the prim that sets it) from the ``subdiv:levels`` of ``prim`` or its nearest ancestor
    that has one (through instance proxies to the instance and above), or None."""
    while prim and not prim.IsPseudoRoot():
        level = authored_level(prim)
        if level is not None:
            return level, str(prim.GetPath())
        prim = prim.GetParent()
    return None


def stage_resolution(stage: Usd.Stage) -> tuple:
    """(width, height) in pixels of the stage's render settings (``renderSettingsPrimPath``), else
    :data:`DEFAULT_RESOLUTION`."""
    settings = UsdRender.Settings.GetStageRenderSettings(stage)
    if settings:
        value = settings.GetResolutionAttr().Get()
        if value is not None and value[0] > 0 and value[1] > 0:
            return int(value[0]), int(value[1])
    return DEFAULT_RESOLUTION


def check_resolution(value) -> tuple:
    """(width, height) from a pair of positive integers or the text ``WxH``."""
    text = value
    if isinstance(value, str):
        parts = value.lower().split("x")
        try:
            value = tuple(int(p) for p in parts) if len(parts) == 2 else None
        except ValueError:
            value = None
    ok = (isinstance(value, (tuple, list)) and len(value) == 2
          and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in value))
    if not ok:
        raise SubdivInputError(f"resolution must be WxH in pixels (two integers > 0), got {text!r}",
                               option="resolution", value=text)
    return int(value[0]), int(value[1])


def to_clip(points, matrix) -> np.ndarray:
    """World-space ``points`` ((n, 3)) in clip space ((n, 4)) through ``matrix`` (USD's row-vector convention:
    a view times a projection matrix of a :class:`Gf.Frustum`)."""
    m = np.asarray(matrix, dtype=np.float64)
    return np.asarray(points, dtype=np.float64).reshape(-1, 3) @ m[:3] + m[3]


def _on_screen_pixels(na, nb, resolution) -> np.ndarray:
    """Pixel lengths of the segments between NDC points ``na`` and ``nb`` ((m, 2)); 0 where the segment's
    bounding box misses the screen."""
    lo, hi = np.minimum(na, nb), np.maximum(na, nb)
    seen = np.all(np.isfinite(na) & np.isfinite(nb), axis=1) & np.all((lo <= 1) & (hi >= -1), axis=1)
    d = (nb - na) * (0.5 * np.asarray(resolution, dtype=np.float64))
    return np.where(seen, np.sqrt(np.einsum("ij,ij->i", d, d)), 0.0)


def clip_lengths(a, b, resolution) -> np.ndarray:
    """The lengths in pixels at ``resolution`` of the segments between clip-space points ``a`` and ``b``
    ((m, 4) each, :func:`to_clip`); 0 for a segment that is not on screen.

    A segment counts when, clipped to the camera's near plane, its projection's bounding box touches the screen
    (so segments that pass just outside a corner count too: the measure errs towards more); a segment wholly
    behind the near plane does not. A segment that crosses the near plane is measured from where it crosses
    it (its projection is unbounded beyond)."""
    out = np.zeros(len(a))
    da, db = a[:, 2] + a[:, 3], b[:, 2] + b[:, 3]  # >= 0: in front of the near plane
    keep = np.flatnonzero((da > 0) | (db > 0))
    a, b, da, db = a[keep], b[keep], da[keep], db[keep]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(da < 0, da / (da - db), 0.0)[:, None]
        a = np.where(t > 0, a + t * (b - a), a)
        t = np.where(db < 0, db / (db - da), 0.0)[:, None]
        b = np.where(t > 0, b + t * (a - b), b)
        out[keep] = _on_screen_pixels(a[:, :2] / a[:, 3:4], b[:, :2] / b[:, 3:4], resolution)
    return out


def projected_lengths(a, b, matrix, resolution) -> np.ndarray:
    """The lengths in pixels of the segments from ``a`` to ``b`` ((m, 3) each, world space) through ``matrix``
    at ``resolution`` (:func:`clip_lengths`)."""
    return clip_lengths(to_clip(a, matrix), to_clip(b, matrix), resolution)


def longest_projected_edge(points, counts, indices, matrix, resolution) -> float:
    """The longest edge of the faces (``counts``, ``indices``) over ``points`` (world space, (n, 3)), in pixels,
    through ``matrix`` at ``resolution`` (as :func:`clip_lengths` measures them); 0 when no edge is on screen.
    Each point is projected once; where every point is in front of the near plane, no edge needs clipping."""
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if len(indices) == 0:
        return 0.0
    clip = to_clip(points, matrix)
    ends = indices[next_corner_of(counts, face_offsets_of(counts))]
    if np.all(clip[:, 2] + clip[:, 3] > 0):
        ndc = clip[:, :2] / clip[:, 3:4]
        lengths = _on_screen_pixels(ndc[indices], ndc[ends], resolution)
    else:
        lengths = clip_lengths(clip[indices], clip[ends], resolution)
    return float(lengths.max(initial=0.0))


def conformed_frustum(camera: UsdGeom.Camera, time, resolution) -> Gf.Frustum:
    """The camera's frustum at ``time`` (usd-core's ``GetCamera(time).frustum``: its world transform, aperture
    and clipping range) with the window widened in one direction to the resolution's aspect ratio (as
    UsdRender's default ``expandAperture`` conform policy does), so that pixels are square."""
    frustum = camera.GetCamera(time).frustum
    window = frustum.GetWindow()
    lo, hi = window.GetMin(), window.GetMax()
    size = hi - lo
    aspect = resolution[0] / resolution[1]
    centre = (lo + hi) * 0.5
    if size[0] / size[1] < aspect:
        half = Gf.Vec2d(size[1] * aspect, size[1]) * 0.5
    else:
        half = Gf.Vec2d(size[0], size[0] / aspect) * 0.5
    frustum.SetWindow(Gf.Range2d(centre - half, centre + half))
    return frustum


def _xform_times(prim: Usd.Prim, own: bool = False) -> set:
    """Time samples of the transforms of ``prim`` and its ancestors (and of all of ``prim``'s attributes when
    ``own``: a camera's aperture and focal length)."""
    out: set = set()
    first = True
    while prim and not prim.IsPseudoRoot():
        for attr in prim.GetAttributes():
            if (own and first) or attr.GetName().startswith("xformOp"):
                out.update(attr.GetTimeSamples())
        prim, first = prim.GetParent(), False
    return out


class CameraLevels:
    """Levels from a camera's pixel error: for each mesh, the smallest level whose longest refined edge projects
    to at most ``pixel_error`` pixels at ``resolution`` (:func:`longest_projected_edge`), at the worst of the
    times it is measured at, up to a cap.

    The edges measured are the refined mesh's own edges (of its refined faces, the control edges of the next
    level), on the refined points the bake writes (refined control points; with ``--limit`` the written limit
    points lie near them), placed by the mesh's world transform. The times: the time samples in ``frames``
    of the mesh's points and of the transforms of the mesh, the camera and their ancestors, and of the
    camera's own attributes (focal length, aperture), with the ends of ``frames`` (see
    :func:`~warp_subdiv.io.usd_stage.times_for_frames`); the default time when nothing is animated.

    A mesh whose control points' bounding box (which holds the refined surface: subdivision is a convex
    combination of them) lies outside the camera's frustum at every one of those times is off-screen and
    gets ``offscreen_level``.

    Refined edges roughly halve per level, and not faster in the limit. The level is predicted from the
    longest edge at level 1, halving per level from there (a prediction that errs low: measuring one level too
    low costs a quarter of the level it falls short of, one too high four times the level needed), then
    checked by refining and measuring at the predicted level (and the one below where it meets the bound),
    moving up or down until the smallest level that meets the bound is found; a mesh that needs more than the
    cap gets the cap, which is not measured."""

    def __init__(self, stage: Usd.Stage, camera: str, pixel_error, *, resolution=None, frames=None,
                 offscreen_level: int = 0, device=None):
        prim = stage.GetPrimAtPath(camera) if isinstance(camera, (str, Sdf.Path)) and camera else None
        if not prim or not prim.IsA(UsdGeom.Camera):
            what = "no prim" if not prim else f"a {prim.GetTypeName() or 'typeless prim'}, not a Camera"
            raise SubdivInputError(f"camera {camera}: {what}", option="camera", value=camera)
        if (isinstance(pixel_error, bool) or not isinstance(pixel_error, (int, float, np.number))
                or not math.isfinite(pixel_error) or pixel_error <= 0):
            raise SubdivInputError(f"pixel_error must be a number > 0 (pixels), got {pixel_error!r}",
                                   option="pixel_error", value=pixel_error)
        self.path = str(prim.GetPath())
        self.device = device
        self.camera = UsdGeom.Camera(prim)
        self.pixel_error = float(pixel_error)
        self.resolution = stage_resolution(stage) if resolution is None else check_resolution(resolution)
        self.frames = frames
        self.offscreen_level = check_level(offscreen_level, "offscreen_level")
        self._camera_times = _xform_times(prim, own=True)
        self._frustums: dict = {}
        self._refined: OrderedDict = OrderedDict()  # (id(sp), level) -> MeshRefinement, a few kept
        self.kept: dict = {}  # (id(control mesh), chosen level) -> hierarchy measured there (tables)
        self.kept_bytes = 0

    def times(self, prim: Usd.Prim, sp: SubdivPrim) -> list:
        """The times a mesh is measured at (see the class)."""
        times = set(self._camera_times) | _xform_times(prim) | set(sp.point_times)
        times = times_for_frames(times, self.frames)
        return times or [DEFAULT]

    def frustum(self, time) -> Gf.Frustum:
        """The camera's frustum at ``time``, conformed to the resolution (:func:`conformed_frustum`), once per
        time."""
        key = "default" if time == DEFAULT else float(time)
        if key not in self._frustums:
            self._frustums[key] = conformed_frustum(self.camera, time, self.resolution)
        return self._frustums[key]

    def refinement(self, sp: SubdivPrim, options, level: int):
        """The mesh refined ``level`` times as the bake refines it (its topology and positions), a few kept."""
        key = (id(sp), level)
        if key not in self._refined:
            try:
                refiner = Refiner(sp.mesh, level, options=options, device=self.device)
            except MemoryGuardError:
                raise
            except SubdivInputError as exc:
                raise sp.error(exc) from None
            self._refined[key] = MeshRefinement(sp, refiner, options, level, False, False, "opensubdiv")
            while len(self._refined) > 4:
                self._refined.popitem(last=False)
        self._refined.move_to_end(key)
        return self._refined[key]

    def longest_edge(self, prim, sp, options, level, placements) -> float:
        """The longest projected refined edge at ``level`` over ``placements`` ([(time, world matrix, clip
        matrix)]). Level 0 is the control mesh as it is (holes included), with no refiner."""
        if level == 0:
            counts, indices = sp.mesh.face_vertex_counts, sp.mesh.face_vertex_indices
        else:
            r = self.refinement(sp, options, level)
            counts, indices = r.counts, r.indices
        worst = 0.0
        for t, world, clip in placements:
            pts = sp.points_at(t) if level == 0 else np.asarray(r.positions(sp.points_at(t))[0], dtype=np.float64)
            world_pts = pts @ world[:3, :3] + world[3, :3]
            worst = max(worst, longest_projected_edge(world_pts, counts, indices, clip, self.resolution))
        return worst

    def placements(self, prim: Usd.Prim, sp: SubdivPrim):
        """([(time, world matrix, clip matrix)] at every time the composed mesh ``prim`` is measured at, whether
        its control points' bounding box meets the frustum at any of them)."""
        xformable = UsdGeom.Xformable(prim)
        placements, visible = [], False
        for t in self.times(prim, sp):
            world = xformable.ComputeLocalToWorldTransform(t)
            frustum = self.frustum(t)
            pts = sp.points_at(t)
            box = Gf.BBox3d(Gf.Range3d(Gf.Vec3d(*pts.min(axis=0)), Gf.Vec3d(*pts.max(axis=0))), world)
            visible = visible or frustum.Intersects(box)
            clip = np.array(frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix())
            placements.append((t, np.array(world), clip))
        return placements, visible

    def edge_rates(self, prim: Usd.Prim, sp: SubdivPrim, curves_at, max_rate: int):
        """(per-edge tessellation rates, note) of the composed mesh ``prim``: each control edge gets
        ceil(its limit curve's projected length / ``pixel_error``) segments (at most ``max_rate``), at the worst
        time; ``curves_at(points) -> (has, samples)`` samples the edge curves of the limit surface of those
        control points (:func:`warp_subdiv.limit.edge_curves`). An off-screen mesh gets rate 1."""
        placements, visible = self.placements(prim, sp)
        worst = None
        for t, world, clip in placements if visible else placements[:1]:
            has, samples = curves_at(sp.points_at(t))
            if worst is None:
                worst = np.zeros(len(has))
            if not visible:
                break
            pts = samples @ world[:3, :3] + world[3, :3]
            seg = projected_lengths(pts[:, :-1], pts[:, 1:], clip, self.resolution).reshape(len(pts), -1)
            worst[has] = np.maximum(worst[has], seg.sum(axis=1))
        rates = np.clip(np.ceil(worst / self.pixel_error), 1, max_rate).astype(np.int64)
        note = "off-screen" if not visible else f"{float(worst.max(initial=0.0)):.3g} px longest edge"
        return rates, note

    def level(self, prim: Usd.Prim, sp: SubdivPrim, options, cap: int):
        """(level, note) of the composed mesh ``prim`` (read as ``sp``, refined with ``options``), at most
        ``cap``; the note says why ("off-screen", "N.N px", or that the cap held it)."""
        if sp.topologies:
            raise SubdivInputError(f"{sp.path}: levels from a camera need a topology that does not change over "
                                   "time; give the mesh subdiv:levels", option="camera")
        placements, visible = self.placements(prim, sp)
        if not visible:
            return min(self.offscreen_level, cap), "off-screen"
        px = self.pixel_error

        def edge(level):
            return self.longest_edge(prim, sp, options, level, placements)

        e0 = edge(0)
        if e0 <= px or cap == 0:
            return 0, f"{e0:.3g} px" if e0 <= px else f"{e0:.3g} px at the cap"
        e1 = edge(1)
        if e1 <= px or cap == 1:
            return 1, f"{e1:.3g} px" if e1 <= px else f"{e1:.3g} px at the cap"
        # edges halve per level at best in the limit: the level they would need halving from level 1 on, which
        # errs low (a level too low costs a quarter of the next one to measure, a level too high four times it)
        level = min(cap, max(2, 1 + math.ceil(math.log2(e1 / px))))
        found = {0: e0, 1: e1}

        def measured(n):
            if n not in found:
                found[n] = edge(n)
            return found[n]

        while level < cap and measured(level) > px:
            level += 1
        while level > 2 and measured(level - 1) <= px:
            level -= 1
        if level not in found:  # the cap, reached from below: not measured there
            return level, f"{found[level - 1]:.3g} px at level {level - 1}; the cap"
        self._keep(sp, options, level)
        e = found[level]
        return level, f"{e:.3g} px" + ("" if e <= px else " at the cap")

    def _keep(self, sp: SubdivPrim, options, level: int) -> None:
        """Keep the tables the mesh was measured with at its chosen level for the bake (:meth:`tables`), while
        all kept ones fit :data:`KEPT_TABLES_BYTES`."""
        key = (id(sp.mesh), level)
        found = self._refined.get((id(sp), level))
        if key in self.kept or found is None:
            return
        size = found.refiner.table_bytes()
        if self.kept_bytes + size <= KEPT_TABLES_BYTES:
            self.kept[key] = found.refiner.hierarchy
            self.kept_bytes += size

    def tables(self, sp: SubdivPrim, level: int):
        """The hierarchy a mesh with ``sp``'s control mesh was measured with at ``level`` (its chosen level),
        kept for the bake's refiner to take whole (``make_refiner(reuse=)``), or None."""
        return self.kept.get((id(sp.mesh), level))


class LevelChooser:
    """The level of every composed mesh of a bake (see the module): ``chooser(prim, sp, options)`` gives
    (level, source), the source saying where the level came from for ``info`` and the reports.

    ``mesh_levels``: {composed mesh path: level} decided before (a distributed bake's driver hands the levels
    its camera chose to the tasks, which see only their own frames): these win over everything else.
    ``scene_levels=False``: ``subdiv:levels`` is not read (every mesh at ``levels``: LOD variants)."""

    def __init__(self, stage: Usd.Stage, levels: int, *, max_levels=None, camera=None, pixel_error=None,
                 resolution=None, offscreen_level=None, frames=None, device=None, mesh_levels=None,
                 scene_levels: bool = True):
        self.levels = check_level(levels, "levels")
        self.scene_levels = scene_levels
        self.mesh_levels = {str(path): check_level(level, f"mesh_levels[{path!r}]")
                            for path, level in dict(mesh_levels or {}).items()}
        self.max_levels = None if max_levels is None else check_level(max_levels, "max_levels")
        if camera is None:
            for name, value in (("pixel_error", pixel_error), ("resolution", resolution),
                                ("offscreen_level", offscreen_level)):
                if value is not None:
                    raise SubdivInputError(f"{name} is for levels from camera: give camera too",
                                           option=(name, "camera"), value=value)
            self.camera = None
        else:
            if pixel_error is None:
                raise SubdivInputError("camera needs pixel_error (the longest refined edge, in pixels)",
                                       option=("camera", "pixel_error"))
            self.camera = CameraLevels(stage, camera, pixel_error, resolution=resolution, frames=frames,
                                       offscreen_level=0 if offscreen_level is None else offscreen_level,
                                       device=device)

    @property
    def per_instance(self) -> bool:
        """Whether a mesh's level depends on where each instance of its prototype is (a camera's), so that
        every instance is read on its own (instances whose meshes get equal levels still share one refined
        prototype)."""
        return self.camera is not None

    def context(self, instance: Usd.Prim):
        """What the levels of the meshes inside ``instance`` depend on besides the prototype: the
        ``subdiv:levels`` at or above the instance prim (and with a camera, the instance itself)."""
        outer = nearest_level(instance) if self.scene_levels else None
        value = None if outer is None else outer[0]
        return (value, str(instance.GetPath())) if self.per_instance else value

    def __call__(self, prim: Usd.Prim, sp: SubdivPrim, options):
        given = self.mesh_levels.get(str(prim.GetPath()))
        if given is not None:
            return given, "mesh_levels"
        found = nearest_level(prim) if self.scene_levels else None
        if found is not None:
            level, where = found
            source = f"{LEVELS_ATTRIBUTE} on {where}"
        else:
            level, source = self.levels, "levels"
        if self.camera is not None:
            level, note = self.camera.level(prim, sp, options, level)
            source = f"camera {self.camera.path} ({note}; at most {source})"
        if self.max_levels is not None and level > self.max_levels:
            level, source = self.max_levels, f"max_levels (from {source})"
        return level, source


__all__ = ["CameraLevels", "DEFAULT_RESOLUTION", "KEPT_TABLES_BYTES", "LEVELS_ATTRIBUTE", "LevelChooser",
           "authored_level", "check_level", "check_resolution", "clip_lengths", "conformed_frustum",
           "longest_projected_edge", "nearest_level", "projected_lengths", "to_clip"]
