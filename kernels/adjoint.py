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



@wp.kernel
def quad_face_adjoint(corner_vert: wp.array(dtype=wp.int32), corner_edge_row: wp.array(dtype=wp.int32),
                      w_vert: wp.array(dtype=Any), edge_weights: wp.array(dtype=Any), src: Any, face_row: int,
                      out: Any, row0: int):
    """The gradient of the face points of a Catmull-Clark step over quads, through everything that read them:
    out[f] = g[face point f] + sum over the face's corners h of edge_weights[1] g[edge child of h's edge] (a
    smooth edge row's wing weight; rows left to the explicit stencils have row -1) + w_vert[h] g[vertex child
    of h's vertex] (a smooth vertex row's ring weight, else 0)."""
    f = wp.tid() + row0
    b = 4 * f
    wing = edge_weights[1]
    for c in range(columns(out)):
        acc = load(src, face_row + f, c)
        for k in range(4):
            h = b + k
            e = corner_edge_row[h]
            if e >= 0:
                acc += wing * load(src, e, c)
            acc += w_vert[h] * load(src, corner_vert[h], c)
        store(out, f, c, acc)


@wp.kernel
def quad_vertex_adjoint(offsets: wp.array(dtype=wp.int32), slot_vert: wp.array(dtype=wp.int32),
                        slot_edge_row: wp.array(dtype=wp.int32), slot_face: wp.array(dtype=wp.int32),
                        w_centre: wp.array(dtype=Any), w_vert: wp.array(dtype=Any), edge_weights: wp.array(dtype=Any),
                        quarter: wp.array(dtype=Any), src: Any, faces: Any, dst: Any, row0: int):
    """The transposed smooth rows of a Catmull-Clark step over quads, per parent vertex j (one per slot: each of
    j's corners, its next vertex u, its edge e and its face f): dst[j] = w_centre[j] g[j] + sum of w_vert g[u]
    (u's vertex row) + edge_weights[0] g[edge child of e] (a smooth edge row's endpoint weight; -1: none) +
    1/4 faces[f] (the face point, whose gradient :func:`quad_face_adjoint` gathered)."""
    j = wp.tid() + row0
    start = offsets[j]
    end = offsets[j + 1]
    w_end = edge_weights[0]
    for c in range(columns(dst)):
        acc = w_centre[j] * load(src, j, c)
        for s in range(start, end):
            acc += w_vert[s] * load(src, slot_vert[s], c) + quarter[0] * load(faces, slot_face[s], c)
            e = slot_edge_row[s]
            if e >= 0:
                acc += w_end * load(src, e, c)
        store(dst, j, c, acc)


@wp.kernel
def tri_vertex_adjoint(offsets: wp.array(dtype=wp.int32), slot_vert: wp.array(dtype=wp.int32),
                       slot_edge_row: wp.array(dtype=wp.int32), slot_opposite_row: wp.array(dtype=wp.int32),
                       w_centre: wp.array(dtype=Any), w_vert: wp.array(dtype=Any), edge_weights: wp.array(dtype=Any),
                       src: Any, dst: Any, row0: int):
    """The transposed smooth rows of a Loop step, per parent vertex j (one per slot: each of j's corners, its
    next vertex u, its edge and the edge opposite j in its face): dst[j] = w_centre[j] g[j] + sum of w_vert
    g[u] + edge_weights[0] g[edge child] + edge_weights[1] g[child of the opposite edge] (rows left to the
    explicit stencils: weight 0, row -1)."""
    j = wp.tid() + row0
    start = offsets[j]
    end = offsets[j + 1]
    w_end = edge_weights[0]
    w_wing = edge_weights[1]
    for c in range(columns(dst)):
        acc = w_centre[j] * load(src, j, c)
        for s in range(start, end):
            acc += w_vert[s] * load(src, slot_vert[s], c)
            e = slot_edge_row[s]
            if e >= 0:
                acc += w_end * load(src, e, c)
            o = slot_opposite_row[s]
            if o >= 0:
                acc += w_wing * load(src, o, c)
        store(dst, j, c, acc)


@wp.kernel
def tri_ring_adjoint(offsets: wp.array(dtype=wp.int32), slot_vert: wp.array(dtype=wp.int32),
                     w_centre: wp.array(dtype=Any), w_vert: wp.array(dtype=Any), src: Any, dst: Any, row0: int):
    """The vertex-child part of :func:`tri_vertex_adjoint` (a first pass on large levels, reading only the
    vertex children): dst[j] = w_centre[j] g[j] + sum of w_vert g[u]."""
    j = wp.tid() + row0
    start = offsets[j]
    end = offsets[j + 1]
    for c in range(columns(dst)):
        acc = w_centre[j] * load(src, j, c)
        for s in range(start, end):
            acc += w_vert[s] * load(src, slot_vert[s], c)
        store(dst, j, c, acc)


@wp.kernel
def tri_edge_adjoint(order: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                     slot_edge_row: wp.array(dtype=wp.int32), slot_opposite_row: wp.array(dtype=wp.int32),
                     edge_weights: wp.array(dtype=Any), src: Any, dst: Any, row0: int):
    """The edge-child part of :func:`tri_vertex_adjoint` (the second pass on large levels): row i of these
    tables belongs to parent ``order[i]``, to which it adds the edge terms of its slots. The parents come in the
    order of their last incident edge, so that the reads of a stretch of rows stay in one region of the edge
    children."""
    i = wp.tid() + row0
    j = order[i]
    start = offsets[i]
    end = offsets[i + 1]
    w_end = edge_weights[0]
    w_wing = edge_weights[1]
    for c in range(columns(dst)):
        acc = load(dst, j, c)
        for s in range(start, end):
            e = slot_edge_row[s]
            if e >= 0:
                acc += w_end * load(src, e, c)
            o = slot_opposite_row[s]
            if o >= 0:
                acc += w_wing * load(src, o, c)
        store(dst, j, c, acc)

# Explicit instantiations: the generic kernel for both layouts of both precisions, the vec3 ones for both
# precisions (so that the module compiles once).
ADJOINT_OVERLOADS = []
for _s, _a in data_types():
    _i = wp.array(dtype=wp.int32)
    _w = wp.array(dtype=_s)
    ADJOINT_OVERLOADS += [
        wp.overload(add_rows, [_a, _a, int]),
        wp.overload(quad_face_adjoint, [_i, _i, _w, _w, _a, int, _a, int]),
        wp.overload(quad_vertex_adjoint, [_i, _i, _i, _i, _w, _w, _w, _w, _a, _a, _a, int]),
        wp.overload(tri_vertex_adjoint, [_i, _i, _i, _i, _w, _w, _w, _a, _a, int]),
        wp.overload(tri_ring_adjoint, [_i, _i, _w, _w, _a, _a, int]),
        wp.overload(tri_edge_adjoint, [_i, _i, _i, _i, _w, _a, _a, int]),
    ]
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
