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
  to the child edges of their edges (:class:`~warp_subdiv.usd.subsets.EdgeMap`);
* the ``extentsHint`` of refined meshes' ancestors is recomputed.

Meshes inside scene-graph instances go into a refined prototype (``/__warpSubdiv/Prototype_<n>``, under a
class) that every instance of the prototype references; identical meshes elsewhere are refined once and
written once (``/__warpSubdiv/Mesh_<n>``, referenced); with ``all_variants`` every variant that changes a mesh
is refined into the same variant set and variant (:mod:`warp_subdiv.usd.output_layout`,
:func:`warp_subdiv.io.usd_scene.read_scene`). Topology that changes over time is refined per sample, with a
refiner per distinct control mesh.

Transforms, materials, relationships and every other prim come from the input unchanged.

The steps of a bake live in the modules of this package: the plan (:mod:`~warp_subdiv.usd.planning`), the
layout of the output (:mod:`~warp_subdiv.usd.output_layout`) and the check that it composes to the refined
data (:mod:`~warp_subdiv.usd.composition`), the batches of small meshes
(:mod:`~warp_subdiv.usd.batching`), the meshes refined ahead on worker threads (:mod:`~warp_subdiv.usd.ahead`),
each mesh's refinement (:mod:`~warp_subdiv.usd.refinement`) and writer (:mod:`~warp_subdiv.usd.writer`,
:mod:`~warp_subdiv.usd.primvars`, :mod:`~warp_subdiv.usd.subsets`). What they share is held by one
:class:`Bake`, which this module's :func:`refine_usd` creates, and passed to them.
"""
from __future__ import annotations

import os
import time as _time
from dataclasses import dataclass, field

import numpy as np

from ..errors import SubdivInputError
from ..io.usd_write import OutputLayer, check_flatten, check_output_path
from ..refiner import Refiner
from ..runtime import phases as _phases
from ..runtime.estimate import check_memory, total_bytes
from .ahead import Ahead
from .batching import Batches
from .order import check_vertex_order
from .output_layout import layout
from .lod import check_lod_run, declare_variant_set, local_meshes, lod_path, merge_levels, variant_name
from .planning import Plan, PrimReport, make_refiner, plan
from .record import layer_record
from .skinning import check_max_influences, check_skinning
from .refinement import MeshRefinement
from .resume import CHUNK_SAMPLES, MeshEntries, SampleChunks, Store, eta_seconds, format_eta, resume_folder
from .tiles import TiledMeshes, check_tileable, choose_tiled, without
from .writer import PrimWriter


@dataclass
class Result:
    output: str
    reports: list
    warnings: list
    seconds: float
    predicted_bytes: int
    phases: dict = field(default_factory=dict)  # seconds per phase (warp_subdiv.runtime.phases): read, analyse, ...
    reused: list = field(default_factory=list)  # what was kept by an earlier run and not refined again (resume)
    reused_samples: dict = field(default_factory=dict)  # mesh path -> its time samples kept by an earlier run


class Progress:
    """Progress bookkeeping: units are predicted output vertices (tables once, then one per sample), so each
    mesh weighs its predicted cost. The label ends with an ETA from the rate of the work done so far in this
    run (meshes kept by an earlier run, :meth:`reuse`, count as done but not towards the rate)."""

    def __init__(self, p: Plan, callback):
        self.callback = callback
        self.start = _time.perf_counter()
        self.kept = 0.0
        self.weights = []  # per prim: (tables, each sample)
        for sp, e in zip(p.prims, p.estimates):
            tables = sum(c.vertices for c in e.counts[1:]) or 1
            self.weights.append((tables, e.final.vertices or 1))
        self.total = sum(t + s * max(1, len(sp.point_times)) for (t, s), sp in zip(self.weights, p.prims)) or 1
        self.done = 0

    def step(self, units: float, label: str, kept: bool = False) -> None:
        """``units`` of work done (``kept``: copied from an earlier run's kept work, at no cost)."""
        self.done += units
        self.kept += units if kept else 0.0
        if self.callback is not None:
            eta = format_eta(eta_seconds(self.done, self.total, self.kept, _time.perf_counter() - self.start))
            self.callback(min(1.0, self.done / self.total), f"{label} ({eta})" if eta else label)

    def reuse(self, i: int, samples: int, label: str) -> None:
        """Mesh ``i`` (``samples`` written samples) was kept by an earlier run: done, at no cost."""
        tables, sample = self.weights[i]
        self.step(tables + sample * max(1, samples), label, kept=True)


class Bake:
    """One run of :func:`refine_usd` once its plan is made: what its steps share, held here and passed to them.

    The plan (``plan``: its meshes, their options and level-0 analyses), the run's settings, the hierarchies
    ``shipped`` to it, the output ``layer``, the batches of small meshes (``batches``, None without batching),
    the meshes refined ahead on worker threads (``ahead``), ``progress`` and ``warnings``. :meth:`write` writes
    every mesh; :meth:`close` stops the workers."""

    def __init__(self, p: Plan, layer: OutputLayer, *, device, limit, normals, vertex_order,
                 samples_only: bool, batch: bool, max_memory, shipped, progress, lod_variants=None,
                 resume: MeshEntries | None = None):
        self.plan, self.layer = p, layer
        self.lod_variants = lod_variants  # levels written as variants of every mesh (warp_subdiv.usd.lod)
        batch = batch and not lod_variants  # batches and workers refine each mesh at its planned level only
        self.device, self.limit, self.normals = device, limit, normals
        self.vertex_order, self.samples_only = vertex_order, samples_only
        self.shipped = tuple(h for h in shipped if h is not None)
        self.progress = Progress(p, progress)
        self.warnings = list(p.warnings)
        self.resume = resume  # meshes kept by an earlier run (copied, not refined) and kept as they are written
        self.reused = sorted(resume.kept) if resume is not None else []  # neither batched nor refined ahead
        self.copied: list = []  # the paths of the meshes copied from kept work (a damaged entry is refined)
        self.partial = sorted(resume.partial) if resume is not None else []  # with time samples kept
        self.reused_samples: dict = {}  # mesh path -> time samples copied from kept chunks
        self.batches = self.ahead = None
        if batch:
            self.batches = Batches(p, device, limit, normals, refiner=self.refiner,
                                   defaults=not samples_only, shipped=self.shipped)
            for i in self.reused:  # not evaluated with their chunk
                chunk = self.batches.chunk_of.pop(i, None)
                if chunk is not None:
                    chunk.remove(i)
        # animated meshes refined on their own keep their time samples in chunks as they are written
        self.chunked = {i for i, sp in enumerate(p.prims) if resume is not None and i not in resume.volatile
                        and len(sp.point_times) >= 2 * CHUNK_SAMPLES
                        and (self.batches is None or i not in self.batches.chunk_of)}
        self.ahead = Ahead(self, max_memory)

    def refiner(self, i: int, sp) -> Refiner:
        """The refiner of control mesh ``sp`` of prim ``i`` (the prim as planned, or one topology of it,
        :meth:`~warp_subdiv.io.usd_read.SubdivPrim.with_topology`): it starts from a shipped hierarchy, else from
        the plan's level-0 analysis, where one fits (:func:`~warp_subdiv.usd.make_refiner`)."""
        p = self.plan
        analysis, level = p.analyses[i], p.levels[i]
        reuse = self.shipped + (p.tables[i],) + ((analysis.hierarchy,) if analysis is not None else ())
        refiner = make_refiner(sp, level, options=p.options[i], device=self.device, reuse=reuse)
        p.tables[i] = None  # used (or built again): not kept for the rest of the bake
        if analysis is not None and level > 0 and not sp.topologies:
            p.analyses[i] = None  # used: not kept for the rest of the bake
        return refiner

    def samples(self, i: int, group: int) -> SampleChunks | None:
        """The kept time samples of prim ``i``'s control mesh ``group`` (see :class:`SampleChunks`), where
        they are kept (an animated mesh refined on its own with resume on), else None."""
        return self.resume.samples(i, group) if i in self.chunked else None

    @_phases.timed("analyse")
    def refinement(self, i: int, sp) -> MeshRefinement:
        """The refinement of control mesh ``sp`` of prim ``i`` (see :meth:`refiner`) with the refiner and results
        a batch prepared for it, else with a refiner of its own. The writer and the workers build them here."""
        prepared = self.batches.take(i) if self.batches is not None and not sp.topologies else None
        refiner, results = prepared if prepared is not None else (self.refiner(i, sp), None)
        return MeshRefinement(sp, refiner, self.plan.options[i], self.plan.levels[i], self.limit, self.normals,
                              self.vertex_order, results)

    def write(self):
        """Refine and write every mesh of the plan at its home in the layout and copy it wherever the layout
        wants copies; write the layout's references and check that the output composes to the refined meshes.
        Returns (a report per mesh, the layout)."""
        p, layer = self.plan, self.layer
        out_layout = layout(p)
        reports = []
        for i, sp in enumerate(p.prims):
            t0 = _time.perf_counter()
            key = p.keys[i]
            target = str(out_layout.homes[key])
            label = f"[{i + 1}/{len(p.prims)}] {sp.path}"
            kept = self.resume.load(i, layer, target) if self.resume is not None else None
            if kept is not None:
                report, warnings = PrimReport(**kept[0]), kept[1]
                self.warnings.extend(warnings)
                self.copied.append(sp.path)
                self.progress.reuse(i, len(sp.point_times), f"{label}: kept")
            elif self.lod_variants:
                for level in self.lod_variants:
                    p.levels[i] = level
                    report = PrimWriter(self, i, str(lod_path(target, level)), f"{label} ({variant_name(level)})"
                                        ).write()
                declare_variant_set(layer.layer, target, self.lod_variants)
            else:
                if self.batches is not None:
                    self.batches.prepare(i)  # the first prim of a chunk of small meshes: the chunk is evaluated now
                prepared = self.ahead.take(i)
                known = len(self.warnings)
                report = PrimWriter(self, i, target, label).write(prepared)
                if self.resume is not None:
                    self.resume.save(i, layer, target, report, self.warnings[known:])
            for dst in out_layout.copies[key]:
                layer.copy(out_layout.homes[key], dst)
            report.seconds = _time.perf_counter() - t0
            reports.append(report)
        out_layout.write(layer)
        out_layout.check(layer, p, reports, samples_only=self.samples_only)
        return reports, out_layout

    def close(self) -> None:
        """Stop the workers (nothing runs after the bake returns)."""
        if self.ahead is not None:
            self.ahead.close()


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
    shipped=(),
    max_levels: int | None = None,
    camera: str | None = None,
    pixel_error: float | None = None,
    resolution=None,
    offscreen_level: int | None = None,
    mesh_levels=None,
    lod_variants=None,
    skinning: str = "bake",
    max_influences: int | None = None,
    resume: bool | str = True,
    fresh: bool = False,
) -> Result:
    """Refine every subdivision mesh of ``input_path`` (or those at or under ``prims``) and write the layer
    ``output_path`` (.usd, .usda or .usdc) that sublayers the input and overrides them.

    Each mesh's level (:mod:`warp_subdiv.usd.levels`): its ``subdiv:levels`` or the nearest ancestor's, else
    ``levels``; ``max_levels`` caps every mesh. ``camera`` (a UsdGeom.Camera prim path) with ``pixel_error``
    (pixels > 0): each mesh gets the smallest level, at most the one above, whose longest refined edge
    projects to at most ``pixel_error`` pixels at ``resolution`` ((width, height) or "WxH"; default: the
    stage's render settings, else 1920x1080) at the worst of the selected frames; meshes outside the frustum
    get ``offscreen_level`` (default 0). ``mesh_levels``: {composed mesh path: level}, winning over all of
    these (levels decided elsewhere). Meshes with identical inputs and different levels are refined apart.
    ``lod_variants``: levels (a list, or "0,1,2"): every mesh is refined to each and written inside the variant
    ``level<N>`` of a variant set ``subdivLOD`` on its refined data, the last one selected
    (:mod:`warp_subdiv.usd.lod`); ``subdiv:levels`` does not apply then (the memory guard predicts every mesh at
    the highest of the levels), and ``camera`` and ``max_levels`` are refused. With ``flatten``, and whenever a
    selected mesh is authored in the input's own layer stack (whose opinions no variant over it can beat; a
    warning says so), the output is flattened: one bake per level, flattened, merged into one layer whose
    meshes hold what differs between the levels in their variants
    (:func:`~warp_subdiv.usd.lod.merge_levels`).

    Meshes inside instances are refined once per prototype and written once per distinct refined prototype,
    which the instances reference (they stay instances); meshes with identical inputs are refined once.
    ``all_variants``: every variant of the variant sets that change a mesh is refined and written inside the
    same variant set and variant (see :func:`plan` and the README's USD section).

    ``frames``: (start, end) time codes (None for an open end) selecting the time samples to refine.
    ``max_memory``: bytes; None for no limit. Meshes that do not fit are refined in tiles, largest first until
    the rest fits (:mod:`warp_subdiv.usd.tiles`: the mesh deactivated, a sibling Xform ``<name>_tiles`` of
    tile meshes, each a layer of its own in ``<output stem>_tiles/``); a mesh that tiles cannot write is refused
    with an error naming it, and so is a bake whose rest does not fit (MemoryGuardError).
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
    ``flatten``: write one self-contained layer, the composed stage flattened (instead of a layer over the
    input); it holds the selected variants only (but the ``subdivLOD`` variants of ``lod_variants``), and is
    refused with ``all_variants``.
    ``shipped``: hierarchies built elsewhere (a distributed bake's topology task ships a mesh's tables to the
    tasks that refine its frames, :mod:`warp_subdiv.usd.distributed`): the refiner of a mesh that one of them
    fits starts from it (:meth:`~warp_subdiv.tables.Hierarchy.fits`), and such a mesh is not batched.
    ``resume``: keep each refined mesh in ``<output>.resume/`` as it is written, and copy the meshes an earlier
    run of the same bake kept there instead of refining them again (:mod:`warp_subdiv.usd.resume`; the
    Result's ``reused`` lists them); a folder: keep them there; False: keep nothing. ``fresh``: remove what was
    kept first.
    """
    start = _time.perf_counter()
    _check_run(input_path, output_path, levels, vertex_order, skinning, max_influences)
    check_flatten(flatten, all_variants)
    if lod_variants is not None:
        lod_variants = check_lod_run(lod_variants, camera=camera, max_levels=max_levels, all_variants=all_variants,
                                     mesh_levels=mesh_levels, samples_only=samples_only)
        levels = max(lod_variants)  # the plan's (and the memory guard's) level of every mesh
    p = plan(input_path, levels, prims=prims, scheme=scheme, rules=rules, boundary=boundary,
             precision=precision, frames=frames, semi_sharp=semi_sharp, normals=normals, limit=limit,
             device=device, all_variants=all_variants, shipped=shipped, max_levels=max_levels, camera=camera,
             pixel_error=pixel_error, resolution=resolution, offscreen_level=offscreen_level,
             mesh_levels=mesh_levels, scene_levels=lod_variants is None,
             skinning=skinning, max_influences=max_influences)
    # the kept work's folder is cleaned and removed: the input must not read anything in it
    out_abs = check_output_path(output_path, p.stage, folders=[resume_folder(os.path.abspath(output_path))])
    tiled_items = _split_off_tiled(p, max_memory, out_abs, lod_variants=lod_variants, flatten=flatten)
    check_memory(p.estimates, max_memory, p.max_level)
    flatten = _flatten_for_lod(p, lod_variants, flatten)
    custom = layer_record(p, levels, limit=limit, normals=normals, semi_sharp=semi_sharp, vertex_order=vertex_order,
                          all_variants=all_variants, flatten=flatten, frames=frames,
                          skinning=skinning, max_influences=max_influences, lod_variants=lod_variants)
    layer = OutputLayer(out_abs, p.stage, custom)
    tiled = TiledMeshes(layer, out_abs, tiled_items, max_memory=max_memory, device=device, limit=limit,
                        normals=normals)
    bake = store = entries = None
    if resume and not lod_variants:  # (a mesh's LOD variants are written together: nothing to keep apart)
        store = Store(out_abs, fresh=fresh, folder=resume if isinstance(resume, str) else None)
        run = dict(limit=bool(limit), normals=bool(normals), semi_sharp=semi_sharp, frames=frames,
                   samples_only=bool(samples_only), device=device, skinning=skinning, max_influences=max_influences)
        entries = MeshEntries(store, p, list(p.levels), vertex_order=vertex_order, run=run)
    settings = dict(device=device, limit=limit, normals=normals, vertex_order=vertex_order,
                    samples_only=samples_only, batch=batch, max_memory=max_memory, shipped=shipped,
                    progress=progress)
    try:
        if lod_variants and flatten:
            bake, reports, merged = _flattened_levels(p, layer, settings, lod_variants, frames)
        else:
            bake = Bake(p, layer, lod_variants=lod_variants, resume=entries, **settings)
            reports, out_layout = bake.write()
            # bounding-box hints above the refined meshes: recomputed for the refined surfaces
            layer.override_extents_hints(p.stage, out_layout.hint_roots(p), frames)
            merged = None
        reports = reports + tiled.write()
        bake.warnings.extend(tiled.warnings)
        if progress is not None:
            progress(1.0, "writing " + os.path.basename(out_abs))
        layer.commit(flatten=flatten, flattened=merged)
        tiled.publish()
    except BaseException as exc:
        layer.discard()
        tiled.discard()
        if store is not None:
            store.failed(exc)
        raise
    finally:
        if bake is not None:
            bake.close()
    if store is not None:
        store.finish()  # the output is complete: nothing left to resume
    return Result(out_abs, reports, bake.warnings, _time.perf_counter() - start,
                  total_bytes(p.estimates, bake.ahead.concurrent), reused=bake.copied,
                  reused_samples=bake.reused_samples)


