"""Resumable bakes: the finished work of a bake kept next to its output, so that a bake killed at any point
(SIGKILL, a lost Dask worker, a reboot) and run again with the same command redoes only what was missing.

The work is kept in ``<output>.resume/`` (:func:`resume_folder`, named like the distributed bake's chunk folder
after the output's full file name, :func:`beside`):

* a single-process bake (:func:`~warp_subdiv.usd.refine_usd`) keeps each refined mesh as soon as it is written
  (:class:`MeshEntries`): the specs the writer authored for it (an ``over`` with the refined points, topology,
  extents, normals, primvars, subsets and blocked attributes, with every time sample) copied into a small
  ``.usdc`` layer, with its report and warnings in the layer's ``customLayerData``, its large numeric arrays
  taken out and saved raw beside it (``.npy``: usd-core's crate writer compresses integer arrays, which cost
  more than writing them raw: about 2.5x in all on the benchmark's scene). A rerun copies the kept specs back into
  the output layer instead of refining the mesh: the output is the same layer, spec for spec;
* a distributed bake (:func:`~warp_subdiv.usd.bake`) keeps each finished task's chunk layer (a mesh, or a
  frame range of an animated one) with the task's result (:class:`UnitEntries`); a rerun submits only the
  tasks whose chunk is not kept.

Every entry is named by a content key (:func:`content_key`): the library version, the mesh's input digest (the
plan's key: every authored value and time sample the mesh refines from, as composed, so an edit anywhere in
the layer stack that changes the mesh changes it, and a file merely touched does not), its path, its level and
refinement options as passed to its refinement, and the run's options that decide the written values (limit
points, normals, semi-sharp handling, vertex order, frames, device). Entries whose key the run does not expect
(stale: another input, other options, an older version) are removed when the run starts. Every entry is
written under a temporary name and renamed, so a bake killed while it writes one leaves no entry that looks
finished (temporary names start with a dot and are removed by the next run).

The output itself is still written once, atomically, at the end. The folder is removed when the bake
succeeds, and when it fails on its input (:class:`~warp_subdiv.errors.SubdivInputError`: the input must change,
and the run leaves nothing behind); any other failure (an interrupt, a lost cluster, memory) keeps it. With
``fresh`` the kept work is removed before the bake starts.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import uuid
from dataclasses import asdict

import numpy as np
from pxr import Sdf, Vt

from ..errors import SubdivInputError
from ..io.usd_write import from_numpy
from ..version import __version__
from .order import resolved_vertex_order

#: Test hook: the environment variable that makes a bake kill its own process (SIGKILL) once it has kept this
#: many entries, for the tests of resumed bakes (a kill at a known point, without timing races).
KILL_ENV = "WARP_SUBDIV_TEST_KILL_AFTER"


def beside(output: str, kind: str) -> str:
    """The folder of a bake's ``kind`` of files next to ``output``, named after the output's full file name
    (``shot.usdc`` -> ``shot.usdc.<kind>``), so that outputs that differ only in their extension do not share
    it."""
    return f"{output}.{kind}"


def resume_folder(output: str) -> str:
    """The folder of a bake's kept work (``shot.usdc`` -> ``shot.usdc.resume``)."""
    return beside(output, "resume")


def content_key(*parts) -> str:
    """A digest of the library version and ``parts`` (plain values, whose ``repr`` is stable)."""
    return hashlib.sha256(repr((__version__,) + parts).encode()).hexdigest()


def eta_seconds(done: float, total: float, kept: float, elapsed: float) -> float | None:
    """Seconds left for a bake that has done ``done`` of ``total`` units of work in ``elapsed`` seconds, of
    which ``kept`` came from kept work (free, so not part of the rate); None before any work was done."""
    worked = done - kept
    if worked <= 0 or elapsed <= 0:
        return None
    return max(0.0, total - done) * elapsed / worked


def format_eta(seconds: float | None) -> str:
    """``seconds`` as a short label: "ETA 42s", "ETA 3m05s", "ETA 1h02m" ("" when unknown)."""
    if seconds is None:
        return ""
    s = int(round(seconds))
    if s < 60:
        return f"ETA {s}s"
    if s < 3600:
        return f"ETA {s // 60}m{s % 60:02d}s"
    return f"ETA {s // 3600}h{(s % 3600) // 60:02d}m"


