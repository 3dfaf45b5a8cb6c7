"""Distributed USD bakes on Dask, and the stitching of chunk layers into one output.

:func:`bake` (``warp-subdiv refine ... --workers N`` or ``--scheduler ADDRESS``) refines the subdivision
meshes of a USD file on a Dask cluster: a local one of ``workers`` worker processes, or an existing one at
``scheduler``. The units of work are

* one mesh: a static mesh, or an animated one with too few time samples to split; its task writes a layer
  with the refined mesh (the single-process bake's ``refine_usd`` restricted to that prim), which becomes a
  sublayer of the output;
* one frame range of an animated mesh: a task refines the mesh's samples in the range (with the ``--frames``
  semantics, so values held or interpolated at the range's ends are written there) into its own chunk layer.
  Neighbouring ranges share their boundary sample, so values between two samples interpolate across chunks.
  The mesh's topology and tables are computed once by a topology task and shipped to its frame tasks
  (``refine_usd(..., shipped=)``, a :class:`~warp_subdiv.tables.Hierarchy`'s ``reuse``): the tasks read the mesh
  at their own frames but refine with the tables of the single-process bake, so they produce its values. A
  mesh's chunks after its first hold only time samples (``refine_usd(..., samples_only=True)``: no topology, no
  defaults), all that value clips read from them; saving the refined ``faceVertexIndices`` was most of a short
  chunk's cost.

Every task writes into a temporary folder next to the output. When all succeeded the driver stitches each
animated mesh's chunks as USD value clips (:func:`stitch_clips`: ``UsdUtils.StitchClipsTopology`` and
``StitchClipsManifest``, one clip set per mesh on the mesh prim), renames the folder to ``<output>.chunks``
(:func:`chunk_folder`: ``shot.usdc.chunks``, each output file its own) and writes the output layer last: clip
sets, then sublayers ``[topology, per-mesh layers..., input]``. A run whose input reads anything in that
folder is refused before any task starts. Any failure cancels the other tasks and removes the folder, so no
output and no chunk file is left; a worker that dies has its tasks rerun elsewhere by Dask. Each finished task
is kept in ``<output>.resume/`` (:mod:`warp_subdiv.usd.resume`): a rerun of a killed bake submits only the
tasks whose chunk is not kept. Each task applies
the memory guard against its worker's memory (the worker's memory limit, and ``max_memory`` when given).

:func:`stitch` (``warp-subdiv stitch``) assembles chunk layers that ``warp-subdiv refine --frames A:B`` runs
wrote (a farm scheduler launching them itself): no Dask needed.

Dask (``distributed``) is an optional dependency (``pip install 'warp-subdiv[distributed]'``), imported
only by :func:`bake`.
"""
from __future__ import annotations

import inspect
import math
import os
import re
import shutil
import tempfile
import time as _time
import uuid
from dataclasses import asdict, dataclass

from pxr import Sdf, Usd, UsdUtils, Vt

from ..errors import SubdivInputError
from ..io.files import current_umask
from ..io.usd_write import (USD_EXTENSIONS, OutputLayer, check_output_path, make_folders, relative_asset_path,
                            remove_folders)
from ..runtime import threads as th
from ..runtime.estimate import MemoryGuardError
from .planning import PrimReport, make_refiner, plan
from .clips import animated, clip_range, stitch_clips
from .record import check_same_refinement, layer_record
from .refine import Result, refine_usd
from .resume import (Store, UnitEntries, beside, content_key, eta_seconds, format_eta, keep_unit, reads_other_prims,
                     resume_folder)

#: Fewest time samples a frame chunk holds (an animated mesh with fewer than twice this is one unit).
MIN_CHUNK_SAMPLES = 4
#: Frame chunks per worker when ``chunk_frames`` is not given (load balance, and little lost to a dead worker).
CHUNKS_PER_WORKER = 3
#: The keywords of refine_usd that choose the meshes' levels (warp_subdiv.usd.levels).
LEVEL_KEYWORDS = ("max_levels", "camera", "pixel_error", "resolution", "offscreen_level", "mesh_levels")
#: Environment variable that makes tasks misbehave, for the tests (see _fault).
FAULT_ENV = "WARP_SUBDIV_TEST_FAULT"


