"""The gradients' entry points: :func:`evaluate`, :func:`limit_points`, :func:`limit_normals` (and the three in
one, :func:`evaluate_with_limits`) take and return Warp arrays and record their backward pass (the refiner's
:class:`~warp_subdiv.gradients.passes.Adjoint`) on an active ``wp.Tape`` (``Tape.record_func``) where an input
requires grad, as Warp records launches (:func:`recording`: the refiner's device entry points route through
here then); :func:`evaluate_vjp`, :func:`limit_points_vjp` and
:func:`limit_normals_vjp` take and return numpy arrays. Host data is checked by
:func:`~warp_subdiv.evaluator.host_rows`, Warp arrays by :func:`~warp_subdiv.evaluator.device_rows` (as the
refiner checks its inputs).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import SubdivInputError
from ..evaluator import PRECISIONS, Evaluated, device_rows, host_rows, kernel_view, normal_control_for
from .checks import check_positions
from .passes import Adjoint, adjoint
from .records import _kernels


def _host_rows(refiner, grad, rows: int, what: str) -> np.ndarray:
    return host_rows(grad, rows, what, refiner.options.precision.value)


def _shaped(out: np.ndarray, like) -> np.ndarray:
    return out[:, 0] if np.ndim(like) == 1 else out


def evaluate_vjp(refiner, grad, normal_control=None) -> np.ndarray:
    """The gradient with respect to the control data of ``grad`` (N, d) (or (N,)), a gradient of
    ``refiner.evaluate(data, normal_control)``: the transposed map applied to it (the map is linear, so the
    control data itself is not needed). ``normal_control`` as in :meth:`Refiner.evaluate` (None: on for width
    3). Returns (n, d) in the evaluation precision."""
    g = _host_rows(refiner, grad, refiner.num_vertices, "gradient")
    if normal_control is None:
        normal_control = g.shape[1] == 3
    adj = adjoint(refiner)
    return _shaped(adj.to_host(adj.backward(adj.to_device(g), bool(normal_control))), grad)


def limit_points_vjp(refiner, grad, normal_control=None) -> np.ndarray:
    """The gradient with respect to the refined data of ``grad``, a gradient of
    ``refiner.limit_points(data, normal_control=normal_control)`` (same shape as the data). ``normal_control`` as
    there: None treats width-3 data as positions (prescribed normals in the extra step where the masks are read
    one level deeper), False never (data that is not a position)."""
    g = _host_rows(refiner, grad, refiner.num_vertices, "gradient")
    adj = adjoint(refiner)
    return _shaped(adj.to_host(adj.limits.points_backward(adj.to_device(g), normal_control)), grad)


def limit_normals_vjp(refiner, refined_points, grad, normal_control=None) -> np.ndarray:
    """The gradient with respect to the refined positions (N, 3) of ``grad`` (N, 3), a gradient of
    ``refiner.limit_normals(refined_points, normal_control=normal_control)``: the true derivative of the
    normalised normals. ``normal_control`` as there: None (or True) substitutes the prescribed normals (their
    rows pass no gradient) and applies them in the extra step where the masks are read one level deeper; False
    (positions refined without normal control) does neither."""
    x = _host_rows(refiner, refined_points, refiner.num_vertices, "refined points")
    g = _host_rows(refiner, grad, refiner.num_vertices, "gradient")
    for name, a in (("refined points", x), ("gradient", g)):
        if a.shape[1] != 3:
            raise SubdivInputError(f"limit normals take (N, 3) {name}, got {a.shape}", element="data",
                                   value=a.shape)
    adj = adjoint(refiner)
    return adj.to_host(adj.limits.normals_backward(adj.to_device(x), adj.to_device(g), normal_control))


def _active_tape():
    ctx = getattr(getattr(wp, "_src", None), "context", None) or wp.context
    return ctx.runtime.tape if ctx.runtime is not None else None


class _NoTape:
    """Within the block no Warp tape records (our kernels have no adjoints; the backward is recorded whole)."""

    def __enter__(self):
        ctx = getattr(getattr(wp, "_src", None), "context", None) or wp.context
        self.ctx = ctx
        self.tape = ctx.runtime.tape if ctx.runtime is not None else None
        if self.tape is not None:
            ctx.runtime.tape = None
        return self.tape

    def __exit__(self, *exc):
        if self.tape is not None:
            self.ctx.runtime.tape = self.tape


def _user_array(refiner, arr, rows: int, what: str) -> wp.array:
    """A caller's Warp array as the kernel view (vec3 for width 3), checked: (rows,), (rows, d) or vec3 (rows,),
    on the refiner's device, of its precision, contiguous (the tape writes its gradient in place)."""
    if not isinstance(arr, wp.array):
        raise TypeError(f"{what} must be a warp array, got {type(arr).__name__}")
    precision = refiner.options.precision.value
    _, scalar, vec = PRECISIONS[precision]
    if arr.device != refiner.device:
        raise SubdivInputError(f"{what} is on {arr.device}, the refiner on {refiner.device}", element="data")
    view = device_rows(arr, rows, what, refiner.device)
    if arr.dtype not in (scalar, vec):
        raise SubdivInputError(f"{what} must hold {precision} (the refiner's precision) or its vec3, got "
                               f"{arr.dtype.__name__}", element="data")
    if not arr.is_contiguous:
        raise SubdivInputError(f"{what} must be contiguous", element="data")
    return arr if arr.dtype == vec else kernel_view(view)


