"""Rule-set agreement and disagreement, polygons, darts, creases, components, level 0, and Refiner.evaluate."""
import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh


def both(mesh, levels, scheme, **kw):
    a = ws.refine(mesh, levels, scheme=scheme, rules="piecewise-smooth", device="cpu", precision="float64", **kw)
    b = ws.refine(mesh, levels, scheme=scheme, rules="opensubdiv", device="cpu", precision="float64", **kw)
    np.testing.assert_array_equal(a.face_vertex_indices, b.face_vertex_indices)
    return a.points, b.points


def lattice_triangle(n=4):
    """A triangle cut into n^2 triangles of a regular lattice: boundary vertices have 3 faces, corners 1."""
    ids = {}
    pts = []
    for j in range(n + 1):
        for i in range(n + 1 - j):
            ids[i, j] = len(pts)
            pts.append([i + 0.5 * j, j * np.sqrt(3) / 2, 0.3 * np.sin(i + 2 * j)])
    tris = []
    for j in range(n):
        for i in range(n - j):
            tris.append([ids[i, j], ids[i + 1, j], ids[i, j + 1]])
            if i + j + 2 <= n:
                tris.append([ids[i + 1, j], ids[i + 1, j + 1], ids[i, j + 1]])
    return ws.Mesh(np.array(pts), [3] * len(tris), np.array(tris).reshape(-1))


@pytest.mark.parametrize("name,scheme", [
    ("cube", "catmull-clark"), ("cube_creased", "catmull-clark"), ("mixed_prism", "catmull-clark"),
    ("icosahedron", "loop"), ("octahedron", "loop"), ("mixed_prism", "loop"),
    ("grid3x3", "catmull-clark"),  # regular boundary (k = 2) and one-face corners
])
def test_rule_sets_coincide(name, scheme):
    a, b = both(load_mesh(name), 3, scheme)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_rule_sets_coincide_on_regular_loop_boundary():
    a, b = both(lattice_triangle(), 3, "loop")
    np.testing.assert_allclose(a, b, atol=1e-12)


@pytest.mark.parametrize("name,scheme,vertex", [
    ("quad_lshape", "catmull-clark", 10),   # boundary vertex with 3 faces (CC regular: 2)
    ("quad_halffan", "catmull-clark", 0),
    ("tri_halffan", "loop", 0),              # boundary vertex with 4 faces (Loop regular: 3)
    ("tri_hexfan", "loop", 1),               # boundary vertices with 2 faces
])
def test_rule_sets_differ_at_extraordinary_boundary_vertices(name, scheme, vertex):
    mesh = load_mesh(name)
    a, b = both(mesh, 1, scheme)
    diff = np.linalg.norm(a - b, axis=1)
    assert diff.max() > 1e-3
    # the vertex itself follows the crease rule in both; only its edge neighbours move
    assert diff[vertex] < 1e-12


def test_concave_corner_changes_the_surface():
    m = load_mesh("quad_lshape")
    convex = ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, corners=[10])
    concave = ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, corners=[10], concave=[[10, 6]])
    a = ws.refine(convex, 2, device="cpu", precision="float64").points
    b = ws.refine(concave, 2, device="cpu", precision="float64").points
    c = ws.refine(concave, 2, rules="opensubdiv", device="cpu", precision="float64").points
    assert np.abs(a - b).max() > 1e-3 and np.abs(b - c).max() > 1e-3
    # the corner interpolates
    np.testing.assert_allclose(b[10], m.points[10], atol=1e-12)


def test_polygon_input():
    mesh = load_mesh("mixed_prism")  # pentagons, quads and triangles
    out = ws.refine(mesh, 1, device="cpu")
    assert np.all(out.face_vertex_counts == 4)
    assert out.num_faces == int(mesh.face_vertex_counts.sum())
    assert out.num_vertices == mesh.num_vertices + mesh.num_faces + mesh.num_edges
    loop = ws.refine(mesh, 1, scheme="loop", device="cpu")
    assert np.all(loop.face_vertex_counts == 3)
    assert loop.num_faces == 4 * int((mesh.face_vertex_counts - 2).sum())


