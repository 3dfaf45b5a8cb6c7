"""The JAX adapter (warp_subdiv.jax): custom-VJP functions for evaluate, limit_points and limit_normals, checked
against the numpy VJPs and by finite differences in float64; eager (zero-copy) and jit (callback) paths agree;
importing warp_subdiv imports neither JAX nor PyTorch."""
import subprocess
import sys

import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv.evaluator import kernel_view

from conftest import load_mesh

jax = pytest.importorskip("jax")
jnp = jax.numpy
wsj = pytest.importorskip("warp_subdiv.jax")


def jax_to_warp(x):
    import warp as wp

    return wp.from_jax(x)


@pytest.fixture
def x64():
    """float64 JAX arrays for the duration of a test."""
    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", before)


def _refiner(precision="float64"):
    base = load_mesh("quad_lshape")
    mesh = ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices,
                   normals=([5], [[0.0, 0.6, 0.8]]))
    return ws.Refiner(mesh, 2, precision=precision, device="cpu", flatness=0.5)


def _points(r, seed=0):
    return r.mesh.points + 0.05 * np.random.default_rng(seed).standard_normal((r.base_num_vertices, 3))


def test_gradients_match_numpy_vjps_and_finite_differences(x64):
    """jax.grad through evaluate, limit_points and limit_normals (positions with normal control and flatness)
    equals the numpy VJPs, and central differences in float64; width-2 data refines without normal control."""
    r = _refiner()
    rng = np.random.default_rng(1)
    p = _points(r)
    g = rng.standard_normal((r.num_vertices, 3))

    def loss(q):
        x = wsj.evaluate(r, q)
        return jnp.sum(g * x) + jnp.sum(g * wsj.limit_points(r, x)) + jnp.sum(g * wsj.limit_normals(r, x))

    value, grad = jax.value_and_grad(loss)(jnp.asarray(p))
    x = r.evaluate(p)
    expected = r.evaluate_vjp(g + r.limit_points_vjp(g) + r.limit_normals_vjp(x, g))
    np.testing.assert_allclose(np.asarray(grad), expected, atol=1e-12)
    assert float(value) == pytest.approx(np.sum(g * (x + r.limit_points(x) + r.limit_normals(x))), rel=1e-12)
    d = rng.standard_normal(p.shape)
    h = 1e-7
    fd = (float(loss(jnp.asarray(p + h * d))) - float(loss(jnp.asarray(p - h * d)))) / (2 * h)
    assert np.sum(np.asarray(grad) * d) == pytest.approx(fd, rel=1e-5)

    data = rng.standard_normal((r.base_num_vertices, 2))
    g2 = rng.standard_normal((r.num_vertices, 2))
    grad2 = jax.grad(lambda q: jnp.sum(g2 * wsj.evaluate(r, q)))(jnp.asarray(data))
    np.testing.assert_allclose(np.asarray(grad2), r.evaluate_vjp(g2, normal_control=False), atol=1e-12)


def test_jit_matches_eager(x64):
    """Under jax.jit the functions run through host callbacks and give what the eager path gives, which hands
    the arrays to Warp without a copy and never calls the refiner's host methods."""
    r = _refiner()
    g = np.random.default_rng(2).standard_normal((r.num_vertices, 3))
    calls = []
    for name in ("evaluate", "limit_normals", "evaluate_vjp", "limit_normals_vjp"):
        method = getattr(r, name)
        setattr(r, name, lambda *a, _m=method, _n=name, **k: (calls.append(_n), _m(*a, **k))[1])

    def loss(q):
        x = wsj.evaluate(r, q)
        return jnp.sum(g * wsj.limit_normals(r, x))

    p = jnp.asarray(_points(r))
    eager = jax.value_and_grad(loss)(p)
    assert calls == []
    assert kernel_view(jax_to_warp(p)).ptr == p.unsafe_buffer_pointer()  # DLPack: the same memory
    jitted = jax.jit(jax.value_and_grad(loss))(p)
    assert set(calls) == {"evaluate", "limit_normals", "evaluate_vjp", "limit_normals_vjp"}
    np.testing.assert_allclose(float(jitted[0]), float(eager[0]), rtol=1e-13)
    np.testing.assert_allclose(np.asarray(jitted[1]), np.asarray(eager[1]), atol=1e-13)