def _split_off_tiled(p: Plan, max_memory, out_abs: str, *, lod_variants, flatten) -> list:
    """The meshes that do not fit ``max_memory``, taken out of the plan to be refined in tiles
    (:mod:`warp_subdiv.usd.tiles`; the rest must fit): (prim, level, options) of each, a warning per mesh.
    A mesh that tiles cannot write is refused here, before anything is refined."""
    chosen = choose_tiled(p, max_memory)
    for i in chosen:
        check_tileable(p, i, lod_variants=lod_variants, flatten=flatten)
    items = [(p.prims[i], p.levels[i], p.options[i]) for i in chosen]
    if chosen:
        p.warnings.extend(f"{sp.path}: does not fit max_memory: refined in tiles ({os.path.basename(out_abs)}: "
                          f"{sp.prim.GetName()}_tiles, the mesh deactivated)" for sp, _, _ in items)
        without(p, chosen)
    return items


def _flatten_for_lod(p: Plan, lod_variants, flatten: bool) -> bool:
    """Whether the output is flattened: asked for, or LOD variants over meshes authored in the input's own layer
    stack, which no variant over them can beat (:mod:`warp_subdiv.usd.lod`; a warning says so)."""
    local = local_meshes(p.stage, [o.composed for o in p.scene.top.meshes]) if lod_variants else []
    if local and not flatten:
        p.warnings.append(f"lod_variants: {len(local)} mesh(es) authored in the input itself ({local[0]}"
                          f"{', ...' if len(local) > 1 else ''}) take their levels only in a flattened output: "
                          "the output is flattened")
        return True
    return flatten


