"""OpenSubdiv's "smooth triangles" (TRI_SUB_SMOOTH, USD triangleSubdivisionRule = "smooth") for Catmull-Clark."""
import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh


def test_edge_between_two_triangles():
    """Face points weigh 0.470 each, the endpoints 0.5 (1 - 2 * 0.470) = 0.03; face points expand to 1/3."""
    ico = load_mesh("icosahedron")
    r = ws.Refiner(ico, 1, triangle_subdivision="smooth", device="cpu", precision="float64")
    e = 0
    a, b = (int(v) for v in ico.edges.edge_verts[e])
    row = r.tables[0].row(12 + 20 + e)
    assert row[a] == pytest.approx(0.03 + 2 * 0.47 / 3, abs=1e-12)
    assert row[b] == pytest.approx(0.03 + 2 * 0.47 / 3, abs=1e-12)
    others = [k for k in row if k not in (a, b)]
    assert len(others) == 2 and all(row[k] == pytest.approx(0.47 / 3, abs=1e-12) for k in others)


def test_edge_between_a_triangle_and_a_quad():
    """mixed_prism: mean face weight (0.470 + 0.25)/2 on both face points, the endpoints what is left."""
    prism = load_mesh("mixed_prism")
    e = int(prism.edges.find(np.array([[1, 6]]), 10)[0])  # edge between triangle (0, 1, 6) and quad (1, 2, 7, 6)
    r = ws.Refiner(prism, 1, triangle_subdivision="smooth", device="cpu", precision="float64")
    row = r.tables[0].row(10 + 8 + e)
    w = 0.5 * (0.47 + 0.25)
    end = 0.5 * (1 - 2 * w)
    counts = prism.face_vertex_counts
    # faces holding both 1 and 2: find their sizes
    offs = np.concatenate([[0], np.cumsum(counts)])
    faces = [prism.face_vertex_indices[offs[f]:offs[f + 1]] for f in range(len(counts))]
    around = [f for f in faces if 1 in f and 6 in f]
    expected = {1: end, 6: end}
    for f in around:
        for v in f:
            expected[int(v)] = expected.get(int(v), 0.0) + w / len(f)
    assert set(row) == set(expected)
    for k in row:
        assert row[k] == pytest.approx(expected[k], abs=1e-12)


def test_only_triangles_of_the_control_mesh_change_and_loop_ignores_it():
    cube = load_mesh("cube")
    a = ws.refine(cube, 2, triangle_subdivision="smooth", device="cpu", precision="float64").points
    b = ws.refine(cube, 2, device="cpu", precision="float64").points
    np.testing.assert_array_equal(a, b)  # no triangles: nothing changes
    ico = load_mesh("icosahedron")
    a = ws.refine(ico, 2, scheme="loop", triangle_subdivision="smooth", device="cpu", precision="float64").points
    b = ws.refine(ico, 2, scheme="loop", device="cpu", precision="float64").points
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="triangle_subdivision"):
        ws.refine(ico, 1, triangle_subdivision="loop", device="cpu")
