"""Distributed bakes on Dask and stitched chunk layers compose to the single-process bake's values; a failed
bake leaves nothing behind; a killed worker's tasks are rerun and the bake completes."""
import os
import signal
import threading
import time

import numpy as np
import pytest
from pxr import Sdf, Usd

from warp_subdiv.usd import distributed as dist
from warp_subdiv.usd.refine import refine_usd

from conftest import dask_client

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ANIMATED = os.path.join(ROOT, "scenes", "animated.usda")  # one creased plate, frames 1-24, primvars, a subset
STATIC = os.path.join(ROOT, "scenes", "concave_corner.usda")  # several static meshes


def _values(path, roots):
    stage = Usd.Stage.Open(path)
    attrs = {}
    for root in roots:
        for prim in Usd.PrimRange(stage.GetPrimAtPath(root)):
            for attr in prim.GetAttributes():
                attrs[str(attr.GetPath())] = attr
    return stage, attrs


def assert_same_composition(expected, actual, roots=("/World",)):
    """Every attribute at or under ``roots`` has the same value in both files at the default time, at every
    time sample of the expected file, between samples and outside them (floats to 1e-6: a chunk's boundary
    value of an attribute sampled elsewhere is refined from the interpolated input, not interpolated output)."""
    se, ea = _values(expected, roots)
    sa, aa = _values(actual, roots)
    assert sorted(ea) == sorted(aa)
    for name, attr in ea.items():
        times = attr.GetTimeSamples()
        probe = [Usd.TimeCode.Default()] + times + [0.5 * (a + b) for a, b in zip(times, times[1:])]
        probe += [times[0] - 1, times[-1] + 1] if times else []
        for t in probe:
            x, y = attr.Get(t), aa[name].Get(t)
            assert (x is None) == (y is None), (name, t)
            if x is None:
                continue
            xa, ya = np.asarray(x), np.asarray(y)
            if xa.dtype.kind == "f":
                np.testing.assert_allclose(ya, xa, rtol=1e-6, atol=1e-6, err_msg=f"{name} at {t}")
            else:
                assert x == y, (name, t)


@pytest.fixture(scope="module")
def client():
    """One local cluster of two worker processes for the module's tests."""
    with dask_client(n_workers=2, processes=True) as c:
        yield c


def _fault(client, spec):
    def set_env(value=spec, dask_worker=None):
        if value is None:
            os.environ.pop(dist.FAULT_ENV, None)
        else:
            os.environ[dist.FAULT_ENV] = value

    client.run(set_env)
    client.run(set_env, nanny=True)  # and in the nannies, for the worker processes they start again


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    """The single-process bakes the distributed ones are compared with."""
    out = tmp_path_factory.mktemp("single")
    refine_usd(ANIMATED, str(out / "animated.usda"), 1)
    refine_usd(ANIMATED, str(out / "animated_3_20.usda"), 1, frames=(3.5, 20))
    refine_usd(STATIC, str(out / "static.usdc"), 2)
    return out


def test_frame_chunks_compose_like_the_single_bake(client, single, tmp_path):
    """An animated mesh split into frame chunks (topology shipped to the frame tasks) and stitched as value
    clips composes to the single-process bake's values, with and without --frames; the output names the
    chunk folder by relative paths and nothing else is left next to it."""
    out = tmp_path / "out" / "animated.usda"
    res = dist.bake(ANIMATED, str(out), 1, chunk_frames=5, client=client)
    assert res.reports[0].samples == 24
    assert_same_composition(str(single / "animated.usda"), str(out))
    assert sorted(os.listdir(out.parent)) == ["animated.usda", "animated.usda.chunks"]
    chunks = sorted(os.listdir(out.parent / "animated.usda.chunks"))
    assert chunks == [f"0000_World_Animated_Plate.{k:04d}.usdc" for k in range(5)] + ["manifest.0000.usdc",
                                                                                    "topology.usdc"]
    stage = Usd.Stage.Open(str(out))
    clips = Usd.ClipsAPI(stage.GetPrimAtPath("/World/Animated/Plate")).GetClipAssetPaths()
    assert all(a.path.startswith("./animated.usda.chunks/") for a in clips)
    ranged = tmp_path / "ranged.usda"
    dist.bake(ANIMATED, str(ranged), 1, chunk_frames=4, frames=(3.5, 20), client=client)
    assert_same_composition(str(single / "animated_3_20.usda"), str(ranged))