class Store:
    """The folder of kept work of the bake that writes ``output`` (:func:`resume_folder`, or ``folder``):
    entries saved atomically (:meth:`save`), found by name (:meth:`find`), stale ones removed (:meth:`clean`),
    the folder removed when the bake is done (:meth:`finish`). ``fresh``: remove what was kept first."""

    def __init__(self, output: str, *, fresh: bool = False, folder: str | None = None):
        self.folder = folder or resume_folder(output)
        self.saved = 0
        if os.path.exists(self.folder) and not os.path.isdir(self.folder):
            raise SubdivInputError(f"{self.folder}: the folder of a resumable bake's kept work is a file; remove "
                                   "it or run with resume off", option="resume")
        if fresh:
            self.clear()

    def path(self, name: str) -> str:
        return os.path.join(self.folder, name)

    def find(self, name: str) -> str | None:
        """The entry ``name``'s path, or None where it is not kept."""
        path = self.path(name)
        return path if os.path.isfile(path) else None

    def clean(self, expected, owners=()) -> None:
        """Remove what the run does not expect (``expected`` names, and names of the parts of an expected
        entry: ``<owner>.samples-...`` for an ``owner`` in ``owners``, :class:`SampleChunks`): entries of other
        keys (stale) and temporary files of writes that were cut short. Called before any of the run's own entries
        is written."""
        if not os.path.isdir(self.folder):
            return
        keep, owners = set(expected), set(owners)
        for name in os.listdir(self.folder):
            if name not in keep and _owner(name) not in owners:
                full = self.path(name)
                shutil.rmtree(full, ignore_errors=True) if os.path.isdir(full) else _unlink(full)

    def save(self, name: str, write, *, counted: bool = True) -> None:
        """Write the entry ``name``: ``write(path)`` writes it at a temporary path in the folder, which is then
        renamed (an entry is complete or absent). ``counted``: counts towards :data:`KILL_ENV`."""
        os.makedirs(self.folder, exist_ok=True)
        stem, ext = os.path.splitext(name)
        tmp = self.path(f".{stem}.{uuid.uuid4().hex}{ext}")
        try:
            write(tmp)
            os.replace(tmp, self.path(name))
        finally:
            _unlink(tmp)
        if not counted:
            return
        self.saved += 1
        kill_after = os.environ.get(KILL_ENV)
        if kill_after and self.saved >= int(kill_after):
            os.kill(os.getpid(), signal.SIGKILL)

    def clear(self) -> None:
        """Remove the folder and everything kept in it."""
        shutil.rmtree(self.folder, ignore_errors=True)

    def finish(self) -> None:
        """The bake succeeded: nothing is left to resume."""
        self.clear()

    def failed(self, exc: BaseException) -> None:
        """The bake failed with ``exc``: keep the work unless the input is at fault (see the module docstring)."""
        if isinstance(exc, SubdivInputError):
            self.clear()


def _raw(value) -> bool:
    """Whether ``value`` is a large numeric Vt array (kept raw, :data:`RAW_ELEMENTS`)."""
    if not hasattr(type(value), "FromNumpy") or not hasattr(value, "__len__") or len(value) < RAW_ELEMENTS:
        return False
    try:
        return np.asarray(value).dtype.kind in "fiu"
    except Exception:  # noqa: BLE001 (a type numpy cannot view: kept in the entry layer)
        return False


def _owner(name: str) -> str | None:
    """The entry that the part ``name`` (``<owner>.samples-...``) belongs to, else None."""
    owner, sep, _ = name.partition(PART_TAG)
    return owner if sep else None


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def link_or_copy(source: str, dest: str) -> None:
    """Make ``dest`` a hard link to ``source`` (no copy of a chunk's data), else a copy where the file system
    has no hard links."""
    try:
        os.link(source, dest)
    except OSError:
        shutil.copyfile(source, dest)


def _slug(path: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in path.strip("/"))[:48] or "root"


def reads_other_prims(sp) -> bool:
    """Whether the refined values of mesh ``sp`` depend on prims other than its own, which its input digest (the
    plan's key) does not cover: a skinned mesh (a skeleton, its animation, blend shape targets and the transforms
    between them, :mod:`warp_subdiv.usd.skinning`) other than one whose binding is dropped. Such work is never
    reused."""
    skin = getattr(sp, "skin", None)
    return skin is not None and skin.mode != "none"


