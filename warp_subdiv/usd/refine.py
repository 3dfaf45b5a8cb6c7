"""The USD pipeline: read the subdivision meshes of a stage, refine them, and write a layer that overrides them.

:func:`refine_usd` is what ``warp-subdiv refine`` runs on USD files; :func:`plan` reads and predicts without
refining (``warp-subdiv info`` and the memory guard). See the README's USD section for the attributes, the
layer layout and what is supported.

The output layer sublayers the input and holds an ``over`` of every refined mesh, at the mesh's own path:

* ``subdivisionScheme = "none"``, ``points``, ``faceVertexCounts``, ``faceVertexIndices``, ``extent`` (per
  time sample), ``velocities`` / ``accelerations`` (refined like points), ``normals`` (with ``normals=True``);
* every subdivision attribute (creases, corners, holes, boundary and face-varying interpolation, triangle
  rule) and every ``subdiv:`` tag is blocked, and so are authored ``normals`` / ``primvars:normals`` when no
  normals are written (they belong to the control mesh);
* vertex, varying, uniform and face-varying primvars are rewritten for the refined faces (constant ones are
  inherited as they are); primvars that cannot be refined are reported and blocked;
* face GeomSubsets (material bindings) get their ``indices`` remapped to the refined faces, edge GeomSubsets
  to the child edges of their edges (:class:`EdgeMap`);
* the ``extentsHint`` of refined meshes' ancestors is recomputed.

Meshes inside scene-graph instances go into a refined prototype (``/__warpSubdiv/Prototype_<n>``, under a
class) that every instance of the prototype references; identical meshes elsewhere are refined once and
written once (``/__warpSubdiv/Mesh_<n>``, referenced); with ``all_variants`` every variant that changes a mesh
is refined into the same variant set and variant (:class:`Layout`, :func:`warp_subdiv.io.usd_read.read_scene`).
Topology that changes over time is refined per sample, with a refiner per distinct control mesh.

Transforms, materials, relationships and every other prim come from the input unchanged.

Every front end gets its refiner here: :func:`options_for` turns what a file says about a control mesh (a USD
prim as read, or an OBJ file) and the run's overrides into :class:`~warp_subdiv.options.Options`, and
:func:`make_refiner` builds the refiner from them, so that ``refine``, ``info`` and ``render --levels`` refine
alike.
"""
from __future__ import annotations

import collections
import contextvars
import functools
import os
import time as _time
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, Vt

from ..version import __version__
from ..runtime import phases as _phases
from ..runtime import threads as _threads
from ..batch import MeshBatch, batch_key
from ..errors import SubdivInputError
from ..runtime.estimate import Estimate, MemoryGuardError, check_memory, estimate, total_bytes
from ..tables import shipped
from ..io.obj import ObjData
from ..options import Boundary, Options, Precision, RuleSet, Scheme
from .order import OrderedRefiner, check_vertex_order
from ..tables import FaceMap, corners_to_vertices, vertices_used
from ..refiner import Refiner
from ..io.usd_read import SUBDIV_ATTRIBUTES, SUBDIVISION_ATTRIBUTES, SubdivPrim, read_mesh
from ..io.usd_scene import read_scene
from ..io.usd_stage import DEFAULT, open_stage
from ..io.usd_write import OutputLayer, check_output_path, extent_of, int_array, vec3f_array, vt_array

T = Sdf.ValueTypeNames


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

    @property
    def predicted_bytes(self) -> int:
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


@dataclass
class Result:
    output: str
    reports: list
    warnings: list
    seconds: float
    predicted_bytes: int
    phases: dict = field(default_factory=dict)  # seconds per phase (warp_subdiv.runtime.phases): read, analyse, ...


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
) -> Plan:
    """Open ``input_path`` and read every subdivision mesh at or under ``prims``; predict output sizes.

    Meshes inside scene-graph instances and PointInstancer prototypes are read once per prototype, meshes
    whose composed inputs are identical once (:func:`~warp_subdiv.io.usd_read.read_scene`; :attr:`Plan.scene`
    says where each one's refined data goes). ``all_variants``: every variant of the variant sets that change
    a mesh is read too. An explicit ``scheme`` with ``prims`` refines the meshes there whatever their
    subdivisionScheme says (polygonal meshes too).

    Every control mesh is analysed with the run's options (``make_refiner(sp, 0)``), so bad tags, options or
    devices fail here, before any refinement."""
    scheme, rules, boundary, precision = _run_options(scheme, rules, boundary, precision)
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    stage = open_stage(input_path)
    force = bool(prims) and scheme is not None  # an explicit scheme on named prims: polygonal meshes too

    def read(prim):
        return read_mesh(prim, frames=frames, semi_sharp=semi_sharp, scheme=scheme or "auto", rules=rules,
                         boundary=boundary, force=force)

    scene = read_scene(stage, prims, read=read, all_variants=all_variants, where=input_path)
    out = Plan(input_path, stage, [], [], scene=scene)
    out.left_alone.extend(scene.left_alone)

    def analyse(sp):
        """The options, level-0 analysis and estimate of one mesh."""
        options = options_for(sp, precision=precision)
        sp.analysed = make_refiner(sp, 0, options=options, device=device)
        return options, estimate_prim(sp, levels, precision, normals, limit, sp.analysed)

    # the meshes are independent: a few contiguous ranges of them on the threads (the first error in the
    # plan's order is raised, as one after the other would raise it)
    units = [(key, sp) for key, sp in scene.units.items() if sp is not None]

    def analyse_range(a, b):
        return [analyse(sp) for _, sp in units[a:b]]

    jobs = [functools.partial(contextvars.copy_context().run, analyse_range, a, b)
            for a, b in _threads.ranges(len(units), _threads.default_threads(), 1)]
    analysed = [done for part in _threads.run(jobs, len(jobs)) for done in part]
    for (key, sp), (options, e) in zip(units, analysed):
        out.prims.append(sp)
        out.keys.append(key)
        out.options.append(options)
        out.warnings.extend(f"{sp.path}: {w}" for w in sp.warnings)
        out.estimates.append(e)
    if require_meshes and not out.prims:
        where = f"under {', '.join(prims)}" if prims else "in the file"
        why = "; ".join(f"{p} ({r})" for p, r in out.left_alone[:3])
        if prims and not scene.units:
            raise SubdivInputError(f"{input_path}: {', '.join(prims)} is not a mesh and holds no meshes")
        how = ""
        if any(r == "subdivisionScheme none" for _, r in out.left_alone):
            how = ("; polygonal meshes (subdivisionScheme none) are refined on request: give scheme loop or "
                   "catmull-clark with prims naming them (or a prim above them)")
        raise SubdivInputError(f"{input_path}: no subdivision meshes {where}" + (f": {why}" if why else "") + how,
                               option=("scheme", "prims") if how else None)
    return out


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
    each control face (:func:`linear_vertex_data`).

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
                 **overrides) -> Refiner:
    """The refiner of one control mesh: ``source`` as for :func:`options_for`, refined ``levels`` times with
    ``options`` (default: ``options_for(source, **overrides)``). Every front end builds its refiners here.

    Errors about the mesh (its tags, the options it asks for) name the prim and the USD attribute, or the OBJ
    file; the memory guard's errors pass as they are."""
    if options is None:
        options = options_for(source, **overrides)
    elif overrides:
        raise TypeError(f"pass either options= or overrides, not both ({', '.join(overrides)})")
    analysed = getattr(source, "analysed", None)  # the plan's level-0 refiner: its analysis is reused
    try:
        with shipped(analysed.hierarchy if analysed is not None else None):
            refiner = Refiner(source.mesh, levels, options=options, device=device, max_memory=max_memory)
        if analysed is not None and levels > 0:
            source.analysed = None  # used: not kept for the rest of the bake
        return refiner
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


