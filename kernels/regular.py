"""Kernels that compute the smooth rows of a step straight from a uniform level's index tables.

No stencil weights are stored for these rows: a face point is the mean of its corners, a smooth edge point
weighs its endpoints and its two wings, a smooth vertex point weighs itself and its ring, with weights
looked up per valence. Rows marked 0 in the ``regular`` masks are left for :func:`explicit_rows`; an empty
mask means every row is regular. On a level of quads what index arithmetic gives is not stored: corner h
lies in face h // 4 and is followed by corner :func:`next_quad_corner` (h), so an edge is read as its two
corners and a vertex's ring as its corners (:func:`quad_edge_points`, :func:`quad_vertex_points`). The
``_expanded`` variants read the same rows from tables with those lookups done once (each edge's endpoints
and faces, each vertex's ring vertices and faces): twice the table bytes, one dependent gather less per
term, which on Warp's CPU backend (latency-bound gathers) makes a large step up to a third faster (a small
one, no faster); the evaluator uses them on the CPU from a refiner's third evaluation on, for steps of at
least ``evaluator.EXPAND_MIN_ROWS`` rows. Both compute every row with the same operations in the same order:
their results are bitwise equal.
Output layout: child vertices [vertex children, face children (Catmull-Clark), edge children].

Vertex data comes in either layout of :mod:`warp_subdiv.kernels.layout` (vec3 rows, or (rows, width)
scalars with a loop over the columns): one thread per output row. Every kernel takes ``row0``, the first
row of its launch: thread ``tid`` computes row ``row0 + tid``, so a launch can cover a contiguous range of
rows (the evaluator splits a CPU launch into a few ranges run on several threads; one launch has row0 0).
"""
from typing import Any

import warp as wp

from .layout import columns, data_types, load, store

wp.set_module_options({"enable_backward": False})


@wp.func
def next_quad_corner(h: int):
    """The corner after ``h`` in its quad (corners 4f..4f+3 belong to face f)."""
    return (h & ~3) | ((h + 1) & 3)


@wp.func
def skipped(regular: wp.array(dtype=wp.uint8), row: int):
    """Whether ``row`` is left to the explicit rows (an empty mask: every row is regular)."""
    if regular.shape[0] == 0:
        return False
    return regular[row] == wp.uint8(0)


@wp.kernel
def quad_face_points(corner_vert: wp.array(dtype=wp.int32), src: Any, dst: Any, first_row: int,
                     quarter: wp.array(dtype=Any), row0: int):
    """Catmull-Clark face points of a quad level: dst[first_row + f] = mean of the face's 4 corners."""
    f = wp.tid() + row0
    b = 4 * f
    c0 = corner_vert[b]
    c1 = corner_vert[b + 1]
    c2 = corner_vert[b + 2]
    c3 = corner_vert[b + 3]
    for c in range(columns(dst)):
        store(dst, first_row + f, c, quarter[0] * (load(src, c0, c) + load(src, c1, c) + load(src, c2, c)
                                                   + load(src, c3, c)))


@wp.kernel
def quad_edge_points(edge_corners: wp.array2d(dtype=wp.int32), corner_vert: wp.array(dtype=wp.int32),
                     regular: wp.array(dtype=wp.uint8), src: Any, dst: Any, face_row: int, first_row: int,
                     weights: wp.array(dtype=Any), row0: int):
    """Smooth Catmull-Clark edge points: w0 (a + b) + w1 (f0 + f1), f the new face points already in dst.

    ``edge_corners[e]`` = (h0, h1), the edge's corners: a, b are h0's vertex and the next one, f0, f1 the
    faces of h0 and h1."""
    e = wp.tid() + row0
    if skipped(regular, e):
        return
    h0 = edge_corners[e, 0]
    a = corner_vert[h0]
    b = corner_vert[next_quad_corner(h0)]
    f0 = face_row + (h0 >> 2)
    f1 = face_row + (edge_corners[e, 1] >> 2)
    for c in range(columns(dst)):
        store(dst, first_row + e, c, weights[0] * (load(src, a, c) + load(src, b, c)) + weights[1] * (
            load(dst, f0, c) + load(dst, f1, c)))


@wp.kernel
def quad_edge_points_expanded(neighbours: wp.array2d(dtype=wp.int32), regular: wp.array(dtype=wp.uint8), src: Any,
                              dst: Any, face_row: int, first_row: int, weights: wp.array(dtype=Any), row0: int):
    """:func:`quad_edge_points` from expanded tables: ``neighbours[e]`` = (a, b, face 0, face 1)."""
    e = wp.tid() + row0
    if skipped(regular, e):
        return
    a = neighbours[e, 0]
    b = neighbours[e, 1]
    f0 = face_row + neighbours[e, 2]
    f1 = face_row + neighbours[e, 3]
    for c in range(columns(dst)):
        store(dst, first_row + e, c, weights[0] * (load(src, a, c) + load(src, b, c)) + weights[1] * (
            load(dst, f0, c) + load(dst, f1, c)))