@dataclass(frozen=True)
class Unit:
    """One task's work: a whole mesh (``kind`` "mesh"), a frame range of one (``kind`` "frames"), or every
    mesh at once (``kind`` "scene": a plan whose meshes are not each written at their own path only)."""

    number: int
    kind: str
    mesh: int  # index of the mesh in the plan (-1: all)
    path: str | None
    frames: tuple | None  # (start, end), None ends open; the run's own frames for "mesh" units
    layer: str  # file name in the chunk folder
    samples_only: bool = False  # a mesh's frame chunk after its first: time samples only (refine_usd's option)

    @property
    def label(self) -> str:
        if self.kind == "scene":
            return "every mesh"
        if self.kind == "mesh":
            return self.path
        a, b = self.frames
        return f"{self.path} frames {'' if a is None else f'{a:g}'}:{'' if b is None else f'{b:g}'}"


def _slug(path: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", path.strip("/")) or "root"


def plan_units(prims, frames, workers: int, chunk_frames: int | None = None, ext: str = ".usdc") -> list:
    """The units of a bake of ``prims`` (the plan's SubdivPrims): a mesh with at least 2 *
    MIN_CHUNK_SAMPLES selected point samples is split into frame ranges of ``chunk_frames`` samples (default:
    about CHUNKS_PER_WORKER ranges per worker), each range starting at the previous one's last sample. The
    ranges after a mesh's first are written with time samples only (the clips read nothing else from them; the
    first range's layer is the stitched topology's source)."""
    units = []
    for i, sp in enumerate(prims):
        times = list(sp.point_times)
        size = chunk_frames or max(MIN_CHUNK_SAMPLES, math.ceil(len(times) / (CHUNKS_PER_WORKER * max(1, workers))))
        size = max(1, int(size))
        if len(times) < 2 * MIN_CHUNK_SAMPLES or len(times) <= size:
            units.append(Unit(len(units), "mesh", i, sp.path, frames, f"{i:04d}_{_slug(sp.path)}{ext}"))
            continue
        starts = list(range(0, len(times), size))
        if len(times) - starts[-1] < max(2, size // 2) and len(starts) > 1:
            starts.pop()  # a short last range joins the one before
        for k, s in enumerate(starts):
            a = times[s] if k else (frames[0] if frames is not None else None)
            b = times[starts[k + 1]] if k + 1 < len(starts) else (frames[1] if frames is not None else None)
            units.append(Unit(len(units), "frames", i, sp.path, (a, b), f"{i:04d}_{_slug(sp.path)}.{k:04d}{ext}",
                              samples_only=k > 0))
    return units


# ------------------------------------------------------------------------------------------------ tasks
def _worker_setup(threads):
    """Per task on a worker: the thread count evaluation uses, and the worker's memory limit (bytes or None)."""
    import warp as wp

    wp.config.log_level = 30  # no start-up banner or module-load lines in the workers' logs
    th.set_default_threads(threads)
    limit = None
    try:
        from distributed import get_worker

        limit = get_worker().memory_manager.memory_limit or None
    except (ImportError, ValueError, AttributeError):  # not on a Dask worker
        pass
    return limit


def _fault(unit_number: int) -> None:
    """Test hook (FAULT_ENV): "sleep:SECONDS[:FOLDER]" (each task start also leaves FOLDER/<unit>.<pid>), or
    "fail:UNIT"."""
    spec = os.environ.get(FAULT_ENV, "")
    kind, _, arg = spec.partition(":")
    if kind == "sleep":
        seconds, _, folder = arg.partition(":")
        if folder:
            open(os.path.join(folder, f"{unit_number}.{os.getpid()}"), "w").close()
        _time.sleep(float(seconds))
    elif kind == "fail" and int(arg) == unit_number:
        raise SubdivInputError(f"unit {unit_number}: failure requested by {FAULT_ENV}")


def _memory(max_memory, worker_limit):
    limits = [m for m in (max_memory, worker_limit) if m]
    return min(limits) if limits else None


def _error_record(exc: SubdivInputError) -> dict:
    return {"type": type(exc).__name__, "message": str(exc), "option": exc.option, "element": exc.element,
            "index": exc.index, "value": repr(exc.value) if exc.value is not None else None}


def topology_task(input_path, path, levels, run, threads=None):
    """(hierarchy, seconds): the topology and tables of the mesh at ``path``, built as the single-process bake
    builds them (``run``: refine_usd's keywords), for the mesh's frame tasks."""
    start = _time.perf_counter()
    limit = _worker_setup(threads)
    p = plan(input_path, levels, prims=[path], **_plan_keywords(run))
    i = [sp.path for sp in p.prims].index(path)
    refiner = make_refiner(p.prims[i], p.levels[i], options=p.options[i], device=run.get("device"),
                           max_memory=_memory(run.get("max_memory"), limit), reuse=(p.analyses[i].hierarchy,))
    return refiner.hierarchy, _time.perf_counter() - start


def _seconds_of(topology):
    return topology[1]


def unit_task(input_path, folder, unit: Unit, levels, run, topology=None, threads=None, keep=None) -> dict:
    """Refine one unit into ``folder/unit.layer`` (written under a private name, then renamed); ``topology``:
    the mesh's (hierarchy, seconds) from :func:`topology_task`, or None. Returns its reports and warnings, or
    {"error": ...} for input errors (the driver raises them). ``keep``: where the finished unit is kept for a
    rerun of a killed bake (:meth:`~warp_subdiv.usd.resume.UnitEntries.spec`), or None."""
    start = _time.perf_counter()
    hierarchy = topology[0] if topology is not None else None
    limit = _worker_setup(threads)
    tmp = os.path.join(folder, f".{unit.layer}.{uuid.uuid4().hex}{os.path.splitext(unit.layer)[1]}")
    try:
        _fault(unit.number)
        keywords = {k: v for k, v in run.items() if k != "prims"}
        keywords.update(max_memory=_memory(run.get("max_memory"), limit), frames=unit.frames, flatten=False,
                        samples_only=unit.samples_only, shipped=(hierarchy,) if hierarchy is not None else ())
        # the whole scene in one task: its meshes are kept one by one beside the bake's units
        keywords["resume"] = os.path.join(keep[0], "scene") if keep is not None and unit.kind == "scene" else False
        prims = [unit.path] if unit.path is not None else run.get("prims")
        result = refine_usd(input_path, tmp, levels, prims=prims, **keywords)
        layer = Sdf.Layer.FindOrOpen(tmp)
        times = layer.ListAllTimeSamples()
        if unit.kind != "frames":
            layer.subLayerPaths.clear()  # a sublayer of the output, beside the input
            layer.Save()
        del layer
        os.replace(tmp, os.path.join(folder, unit.layer))
    except SubdivInputError as exc:
        return {"error": _error_record(exc)}
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    done = {"unit": unit.number, "reports": [asdict(r) for r in result.reports], "warnings": result.warnings,
            "times": (min(times), max(times)) if times else None, "seconds": result.seconds,
            "wall": _time.perf_counter() - start, "reused": result.reused}
    if keep is not None:
        keep_unit(keep, os.path.join(folder, unit.layer), done)
    return done


def _plan_keywords(run: dict) -> dict:
    keep = ("scheme", "rules", "boundary", "precision", "frames", "semi_sharp", "normals", "limit", "device",
            "all_variants", "skinning", "max_influences") + LEVEL_KEYWORDS
    return {k: run[k] for k in keep if k in run}


# ------------------------------------------------------------------------------------------------ the bake
def chunk_folder(output: str) -> str:
    """The folder of a distributed bake's chunks: named after the output's full file name (``shot.usdc`` ->
    ``shot.usdc.chunks``), so that outputs that differ only in their extension do not share it."""
    return beside(output, "chunks")


def stitch_folder(output: str) -> str:
    """The folder of a stitched output's topology and manifests (``shot.usda`` -> ``shot.usda.stitch``)."""
    return beside(output, "stitch")


class _Folder:
    """A temporary folder next to the output, renamed to ``final`` (default :func:`chunk_folder`) when it is
    complete. As a context manager: everything it holds is discarded when the block fails, and when it succeeds
    the older folder set aside is removed, and the folder itself where the output was flattened (``flatten``:
    its layers were copied into the output)."""

    def __init__(self, output: str, final: str | None = None, *, flatten: bool = False):
        self.output = output
        self.flatten = flatten
        parent = os.path.dirname(output)
        self.created = make_folders(parent)
        self.final = final or chunk_folder(output)
        self.path = tempfile.mkdtemp(prefix="." + os.path.basename(self.final) + "-", dir=parent)
        self.old = None

    def keep_only(self, names) -> None:
        """Remove files that are not ``names`` (temporary files of tasks whose worker died)."""
        keep = set(names)
        for name in os.listdir(self.path):
            if name not in keep:
                full = os.path.join(self.path, name)
                shutil.rmtree(full) if os.path.isdir(full) else os.unlink(full)

    def publish(self) -> None:
        """Move the finished folder to its final name (an older one aside, removed by :meth:`done`)."""
        if os.path.lexists(self.final):
            self.old = tempfile.mkdtemp(prefix="." + os.path.basename(self.final) + "-old-",
                                        dir=os.path.dirname(self.final))
            os.replace(self.final, os.path.join(self.old, "chunks"))
        os.chmod(self.path, 0o777 & ~current_umask())  # mkdtemp's 0700 would keep other users out of the chunks
        os.replace(self.path, self.final)
        self.path = self.final

    def done(self) -> None:
        if self.old:
            shutil.rmtree(self.old, ignore_errors=True)
            self.old = None
        if self.flatten:
            shutil.rmtree(self.final, ignore_errors=True)

    def __enter__(self) -> "_Folder":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if kind is None:
            self.done()
        else:
            self.discard()

    def discard(self) -> None:
        """Remove everything this bake wrote (and put an older chunk folder back)."""
        for _ in range(20):  # a task that was cancelled while it saved may add a file meanwhile
            shutil.rmtree(self.path, ignore_errors=True)
            if not os.path.exists(self.path):
                break
            _time.sleep(0.1)
        if self.old:
            os.replace(os.path.join(self.old, "chunks"), self.final)
            shutil.rmtree(self.old, ignore_errors=True)
            self.old = None
        remove_folders(self.created)


def _sweep_killed(output: str) -> None:
    """Remove the temporary chunk folders that killed bakes of ``output`` left (``.<name>.chunks-*``): their
    finished chunks are kept in the resume folder (hard links to the same files). One bake per output at a time."""
    parent, prefix = os.path.dirname(output), "." + os.path.basename(chunk_folder(output)) + "-"
    for name in os.listdir(parent) if os.path.isdir(parent) else ():
        if name.startswith(prefix) and os.path.isdir(os.path.join(parent, name)):
            shutil.rmtree(os.path.join(parent, name), ignore_errors=True)


def _client(workers, scheduler):
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise SubdivInputError("a distributed bake (workers, scheduler) needs Dask: pip install "
                               "'warp-subdiv[distributed]' (or 'distributed')", option="workers") from None
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise SubdivInputError(f"scheduler {scheduler}: cannot connect ({exc})", option="scheduler",
                                   value=scheduler) from None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=50)
    return Client(cluster), cluster


def bake(input_path: str, output_path: str, levels: int, *, workers: int | None = None,
         scheduler: str | None = None, chunk_frames: int | None = None, threads: int | None = None,
         progress=None, client=None, **run):
    """Refine the subdivision meshes of ``input_path`` on a Dask cluster and write ``output_path`` (see the
    module docstring). ``run``: :func:`warp_subdiv.usd.refine_usd`'s keywords (prims, scheme, rules, boundary,
    device, precision, frames, limit, normals, max_memory, flatten, semi_sharp, vertex_order: each
    task passes it on, so every chunk numbers the refined vertices alike; resume and fresh: the finished tasks
    are kept for a rerun, :mod:`warp_subdiv.usd.resume`). ``workers``: worker processes
    of a local cluster (default: the cores this process may use); ``scheduler``: the address of an existing
    cluster's scheduler instead; ``client``: an existing ``distributed.Client``. ``threads``: evaluation
    threads per task (default: the local cluster's share of the cores, a remote worker's own cores).
    Returns a :class:`warp_subdiv.usd.Result`."""
    start = _time.perf_counter()
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 0:
        raise SubdivInputError(f"levels must be an integer >= 0, got {levels!r}", option="levels", value=levels)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise SubdivInputError(f"workers must be an integer >= 1, got {workers!r}", option="workers",
                               value=workers)
    if chunk_frames is not None and (not isinstance(chunk_frames, int) or chunk_frames < 1):
        raise SubdivInputError(f"chunk_frames must be an integer >= 1, got {chunk_frames!r}",
                               option="chunk_frames", value=chunk_frames)
    threads = th.check_threads(threads)
    if run.get("lod_variants") is not None:
        raise SubdivInputError("lod_variants does not combine with a distributed bake (workers, scheduler)",
                               option=("lod_variants", "workers"))
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    check_output_path(output_path)
    flatten = bool(run.pop("flatten", False))
    resume, fresh = run.pop("resume", True), bool(run.pop("fresh", False))
    run.setdefault("max_memory", None)
    p = plan(input_path, levels, **{k: v for k, v in _plan_keywords(run).items()}, prims=run.get("prims"))
    if run.get("camera") is not None:  # the tasks see their own frames only: they take the levels chosen here
        for key in LEVEL_KEYWORDS:
            run.pop(key, None)
        run["mesh_levels"] = {path: level for path, (level, _) in p.level_sources.items()}
    # the chunk and kept work's folders are replaced as a whole: the input must not read anything in them
    given = os.path.abspath(output_path)
    out_abs = check_output_path(output_path, p.stage, folders=[chunk_folder(given), resume_folder(given)])
    run.pop("progress", None)

    timings = {"plan_s": _time.perf_counter() - start}
    own = client is None
    cluster = None
    if own:
        t = _time.perf_counter()
        client, cluster = _client(workers or th.available_cores(), scheduler)
        timings["cluster_s"] = _time.perf_counter() - t
    try:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or (workers or 1))
        if threads is None and cluster is not None:
            threads = max(1, th.available_cores() // n_workers)
        ext = ".usdc"
        if p.one_place_each:
            units = plan_units(p.prims, run.get("frames"), n_workers, chunk_frames, ext)
        else:  # instances, shared or variant refinements: one task bakes the plan as the single process does
            units = [Unit(0, "scene", -1, None, run.get("frames"), "scene" + ext)]
        store = Store(out_abs, fresh=fresh) if resume else None
        if store is not None:
            _sweep_killed(out_abs)
        entries = UnitEntries(store, units, [unit_key(p, u, levels, run) for u in units]) if resume else None
        with _Folder(out_abs, flatten=flatten) as folder:
            t = _time.perf_counter()
            kept = {}  # units finished by an earlier run of this bake: their layers are linked in, not refined
            for u in units if entries is not None else ():
                found = entries.load(u.number, os.path.join(folder.path, u.layer))
                if found is not None:
                    kept[u.number] = found
            try:
                results = _run_units(client, input_path, folder.path, [u for u in units if u.number not in kept],
                                     p, levels, run, threads, progress, timings, entries, unit_weights(p, units))
            except BaseException as exc:
                if store is not None:
                    store.failed(exc)
                raise
            results.update(kept)
            timings["tasks_s"] = _time.perf_counter() - t
            reports, warnings = _merge(p, units, results)
            names = {u.layer for u in units}
            folder.keep_only(names)
            out = _write_output(p, out_abs, folder, units, results, levels, run, flatten, n_workers, timings)
    finally:
        if own:
            client.close()
        if cluster is not None:
            cluster.close()
    if store is not None:
        store.finish()  # the output is complete: nothing left to resume
    result = Result(out, reports, list(dict.fromkeys(p.warnings + warnings)), _time.perf_counter() - start,
                    p.predicted_bytes, reused=[u.label for u in units if u.number in kept]
                    + [path for u in units if u.number not in kept for path in results[u.number].get("reused", ())])
    timings["units"] = [{"kind": u.kind, "path": u.path, "frames": u.frames, "seconds": results[u.number]["seconds"],
                         "wall": results[u.number]["wall"]} for u in units]
    timings["workers"] = n_workers
    result.timings = timings  # where the time went (bench/bench_distributed.py reads it)
    return result


def unit_key(p, u: Unit, levels, run) -> str:
    """The content key of unit ``u`` (:mod:`warp_subdiv.usd.resume`): what it is (number, kind, path, frames,
    chunk layer), its meshes' input digests, levels and options as their refinement gets them, ``levels``, and the
    run's options that decide the written values (``run``: :func:`bake`'s; not its memory limit)."""
    meshes = range(len(p.prims)) if u.mesh < 0 else [u.mesh]
    # a mesh unit that reads other prims (a skinned mesh) gets a key no later run matches: refined every time
    fresh = [os.urandom(16).hex()] if u.mesh >= 0 and reads_other_prims(p.prims[u.mesh]) else []
    return content_key("unit", *fresh, u.number, u.kind, u.path, u.frames, u.samples_only, u.layer, int(levels),
                       [(p.keys[i], int(p.levels[i]), sorted(p.options[i].as_dict().items())) for i in meshes],
                       [(k, repr(run.get(k, default))) for k, default in _VALUE_DEFAULTS.items()])


#: refine_usd's keywords that decide the written values, with their defaults (a run that leaves one out and a
#: run that passes its default bake the same units).
_VALUE_DEFAULTS = {name: param.default for name, param in inspect.signature(refine_usd).parameters.items()
                   if name in ("prims", "scheme", "rules", "boundary", "device", "precision", "frames", "limit",
                               "normals", "semi_sharp", "all_variants", "vertex_order", "skinning",
                               "max_influences", "max_levels", "camera", "pixel_error", "resolution",
                               "offscreen_level", "mesh_levels")}


def unit_weights(p, units) -> dict:
    """Each unit's predicted cost (refined vertices x the samples it writes), for the progress's ETA."""
    weights = {}
    for u in units:
        meshes = range(len(p.prims)) if u.mesh < 0 else [u.mesh]
        total = 0
        for i in meshes:
            times = p.prims[i].point_times
            if u.kind == "frames":
                a, b = u.frames
                times = [t for t in times if (a is None or t >= a) and (b is None or t <= b)]
            total += (p.estimates[i].final.vertices or 1) * max(1, len(times))
        weights[u.number] = total
    return weights


def _run_units(client, input_path, folder, units, p, levels, run, threads, progress, timings, entries=None,
               weights=None) -> dict:
    """Submit the topology and unit tasks; wait for all of them. The first failure cancels the rest and is
    raised (input errors as SubdivInputError). ``entries``: where the finished units are kept
    (:class:`~warp_subdiv.usd.resume.UnitEntries`); ``weights``: the units' predicted costs (the ETA)."""
    from distributed import as_completed

    by_number = {u.number: u for u in units}
    weights = weights or {}
    total = sum(weights.values()) or 1
    kept = total - sum(weights.get(u.number, 0) for u in units)
    done_weight, start = kept, _time.perf_counter()

    topo = {}
    for u in units:
        if u.kind == "frames" and u.mesh not in topo:
            topo[u.mesh] = client.submit(topology_task, input_path, u.path, levels, run, threads, pure=False,
                                         key=f"warp-subdiv-topology-{u.mesh}-{uuid.uuid4().hex}")
    futures = [client.submit(unit_task, input_path, folder, u, levels, run, topo.get(u.mesh), threads,
                             entries.spec(u.number) if entries is not None else None,
                             pure=False, key=f"warp-subdiv-unit-{u.number}-{uuid.uuid4().hex}") for u in units]
    seconds = [client.submit(_seconds_of, f, pure=False) for f in topo.values()]
    results = {}
    try:
        for done, (future, value) in enumerate(as_completed(futures, with_results=True), 1):
            if isinstance(value, dict) and "error" in value:
                raise _reraise(value["error"])
            results[value["unit"]] = value
            done_weight += weights.get(value["unit"], 0)
            if progress is not None:
                eta = format_eta(eta_seconds(done_weight, total, kept, _time.perf_counter() - start))
                progress(done / (len(units) + 1),
                         f"[{done}/{len(units)}] {by_number[value['unit']].label}" + (f" ({eta})" if eta else ""))
        timings["topology_s"] = client.gather(seconds)
    except BaseException:
        client.cancel(futures + list(topo.values()))
        _wait_idle(client, {f.key for f in futures})
        raise
    finally:
        for f in topo.values():
            f.release()
    return results


def _executing(dask_worker=None):
    """The keys of the tasks a worker is running (cancelled ones too: Dask cannot interrupt a task)."""
    return [str(ts.key) for ts in dask_worker.state.executing]


def _wait_idle(client, keys, timeout: float = 60.0) -> None:
    """Wait until no worker runs any of ``keys`` (cancelled tasks run to their end), so that none writes into
    the folder after it is removed."""
    end = _time.monotonic() + timeout
    while _time.monotonic() < end:
        try:
            running = client.run(_executing)
        except Exception:  # noqa: BLE001 (a cluster going away: nothing runs any more)
            return
        if not any(k in keys for ks in running.values() for k in ks):
            return
        _time.sleep(0.1)


def _reraise(record: dict) -> SubdivInputError:
    cls = MemoryGuardError if record["type"] == "MemoryGuardError" else SubdivInputError
    return cls(record["message"], option=record["option"], element=record["element"], index=record["index"],
               value=record["value"])


def _merge(p, units, results):
    """One report per mesh (samples counted once where chunks share a boundary) and the tasks' warnings."""
    reports, warnings = [], []
    if units[0].kind == "scene":
        res = results[0]
        return [PrimReport(**r) for r in res["reports"]], [w for w in res["warnings"] if w not in p.warnings]
    for i, sp in enumerate(p.prims):
        mine = [results[u.number] for u in units if u.mesh == i]
        rows = [r for res in mine for r in res["reports"] if r["path"] == sp.path]
        first = dict(rows[0])
        first["seconds"] = sum(r["seconds"] for r in rows)
        first["samples"] = max(1, len(sp.point_times)) if len(rows) > 1 else first["samples"]
        reports.append(PrimReport(**first))
        for res in mine:
            warnings += [w for w in res["warnings"] if w not in p.warnings]
    return reports, warnings


def _write_output(p, out_abs, folder, units, results, levels, run, flatten, n_workers, timings) -> str:
    """Stitch the chunks, move the folder into place and write the output layer (last)."""
    frames = run.get("frames")
    custom = layer_record(p, levels, limit=bool(run.get("limit")), normals=bool(run.get("normals")),
                          semi_sharp=run.get("semi_sharp", "keep"), vertex_order=run.get("vertex_order", "auto"),
                          all_variants=bool(run.get("all_variants")), flatten=flatten, frames=frames)
    custom["warpSubdiv"]["distributed"] = {"workers": int(n_workers), "tasks": len(units)}
    layer = OutputLayer(out_abs, p.stage, custom)
    try:
        final = folder.final
        clips = {}
        for u in units:
            if u.kind != "frames":
                continue
            rng = results[u.number]["times"]
            start = u.frames[0] if u.frames[0] is not None else (rng[0] if rng else 0.0)
            end = u.frames[1] if u.frames[1] is not None else (rng[1] if rng else start)
            path = os.path.join(folder.path, u.layer)
            clips.setdefault(u.path, []).append((path, float(start), float(end)))
        t = _time.perf_counter()
        # the first chunk of each mesh is the topology's source: one plan refined the chunks, its defaults are
        # the single bake's, and the later chunks hold time samples only (Unit.samples_only)
        firsts = [chunks[0][0] for chunks in clips.values()]
        topo = stitch_clips(layer.layer, folder.path, clips, firsts, p.stage) if clips else None
        timings["stitch_s"] = _time.perf_counter() - t
        t = _time.perf_counter()
        # asset paths were written for the temporary folder: point them at the final one
        _retarget(layer.layer, folder.path, final)
        subs = [os.path.join(final, "topology.usdc")] if topo else []
        subs += [os.path.join(final, u.layer) for u in units if u.kind != "frames"]
        anchor = os.path.dirname(out_abs)
        for k, s in enumerate(subs):
            layer.layer.subLayerPaths.insert(k, relative_asset_path(s, anchor))
        folder.publish()
        layer.override_extents_hints(p.stage, {sp.path: sp.point_times for sp in p.prims}, frames)
        layer.commit(flatten=flatten)
        timings["commit_s"] = _time.perf_counter() - t
    except BaseException:
        layer.discard()
        raise
    return out_abs


def _retarget(layer: Sdf.Layer, old_dir: str, new_dir: str) -> None:
    """Rewrite the clip asset paths of ``layer`` that point into ``old_dir`` to point into ``new_dir``."""
    anchor = os.path.dirname(layer.realPath or layer.identifier)
    old_rel = relative_asset_path(old_dir, anchor)
    new_rel = relative_asset_path(new_dir, anchor)

    def fix(value):
        return value.replace(old_rel + "/", new_rel + "/", 1) if value.startswith(old_rel + "/") else value

    def visit(path):
        if not path.IsPrimPath():
            return
        spec = layer.GetPrimAtPath(path)
        if "clips" not in spec.ListInfoKeys():
            return
        clips = dict(spec.GetInfo("clips"))
        for name, data in clips.items():
            data = dict(data)
            data["assetPaths"] = Sdf.AssetPathArray([fix(a.path) for a in data["assetPaths"]])
            data["manifestAssetPath"] = Sdf.AssetPath(fix(data["manifestAssetPath"].path))
            clips[name] = data
        spec.SetInfo("clips", clips)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)


