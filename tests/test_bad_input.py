"""Bad input: every user error raises warp_subdiv.SubdivInputError (a ValueError) naming the face, vertex or tag
at fault; invalid options raise ValueError; unsupported features raise NotImplementedError; non-manifold input
warns and still refines. Nothing half-made is returned.
"""
import re
import warnings

import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv import NonManifoldWarning, SubdivInputError

from conftest import load_mesh, mesh_path

# two quads sharing edge (1, 4):  0 1 2 / 3 4 5
GRID_PTS = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], dtype=np.float64)
GRID_COUNTS = [4, 4]
GRID_IDX = [0, 1, 4, 3, 1, 2, 5, 4]


def grid(**tags):
    return ws.Mesh(GRID_PTS, GRID_COUNTS, GRID_IDX, **tags)


def lshape(**tags):
    m = load_mesh("quad_lshape")
    return ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, **tags)


def build(mesh, levels=1, **kw):
    return ws.Refiner(mesh, levels, device="cpu", precision="float64", **kw)


def test_error_class_is_a_value_error():
    assert issubclass(SubdivInputError, ValueError)
    assert issubclass(NonManifoldWarning, Warning)


# --------------------------------------------------------------------------------------------------------
# faces


def test_vertex_index_out_of_range():
    with pytest.raises(SubdivInputError, match=r"face 1\b.*vertex 6\b") as info:
        ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, 6, 4])
    assert "[0, 6)" in str(info.value)


def test_vertex_index_negative():
    with pytest.raises(SubdivInputError, match=r"face 1\b.*vertex -1\b"):
        ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, -1, 4])
    with pytest.raises(SubdivInputError, match=r"face 0\b.*vertex -3\b"):
        ws.Mesh(GRID_PTS, GRID_COUNTS, [-3, 1, 4, 3, 1, 2, 5, 4])


@pytest.mark.parametrize("counts,n_idx", [([4, 4], 7), ([4, 4], 9), ([4, 3], 8), ([4, 4, 4], 8)])
def test_counts_do_not_add_up(counts, n_idx):
    idx = (GRID_IDX * 2)[:n_idx]
    with pytest.raises(SubdivInputError, match=rf"add up to {sum(counts)}\b.*\b{n_idx} entries"):
        ws.Mesh(GRID_PTS, counts, idx)


@pytest.mark.parametrize("bad", [2, 1, 0, -1])
def test_face_with_fewer_than_three_vertices(bad):
    counts = [3, 3, bad, 3]
    idx = [0, 1, 4, 0, 4, 3] + [1, 2][: max(bad, 0)] + [1, 2, 5]
    with pytest.raises(SubdivInputError, match=rf"face 2 has {bad} vertices"):
        ws.Mesh(GRID_PTS, counts, idx)


def test_face_with_repeated_vertex_is_accepted():
    """Faces that use a vertex twice (adjacent or not) are accepted, as OpenSubdiv accepts them: the repeated
    pairs and degenerate edges are non-manifold (sharp) edges (tests/test_osd_differential.py checks the
    result against OpenSubdiv)."""
    for counts, idx in ((GRID_COUNTS, [0, 1, 4, 3, 1, 2, 5, 2]), ([4, 3], [4, 1, 4, 3, 1, 2, 5])):
        mesh = ws.Mesh(GRID_PTS, counts, idx)
        with pytest.warns(ws.NonManifoldWarning):
            out = ws.refine(mesh, 1, device="cpu")
        assert np.all(np.isfinite(out.points))


def test_no_faces():
    with pytest.raises(SubdivInputError, match="no faces"):
        ws.Mesh(GRID_PTS, [], [])


def test_non_integer_indices():
    with pytest.raises(SubdivInputError, match="face_vertex_indices"):
        ws.Mesh(GRID_PTS, GRID_COUNTS, np.array(GRID_IDX, dtype=float) + 0.5)
    with pytest.raises(SubdivInputError, match="face_vertex_counts"):
        ws.Mesh(GRID_PTS, [4.5, 3.5], GRID_IDX)


