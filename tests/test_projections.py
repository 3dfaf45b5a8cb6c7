"""Flatness and normal-control options: validation, averaging, interplay, and vertex data."""
import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh
from warp_subdiv.rules import limit_masks as M
from warp_subdiv.tables.projections import sector_local_vectors
from warp_subdiv.rules.weights import SECTOR_CREASE
from warp_subdiv.topology import base_level, refine_level


def tagged(name, **tags):
    m = load_mesh(name)
    return ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, **tags)


def test_flatness_out_of_range_names_the_vertex():
    grid = load_mesh("grid3x3")
    with pytest.raises(ws.SubdivInputError, match=r"flatness 1.5 is outside \[0, 1\]"):  # before any analysis
        ws.refine(grid, 1, flatness=1.5, device="cpu")
    per_vertex = np.zeros(16)
    per_vertex[2] = -0.25
    with pytest.raises(ws.SubdivInputError, match=r"flatness -0.25 at vertex 2 "):
        ws.refine(grid, 1, flatness=per_vertex, device="cpu")
    with pytest.raises(ws.SubdivInputError, match=r"one value per vertex \(16\)"):
        ws.refine(grid, 1, flatness=np.zeros(5), device="cpu")


def test_concave_corner_needs_flatness_above_s_min():
    mesh = tagged("quad_lshape", corners=[10], concave=[[10, 6]])
    s = np.full(mesh.num_vertices, np.nan)
    s[10] = 0.05
    with pytest.raises(ws.SubdivInputError, match=r"concave corner vertex 10 must exceed s_min = 0\.\d+"):
        ws.refine(mesh, 1, flatness=s, device="cpu")
    s[10] = 0.9
    assert np.all(np.isfinite(ws.refine(mesh, 2, flatness=s, device="cpu").points))


def test_options_that_do_not_fit_the_rule_set():
    grid = load_mesh("grid3x3")
    with pytest.raises(ValueError, match="flatness"):
        ws.refine(grid, 1, rules="opensubdiv", flatness=0.5, device="cpu")
    with_normal = tagged("grid3x3", normals=([5], [[0, 0, 1]]))
    with pytest.raises(ValueError, match="piecewise-smooth"):
        ws.refine(with_normal, 1, rules="opensubdiv", device="cpu")
    with pytest.raises(ValueError, match="normal_strength"):
        ws.refine(with_normal, 1, normal_strength=1.5, device="cpu")
    # a one-face corner has no sector of two faces for normal control
    corner = tagged("grid3x3", normals=([0], [[0, 0, 1]]))
    with pytest.raises(ws.SubdivInputError, match="prescribed normal at vertex 0"):
        ws.refine(corner, 1, device="cpu")


def test_adjacent_prescribed_normals_average_their_displacements():
    """First level: a point in the rings of two constrained vertices gets the average of both moves."""
    cube = load_mesh("cube")
    n0 = np.array([-1.0, -1.0, -0.5]) / 1.5
    n1 = np.array([1.0, -0.6, -0.8]) / np.sqrt(2.0)

    def level1(ids, normals):
        mesh = ws.Mesh(cube.points, cube.face_vertex_counts, cube.face_vertex_indices,
                       normals=(ids, normals) if ids else None)
        r = ws.Refiner(mesh, 1, device="cpu", precision="float64")
        ring = np.zeros(r.num_vertices, dtype=bool)
        if ids:
            ring[r.normal_tables[0].targets] = True
        return r.evaluate(cube.points), ring

    (none, _), (only0, moved0), (only1, moved1) = level1([], []), level1([0], [n0]), level1([1], [n1])
    both, _ = level1([0, 1], [n0, n1])
    d0, d1 = only0 - none, only1 - none
    assert np.any(moved0 & moved1)  # the shared edge and face points
    expected = none + np.where((moved0 & moved1)[:, None], (d0 + d1) / 2, d0 + d1)
    np.testing.assert_allclose(both, expected, atol=1e-12)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_normal_control_with_flatness_uses_the_modified_cross_mask(scheme):
    """At a crease vertex with flatness s_f > 0 and normal strength 1, the l_cross(s_f) normal is n after a step."""
    grid = load_mesh("grid3x3" if scheme == "catmull-clark" else "tri_grid3x3")
    n = np.array([0.6, -0.48, 0.64])
    bent = grid.points.copy()
    bent[1, 2] += 0.3  # a curved boundary, so that l_cross(s) and l_cross see different tangents
    mesh = ws.Mesh(bent, grid.face_vertex_counts, grid.face_vertex_indices, normals=([1], [n]))
    s_f = np.full(16, np.nan)
    s_f[1] = 0.6
    pts = ws.refine(mesh, 1, scheme=scheme, flatness=s_f, device="cpu", precision="float64").points
    level = refine_level(base_level(mesh, scheme, "edge-and-corner", "piecewise-smooth", flatness=s_f))
    sector = int(np.flatnonzero(level.sector_vertex == 1)[0])
    k = int(level.sector_k()[sector])
    ids = sector_local_vectors(level, np.array([sector]), k)[0]
    m = M.sector_masks(scheme, np.array([SECTOR_CREASE]), k, np.array([np.pi / k]), np.array([0.6]))
    normal = np.cross(m.tu[0] @ pts[ids], m.tv[0] @ pts[ids])
    np.testing.assert_allclose(normal / np.linalg.norm(normal), n, atol=1e-9)
    plain = M.sector_masks(scheme, np.array([SECTOR_CREASE]), k, np.array([np.pi / k]))
    other = np.cross(plain.tu[0] @ pts[ids], plain.tv[0] @ pts[ids])
    if scheme == "loop":  # the unmodified cross mask misses n (g3 != 0 at the regular Loop crease; 0 for CC)
        assert np.linalg.norm(other / np.linalg.norm(other) - n) > 1e-4