def linear_vertex_data(refiner: Refiner, fmap: FaceMap, values, indices, complete: bool | None = None) -> np.ndarray:
    """Per-vertex ``values`` of the control mesh refined linearly inside each control face (bilinear meshes,
    varying primvars): the refined vertices of ``refiner`` (whose ``topology()`` indices are ``indices``)
    that no face uses (holes) get the refiner's values. ``complete``: whether every vertex is used (computed
    when None)."""
    mesh = refiner.mesh
    corners = fmap.refine_corners(np.asarray(values, dtype=np.float64)[mesh.face_vertex_indices])
    if complete is None:
        complete = vertices_used(indices, refiner.num_vertices)
    fill = None if complete else refiner.evaluate(values)
    return corners_to_vertices(corners, indices, refiner.num_vertices, fill)


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


class _Work:
    """Progress bookkeeping: units are predicted output vertices (tables once, then one per sample)."""

    def __init__(self, p: Plan, callback):
        self.callback = callback
        self.weights = []
        for sp, e in zip(p.prims, p.estimates):
            tables = sum(c.vertices for c in e.counts[1:]) or 1
            self.weights.append((tables, e.final.vertices or 1))
        self.total = sum(t + s * max(1, len(sp.point_times)) for (t, s), sp in zip(self.weights, p.prims)) or 1
        self.done = 0

    def step(self, units: float, label: str) -> None:
        self.done += units
        if self.callback is not None:
            self.callback(min(1.0, self.done / self.total), label)


@_phases.records
def refine_usd(
    input_path: str,
    output_path: str,
    levels: int,
    *,
    prims=None,
    scheme: str = "auto",
    rules: str | None = None,
    boundary: str | None = None,
    device=None,
    precision: str = "float32",
    frames=None,
    limit: bool = False,
    normals: bool = False,
    max_memory: int | None = None,
    flatten: bool = False,
    semi_sharp: str = "keep",
    progress=None,
    all_variants: bool = False,
    vertex_order: str = "auto",
    samples_only: bool = False,
    batch: bool = True,
) -> Result:
    """Refine every subdivision mesh of ``input_path`` (or those at or under ``prims``) ``levels`` times and
    write the layer ``output_path`` (.usd, .usda or .usdc) that sublayers the input and overrides them.

    Meshes inside instances are refined once per prototype and written once per distinct refined prototype,
    which the instances reference (they stay instances); meshes with identical inputs are refined once.
    ``all_variants``: every variant of the variant sets that change a mesh is refined and written inside the
    same variant set and variant (see :func:`plan` and the README's USD section).

    ``frames``: (start, end) time codes (None for an open end) selecting the time samples to refine.
    ``max_memory``: bytes; refuse (MemoryGuardError) when the prediction is larger; None for no limit.
    ``semi_sharp``: "keep" (refine semi-sharp creases and corners as such) or "sharp" (treat them as infinitely
    sharp, with a warning).
    ``progress``: callable(fraction, label) or None. Errors in the input are SubdivInputError.
    ``vertex_order``: "auto" (the default: compact for meshes refined with the piecewise-smooth rules,
    OpenSubdiv's for ``rules="opensubdiv"``), "opensubdiv" (the refiner's, as :func:`~warp_subdiv.refine` numbers
    the vertices) or "compact" (indices that usdc compresses well, written much faster; see
    :mod:`warp_subdiv.usd.order`).
    ``batch``: evaluate small meshes (at most :data:`BATCH_VERTICES` refined vertices each with limit points or
    normals, :data:`BATCH_VERTICES_POINTS` without) that share their
    options, levels and time samples together, one evaluation of their disjoint union per time sample
    (:mod:`warp_subdiv.batch`) instead of one per mesh; the layer written is identical either way (values
    bitwise, the same specs). False: every mesh is evaluated on its own.
    ``samples_only``: write the refined meshes' time samples only, no default values: not the time-invariant
    topology (faceVertexCounts, faceVertexIndices), nor the defaults of points, normals, primvars (face-varying
    indices included) and subsets. For the frame chunks of a distributed bake after a mesh's first: value clips
    read only time samples from a chunk (the first chunk supplies everything else), and saving a refined
    faceVertexIndices is most of a short chunk's cost. The layer alone does not compose to the refined meshes,
    so only their scheme is checked to compose from it.
    """
    start = _time.perf_counter()
    check_vertex_order(vertex_order)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels", value=levels)
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    check_output_path(output_path)
    p = plan(input_path, levels, prims=prims, scheme=scheme, rules=rules, boundary=boundary,
             precision=precision, frames=frames, semi_sharp=semi_sharp, normals=normals, limit=limit,
             device=device, all_variants=all_variants)
    out_abs = check_output_path(output_path, p.stage)
    check_memory(p.estimates, max_memory, levels)

    custom = {"warpSubdiv": {
        "version": __version__, "levels": int(levels), "source": os.path.basename(input_path),
        "prims": Vt.StringArray([sp.path for sp in p.prims]),
        "rules": Vt.StringArray(sorted({sp.rules for sp in p.prims})),
        "schemes": Vt.StringArray(sorted({sp.scheme for sp in p.prims})), "limitPoints": bool(limit),
        "normals": bool(normals), "flattened": bool(flatten), "allVariants": bool(all_variants),
    }}
    if frames is not None:
        custom["warpSubdiv"]["frames"] = ":".join("" if v is None else f"{v:g}" for v in frames)
    work = _Work(p, progress)
    warnings = list(p.warnings)
    layer = OutputLayer(out_abs, p.stage, custom)
    reports = []
    batches = _Batches(p, levels, device, limit, normals, defaults=not samples_only) if batch else None
    token = _BATCHES.set(batches)
    ahead = None
    try:
        ahead = _Ahead(p, levels, device, limit, normals, vertex_order, batches, samples_only=samples_only,
                       max_memory=max_memory)
        out_layout = layout(p)
        for i, sp in enumerate(p.prims):
            t0 = _time.perf_counter()
            key = p.keys[i]
            if batches is not None:
                batches.prepare(i)  # the first prim of a chunk of small meshes: the chunk is evaluated now
            sp.target = str(out_layout.homes[key])
            rep = _refine_prim(sp, p.options[i], layer, levels, device, limit, normals, warnings, work,
                               work.weights[i], f"[{i + 1}/{len(p.prims)}] {sp.path}", vertex_order,
                               samples_only=samples_only, prepared=ahead.take(i))
            for dst in out_layout.copies[key]:
                layer.copy(out_layout.homes[key], dst)
            rep.seconds = _time.perf_counter() - t0
            reports.append(rep)
        out_layout.write(layer)
        out_layout.check(layer, p, reports, samples_only=samples_only)
        # bounding-box hints above the refined meshes: recomputed for the refined surfaces
        layer.override_extents_hints(p.stage, out_layout.hint_roots(p), frames)
        if progress is not None:
            progress(1.0, "writing " + os.path.basename(out_abs))
        layer.commit(flatten=flatten)
    except BaseException:
        layer.discard()
        raise
    finally:
        if ahead is not None:
            ahead.close()
        _BATCHES.reset(token)
    return Result(out_abs, reports, warnings, _time.perf_counter() - start,
                  total_bytes(p.estimates, ahead.concurrent))


