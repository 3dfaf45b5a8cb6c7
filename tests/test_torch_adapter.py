"""The PyTorch adapter (warp_subdiv.torch): autograd functions for evaluate, limit_points and limit_normals,
checked against the numpy VJPs, by torch.autograd.gradcheck (finite differences in float64) and for zero-copy
inputs. Skipped where torch is not importable (it is an optional extra; CI does not install it)."""
import numpy as np
import pytest

import warp_subdiv as ws

from conftest import load_mesh

torch = pytest.importorskip("torch")
wst = pytest.importorskip("warp_subdiv.torch")


def _refiner(precision="float64", levels=2):
    base = load_mesh("tri_hexfan")
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices,
                   normals=([0], [[0.0, 0.6, 0.8]]))
    return ws.Refiner(mesh, levels, scheme="loop", precision=precision, device="cpu")


def _points(r, seed=0):
    return r.mesh.points + 0.05 * np.random.default_rng(seed).standard_normal((r.base_num_vertices, 3))


def test_gradients_match_numpy_vjps():
    """backward() through evaluate, limit_points and limit_normals equals the numpy VJPs; forward values equal
    the refiner's; width-2 and 1-D data work too."""
    r = _refiner()
    rng = np.random.default_rng(1)
    p = torch.tensor(_points(r), requires_grad=True)
    g = rng.standard_normal((r.num_vertices, 3))
    gt = torch.tensor(g)
    x = wst.evaluate(r, p)
    loss = (gt * x).sum() + (gt * wst.limit_points(r, x)).sum() + (gt * wst.limit_normals(r, x)).sum()
    loss.backward()
    xn = r.evaluate(p.detach().numpy())
    np.testing.assert_array_equal(x.detach().numpy(), xn)
    expected = r.evaluate_vjp(g + r.limit_points_vjp(g) + r.limit_normals_vjp(xn, g))
    np.testing.assert_allclose(p.grad.numpy(), expected, atol=1e-12)

    data = torch.tensor(rng.standard_normal((r.base_num_vertices, 2)), requires_grad=True)
    g2 = rng.standard_normal((r.num_vertices, 2))
    (torch.tensor(g2) * wst.evaluate(r, data)).sum().backward()
    np.testing.assert_allclose(data.grad.numpy(), r.evaluate_vjp(g2, normal_control=False), atol=1e-12)
    one = torch.tensor(rng.standard_normal(r.base_num_vertices), requires_grad=True)
    assert wst.evaluate(r, one).shape == (r.num_vertices,)


def test_limit_points_take_the_normal_control_switch():
    """wst.limit_points(normal_control=) as Refiner.limit_points: three-column data that is not a position
    (colours) with normal_control=False gets no normal control in the extra step where the masks are read one
    level deeper; values equal the refiner's with the same switch, gradients its limit_points_vjp, and the whole
    chain from the control data matrix("limit").T @ g (the adapter used to treat every width-3 tensor as
    positions)."""
    r = _refiner()
    assert r.limit_reads_deeper()
    rng = np.random.default_rng(5)
    colours = rng.random((r.base_num_vertices, 3))
    x = r.evaluate(colours, normal_control=False)
    g = rng.standard_normal((r.num_vertices, 3))
    full = {False: r.matrix("limit").T @ g,
            None: (r.matrix("limit", normal_control=True).T @ g.reshape(-1)).reshape(-1, 3)}
    for nc in (None, False):
        xt = torch.tensor(x, requires_grad=True)
        y = wst.limit_points(r, xt, normal_control=nc)
        np.testing.assert_allclose(y.detach().numpy(), r.limit_points(x, normal_control=nc), rtol=0, atol=1e-13)
        (torch.tensor(g) * y).sum().backward()
        np.testing.assert_allclose(xt.grad.numpy(), r.limit_points_vjp(g, normal_control=nc), rtol=0, atol=1e-13)
        c = torch.tensor(colours, requires_grad=True)
        y = wst.limit_points(r, wst.evaluate(r, c, normal_control=nc), normal_control=nc)
        (torch.tensor(g) * y).sum().backward()
        np.testing.assert_allclose(c.grad.numpy(), full[nc], rtol=0, atol=1e-12)
    assert np.abs(r.limit_points(x, normal_control=False) - r.limit_points(x)).max() > 1e-3
    with pytest.raises(ws.SubdivInputError) as err:
        wst.limit_points(r, torch.ones((r.num_vertices, 2)), normal_control=True)
    assert err.value.option == "normal_control"


