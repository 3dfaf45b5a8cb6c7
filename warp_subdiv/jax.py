"""JAX adapter: refinement, limit points and limit normals as differentiable JAX functions.

Install with the optional extra ``pip install "warp-subdiv[jax]"``; importing :mod:`warp_subdiv` does not
import JAX, only ``import warp_subdiv.jax`` does.

Each function has a custom VJP whose backward pass is :mod:`warp_subdiv.gradients`' (the transposed tables:
deterministic, no atomics). Concrete arrays on the refiner's device cross to Warp and back without a copy
(DLPack, ``wp.from_jax`` / ``wp.to_jax``); under ``jax.jit`` (traced values) or from another device the work
runs in a ``jax.pure_callback`` on host copies. Inputs of another float type are cast to the refiner's
precision first (a float64 refiner needs ``jax_enable_x64``).

    import jax, jax.numpy as jnp
    import warp_subdiv as ws
    from warp_subdiv import jax as wsj

    refiner = ws.Refiner(mesh, 3)
    loss = lambda p: jnp.sum((wsj.evaluate(refiner, p) - target) ** 2)
    grad = jax.grad(loss)(jnp.asarray(mesh.points, jnp.float32))
"""
from __future__ import annotations

import threading

import jax
import jax.numpy as jnp
import numpy as np
import warp as wp

from .errors import SubdivInputError
from .evaluator import kernel_view, normal_control_for, shaped_rows
from . import gradients as G

__all__ = ["evaluate", "limit_normals", "limit_points", "function"]

KINDS = ("evaluate", "limit_points", "limit_normals")
_lock = threading.Lock()


def evaluate(refiner, points, normal_control=None):
    """``refiner.evaluate`` of a JAX array of control data (n, d) or (n,), differentiable (reverse mode).
    ``normal_control`` as there (None: on for width 3)."""
    return function(refiner, "evaluate", normal_control)(points)


def limit_points(refiner, refined, normal_control=None):
    """``refiner.limit_points`` of a JAX array of last-level data (N, d) or (N,), differentiable.
    ``normal_control`` as there (None: on for width 3; False for data that is not a position, colours say), for
    the values and the gradient alike."""
    return function(refiner, "limit_points", normal_control)(refined)


def limit_normals(refiner, refined, normal_control=None):
    """``refiner.limit_normals`` of a JAX array of last-level positions (N, 3), differentiable (the true
    derivative of the unit normals). ``normal_control`` as there (None: prescribed normals substituted and
    applied in the extra step; False for positions refined without normal control), for the values and the
    gradient alike."""
    return function(refiner, "limit_normals", normal_control)(refined)


