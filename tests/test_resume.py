"""Resumable bakes: a bake killed after some meshes (a subprocess killed by the library's test hook, a Dask
bake's client process killed while tasks run) and run again with the same command writes the layer an
uninterrupted bake writes and refines only what was missing; stale kept work is not reused; ``--fresh``."""
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd import refine_usd
from warp_subdiv.usd import resume as rs

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
T = Sdf.ValueTypeNames


def _grid(n, lift, seed):
    """An n x n grid of quads, noisy heights: (points, counts, indices)."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(n + 1, dtype=float), np.arange(n + 1, dtype=float))
    pts = np.stack([xs.ravel(), ys.ravel(), lift + 0.2 * rng.standard_normal(xs.size)], 1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    quads = np.stack([i, i + 1, i + n + 2, i + n + 1], -1).reshape(-1)
    return pts, np.full(n * n, 4, np.int32), quads.astype(np.int32)


def make_scene(path, meshes=6, animated=True, seed=0, samples=12, animated_cells=None):
    """``meshes`` grids of different sizes (small ones batched, larger ones refined alone) with a vertex
    primvar, a face-varying one and a face subset, and an animated grid of ``samples`` samples (of
    ``animated_cells`` x ``animated_cells`` quads, else the size its place gives it)."""
    layer = Sdf.Layer.CreateNew(path)
    world = Sdf.CreatePrimInLayer(layer, "/World")
    world.specifier, world.typeName = Sdf.SpecifierDef, "Xform"
    layer.defaultPrim = "World"
    for k in range(meshes + (1 if animated else 0)):
        n = animated_cells if animated and k == meshes and animated_cells else 3 + 3 * (k % 4)
        pts, counts, idx = _grid(n, float(k), seed + k)
        prim = Sdf.CreatePrimInLayer(layer, f"/World/Grid_{k}")
        prim.specifier, prim.typeName = Sdf.SpecifierDef, "Mesh"
        points = Sdf.AttributeSpec(prim, "points", T.Point3fArray)
        points.default = Vt.Vec3fArray.FromNumpy(pts.astype(np.float32))
        if animated and k == meshes:
            for t in range(1, samples + 1):
                layer.SetTimeSample(points.path, float(t), Vt.Vec3fArray.FromNumpy((pts * (1 + 0.01 * t)).astype(np.float32)))
        Sdf.AttributeSpec(prim, "faceVertexCounts", T.IntArray).default = Vt.IntArray.FromNumpy(counts)
        Sdf.AttributeSpec(prim, "faceVertexIndices", T.IntArray).default = Vt.IntArray.FromNumpy(idx)
        Sdf.AttributeSpec(prim, "subdivisionScheme", T.Token, Sdf.VariabilityUniform).default = "catmullClark"
        heat = Sdf.AttributeSpec(prim, "primvars:heat", T.FloatArray)
        heat.default = Vt.FloatArray.FromNumpy(pts[:, 2].astype(np.float32))
        heat.SetInfo("interpolation", "vertex")
        st = Sdf.AttributeSpec(prim, "primvars:st", T.TexCoord2fArray)
        st.default = Vt.Vec2fArray.FromNumpy(pts[idx, :2].astype(np.float32))
        st.SetInfo("interpolation", "faceVarying")
        sub = Sdf.CreatePrimInLayer(layer, f"/World/Grid_{k}/Top")
        sub.specifier, sub.typeName = Sdf.SpecifierDef, "GeomSubset"
        Sdf.AttributeSpec(sub, "elementType", T.Token, Sdf.VariabilityUniform).default = "face"
        Sdf.AttributeSpec(sub, "indices", T.IntArray).default = Vt.IntArray(list(range(0, n * n, 2)))
    layer.Save()
    return [f"/World/Grid_{k}" for k in range(meshes + (1 if animated else 0))]


def layer_text(path):
    """The whole layer as text, but its sublayer (the input, relative to the output): two bakes of one input wrote
    the same layer when these are equal."""
    layer = Sdf.Layer.OpenAsAnonymous(path)
    assert len(layer.subLayerPaths) == 1
    layer.subLayerPaths.clear()
    return layer.ExportToString()


def cli(*args, env=None, quiet=True):
    full = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""), **(env or {}))
    return subprocess.run([sys.executable, "-m", "warp_subdiv", "refine", *map(str, args)]
                          + (["--quiet"] if quiet else []), capture_output=True, text=True, env=full, timeout=300)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("resume_scene")
    path = str(folder / "scene.usda")
    paths = make_scene(path)
    reference = str(folder / "reference.usdc")
    refine_usd(path, reference, 2, normals=True, resume=False)
    return path, paths, reference


def entries(out):
    folder = rs.resume_folder(str(out))
    return sorted(n for n in os.listdir(folder) if n.endswith(".usdc")) if os.path.isdir(folder) else []


def sample_chunks(out):
    folder = rs.resume_folder(str(out))
    return sorted(n for n in os.listdir(folder) if rs.PART_TAG + "samples-" in n) if os.path.isdir(folder) else []


def test_killed_bake_resumes(scene, tmp_path):
    """A bake killed (SIGKILL) after 3 meshes were kept leaves no output and 3 entries; the same command again
    refines only the other meshes, writes the layer the uninterrupted bake writes and removes the kept work."""
    path, paths, reference = scene
    out = tmp_path / "out.usdc"
    killed = cli(path, "-o", out, "--levels", 2, "--normals", env={rs.KILL_ENV: "3"})
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert not out.exists()
    kept = entries(out)
    assert len(kept) == 3
    # the kept work (and the killed process's temporary output file, which no one else removes)
    assert sorted(n for n in os.listdir(tmp_path) if not n.startswith(".warp-subdiv-")) == ["out.usdc.resume"]
    labels = []
    result = refine_usd(path, str(out), 2, normals=True, progress=lambda f, label: labels.append((f, label)))
    assert result.reused == paths[:3]  # the plan's order: the first three were kept
    # progress: the kept meshes first, done at no cost (no rate yet: no ETA); then an ETA from the rate
    assert [label for _, label in labels[:3]] == [f"[{k + 1}/{len(paths)}] {p}: kept" for k, p in enumerate(paths[:3])]
    assert all("ETA" in label for _, label in labels[3:-1]) and labels[-1][0] == 1.0
    assert [r.path for r in result.reports] == paths
    assert layer_text(str(out)) == layer_text(reference)
    assert [n for n in os.listdir(tmp_path) if not n.startswith(".warp")] == ["out.usdc"]  # kept work removed


class Stopped(BaseException):
    """A bake stopped in this process as a kill would stop it (not an input error: its work is kept)."""


def stopped_bake(monkeypatch, n, *args, **keywords):
    """Run ``refine_usd(*args, **keywords)`` until it has kept ``n`` entries, then stop it (:class:`Stopped`):
    what a killed process leaves, without a process of its own (the bake's clean-up runs and keeps the work)."""
    save = rs.Store.save
    count = [0]

    def counting(self, name, write, *, counted=True):
        save(self, name, write, counted=counted)
        count[0] += counted
        if count[0] >= n:
            raise Stopped

    with monkeypatch.context() as m:
        m.setattr(rs.Store, "save", counting)
        with pytest.raises(Stopped):
            refine_usd(*args, **keywords)


def test_resume_through_the_command(scene, tmp_path, monkeypatch):
    """Stopped after 5 meshes, the same bake run as a command finishes with the uninterrupted layer and says
    what it reused; --fresh removes what was kept and refines everything."""
    path, paths, reference = scene
    out = tmp_path / "out.usdc"
    stopped_bake(monkeypatch, 5, path, str(out), 2, normals=True)
    assert len(entries(out)) == 5 and not out.exists()
    done = cli(path, "-o", out, "--levels", 2, "--normals", quiet=False)
    assert done.returncode == 0, done.stderr
    assert "resumed: 5 meshes and 0 time samples kept by an earlier run" in done.stdout
    assert layer_text(str(out)) == layer_text(reference)
    assert not os.path.exists(rs.resume_folder(str(out)))
    # --fresh: what a stopped run kept is removed, every mesh refined
    stopped_bake(monkeypatch, 2, path, str(out), 2, normals=True)
    assert len(entries(out)) == 2
    fresh = cli(path, "-o", out, "--levels", 2, "--normals", "--fresh", quiet=False)
    assert fresh.returncode == 0, fresh.stderr
    assert "resumed" not in fresh.stdout
    assert layer_text(str(out)) == layer_text(reference)
    assert not os.path.exists(rs.resume_folder(str(out)))


def test_stale_entries_are_not_reused(tmp_path, monkeypatch):
    """Kept work of other options or another level is removed and not reused; an edited mesh is refined again
    while the unchanged ones are reused; a file touched but unchanged keeps everything (content keys)."""
    src = str(tmp_path / "scene.usda")
    paths = make_scene(src, meshes=4, animated=False)
    out = tmp_path / "out.usdc"
    stopped_bake(monkeypatch, 3, src, str(out), 2, normals=True)
    first = entries(out)
    # other options: nothing reused, and the stale entries are gone once the run starts
    stopped_bake(monkeypatch, 1, src, str(out), 1)
    assert len(entries(out)) == 1 and not set(entries(out)) & set(first)
    # a touched file (same content) keeps the entries
    os.utime(src, (time.time() + 5, time.time() + 5))
    result = refine_usd(src, str(out), 1)
    assert result.reused == paths[:1]
    expected = str(tmp_path / "expected.usdc")
    refine_usd(src, expected, 1, resume=False)
    assert layer_text(str(out)) == layer_text(expected)
    # an edited mesh is refined again, the others are reused
    stopped_bake(monkeypatch, 3, src, str(out), 2, normals=True)
    layer = Sdf.Layer.FindOrOpen(src)
    pts = np.array(layer.GetAttributeAtPath(paths[1] + ".points").default)
    layer.GetAttributeAtPath(paths[1] + ".points").default = Vt.Vec3fArray.FromNumpy(pts * 1.5)
    layer.Save()
    result = refine_usd(src, str(out), 2, normals=True)
    assert result.reused == [paths[0], paths[2]]
    refine_usd(src, expected, 2, normals=True, resume=False)
    assert layer_text(str(out)) == layer_text(expected)


def test_no_batching_or_workers_same_layer(scene, tmp_path, monkeypatch):
    """Kept meshes leave the batches of small meshes and the meshes refined ahead: a resumed bake on one thread
    and unbatched writes the same layer."""
    path, paths, reference = scene
    out = tmp_path / "out.usdc"
    stopped_bake(monkeypatch, 2, path, str(out), 2, normals=True)
    monkeypatch.setenv("WARP_SUBDIV_THREADS", "1")
    result = refine_usd(path, str(out), 2, normals=True, batch=False)
    assert result.reused == paths[:2]
    assert layer_text(str(out)) == layer_text(reference)


def test_damaged_entry_is_refined_again(scene, tmp_path, monkeypatch):
    """An entry that cannot be read (cut short by a full disk, say) is refined again, not trusted."""
    path, paths, reference = scene
    out = tmp_path / "out.usdc"
    stopped_bake(monkeypatch, 3, path, str(out), 2, normals=True)
    folder = rs.resume_folder(str(out))
    arrays = sorted(n for n in os.listdir(folder) if n.endswith(rs.PART_TAG + "arrays.npy"))
    assert len(arrays) == 3  # the large arrays of each kept mesh, saved raw beside its entry layer
    for damaged in (entries(out)[0], arrays[1]):  # one mesh's entry layer, another's arrays
        with open(os.path.join(folder, damaged), "r+b") as f:
            f.truncate(100)
    result = refine_usd(path, str(out), 2, normals=True)
    assert len(result.reused) == 1
    assert layer_text(str(out)) == layer_text(reference)


def test_whole_scene_task_keeps_its_meshes(tmp_path, monkeypatch):
    """A distributed bake's task that bakes a whole scene (instances: one task, as the single process bakes it)
    keeps its meshes one by one beside the bake's units: run again after it was stopped, it reuses them; once
    done, the unit is kept whole and the meshes' folder is gone."""
    from warp_subdiv.usd import distributed as dist
    from warp_subdiv.usd import plan

    scene = os.path.join(ROOT, "scenes", "instanced.usda")
    p = plan(scene, 1)
    assert not p.one_place_each and len(p.prims) >= 2
    unit = dist.Unit(0, "scene", -1, None, None, "scene.usdc")
    out = tmp_path / "out.usda"
    kept = rs.UnitEntries(rs.Store(str(out)), [unit], [dist.unit_key(p, unit, 1, {})])
    chunks = tmp_path / "chunks"
    chunks.mkdir()
    with monkeypatch.context() as m:
        save = rs.Store.save

        def stop_after_first(self, name, write, *, counted=True):
            save(self, name, write, counted=counted)
            raise Stopped

        m.setattr(rs.Store, "save", stop_after_first)
        with pytest.raises(Stopped):
            dist.unit_task(scene, str(chunks), unit, 1, {}, keep=kept.spec(0))
    assert len(os.listdir(kept.scene)) == 1
    done = dist.unit_task(scene, str(chunks), unit, 1, {}, keep=kept.spec(0))
    assert done["reused"] == [p.prims[0].path]
    assert sorted(os.listdir(kept.store.folder)) == [kept.names[0] + ".json", kept.names[0] + ".usdc"]
    assert os.listdir(chunks) == ["scene.usdc"]
    assert kept.load(0, str(tmp_path / "again.usdc"))["reports"] == done["reports"]


def test_input_error_removes_kept_work(tmp_path, monkeypatch):
    """A bake that fails on its input after some meshes were kept leaves nothing behind, kept work included
    (the input must change); a bake stopped otherwise (an interrupt) keeps it."""
    from warp_subdiv.usd import refine as refine_module

    src = str(tmp_path / "scene.usda")
    paths = make_scene(src, meshes=3, animated=False)
    out = tmp_path / "out.usda"
    write = refine_module.PrimWriter.write

    def failing(kind):
        def write_or_fail(self, prepared=None):
            if self.sp.path == paths[2]:
                raise kind(f"{self.sp.path}: failure requested by the test")
            return write(self, prepared)
        return write_or_fail

    monkeypatch.setattr(refine_module.PrimWriter, "write", failing(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        refine_usd(src, str(out), 1)
    assert len(entries(out)) == 2
    monkeypatch.setattr(refine_module.PrimWriter, "write", failing(SubdivInputError))
    with pytest.raises(SubdivInputError, match="Grid_2"):
        refine_usd(src, str(out), 1)
    assert sorted(os.listdir(tmp_path)) == ["scene.usda"]


def test_animated_mesh_resumes_from_its_last_chunk_of_samples(tmp_path, monkeypatch):
    """An animated mesh refined on its own keeps its time samples in chunks as they are written: stopped after
    two chunks, the rerun refines only the later samples and writes the uninterrupted layer."""
    src = str(tmp_path / "scene.usda")
    paths = make_scene(src, meshes=1, samples=40, animated_cells=34)  # 4,624 refined vertices: not batched
    reference = str(tmp_path / "reference.usdc")
    refine_usd(src, reference, 1, normals=True, resume=False)
    out = tmp_path / "out.usdc"
    stopped_bake(monkeypatch, 3, src, str(out), 1, normals=True)  # the static mesh, two chunks of samples
    assert len(entries(out)) == 1 and len(sample_chunks(out)) == 2
    result = refine_usd(src, str(out), 1, normals=True)
    assert result.reused == paths[:1]
    assert result.reused_samples == {paths[1]: 2 * rs.CHUNK_SAMPLES}
    assert layer_text(str(out)) == layer_text(reference)
    assert not os.path.exists(rs.resume_folder(str(out)))
    # once the mesh is kept whole its chunks are removed: after its entry is written, or by the next run where
    # a kill came between the two (here: stopped right after the 5th save, the entry after 3 chunks)
    stopped_bake(monkeypatch, 5, src, str(out), 1, normals=True, fresh=True)
    assert len(entries(out)) == 2 and len(sample_chunks(out)) == 3
    monkeypatch.setattr(rs.Store, "finish", lambda self: None)  # what a successful run would remove
    result = refine_usd(src, str(out), 1, normals=True)
    assert result.reused == paths and len(entries(out)) == 2 and sample_chunks(out) == []
    assert refine_usd(src, str(out), 1, normals=True, fresh=True).reused == []
    assert len(entries(out)) == 2 and sample_chunks(out) == []


def test_eta():
    """The ETA counts only the work done in this run: kept work is free."""
    assert rs.eta_seconds(0.5, 1.0, 0.0, 10.0) == pytest.approx(10.0)
    assert rs.eta_seconds(0.6, 1.0, 0.4, 10.0) == pytest.approx(20.0)
    assert rs.eta_seconds(0.4, 1.0, 0.4, 10.0) is None
    assert rs.format_eta(3725) == "ETA 1h02m" and rs.format_eta(65) == "ETA 1m05s" and rs.format_eta(None) == ""


ANIMATED = os.path.join(ROOT, "scenes", "animated.usda")  # one creased plate, frames 1-24, primvars, a subset


@pytest.fixture(scope="module")
def client():
    from conftest import dask_client

    with dask_client(n_workers=2, processes=True) as c:
        yield c


def test_distributed_bake_resumes_after_its_client_is_killed(client, tmp_path):
    """A distributed bake whose client process (and with it its local cluster) is killed while tasks run keeps
    the finished frame chunks; the bake run again submits only the others and composes to the single-process
    bake, and the kept work is removed."""
    from test_distributed import assert_same_composition

    from warp_subdiv.usd import distributed as dist

    single = str(tmp_path / "single.usda")
    refine_usd(ANIMATED, single, 1, resume=False)
    out = tmp_path / "out" / "animated.usda"
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env[dist.FAULT_ENV] = "sleep:0.8"  # every task sleeps first: the kill lands while tasks run
    proc = subprocess.Popen([sys.executable, "-m", "warp_subdiv", "refine", ANIMATED, "-o", str(out), "--levels",
                             "1", "--workers", "2", "--chunk-frames", "4", "--quiet"], env=env,
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    folder = rs.resume_folder(str(out))

    def finished():
        return [n for n in os.listdir(folder) if n.endswith(".json")] if os.path.isdir(folder) else []

    deadline = time.monotonic() + 180
    while len(finished()) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the client, its scheduler and workers
    proc.wait(30)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read()
    kept = len(finished())
    assert kept >= 2 and not out.exists()
    labels = []
    result = dist.bake(ANIMATED, str(out), 1, chunk_frames=4, client=client,
                       progress=lambda f, label: labels.append(label))
    units = result.timings["units"]
    assert len(result.reused) == kept < len(units)  # only the missing chunks ran again
    assert len(labels) == len(units) - kept and all("ETA" in label for label in labels)  # one per task run
    assert all("frames" in label for label in result.reused)
    assert_same_composition(single, str(out))
    assert sorted(os.listdir(out.parent)) == ["animated.usda", "animated.usda.chunks"]


# (every mesh of the skinned character reads its skeleton: nothing of it is kept, see the next test)
@pytest.mark.parametrize("name", sorted(n[:-5] for n in os.listdir(os.path.join(ROOT, "scenes"))
                                         if n.endswith(".usda") and n not in ("adaptive_tessellation.usda",
                                                                              "skinned_character.usda")))
def test_bundled_scenes_resume_to_the_same_layer(name, tmp_path, monkeypatch):
    """The bundled scenes with subdivision meshes (time samples, primvars of several kinds, subsets, instances,
    prescribed normals), stopped after their first kept mesh and resumed: the layer of an uninterrupted bake."""
    src = os.path.join(ROOT, "scenes", f"{name}.usda")
    reference = str(tmp_path / "reference.usda")
    refine_usd(src, reference, 1, normals=True, resume=False)
    out = tmp_path / "out.usda"
    stopped_bake(monkeypatch, 1, src, str(out), 1, normals=True)
    result = refine_usd(src, str(out), 1, normals=True)
    assert len(result.reused) == 1
    assert layer_text(str(out)) == layer_text(reference)


def test_skinned_meshes_are_never_reused(tmp_path, monkeypatch):
    """A skinned mesh's baked points depend on its skeleton's animation, which its input digest does not cover:
    work kept for it is never reused, so an animation edited between a stopped run and its rerun bakes the new
    pose (the plain mesh beside it is still reused)."""
    src = str(tmp_path / "character.usda")
    shutil.copy(os.path.join(ROOT, "scenes", "skinned_character.usda"), src)
    layer = Sdf.Layer.FindOrOpen(src)
    stage = Usd.Stage.Open(layer)
    plain = UsdGeom.Mesh.Define(stage, "/World/Prop")  # a mesh no skeleton deforms
    plain.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    plain.CreateFaceVertexCountsAttr([4])
    plain.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    layer.Save()
    out = tmp_path / "out.usdc"
    stopped_bake(monkeypatch, 1, src, str(out), 1)
    assert len(entries(out)) == 1  # the prop's
    rotations = layer.GetAttributeAtPath("/World/Character/Skel/Anim.rotations")
    for t in layer.ListTimeSamplesForPath(rotations.path):  # the joints held in their first pose
        layer.SetTimeSample(rotations.path, t, layer.QueryTimeSample(rotations.path, 1.0))
    layer.Save()
    result = refine_usd(src, str(out), 1)
    assert result.reused == ["/World/Prop"]
    expected = str(tmp_path / "expected.usdc")
    refine_usd(src, expected, 1, resume=False)
    assert layer_text(str(out)) == layer_text(expected)