def mesh_key(unit: str, path: str, level: int, options, vertex_order: str, run: dict) -> str:
    """The content key of one refined mesh: its input digest ``unit`` (the plan's key), ``path``, ``level`` and
    refinement ``options`` as passed to its refinement, its resolved vertex order, and the run's options that
    decide the written values (``run``: limit, normals, semi_sharp, frames, samples_only, device)."""
    return content_key("mesh", unit, path, int(level), sorted(options.as_dict().items()),
                       resolved_vertex_order(vertex_order, options), sorted(run.items()))


#: Time samples of an animated mesh kept together (:class:`SampleChunks`), fewer where they hold more than
#: :data:`CHUNK_BYTES`.
CHUNK_SAMPLES = 16
#: Bytes of refined points and normals one chunk of time samples holds at most (one sample at least).
CHUNK_BYTES = 128 * 2**20

#: What separates a kept mesh's entry name (without its extension) from the name of one of its parts (its large
#: arrays, a chunk of its time samples).
PART_TAG = ".part-"
#: Arrays of at least this many elements are kept raw beside a mesh's entry layer, not in it (see
#: :meth:`MeshEntries.save`).
RAW_ELEMENTS = 256

#: The prim path a kept mesh's specs have inside its entry layer.
_ENTRY_ROOT = Sdf.Path("/Kept")


