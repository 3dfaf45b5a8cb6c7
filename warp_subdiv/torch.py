"""PyTorch adapter: refinement, limit points and limit normals as differentiable torch functions.

Install with the optional extra ``pip install "warp-subdiv[torch]"``; importing :mod:`warp_subdiv` does not
import torch, only ``import warp_subdiv.torch`` does.

Each function is a ``torch.autograd.Function`` whose backward pass is :mod:`warp_subdiv.gradients`' (the
transposed tables: deterministic, no atomics). Tensors on the refiner's device cross to Warp and back without
a copy (``wp.from_torch`` / ``wp.to_torch``); tensors elsewhere are moved to it and their gradients moved back.
Inputs of another float type are cast to the refiner's precision first.

    import torch
    import warp_subdiv as ws
    from warp_subdiv import torch as wst

    refiner = ws.Refiner(mesh, 3, device="cpu")
    points = torch.tensor(mesh.points, dtype=torch.float32, requires_grad=True)
    loss = ((wst.evaluate(refiner, points) - target) ** 2).sum()
    loss.backward()                                  # points.grad
"""
from __future__ import annotations

import torch
import warp as wp

from .evaluator import kernel_view, normal_control_for, shaped_rows
from . import gradients as G

__all__ = ["evaluate", "limit_normals", "limit_points"]


def evaluate(refiner, points: torch.Tensor, normal_control=None) -> torch.Tensor:
    """``refiner.evaluate`` of a tensor of control data (n, d) or (n,), differentiable. ``normal_control`` as
    there (None: on for width 3)."""
    return _apply(refiner, "evaluate", normal_control, points)


def limit_points(refiner, refined: torch.Tensor, normal_control=None) -> torch.Tensor:
    """``refiner.limit_points`` of a tensor of last-level data (N, d) or (N,), differentiable. ``normal_control``
    as there (None: on for width 3; False for data that is not a position, colours say), for the values and
    the gradient alike."""
    return _apply(refiner, "limit_points", normal_control, refined)


def limit_normals(refiner, refined: torch.Tensor, normal_control=None) -> torch.Tensor:
    """``refiner.limit_normals`` of a tensor of last-level positions (N, 3), differentiable (the true derivative
    of the unit normals). ``normal_control`` as there (None: prescribed normals substituted and applied in the
    extra step; False for positions refined without normal control), for the values and the gradient alike."""
    return _apply(refiner, "limit_normals", normal_control, refined)


_DTYPES = {"float32": torch.float32, "float64": torch.float64}


def _apply(refiner, kind, normal_control, x: torch.Tensor) -> torch.Tensor:
    # checked before the cast, which would drop an imaginary part, and before Warp reads the memory
    x = torch.as_tensor(x)
    rows, what = ((refiner.base_num_vertices, "vertex data") if kind == "evaluate" else
                  (refiner.num_vertices, "refined points"))
    width, one_d = shaped_rows(x.shape, str(x.dtype).removeprefix("torch."), rows, what,
                               positions=kind == "limit_normals")
    normal_control_for(normal_control, width)
    if one_d:
        x = x[:, None]
    device = wp.device_to_torch(refiner.device)
    y = _Refine.apply(x.to(device=device, dtype=_DTYPES[refiner.options.precision.value]), refiner, kind,
                      normal_control)
    y = y.to(x.device)
    return y[:, 0] if one_d else y


def _to_warp(t: torch.Tensor) -> wp.array:
    """A contiguous tensor (rows, d) as a Warp array in the kernels' view, sharing its memory."""
    return kernel_view(wp.from_torch(t.detach().contiguous()))


def _to_torch(a: wp.array, rows: int, width: int) -> torch.Tensor:
    return wp.to_torch(a).reshape(rows, width)


class _Refine(torch.autograd.Function):
    """One of the refiner's maps (``kind``) with the transposed tables as its backward."""

    @staticmethod
    def forward(ctx, x, refiner, kind, normal_control):
        adj = G.adjoint(refiner)
        width = x.shape[1]
        nc = (width == 3) if normal_control is None else bool(normal_control)
        xw = _to_warp(x)
        if kind == "evaluate":
            y = adj.forward(xw, nc)
        elif kind == "limit_points":
            y = adj.limits.points_forward(xw, nc)
        else:
            y = adj.limits.normals_forward(xw, nc)
        ctx.refiner, ctx.kind, ctx.nc = refiner, kind, nc
        if kind == "limit_normals":
            ctx.save_for_backward(x)
        return _to_torch(y, refiner.num_vertices, width)

    @staticmethod
    def backward(ctx, grad):
        adj = G.adjoint(ctx.refiner)
        width = grad.shape[1]
        gw = _to_warp(grad)
        if ctx.kind == "evaluate":
            y = adj.backward(gw, ctx.nc)
            rows = ctx.refiner.base_num_vertices
        elif ctx.kind == "limit_points":
            y = adj.limits.points_backward(gw, ctx.nc)
            rows = ctx.refiner.num_vertices
        else:
            (x,) = ctx.saved_tensors
            y = adj.limits.normals_backward(_to_warp(x), gw, ctx.nc)
            rows = ctx.refiner.num_vertices
        return _to_torch(y, rows, width), None, None, None