def test_dart_uses_interior_rule_and_crease_edge_midpoint():
    cube = load_mesh("cube")
    dart = ws.Mesh(cube.points, cube.face_vertex_counts, cube.face_vertex_indices, creases=[[0, 1]])
    plain = ws.refine(cube, 1, device="cpu", precision="float64").points
    out = ws.refine(dart, 1, device="cpu", precision="float64").points
    np.testing.assert_allclose(out[:8], plain[:8], atol=1e-12)  # vertex points: interior rule
    e = dart.edges.find(np.array([[0, 1]]), 8)[0]
    np.testing.assert_allclose(out[8 + 6 + e], (cube.points[0] + cube.points[1]) / 2, atol=1e-12)
    a, b = both(dart, 2, "catmull-clark")
    np.testing.assert_allclose(a, b, atol=1e-12)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_crease_curve_depends_only_on_crease_points(scheme):
    """A crease loop around a closed cube: the refined crease is a B-spline of the crease points alone."""
    cube = load_mesh("cube")
    ring = [[4, 5], [5, 6], [6, 7], [7, 4]]  # the top face's edges
    def make(pts):
        return ws.Mesh(pts, cube.face_vertex_counts, cube.face_vertex_indices, creases=ring)
    moved = cube.points.copy()
    moved[0] += [0.3, -0.2, 0.5]  # a vertex off the crease
    r = ws.Refiner(make(cube.points), 3, scheme=scheme, device="cpu", precision="float64")
    a, b = r.evaluate(cube.points), r.evaluate(moved)
    on_crease = np.flatnonzero(np.all(np.isclose(a[:, 2:], 1.0), axis=1) & np.all(np.isclose(b[:, 2:], 1.0), axis=1))
    assert len(on_crease) >= 4 * 8  # the curve's points at level 3
    np.testing.assert_allclose(a[on_crease], b[on_crease], atol=1e-12)
    # level-1 crease vertex: 3/4 c + 1/8 (a + b)
    r1 = ws.refine(make(cube.points), 1, scheme=scheme, device="cpu", precision="float64").points
    p = cube.points
    np.testing.assert_allclose(r1[4], 0.75 * p[4] + 0.125 * (p[5] + p[7]), atol=1e-12)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_two_components_refine_independently(scheme):
    base = load_mesh("cube" if scheme == "catmull-clark" else "icosahedron")
    n = base.num_vertices
    shifted = base.points + [10.0, 0, 0]
    two = ws.Mesh(np.vstack([base.points, shifted]), np.concatenate([base.face_vertex_counts] * 2),
                  np.concatenate([base.face_vertex_indices, base.face_vertex_indices + n]))
    one = ws.refine(base, 2, scheme=scheme, device="cpu", precision="float64").points
    both_out = ws.refine(two, 2, scheme=scheme, device="cpu", precision="float64").points
    expected = np.vstack([one, one + [10.0, 0, 0]])
    np.testing.assert_allclose(np.sort(both_out, axis=0), np.sort(expected, axis=0), atol=1e-12)


def test_level_zero_is_the_control_mesh():
    mesh = load_mesh("mixed_prism")
    out = ws.refine(mesh, 0, device="cpu", precision="float64")
    np.testing.assert_array_equal(out.points, mesh.points)
    np.testing.assert_array_equal(out.face_vertex_counts, mesh.face_vertex_counts)
    np.testing.assert_array_equal(out.face_vertex_indices, mesh.face_vertex_indices)
    loop = ws.refine(mesh, 0, scheme="loop", device="cpu")
    assert np.all(loop.face_vertex_counts == 3)


def test_holes_are_left_out():
    grid = load_mesh("grid3x3")
    holed = ws.Mesh(grid.points, grid.face_vertex_counts, grid.face_vertex_indices, holes=[4])
    a = ws.refine(grid, 2, device="cpu", precision="float64")
    b = ws.refine(holed, 2, device="cpu", precision="float64")
    np.testing.assert_array_equal(a.points, b.points)  # holes shape their neighbours as faces do
    assert b.num_faces == a.num_faces - 16
    kept = a.face_vertex_indices.reshape(-1, 4)
    assert set(map(tuple, b.face_vertex_indices.reshape(-1, 4))) < set(map(tuple, kept))


