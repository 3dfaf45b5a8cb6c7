"""rules="opensubdiv" reproduces OpenSubdiv 3.6's uniform refinement (tests/data/*.npz, see their README)."""
import glob
import os

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import DATA, load_mesh

CASES = sorted(os.path.basename(p)[:-4] for p in glob.glob(os.path.join(DATA, "*.npz")))
SCHEMES = {"catmark": "catmull-clark", "loop": "loop"}


def parse(case):
    mesh, scheme, boundary, level = case.split("__")
    return mesh, SCHEMES[scheme], boundary.replace("_", "-"), int(level[1:])


def test_all_reference_cases_present():
    assert len(CASES) == 10
    boundaries = {parse(c)[2] for c in CASES}
    assert boundaries == {"edge-and-corner", "edge-only"}


@pytest.mark.parametrize("case", CASES)
def test_matches_opensubdiv_at_every_stored_level(case):
    name, scheme, boundary, top = parse(case)
    ref = np.load(os.path.join(DATA, case + ".npz"))
    mesh = load_mesh(name)
    assert np.allclose(ref["L0_points"], mesh.points)
    for level in range(1, top + 1):
        out = ws.refine(mesh, level, scheme=scheme, rules="opensubdiv", boundary=boundary, device="cpu",
                        precision="float64")
        expected = ref[f"L{level}_points"]
        assert out.points.shape == expected.shape
        scale = np.abs(expected).max()
        np.testing.assert_allclose(out.points, expected, rtol=0, atol=1e-6 * scale)
        # same vertex, face and corner order as OpenSubdiv
        np.testing.assert_array_equal(out.face_vertex_counts, ref[f"L{level}_face_counts"])
        np.testing.assert_array_equal(out.face_vertex_indices, ref[f"L{level}_face_indices"])
        assert out.face_vertex_indices.dtype == np.int32 and out.level == level


@pytest.mark.parametrize("case", CASES)
def test_float32_and_device(case, device):
    name, scheme, boundary, top = parse(case)
    ref = np.load(os.path.join(DATA, case + ".npz"))
    out = ws.refine(load_mesh(name), top, scheme=scheme, rules="opensubdiv", boundary=boundary, device=device)
    assert out.points.dtype == np.float32
    expected = ref[f"L{top}_points"]
    np.testing.assert_allclose(out.points, expected, rtol=0, atol=1e-6 * np.abs(expected).max() * 4)


@pytest.mark.parametrize("case", CASES)
def test_stencil_tables_compose_to_opensubdiv_factorised_stencils(case):
    """The product of our per-level tables equals OpenSubdiv's level-0 stencils of the last level."""
    name, scheme, boundary, top = parse(case)
    ref = np.load(os.path.join(DATA, case + ".npz"))
    r = ws.Refiner(load_mesh(name), top, scheme=scheme, rules="opensubdiv", boundary=boundary, device="cpu")
    from conftest import dense

    product = np.eye(r.base_num_vertices)
    for table in r.tables:
        product = dense(table) @ product
    expected = np.zeros_like(product)
    rows = np.repeat(np.arange(len(ref["stencil_sizes"])), ref["stencil_sizes"])
    np.add.at(expected, (rows, ref["stencil_indices"]), ref["stencil_weights"])
    np.testing.assert_allclose(product, expected, atol=1e-12)


@pytest.mark.parametrize("case", CASES)
def test_limit_points_and_normals_match_opensubdiv(case, device):
    """Refined.limit_points() / limit_normals() against OpenSubdiv's limit positions and T1 x T2."""
    name, scheme, boundary, top = parse(case)
    ref = np.load(os.path.join(DATA, case + ".npz"))
    out = ws.refine(load_mesh(name), top, scheme=scheme, rules="opensubdiv", boundary=boundary, device=device,
                    precision="float64")
    scale = np.abs(ref["limit_points"]).max()
    np.testing.assert_allclose(out.limit_points(), ref["limit_points"], rtol=0, atol=1e-6 * scale)
    normal = np.cross(ref["limit_tangent1"], ref["limit_tangent2"])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    np.testing.assert_allclose(out.limit_normals(), normal, rtol=0, atol=1e-5)