#: The root prim of the output layer that holds refined prototypes and shared meshes (a class: not part of the
#: scene; a suffix is added where the input has a prim of that name).
CONTAINER = "__warpSubdiv"
#: The attributes whose composed values must come from the refined data (checked on the output).
_CHECKED = ("subdivisionScheme", "faceVertexCounts", "faceVertexIndices", "points")


@dataclass
class Layout:
    """Where the refined data goes in the output layer.

    * ``homes``: the path each unit (a distinct input, :attr:`Plan.keys`) is written at; ``copies``: further
      paths that get a copy of it (inside variants, or in other prototypes' content);
    * ``refs``: internal references (path, target): each top-level instance prim references the refined
      content of its prototype (``<container>/Prototype_<n>``; nested instances reference theirs from inside
      it), and meshes outside instances with identical inputs reference one shared refined mesh
      (``<container>/Mesh_<n>``) written once;
    * ``shared``: those meshes' paths (a reference that the composed output shows to lose against a stronger
      opinion of the input becomes a copy).
    """

    container: Sdf.Path
    homes: dict
    copies: dict
    refs: list
    shared: dict
    prototypes: dict

    @_phases.timed("write")
    def write(self, layer: OutputLayer) -> None:
        """The container and the references (the refined data is written already)."""
        if self.prototypes or any(h.HasPrefix(self.container) for h in self.homes.values()):
            layer.container(self.container)
        for path, target in self.refs:
            layer.reference(path, target)

    @_phases.timed("write")
    def check(self, layer: OutputLayer, p: Plan, reports, *, samples_only: bool = False) -> None:
        """Compose the output (in each variant configuration that was read) and check that every refined mesh
        composes to its refined data: the strongest opinion of its topology, points and scheme must be the
        output layer's. A shared mesh that fails gets its own copy; anything else is an error naming the
        input's opinion that wins. ``samples_only``: the layer holds no default values (see :func:`refine_usd`),
        only the scheme, which it still holds, is checked."""
        scene = p.scene
        faces = {key: rep.faces_out for key, rep in zip(p.keys, reports)}
        todo = [(o.composed, o.config, o.key, o.dest if o.dest in self.shared else None) for o in scene.top.meshes]
        for key in self.prototypes:
            todo += [(o.composed, o.config, o.key, None) for o in scene.sites[key].meshes]
        by_config: dict = {}
        for item in todo:
            by_config.setdefault(item[1], []).append(item)
        for config, items in by_config.items():
            stage = config.open(layer.layer)
            for composed, _, key, shared in items:
                bad = _losing_opinion(stage.GetPrimAtPath(composed), layer.layer, faces[key], samples_only)
                if bad is None:
                    continue
                if shared is not None:  # the reference loses: write the mesh's own copy instead
                    layer.unreference(shared, self.homes[key])
                    layer.copy(self.homes[key], shared)
                    continue
                where = "".join(f" with {vset} = {v} on {path}" for path, vset, v in config.selections)
                raise SubdivInputError(
                    f"{composed}: the refined mesh written for it{where} does not compose: {bad} is stronger "
                    "(an opinion outside the variant or instance that carries the refined data); refine without "
                    "all_variants, or move the mesh into a referenced asset")
            del stage

    def hint_roots(self, p: Plan) -> dict:
        """Composed prims whose ancestors' extentsHint is recomputed, with the times written under them: the
        refined meshes outside instances and the instance prims that reference refined prototypes."""
        scene = p.scene
        times_of = {key: sp.point_times for key, sp in zip(p.keys, p.prims)}
        memo: dict = {}

        def site_times(key):
            if key not in memo:
                site = scene.sites[key]
                out = set()
                for o in site.meshes:
                    out.update(times_of[o.key])
                for r in site.refs:
                    out.update(site_times(r.site))
                memo[key] = out
            return memo[key]

        roots: dict = {}
        for o in scene.top.meshes:
            roots.setdefault(o.composed, set()).update(times_of[o.key])
        for r in scene.top.refs:
            roots.setdefault(r.composed, set()).update(site_times(r.site))
        return {path: sorted(times) for path, times in roots.items()}


def _losing_opinion(prim, layer: Sdf.Layer, faces: int, samples_only: bool = False):
    """None when the composed ``prim`` takes its refined attributes from ``layer`` (and has ``faces`` faces);
    else the stronger opinion (layer and spec path) that wins, as text. ``samples_only``: only the scheme is
    checked (a layer without default values: no topology, maybe no points)."""
    if not prim:
        return "nothing (the prim does not compose)"
    for name in _CHECKED[:1] if samples_only else _CHECKED:
        attr = prim.GetAttribute(name)
        stack = [s for s in attr.GetPropertyStack(DEFAULT)
                 if s.HasDefaultValue() or s.layer.GetNumTimeSamplesForPath(s.path)] if attr else []
        if stack and stack[0].layer != layer:
            return f"{stack[0].layer.identifier} {stack[0].path}"
    counts = prim.GetAttribute("faceVertexCounts").Get()
    if not samples_only and (counts is None or len(counts) != faces):
        return f"a faceVertexCounts of {0 if counts is None else len(counts)} faces (not {faces})"
    return None


def layout(p: Plan) -> Layout:
    """The output layout of a plan: prototypes named in the order the top level reaches them, each unit's home
    and copies, the references (see :class:`Layout`)."""
    name, n = CONTAINER, 1
    while p.stage.GetPrimAtPath("/" + name):
        n += 1
        name = f"{CONTAINER}_{n}"
    container = Sdf.Path("/" + name)
    targets, refs, prototypes = p.scene.layout(container)
    homes, copies, shared = {}, {}, {}
    count = 0
    for key in p.keys:
        paths = targets[key]
        plain = [t for t in paths if not t.ContainsPrimVariantSelection() and not t.HasPrefix(container)]
        if len(plain) >= 2:  # identical meshes outside instances: written once, referenced from each
            count += 1
            home = container.AppendChild(f"Mesh_{count}")
            for t in plain:
                refs.append((t, home))
                shared[t] = key
            copies[key] = [t for t in paths if t not in plain]
        else:
            home, copies[key] = paths[0], paths[1:]
        homes[key] = home
    return Layout(container, homes, copies, refs, shared, prototypes)