def _result_like(adj: Adjoint, x_user: wp.array, rows: int, width: int, requires_grad: bool):
    """(the array handed back, in the caller's shape convention, and its view in the kernels' layout)."""
    if x_user.ndim == 1 and x_user.dtype == adj.vec:
        shape, dtype = rows, adj.vec
    elif x_user.ndim == 1:
        shape, dtype = rows, adj.scalar
    else:
        shape, dtype = (rows, width), adj.scalar
    out = wp.empty(shape, dtype=dtype, device=adj.device, requires_grad=requires_grad)
    if out.ndim == 2:
        return out, kernel_view(out)
    return out, (out if dtype == adj.vec else out.reshape((rows, 1)))


def _grad_view(arr: wp.array, rows: int) -> wp.array:
    g = arr.grad
    if g.ndim == 1 and g.dtype in (wp.vec3f, wp.vec3d):
        return g
    return kernel_view(g.reshape((rows, 1)) if g.ndim == 1 else g)


def recording(*arrays) -> bool:
    """Whether work on ``arrays`` is recorded now, by Warp's convention for launches: a ``wp.Tape`` is active
    and one of them is a Warp array that requires grad. The refiner's device entry points follow it (their
    ``requires_grad`` argument overrides it)."""
    return _active_tape() is not None and any(isinstance(a, wp.array) and a.requires_grad for a in arrays)


def _record(requires_grad: bool, inputs, output, backward) -> None:
    """Record ``backward`` on the active tape where the result has a gradient and an input needs one."""
    tape = _active_tape()
    if tape is None or not requires_grad or not any(a.requires_grad for a in inputs):
        return
    tape.record_func(backward, [a for a in list(inputs) + [output] if a.requires_grad])


def _given_out(refiner, out, width: int, requires_grad: bool) -> wp.array:
    """The kernel view of a caller's ``out`` for :func:`evaluate`'s result: a Warp array checked as the inputs
    are (the last level's rows, the refiner's precision and device, contiguous), of the result's width, and
    with a gradient array where the result has one (the recorded backward reads ``out.grad``)."""
    if not isinstance(out, wp.array):
        raise SubdivInputError(f"out must be a warp array where the result has a gradient (its backward reads "
                               f"out.grad), got {type(out).__name__}", element="data", value=type(out).__name__)
    view = _user_array(refiner, out, refiner.num_vertices, "out")
    if adjoint(refiner).width(view) != width:
        raise SubdivInputError(f"out must have width {width} (the points'), got {tuple(out.shape)}",
                               element="data", value=tuple(out.shape))
    if requires_grad and not out.requires_grad:
        raise SubdivInputError("out must have requires_grad=True: the recorded backward reads out.grad",
                               element="data")
    return view