def test_vertex_data_gets_flatness_but_not_normal_control(device):
    mesh = tagged("quad_lshape", corners=[10], concave=[[10, 6]], normals=([5], [[0.0, 0.6, 0.8]]))
    r = ws.Refiner(mesh, 2, device=device, precision="float64")
    p = mesh.points
    with_normals = r.evaluate(p)
    without = r.evaluate(p, normal_control=False)
    assert np.abs(with_normals - without).max() > 1e-3
    data = r.evaluate(np.column_stack([p, np.ones(len(p))]))  # (n, 4): flatness only
    np.testing.assert_allclose(data[:, :3], without, atol=1e-12)
    np.testing.assert_allclose(data[:, 3], 1.0, atol=1e-12)  # flatness keeps constants (affine)
    with pytest.raises(ValueError, match="positions only"):
        r.evaluate(np.column_stack([p, p]), normal_control=True)


@pytest.mark.parametrize("levels", [0, 2])
def test_limits_of_data_take_no_normal_control(levels):
    """Limit points of data that is not a position (colours, three columns like positions) take no normal control
    with normal_control=False, also where the masks are read one level deeper (that extra step used to apply it to
    every (N, 3) array): they equal matrix("limit") @ data, the same data in four columns, and
    evaluate_with_limits. Positions keep normal control by default."""
    mesh = tagged("quad_lshape", corners=[10], concave=[[10, 6]], normals=([5], [[0.0, 0.6, 0.8]]))
    r = ws.Refiner(mesh, levels, device="cpu", precision="float64")
    assert r.limit_reads_deeper()
    colours = np.random.default_rng(4).random((r.base_num_vertices, 3))
    refined = r.evaluate(colours, normal_control=False)
    limit = r.limit_points(refined, normal_control=False)
    np.testing.assert_allclose(limit, r.matrix("limit") @ colours, rtol=0, atol=1e-12)
    four = r.limit_points(np.column_stack([refined, np.ones(len(refined))]))  # 4 columns: never normal control
    np.testing.assert_allclose(limit, four[:, :3], rtol=0, atol=1e-14)
    one_pass = r.evaluate_with_limits(colours, normal_control=False)
    assert np.array_equal(one_pass.points, refined)
    assert np.array_equal(one_pass.limit_points, limit)
    normals = r.limit_normals(refined, normal_control=False)
    assert np.array_equal(one_pass.limit_normals, normals)
    assert abs(normals[5] @ [0.0, 0.6, 0.8]) < 0.99  # the surface refined without normal control: not prescribed
    with pytest.raises(ws.SubdivInputError, match="positions only"):
        r.limit_points(np.zeros((r.num_vertices, 2)), normal_control=True)

    points = r.evaluate(mesh.points)  # positions: normal control by default, as the matrix with normal_control
    np.testing.assert_allclose(r.limit_points(points).ravel(),
                               r.matrix("limit", normal_control=True) @ mesh.points.ravel(), rtol=0, atol=1e-12)
    one_pass = r.evaluate_with_limits(mesh.points)
    assert np.array_equal(one_pass.limit_points, r.limit_points(points))
    assert np.array_equal(one_pass.limit_normals, r.limit_normals(points))
    np.testing.assert_allclose(one_pass.limit_normals[5], [0.0, 0.6, 0.8], atol=1e-12)