#: Prims whose refined vertex count (the plan's prediction) is at most this are batched with others of the same
#: options, levels and time samples (:class:`_Batches`). A small prim's evaluation costs less than the fixed
#: costs of its own evaluator (the first call's buffers and recorded launches, limit masks, tens of microseconds
#: per later call), which a batch pays once for all its members; measured over 25 samples of 20 equal props at
#: level 2 (CPU), the batch is 14x faster per member at 98 refined vertices, 2.3x at 1,538, 1.4x at 3,458 and
#: slower from about 6,000 on (its gathers and larger buffers).
BATCH_VERTICES = 4096
#: The same bound where only points are written (no limit points or normals): a small prim's own evaluation is
#: then only its recorded launches, and the batch's extra costs (the union's build, reading the points for it)
#: outweigh what it saves sooner. Measured end to end (bench/bench_batch.py, quiet machine): 200 props of 1,538
#: refined vertices x 24 samples baked 0.88x as fast batched (points only) and 1.15x as fast with normals;
#: 1,000 cubes of 98 refined vertices 1.42x and 1.45x.
BATCH_VERTICES_POINTS = 1024
#: The most refined rows x written samples one batch holds at once (its results, kept until each member is
#: written): about 24 MiB of float32 points (and as much again for normals or limit points).
BATCH_ROWS = 1 << 21


class _Batches:
    """The USD writer's batching of small meshes (:mod:`warp_subdiv.batch`): which prims are evaluated together,
    and their results, prepared before the first of them is written.

    A prim is a candidate when its refinement is small (:data:`BATCH_VERTICES`; :data:`BATCH_VERTICES_POINTS`
    where neither limit points nor normals are written), its topology does not change
    over time, it is not bilinear, its options have no per-vertex flatness and no shipped hierarchy (a
    distributed task's) stands in for its refiner. Candidates with equal options and selected time samples
    form chunks in the plan's order, each of at most :data:`BATCH_ROWS` refined rows x samples. When the first
    prim of a chunk is written, :meth:`prepare` builds every member's refiner (the one its :class:`_Context`
    would build), groups the members by :func:`warp_subdiv.batch.batch_key` (those whose union refines them
    bitwise as they refine alone), and evaluates each group of two or more as one :class:`MeshBatch` at every
    written time (the default unless ``defaults`` is False, then each selected sample): points, and limit
    points and normals where asked.
    Each member's :class:`_Context` then takes its refiner and results (:meth:`take`) instead of building and
    evaluating its own; a result is found by the control points it was computed from, so a time whose points
    the writer reads differently (or not at all) is evaluated as without batching. Any input error while
    preparing leaves the chunk (or that sample) to the unbatched path, which reports it as it would."""

    def __init__(self, p: Plan, levels, device, limit, normals, *, defaults: bool = True):
        from ..tables import _shipped_for

        self.levels, self.device, self.limit, self.normals = levels, device, limit, normals
        self.defaults = defaults  # whether default values are written (not with samples_only)
        self.prims, self.options = p.prims, p.options
        small = BATCH_VERTICES if (limit or normals) else BATCH_VERTICES_POINTS
        self.chunk_of: dict = {}  # prim index -> its chunk (a list of prim indices)
        self.ready: dict = {}  # id(sp) -> (refiner, {control points bytes: (points, normals)})
        open_chunks: dict = {}  # key -> (chunk, rows x samples so far)
        for i, (sp, options, e) in enumerate(zip(p.prims, p.options, p.estimates)):
            rows = e.final.vertices
            if (sp.topologies or sp.scheme == "bilinear" or rows > small
                    or isinstance(options.flatness, np.ndarray) or _shipped_for(sp.mesh, options) is not None):
                continue
            key = (options, tuple(sp.point_times))
            cost = rows * (len(sp.point_times) + 1)
            chunk, held = open_chunks.get(key, (None, 0))
            if chunk is None or held + cost > BATCH_ROWS:
                chunk, held = [], 0
            chunk.append(i)
            open_chunks[key] = (chunk, held + cost)
            self.chunk_of[i] = chunk

    def prepare(self, i: int) -> None:
        """Evaluate the chunk of prim ``i`` when ``i`` is its first member (and the chunk has two or more)."""
        chunk = self.chunk_of.pop(i, None)
        if chunk is None or chunk[0] != i or len(chunk) < 2:
            return
        for j in chunk[1:]:
            self.chunk_of.pop(j, None)
        try:
            with _phases.phase("analyse"):
                refiners = [make_refiner(self.prims[j], self.levels, options=self.options[j], device=self.device)
                            for j in chunk]
        except SubdivInputError:
            return  # the unbatched path reports it, prim by prim
        groups: dict = {}
        for j, refiner in zip(chunk, refiners):
            groups.setdefault(batch_key(refiner), []).append((j, refiner))
        for members in groups.values():
            for j, refiner in members:
                self.ready[id(self.prims[j])] = (refiner, {})
            if len(members) >= 2:
                self._evaluate(members)

    def _evaluate(self, members) -> None:
        """Every time sample of one group of members as one union (see the class docstring)."""
        sps = [self.prims[j] for j, _ in members]
        with _phases.phase("analyse"):
            batch = MeshBatch([sp.mesh for sp in sps], self.levels, options=self.options[members[0][0]],
                              device=self.device, check=False)
        with_limits = self.limit or self.normals
        queries = [Usd.AttributeQuery(sp.prim.GetAttribute("points")) for sp in sps]
        for t in ([DEFAULT] if self.defaults else []) + list(sps[0].point_times):
            data, read = [], []
            for sp, query in zip(sps, queries):
                pts = _read_points(sp, query, t)
                read.append(pts is not None)  # else left to the unbatched path; the control points fill its rows
                data.append(sp.mesh.points if pts is None else pts)
            try:
                with _phases.phase("refine"):
                    if with_limits:
                        res = batch.evaluate_with_limits(data, limit_points=self.limit, limit_normals=self.normals)
                        out = [(r.limit_points if self.limit else r.points, r.limit_normals) for r in res]
                    else:
                        out = [(r, None) for r in batch.evaluate(data)]
            except SubdivInputError:
                continue  # (data beyond the precision's bound) each member evaluates this time alone
            for sp, pts, ok, (pos, nrm) in zip(sps, data, read, out):
                if ok:
                    self.ready[id(sp)][1][_points_key(pts)] = (pos, nrm)

    def take(self, sp):
        """(refiner, results by control points) prepared for ``sp``, or None; each prim takes its own once."""
        return self.ready.pop(id(sp), None)


#: Refined vertices from which a mesh is refined ahead of the writer on a worker thread (:class:`_Ahead`);
#: smaller ones cost less to refine than to hand over (and are batched, :class:`_Batches`).
AHEAD_VERTICES = 16_384
#: Bytes of results (points, normals, face-varying values) a worker computes ahead per mesh, besides its
#: refiner; time samples beyond it are evaluated by the writer as they are written.
AHEAD_BYTES = 256 * 2**20