def test_later_chunks_hold_time_samples_only(client, single, tmp_path):
    """A mesh's frame chunks after its first are written with time samples only (no faceVertexIndices or
    faceVertexCounts, no default values), the first chunk with everything; the stitched output composes to the
    single-process bake's values all the same."""
    out = tmp_path / "animated.usda"
    res = dist.bake(ANIMATED, str(out), 1, chunk_frames=6, client=client)
    assert [u["kind"] for u in res.timings["units"]] == ["frames"] * 4
    assert_same_composition(str(single / "animated.usda"), str(out))
    folder = tmp_path / "animated.usda.chunks"
    plate = "/World/Animated/Plate"
    names = [f"0000_World_Animated_Plate.{k:04d}.usdc" for k in range(4)]
    first = Sdf.Layer.FindOrOpen(str(folder / names[0]))
    assert first.GetAttributeAtPath(plate + ".faceVertexIndices").HasDefaultValue()
    assert first.GetAttributeAtPath(plate + ".points").HasDefaultValue()
    for name in names[1:]:
        layer = Sdf.Layer.FindOrOpen(str(folder / name))
        for attr in ("faceVertexIndices", "faceVertexCounts"):
            spec = layer.GetAttributeAtPath(f"{plate}.{attr}")
            assert spec is None or not (spec.HasDefaultValue() or layer.GetNumTimeSamplesForPath(spec.path)), attr
        defaults = []

        def visit(path, layer=layer, defaults=defaults):
            spec = layer.GetAttributeAtPath(path) if path.IsPropertyPath() else None
            if spec is not None and spec.HasDefaultValue() and not isinstance(spec.default, Sdf.ValueBlock):
                defaults.append(str(path))

        layer.Traverse(plate, visit)
        assert defaults == [f"{plate}.subdivisionScheme"]  # (and blocks: no value)
        assert layer.GetNumTimeSamplesForPath(plate + ".points") >= 6


def test_mesh_units_are_sublayers(client, single, tmp_path):
    """Static meshes are one task each, whose layers the output sublayers before the input."""
    out = tmp_path / "static.usdc"
    res = dist.bake(STATIC, str(out), 2, client=client)
    assert len(res.reports) >= 2
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert len(layer.subLayerPaths) == len(res.reports) + 1 and layer.subLayerPaths[-1].endswith("concave_corner.usda")
    assert_same_composition(str(single / "static.usdc"), str(out))


def test_failure_leaves_no_output_and_no_chunks(client, tmp_path):
    """A failing task (and a memory guard that refuses every task) leaves no output, no chunk folder and no
    temporary file; an output from before stays as it was."""
    out = tmp_path / "animated.usda"
    _fault(client, "fail:2")
    try:
        with pytest.raises(dist.SubdivInputError, match="unit 2"):
            dist.bake(ANIMATED, str(out), 1, chunk_frames=5, client=client)
    finally:
        _fault(client, None)
    assert os.listdir(tmp_path) == []
    with pytest.raises(dist.SubdivInputError, match="memory"):
        dist.bake(ANIMATED, str(out), 1, chunk_frames=5, client=client, max_memory=1 << 20)
    assert os.listdir(tmp_path) == []

    def state():
        return {os.path.join(b, f): os.stat(os.path.join(b, f)).st_mtime_ns
                for b, _, fs in os.walk(tmp_path) for f in fs}

    dist.bake(ANIMATED, str(out), 1, chunk_frames=8, client=client)  # an earlier output and its chunks
    before = state()
    _fault(client, "fail:1")
    try:
        with pytest.raises(dist.SubdivInputError, match="unit 1"):
            dist.bake(ANIMATED, str(out), 1, chunk_frames=5, client=client)
    finally:
        _fault(client, None)
    assert state() == before