class MeshEntries:
    """The refined meshes of one single-process bake kept in a :class:`Store` (see the module docstring).

    ``p``: the bake's plan; ``levels``: each mesh's level, as its refinement gets it; ``run``: the run's options
    that decide the written values (:func:`mesh_key`). The stale entries are removed here."""

    def __init__(self, store: Store, p, levels, *, vertex_order: str, run: dict):
        self.store = store
        self.names = [f"mesh-{_slug(sp.path)}-{mesh_key(unit, sp.path, level, options, vertex_order, run)[:32]}.usdc"
                      for sp, unit, level, options in zip(p.prims, p.keys, levels, p.options)]
        found = set(os.listdir(store.folder)) if os.path.isdir(store.folder) else set()
        #: the meshes whose refined values depend on prims other than their own (a skeleton, its animation, blend
        #: shape targets, the transforms between them: :mod:`warp_subdiv.usd.skinning`), which their input digest
        #: does not cover: never kept, always refined
        self.volatile = {i for i, sp in enumerate(p.prims) if reads_other_prims(sp)}
        #: the meshes (plan indices) whose refined specs are kept: the bake copies them instead of refining
        self.kept = {i for i, name in enumerate(self.names) if name in found and i not in self.volatile}
        # chunks of samples are expected of the meshes not kept whole (a kill can come between the two)
        store.clean(self.names + [self._arrays(i) for i in range(len(self.names))],
                    [self._owner(i) for i in range(len(self.names)) if i not in self.kept])
        found = set(os.listdir(store.folder)) if os.path.isdir(store.folder) else set()
        owners = {_owner(n) for n in found}
        #: the meshes not kept whole that have time samples kept (:class:`SampleChunks`)
        self.partial = {i for i in range(len(self.names)) if i not in self.kept and self._owner(i) in owners}
        self._chunks: dict = {}  # mesh -> its SampleChunks (removed once the mesh is kept whole)

    def _owner(self, i: int) -> str:
        return self.names[i][: -len(".usdc")]

    def _samples_prefix(self, i: int) -> str:
        return self._owner(i) + PART_TAG + "samples-"

    def _arrays(self, i: int) -> str:
        return self._owner(i) + PART_TAG + "arrays.npy"

    def samples(self, i: int, group: int) -> "SampleChunks":
        """The kept time samples of mesh ``i``'s control mesh ``group`` (0 unless its topology changes over
        time), and where its refined samples are kept as they are written."""
        chunks = SampleChunks(self.store, f"{self._samples_prefix(i)}{group}-")
        self._chunks.setdefault(i, []).append(chunks)
        return chunks

    def load(self, i: int, layer, target: str):
        """Copy the kept specs of mesh ``i`` to ``target`` in the output ``layer`` (an
        :class:`~warp_subdiv.io.usd_write.OutputLayer`); returns (report fields, warnings), or None where the
        entry cannot be read (then the mesh is refined, and the entry is written again)."""
        path = self.store.find(self.names[i]) if i in self.kept else None
        if path is None:
            return None
        try:
            entry = Sdf.Layer.OpenAsAnonymous(path)
            record = json.loads(entry.customLayerData.get("warpSubdivKept", "null") or "null") if entry else None
        except Exception:  # noqa: BLE001 (a damaged entry, e.g. a disk that filled up: refined again)
            record = None
        if record is None or entry.GetPrimAtPath(_ENTRY_ROOT) is None:
            return None
        dest = Sdf.Path(str(target))
        Sdf.CreatePrimInLayer(layer.layer, dest)
        try:
            if not Sdf.CopySpec(entry, _ENTRY_ROOT, layer.layer, dest):
                raise OSError(f"could not copy {path}")
            if record.get("raw"):
                with open(self.store.path(self._arrays(i)), "rb") as arrays:
                    for attr, time, cls in record["raw"]:  # saved one after the other, in this order
                        at = Sdf.Path(attr).ReplacePrefix(_ENTRY_ROOT, dest)
                        value = from_numpy(getattr(Vt, cls), np.load(arrays, allow_pickle=False))
                        if time is None:
                            layer.layer.GetAttributeAtPath(at).default = value
                        else:
                            layer.layer.SetTimeSample(at, time, value)
        except Exception:  # noqa: BLE001 (a damaged entry: refined again)
            layer.remove(dest)  # nothing half-copied stays under what the writer writes
            return None
        return record["report"], record["warnings"]

    def save(self, i: int, layer, target: str, report, warnings) -> None:
        """Keep what the writer authored for mesh ``i`` at ``target`` (its subtree in the output layer), its
        ``report`` (a :class:`~warp_subdiv.usd.PrimReport`) and ``warnings``: the specs in an entry layer, less the
        values of at least :data:`RAW_ELEMENTS` numbers (defaults and time samples), which go raw into the
        entry's arrays file, saved first (the entry layer, which lists them, marks a complete entry)."""
        if i in self.volatile:
            return
        entry = Sdf.Layer.CreateAnonymous(".usdc")
        Sdf.CreatePrimInLayer(entry, _ENTRY_ROOT)
        if not Sdf.CopySpec(layer.layer, Sdf.Path(str(target)), entry, _ENTRY_ROOT):
            raise OSError(f"could not copy {target} into an entry")
        raw, arrays = [], []  # the large numeric arrays, taken out of the entry layer: saved raw

        def take(path):
            spec = entry.GetAttributeAtPath(path) if path.IsPropertyPath() else None
            if spec is None:
                return
            if spec.HasDefaultValue() and _raw(spec.default):
                raw.append((str(path), None, type(spec.default).__name__))
                arrays.append(np.asarray(spec.default))
                spec.ClearDefaultValue()
            for time in entry.ListTimeSamplesForPath(path):
                value = entry.QueryTimeSample(path, time)
                if _raw(value):
                    raw.append((str(path), time, type(value).__name__))
                    arrays.append(np.asarray(value))
                    entry.EraseTimeSample(path, time)

        entry.Traverse(_ENTRY_ROOT, take)
        entry.customLayerData = {"warpSubdivKept": json.dumps({"report": asdict(report), "warnings": list(warnings),
                                                               "raw": raw})}

        def write_arrays(tmp):  # .npy one after the other (no zip: its checksums cost more than the writes)
            with open(tmp, "wb") as f:
                for array in arrays:
                    np.save(f, array, allow_pickle=False)

        def write(tmp):
            if not entry.Export(tmp):
                raise OSError(f"could not write {tmp}")

        if arrays:  # first: the entry layer is the mark of a complete entry
            self.store.save(self._arrays(i), write_arrays, counted=False)
        self.store.save(self.names[i], write)
        for chunks in self._chunks.pop(i, ()):  # the mesh is kept whole: its chunks of samples are not needed
            for name in set(chunks.files.values()) | chunks.written:
                _unlink(self.store.path(name))