class _Ahead:
    """Meshes refined ahead of the writer on worker threads, so that a bake keeps every core busy: while the
    main thread writes one mesh (Vt arrays, specs; usd-core holds the GIL there), workers analyse and refine
    the next ones (Warp's CPU launches and numpy's large array operations release the GIL).

    A mesh is refined ahead when its topology does not change over time, it is not batched (:class:`_Batches`)
    and it has at least :data:`AHEAD_VERTICES` refined vertices. A worker builds the mesh's :class:`_Context`
    (the refiner, its topology and face map, exactly as the writer would) and evaluates what the writer will
    ask of it (:meth:`_Context.run_ahead`: positions and face-varying channels, by their inputs); the writer
    takes the context when it reaches the mesh (:meth:`take`) and writes it as it would have, so the layer is
    the same with or without workers. A mesh whose inputs fail is left to the writer, which reports the error.

    Workers: :func:`warp_subdiv.runtime.threads.default_threads` (``--threads``, ``WARP_SUBDIV_THREADS``, the cores),
    on the CPU only; one thread means none. At most ``workers`` meshes are in flight besides the one being
    written, fewer where ``max_memory`` does not allow their working sets at once (:attr:`concurrent`: the
    meshes held at once, which the memory prediction counts)."""

    def __init__(self, p: Plan, levels, device, limit, normals, vertex_order, batches, *, samples_only: bool,
                 max_memory=None):
        import warp as wp

        from ..runtime.estimate import memory_limit

        self.p, self.levels, self.device = p, levels, device
        self.limit, self.normals, self.vertex_order = limit, normals, vertex_order
        self.samples_only = samples_only
        self.futures: dict = {}
        self.pool = None
        self.concurrent = 1
        self.queue = collections.deque(
            i for i, (sp, e) in enumerate(zip(p.prims, p.estimates))
            if not sp.topologies and e.final.vertices >= AHEAD_VERTICES
            and (batches is None or i not in batches.chunk_of))
        workers = _threads.default_threads()
        if workers < 2 or len(self.queue) < 2 or not wp.get_device(device).is_cpu:
            return
        limit_bytes = memory_limit(max_memory)
        depth = workers
        while depth and limit_bytes is not None and total_bytes(p.estimates, depth + 1) > limit_bytes:
            depth -= 1
        if depth == 0:
            return
        from concurrent.futures import ThreadPoolExecutor

        from ..evaluator import _load_kernels

        _load_kernels(wp.get_device(device))  # loaded once, before threads launch them
        self.depth, self.concurrent = depth, depth + 1
        self.pool = ThreadPoolExecutor(workers, thread_name_prefix="warp-subdiv-bake")

    def _fill(self, i: int) -> None:
        """Keep :attr:`depth` meshes from ``i`` on in flight."""
        while self.queue and self.queue[0] < i:
            self.queue.popleft()
        while self.queue and len(self.futures) < self.depth:
            j = self.queue.popleft()
            self.futures[j] = self.pool.submit(contextvars.copy_context().run, self._refine, j)

    def _refine(self, i: int):
        """A worker's job: the context of mesh ``i``, evaluated ahead; None where anything fails (the writer
        builds it again and reports the error)."""
        sp = self.p.prims[i]
        try:
            with _threads.inline():
                ctx = _Context(sp, self.p.options[i], self.levels, self.device, self.limit, self.normals,
                               self.vertex_order)
                ctx.run_ahead(sp.face_varying_mode if sp.scheme != "bilinear" else None,
                              defaults=not self.samples_only, budget=AHEAD_BYTES)
            return ctx
        except Exception:  # noqa: BLE001 (reported by the writer, which builds the context again)
            return None

    def take(self, i: int):
        """The context of mesh ``i`` refined ahead (waiting for its worker), or None."""
        if self.pool is None:
            return None
        self._fill(i)
        future = self.futures.pop(i, None)
        self._fill(i + 1)
        if future is None:
            return None
        with _phases.phase("waiting"):
            return future.result()

    def close(self) -> None:
        """Cancel what has not started and wait for the running jobs (nothing runs after the bake returns)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
            self.futures.clear()


def _read_points(sp: SubdivPrim, query, t):
    """The control points of ``sp`` at ``t`` as :meth:`SubdivPrim.points_at` reads them (float64 (n, 3)), read
    through an attribute query and without its checks (the batch's evaluation checks finite values and their
    bound); None where they do not fit the mesh or points_at would refuse them. Results are found by these
    points' bytes (:func:`_points_key`), so points read otherwise are merely not found."""
    try:
        if t == DEFAULT:
            return sp.points_at(t)
        value = query.Get(t)
    except SubdivInputError:
        return None
    if value is None:
        return None
    pts = np.asarray(value, dtype=np.float64)
    return pts if pts.shape == (sp.mesh.num_vertices, 3) else None


def _points_key(pts) -> tuple:
    """What identifies control points exactly (their shape, type and bytes): the key of a prepared result."""
    pts = np.ascontiguousarray(pts)
    return pts.shape, pts.dtype.str, pts.tobytes()


#: The batches of the refine_usd call running in this context (None: no batching).
_BATCHES: contextvars.ContextVar = contextvars.ContextVar("warp_subdiv_usd_batches", default=None)