def function(refiner, kind: str = "evaluate", normal_control=None):
    """The differentiable JAX function of ``refiner`` for ``kind`` ("evaluate", "limit_points" or
    "limit_normals"), made once per refiner, kind and ``normal_control`` (usable under ``jax.jit``).
    ``normal_control`` as :meth:`Refiner.evaluate` / :meth:`Refiner.limit_points` / :meth:`Refiner.limit_normals`
    take it."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    key = ("jax", kind, None if normal_control is None else bool(normal_control))
    cache = G.adjoint(refiner).adapter_functions  # kept with the refiner's gradient state
    with _lock:
        if key not in cache:
            cache[key] = _make(refiner, kind, key[2])
        return cache[key]


def _warp_device(x):
    """The Warp device name of a concrete JAX array, or None."""
    devices = list(x.devices())
    if len(devices) != 1:
        return None
    d = devices[0]
    if d.platform == "cpu":
        return "cpu"
    if d.platform in ("gpu", "cuda"):
        return f"cuda:{d.id}"
    return None


def _checked_input(refiner, kind: str, normal_control, x) -> tuple:
    """(x as a (rows, d) JAX array, whether it was (rows,)), checked before Warp reads its memory or a
    callback's result is declared (under jit: while tracing, from the static shape) as the refiner checks its
    input (:func:`warp_subdiv.evaluator.shaped_rows`). A float64 refiner needs JAX's 64-bit floats: without
    them JAX would silently make float32 of the data."""
    if refiner.options.precision.value == "float64" and not jax.config.jax_enable_x64:
        raise SubdivInputError("a float64 refiner takes JAX arrays only with JAX's 64-bit floats on "
                               "(jax.config.update('jax_enable_x64', True)); or build the refiner with "
                               "precision='float32'", option="precision", value="float64")
    x = jnp.asarray(x)
    rows, what = ((refiner.base_num_vertices, "vertex data") if kind == "evaluate" else
                  (refiner.num_vertices, "refined points"))
    width, one_d = shaped_rows(x.shape, x.dtype.name, rows, what, positions=kind == "limit_normals")
    normal_control_for(normal_control, width)
    return (x[:, None] if one_d else x), one_d


def _make(refiner, kind: str, normal_control):
    adj = G.adjoint(refiner)
    dtype = np.dtype(adj.scalar_np)
    n, N = refiner.base_num_vertices, refiner.num_vertices

    def out_rows(forward: bool) -> int:
        if kind == "evaluate":
            return N if forward else n
        return N

    def nc_of(width: int) -> bool:
        return (width == 3) if normal_control is None else normal_control

    def direct(x) -> bool:
        return not isinstance(x, jax.core.Tracer) and _warp_device(x) == str(refiner.device)

    def to_warp(x):
        return kernel_view(wp.from_jax(x))

    # ----- forward
    def host_forward(x):
        x = np.asarray(x)
        if kind == "evaluate":
            out = refiner.evaluate(x, normal_control=nc_of(x.shape[1]))
        elif kind == "limit_points":
            out = refiner.limit_points(x, normal_control=nc_of(x.shape[1]))
        else:
            out = refiner.limit_normals(x, normal_control=nc_of(x.shape[1]))
        return np.asarray(out, dtype=dtype)

    def forward(x):
        width = x.shape[1]
        if direct(x):
            xw = to_warp(x)
            if kind == "evaluate":
                y = adj.forward(xw, nc_of(width))
            elif kind == "limit_points":
                y = adj.limits.points_forward(xw, nc_of(width))
            else:
                y = adj.limits.normals_forward(xw, nc_of(width))
            return wp.to_jax(y).reshape(out_rows(True), width)
        shape = jax.ShapeDtypeStruct((out_rows(True), width), dtype)
        return jax.pure_callback(host_forward, shape, x, vmap_method="sequential")

    # ----- backward
    def host_backward(x, g):
        g = np.asarray(g)
        if kind == "evaluate":
            out = refiner.evaluate_vjp(g, normal_control=nc_of(g.shape[1]))
        elif kind == "limit_points":
            out = refiner.limit_points_vjp(g, normal_control=nc_of(g.shape[1]))
        else:
            out = refiner.limit_normals_vjp(np.asarray(x), g, normal_control=nc_of(g.shape[1]))
        return np.asarray(out, dtype=dtype)

    def backward(x, g):
        width = g.shape[1]
        g = g.astype(dtype)
        if direct(g) and (x is None or direct(x)):
            gw = to_warp(g)
            if kind == "evaluate":
                y = adj.backward(gw, nc_of(width))
            elif kind == "limit_points":
                y = adj.limits.points_backward(gw, nc_of(width))
            else:
                y = adj.limits.normals_backward(to_warp(x), gw, nc_of(width))
            return wp.to_jax(y).reshape(out_rows(False), width)
        shape = jax.ShapeDtypeStruct((out_rows(False), width), dtype)
        args = (jnp.zeros((0,), dtype) if x is None else x, g)
        return jax.pure_callback(host_backward, shape, *args, vmap_method="sequential")

    @jax.custom_vjp
    def core(x):
        return forward(x)

    def core_fwd(x):
        return forward(x), (x if kind == "limit_normals" else None)

    def core_bwd(saved, g):
        return (backward(saved, g),)

    core.defvjp(core_fwd, core_bwd)

    def apply(x):
        x, one_d = _checked_input(refiner, kind, normal_control, x)
        y = core(x.astype(dtype))
        return y[:, 0] if one_d else y

    apply.__name__ = f"warp_subdiv_{kind}"
    apply.__doc__ = f"Differentiable {kind} of a warp_subdiv.Refiner (see warp_subdiv.jax)."
    return apply
