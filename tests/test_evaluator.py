"""The evaluator: typed device records, data of any width in one pass, thread safety, the device result."""
import threading

import numpy as np
import pytest
import warp as wp

import warp_subdiv as ws
from warp_subdiv import evaluator as ev
from warp_subdiv import kernels

from conftest import load_mesh

# (mesh, scheme): quad steps, triangle steps, and a first step of explicit stencils (non-uniform level)
MESHES = [("cube_creased", "catmull-clark"), ("tri_hexfan", "loop"), ("mixed_prism", "catmull-clark"),
          ("mixed_prism", "loop")]


@pytest.mark.parametrize("name,scheme", MESHES + [("quad_lshape", "catmull-clark")])
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_any_width_equals_each_column_refined_alone(name, scheme, precision, device):
    """Data of width 1, 2, 3, 5, 7 is refined in one pass and gives, bitwise, what refining each column
    separately gives; so do its limit values. quad_lshape has flatness tables on every level (they act on
    every column) and limit masks read one level deeper."""
    r = ws.Refiner(load_mesh(name), 3, scheme=scheme, precision=precision, device=device)
    if name == "quad_lshape":
        assert all(t is not None for t in r.flatness_tables) and r.limit_reads_deeper()
    rng = np.random.default_rng(7)
    for width in (1, 2, 3, 5, 7):
        data = rng.standard_normal((r.base_num_vertices, width))
        out = r.evaluate(data, normal_control=False)
        assert out.shape == (r.num_vertices, width) and out.dtype == np.dtype(precision)
        columns = np.stack([r.evaluate(data[:, c]) for c in range(width)], axis=1)
        np.testing.assert_array_equal(out, columns)
        limit = r.limit_points(out)
        assert limit.shape == out.shape
        np.testing.assert_array_equal(limit, np.stack([r.limit_points(out[:, c]) for c in range(width)], axis=1))


def test_width_3_data_is_refined_as_positions():
    """(n, 3) data is refined as positions (with normal control by default), other widths never are:
    normal control is refused for them."""
    base = load_mesh("cube")
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices,
                   normals=([0], [[0.6, 0.48, 0.64]]))
    r = ws.Refiner(mesh, 2, device="cpu", precision="float64")
    with_control = r.evaluate(mesh.points)
    without = r.evaluate(mesh.points, normal_control=False)
    assert np.abs(with_control - without).max() > 1e-6
    np.testing.assert_array_equal(
        without, np.stack([r.evaluate(mesh.points[:, c]) for c in range(3)], axis=1))
    with pytest.raises(ws.SubdivInputError):
        r.evaluate(np.zeros((r.base_num_vertices, 2)), normal_control=True)


def test_one_compiled_overload_serves_every_width():
    """Evaluating data of new widths adds no kernel overload (Warp would compile the module again for each
    new one): every kernel was instantiated up front for both layouts of both precisions."""
    generic = [kernels.quad_face_points, kernels.quad_edge_points, kernels.quad_vertex_points,
               kernels.tri_edge_points, kernels.tri_vertex_points, kernels.explicit_rows, kernels.stencil_rows,
               kernels.displace_rows, kernels.scatter_rows]
    before = {k.key: len(k.overloads) for k in generic}
    assert set(before.values()) == {4}
    for name, scheme in MESHES:
        r = ws.Refiner(load_mesh(name), 2, scheme=scheme, device="cpu")
        for width in (1, 2, 4, 6, 9):
            r.limit_points(r.evaluate(np.ones((r.base_num_vertices, width))))
    assert {k.key: len(k.overloads) for k in generic} == before


@pytest.mark.parametrize("name,scheme,kind", [("cube", "catmull-clark", ev.QuadStep), ("icosahedron", "loop",
                                                                                        ev.TriangleStep),
                                              ("mixed_prism", "catmull-clark", ev.StencilStep)])