class _Context:
    """The refiner of one control mesh of a prim (its only one, or one of a time-varying topology) and what the
    writer derives from it: refined topology, face map, linear refinement and edge map."""

    @_phases.timed("analyse")
    def __init__(self, sp: SubdivPrim, options: Options, levels, device, limit, normals, vertex_order="opensubdiv"):
        self.sp = sp
        batches = _BATCHES.get()
        prepared = batches.take(sp) if batches is not None and not sp.topologies else None
        self._prepared = prepared[1] if prepared is not None else None  # results by control points
        if prepared is not None:
            self.refiner = refiner = prepared[0]
        else:
            self.refiner = refiner = make_refiner(sp, levels, options=options, device=device)
        if vertex_order == "compact" or (vertex_order == "auto" and options.piecewise_smooth):
            self.refiner = refiner = OrderedRefiner(refiner)  # the same results, numbered to compress well
        self.counts, self.indices = refiner.topology()
        self.fmap = FaceMap(sp.mesh, levels, sp.scheme, options.boundary.value, hierarchy=refiner.hierarchy)
        self.fmap.check(self.counts)
        self._complete = None  # whether every refined vertex is used (linear_field), found on first use
        self.limit, self.normals = limit, normals
        self._edges = None
        self._ahead: dict = {}  # results a worker computed ahead of the writer (_Ahead), by their inputs

    def run_ahead(self, fvar_mode, *, defaults: bool, budget: int) -> None:
        """Compute ahead (on a worker thread, :class:`_Ahead`) what the writer will ask of this context: the
        positions at the default time (``defaults``) and every selected time sample, and the channel of every
        face-varying primvar (``fvar_mode`` None: none) at those times, defaults first, until the results hold
        ``budget`` bytes. Each result is kept under its inputs and handed out once when the writer asks with the
        same inputs (:meth:`positions`, :meth:`face_varying`); an input that cannot be read or refined is left to
        the writer, which reports it where it belongs."""
        sp = self.sp
        channels = [pv for pv in sp.primvars if pv.interpolation == "faceVarying"] if fvar_mode is not None else []
        first = [DEFAULT] if defaults else []
        jobs = [(t, None) for t in first] + [(t, pv) for pv in channels for t in first]
        jobs += [(t, None) for t in sp.point_times] + [(t, pv) for pv in channels for t in pv.times]
        held = 0
        for t, pv in jobs:
            if held > budget:
                return
            try:
                if pv is None:
                    pts = sp.points_at(t)
                    result = self.positions(pts)
                    key = ("points", _points_key(pts))
                else:
                    rows, idx = _face_varying_input(sp, pv, t)
                    result = self.face_varying(rows, idx, fvar_mode)
                    key = ("face-varying", fvar_mode, _points_key(rows), _points_key(idx))
            except SubdivInputError:
                continue
            self._ahead[key] = result
            held += sum(np.asarray(r).nbytes for r in result if r is not None)

    def linear_field(self, values):
        """Bilinear refinement of per-vertex data (varying primvars, bilinear meshes)."""
        if self._complete is None:
            self._complete = vertices_used(self.indices, self.refiner.num_vertices)
        return linear_vertex_data(self.refiner, self.fmap, values, self.indices, self._complete)

    @_phases.timed("refine")
    def positions(self, pts):
        """Refined (or limit) points and limit normals (or None) of control points ``pts``."""
        sp, refiner = self.sp, self.refiner
        if self._ahead:
            found = self._ahead.pop(("points", _points_key(pts)), None)
            if found is not None:
                return found
        if sp.scheme == "bilinear":
            return self.linear_field(pts), None
        if self._prepared:  # evaluated with a batch of small meshes (_Batches), in the refiner's order
            found = self._prepared.get(_points_key(pts))
            if found is not None:
                pos, nrm = found
                if isinstance(refiner, OrderedRefiner):
                    pos = refiner.compact(pos)
                    nrm = None if nrm is None else refiner.compact(nrm)
                if nrm is not None and sp.orientation == "leftHanded":
                    nrm = -nrm
                return pos, nrm
        if not (self.limit or self.normals):
            return refiner.evaluate(pts), None
        # points, limit points and normals in one pass from the last level's buffer (no round trip)
        res = refiner.evaluate_with_limits(pts, limit_points=self.limit, limit_normals=self.normals)
        nrm = res.limit_normals
        if nrm is not None and sp.orientation == "leftHanded":
            nrm = -nrm  # refined as right-handed: the front of a left-handed mesh is the other side
        return (res.limit_points if self.limit else res.points), nrm

    @_phases.timed("face-varying")
    def face_varying(self, rows, idx, mode):
        """(values, indices) of a face-varying primvar's refined channel (limit values with ``limit``)."""
        if self._ahead:
            found = self._ahead.pop(("face-varying", mode, _points_key(rows), _points_key(idx)), None)
            if found is not None:
                return found
        channel = self.refiner.limit_face_varying if self.limit else self.refiner.evaluate_face_varying
        return channel(rows, idx, mode=mode)

    @_phases.timed("refine")
    def vectors(self, data):
        """Velocities / accelerations: the derivatives of the points, so the same linear maps."""
        if self.sp.scheme == "bilinear":
            return self.linear_field(data)
        refined = self.refiner.evaluate(data)
        return self.refiner.limit_points(refined) if self.limit else refined

    @property
    @_phases.timed("analyse")
    def edges(self):
        if self._edges is None:
            self._edges = EdgeMap(self.sp.mesh, self.refiner, self.indices, self.counts)
        return self._edges


def _refine_prim(sp: SubdivPrim, options: Options, layer: OutputLayer, levels, device, limit, normals, warnings,
                 work, weights, label, vertex_order="opensubdiv", *, samples_only=False, prepared=None) -> PrimReport:
    """Refine one mesh and write it at :attr:`SubdivPrim.output_path` of ``layer``. A mesh whose topology changes
    over time gets one refiner per distinct control mesh (built once, used for every time that has it), and
    time-sampled topology: each written time takes the refiner of its control mesh. ``samples_only``: no
    default values are written (see :func:`refine_usd`). ``prepared``: the mesh's :class:`_Context`, built
    (and partly evaluated) ahead by a worker (:class:`_Ahead`), or None."""
    prim = layer.prim(sp.output_path)
    varying = bool(sp.topologies)
    groups = range(len(sp.topologies)) if varying else [0]
    w_tables, w_sample = weights

    # the subdivision attributes and every subdiv: tag are blocked; authored normals too (unless written)
    layer.set(layer.attr(prim, "subdivisionScheme", T.Token, uniform=True), "none")
    for name in SUBDIVISION_ATTRIBUTES:
        attr = sp.prim.GetAttribute(name)
        layer.block(prim, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform)
    for name in sp.subdiv_attributes:
        attr = sp.prim.GetAttribute(name)
        layer.block(prim, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform, custom=True)
    nrm_spec = None
    if normals and sp.scheme != "bilinear":
        nrm_spec = layer.attr(prim, "normals", T.Normal3fArray)
        nrm_spec.SetInfo("interpolation", "vertex")
    elif normals:
        warnings.append(f"{sp.path}: a bilinear mesh has no limit normals; none written")
    for name in sp.authored_normals:
        if name == "normals" and nrm_spec is not None:
            continue
        attr = sp.prim.GetAttribute(name)
        layer.block(prim, name, attr.GetTypeName())
        if name == "primvars:normals" and sp.prim.GetAttribute(name + ":indices"):
            layer.block(prim, name + ":indices", T.IntArray)
    for name, reason in sp.dropped:
        _drop(sp, layer, prim, name, reason, warnings)

    def times_of(own):
        """[DEFAULT] and the written times of an attribute with time samples ``own``: with a time-varying
        topology, also every time where the topology changes (the refined value changes there)."""
        own = set(own) | (set(sp.topology_changes) if varying else set())
        return [DEFAULT] + sorted(own)

    def mine(times, group):
        """The written times of ``times`` that take the topology ``group`` (every list of written times passes here)."""
        if samples_only:
            times = [t for t in times if t != DEFAULT]
        return [t for t in times if sp.topology_index(t) == group] if varying else list(times)

    fvar_mode = sp.face_varying_mode if sp.scheme != "bilinear" else None
    dropped = set()
    report = None
    for group in groups:
        spg = sp.with_topology(group)
        if prepared is not None and not varying:
            ctx, prepared = prepared, None
        else:
            ctx = _Context(spg, options, levels, device, limit, normals, vertex_order)
        counts, indices = ctx.counts, ctx.indices
        work.step(w_tables / len(groups), f"{label}: {levels} levels" + (f" (topology {group + 1})" if varying else ""))

        # topology: the default, and with a time-varying topology a sample wherever it changes
        cnt_spec = layer.attr(prim, "faceVertexCounts", T.IntArray)
        idx_spec = layer.attr(prim, "faceVertexIndices", T.IntArray)
        for t in mine([DEFAULT] + list(sp.topology_changes if varying else []), group):
            layer.set(cnt_spec, *_default_or_sample(t, int_array(counts)))
            layer.set(idx_spec, *_default_or_sample(t, int_array(indices)))

        # points, extent, normals: the default, then every selected time sample
        pts_spec = layer.attr(prim, "points", T.Point3fArray)
        ext_spec = layer.attr(prim, "extent", T.Float3Array)
        for t in mine([DEFAULT] + list(sp.point_times), group):
            pos, nrm = ctx.positions(spg.points_at(t))
            layer.set(pts_spec, *_default_or_sample(t, vec3f_array(pos)))
            layer.set(ext_spec, *_default_or_sample(t, extent_of(pos)))
            if nrm_spec is not None:
                layer.set(nrm_spec, *_default_or_sample(t, vec3f_array(nrm)))
            if t != DEFAULT:
                work.step(w_sample, f"{label}: time {t:g}")
        if not sp.point_times:
            work.step(w_sample, f"{label}: points")

        # velocities and accelerations: derivatives of the points, refined by the same (linear) rules
        for name, arr_times in sp.point_arrays.items():
            spec = layer.attr(prim, name, sp.prim.GetAttribute(name).GetTypeName())
            for t in mine(times_of(arr_times) if varying else [DEFAULT] + list(arr_times), group):
                layer.set(spec, *_default_or_sample(t, vec3f_array(ctx.vectors(spg.vector_array_at(name, t)))))

        # primvars; face-varying ones by the refiner's face-varying channels where it has them (OpenSubdiv's
        # FVarLinearInterpolation modes), else linearly per face
        for pv in sp.primvars:
            if pv.name in dropped:
                continue
            times = mine(times_of(pv.times) if varying else [DEFAULT] + list(pv.times), group)
            try:
                _write_primvar(spg, pv, layer, prim, ctx, fvar_mode, warnings, limit, times)
            except SubdivInputError as exc:
                dropped.add(pv.name)
                _drop(sp, layer, prim, pv.name, str(exc).split(": ", 1)[-1], warnings)
        # face and edge subsets
        for subset in sp.subsets:
            if subset.path in dropped:
                continue
            times = mine(times_of(subset.times) if varying else [DEFAULT] + list(subset.times), group)
            if not _write_subset(spg, subset, layer, ctx.fmap, warnings, ctx if subset.element == "edge" else None,
                                 times):
                dropped.add(subset.path)
        if group == sp.default_topology or not varying:
            report = PrimReport(sp.path, sp.scheme, sp.rules if sp.scheme != "bilinear" else "-", spg.mesh.num_faces,
                                len(counts), spg.mesh.num_vertices, ctx.refiner.num_vertices, len(sp.point_times) or 1)
        del ctx
    return report


