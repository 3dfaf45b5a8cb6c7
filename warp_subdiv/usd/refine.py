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
from .planning import Plan, PrimReport, make_refiner, plan
from .record import layer_record
from .refinement import MeshRefinement
from .resume import CHUNK_SAMPLES, MeshEntries, SampleChunks, Store, eta_seconds, format_eta, resume_folder
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

    def __init__(self, p: Plan, layer: OutputLayer, levels: int, *, device, limit, normals, vertex_order,
                 samples_only: bool, batch: bool, max_memory, shipped, progress, resume: MeshEntries | None = None):
        self.plan, self.layer, self.levels = p, layer, levels
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
            self.batches = Batches(p, levels, device, limit, normals, refiner=self.refiner,
                                   defaults=not samples_only, shipped=self.shipped)
            for i in self.reused:  # not evaluated with their chunk
                chunk = self.batches.chunk_of.pop(i, None)
                if chunk is not None:
                    chunk.remove(i)
        # animated meshes refined on their own keep their time samples in chunks as they are written
        self.chunked = {i for i, sp in enumerate(p.prims) if resume is not None
                        and len(sp.point_times) >= 2 * CHUNK_SAMPLES
                        and (self.batches is None or i not in self.batches.chunk_of)}
        self.ahead = Ahead(self, max_memory)

    def refiner(self, i: int, sp) -> Refiner:
        """The refiner of control mesh ``sp`` of prim ``i`` (the prim as planned, or one topology of it,
        :meth:`~warp_subdiv.io.usd_read.SubdivPrim.with_topology`): it starts from a shipped hierarchy, else from
        the plan's level-0 analysis, where one fits (:func:`~warp_subdiv.usd.make_refiner`)."""
        p = self.plan
        analysis = p.analyses[i]
        reuse = self.shipped + ((analysis.hierarchy,) if analysis is not None else ())
        refiner = make_refiner(sp, self.levels, options=p.options[i], device=self.device, reuse=reuse)
        if analysis is not None and self.levels > 0 and not sp.topologies:
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
        return MeshRefinement(sp, refiner, self.plan.options[i], self.levels, self.limit, self.normals,
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
    resume: bool | str = True,
    fresh: bool = False,
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
    ``flatten``: write one self-contained layer, the composed stage flattened (instead of a layer over the
    input); it holds the selected variants only, and is refused with ``all_variants``.
    ``shipped``: hierarchies built elsewhere (a distributed bake's topology task ships a mesh's tables to the
    tasks that refine its frames, :mod:`warp_subdiv.usd.distributed`): the refiner of a mesh that one of them
    fits starts from it (:meth:`~warp_subdiv.tables.Hierarchy.fits`), and such a mesh is not batched.
    ``resume``: keep each refined mesh in ``<output>.resume/`` as it is written, and copy the meshes an earlier
    run of the same bake kept there instead of refining them again (:mod:`warp_subdiv.usd.resume`; the
    Result's ``reused`` lists them); a folder: keep them there; False: keep nothing. ``fresh``: remove what was
    kept first.
    """
    start = _time.perf_counter()
    _check_run(input_path, output_path, levels, vertex_order)
    check_flatten(flatten, all_variants)
    p = plan(input_path, levels, prims=prims, scheme=scheme, rules=rules, boundary=boundary,
             precision=precision, frames=frames, semi_sharp=semi_sharp, normals=normals, limit=limit,
             device=device, all_variants=all_variants, shipped=shipped)
    # the kept work's folder is cleaned and removed: the input must not read anything in it
    out_abs = check_output_path(output_path, p.stage, folders=[resume_folder(os.path.abspath(output_path))])
    check_memory(p.estimates, max_memory, levels)
    custom = layer_record(p, levels, limit=limit, normals=normals, semi_sharp=semi_sharp, vertex_order=vertex_order,
                          all_variants=all_variants, flatten=flatten, frames=frames)
    layer = OutputLayer(out_abs, p.stage, custom)
    bake = store = None
    try:
        entries = None
        if resume:
            store = Store(out_abs, fresh=fresh, folder=resume if isinstance(resume, str) else None)
            entries = MeshEntries(store, p, [levels] * len(p.prims), vertex_order=vertex_order,
                                  run=dict(limit=bool(limit), normals=bool(normals), semi_sharp=semi_sharp,
                                           frames=frames, samples_only=bool(samples_only), device=device))
        bake = Bake(p, layer, levels, device=device, limit=limit, normals=normals, vertex_order=vertex_order,
                    samples_only=samples_only, batch=batch, max_memory=max_memory, shipped=shipped,
                    progress=progress, resume=entries)
        reports, out_layout = bake.write()
        # bounding-box hints above the refined meshes: recomputed for the refined surfaces
        layer.override_extents_hints(p.stage, out_layout.hint_roots(p), frames)
        if progress is not None:
            progress(1.0, "writing " + os.path.basename(out_abs))
        layer.commit(flatten=flatten)
    except BaseException as exc:
        layer.discard()
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


def _check_run(input_path, output_path, levels, vertex_order) -> None:
    """The run's arguments that the plan does not check: errors before the input is read."""
    check_vertex_order(vertex_order)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels", value=levels)
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    check_output_path(output_path)


__all__ = ["Bake", "Result", "refine_usd"]
