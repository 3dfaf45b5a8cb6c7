"""Regression tests of issue 15 (items 10-20): time-sampled primvar indices, elementSize of indexed uniform
primvars, what --frames evaluates, empty or wrongly sized defaults, symlinked output folders, stale
extentsHint, render times, --prim on inactive or abstract prims, --limit and vertex primvars, edge subsets,
the flattened layer's doc and the frames parser. Each test builds its own small USD file."""
import os

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

from test_usd_support import grid, write_mesh
from warp_subdiv.errors import SubdivInputError
from warp_subdiv.usd import refine_usd

T = Sdf.ValueTypeNames
_OPEN = []


def opened(path):
    """A stage kept alive for the rest of the test (prims do not keep their stage)."""
    stage = Usd.Stage.Open(str(path))
    _OPEN.append(stage)
    return stage


@pytest.fixture(autouse=True)
def _close_stages():
    yield
    _OPEN.clear()


def out_prim(path, prim="/World/Mesh"):
    return opened(path).GetPrimAtPath(prim)


# -- item 10 -------------------------------------------------------------------------------------------

def test_indices_authored_only_as_time_samples_are_read(tmp_path):
    """Indexed primvars whose values and indices exist only as time samples (UV sets exported per frame):
    GetIndices(Default) is an empty array, not None, which used to hide the samples; both the face-varying
    st and an indexed uniform primvar must be refined, not blocked."""
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        api = UsdGeom.PrimvarsAPI(mesh)
        st = api.CreatePrimvar("st", T.TexCoord2fArray, "faceVarying")
        tag = api.CreatePrimvar("tag", T.FloatArray, "uniform")
        for t in (1.0, 2.0):
            st.Set(Vt.Vec2fArray.FromNumpy((pts[:, :2] * t).astype(np.float32)), t)
            st.SetIndices(Vt.IntArray(idx), t)
            tag.Set(Vt.FloatArray([10.0 * t, 20.0 * t]), t)
            tag.SetIndices(Vt.IntArray([1, 0]), t)

    src = write_mesh(tmp_path / "uv.usda", pts, counts, idx, setup=setup)
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu")
    assert not [w for w in result.warnings if "dropped" in w], result.warnings
    api = UsdGeom.PrimvarsAPI(out_prim(dst))
    mesh = UsdGeom.Mesh(out_prim(dst))
    p = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    for t in (1.0, 2.0):
        st = np.asarray(api.GetPrimvar("st").ComputeFlattened(t))
        np.testing.assert_allclose(st, p[fvi, :2] * t, atol=1e-5)  # a plane: face-varying = positions
        tag = np.asarray(api.GetPrimvar("tag").ComputeFlattened(t))
        np.testing.assert_allclose(tag, np.repeat([20.0 * t, 10.0 * t], 4))
    assert len(api.GetPrimvar("st").ComputeFlattened()) == len(fvi)  # the default: the first sample


# -- item 11 -------------------------------------------------------------------------------------------

def test_indexed_uniform_primvar_with_element_size_two(tmp_path):
    """An indexed uniform primvar with elementSize 2: its indices count elements (one per face), not scalars;
    every refined face gets its control face's element."""
    pts, counts, idx = grid(3, 3)

    def setup(stage, mesh):
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", T.FloatArray, "uniform", 2)
        pv.Set(Vt.FloatArray([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))  # three elements of two floats
        pv.SetIndices(Vt.IntArray([f % 3 for f in range(9)]))

    src = write_mesh(tmp_path / "w.usda", pts, counts, idx, setup=setup)
    dst = tmp_path / "out.usda"
    result = refine_usd(src, str(dst), 1, device="cpu")
    assert not [w for w in result.warnings if "dropped" in w], result.warnings
    pv = UsdGeom.PrimvarsAPI(out_prim(dst)).GetPrimvar("w")
    assert pv.GetElementSize() == 2 and pv.IsIndexed()
    indices = np.asarray(pv.GetIndices())
    assert len(indices) == 36  # one element per refined face
    # the refined faces of control face f: 4f .. 4f + 3 (Catmull-Clark quads)
    np.testing.assert_array_equal(indices, np.repeat([f % 3 for f in range(9)], 4))
    np.testing.assert_allclose(np.asarray(pv.ComputeFlattened()).reshape(-1, 2),
                               np.array([[1, 2], [3, 4], [5, 6]])[indices])


def test_indexed_uniform_primvar_indices_out_of_range_are_reported(tmp_path):
    """Indices of an indexed uniform primvar that point past its elements (elementSize 2) are reported
    and the primvar blocked, never a crash or a wrongly sized array."""
    pts, counts, idx = grid(2, 1)

    def setup(stage, mesh):
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("w", T.FloatArray, "uniform", 2)
        pv.Set(Vt.FloatArray([1.0, 2.0, 3.0]))  # 3 floats: not whole elements of 2
        pv.SetIndices(Vt.IntArray([0, 1]))

    src = write_mesh(tmp_path / "w.usda", pts, counts, idx, setup=setup)
    result = refine_usd(src, str(tmp_path / "out.usda"), 1, device="cpu")
    assert any("primvars:w dropped" in w and "elementSize 2" in w for w in result.warnings), result.warnings