class SampleChunks:
    """The refined points (and normals) of an animated mesh's time samples, kept in chunks of
    :data:`CHUNK_SAMPLES` as the writer evaluates them, so that a bake killed inside a long animation resumes
    from its last chunk: :meth:`get` gives a kept sample's arrays (exactly those written), :meth:`add` keeps one,
    :meth:`flush` writes the pending chunk (``.npz``, atomically). Chunks are read one at a time, as the writer
    asks for their samples (in time order)."""

    def __init__(self, store: Store, prefix: str):
        self.store, self.prefix = store, prefix
        self.files: dict = {}  # time -> the chunk file that holds it
        names = os.listdir(store.folder) if os.path.isdir(store.folder) else []
        for name in sorted(n for n in names if n.startswith(prefix) and n.endswith(".npz")):
            try:
                with np.load(store.path(name)) as data:
                    times = data["times"].tolist()
            except (OSError, ValueError, KeyError):
                continue  # unreadable: its samples are refined again
            self.files.update((t, name) for t in times)
        self.loaded_name, self.loaded = None, {}
        self.pending: list = []
        self.written: set = set()  # the chunks this run wrote
        self.reused = 0  # samples given from kept chunks

    def get(self, t: float):
        """(points, normals or None) kept for time ``t``, or None."""
        name = self.files.get(t)
        if name is None:
            return None
        if name != self.loaded_name:
            with np.load(self.store.path(name)) as data:
                times = data["times"].tolist()
                has_normals = bool(data["has_normals"])
                self.loaded = {t: (data["points"][k], data["normals"][k] if has_normals else None)
                               for k, t in enumerate(times)}
            self.loaded_name = name
        self.reused += 1
        return self.loaded[t]

    def add(self, t: float, points, normals) -> None:
        """Keep the refined ``points`` and ``normals`` (or None) of time ``t``; a full chunk is written."""
        # copies: an evaluator may hand out its own buffers, which its next evaluation overwrites
        self.pending.append((t, np.array(points), None if normals is None else np.array(normals)))
        size = sum(p.nbytes + (0 if n is None else n.nbytes) for _, p, n in self.pending)
        if len(self.pending) >= CHUNK_SAMPLES or size >= CHUNK_BYTES:
            self.flush()

    def flush(self) -> None:
        """Write the pending samples as one chunk."""
        if not self.pending:
            return
        pending, self.pending = self.pending, []
        has_normals = pending[0][2] is not None

        def write(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, times=np.array([t for t, _, _ in pending], dtype=np.float64),
                         points=np.stack([p for _, p, _ in pending]), has_normals=np.array(has_normals),
                         normals=np.stack([n for _, _, n in pending]) if has_normals else np.zeros(0))

        name = f"{self.prefix}{pending[0][0]!r}.npz"
        self.store.save(name, write)
        self.written.add(name)


class UnitEntries:
    """The finished tasks of one distributed bake kept in a :class:`Store`: each task's chunk layer (``.usdc``,
    hard-linked from the chunk folder) and its result (``.json``, written after the layer: an entry is complete
    when both are there). ``keys``: each unit's content key (the units in the plan's order)."""

    def __init__(self, store: Store, units, keys, scene_folder: str = "scene"):
        self.store = store
        self.names = [f"unit-{u.number:04d}-{key[:32]}" for u, key in zip(units, keys)]
        self.scene_folder = scene_folder
        store.clean([n + ext for n in self.names for ext in (".usdc", ".json")] + [scene_folder])

    def load(self, number: int, dest: str):
        """Put the kept chunk layer of unit ``number`` at ``dest`` and return its task's result, or None."""
        name = self.names[number]
        layer, result = self.store.find(name + ".usdc"), self.store.find(name + ".json")
        if layer is None or result is None:
            return None
        with open(result) as f:
            record = json.load(f)
        link_or_copy(layer, dest)
        return record

    def spec(self, number: int) -> tuple:
        """What a task needs to keep its unit: (folder, entry name)."""
        return self.store.folder, self.names[number]

    @property
    def scene(self) -> str:
        """The folder where a whole-scene task keeps its meshes (:class:`MeshEntries`)."""
        return self.store.path(self.scene_folder)


def keep_unit(spec, layer_path: str, result: dict) -> None:
    """In a distributed bake's task: keep its finished chunk layer ``layer_path`` and ``result`` as entry
    ``spec`` (:meth:`UnitEntries.spec`), the layer first."""
    folder, name = spec
    store = Store("", folder=folder)
    store.save(name + ".usdc", lambda tmp: link_or_copy(layer_path, tmp), counted=False)

    def write(tmp):
        with open(tmp, "w") as f:
            json.dump(result, f)

    store.save(name + ".json", write, counted=False)


__all__ = ["CHUNK_BYTES", "CHUNK_SAMPLES", "KILL_ENV", "MeshEntries", "PART_TAG", "RAW_ELEMENTS", "SampleChunks",
           "Store", "UnitEntries", "beside", "content_key", "eta_seconds", "format_eta", "keep_unit", "link_or_copy",
           "mesh_key", "resume_folder"]
