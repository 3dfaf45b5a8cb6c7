"""Kernels of the backward pass (:mod:`warp_subdiv.gradients`) that the forward kernels do not already provide.

The adjoint of a linear step is its transposed table, applied with the forward gather kernels
(:func:`~warp_subdiv.kernels.stencil.stencil_rows`, :func:`~warp_subdiv.kernels.projection.displace_rows`,
:func:`~warp_subdiv.kernels.projection.project_rows`): no atomics, one thread per output row, so gradients are
bitwise equal run to run and for any split of the rows over threads. This module adds the pieces around them:
accumulating into a gradient, zeroing the rows of prescribed normals, and the (non-linear) derivative of the
limit normals with respect to their tangents.
"""
from typing import Any

import warp as wp

from .layout import columns, data_types, load, store

wp.set_module_options({"enable_backward": False})


@wp.kernel
def add_rows(src: Any, dst: Any, row0: int):
    """dst[i] += src[i] (any width; row ``row0 + tid``)."""
    i = wp.tid() + row0
    for c in range(columns(dst)):
        store(dst, i, c, load(dst, i, c) + load(src, i, c))


@wp.kernel
def zero_rows(rows: wp.array(dtype=wp.int32), zero: Any, dst: wp.array(dtype=Any)):
    """dst[rows[i]] = zero (vec3 rows)."""
    i = wp.tid()
    dst[rows[i]] = zero


@wp.kernel
def vertex_normals_adjoint(
    vertex_offsets: wp.array(dtype=wp.int32),
    tangent_u: wp.array(dtype=Any),
    tangent_v: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    zero: Any,
    v_row: int,
    grad_uv: wp.array(dtype=Any),
    row0: int,
):
    """The derivative of :func:`~warp_subdiv.kernels.projection.vertex_normals` (one thread per vertex): from the
    gradient of vertex i's unit normal, the gradients of its tangent pairs, ``grad_uv[j]`` for tangent_u[j] and
    ``grad_uv[v_row + j]`` for tangent_v[j].

    The forward value is normalize(sum_j normalize(u_j x v_j)), or normalize of the first non-zero term where the
    sum cancels exactly; with n = c / |c|, dn = (I - n n^T) dc / |c|, and d(u x v) = du x v + u x dv, so
    g_u = v x g_c and g_v = g_c x u. Terms of zero length (normalised to zero in the forward pass) pass no
    gradient, as there."""
    i = wp.tid() + row0
    start = vertex_offsets[i]
    end = vertex_offsets[i + 1]
    z = wp.length(zero)
    acc = zero
    first = int(-1)
    for j in range(start, end):
        n = wp.normalize(wp.cross(tangent_u[j], tangent_v[j]))
        if first < 0 and wp.length(n) > z:
            first = j
        acc += n
    only = int(-1)  # the one term the normal depends on where the sum cancels (-1: every term)
    if wp.length_sq(acc) == wp.length_sq(zero):
        only = first
        if first >= 0:
            acc = wp.normalize(wp.cross(tangent_u[first], tangent_v[first]))
    length = wp.length(acc)
    ga = zero
    if length > z:
        out = acc / length
        g = grad_out[i]
        ga = (g - out * wp.dot(out, g)) / length
    for j in range(start, end):
        u = tangent_u[j]
        v = tangent_v[j]
        c = wp.cross(u, v)
        lc = wp.length(c)
        gc = zero
        if lc > z and (only < 0 or j == only):
            n = c / lc
            gc = (ga - n * wp.dot(n, ga)) / lc
        grad_uv[j] = wp.cross(v, gc)
        grad_uv[v_row + j] = wp.cross(gc, u)


# Explicit instantiations: the generic kernel for both layouts of both precisions, the vec3 ones for both
# precisions (so that the module compiles once).
ADJOINT_OVERLOADS = []
for _s, _a in data_types():
    ADJOINT_OVERLOADS.append(wp.overload(add_rows, [_a, _a, int]))
for _v in (wp.vec3f, wp.vec3d):
    _i = wp.array(dtype=wp.int32)
    _a = wp.array(dtype=_v)
    ADJOINT_OVERLOADS += [
        wp.overload(zero_rows, [_i, _v, _a]),
        wp.overload(vertex_normals_adjoint, [_i, _a, _a, _a, _v, int, _a, int]),
    ]


@wp.kernel
def explicit_rows_add(rows: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                      indices: wp.array(dtype=wp.int32), weights: wp.array(dtype=Any), src: Any, dst: Any, row0: int):
    """dst[rows[i]] += sum_j weights[j] src[indices[j]] over row i of a CSR table (distinct ``rows``): the far part
    of a transposed step (see :class:`warp_subdiv.gradients.TransposedStep`)."""
    i = wp.tid() + row0
    start = offsets[i]
    end = offsets[i + 1]
    r = rows[i]
    for c in range(columns(dst)):
        acc = load(dst, r, c)
        for j in range(start, end):
            acc += weights[j] * load(src, indices[j], c)
        store(dst, r, c, acc)


for _s, _a in data_types():
    _i = wp.array(dtype=wp.int32)
    ADJOINT_OVERLOADS.append(wp.overload(explicit_rows_add, [_i, _i, _i, wp.array(dtype=_s), _a, _a, int]))
