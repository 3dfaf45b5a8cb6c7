"""What distributed bakes and stitched chunks write besides the refined values: each output owns its folder of
chunks, a run never rewrites a file its input reads, chunks record every option that decides their values and
a stitch refuses chunks that disagree, and the output's time samples are the input's."""
import os

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

from conftest import dask_client
from test_usd_support import grid, write_mesh
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd import distributed as dist
from warp_subdiv.usd.refine import refine_usd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ANIMATED = os.path.join(ROOT, "scenes", "animated.usda")  # one creased plate, frames 1-24, primvars, a subset


@pytest.fixture(scope="module")
def client():
    """One in-process Dask worker (a thread): these tests are about files, not about processes."""
    with dask_client(n_workers=1, processes=False) as c:
        yield c


def faces(path, prim="/World/Mesh"):
    stage = Usd.Stage.Open(str(path))
    return len(UsdGeom.Mesh(stage.GetPrimAtPath(prim)).GetFaceVertexCountsAttr().Get())


def animated_grid(path, nx, frames=range(1, 13)):
    """A flat nx x 1 grid whose points move at every frame: several frame chunks."""
    pts = grid(nx, 1)[0]
    moving = {float(t): pts + [0.0, 0.0, 0.1 * t] for t in frames}
    return write_mesh(path, pts, *grid(nx, 1)[1:], time_points=moving)


# -- chunk folders ---------------------------------------------------------------------------------------

def test_outputs_sharing_a_stem_keep_their_own_chunks(client, tmp_path):
    """shot.usda and shot.usdc in one folder: baking another input to shot.usdc leaves shot.usda composing its
    own mesh (each output's chunks are in a folder named after its full file name)."""
    a = write_mesh(tmp_path / "a.usda", *grid(2, 1))
    b = write_mesh(tmp_path / "b.usda", *grid(5, 1))
    dist.bake(a, str(tmp_path / "shot.usda"), 1, client=client)
    dist.bake(b, str(tmp_path / "shot.usdc"), 1, client=client)
    assert faces(tmp_path / "shot.usda") == 8
    assert faces(tmp_path / "shot.usdc") == 20
    assert {"shot.usda.chunks", "shot.usdc.chunks"} <= set(os.listdir(tmp_path))


def test_a_bake_refuses_to_replace_the_chunks_its_input_reads(client, tmp_path):
    """Refining a bake's own output again into a file whose chunk folder the input reads would rewrite the
    input under it: refused, and the input still composes as before."""
    a = write_mesh(tmp_path / "a.usda", *grid(2, 1))
    shot = tmp_path / "shot.usda"
    dist.bake(a, str(shot), 1, client=client)
    # an input that reads the chunks of the output the next run writes (a hand-made layer)
    other = tmp_path / "other.usdc"
    dist.bake(a, str(other), 1, client=client)
    reader = Sdf.Layer.CreateNew(str(tmp_path / "reader.usda"))
    reader.subLayerPaths.append("./other.usdc.chunks/" + os.listdir(tmp_path / "other.usdc.chunks")[0])
    reader.subLayerPaths.append("./a.usda")
    reader.Save()
    with pytest.raises(SubdivInputError, match=r"other\.usdc\.chunks.*the input reads"):
        dist.bake(str(tmp_path / "reader.usda"), str(other), 1, client=client, scheme="catmull-clark",
                  prims=["/World/Mesh"])
    assert faces(tmp_path / "reader.usda") == 8 and faces(other) == 8
    # the bake's own output as input, written next to it: the input's chunks stay as they are
    dist.bake(str(shot), str(tmp_path / "shot.usdc"), 1, client=client, scheme="catmull-clark",
              prims=["/World/Mesh"])
    assert faces(shot) == 8 and faces(tmp_path / "shot.usdc") == 32