def evaluate(refiner, points: wp.array, normal_control=None, requires_grad=None, *, out=None) -> wp.array:
    """Refine a Warp array of control data (vec3 (n,), (n, d) or (n,) of the refiner's precision, on its device);
    returns a fresh array of the last level in the same convention, or ``out`` (a Warp array of the last level's
    rows and the points' width, as the points are checked) written in place. ``normal_control`` as in
    :meth:`Refiner.evaluate` (None: on for width 3). ``requires_grad`` (default: the input's): the result has a
    gradient array (``out`` must have one), and under an active ``wp.Tape`` the backward pass (the transposed
    tables) is recorded; it adds to ``points.grad``."""
    adj = adjoint(refiner)
    x = _user_array(refiner, points, refiner.base_num_vertices, "points")
    width = adj.width(x)
    nc = bool(normal_control_for(normal_control, width))
    rg = points.requires_grad if requires_grad is None else bool(requires_grad)
    if out is None:
        out, view = _result_like(adj, points, refiner.num_vertices, width, rg)
    else:
        view = _given_out(refiner, out, width, rg)
    with _NoTape():
        wp.copy(view, adj.forward(x, nc))
    n = refiner.base_num_vertices

    def backward():
        adj.backward(_grad_view(out, refiner.num_vertices), nc, out=_grad_view(points, n), accumulate=True)

    _record(rg, [points], out, backward)
    return out


def limit_points(refiner, refined: wp.array, requires_grad=None, *, normal_control=None) -> wp.array:
    """Limit values of a Warp array of the last level's data (as :func:`evaluate` takes data), recorded on an
    active tape; ``normal_control`` as in :meth:`Refiner.limit_points` (None: on for width 3; pass False for
    data that is not a position), for the forward and the recorded backward alike."""
    adj = adjoint(refiner)
    N = refiner.num_vertices
    x = _user_array(refiner, refined, N, "refined points")
    width = adj.width(x)
    nc = bool(normal_control_for(normal_control, width))
    rg = refined.requires_grad if requires_grad is None else bool(requires_grad)
    out, view = _result_like(adj, refined, N, width, rg)
    with _NoTape():
        wp.copy(view, adj.limits.points_forward(x, nc))

    def backward():
        g = adj.limits.points_backward(_grad_view(out, N), nc)
        adj.launcher.rows(_kernels().add_rows, N, [g, _grad_view(refined, N)])

    _record(rg, [refined], out, backward)
    return out


def limit_normals(refiner, refined: wp.array, requires_grad=None, *, normal_control=None) -> wp.array:
    """Unit limit normals of a Warp array of the last level's positions (vec3 (N,) or (N, 3)), recorded on an
    active tape (the backward recomputes the tangents from ``refined`` as it is then); ``normal_control`` as in
    :meth:`Refiner.limit_normals` (None: on; pass False for positions refined without normal control: no
    prescribed normal substituted nor applied in the extra step), for the forward and the recorded backward
    alike."""
    adj = adjoint(refiner)
    N = refiner.num_vertices
    x = _user_array(refiner, refined, N, "refined points")
    check_positions(x)
    nc = bool(normal_control_for(normal_control, 3))
    rg = refined.requires_grad if requires_grad is None else bool(requires_grad)
    out, view = _result_like(adj, refined, N, 3, rg)
    with _NoTape():
        wp.copy(view, adj.limits.normals_forward(x, nc))

    def backward():
        g = adj.limits.normals_backward(x, _grad_view(out, N), nc)
        adj.launcher.rows(_kernels().add_rows, N, [g, _grad_view(refined, N)])

    _record(rg, [refined], out, backward)
    return out


def evaluate_with_limits(refiner, points: wp.array, normal_control=None, with_limit_points: bool = True,
                         with_limit_normals: bool = True) -> Evaluated:
    """:meth:`Refiner.evaluate_with_limits` on the device, recorded: :func:`evaluate` of ``points``, then
    :func:`limit_points` and :func:`limit_normals` of its result (each a fresh array with a gradient where
    ``points`` requires one; under an active ``wp.Tape`` each backward is recorded). ``normal_control`` applies to
    the refinement, the limits' extra step and the limit normals' prescribed ones alike. The same values as the
    evaluator's one pass, whose shared buffers a tape cannot hold."""
    refined = evaluate(refiner, points, normal_control)
    return Evaluated(refined,
                     limit_points(refiner, refined, normal_control=normal_control) if with_limit_points else None,
                     limit_normals(refiner, refined, normal_control=normal_control) if with_limit_normals else None)