def test_limit_points_take_the_normal_control_switch(x64):
    """wsj.limit_points(normal_control=) as Refiner.limit_points: three-column data that is not a position
    (colours) with normal_control=False gets no normal control in the extra step where the masks are read one
    level deeper, eagerly (zero-copy) and under jit (callbacks); values equal the refiner's with the same
    switch, gradients its limit_points_vjp, and the whole chain from the control data matrix("limit").T @ g.
    Each switch value has its own cached function (a function made for one used to serve the other)."""
    r = _refiner()
    assert r.limit_reads_deeper()
    rng = np.random.default_rng(5)
    colours = rng.random((r.base_num_vertices, 3))
    x = r.evaluate(colours, normal_control=False)
    g = rng.standard_normal((r.num_vertices, 3))
    full = {False: r.matrix("limit").T @ g,
            None: (r.matrix("limit", normal_control=True).T @ g.reshape(-1)).reshape(-1, 3)}
    assert wsj.function(r, "limit_points", False) is not wsj.function(r, "limit_points")
    for nc in (None, False):
        def loss(q, nc=nc):
            return jnp.sum(g * wsj.limit_points(r, q, normal_control=nc))

        def chain(c, nc=nc):
            return jnp.sum(g * wsj.limit_points(r, wsj.evaluate(r, c, normal_control=nc), normal_control=nc))

        want = r.limit_points(x, normal_control=nc)
        np.testing.assert_allclose(np.asarray(wsj.limit_points(r, jnp.asarray(x), normal_control=nc)), want,
                                   rtol=0, atol=1e-13)
        for run in (lambda f: f, jax.jit):
            np.testing.assert_allclose(np.asarray(run(jax.grad(loss))(jnp.asarray(x))),
                                       r.limit_points_vjp(g, normal_control=nc), rtol=0, atol=1e-13)
            np.testing.assert_allclose(np.asarray(run(jax.grad(chain))(jnp.asarray(colours))), full[nc],
                                       rtol=0, atol=1e-12)
    assert np.abs(r.limit_points(x, normal_control=False) - r.limit_points(x)).max() > 1e-3
    with pytest.raises(ws.SubdivInputError) as err:
        wsj.limit_points(r, jnp.ones((r.num_vertices, 2)), normal_control=True)
    assert err.value.option == "normal_control"


def test_limit_normals_take_the_normal_control_switch(x64):
    """wsj.limit_normals(normal_control=) as Refiner.limit_normals: positions refined with normal_control=False
    get no prescribed normal (neither substituted nor applied in the extra step where the masks are read one
    level deeper), eagerly (zero-copy) and under jit (callbacks); values equal the refiner's with the same
    switch, gradients its limit_normals_vjp, and the whole chain from the control points evaluate_vjp of that
    (the adapter used to apply prescribed normals whatever the switch). Each switch value has its own cached
    function."""
    r = _refiner()
    assert r.limit_reads_deeper()
    rng = np.random.default_rng(9)
    p = _points(r, seed=4)
    g = rng.standard_normal((r.num_vertices, 3))
    assert wsj.function(r, "limit_normals", False) is not wsj.function(r, "limit_normals")
    for nc in (None, False):
        def loss(q, nc=nc):
            return jnp.sum(g * wsj.limit_normals(r, q, normal_control=nc))

        def chain(c, nc=nc):
            return jnp.sum(g * wsj.limit_normals(r, wsj.evaluate(r, c, normal_control=nc), normal_control=nc))

        x = r.evaluate(p, normal_control=nc)
        vjp = r.limit_normals_vjp(x, g, normal_control=nc)
        for run in (lambda f: f, jax.jit):
            y = run(lambda q, nc=nc: wsj.limit_normals(r, q, normal_control=nc))(jnp.asarray(x))
            np.testing.assert_allclose(np.asarray(y), r.limit_normals(x, normal_control=nc), rtol=0, atol=1e-13)
            np.testing.assert_allclose(np.asarray(run(jax.grad(loss))(jnp.asarray(x))), vjp, rtol=0, atol=1e-13)
            np.testing.assert_allclose(np.asarray(run(jax.grad(chain))(jnp.asarray(p))),
                                       r.evaluate_vjp(vjp, normal_control=nc), rtol=0, atol=1e-12)
    x = r.evaluate(p, normal_control=False)
    assert np.abs(r.limit_normals(x, normal_control=False) - r.limit_normals(x)).max() > 1e-2


def test_float32_default_and_casting():
    """A float32 refiner takes JAX's default float32 arrays (and casts float64 ones); the result is float32 and
    equals refiner.evaluate; 1-D data gives 1-D results."""
    r = _refiner("float32")
    p = _points(r).astype(np.float32)
    out = wsj.evaluate(r, jnp.asarray(p))
    assert out.dtype == jnp.float32 and out.shape == (r.num_vertices, 3)
    np.testing.assert_array_equal(np.asarray(out), r.evaluate(p))
    one = wsj.evaluate(r, jnp.asarray(p[:, 0]))
    assert one.shape == (r.num_vertices,)
    np.testing.assert_array_equal(np.asarray(one), r.evaluate(p[:, 0]))