def _flattened_levels(p: Plan, layer: OutputLayer, settings: dict, levels, frames):
    """LOD variants in a flattened output (:func:`~warp_subdiv.usd.lod.merge_levels`): one plain bake per level
    into ``layer`` (refined, checked and flattened, then cleared for the next), the flattened layers merged.
    Returns (the last bake, its reports, the merged layer); the bakes' warnings are gathered on the last."""
    flats, warnings, bake, reports = {}, [], None, []
    root = layer.layer.pseudoRoot
    for level in levels:
        for child in list(root.nameChildren):  # the previous level's bake
            del root.nameChildren[child.name]
        p.levels[:] = [level] * len(p.prims)
        bake = Bake(p, layer, **settings)
        try:
            reports, out_layout = bake.write()
            layer.override_extents_hints(p.stage, out_layout.hint_roots(p), frames)
        finally:
            bake.close()
        warnings += [w for w in bake.warnings if w not in warnings]
        flats[level] = layer.flatten()
    bake.warnings = warnings
    return bake, reports, merge_levels(flats, levels)


def _check_run(input_path, output_path, levels, vertex_order, skinning="bake", max_influences=None) -> None:
    """The run's arguments that the plan does not check: errors before the input is read."""
    check_vertex_order(vertex_order)
    check_skinning(skinning)
    check_max_influences(max_influences, skinning)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels", value=levels)
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    check_output_path(output_path)


__all__ = ["Bake", "Result", "refine_usd"]