def test_killed_worker_tasks_are_rerun(client, single, tmp_path):
    """A worker process killed while tasks run has its tasks rerun elsewhere; the bake completes with the
    single-process values and no stray temporary files."""
    out = tmp_path / "out" / "animated.usda"
    log = tmp_path / "log"
    log.mkdir()
    _fault(client, f"sleep:0.6:{log}")
    pids = list(client.run(os.getpid).values())
    result = {}

    def run():
        try:
            result["res"] = dist.bake(ANIMATED, str(out), 1, chunk_frames=4, client=client)
        except BaseException as exc:  # noqa: BLE001 (reported below)
            result["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    deadline = time.monotonic() + 60
    while not any(n.endswith(f".{pids[0]}") for n in os.listdir(log)) and time.monotonic() < deadline:
        time.sleep(0.05)
    os.kill(pids[0], signal.SIGKILL)  # while it runs a unit (each sleeps 0.6 s first)
    t.join(120)
    _fault(client, None)
    assert "error" not in result, result.get("error")
    started = [n.split(".") for n in os.listdir(log)]
    killed = {u for u, pid in started if pid == str(pids[0])}
    assert any(u in killed and pid != str(pids[0]) for u, pid in started)  # a killed unit ran again elsewhere
    assert_same_composition(str(single / "animated.usda"), str(out))
    assert sorted(os.listdir(out.parent)) == ["animated.usda", "animated.usda.chunks"]
    assert not [n for n in os.listdir(out.parent / "animated.usda.chunks") if n.startswith(".")]


def test_stitch_farm_chunks(single, tmp_path):
    """Layers of `refine --frames A:B` runs that share their ends, stitched (no Dask), compose to the
    single-process bake; chunks whose frames overlap more are refused."""
    parts = [(None, 9), (9, 17), (17, None)]
    files = []
    for k, frames in enumerate(parts):
        files.append(str(tmp_path / "farm" / f"chunk{k}.usdc"))
        refine_usd(ANIMATED, files[-1], 1, frames=frames)
    out = tmp_path / "stitched.usda"
    dist.stitch(files[::-1], str(out))
    assert_same_composition(str(single / "animated.usda"), str(out))
    assert sorted(os.listdir(tmp_path)) == ["farm", "stitched.usda", "stitched.usda.stitch"]
    bad = str(tmp_path / "farm" / "bad.usdc")
    refine_usd(ANIMATED, bad, 1, frames=(5, 12))
    with pytest.raises(dist.SubdivInputError, match="overlap"):
        dist.stitch(files + [bad], str(tmp_path / "nope.usda"))
    assert not os.path.exists(tmp_path / "nope.usda") and not os.path.exists(tmp_path / "nope.usda.stitch")
    # flattened: the clips' content is copied into the output, and the folder of stitched layers is removed
    flat = tmp_path / "flat.usda"
    dist.stitch(files, str(flat), flatten=True)
    assert_same_composition(str(single / "animated.usda"), str(flat))
    assert not os.path.exists(tmp_path / "flat.usda.stitch")


def test_cli_scheduler_threads_and_stitch(client, single, tmp_path):
    """`refine --scheduler ADDRESS --threads 1` bakes on an existing cluster; `stitch` assembles chunk layers;
    bad counts are usage errors (exit 2)."""
    from warp_subdiv.cli import main

    out = tmp_path / "cli.usda"
    assert main(["refine", ANIMATED, "-o", str(out), "--levels", "1", "--scheduler", client.scheduler.address,
                 "--threads", "1", "--chunk-frames", "6", "--quiet"]) == 0
    assert_same_composition(str(single / "animated.usda"), str(out))
    for k, frames in enumerate(["1:12", "12:24"]):
        assert main(["refine", ANIMATED, "-o", str(tmp_path / f"c{k}.usdc"), "--levels", "1", "--frames", frames,
                     "--quiet"]) == 0
    assert main(["stitch", str(tmp_path / "c1.usdc"), str(tmp_path / "c0.usdc"), "-o", str(tmp_path / "s.usda"),
                 "--quiet"]) == 0
    assert_same_composition(str(single / "animated.usda"), str(tmp_path / "s.usda"))
    for bad in (["--workers", "0"], ["--threads", "0"], ["--chunk-frames", "0"]):
        assert main(["refine", ANIMATED, "-o", str(tmp_path / "x.usda"), "--levels", "1"] + bad) == 2
    assert main(["stitch", str(tmp_path / "x.usda"), "-o", str(tmp_path / "y.usda")]) == 2


def test_quick_start_without_dask(tmp_path):
    """Without Dask importable, refining works as before and --workers is an input error naming the extra."""
    import subprocess
    import sys

    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] in ('dask', 'distributed'):\n"
            "            raise ImportError(name)\n"
            "sys.meta_path.insert(0, Block())\n"
            "from warp_subdiv.cli import main\n"
            "if __name__ == '__main__':\n"
            f"    assert main(['refine', {STATIC!r}, '-o', {str(tmp_path / 'a.usda')!r}, '--levels', '2', "
            "'--quiet']) == 0\n"
            f"    assert main(['refine', {STATIC!r}, '-o', {str(tmp_path / 'b.usda')!r}, '--levels', '1', "
            "'--workers', '2']) == 2\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "pip install 'warp-subdiv[distributed]'" in proc.stderr
    assert sorted(os.listdir(tmp_path)) == ["a.usda"]


def test_instanced_scene_is_one_unit(client, tmp_path):
    """A plan whose meshes are not each written at their own path (an instanced prototype: instances reference
    its refined content) is baked by one task, as the single process bakes it, and composes the same."""
    from pxr import Gf, UsdGeom, Vt

    src = str(tmp_path / "in.usda")
    st = Usd.Stage.CreateNew(src)
    m = UsdGeom.Mesh.Define(st, "/Proto/Cube")
    m.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]))
    m.GetFaceVertexCountsAttr().Set([4] * 6)
    m.GetFaceVertexIndicesAttr().Set([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 1, 3, 7, 5, 3, 2, 6, 7, 2, 0, 4, 6])
    for name in ("A", "B"):
        prim = st.DefinePrim(f"/World/{name}")
        prim.GetReferences().AddInternalReference("/Proto")
        prim.SetInstanceable(True)
    st.Save()
    refine_usd(src, str(tmp_path / "single.usda"), 2)
    res = dist.bake(src, str(tmp_path / "dist.usda"), 2, client=client)
    assert [u["kind"] for u in res.timings["units"]] == ["scene"]
    assert_same_composition(str(tmp_path / "single.usda"), str(tmp_path / "dist.usda"), roots=("/World", "/Proto"))