def test_importing_warp_subdiv_imports_neither_jax_nor_torch():
    """The adapters are optional: `import warp_subdiv` (and its gradients module) loads neither JAX nor torch."""
    code = ("import sys, warp_subdiv, warp_subdiv.gradients; "
            "print(sorted(m for m in ('jax', 'torch') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_inputs_are_checked_eager_and_under_jit():
    """Data with the wrong number of rows, more than two dimensions or complex values, (N, 2) data for limit
    normals and normal control on width 2 are refused with SubdivInputError naming the argument, as
    Refiner.evaluate refuses them, both outside jit (concrete arrays handed to Warp without a copy, which would
    otherwise be read past their end) and under jax.jit (shapes are static: refused while tracing)."""
    r = _refiner("float32")
    n, N = r.base_num_vertices, r.num_vertices
    bad = [(wsj.evaluate, (n - 1, 3), "vertex data"), (wsj.evaluate, (1, 3), "vertex data"),
           (wsj.evaluate, (n + 1, 3), "vertex data"), (wsj.evaluate, (n - 1,), "vertex data"),
           (wsj.evaluate, (n, 3, 1), "vertex data"), (wsj.evaluate, (n, 0), "vertex data"),
           (wsj.limit_points, (10, 3), "refined points"), (wsj.limit_points, (N + 1, 2), "refined points"),
           (wsj.limit_normals, (N - 1, 3), "refined points"), (wsj.limit_normals, (N, 2), "refined points")]
    for f, shape, what in bad:
        x = jnp.ones(shape, jnp.float32)
        for run in (f, jax.jit(f, static_argnums=0)):
            with pytest.raises(ws.SubdivInputError, match=what) as err:
                run(r, x)
            assert err.value.element == "data", (f.__name__, shape)
        with pytest.raises(ws.SubdivInputError, match=what):
            jax.grad(lambda q, f=f: jnp.sum(f(r, q)))(x)
    with pytest.raises(ws.SubdivInputError, match="real numbers"):
        wsj.evaluate(r, jnp.ones((n, 3), jnp.complex64))
    with pytest.raises(ws.SubdivInputError) as err:
        wsj.evaluate(r, jnp.ones((n, 2), jnp.float32), normal_control=True)
    assert err.value.option == "normal_control"
    np.testing.assert_array_equal(np.asarray(wsj.evaluate(r, jnp.ones((n, 3), jnp.int32))),
                                  r.evaluate(np.ones((n, 3), np.int32)))  # integers are cast, as numpy's are


_FLOAT64_WITHOUT_X64 = """
import jax, numpy as np, warp as wp
import warp_subdiv as ws
from warp_subdiv import gradients as G, jax as wsj
from conftest import load_mesh
assert not jax.config.jax_enable_x64
mesh = load_mesh("quad_lshape")
expected = ws.Refiner(mesh, 2, device="cpu").evaluate(mesh.points)
r64 = ws.Refiner(mesh, 2, precision="float64", device="cpu")
for call in (lambda: wsj.evaluate(r64, mesh.points), lambda: jax.jit(wsj.function(r64))(mesh.points),
             lambda: G.adjoint(r64).forward(wp.array(mesh.points, dtype=wp.vec3f), True)):
    try:
        call()
    except ws.SubdivInputError as exc:
        print("refused:", exc)
    else:
        raise SystemExit("not refused")
for precision in ("float32", "float64"):  # the process is not damaged: new refiners evaluate as before
    out = ws.Refiner(mesh, 2, precision=precision, device="cpu").evaluate(mesh.points)
    np.testing.assert_allclose(out, expected, rtol=1e-6, atol=1e-6)
print("ok")
"""


def test_float64_refiner_without_x64_is_refused_and_leaves_no_damage():
    """A float64 refiner cannot take JAX arrays while JAX has no 64-bit floats (jax_enable_x64 off: JAX would
    silently make float32 of them): refused up front, naming the option to set, eagerly and under jit. Arrays
    of another precision never reach a kernel (a generic Warp kernel launched with mixed precisions registers
    an overload that does not compile, and every later load of that kernel module fails, in any refiner), so
    refiners made afterwards, of either precision, evaluate as before. In a fresh process, so that a failure
    cannot damage the other tests."""
    import os
    import pathlib

    tests = pathlib.Path(__file__).parent
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tests.parent), str(tests)]), JAX_ENABLE_X64="0")
    out = subprocess.run([sys.executable, "-c", _FLOAT64_WITHOUT_X64], capture_output=True, text=True,
                         timeout=300, env=env, cwd=tests)
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[-1] == "ok"
    refusals = [line for line in lines if line.startswith("refused:")]
    assert len(refusals) == 3
    assert all("jax_enable_x64" in line for line in refusals[:2]), refusals
    assert "float64" in refusals[2], refusals