def _drop(sp, layer, prim, name, reason, warnings):
    attr = sp.prim.GetAttribute(name)
    layer.block(prim, name, attr.GetTypeName(), custom=attr.IsCustom())
    if sp.prim.GetAttribute(name + ":indices").HasAuthoredValue() or name + ":indices" in prim.attributes:
        layer.block(prim, name + ":indices", T.IntArray)
    warnings.append(f"{sp.path}: {name} dropped ({reason})")


def _write_primvar(sp, pv, layer, prim, ctx, fvar_mode=None, warnings=None, limit=False, times=None):
    """Refine one primvar at ``times`` (default: the default time and each of its selected samples). A default
    that does not fit the mesh beside time samples gives way to the first selected sample (with a warning).
    ``limit``: vertex and face-varying values are limit values (as the points are with ``limit``)."""
    for t in ([DEFAULT] + list(pv.times)) if times is None else times:
        try:
            _write_primvar_at(sp, pv, t, layer, prim, ctx, fvar_mode, limit)
        except SubdivInputError as exc:
            if t != DEFAULT or not pv.times or pv.default_time is not None:
                raise
            pv.default_time = pv.times[0]
            _write_primvar_at(sp, pv, t, layer, prim, ctx, fvar_mode, limit)
            if warnings is not None:
                warnings.append(f"{sp.path}: {pv.name} default does not fit the mesh ({str(exc).split(': ', 1)[-1]})"
                                f": the sample at time {pv.times[0]:g} stands in for it")


@_phases.timed("refine")
def _write_primvar_at(sp, pv, t, layer, prim, ctx, fvar_mode, limit=False):
    mesh = sp.mesh
    refiner, fmap, linear_field = ctx.refiner, ctx.fmap, ctx.linear_field
    where = sp.path
    n_expected = {"vertex": mesh.num_vertices, "varying": mesh.num_vertices, "uniform": mesh.num_faces,
                  "faceVarying": len(mesh.face_vertex_indices)}[pv.interpolation]
    spec = layer.attr(prim, pv.name, pv.type_name, custom=pv.primvar.GetAttr().IsCustom())
    raw, raw_idx = pv.raw(t)
    if raw is None:
        if t == DEFAULT:
            return
        raise SubdivInputError(f"{where}: {pv.name} has no value at time {t:g}")
    like = np.asarray(raw)
    if pv.interpolation == "uniform" and pv.indexed:
        _, idx = pv.elements(t, where)  # checked against the values' elements (elementSize values each)
        if idx is None or len(idx) != n_expected:  # indices count elements, one per face
            raise SubdivInputError(f"{where}: {pv.name}:indices has {0 if idx is None else len(idx)} entries "
                                   f"for {n_expected} faces")
        new_idx = idx[fmap.parent]
        idx_spec = layer.attr(prim, pv.name + ":indices", T.IntArray)
        layer.set(idx_spec, *_default_or_sample(t, int_array(new_idx)))
        return
    if pv.interpolation == "faceVarying" and fvar_mode is not None:
        values, new_idx = ctx.face_varying(*_face_varying_input(sp, pv, t), fvar_mode)
        values = np.asarray(values).reshape(len(values), -1)
        shaped = values.reshape((len(values) * pv.element_size,) + like.shape[1:])
        layer.set(spec, *_default_or_sample(t, vt_array(pv.type_name, shaped, like)))
        idx_spec = layer.attr(prim, pv.name + ":indices", T.IntArray)
        layer.set(idx_spec, *_default_or_sample(t, int_array(new_idx)))
        return
    rows = pv.flattened(t, where)
    if len(rows) != n_expected:
        raise SubdivInputError(f"{where}: {pv.name} has {len(rows)} {pv.interpolation} values, the mesh needs "
                               f"{n_expected}")
    if pv.interpolation == "uniform":
        out = rows[fmap.parent]
    elif pv.interpolation == "faceVarying":
        out = fmap.refine_corners(rows.astype(np.float64))
    elif pv.interpolation == "varying" or sp.scheme == "bilinear":
        out = linear_field(rows.astype(np.float64))
    else:  # vertex: the subdivision rules (with flatness), but prescribed normals move positions only
        out = refiner.evaluate(rows.astype(np.float64), normal_control=False)
        if limit:
            out = limit_values(refiner, out)
    shaped = np.asarray(out).reshape((len(out) * pv.element_size,) + like.shape[1:])
    layer.set(spec, *_default_or_sample(t, vt_array(pv.type_name, shaped, like)))
    if pv.indexed and t == DEFAULT:
        layer.block(prim, pv.name + ":indices", T.IntArray)


def _face_varying_input(sp: SubdivPrim, pv, t):
    """(values as float64 rows, value index per face corner) of face-varying primvar ``pv`` at ``t``, checked
    against the mesh's corners: what a refiner's face-varying channel takes. The writer and its workers
    (:meth:`_Context.run_ahead`) read it here alike, so a result computed ahead is found by these inputs."""
    rows, idx = pv.elements(t, sp.path)
    idx = np.arange(len(rows)) if idx is None else idx
    corners = len(sp.mesh.face_vertex_indices)
    if len(idx) != corners:
        raise SubdivInputError(f"{sp.path}: {pv.name} has {len(idx)} faceVarying values, the mesh needs {corners}")
    return rows.astype(np.float64), idx


