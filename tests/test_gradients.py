"""Gradients of refinement (warp_subdiv.gradients): the sparse operator ``Refiner.matrix``, vector-Jacobian
products of ``evaluate``, ``limit_points`` and ``limit_normals`` checked by finite differences in float64, the
``wp.Tape`` path, and deterministic backward passes (bitwise equal run to run and for any thread count)."""
import numpy as np
import pytest
import warp as wp

import warp_subdiv as ws
from warp_subdiv import gradients as G
from warp_subdiv.gradients import transposed
from warp_subdiv.gradients.records import RegularRecord
from warp_subdiv.tables import rows_of
from warp_subdiv.runtime import threads as th

from conftest import load_mesh


def _with(name, **tags):
    base = load_mesh(name)
    keep = dict(creases=base.creases if len(base.creases) else None,
                corners=base.corners if len(base.corners) else None)
    keep.update(tags)
    return ws.Mesh(base.points, base.face_vertex_counts, base.face_vertex_indices, **keep)


def _semi_sharp_cube():
    return _with("cube", creases=[[0, 1], [1, 2], [2, 3]], crease_sharpness=[1.5, 2.0, 0.7], corners=[5],
                 corner_sharpness=[2.3])


# (id, mesh factory, options): both schemes, both rule sets, boundaries, creases, corners, semi-sharp tags,
# flatness, prescribed normals (interior and boundary sector vertices), stencil (non-uniform) steps
CASES = [
    ("cc-creased-corners", lambda: _with("cube_creased"), dict(scheme="catmull-clark")),
    ("cc-boundary-flatness-normals", lambda: _with("quad_lshape", normals=([5, 10], [[0.0, 0.6, 0.8],
                                                                                     [0.28, 0.0, 0.96]])),
     dict(scheme="catmull-clark", flatness=0.6, normal_strength=0.5)),
    ("cc-boundary-opensubdiv", lambda: _with("quad_lshape"), dict(scheme="catmull-clark", rules="opensubdiv")),
    ("cc-semi-sharp", _semi_sharp_cube, dict(scheme="catmull-clark", rules="opensubdiv")),
    ("cc-semi-sharp-ps-normal", lambda: _with("cube", creases=[[0, 1], [1, 2]], crease_sharpness=[1.5, 0.7],
                                              normals=([6], [[0.6, 0.48, 0.64]])), dict(scheme="catmull-clark")),
    ("cc-polygons", lambda: _with("mixed_prism"), dict(scheme="catmull-clark")),
    ("loop-boundary-normal", lambda: _with("tri_hexfan", normals=([0], [[0.0, 0.6, 0.8]])), dict(scheme="loop")),
    ("loop-polygons-opensubdiv", lambda: _with("mixed_prism"), dict(scheme="loop", rules="opensubdiv")),
    ("loop-semi-sharp-flatness", lambda: _with("icosahedron", creases=[[11, 0], [0, 5], [5, 1]],
                                               crease_sharpness=[10.0, 10.0, 1.5], corners=[0]),
     dict(scheme="loop", flatness=0.4)),
]


_REFINERS: dict = {}


def refiner(case_id, levels=2, threads=1):
    """A float64 CPU refiner of a case (cached per test session)."""
    key = (case_id, levels, threads)
    if key not in _REFINERS:
        _, make, opts = next(c for c in CASES if c[0] == case_id)
        mesh = make()
        _REFINERS[key] = ws.Refiner(mesh, levels, precision="float64", device="cpu", threads=threads, **opts)
    return _REFINERS[key]


def _points(r, seed=0):
    rng = np.random.default_rng(seed)
    return np.asarray(r.mesh.points, np.float64) + 0.05 * rng.standard_normal((r.base_num_vertices, 3))


def _fd(f, x, g, d, h=1e-6):
    """Central difference of <g, f(x)> along d."""
    return (np.sum(g * f(x + h * d)) - np.sum(g * f(x - h * d))) / (2 * h)