def test_boundary_none_leaves_out_faces_touching_the_boundary():
    grid = load_mesh("grid3x3")
    out = ws.refine(grid, 1, boundary="none", device="cpu")
    assert out.num_faces == 4  # only the centre quad's four children


def test_evaluate_vertex_data(device):
    mesh = load_mesh("quad_lshape")
    r = ws.Refiner(mesh, 2, device=device, precision="float64")
    p = mesh.points
    ref = r.evaluate(p)
    # animation frames: the same tables, affine invariance
    np.testing.assert_allclose(r.evaluate(p + [1.0, -2.0, 3.0]), ref + [1.0, -2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(r.evaluate(2.0 * p), 2.0 * ref, atol=1e-12)
    # (n, d) data: each column refines like a coordinate
    data = np.column_stack([p, p[:, :2] ** 2, np.ones(len(p))])
    out = r.evaluate(data)
    assert out.shape == (r.num_vertices, 6)
    np.testing.assert_allclose(out[:, :3], ref, atol=1e-12)
    np.testing.assert_allclose(out[:, 5], 1.0, atol=1e-12)
    one_d = r.evaluate(p[:, 0])
    assert one_d.shape == (r.num_vertices,)
    np.testing.assert_allclose(one_d, ref[:, 0], atol=1e-12)
    counts, indices = r.topology()
    assert counts.dtype == np.int32 and indices.dtype == np.int32 and indices.max() < r.num_vertices


def test_table_bytes_reported():
    """Uniform levels keep index tables and explicit stencils for the irregular rows only."""
    r = ws.Refiner(load_mesh("quad_lshape"), 3, device="cpu")
    full = sum(len(t.weights) * 4 + t.offsets.nbytes + t.indices.nbytes for t in r.tables)
    assert r.table_bytes() == sum(step.nbytes(4) for step in r.steps)
    assert 0 < r.table_bytes() < full
    regular = r.steps[-1]
    assert regular.explicit.num_rows < 0.2 * regular.num_rows  # most rows come from the index tables


CASES = [("cube", "catmull-clark"), ("cube_creased", "catmull-clark"), ("quad_lshape", "catmull-clark"),
         ("quad_halffan", "catmull-clark"), ("mixed_prism", "catmull-clark"), ("grid3x3", "catmull-clark"),
         ("icosahedron", "loop"), ("tri_halffan", "loop"), ("tri_hexfan", "loop"), ("mixed_prism", "loop"),
         ("tri_grid3x3", "loop"), ("icosahedron", "catmull-clark"), ("tri_hexfan", "catmull-clark")]


@pytest.mark.parametrize("name,scheme", CASES)
@pytest.mark.parametrize("rules", ["piecewise-smooth", "opensubdiv"])
def test_index_arithmetic_kernels_equal_the_full_stencil_tables(name, scheme, rules, device):
    """The kernels that compute smooth rows from the index tables give exactly what the full tables give."""
    mesh = load_mesh(name)
    extra = {}
    if name == "quad_lshape" and rules == "piecewise-smooth":
        mesh = ws.Mesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, corners=[10, 0],
                       creases=[[5, 6], [6, 10]])
    if rules == "piecewise-smooth":
        extra["flatness"] = 0.0  # linear rules only: compare with the plain stencil tables
    r = ws.Refiner(mesh, 3, scheme=scheme, rules=rules, device=device, precision="float64", **extra)
    expected = mesh.points
    for table in r.tables:
        rows = np.repeat(np.arange(table.num_rows), np.diff(table.offsets.astype(np.int64)))
        step = np.zeros((table.num_rows, 3))
        np.add.at(step, rows, table.weights[:, None] * expected[table.indices])
        expected = step
    np.testing.assert_allclose(r.evaluate(mesh.points), expected, atol=1e-12)