def test_limit_normals_take_the_normal_control_switch():
    """wst.limit_normals(normal_control=) as Refiner.limit_normals: positions refined with normal_control=False
    get no prescribed normal (neither substituted nor applied in the extra step where the masks are read one
    level deeper); values equal the refiner's with the same switch, gradients its limit_normals_vjp, and the
    whole chain from the control points evaluate_vjp of that (the adapter used to apply prescribed normals
    whatever the switch)."""
    r = _refiner()
    assert r.limit_reads_deeper()
    rng = np.random.default_rng(9)
    p = _points(r, seed=4)
    g = rng.standard_normal((r.num_vertices, 3))
    for nc in (None, False):
        x = r.evaluate(p, normal_control=nc)
        vjp = r.limit_normals_vjp(x, g, normal_control=nc)
        xt = torch.tensor(x, requires_grad=True)
        y = wst.limit_normals(r, xt, normal_control=nc)
        np.testing.assert_allclose(y.detach().numpy(), r.limit_normals(x, normal_control=nc), rtol=0, atol=1e-13)
        (torch.tensor(g) * y).sum().backward()
        np.testing.assert_allclose(xt.grad.numpy(), vjp, rtol=0, atol=1e-13)
        c = torch.tensor(p, requires_grad=True)
        y = wst.limit_normals(r, wst.evaluate(r, c, normal_control=nc), normal_control=nc)
        (torch.tensor(g) * y).sum().backward()
        np.testing.assert_allclose(c.grad.numpy(), r.evaluate_vjp(vjp, normal_control=nc), rtol=0, atol=1e-12)
    x = r.evaluate(p, normal_control=False)
    assert np.abs(r.limit_normals(x, normal_control=False) - r.limit_normals(x)).max() > 1e-2


def test_gradcheck_float64():
    """torch.autograd.gradcheck (central differences in float64) of the three functions on a level-1 mesh."""
    r = _refiner(levels=1)
    p = torch.tensor(_points(r), requires_grad=True)
    assert torch.autograd.gradcheck(lambda q: wst.evaluate(r, q), (p,), eps=1e-6, atol=1e-6)
    x = torch.tensor(r.evaluate(_points(r)), requires_grad=True)
    assert torch.autograd.gradcheck(lambda q: wst.limit_points(r, q), (x,), eps=1e-6, atol=1e-6)
    assert torch.autograd.gradcheck(lambda q: wst.limit_normals(r, q), (x,), eps=1e-7, atol=1e-5)


def test_float32_zero_copy_input():
    """A float32 refiner takes float32 tensors without a copy (the Warp view shares the tensor's memory) and
    casts float64 ones; results are float32 and equal refiner.evaluate."""
    import warp as wp

    r = _refiner("float32")
    p = torch.tensor(_points(r), dtype=torch.float32)
    assert wp.from_torch(p).ptr == p.data_ptr()
    out = wst.evaluate(r, p)
    assert out.dtype == torch.float32
    np.testing.assert_array_equal(out.numpy(), r.evaluate(p.numpy()))
    np.testing.assert_array_equal(wst.evaluate(r, p.double()).numpy(), out.numpy())


def test_inputs_are_checked():
    """Tensors with the wrong number of rows, more than two dimensions or complex values, (N, 2) data for limit
    normals and normal control on width 2 are refused with SubdivInputError naming the argument, as
    Refiner.evaluate refuses them (a tensor is otherwise handed to Warp without a copy and read past its end);
    integer tensors are cast, as numpy's integers are."""
    r = _refiner("float32")
    n, N = r.base_num_vertices, r.num_vertices
    bad = [(wst.evaluate, (n - 1, 3), "vertex data"), (wst.evaluate, (1, 3), "vertex data"),
           (wst.evaluate, (n + 1, 3), "vertex data"), (wst.evaluate, (n - 1,), "vertex data"),
           (wst.evaluate, (n, 3, 1), "vertex data"), (wst.evaluate, (n, 0), "vertex data"),
           (wst.limit_points, (10, 3), "refined points"), (wst.limit_points, (N + 1, 2), "refined points"),
           (wst.limit_normals, (N - 1, 3), "refined points"), (wst.limit_normals, (N, 2), "refined points")]
    for f, shape, what in bad:
        with pytest.raises(ws.SubdivInputError, match=what) as err:
            f(r, torch.ones(shape, requires_grad=True))
        assert err.value.element == "data", (f.__name__, shape)
    with pytest.raises(ws.SubdivInputError, match="real numbers"):
        wst.evaluate(r, torch.ones((n, 3), dtype=torch.complex64))
    with pytest.raises(ws.SubdivInputError) as err:
        wst.evaluate(r, torch.ones((n, 2)), normal_control=True)
    assert err.value.option == "normal_control"
    np.testing.assert_array_equal(wst.evaluate(r, torch.ones((n, 3), dtype=torch.int32)).numpy(),
                                  r.evaluate(np.ones((n, 3), np.int32)))