# ------------------------------------------------------------------------------------------------ stitch
def stitch(chunk_paths, output_path: str, *, flatten: bool = False):
    """Assemble the layers that ``warp-subdiv refine IN -o CHUNK --frames A:B`` runs wrote (the same input,
    levels and options, frame ranges in any order) into ``output_path``: each animated refined mesh gets a
    clip set over the chunks, everything else comes from the first chunk (``<output>.stitch/topology.usdc``,
    :func:`stitch_folder`).
    Chunks stay where they are and are referenced by relative paths. Ranges that share their ends (1:25,
    25:50) interpolate across chunk boundaries; with 1:25, 26:50 values between 25 and 26 hold at 25.
    Returns a :class:`warp_subdiv.usd.Result` (no reports)."""
    start = _time.perf_counter()
    if not chunk_paths:
        raise SubdivInputError("stitch needs at least one chunk layer")
    chunks = []
    for path in chunk_paths:
        if os.path.splitext(path)[1].lower() not in USD_EXTENSIONS:
            raise SubdivInputError(f"{path}: a chunk must be a .usd, .usda or .usdc layer")
        if not os.path.isfile(path):
            raise SubdivInputError(f"{path}: no such file")
        layer = Sdf.Layer.FindOrOpen(os.path.abspath(path))
        info = dict(layer.customLayerData).get("warpSubdiv") if layer is not None else None
        if not info:
            raise SubdivInputError(f"{path}: not a layer written by warp-subdiv refine")
        if len(layer.subLayerPaths) != 1:
            raise SubdivInputError(f"{path}: a flattened layer cannot be stitched (refine the chunks without "
                                   "flattening)")
        source = os.path.normpath(os.path.join(os.path.dirname(layer.realPath), layer.subLayerPaths[0]))
        frames = None
        if info.get("frames"):
            a, _, b = info["frames"].partition(":")
            frames = (float(a) if a else None, float(b) if b else None)
        chunks.append((layer, info, source, frames))
    first = chunks[0]
    check_same_refinement([(layer.realPath, info) for layer, info, _, _ in chunks])
    for layer, info, source, _ in chunks[1:]:
        if source != first[2]:
            raise SubdivInputError(f"{layer.realPath}: refines {source}, {first[0].realPath} refines {first[2]}")
    ranges = [(clip_range(layer, frames), layer) for layer, _, _, frames in chunks]
    ranges.sort(key=lambda r: r[0])
    for (r0, l0), (r1, l1) in zip(ranges, ranges[1:]):
        if r1[0] < r0[1] or r0 == r1:
            raise SubdivInputError(f"{l1.realPath}: its frames {r1[0]:g}:{r1[1]:g} overlap those of {l0.realPath} "
                                   f"({r0[0]:g}:{r0[1]:g}) beyond a shared end")
    out_abs = check_output_path(output_path)
    files = [layer.realPath for _, layer in ranges]
    if os.path.realpath(out_abs) in {os.path.realpath(f) for f in files}:
        raise SubdivInputError(f"{output_path}: is one of the chunks to stitch; write the stitched layer somewhere "
                               "else")
    if not os.path.exists(first[2]):
        raise SubdivInputError(f"{first[2]}: the chunks' input is missing")
    stage = Usd.Stage.Open(first[2])
    out_abs = check_output_path(output_path, stage, folders=[stitch_folder(out_abs)], reads=files)
    prims = list(first[1].get("prims") or [])
    clips = {}
    for path in prims:
        if any(animated(layer, path) for _, layer in ranges):
            clips[path] = [(layer.realPath, r[0], r[1]) for r, layer in ranges]
    custom = {"warpSubdiv": dict(first[1])}
    custom["warpSubdiv"]["frames"] = f"{ranges[0][0][0]:g}:{ranges[-1][0][1]:g}"
    custom["warpSubdiv"]["stitched"] = Vt.StringArray([relative_asset_path(f, os.path.dirname(out_abs))
                                                       for f in files])
    custom["warpSubdiv"]["flattened"] = bool(flatten)
    with _Folder(out_abs, stitch_folder(out_abs), flatten=flatten) as folder:
        layer = OutputLayer(out_abs, stage, custom)
        try:
            # one refinement wrote every chunk: their static content is the same, the first one's defaults
            # are those of a run over all the frames
            topo = stitch_clips(layer.layer, folder.path, clips, files[:1], stage)
            if topo is None:  # nothing animated: the first chunk's content is the topology
                topo = os.path.join(folder.path, "topology.usdc")
                t = Sdf.Layer.CreateNew(topo)
                UsdUtils.StitchClipsTopology(t, files[:1])
                t.subLayerPaths.clear()
                t.customLayerData = {}
                t.Save()
            _retarget(layer.layer, folder.path, folder.final)
            layer.layer.subLayerPaths.insert(0, relative_asset_path(os.path.join(folder.final, "topology.usdc"),
                                                                    os.path.dirname(out_abs)))
            folder.publish()
            layer.commit(flatten=flatten)
        except BaseException:
            layer.discard()
            raise
    return Result(out_abs, [], [], _time.perf_counter() - start, 0)