# --------------------------------------------------------------------------------------------------------
# points


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_points(value):
    pts = GRID_PTS.copy()
    pts[4, 1] = value
    with pytest.raises(SubdivInputError, match=r"point 4\b"):
        ws.Mesh(pts, GRID_COUNTS, GRID_IDX)


@pytest.mark.parametrize("shape", [(6, 2), (6, 4), (18,), (6, 3, 1)])
def test_points_of_wrong_shape(shape):
    pts = np.zeros(shape)
    with pytest.raises(SubdivInputError, match=r"points must have shape \(n, 3\).*" + re.escape(str(shape))):
        ws.Mesh(pts, GRID_COUNTS, GRID_IDX)


@pytest.mark.parametrize("bad", [True, np.True_, "1", 1j])
def test_points_that_are_not_numbers(bad):
    """Bools, strings and complex numbers, which numpy would turn into coordinates without a word, are refused
    naming the vertex, in a list or as an array's dtype."""
    pts = GRID_PTS.tolist()
    pts[4][2] = bad
    with pytest.raises(SubdivInputError, match=r"points must hold real numbers, got .* \(vertex 4\)") as err:
        ws.Mesh(pts, GRID_COUNTS, GRID_IDX)
    assert (err.value.option, err.value.element, err.value.index) == ("points", "vertex", 4)
    with pytest.raises(SubdivInputError, match="points must hold real numbers"):
        ws.Mesh(GRID_PTS.astype(bool), GRID_COUNTS, GRID_IDX)
    with pytest.raises(SubdivInputError, match=r"normals must hold real numbers, got .* \(normal 0\)"):
        grid(normals=([1], [[0.0, bad, 1.0]]))


def test_ragged_points():
    with pytest.raises(SubdivInputError, match="points must be an array of real numbers"):
        ws.Mesh([[0, 0, 0], [1, 0]] * 3, GRID_COUNTS, GRID_IDX)


# --------------------------------------------------------------------------------------------------------
# tags


def test_crease_pair_not_an_edge():
    # (0, 4) is the diagonal of the first quad
    with pytest.raises(SubdivInputError, match=r"crease 1 \(0, 4\) is not an edge"):
        grid(creases=[[1, 4], [0, 4]])
    # two vertices of different faces
    with pytest.raises(SubdivInputError, match=r"crease 0 \(0, 5\) is not an edge"):
        grid(creases=[[0, 5]])


@pytest.mark.parametrize("bad", [6, 100, -1])
def test_crease_vertex_out_of_range(bad):
    with pytest.raises(SubdivInputError, match=rf"creases.*vertex {bad}\b"):
        grid(creases=[[1, 4], [2, bad]])


@pytest.mark.parametrize("bad", [6, -2])
def test_corner_vertex_out_of_range(bad):
    with pytest.raises(SubdivInputError, match=rf"corners.*vertex {bad}\b"):
        grid(corners=[0, bad])


def test_crease_tags_of_wrong_shape():
    with pytest.raises(SubdivInputError, match=r"creases must have shape \(n, 2\)"):
        grid(creases=[[1, 4, 2]])


def test_negative_or_nan_sharpness():
    with pytest.raises(SubdivInputError, match=r"crease_sharpness\[1\]"):
        grid(creases=[[1, 4], [0, 1]], crease_sharpness=[10.0, -1.0])
    with pytest.raises(SubdivInputError, match=r"corner_sharpness\[0\]"):
        grid(corners=[0], corner_sharpness=[np.nan])
    with pytest.raises(SubdivInputError, match=r"crease_sharpness has 3 values for 2 tags"):
        grid(creases=[[1, 4], [0, 1]], crease_sharpness=[10.0, 10.0, 10.0])


