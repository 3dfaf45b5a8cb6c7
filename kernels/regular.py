"""Kernels that compute the smooth rows of a step straight from a uniform level's index tables.

No stencil weights are stored for these rows: a face point is the mean of its corners, a smooth edge point
weighs its endpoints and its two wings, a smooth vertex point weighs itself and its ring, with weights
looked up per valence. Rows marked 0 in the ``regular`` masks are left for the explicit-stencil kernel.
Output layout: child vertices [vertex children, face children (Catmull-Clark), edge children].
"""
from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def quad_face_points(corner_vert: wp.array(dtype=wp.int32), src: wp.array(dtype=Any), dst: wp.array(dtype=Any),
                     first_row: int, quarter: wp.array(dtype=Any)):
    """Catmull-Clark face points of a quad level: dst[first_row + f] = mean of the face's 4 corners."""
    f = wp.tid()
    b = 4 * f
    dst[first_row + f] = quarter[0] * (src[corner_vert[b]] + src[corner_vert[b + 1]] + src[corner_vert[b + 2]]
                                       + src[corner_vert[b + 3]])


@wp.kernel
def quad_edge_points(neighbours: wp.array2d(dtype=wp.int32), regular: wp.array(dtype=wp.uint8),
                     src: wp.array(dtype=Any), dst: wp.array(dtype=Any), face_row: int, first_row: int,
                     weights: wp.array(dtype=Any)):
    """Smooth Catmull-Clark edge points: w0 (a + b) + w1 (f0 + f1), f the new face points already in dst.

    ``neighbours[e]`` = (a, b, face 0, face 1)."""
    e = wp.tid()
    if regular[e] == wp.uint8(0):
        return
    dst[first_row + e] = weights[0] * (src[neighbours[e, 0]] + src[neighbours[e, 1]]) + weights[1] * (
        dst[face_row + neighbours[e, 2]] + dst[face_row + neighbours[e, 3]])


@wp.kernel
def quad_vertex_points(offsets: wp.array(dtype=wp.int32), ring: wp.array(dtype=wp.int32),
                       ring_faces: wp.array(dtype=wp.int32), regular: wp.array(dtype=wp.uint8),
                       src: wp.array(dtype=Any), dst: wp.array(dtype=Any), face_row: int,
                       weights: wp.array2d(dtype=Any)):
    """Smooth Catmull-Clark vertex points: w0(n) v + w1(n) (sum of ring vertices + sum of new face points)."""
    v = wp.tid()
    if regular[v] == wp.uint8(0):
        return
    start = offsets[v]
    end = offsets[v + 1]
    acc = src[ring[start]] + dst[face_row + ring_faces[start]]
    for j in range(start + 1, end):
        acc += src[ring[j]] + dst[face_row + ring_faces[j]]
    n = end - start
    dst[v] = weights[n, 0] * src[v] + weights[n, 1] * acc


@wp.kernel
def tri_edge_points(neighbours: wp.array2d(dtype=wp.int32), regular: wp.array(dtype=wp.uint8),
                    src: wp.array(dtype=Any), dst: wp.array(dtype=Any), first_row: int,
                    weights: wp.array(dtype=Any)):
    """Smooth Loop edge points: w0 (a + b) + w1 (o0 + o1). ``neighbours[e]`` = (a, b, o0, o1), o the vertices
    opposite the edge."""
    e = wp.tid()
    if regular[e] == wp.uint8(0):
        return
    dst[first_row + e] = weights[0] * (src[neighbours[e, 0]] + src[neighbours[e, 1]]) + weights[1] * (
        src[neighbours[e, 2]] + src[neighbours[e, 3]])


@wp.kernel
def tri_vertex_points(offsets: wp.array(dtype=wp.int32), ring: wp.array(dtype=wp.int32),
                      regular: wp.array(dtype=wp.uint8), src: wp.array(dtype=Any), dst: wp.array(dtype=Any),
                      weights: wp.array2d(dtype=Any)):
    """Smooth Loop vertex points: (1 - n beta) v + beta (sum of ring vertices); ``ring`` lists the vertices."""
    v = wp.tid()
    if regular[v] == wp.uint8(0):
        return
    start = offsets[v]
    end = offsets[v + 1]
    acc = src[ring[start]]
    for j in range(start + 1, end):
        acc += src[ring[j]]
    n = end - start
    dst[v] = weights[n, 0] * src[v] + weights[n, 1] * acc


@wp.kernel
def explicit_rows(rows: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                  indices: wp.array(dtype=wp.int32), weights: wp.array(dtype=Any), src: wp.array(dtype=Any),
                  dst: wp.array(dtype=Any)):
    """dst[rows[i]] = sum_j weights[j] src[indices[j]] over row i of a CSR table."""
    i = wp.tid()
    start = offsets[i]
    acc = weights[start] * src[indices[start]]
    for j in range(start + 1, offsets[i + 1]):
        acc += weights[j] * src[indices[j]]
    dst[rows[i]] = acc


REGULAR_OVERLOADS = []
for _s, _v in ((wp.float32, wp.vec3f), (wp.float64, wp.vec3d)):
    _i = wp.array(dtype=wp.int32)
    _i2 = wp.array2d(dtype=wp.int32)
    _u = wp.array(dtype=wp.uint8)
    _a = wp.array(dtype=_v)
    REGULAR_OVERLOADS += [
        wp.overload(quad_face_points, [_i, _a, _a, int, wp.array(dtype=_s)]),
        wp.overload(quad_edge_points, [_i2, _u, _a, _a, int, int, wp.array(dtype=_s)]),
        wp.overload(quad_vertex_points, [_i, _i, _i, _u, _a, _a, int, wp.array2d(dtype=_s)]),
        wp.overload(tri_edge_points, [_i2, _u, _a, _a, int, wp.array(dtype=_s)]),
        wp.overload(tri_vertex_points, [_i, _i, _u, _a, _a, wp.array2d(dtype=_s)]),
        wp.overload(explicit_rows, [_i, _i, _i, wp.array(dtype=_s), _a, _a]),
    ]