def test_upload_makes_typed_records(name, scheme, kind):
    """Each step becomes a typed record (quad, triangle or stencil step) with its displacements, on the
    evaluator's device; the dispatch refuses objects that are not records."""
    r = ws.Refiner(load_mesh(name), 2, scheme=scheme, device="cpu", rules="piecewise-smooth")
    records = r.evaluator.records()
    assert len(records) == 2 and isinstance(records[0].rows, kind)
    assert records is r.evaluator.records()  # uploaded once
    for rec in records:
        assert rec.num_rows in (r.hierarchy.num_vertices, *(t.num_rows for t in r.hierarchy.steps))
        assert rec.flatness is None or isinstance(rec.flatness, ev.Displacement)
        assert rec.normals is None
    masks = r.evaluator.limit_masks()
    assert isinstance(masks, ev.LimitMasks) and masks.num_vertices == r.num_vertices
    with pytest.raises(TypeError):
        ev.apply({"regular": None}, None, None, "cpu")


def test_level_buffers_are_allocated_once_and_grown_for_wider_data():
    """Repeated calls reuse the level buffers; wider data reallocates them once, narrower data takes views."""
    r = ws.Refiner(load_mesh("cube"), 2, device="cpu")
    r.evaluate(np.ones((r.base_num_vertices, 2)))
    first = [a.ptr for a in r.evaluator._buffers.flat]
    r.evaluate(np.ones((r.base_num_vertices, 2)))
    r.evaluate(np.ones((r.base_num_vertices, 1)))
    assert [a.ptr for a in r.evaluator._buffers.flat] == first
    r.evaluate(np.ones((r.base_num_vertices, 5)))
    grown = [a.ptr for a in r.evaluator._buffers.flat]
    r.evaluate(np.ones((r.base_num_vertices, 3)))
    assert [a.ptr for a in r.evaluator._buffers.flat] == grown


@pytest.mark.parametrize("precision,vec", [("float32", wp.vec3f), ("float64", wp.vec3d)])
def test_evaluate_device_returns_the_last_level_as_vec3(precision, vec, device):
    """evaluate_device gives the last level's device array of vec3 of the precision, equal to evaluate's
    result, also after data of other widths went through the same buffers."""
    mesh = load_mesh("cube_creased")
    r = ws.Refiner(mesh, 2, precision=precision, device=device)
    r.evaluate(np.ones((r.base_num_vertices, 7)))
    out = r.evaluate_device(mesh.points)
    assert out.dtype == vec and out.shape == (r.num_vertices,) and out.device == wp.get_device(device)
    np.testing.assert_array_equal(out.numpy(), r.evaluate(mesh.points))
    with pytest.raises(ws.SubdivInputError):
        r.evaluate_device(np.ones((r.base_num_vertices, 2)))


def test_one_refiner_serves_several_threads():
    """Two threads evaluating different data (positions and 5-wide data) through one Refiner 50 times each
    get their own correct results every time: the shared level buffers are used under the evaluator's lock."""
    mesh = load_mesh("cube_creased")
    r = ws.Refiner(mesh, 4, device="cpu", precision="float64")
    rng = np.random.default_rng(3)
    inputs = [mesh.points + 0.1 * rng.standard_normal(mesh.points.shape),
              rng.standard_normal((r.base_num_vertices, 5))]
    expected = [r.evaluate(x) for x in inputs]
    failures = []
    start = threading.Barrier(2)

    def work(k):
        start.wait()
        for i in range(50):
            out = r.evaluate(inputs[k])
            if not np.array_equal(out, expected[k]):
                failures.append((k, i))

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not failures


@pytest.mark.parametrize("name,scheme", [("cube_creased", "catmull-clark"), ("tri_hexfan", "loop")])
@pytest.mark.parametrize("precision,scales", [("float32", [1e11, 1e-11, 1e17, 1e-30]),
                                              ("float64", [1e80, 1e-80, 1e149, 1e-150, 1e-280])])
def test_limit_normals_do_not_depend_on_the_scale(name, scheme, precision, scales, device):
    """Unit limit normals of points scaled far from 1 (within the data bound a refiner accepts): the cross
    product of the limit tangents over- or underflows there (its squared length is of the scale to the fourth),
    which made every normal (0, 0, 0); the normals are those of the unscaled points."""
    mesh = load_mesh(name)
    r = ws.Refiner(mesh, 2, scheme=scheme, precision=precision, device=device)
    want = r.limit_normals(r.evaluate(mesh.points))
    tol = 1e-5 if precision == "float32" else 1e-12
    for s in scales:
        got = r.limit_normals(r.evaluate(mesh.points * s))
        np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, rtol=0, atol=tol, err_msg=f"scale {s:g}")
        np.testing.assert_allclose(got, want, rtol=0, atol=tol, err_msg=f"scale {s:g}")