def test_concave_tag_on_non_corner_vertex():
    """Vertex 10 of quad_lshape is a crease vertex unless tagged as a corner; 5 is an interior vertex."""
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(10, 6\).*vertex 10 is not a corner"):
        build(lshape(concave=[[10, 6]]))
    with pytest.raises(SubdivInputError, match=r"concave tag 1 \(5, 6\).*vertex 5 is not a corner"):
        build(lshape(corners=[10], concave=[[10, 6], [5, 6]]))
    with pytest.raises(SubdivInputError, match=r"concave tag 0 .*vertex 10 is not a corner"):
        build(lshape(concave=[[10, 6]]), scheme="loop")


def test_concave_tag_on_non_corner_vertex_opensubdiv_rules():
    """Bad tags are refused under both rule sets (OpenSubdiv's rules ignore valid concave tags)."""
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(10, 6\).*vertex 10 is not a corner"):
        build(lshape(concave=[[10, 6]]), rules="opensubdiv")


def test_concave_tag_on_one_face_sector():
    # grid3x3 vertex 0 has one face: a corner (boundary='edge-and-corner', or tagged) whose only sector has k = 1
    g = load_mesh("grid3x3")
    m = ws.Mesh(g.points, g.face_vertex_counts, g.face_vertex_indices, concave=[[0, 1]])
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(0, 1\).*corner 0\b.*one face"):
        build(m)
    m = ws.Mesh(g.points, g.face_vertex_counts, g.face_vertex_indices, corners=[0, 3], concave=[[0, 4], [3, 7]])
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(0, 4\).*one face"):
        build(m, boundary="edge-only")
    # a corner of quad_lshape with one face, after a valid tag
    with pytest.raises(SubdivInputError, match=r"concave tag 1 \(12, 13\).*corner 12\b.*one face"):
        build(lshape(corners=[10, 12], concave=[[10, 6], [12, 13]]))


def test_concave_tag_on_crease_between_two_sectors():
    """On cube_creased every edge is a crease, so an edge names no single sector of its corner."""
    c = load_mesh("cube_creased")
    m = ws.Mesh(c.points, c.face_vertex_counts, c.face_vertex_indices, creases=c.creases, corners=c.corners,
                concave=[[0, 1]])
    with pytest.raises(SubdivInputError, match=r"concave tag 0 \(0, 1\)"):
        build(m)


def test_concave_pair_not_an_edge():
    # (10, 5) is a diagonal of face (5 6 10 9)
    with pytest.raises(SubdivInputError, match=r"concave tag 1 \(10, 5\).*not an edge"):
        lshape(corners=[10], concave=[[10, 6], [10, 5]])


def test_concave_vertex_out_of_range():
    with pytest.raises(SubdivInputError, match=r"concave.*vertex 99\b"):
        lshape(corners=[10], concave=[[10, 99]])


@pytest.mark.parametrize("bad", [2, 7, -1])
def test_hole_face_out_of_range(bad):
    with pytest.raises(SubdivInputError, match=rf"hole 1 is face {bad}\b"):
        grid(holes=[0, bad])


def test_normals_of_wrong_length():
    with pytest.raises(SubdivInputError, match=r"normals need shape \(2, 3\)"):
        grid(normals=([0, 1], [[0.0, 0.0, 1.0]]))
    with pytest.raises(SubdivInputError, match=r"normals need shape \(1, 3\)"):
        grid(normals=([0], [[0.0, 1.0]]))