IDS = [c[0] for c in CASES]


@pytest.mark.parametrize("case", IDS)
def test_evaluate_gradient_matches_finite_differences(case):
    """evaluate_vjp is the derivative of evaluate, by central differences in float64: positions with normal
    control (an affine map; normal control couples the coordinates), and data of width 2 without it."""
    r = refiner(case)
    rng = np.random.default_rng(1)
    p = _points(r)
    for width, nc in ((3, True), (2, False)):
        x = p if width == 3 else rng.standard_normal((r.base_num_vertices, width))
        g = rng.standard_normal((r.num_vertices, width))
        d = rng.standard_normal(x.shape)
        vjp = r.evaluate_vjp(g, normal_control=nc)
        assert vjp.shape == x.shape and vjp.dtype == np.float64
        fd = _fd(lambda y: r.evaluate(y, normal_control=nc), x, g, d)
        assert np.sum(vjp * d) == pytest.approx(fd, rel=1e-7, abs=1e-7)


@pytest.mark.parametrize("case", IDS)
def test_limit_gradients_match_finite_differences(case):
    """limit_points_vjp and limit_normals_vjp (the true derivative of the unit normals) by central differences
    in float64, on the refined points of a random control cage, composed with evaluate_vjp as well."""
    r = refiner(case)
    rng = np.random.default_rng(2)
    p = _points(r)
    x = r.evaluate(p)
    g = rng.standard_normal(x.shape)
    d = rng.standard_normal(x.shape)
    assert np.sum(r.limit_points_vjp(g) * d) == pytest.approx(_fd(r.limit_points, x, g, d), rel=1e-7, abs=1e-7)
    assert np.sum(r.limit_normals_vjp(x, g) * d) == pytest.approx(_fd(r.limit_normals, x, g, d, h=1e-7),
                                                                  rel=1e-5, abs=1e-6)
    # control points -> limit normals
    dp = rng.standard_normal(p.shape)
    chain = r.evaluate_vjp(r.limit_normals_vjp(x, g))
    fd = _fd(lambda q: r.limit_normals(r.evaluate(q)), p, g, dp, h=1e-7)
    assert np.sum(chain * dp) == pytest.approx(fd, rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("case", IDS)
def test_matrix_is_the_refinement_map(case):
    """matrix(level) @ data equals evaluate's data on every level (a refiner of that many levels) and at the
    limit; with normal control, the (3N, 3n) map of positions; the affine offset is zero; matrix().T @ g is
    evaluate_vjp(g)."""
    r = refiner(case)
    rng = np.random.default_rng(3)
    p = _points(r)
    data = rng.standard_normal((r.base_num_vertices, 2))
    for level in range(r.levels + 1):
        m = r.matrix(level)
        sub = r if level == r.levels else ws.Refiner(r.mesh, level, options=r.options, device="cpu")
        np.testing.assert_allclose(m @ data, sub.evaluate(data, normal_control=False), atol=1e-12)
        m3, offset = r.matrix(level, normal_control=True, with_offset=True)
        assert m3.shape == (3 * sub.num_vertices, 3 * r.base_num_vertices) and not np.any(offset)
        np.testing.assert_allclose((m3 @ p.reshape(-1)).reshape(-1, 3) + offset.reshape(-1, 3), sub.evaluate(p),
                                   atol=1e-12)
    limit = r.matrix("limit", normal_control=True)
    np.testing.assert_allclose((limit @ p.reshape(-1)).reshape(-1, 3), r.limit_points(r.evaluate(p)), atol=1e-12)
    g = rng.standard_normal((r.num_vertices, 2))
    np.testing.assert_allclose(r.matrix().T @ g, r.evaluate_vjp(g, normal_control=False), atol=1e-12)


def test_matrix_without_scipy(monkeypatch):
    """Without scipy, matrix() returns the same CSR arrays as a CSRMatrix (@, .T, toarray)."""
    import builtins

    r = refiner("cc-boundary-flatness-normals")
    real_import = builtins.__import__

    def no_scipy(name, *args, **kwargs):
        if name.startswith("scipy"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_scipy)
    m = r.matrix(normal_control=True)
    assert isinstance(m, G.CSRMatrix) and m.shape == (3 * r.num_vertices, 3 * r.base_num_vertices)
    p = _points(r)
    np.testing.assert_allclose((m @ p.reshape(-1)).reshape(-1, 3), r.evaluate(p), atol=1e-12)
    g = np.random.default_rng(4).standard_normal(3 * r.num_vertices)
    np.testing.assert_allclose(m.T @ g, r.evaluate_vjp(g.reshape(-1, 3)).reshape(-1), atol=1e-12)
    np.testing.assert_allclose(m.toarray() @ p.reshape(-1), m @ p.reshape(-1), atol=1e-12)


def test_matrix_level_is_checked():
    """A level outside 0..levels (or of another type) is refused, naming the option."""
    r = refiner("cc-creased-corners")
    for bad in (-1, 3, 1.5, "deep", True):
        with pytest.raises(ws.SubdivInputError) as err:
            r.matrix(bad)
        assert err.value.option == "level"


@wp.kernel
def _dot_loss(x: wp.array(dtype=wp.vec3d), g: wp.array(dtype=wp.vec3d), loss: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(loss, 0, wp.dot(x[i], g[i]))


@wp.kernel
def _dot_loss_2d(x: wp.array2d(dtype=wp.float64), g: wp.array2d(dtype=wp.float64),
                 loss: wp.array(dtype=wp.float64)):
    i, j = wp.tid()
    wp.atomic_add(loss, 0, x[i, j] * g[i, j])


@pytest.mark.parametrize("case", ["cc-boundary-flatness-normals", "loop-boundary-normal", "cc-polygons"])
def test_tape_gradient_equals_matrix_transpose(case):
    """Under wp.Tape, evaluate_device(requires_grad=True) followed by limit_points gives points.grad equal to
    matrix('limit').T @ g (positions, normal control), and evaluate of width-2 data gives matrix().T @ g; the
    forward values equal evaluate's; tape.zero() clears the gradients."""
    r = refiner(case)
    rng = np.random.default_rng(5)
    p = _points(r)
    pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
    g = rng.standard_normal((r.num_vertices, 3))
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    tape = wp.Tape()
    with tape:
        out = r.evaluate_device(pts, requires_grad=True)
        lim = G.limit_points(r, out)
        wp.launch(_dot_loss, dim=r.num_vertices, inputs=[lim, wp.array(g, dtype=wp.vec3d), loss])
    tape.backward(loss)
    np.testing.assert_array_equal(out.numpy(), r.evaluate(p))
    expected = (r.matrix("limit", normal_control=True).T @ g.reshape(-1)).reshape(-1, 3)
    np.testing.assert_allclose(pts.grad.numpy(), expected, atol=1e-12)
    tape.zero()
    assert not np.any(pts.grad.numpy())

    data = wp.array(rng.standard_normal((r.base_num_vertices, 2)), dtype=wp.float64, requires_grad=True)
    g2 = rng.standard_normal((r.num_vertices, 2))
    loss2 = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    with wp.Tape() as tape2:
        out2 = r.evaluate_device(data, requires_grad=True)
        wp.launch(_dot_loss_2d, dim=(r.num_vertices, 2), inputs=[out2, wp.array(g2, dtype=wp.float64), loss2])
    tape2.backward(loss2)
    assert out2.shape == (r.num_vertices, 2)
    np.testing.assert_allclose(data.grad.numpy(), r.matrix().T @ g2, atol=1e-12)


def test_tape_limit_normals_and_accumulation():
    """limit_normals on the tape gives evaluate_vjp(limit_normals_vjp(...)) at the control points; a second
    use of the same control points adds its gradient (Warp's accumulation convention)."""
    r = refiner("cc-boundary-flatness-normals")
    rng = np.random.default_rng(6)
    p = _points(r)
    g = rng.standard_normal((r.num_vertices, 3))
    pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    gw = wp.array(g, dtype=wp.vec3d)
    with wp.Tape() as tape:
        for _ in range(2):
            normals = G.limit_normals(r, G.evaluate(r, pts))
            wp.launch(_dot_loss, dim=r.num_vertices, inputs=[normals, gw, loss])
    tape.backward(loss)
    x = r.evaluate(p)
    np.testing.assert_allclose(normals.numpy(), r.limit_normals(x), atol=1e-14)
    np.testing.assert_allclose(pts.grad.numpy(), 2 * r.evaluate_vjp(r.limit_normals_vjp(x, g)), atol=1e-12)


@pytest.mark.parametrize("case", ["cc-boundary-flatness-normals", "loop-boundary-normal"])
def test_active_tape_records_without_the_requires_grad_flag(case):
    """Warp's convention: work on an array that requires grad, under an active wp.Tape, is recorded.
    evaluate_device, limit_points and limit_normals (on_device) and evaluate_with_limits (on_device) of such an
    array record their backward without requires_grad=True (their gradients used to be zeros, the loss right);
    the values equal the unrecorded calls'; requires_grad=False still turns recording off."""
    r = refiner(case)
    rng = np.random.default_rng(11)
    p = _points(r)
    g = rng.standard_normal((r.num_vertices, 3))
    gw = wp.array(g, dtype=wp.vec3d)
    x = r.evaluate(p)
    pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    with wp.Tape() as tape:
        out = r.evaluate_device(pts)
        lim = r.limit_points(out, on_device=True)
        wp.launch(_dot_loss, dim=r.num_vertices, inputs=[lim, gw, loss])
    tape.backward(loss)
    np.testing.assert_array_equal(out.numpy(), x)
    np.testing.assert_array_equal(lim.numpy(), r.limit_points(x))
    expected = (r.matrix("limit", normal_control=True).T @ g.reshape(-1)).reshape(-1, 3)
    np.testing.assert_allclose(pts.grad.numpy(), expected, atol=1e-12)

    refined = wp.array(x, dtype=wp.vec3d, requires_grad=True)
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    with wp.Tape() as tape:
        normals = r.limit_normals(refined, on_device=True)
        wp.launch(_dot_loss, dim=r.num_vertices, inputs=[normals, gw, loss])
    tape.backward(loss)
    np.testing.assert_array_equal(normals.numpy(), r.limit_normals(x))
    np.testing.assert_allclose(refined.grad.numpy(), r.limit_normals_vjp(x, g), atol=1e-12)

    pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    with wp.Tape() as tape:
        res = r.evaluate_with_limits(pts, on_device=True)
        for a in (res.points, res.limit_points, res.limit_normals):
            wp.launch(_dot_loss, dim=r.num_vertices, inputs=[a, gw, loss])
    tape.backward(loss)
    plain = r.evaluate_with_limits(p)
    for a, b in ((res.points, plain.points), (res.limit_points, plain.limit_points),
                 (res.limit_normals, plain.limit_normals)):
        np.testing.assert_array_equal(a.numpy(), b)
    expected = r.evaluate_vjp(g + r.limit_points_vjp(g) + r.limit_normals_vjp(x, g))
    np.testing.assert_allclose(pts.grad.numpy(), expected, atol=1e-12)

    with wp.Tape() as tape:
        off = r.evaluate_device(pts, requires_grad=False)
    assert not off.requires_grad and not any(callable(launch) for launch in tape.launches)  # no backward
    np.testing.assert_array_equal(off.numpy(), x)


def _limit_transpose(r, g, normal_control):
    """matrix("limit").T @ g of (N, 3) gradients, as (n, 3), with normal control unless ``normal_control`` is
    False (None: on for width 3)."""
    if normal_control is not False:
        return (r.matrix("limit", normal_control=True).T @ g.reshape(-1)).reshape(-1, 3)
    return r.matrix("limit").T @ g


@pytest.mark.parametrize("case", ["cc-boundary-flatness-normals", "loop-boundary-normal"])
def test_limit_points_gradients_take_the_normal_control_switch(case):
    """limit_points_vjp, gradients.limit_points (the wp.Tape path, also through Refiner.limit_points(on_device))
    and gradients.evaluate_with_limits take normal_control as Refiner.limit_points does: three-column data that
    is not a position (colours) with normal_control=False gets none in the extra step where the masks are read
    one level deeper, positions (None, True) do. Forward values equal Refiner.limit_points' with the same
    switch; the gradients are the derivative (central differences) and, composed with evaluate_vjp,
    matrix("limit").T @ g of that switch (the gradient paths used to treat every width-3 array as positions)."""
    r = refiner(case)
    assert r.limit_reads_deeper()
    rng = np.random.default_rng(13)
    colours = rng.random((r.base_num_vertices, 3))
    x = r.evaluate(colours, normal_control=False)
    g = rng.standard_normal((r.num_vertices, 3))
    d = rng.standard_normal(x.shape)
    gw = wp.array(g, dtype=wp.vec3d)
    vjps = {}
    for nc in (False, None, True):
        vjp = vjps[nc] = r.limit_points_vjp(g, normal_control=nc)
        fd = _fd(lambda y: r.limit_points(y, normal_control=nc), x, g, d)
        assert np.sum(vjp * d) == pytest.approx(fd, rel=1e-7, abs=1e-7)
        np.testing.assert_allclose(r.evaluate_vjp(vjp, normal_control=nc), _limit_transpose(r, g, nc),
                                   rtol=0, atol=1e-12)

        refined = wp.array(x, dtype=wp.vec3d, requires_grad=True)
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        with wp.Tape() as tape:
            lim = G.limit_points(r, refined, normal_control=nc)
            wp.launch(_dot_loss, dim=r.num_vertices, inputs=[lim, gw, loss])
        tape.backward(loss)
        np.testing.assert_allclose(lim.numpy(), r.limit_points(x, normal_control=nc), rtol=0, atol=1e-13)
        np.testing.assert_array_equal(refined.grad.numpy(), vjp)

        pts = wp.array(colours, dtype=wp.vec3d, requires_grad=True)  # control data -> limit, on the tape
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        with wp.Tape() as tape:
            out = r.evaluate_device(pts, normal_control=nc is not False)
            lim = r.limit_points(out, normal_control=nc, on_device=True)
            wp.launch(_dot_loss, dim=r.num_vertices, inputs=[lim, gw, loss])
        tape.backward(loss)
        plain = r.limit_points(r.evaluate(colours, normal_control=nc), normal_control=nc)
        np.testing.assert_allclose(lim.numpy(), plain, rtol=0, atol=1e-13)
        np.testing.assert_allclose(pts.grad.numpy(), _limit_transpose(r, g, nc), rtol=0, atol=1e-12)

        pts = wp.array(colours, dtype=wp.vec3d, requires_grad=True)
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        with wp.Tape() as tape:
            res = G.evaluate_with_limits(r, pts, nc, with_limit_normals=False)
            wp.launch(_dot_loss, dim=r.num_vertices, inputs=[res.limit_points, gw, loss])
        tape.backward(loss)
        one_pass = r.evaluate_with_limits(colours, normal_control=nc, limit_normals=False)
        np.testing.assert_allclose(res.limit_points.numpy(), one_pass.limit_points, rtol=0, atol=1e-13)
        np.testing.assert_allclose(pts.grad.numpy(), _limit_transpose(r, g, nc), rtol=0, atol=1e-12)
    assert np.abs(vjps[False] - vjps[None]).max() > 1e-4  # the switch matters on this mesh
    np.testing.assert_array_equal(vjps[None], vjps[True])
    for call in (lambda: r.limit_points_vjp(g[:, :2], normal_control=True),
                 lambda: G.limit_points(r, wp.array(x[:, :2], dtype=wp.float64), normal_control=True)):
        with pytest.raises(ws.SubdivInputError) as err:
            call()
        assert err.value.option == "normal_control"


@pytest.mark.parametrize("case", ["cc-boundary-flatness-normals", "loop-boundary-normal"])
def test_limit_normals_gradients_take_the_normal_control_switch(case):
    """limit_normals_vjp, gradients.limit_normals (the wp.Tape path, also through Refiner.limit_normals(on_device))
    and the recorded Refiner.evaluate_with_limits(on_device) take normal_control as Refiner.limit_normals does:
    positions refined with normal_control=False get no prescribed normal, neither substituted nor applied in the
    extra step where the masks are read one level deeper; None and True get both. Forward values equal the
    numpy path's with the same switch; the gradients are the derivative (central differences, from the refined
    points and from the control points) and the tape's equal the VJPs (the gradient paths used to apply
    prescribed normals whatever the switch: limit normals off by up to 0.81 on the first mesh)."""
    r = refiner(case)
    assert r.limit_reads_deeper()
    rng = np.random.default_rng(17)
    p = _points(r, seed=3)
    g = rng.standard_normal((r.num_vertices, 3))
    d = rng.standard_normal((r.num_vertices, 3))
    dp = rng.standard_normal(p.shape)
    gw = wp.array(g, dtype=wp.vec3d)
    normals, vjps = {}, {}
    for nc in (False, None, True):
        x = r.evaluate(p, normal_control=nc)
        want = normals[nc] = r.limit_normals(x, normal_control=nc)
        vjp = vjps[nc] = r.limit_normals_vjp(x, g, normal_control=nc)
        fd = _fd(lambda y: r.limit_normals(y, normal_control=nc), x, g, d, h=1e-7)
        assert np.sum(vjp * d) == pytest.approx(fd, rel=1e-5, abs=1e-6)
        chain = r.evaluate_vjp(vjp, normal_control=nc)
        fd = _fd(lambda q: r.limit_normals(r.evaluate(q, normal_control=nc), normal_control=nc), p, g, dp,
                 h=1e-7)
        assert np.sum(chain * dp) == pytest.approx(fd, rel=1e-5, abs=1e-6)

        for through_refiner in (False, True):
            refined = wp.array(x, dtype=wp.vec3d, requires_grad=True)
            loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
            with wp.Tape() as tape:
                if through_refiner:
                    lim = r.limit_normals(refined, normal_control=nc, on_device=True)
                else:
                    lim = G.limit_normals(r, refined, normal_control=nc)
                wp.launch(_dot_loss, dim=r.num_vertices, inputs=[lim, gw, loss])
            tape.backward(loss)
            np.testing.assert_allclose(lim.numpy(), want, rtol=0, atol=1e-13)
            np.testing.assert_array_equal(refined.grad.numpy(), vjp)

        pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        with wp.Tape() as tape:
            res = r.evaluate_with_limits(pts, normal_control=nc, on_device=True)
            wp.launch(_dot_loss, dim=r.num_vertices, inputs=[res.limit_normals, gw, loss])
        tape.backward(loss)
        one_pass = r.evaluate_with_limits(p, normal_control=nc)
        np.testing.assert_allclose(res.limit_normals.numpy(), one_pass.limit_normals, rtol=0, atol=1e-13)
        np.testing.assert_allclose(res.limit_points.numpy(), one_pass.limit_points, rtol=0, atol=1e-13)
        np.testing.assert_allclose(pts.grad.numpy(), chain, rtol=0, atol=1e-12)
    assert np.abs(normals[False] - normals[None]).max() > 1e-2  # the switch matters on this mesh
    assert np.abs(vjps[False] - vjps[None]).max() > 1e-4
    np.testing.assert_array_equal(normals[None], normals[True])


def test_recorded_evaluate_device_writes_into_out():
    """evaluate_device(requires_grad=True, out=buf) writes the result into buf (vec3 or (N, 3)) and returns it,
    recorded: its gradient flows back through buf.grad (out used to be ignored: a fresh array came back and buf
    stayed as it was). An out that cannot carry the gradient (no requires_grad, not a Warp array, another width
    or precision) is refused."""
    r = refiner("cc-boundary-flatness-normals")
    rng = np.random.default_rng(12)
    p = _points(r)
    g = rng.standard_normal((r.num_vertices, 3))
    expected = (r.matrix(normal_control=True).T @ g.reshape(-1)).reshape(-1, 3)
    for buf in (wp.zeros(r.num_vertices, dtype=wp.vec3d, requires_grad=True),
                wp.zeros((r.num_vertices, 3), dtype=wp.float64, requires_grad=True)):
        pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        with wp.Tape() as tape:
            got = r.evaluate_device(pts, requires_grad=True, out=buf)
            if buf.ndim == 1:
                wp.launch(_dot_loss, dim=r.num_vertices, inputs=[buf, wp.array(g, dtype=wp.vec3d), loss])
            else:
                wp.launch(_dot_loss_2d, dim=(r.num_vertices, 3), inputs=[buf, wp.array(g), loss])
        assert got is buf
        tape.backward(loss)
        np.testing.assert_array_equal(buf.numpy().reshape(-1, 3), r.evaluate(p))
        np.testing.assert_allclose(pts.grad.numpy(), expected, atol=1e-12)
    pts = wp.array(p, dtype=wp.vec3d, requires_grad=True)
    for bad in (wp.zeros(r.num_vertices, dtype=wp.vec3d), np.zeros((r.num_vertices, 3)),
                wp.zeros((r.num_vertices, 2), dtype=wp.float64, requires_grad=True),
                wp.zeros(r.num_vertices, dtype=wp.vec3f, requires_grad=True),
                wp.zeros(r.num_vertices + 1, dtype=wp.vec3d, requires_grad=True)):
        with pytest.raises(ws.SubdivInputError, match="out"):
            r.evaluate_device(pts, requires_grad=True, out=bad)


def test_two_pass_transposed_steps():
    """Transposed steps read in two passes (near and far child rows, as on large levels) give the same gradient
    as one pass, up to rounding, and the near part covers every parent row; so does the two-pass Loop step."""
    r = refiner("cc-boundary-flatness-normals")
    for t in r.tables:
        split = transposed.transposed_step(t, split=True)
        assert split.near.num_rows == t.num_sources and split.far.num_rows > 0
        dense = np.zeros((t.num_sources, t.num_rows))
        for part in (split.near, split.far):
            rows = rows_of(part.offsets)
            rows = rows if part.rows is None else part.rows[rows]
            np.add.at(dense, (rows, part.indices), part.weights)
        expected = np.zeros_like(dense)
        np.add.at(expected, (t.indices, rows_of(t.offsets)), t.weights)
        np.testing.assert_allclose(dense, expected, atol=1e-15)
    import unittest.mock as mock

    for case in ("cc-boundary-flatness-normals", "loop-boundary-normal", "loop-polygons-opensubdiv"):
        r = refiner(case)
        g = np.random.default_rng(9).standard_normal((r.num_vertices, 3))
        one = r.evaluate_vjp(g)
        two = ws.Refiner(r.mesh, r.levels, options=r.options, device="cpu")
        with mock.patch.object(transposed, "SPLIT_ROWS", 1):  # every step in two passes (Loop: ring, then edges)
            np.testing.assert_allclose(two.evaluate_vjp(g), one, atol=1e-12)
        if r.scheme.value == "loop":
            assert any(s.rows.far is not None for s in G.adjoint(two).tables.steps.values()
                       if isinstance(s.rows, RegularRecord))


@pytest.mark.parametrize("case,split_rows", [("cc-boundary-flatness-normals", transposed.SPLIT_ROWS),
                                             ("loop-boundary-normal", 1)])
def test_backward_is_bitwise_deterministic(monkeypatch, case, split_rows):
    """Two backward passes give the same bits, and so do 1, 2 and 3 CPU threads (launches split into row
    ranges of a few rows), for evaluate, limit_points and limit_normals, in float32 and float64: Catmull-Clark
    and Loop (with the two-pass steps of large levels)."""
    monkeypatch.setattr(th, "MIN_ROWS", 3)
    monkeypatch.setattr(transposed, "SPLIT_ROWS", split_rows)
    for precision in ("float32", "float64"):
        results = []
        for threads in (1, 2, 3):
            _, make, opts = next(c for c in CASES if c[0] == case)
            r = ws.Refiner(make(), 3, precision=precision, device="cpu", threads=threads,
                           **opts)
            rng = np.random.default_rng(7)
            g = rng.standard_normal((r.num_vertices, 3))
            x = r.evaluate(_points(r))
            runs = [(r.evaluate_vjp(g), r.evaluate_vjp(g[:, :2]), r.limit_points_vjp(g), r.limit_normals_vjp(x, g))
                    for _ in range(2)]
            for a, b in zip(*runs):
                np.testing.assert_array_equal(a, b)
            results.append(runs[0])
        for other in results[1:]:
            for a, b in zip(results[0], other):
                np.testing.assert_array_equal(a, b)


def test_gradient_inputs_are_checked():
    """Wrong shapes, precisions and devices are refused with SubdivInputError; normal control needs width 3."""
    r = refiner("cc-creased-corners")
    with pytest.raises(ws.SubdivInputError):
        r.evaluate_vjp(np.zeros((r.num_vertices + 1, 3)))
    with pytest.raises(ws.SubdivInputError):
        r.evaluate_vjp(np.zeros((r.num_vertices, 2)), normal_control=True)
    with pytest.raises(ws.SubdivInputError):
        r.limit_normals_vjp(np.zeros((r.num_vertices, 2)), np.zeros((r.num_vertices, 2)))
    with pytest.raises(ws.SubdivInputError):
        r.evaluate_device(wp.zeros(r.base_num_vertices, dtype=wp.vec3f, requires_grad=True), requires_grad=True)
    with pytest.raises(ws.SubdivInputError):
        r.evaluate_device(wp.zeros(r.base_num_vertices + 2, dtype=wp.vec3d), requires_grad=True)
    with pytest.raises(TypeError):
        r.evaluate_device(np.zeros((r.base_num_vertices, 3)), requires_grad=True)
    for f, rows in ((G.evaluate, r.base_num_vertices), (G.limit_points, r.num_vertices),
                    (G.limit_normals, r.num_vertices)):  # rows past the end would be read, or left out
        for wrong in (1, rows - 1, rows + 1):
            with pytest.raises(ws.SubdivInputError, match="must have shape"):
                f(r, wp.zeros(wrong, dtype=wp.vec3d, requires_grad=True))


def test_levels_zero_is_the_identity():
    """A refiner of 0 levels: the matrix is the identity and the gradient is the incoming one."""
    r = ws.Refiner(load_mesh("quad_lshape"), 0, precision="float64", device="cpu")
    m = r.matrix()
    np.testing.assert_array_equal(m.toarray(), np.eye(r.base_num_vertices))
    g = np.random.default_rng(8).standard_normal((r.num_vertices, 3))
    np.testing.assert_array_equal(r.evaluate_vjp(g), g)
