"""What a bake will do, before it does it: the stage's subdivision meshes as read, their options, their level-0
analysis and their predicted sizes (:func:`plan`, :class:`Plan`).

Every front end gets its refiner here: :func:`options_for` turns what a file says about a control mesh (a USD
prim as read, or an OBJ file) and the run's overrides into :class:`~warp_subdiv.options.Options`, and
:func:`make_refiner` builds the refiner from them, so that ``refine``, ``info`` and ``render --levels`` refine
alike.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

from pxr import Usd

from ..errors import SubdivInputError
from ..io.obj import ObjData
from ..io.usd_read import SubdivPrim, read_mesh
from ..io.usd_stage import open_stage
from ..io.usd_scene import read_scene
from ..options import Boundary, Options, Precision, RuleSet, Scheme
from ..refiner import Refiner
from ..runtime import phases as _phases
from ..runtime import threads as _threads
from ..runtime.estimate import Estimate, MemoryGuardError, estimate, total_bytes
from .levels import LevelChooser
from .skinning import Skinning


@dataclass
class PrimReport:
    path: str
    scheme: str
    rules: str
    faces_in: int
    faces_out: int
    vertices_in: int
    vertices_out: int
    samples: int
    seconds: float = 0.0
    level: int | None = None  # the level it was refined to (see warp_subdiv.usd.levels)


@dataclass
class Plan:
    """What a run will do: the stage, its subdivision meshes and their predicted sizes."""

    input: str
    stage: Usd.Stage
    prims: list
    estimates: list
    options: list = field(default_factory=list)  # the Options of each of prims
    left_alone: list = field(default_factory=list)  # (path, reason)
    warnings: list = field(default_factory=list)  # "path: message"
    scene: object = None  # the usd_read.Scene: where each mesh's refined data goes
    keys: list = field(default_factory=list)  # the input digest of each of prims (its unit in scene)
    # the level-0 refiner each of prims was analysed with: the bake's refiner of the same control mesh and
    # options starts from its analysis instead of analysing again (make_refiner's reuse), and drops it then
    analyses: list = field(default_factory=list, repr=False)
    levels: list = field(default_factory=list)  # the level of each of prims (warp_subdiv.usd.levels)
    # the tables a camera measured each of prims with at its level (or None): the bake's refiner takes them whole
    tables: list = field(default_factory=list, repr=False)
    # composed mesh path -> (level, where it came from: "levels", "subdiv:levels on /path", a camera ...)
    level_sources: dict = field(default_factory=dict)

    @property
    def max_level(self) -> int:
        """The highest level of any mesh (0 without meshes)."""
        return max(self.levels, default=0)

    @property
    def predicted_bytes(self) -> int:
        """The memory the whole bake is predicted to need (the memory guard's estimate)."""
        return total_bytes(self.estimates)

    @property
    def one_place_each(self) -> bool:
        """Whether every refined mesh is written at its own path only (no instances, no variants written with
        all_variants, no identical meshes sharing a refinement): then ``refine_usd(prims=[sp.path])`` of each
        of :attr:`prims` bakes the whole plan (as a distributed bake does, mesh by mesh)."""
        scene = self.scene
        if scene is None:
            return True
        return (not scene.top.refs and len(scene.top.meshes) == len(self.prims)
                and all(not o.dest.ContainsPrimVariantSelection() for o in scene.top.meshes))


def _sample_count(sp: SubdivPrim) -> int:
    """Point arrays written for a mesh: one per time sample, and the default value."""
    return max(1, len(sp.point_times)) + (1 if sp.point_times else 0)


@_phases.timed("read")
def plan(
    input_path: str,
    levels: int,
    *,
    prims=None,
    scheme: str = "auto",
    rules: str | None = None,
    boundary: str | None = None,
    precision: str = "float32",
    frames=None,
    semi_sharp: str = "keep",
    normals: bool = False,
    limit: bool = False,
    require_meshes: bool = True,
    device=None,
    all_variants: bool = False,
    shipped=(),
    max_levels: int | None = None,
    camera: str | None = None,
    pixel_error: float | None = None,
    resolution=None,
    offscreen_level: int | None = None,
    mesh_levels=None,
    scene_levels: bool = True,
    skinning: str = "bake",
    max_influences: int | None = None,
    describe_instances: bool = False,
) -> Plan:
    """Open ``input_path`` and read every subdivision mesh at or under ``prims``; predict output sizes.

    Meshes inside scene-graph instances and PointInstancer prototypes are read once per prototype, meshes
    whose composed inputs are identical once (:func:`~warp_subdiv.io.usd_read.read_scene`; :attr:`Plan.scene`
    says where each one's refined data goes). ``all_variants``: every variant of the variant sets that change
    a mesh is read too. An explicit ``scheme`` with ``prims`` refines the meshes there whatever their
    subdivisionScheme says (polygonal meshes too).

    Every control mesh is analysed with the run's options (``make_refiner(sp, 0)``, kept in
    :attr:`Plan.analyses`), so bad tags, options or devices fail here, before any refinement. ``shipped``:
    hierarchies built elsewhere (see :func:`~warp_subdiv.usd.refine_usd`) that the analysis starts from.

    Each mesh's level (:attr:`Plan.levels`, :attr:`Plan.level_sources`) is chosen by
    :class:`~warp_subdiv.usd.levels.LevelChooser`: its ``subdiv:levels`` or an ancestor's, else ``levels``;
    with ``camera`` and ``pixel_error`` (``resolution``, ``offscreen_level``) the smallest level whose refined
    edges project small enough, up to that; ``max_levels`` caps them all; ``mesh_levels`` ({composed path:
    level}) wins over all of them; ``scene_levels=False`` reads no ``subdiv:levels``.
    ``skinning``, ``max_influences``: what becomes of meshes bound to a skeleton (:mod:`~warp_subdiv.usd.skinning`);
    ``describe_instances`` (``info``): a skinned mesh inside an instance, which ``skinning="bake"`` refuses, is
    planned with its rest pose and the reason (:attr:`~warp_subdiv.usd.skinning.SkinBinding.refused`) instead."""
    scheme, rules, boundary, precision = _run_options(scheme, rules, boundary, precision)
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    stage = open_stage(input_path)
    chooser = LevelChooser(stage, levels, max_levels=max_levels, camera=camera, pixel_error=pixel_error,
                           resolution=resolution, offscreen_level=offscreen_level, frames=frames, device=device,
                           mesh_levels=mesh_levels, scene_levels=scene_levels)
    force = bool(prims) and scheme is not None  # an explicit scheme on named prims: polygonal meshes too
    skin = Skinning(skinning, frames, max_influences, describe_instances=describe_instances)

    def read(prim):
        return skin.attach(read_mesh(prim, frames=frames, semi_sharp=semi_sharp, scheme=scheme or "auto",
                                     rules=rules, boundary=boundary, force=force))

    options_of: dict = {}

    def level(prim, sp):
        if id(sp) not in options_of:
            options_of[id(sp)] = options_for(sp, precision=precision)
        return chooser(prim, sp, options_of[id(sp)])

    scene = read_scene(stage, prims, read=read, all_variants=all_variants, where=input_path, level=level,
                       level_context=chooser.context)
    out = Plan(input_path, stage, [], [], scene=scene, level_sources=dict(scene.placed))
    out.left_alone.extend(scene.left_alone)

    def analyse(key, sp):
        """The options, level-0 refiner and estimate of one mesh."""
        options = options_of.get(id(sp)) or options_for(sp, precision=precision)
        control = make_refiner(sp, 0, options=options, device=device, reuse=shipped)
        return options, control, estimate_prim(sp, scene.levels[key], precision, normals, limit, control)

    # the meshes are independent: a few contiguous ranges of them on the threads (the first error in the
    # plan's order is raised, as one after the other would raise it)
    units = [(key, sp) for key, sp in scene.units.items() if sp is not None]

    def analyse_range(a, b):
        with _phases.phase("analyse"):  # (not reading: on the calling thread it would count to "read")
            return [analyse(key, sp) for key, sp in units[a:b]]

    jobs = [_phases.bound(analyse_range, a, b)
            for a, b in _threads.ranges(len(units), _threads.default_threads(), 1)]
    analysed = [done for part in _threads.run(jobs, len(jobs)) for done in part]
    for (key, sp), (options, control, e) in zip(units, analysed):
        out.prims.append(sp)
        out.keys.append(key)
        out.levels.append(scene.levels[key])
        out.tables.append(chooser.camera.tables(sp, scene.levels[key]) if chooser.camera is not None else None)
        out.options.append(options)
        out.analyses.append(control)
        out.warnings.extend(f"{sp.path}: {w}" for w in sp.warnings)
        out.estimates.append(e)
    if require_meshes and not out.prims:
        _refuse_empty(input_path, prims, scene, out.left_alone)
    return out


def _refuse_empty(input_path: str, prims, scene, left_alone) -> None:
    """The error for a run that found no subdivision mesh to refine: where it looked, why the meshes there were
    left alone, and how to refine polygonal meshes where those were all it found."""
    where = f"under {', '.join(prims)}" if prims else "in the file"
    why = "; ".join(f"{p} ({r})" for p, r in left_alone[:3])
    if prims and not scene.units:
        raise SubdivInputError(f"{input_path}: {', '.join(prims)} is not a mesh and holds no meshes")
    how = ""
    if any(r == "subdivisionScheme none" for _, r in left_alone):
        how = ("; polygonal meshes (subdivisionScheme none) are refined on request: give scheme loop or "
               "catmull-clark with prims naming them (or a prim above them)")
    raise SubdivInputError(f"{input_path}: no subdivision meshes {where}" + (f": {why}" if why else "") + how,
                           option=("scheme", "prims") if how else None)


def _run_options(scheme, rules, boundary, precision):
    """The run's overrides, checked (their errors name the option, not a mesh), as plain strings; None where
    the file decides (a scheme of "auto" too)."""
    scheme = None if scheme in (None, "auto") else Scheme.parse(scheme, "scheme").value
    rules = None if rules is None else RuleSet.parse(rules, "rules").value
    boundary = None if boundary is None else Boundary.parse(boundary, "boundary").value
    return scheme, rules, boundary, Precision.parse(precision, "precision").value


def options_for(source, *, scheme=None, rules=None, boundary=None, precision="float32") -> Options:
    """The refinement options of one control mesh, as its file gives them, with the run's overrides.

    The one place every front end (the USD bake, ``info``, ``render --levels``, OBJ refinement) gets its
    options from. ``source`` is a :class:`~warp_subdiv.io.usd_read.SubdivPrim` (a USD mesh as read: its scheme,
    ``subdiv:rules``, ``interpolateBoundary``, ``subdiv:flatness``, ``subdiv:normalStrength``,
    ``triangleSubdivisionRule``) or an :class:`~warp_subdiv.io.obj.ObjData` (OBJ: Loop for an all-triangle
    mesh, else Catmull-Clark; its ``interpolateboundary`` and ``creasemethod`` tags). ``scheme`` ("auto" or
    None: the file's), ``rules`` and ``boundary`` (None: the file's) override what the file says.

    A bilinear USD mesh gets Catmull-Clark topology with edge-and-corner boundaries and neither flatness nor
    normal control: its refined faces are those of Catmull-Clark, its data is interpolated linearly inside
    each control face (:func:`~warp_subdiv.usd.linear_vertex_data`).

    Errors in what the file says name the prim and attribute (USD) or the file (OBJ); errors in the overrides
    name the option.
    """
    scheme, rules, boundary, precision = _run_options(scheme, rules, boundary, precision)
    if isinstance(source, ObjData):
        mesh = source.mesh
        chosen = scheme or ("loop" if mesh.is_all(3) else "catmull-clark")
        keywords = dict(scheme=chosen, rules=rules or "piecewise-smooth",
                        boundary=boundary or source.options.get("boundary", "edge-and-corner"), precision=precision,
                        crease_method=source.options.get("crease_method", "uniform"))
    else:
        chosen = scheme or source.scheme
        bilinear = chosen == "bilinear"
        keywords = dict(scheme="catmull-clark" if bilinear else chosen, rules=rules or source.rules,
                        boundary="edge-and-corner" if bilinear else (boundary or source.boundary),
                        precision=precision)
        if source.smooth_triangles and not bilinear:
            keywords["triangle_subdivision"] = "smooth"  # OpenSubdiv's TRI_SUB_SMOOTH
        if not bilinear:
            if source.flatness is not None:
                keywords["flatness"] = source.flatness
            if source.normal_strength is not None:
                keywords["normal_strength"] = source.normal_strength
    try:
        return Options(**keywords)
    except SubdivInputError as exc:
        raise _about(source, exc) from None


def make_refiner(source, levels: int, *, options: Options | None = None, device=None, max_memory=None,
                 reuse=(), **overrides) -> Refiner:
    """The refiner of one control mesh: ``source`` as for :func:`options_for`, refined ``levels`` times with
    ``options`` (default: ``options_for(source, **overrides)``). Every front end builds its refiners here.

    ``reuse``: hierarchies built before (tables shipped to a distributed task, the level-0 analysis of
    :attr:`Plan.analyses`; None entries are skipped); the first that fits the mesh and options
    (:meth:`~warp_subdiv.tables.Hierarchy.fits`) is what the refiner starts from.

    Errors about the mesh (its tags, the options it asks for) name the prim and the USD attribute, or the OBJ
    file; the memory guard's errors pass as they are."""
    if options is None:
        options = options_for(source, **overrides)
    elif overrides:
        raise TypeError(f"pass either options= or overrides, not both ({', '.join(overrides)})")
    start = next((h for h in reuse if h is not None and h.fits(source.mesh, options)), None)
    try:
        return Refiner(source.mesh, levels, options=options, device=device, max_memory=max_memory, reuse=start)
    except MemoryGuardError:
        raise
    except SubdivInputError as exc:
        raise _about(source, exc) from None


def _about(source, exc: SubdivInputError) -> SubdivInputError:
    """``exc``, an error about the mesh of ``source``, said in the terms of its file."""
    if isinstance(source, ObjData):
        return SubdivInputError(f"{source.path}: {exc}" if source.path else str(exc), option=exc.option,
                                element=exc.element, index=exc.index, value=exc.value)
    return source.error(exc)


def estimate_prim(sp: SubdivPrim, levels: int, precision: str = "float32", normals: bool = False,
                  limit: bool = False, control: Refiner | None = None) -> Estimate:
    """Predicted counts and bytes of refining one mesh (its samples, primvars and point arrays included).

    ``control`` (the prim's level-0 refiner, ``make_refiner(sp, 0)``, analysed here when not given) says
    whether the refiner projects on every level and where limit masks are read."""
    if control is None:
        control = make_refiner(sp, 0, device="cpu", precision=precision)
    widths = {"vertex": 0, "faceVarying": 0, "uniform": 0}
    channels = sum(pv.interpolation == "faceVarying" for pv in sp.primvars) if sp.scheme != "bilinear" else 0
    for pv in sp.primvars:
        comps = _components(pv) * pv.element_size
        key = "vertex" if pv.interpolation in ("vertex", "varying") else pv.interpolation
        widths[key] += comps
    out = None
    # a time-varying topology: the largest of its control meshes (their refiners are built one at a time)
    for mesh in [top.mesh for top in sp.topologies] or [sp.mesh]:
        e = estimate(
            sp.path, mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, levels,
            "loop" if sp.scheme == "loop" else "catmull-clark", precision=precision, samples=_sample_count(sp),
            vertex_width=widths["vertex"], face_varying_width=widths["faceVarying"], face_varying_channels=channels,
            uniform_width=widths["uniform"],
            extra_point_arrays=len(sp.point_arrays) + (1 if normals else 0), projecting=control.projects,
            limit=(limit or normals) and sp.scheme != "bilinear", limit_deeper=control.limit_reads_deeper(levels),
            layer=True,
        )
        if out is None or total_bytes([e]) > total_bytes([out]):
            out = e
    return out


def _components(pv) -> int:
    """Scalars per value of the primvar's type (float3 -> 3, texCoord2f -> 2, float -> 1)."""
    digits = [c for c in str(pv.type_name.scalarType) if c.isdigit()]
    return int(digits[0]) if digits else 1