def test_normals_not_unit():
    with pytest.raises(SubdivInputError, match=r"normal for vertex 4 has length 2\b"):
        grid(normals=([1, 4], [[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]))
    with pytest.raises(SubdivInputError, match=r"normal for vertex 3 has length 0\b"):
        grid(normals=([3], [[0.0, 0.0, 0.0]]))
    with pytest.raises(SubdivInputError, match=r"normal for vertex 0\b"):
        grid(normals=([0], [[np.nan, 0.0, 1.0]]))


def test_normals_bad_vertex_or_duplicate():
    with pytest.raises(SubdivInputError, match=r"normals vertex ids.*vertex 6\b"):
        grid(normals=([6], [[0.0, 0.0, 1.0]]))
    with pytest.raises(SubdivInputError, match=r"vertex 2 has more than one prescribed normal"):
        grid(normals=([2, 2], [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(SubdivInputError, match="pair"):
        grid(normals=[[0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------------------------------------
# scheme, options and evaluation


def test_loop_with_polygons_and_no_triangulation():
    # triangles 0, 1, then the quad as face 2
    m = ws.Mesh(GRID_PTS, [3, 3, 4], [0, 1, 4, 0, 4, 3, 1, 2, 5, 4])
    with pytest.raises(SubdivInputError, match=r"face 2 has 4 vertices"):
        ws.refine(m, 1, scheme="loop", triangulate=False, device="cpu")
    with pytest.raises(SubdivInputError, match=r"face 2 has 4 vertices"):
        ws.Refiner(m, 1, scheme="loop", triangulate=False, device="cpu")
    # the default fan-triangulates
    out = ws.refine(m, 1, scheme="loop", device="cpu")
    assert np.all(out.face_vertex_counts == 3) and np.all(np.isfinite(out.points))


def test_evaluate_wrong_number_of_rows():
    m = grid()
    r = build(m)
    for rows in (5, 7, 0):
        with pytest.raises(SubdivInputError, match=r"\(6, d\).*" + re.escape(f"({rows}, 3)")):
            r.evaluate(np.zeros((rows, 3)))
    with pytest.raises(SubdivInputError, match=r"\(6, d\)"):
        r.evaluate(np.zeros((6, 3, 1)))


@pytest.mark.parametrize("value", [np.nan, np.inf])
@pytest.mark.parametrize("width", [3, 2])
def test_evaluate_non_finite_data(value, width):
    r = build(grid())
    data = np.ones((6, width))
    data[3, width - 1] = value
    with pytest.raises(SubdivInputError, match=r"row 3\b"):
        r.evaluate(data)


@pytest.mark.parametrize("kw", [dict(scheme="foo"), dict(rules="foo"), dict(boundary="foo"),
                                dict(precision="float16"), dict(loop_beta="foo")])
def test_invalid_option_values(kw):
    m = grid()
    with pytest.raises(ValueError, match=re.escape(repr("foo" if "float16" not in kw.values() else "float16"))):
        ws.Refiner(m, 1, device="cpu", **kw)
    with pytest.raises(ValueError):
        ws.refine(m, 1, device="cpu", **kw)


@pytest.mark.parametrize("levels", [-1, 1.5, "2", True, None])
def test_invalid_levels(levels):
    m = grid()
    with pytest.raises(ValueError, match="levels"):
        ws.Refiner(m, levels, device="cpu")
    with pytest.raises(ValueError, match="levels"):
        ws.refine(m, levels, device="cpu")


def test_mesh_must_be_a_mesh():
    with pytest.raises(TypeError):
        ws.Refiner((GRID_PTS, GRID_COUNTS, GRID_IDX), 1, device="cpu")


@pytest.mark.parametrize("tags,option,index", [
    (dict(creases=[[1, 4]], crease_sharpness=[True]), "crease_sharpness", 0),
    (dict(creases=[[1, 4], [0, 1]], crease_sharpness=[2.0, "2"]), "crease_sharpness", 1),
    (dict(creases=[[1, 4]], crease_sharpness=np.array([False])), "crease_sharpness", 0),
    (dict(creases=[[1, 4]], crease_sharpness=np.array(["2"])), "crease_sharpness", 0),
    (dict(corners=[0], corner_sharpness="2"), "corner_sharpness", None),
    (dict(corners=[0], corner_sharpness=True), "corner_sharpness", None),
    (dict(corners=[0], corner_sharpness=b"2"), "corner_sharpness", None),
    (dict(corners=[0, 5], corner_sharpness=[1.0, np.bool_(True)]), "corner_sharpness", 1),
    (dict(corners=[0], corner_sharpness=np.array([1 + 0j])), "corner_sharpness", 0),
])
def test_sharpness_refuses_bools_and_strings(tags, option, index):
    """A bool or a string in a sharpness argument (or as the one value for all tags) is refused naming the
    argument (and the tag): numpy would turn True into sharpness 1 and '2' into 2 without a word."""
    with pytest.raises(SubdivInputError, match=f"{option} must hold numbers") as err:
        grid(**tags)
    assert err.value.option == option and err.value.index == index
    if index is not None:
        assert err.value.element == option.split("_")[0]


def test_sharpness_takes_numbers_of_any_kind():
    """Numbers of every numeric type stay accepted, as before."""
    for value in ([2], np.array([2], np.int32), np.array([2.0], np.float32), [np.float64(2.0)], 2, np.int64(2)):
        assert grid(creases=[[1, 4]], crease_sharpness=value).crease_sharpness.tolist() == [2.0]
        assert grid(corners=[0], corner_sharpness=value).corner_sharpness.tolist() == [2.0]

def test_sharpness_values():
    """Finite sharpness is semi-sharp (supported); >= 10 infinitely sharp; 0 untagged; negative refused."""
    build(grid(creases=[[0, 1], [1, 4]], crease_sharpness=[10.0, 2.5]))
    build(grid(corners=[4], corner_sharpness=[2.5]))
    build(grid(creases=[[1, 4]], crease_sharpness=[12.0]))
    build(grid(creases=[[1, 4]], crease_sharpness=[0.0]))
    with pytest.raises(SubdivInputError, match=r"crease_sharpness\[0\] = -1"):
        grid(creases=[[1, 4]], crease_sharpness=[-1.0])
    with pytest.raises(ValueError, match="crease_method"):
        ws.Refiner(grid(), 1, device="cpu", crease_method="bspline")


# --------------------------------------------------------------------------------------------------------
# non-manifold and disconnected input


def three_face_fan(scheme):
    """Three faces fanned around edge (0, 1)."""
    pts = [[0, 0, 0], [0, 0, 1]]
    idx = []
    for i in range(3):
        a = 2 * np.pi * i / 3
        if scheme == "loop":
            pts.append([np.cos(a), np.sin(a), 0.5])
            idx += [0, 2 + i, 1]
        else:
            pts += [[np.cos(a), np.sin(a), 0], [np.cos(a), np.sin(a), 1]]
            idx += [0, 2 + 2 * i, 3 + 2 * i, 1]
    return ws.Mesh(np.array(pts, dtype=np.float64), [3 if scheme == "loop" else 4] * 3, idx)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_non_manifold_edge_warns_and_refines(scheme):
    m = three_face_fan(scheme)
    with pytest.warns(NonManifoldWarning, match="non-manifold"):
        r = build(m, levels=2, scheme=scheme)
    out = r.refine()
    assert np.all(np.isfinite(out.points))
    assert len(out.points) == r.num_vertices
    # the non-manifold edge is sharp: its child is the midpoint; its end vertices do not move off the edge
    extra = m.num_faces if scheme == "catmull-clark" else 0
    child = m.num_vertices + extra + int(m.edges.find(np.array([[0, 1]]), m.num_vertices)[0])
    with pytest.warns(NonManifoldWarning):
        one = ws.refine(m, 1, scheme=scheme, device="cpu", precision="float64")
    np.testing.assert_allclose(one.points[child], [0.0, 0.0, 0.5], atol=1e-12)
    for v in (0, 1):
        assert abs(one.points[v][0]) < 1e-12 and abs(one.points[v][1]) < 1e-12


def test_manifold_mesh_does_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", NonManifoldWarning)
        build(load_mesh("cube"), levels=2)
        build(load_mesh("icosahedron"), levels=2, scheme="loop")


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_disconnected_components(scheme):
    name = "cube" if scheme == "catmull-clark" else "octahedron"
    a = load_mesh(name)
    V = a.num_vertices
    shift = np.array([5.0, 0.0, 0.0])
    pts = np.concatenate([a.points, a.points + shift])
    counts = np.concatenate([a.face_vertex_counts, a.face_vertex_counts])
    idx = np.concatenate([a.face_vertex_indices, a.face_vertex_indices + V])
    both = ws.Mesh(pts, counts, idx)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NonManifoldWarning)
        out2 = ws.refine(both, 2, scheme=scheme, device="cpu", precision="float64")
    out1 = ws.refine(a, 2, scheme=scheme, device="cpu", precision="float64")
    assert np.all(np.isfinite(out2.points))
    assert len(out2.points) == 2 * len(out1.points)
    assert len(out2.face_vertex_counts) == 2 * len(out1.face_vertex_counts)
    # the vertex children of the second copy are those of the first, shifted
    np.testing.assert_allclose(out2.points[V:2 * V], out1.points[:V] + shift, atol=1e-12)
    np.testing.assert_allclose(out2.points[:V], out1.points[:V], atol=1e-12)
    # the set of refined points is the union of the two copies
    key = lambda p: np.round(p, 9)  # noqa: E731
    got = {tuple(x) for x in key(out2.points)}
    want = {tuple(x) for x in key(np.concatenate([out1.points, out1.points + shift]))}
    assert got == want


# --------------------------------------------------------------------------------------------------------
# nothing half-made


def test_failed_calls_return_nothing():
    result = sentinel = object()
    with pytest.raises(SubdivInputError):
        result = ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, 6, 4])
    assert result is sentinel
    with pytest.raises(SubdivInputError):
        result = ws.refine(lshape(concave=[[10, 6]]), 1, device="cpu")
    assert result is sentinel
    with pytest.raises(ValueError):
        result = ws.refine(grid(), 1, scheme="foo", device="cpu")
    assert result is sentinel


def test_failed_evaluate_leaves_refiner_usable():
    """A refused evaluate must not leave stale or partial data behind: the next good call is exact."""
    m = load_mesh("cube")
    r = build(m, levels=2)
    good = r.evaluate(m.points)
    bad = m.points.copy()
    bad[5] = np.nan
    with pytest.raises(SubdivInputError, match=r"row 5\b"):
        r.evaluate(bad)
    with pytest.raises(SubdivInputError):
        r.evaluate(m.points[:-1])
    again = r.evaluate(m.points)
    np.testing.assert_array_equal(again, good)
    moved = r.evaluate(m.points * 2.0)
    np.testing.assert_allclose(moved, good * 2.0, atol=1e-12)


def test_failed_refiner_does_not_touch_mesh():
    m = lshape(concave=[[10, 6]])
    before = (m.points.copy(), m.face_vertex_indices.copy(), m.concave.copy())
    with pytest.raises(SubdivInputError):
        build(m)
    np.testing.assert_array_equal(m.points, before[0])
    np.testing.assert_array_equal(m.face_vertex_indices, before[1])
    np.testing.assert_array_equal(m.concave, before[2])
    # the same mesh with the missing corner tag refines
    fixed = lshape(corners=[10], concave=[[10, 6]])
    assert np.all(np.isfinite(build(fixed).refine().points))


# --------------------------------------------------------------------------------------------------------
# OBJ input


def test_obj_bad_lines_name_file_and_line(tmp_path):
    from warp_subdiv.io.obj import read_obj

    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
    with pytest.raises(SubdivInputError, match=r"bad\.obj:4"):
        read_obj(str(p))
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 9\n")
    with pytest.raises(SubdivInputError, match=r"face 1\b.*vertex 8\b"):
        read_obj(str(p))
    with pytest.raises(SubdivInputError, match="cannot read"):
        read_obj(str(tmp_path / "missing.obj"))
    # a good file still reads
    assert read_obj(mesh_path("cube")).mesh.num_faces == 6


def test_size_guards_refuse_before_any_work():
    """32-bit tables: a request whose last level has more than 2^31 - 1 face corners is refused at once; a
    memory limit refuses predictions above it with the amount needed."""
    import time

    from warp_subdiv.runtime.estimate import MemoryGuardError

    cube = load_mesh("cube")
    start = time.perf_counter()
    with pytest.raises(MemoryGuardError, match="32-bit"):
        ws.Refiner(cube, 15, device="cpu")
    with pytest.raises(MemoryGuardError, match=r"would need about .* more than"):
        ws.refine(cube, 6, device="cpu", max_memory=1_000_000)
    assert time.perf_counter() - start < 2.0
    assert ws.refine(cube, 2, device="cpu", max_memory=10**9).num_faces == 96


def test_obj_bad_crease_method_names_file_and_line(tmp_path):
    """An OBJ creasemethod tag that is neither uniform nor chaikin is refused where it is read."""
    from warp_subdiv.io.obj import read_obj

    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nt creasemethod 0/0/1 bspline\n")
    with pytest.raises(SubdivInputError, match=r"bad\.obj:5: creasemethod 'bspline' is not uniform or chaikin"):
        read_obj(str(p))
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nt creasemethod 0/0/1 chaikin\n")
    assert read_obj(str(p)).options == {"crease_method": "chaikin"}


# --------------------------------------------------------------------------------------------------------
# structured fields: what a front end puts in its own terms


@pytest.mark.parametrize("make,fields", [
    (lambda: ws.Mesh(GRID_PTS, GRID_COUNTS, [0, 1, 4, 3, 1, 2, 6, 4]), ("face_vertex_indices", "face", 1)),
    (lambda: ws.Mesh(GRID_PTS, [3, 3, 2, 3], [0, 1, 4, 0, 4, 3, 1, 2, 1, 2, 5]), ("face_vertex_counts", "face", 2)),
    (lambda: ws.Mesh(GRID_PTS, [4, 4], GRID_IDX[:7]), ("face_vertex_counts", None, None)),
    (lambda: ws.Mesh(np.where(np.arange(6)[:, None] == 4, np.nan, GRID_PTS), GRID_COUNTS, GRID_IDX),
     ("points", "vertex", 4)),
    (lambda: grid(creases=[[0, 1], [0, 4]]), ("creases", "crease", 1)),
    (lambda: grid(creases=[[0, 1], [0, 9]]), ("creases", "crease", 1)),
    (lambda: grid(creases=[[0, 1], [1, 2]], crease_sharpness=[1.0, -1.0]), ("crease_sharpness", "crease", 1)),
    (lambda: grid(corners=[0, 7]), ("corners", "corner", 1)),
    (lambda: grid(corners=[0], corner_sharpness=[np.nan]), ("corner_sharpness", "corner", 0)),
    (lambda: grid(concave=[[0, 1], [0, 5]]), ("concave", "concave", 1)),
    (lambda: grid(normals=([0, 4], [[0, 0, 1], [0, 0, 2]])), ("normals", "normal", 1)),
    (lambda: grid(normals=([2, 2], [[0, 0, 1], [0, 0, 1]])), ("normals", "vertex", 2)),
    (lambda: grid(holes=[0, 2]), ("holes", "hole", 1)),
])
def test_mesh_errors_carry_structured_fields(make, fields):
    """Every Mesh error says which argument (option), element and index are at fault, besides its message
    (which names the same element; a prescribed normal's index is its place in the normals, the message names
    its vertex)."""
    with pytest.raises(SubdivInputError) as info:
        make()
    exc = info.value
    assert (exc.option, exc.element, exc.index) == fields, str(exc)
    if exc.index is not None and exc.element != "normal":
        assert re.search(rf"\b{exc.index}\b", str(exc)), str(exc)