def limit_values(refiner: Refiner, refined: np.ndarray) -> np.ndarray:
    """Limit values of refined vertex data (N, d) that is not a position: as the points' limit, but without
    normal control, which the refiner applies to 3-wide data where its limit masks read one level deeper
    (3-wide data goes through 4 wide, a zero column added)."""
    data = np.asarray(refined, dtype=np.float64)
    data = data.reshape(len(data), -1)
    if data.shape[1] == 3:
        return refiner.limit_points(np.pad(data, ((0, 0), (0, 1))))[:, :3]
    return refiner.limit_points(data)


def _default_or_sample(t, value):
    return (value, None) if t == DEFAULT else (None, [(t, value)])


class EdgeMap:
    """The edges of the refined mesh (``refiner.topology()``: ``indices``, ``counts``) that lie on each edge of
    the control mesh, from the refiner's parentage (:meth:`Hierarchy.vertex_parent`,
    :meth:`Hierarchy.edge_parent`): a refined vertex lies inside a level-0 edge when it is the edge child of
    an edge that lies on it (or the vertex child of such a vertex), and a refined edge lies on the level-0
    edge that holds both its ends (or one end and the other at that edge's control vertex)."""

    def __init__(self, mesh, refiner: Refiner, indices, counts):
        from ..mesh import face_offsets_of, next_corner_of
        from ..topology import EDGE, VERTEX, base_faces

        options = refiner.options
        self.mesh = mesh
        base = base_faces(mesh, options.scheme.value, options.boundary.value)
        self.base_edges = base.edges  # level 0 (a Loop mesh's triangulation adds edges inside polygons)
        ends = self.base_edges.edge_verts.astype(np.int64)
        nv = mesh.num_vertices
        ctrl = np.arange(nv, dtype=np.int64)  # the control vertex a vertex is the child of, or -1
        inside = np.full(nv, -1, dtype=np.int64)  # the level-0 edge a vertex lies inside, or -1
        edge_on = np.arange(len(ends), dtype=np.int64)  # the level-0 edge an edge lies on, or -1
        h = refiner.hierarchy
        for level in range(1, refiner.levels + 1):
            kind, parent = h.vertex_parent(level)
            is_v, is_e = kind == VERTEX, kind == EDGE
            ctrl_next = np.full(len(kind), -1, dtype=np.int64)
            ctrl_next[is_v] = ctrl[parent[is_v]]
            inside_next = np.full(len(kind), -1, dtype=np.int64)
            inside_next[is_v] = inside[parent[is_v]]
            inside_next[is_e] = edge_on[parent[is_e]]
            ctrl, inside = ctrl_next, inside_next
            if level < refiner.levels:
                ekind, eparent, _ = h.edge_parent(level)
                on = ekind == EDGE
                edge_on_next = np.full(len(ekind), -1, dtype=np.int64)
                edge_on_next[on] = edge_on[eparent[on]]
                edge_on = edge_on_next
        # the refined edges, once each, as (low, high) vertex pairs
        counts = np.asarray(counts, dtype=np.int64)
        a = np.asarray(indices, dtype=np.int64)
        b = a[next_corner_of(counts, face_offsets_of(counts))]
        pairs = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1), axis=0)
        u, w = pairs[:, 0], pairs[:, 1]
        cu, cw = ctrl[u], ctrl[w]
        eu, ew = inside[u], inside[w]

        def at_end(e, v):  # whether control vertex v is an end of level-0 edge e (e >= 0)
            safe = np.maximum(e, 0)
            return (e >= 0) & (v >= 0) & ((ends[safe, 0] == v) | (ends[safe, 1] == v))

        edge = np.full(len(pairs), -1, dtype=np.int64)
        both = (eu >= 0) & (eu == ew)
        edge[both] = eu[both]
        one = (eu >= 0) & (ew < 0) & at_end(eu, cw)
        edge[one] = eu[one]
        other = (ew >= 0) & (eu < 0) & at_end(ew, cu)
        edge[other] = ew[other]
        corners = (cu >= 0) & (cw >= 0)  # level 0 only: the control edge itself
        edge[corners] = self.base_edges.find(np.stack([cu[corners], cw[corners]], axis=1), nv)
        self.pairs, self.edge_of_pair = pairs, edge

    def children(self, pairs) -> tuple:
        """(refined edges (k, 2) on the control edges ``pairs`` (m, 2), index of the first pair that is not an
        edge of the control mesh or None)."""
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        nv = self.mesh.num_vertices
        bad = np.flatnonzero((pairs < 0).any(axis=1) | (pairs >= nv).any(axis=1))
        if len(bad):
            return None, int(bad[0])
        own = self.mesh.edges.find(pairs, nv)  # the control polygons' edges (not a triangulation's)
        bad = np.flatnonzero(own < 0)
        if len(bad):
            return None, int(bad[0])
        chosen = np.zeros(len(self.base_edges.edge_verts), dtype=bool)
        chosen[self.base_edges.find(pairs, nv)] = True
        on = self.edge_of_pair >= 0
        keep = np.zeros(len(self.pairs), dtype=bool)
        keep[on] = chosen[self.edge_of_pair[on]]
        return self.pairs[keep], None


def _write_subset(sp, subset, layer, fmap, warnings, context=None, times=None) -> bool:
    """Remap the indices of a face or edge subset at ``times`` (default: the default time and its samples),
    written under the mesh's output path; False (the subset blocked, with a warning) when they do not fit."""
    prim = layer.prim(sp.output_path + subset.path[len(sp.path):])
    spec = layer.attr(prim, "indices", T.IntArray)
    n = sp.mesh.num_faces
    for t in ([DEFAULT] + list(subset.times)) if times is None else times:
        value = subset.attr.Get(t)
        if value is None and t == DEFAULT and subset.times:
            value = subset.attr.Get(subset.times[0])  # no default: the first selected sample stands in
        if value is None:
            continue
        ids = np.asarray(value, dtype=np.int64)
        if subset.element == "edge":
            refined, bad = context.edges.children(ids) if len(ids) % 2 == 0 else (None, None)
            if refined is None:
                layer.block(prim, "indices", T.IntArray)
                why = (f"edge {bad} ({ids[2 * bad]}, {ids[2 * bad + 1]}) is not an edge of the mesh" if bad is not None
                       else f"has {len(ids)} indices, not pairs of points")
                warnings.append(f"{subset.path}: {why}; the subset is dropped")
                return False
            layer.set(spec, *_default_or_sample(t, int_array(refined.reshape(-1))))
            continue
        bad = np.flatnonzero((ids < 0) | (ids >= n))
        if len(bad):
            layer.block(prim, "indices", T.IntArray)
            warnings.append(f"{subset.path}: indices[{bad[0]}] = {ids[bad[0]]} is not a face of the mesh; the subset "
                            "is dropped")
            return False
        member = np.zeros(n, dtype=bool)
        member[ids] = True
        layer.set(spec, *_default_or_sample(t, int_array(np.flatnonzero(member[fmap.parent]))))
    return True


__all__ = ["plan", "refine_usd", "options_for", "make_refiner", "check_memory", "Plan", "Result", "PrimReport",
           "MemoryGuardError", "SUBDIV_ATTRIBUTES"]