@wp.kernel
def quad_vertex_points_expanded(offsets: wp.array(dtype=wp.int32), ring: wp.array(dtype=wp.int32),
                                ring_faces: wp.array(dtype=wp.int32), regular: wp.array(dtype=wp.uint8), src: Any,
                                dst: Any, face_row: int, weights: wp.array2d(dtype=Any), row0: int):
    """:func:`quad_vertex_points` from expanded tables: ``ring`` the ring vertices, ``ring_faces`` their faces."""
    v = wp.tid() + row0
    if skipped(regular, v):
        return
    start = offsets[v]
    end = offsets[v + 1]
    n = end - start
    for c in range(columns(dst)):
        acc = load(src, ring[start], c) + load(dst, face_row + ring_faces[start], c)
        for j in range(start + 1, end):
            acc += load(src, ring[j], c) + load(dst, face_row + ring_faces[j], c)
        store(dst, v, c, weights[n, 0] * load(src, v, c) + weights[n, 1] * acc)


@wp.kernel
def quad_vertex_points(offsets: wp.array(dtype=wp.int32), ring: wp.array(dtype=wp.int32),
                       corner_vert: wp.array(dtype=wp.int32), regular: wp.array(dtype=wp.uint8), src: Any,
                       dst: Any, face_row: int, weights: wp.array2d(dtype=Any), row0: int):
    """Smooth Catmull-Clark vertex points: w0(n) v + w1(n) (sum of ring vertices + sum of new face points).

    ``ring`` lists the vertex's corners h: each adds the vertex after it and the face point of face h // 4."""
    v = wp.tid() + row0
    if skipped(regular, v):
        return
    start = offsets[v]
    end = offsets[v + 1]
    n = end - start
    for c in range(columns(dst)):
        h = ring[start]
        acc = load(src, corner_vert[next_quad_corner(h)], c) + load(dst, face_row + (h >> 2), c)
        for j in range(start + 1, end):
            h = ring[j]
            acc += load(src, corner_vert[next_quad_corner(h)], c) + load(dst, face_row + (h >> 2), c)
        store(dst, v, c, weights[n, 0] * load(src, v, c) + weights[n, 1] * acc)


@wp.kernel
def tri_edge_points(neighbours: wp.array2d(dtype=wp.int32), regular: wp.array(dtype=wp.uint8), src: Any, dst: Any,
                    first_row: int, weights: wp.array(dtype=Any), row0: int):
    """Smooth Loop edge points: w0 (a + b) + w1 (o0 + o1). ``neighbours[e]`` = (a, b, o0, o1), o the vertices
    opposite the edge."""
    e = wp.tid() + row0
    if skipped(regular, e):
        return
    a = neighbours[e, 0]
    b = neighbours[e, 1]
    o0 = neighbours[e, 2]
    o1 = neighbours[e, 3]
    for c in range(columns(dst)):
        store(dst, first_row + e, c, weights[0] * (load(src, a, c) + load(src, b, c)) + weights[1] * (
            load(src, o0, c) + load(src, o1, c)))


@wp.kernel
def tri_vertex_points(offsets: wp.array(dtype=wp.int32), ring: wp.array(dtype=wp.int32),
                      regular: wp.array(dtype=wp.uint8), src: Any, dst: Any, weights: wp.array2d(dtype=Any),
                      row0: int):
    """Smooth Loop vertex points: (1 - n beta) v + beta (sum of ring vertices); ``ring`` lists the vertices."""
    v = wp.tid() + row0
    if skipped(regular, v):
        return
    start = offsets[v]
    end = offsets[v + 1]
    n = end - start
    for c in range(columns(dst)):
        acc = load(src, ring[start], c)
        for j in range(start + 1, end):
            acc += load(src, ring[j], c)
        store(dst, v, c, weights[n, 0] * load(src, v, c) + weights[n, 1] * acc)


@wp.kernel
def explicit_rows(rows: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                  indices: wp.array(dtype=wp.int32), weights: wp.array(dtype=Any), src: Any, dst: Any, row0: int):
    """dst[rows[i]] = sum_j weights[j] src[indices[j]] over row i of a CSR table (the irregular rows of a
    uniform step)."""
    i = wp.tid() + row0
    start = offsets[i]
    end = offsets[i + 1]
    for c in range(columns(dst)):
        acc = weights[start] * load(src, indices[start], c)
        for j in range(start + 1, end):
            acc += weights[j] * load(src, indices[j], c)
        store(dst, rows[i], c, acc)


# Explicit instantiations (both layouts of both precisions), so that the module compiles once whatever the
# data's width, and ahead-of-time compilation and the kernel cache hold every variant we launch.
REGULAR_OVERLOADS = []
for _s, _a in data_types():
    _i = wp.array(dtype=wp.int32)
    _i2 = wp.array2d(dtype=wp.int32)
    _u = wp.array(dtype=wp.uint8)
    _w = wp.array(dtype=_s)
    _w2 = wp.array2d(dtype=_s)
    REGULAR_OVERLOADS += [
        wp.overload(quad_face_points, [_i, _a, _a, int, _w, int]),
        wp.overload(quad_edge_points, [_i2, _i, _u, _a, _a, int, int, _w, int]),
        wp.overload(quad_vertex_points, [_i, _i, _i, _u, _a, _a, int, _w2, int]),
        wp.overload(quad_edge_points_expanded, [_i2, _u, _a, _a, int, int, _w, int]),
        wp.overload(quad_vertex_points_expanded, [_i, _i, _i, _u, _a, _a, int, _w2, int]),
        wp.overload(tri_edge_points, [_i2, _u, _a, _a, int, _w, int]),
        wp.overload(tri_vertex_points, [_i, _i, _u, _a, _a, _w2, int]),
        wp.overload(explicit_rows, [_i, _i, _i, _w, _a, _a, int]),
    ]