def test_stitches_sharing_a_stem_keep_their_own_topology(tmp_path):
    """Stitching the chunks of b into shot.usdc after those of a into shot.usda leaves shot.usda with a's
    topology under a's points; a stitch refuses to write over one of its chunks."""
    def chunks(name, nx):
        src = animated_grid(tmp_path / f"{name}.usda", nx)
        out = []
        for k, frames in enumerate([(None, 6), (6, None)]):
            out.append(str(tmp_path / f"{name}{k}.usdc"))
            refine_usd(src, out[-1], 1, frames=frames)
        return out

    dist.stitch(chunks("a", 2), str(tmp_path / "shot.usda"))
    dist.stitch(chunks("b", 5), str(tmp_path / "shot.usdc"))
    assert faces(tmp_path / "shot.usda") == 8 and faces(tmp_path / "shot.usdc") == 20
    stage = Usd.Stage.Open(str(tmp_path / "shot.usda"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh"))
    assert len(mesh.GetPointsAttr().Get(3.0)) == 15  # a's 3 x 2 control points refined once
    with pytest.raises(SubdivInputError, match="a1.usdc: .*chunk"):
        dist.stitch([str(tmp_path / "a0.usdc"), str(tmp_path / "a1.usdc")], str(tmp_path / "a1.usdc"))


def test_refine_refuses_an_output_the_input_references_in_a_variant(tmp_path):
    """The files an input reads include those its other variants reference: writing one of them is refused."""
    write_mesh(tmp_path / "part.usda", *grid(2, 1))
    write_mesh(tmp_path / "b.usda", *grid(3, 1))
    src = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(src))
    prim = stage.DefinePrim("/World")
    looks = prim.GetVariantSets().AddVariantSet("look")
    for name, part in (("a", "./part.usda"), ("b", "./b.usda")):
        looks.AddVariant(name)
        looks.SetVariantSelection(name)
        with looks.GetVariantEditContext():
            prim.GetReferences().AddReference(part)
    looks.SetVariantSelection("a")
    stage.GetRootLayer().Save()
    with pytest.raises(SubdivInputError, match="b.usda: the input reads this file"):
        refine_usd(str(src), str(tmp_path / "b.usda"), 1)
    assert faces(tmp_path / "b.usda") == 3 and faces(src) == 2


# -- recorded options --------------------------------------------------------------------------------------

@pytest.mark.parametrize("option, value, named", [
    ("vertex_order", "opensubdiv", "vertex order"), ("boundary", "edge-only", "boundary"),
    ("precision", "float64", "precision"), ("semi_sharp", "sharp", "semi-sharp"), ("rules", "opensubdiv", "rules"),
    ("limit", True, "limit"), ("normals", True, "normals"),
])
def test_stitch_refuses_chunks_refined_with_other_options(tmp_path, option, value, named):
    """Every option that decides the refined values is recorded in each chunk, and chunks refined with another
    value of one of them are refused (a chunk in another vertex order scrambles the mesh, another boundary
    rule makes the shape jump), naming the option and both chunks; nothing is written."""
    src = animated_grid(tmp_path / "in.usda", 3)
    first, second = str(tmp_path / "c0.usdc"), str(tmp_path / "c1.usdc")
    refine_usd(src, first, 1, frames=(None, 6))
    refine_usd(src, second, 1, frames=(6, None), **{option: value})
    with pytest.raises(SubdivInputError, match=rf"c1.usdc: {named} differs from .*c0.usdc's") as info:
        dist.stitch([first, second], str(tmp_path / "out.usda"))
    assert "chunks must come from one refinement" in str(info.value)
    assert sorted(os.listdir(tmp_path)) == ["c0.usdc", "c1.usdc", "in.usda"]


def test_stitch_accepts_chunks_whose_options_resolve_alike(tmp_path):
    """Options that name what the defaults resolve to (the compact vertex order for the piecewise-smooth rules,
    the file's own boundary rule) refine alike: such chunks are stitched."""
    src = animated_grid(tmp_path / "in.usda", 3)
    first, second = str(tmp_path / "c0.usdc"), str(tmp_path / "c1.usdc")
    refine_usd(src, first, 1, frames=(None, 6))
    refine_usd(src, second, 1, frames=(6, None), vertex_order="compact", boundary="edge-and-corner")
    dist.stitch([first, second], str(tmp_path / "out.usda"))
    record = dict(Sdf.Layer.FindOrOpen(second).customLayerData)["warpSubdiv"]
    assert list(record["vertexOrders"]) == ["compact"] and list(record["boundaries"]) == ["edge-and-corner"]
    assert record["semiSharp"] == "keep" and list(record["precisions"]) == ["float32"]


# -- time samples ----------------------------------------------------------------------------------------

def composed_times(path, roots=("/World",)):
    """Attribute path -> its time samples, as the stage composes them (value clips included)."""
    stage = Usd.Stage.Open(str(path))
    out = {}
    for root in roots:
        for prim in Usd.PrimRange(stage.GetPrimAtPath(root)):
            for attr in prim.GetAttributes():
                times = attr.GetTimeSamples()
                if times:
                    out[str(attr.GetPath())] = times
    return out


def authored_times(path):
    """Attribute path -> the time samples a (flattened) layer authors."""
    layer = Sdf.Layer.FindOrOpen(str(path))
    out = {}

    def visit(p):
        if p.IsPropertyPath() and layer.GetNumTimeSamplesForPath(p):
            out[str(p)] = list(layer.ListTimeSamplesForPath(p))

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out


def test_distributed_and_stitched_outputs_have_the_input_time_samples(client, tmp_path):
    """The outputs of a distributed bake and of a stitch author exactly the input's time samples, attribute by
    attribute, flattened or not: no sample just before each chunk boundary (value clip times that repeat the
    boundary make USD add one there), and no sample at a chunk boundary for an attribute sampled more sparsely
    than the points (primvars:weight: at 1, 12 and 24 only)."""
    source = composed_times(ANIMATED)
    assert source["/World/Animated/Plate.primvars:weight"] == [1.0, 12.0, 24.0]
    single = tmp_path / "single.usda"
    refine_usd(ANIMATED, str(single), 1, flatten=True)
    expected = authored_times(single)
    for name, times in source.items():
        assert expected[name] == times, name  # the single-process bake keeps them

    outputs = {}
    for flatten in (False, True):
        out = tmp_path / f"dist_{flatten}.usda"
        dist.bake(ANIMATED, str(out), 1, chunk_frames=5, client=client, flatten=flatten)
        outputs[out] = flatten
        files = []
        for k, frames in enumerate([(None, 9), (9, 17), (17, None)]):
            files.append(str(tmp_path / f"farm_{flatten}" / f"chunk{k}.usdc"))
            refine_usd(ANIMATED, files[-1], 1, frames=frames)
        out = tmp_path / f"stitched_{flatten}.usda"
        dist.stitch(files, str(out), flatten=flatten)
        outputs[out] = flatten
    reference = Usd.Stage.Open(str(single))
    for out, flatten in outputs.items():
        assert composed_times(out) == composed_times(single), out
        if flatten:
            assert authored_times(out) == expected, out
        stage = Usd.Stage.Open(str(out))
        for name in ("primvars:weight", "points"):
            want = reference.GetAttributeAtPath("/World/Animated/Plate." + name)
            got = stage.GetAttributeAtPath("/World/Animated/Plate." + name)
            for t in np.arange(0.0, 26.0, 0.25):
                np.testing.assert_allclose(np.asarray(got.Get(t)), np.asarray(want.Get(t)), rtol=1e-6, atol=1e-6,
                                           err_msg=f"{out} {name} at {t}")



def test_stitched_time_varying_topology_reads_as_the_single_bake(tmp_path):
    """A mesh whose faces change at time 6, with a primvar sampled at 1 and 12 and a subset at 2 and 10: a
    chunk within one topology writes it as its default only; stitched, every attribute reads as in the
    single-process bake at every time (its topology too, which value clips would interpolate towards the next
    chunk), and no sample lies between the input's time codes."""
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        fvi = mesh.GetFaceVertexIndicesAttr()
        fvi.Set(Vt.IntArray(idx), 1.0)
        fvi.Set(Vt.IntArray(idx[4:] + idx[:4]), 6.0)
        w = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", Sdf.ValueTypeNames.FloatArray, "varying")
        w.Set(Vt.FloatArray([0.0] * 6), 1.0)
        w.Set(Vt.FloatArray([float(i) for i in range(6)]), 12.0)
        subset = UsdGeom.Subset.Define(stage, "/World/Mesh/sub")
        subset.CreateElementTypeAttr("face")
        subset.CreateIndicesAttr().Set(Vt.IntArray([0]), 2.0)
        subset.GetIndicesAttr().Set(Vt.IntArray([1]), 10.0)

    moving = {float(t): pts + [0, 0, 0.1 * t] for t in range(1, 13)}
    src = write_mesh(tmp_path / "in.usda", pts, counts, idx, time_points=moving, setup=setup)
    refine_usd(src, str(tmp_path / "single.usda"), 1)
    files = []
    for k, frames in enumerate([(None, 4), (4, 8), (8, None)]):
        files.append(str(tmp_path / f"c{k}.usdc"))
        refine_usd(src, files[-1], 1, frames=frames)
    dist.stitch(files, str(tmp_path / "out.usda"))
    want, got = Usd.Stage.Open(str(tmp_path / "single.usda")), Usd.Stage.Open(str(tmp_path / "out.usda"))
    for name in ("/World/Mesh.faceVertexIndices", "/World/Mesh.points", "/World/Mesh.primvars:w",
                 "/World/Mesh/sub.indices"):
        for t in np.arange(0.0, 14.0, 0.25):
            np.testing.assert_allclose(np.asarray(got.GetAttributeAtPath(name).Get(t), dtype=float),
                                       np.asarray(want.GetAttributeAtPath(name).Get(t), dtype=float), atol=1e-6,
                                       err_msg=f"{name} at {t}")
        assert set(got.GetAttributeAtPath(name).GetTimeSamples()) <= set(range(1, 13)), name


def test_reindexed_primvars_agree_with_the_single_bake_at_chunk_ends(client, tmp_path):
    """Primvars whose indices change at samples that are chunk boundaries (7 and 13 in the distributed bake, 10
    in the stitch): the outputs read as the single-process bake at every time, sub-frames and the step before
    each change included, and have its time samples."""
    from test_usd_bugs import REINDEXED_TIMES, reindexed_primvars_scene

    src = reindexed_primvars_scene(tmp_path / "in.usda")
    stage = Usd.Stage.Open(src)
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh")).GetPointsAttr()
    rest = np.asarray(points.Get())
    for t in range(1, 18):
        points.Set(Vt.Vec3fArray.FromNumpy((rest + [0.0, 0.0, 0.1 * t]).astype(np.float32)), float(t))
    stage.GetRootLayer().Save()
    single = tmp_path / "single.usda"
    refine_usd(src, str(single), 1)
    distributed_out = tmp_path / "dist.usda"
    res = dist.bake(src, str(distributed_out), 1, chunk_frames=6, client=client)
    assert [u["frames"] for u in res.timings["units"]] == [(None, 7.0), (7.0, 13.0), (13.0, None)]
    files = [str(tmp_path / "c0.usdc"), str(tmp_path / "c1.usdc")]
    refine_usd(src, files[0], 1, frames=(None, 10))
    refine_usd(src, files[1], 1, frames=(10, None))
    stitched = tmp_path / "stitched.usda"
    dist.stitch(files, str(stitched))
    reference = Usd.Stage.Open(str(single))
    want = UsdGeom.PrimvarsAPI(reference.GetPrimAtPath("/World/Mesh"))
    steps = [t - Usd.TimeCode.SafeStep() for t in (7.0, 10.0, 13.0)]
    for out in (distributed_out, stitched):
        assert composed_times(out) == composed_times(single), out
        out_stage = Usd.Stage.Open(str(out))
        got = UsdGeom.PrimvarsAPI(out_stage.GetPrimAtPath("/World/Mesh"))
        for name in ("v", "vy", "fv", "u"):
            for t in REINDEXED_TIMES + steps + list(np.arange(0.0, 18.0, 0.5)):
                np.testing.assert_allclose(np.asarray(got.GetPrimvar(name).ComputeFlattened(t)),
                                           np.asarray(want.GetPrimvar(name).ComputeFlattened(t)), atol=1e-6,
                                           err_msg=f"{out} {name} at {t}")


def test_a_published_chunk_folder_is_readable_as_a_new_folder_would_be(tmp_path):
    """The chunk folder is made with mkdtemp (0700) and renamed into place: once published it has the mode a
    folder made with os.mkdir gets (0777 less the umask), or other users could not read the chunks the output
    composes."""
    from warp_subdiv.usd.distributed import _Folder

    old = os.umask(0o022)
    try:
        folder = _Folder(str(tmp_path / "shot.usdc"))
        folder.publish()
        folder.done()
    finally:
        os.umask(old)
    assert oct(os.stat(tmp_path / "shot.usdc.chunks").st_mode & 0o777) == oct(0o755)
