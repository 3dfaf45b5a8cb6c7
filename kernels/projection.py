"""Kernels for displacement tables (flatness, normal control) and limit normals.

A displacement table moves a few target points: out[i] = src[t_i] + sum_j w_j src[idx_j] (scalar weights,
:func:`displace_rows`, data of any width), or + sum_j w_j n_j (n_j . src[idx_j]) (projections onto given
normals, :func:`project_rows`, positions only). Results go to a small buffer first and are scattered back
afterwards (:func:`scatter_rows`), so every row reads unmodified points.

:func:`displace_rows` and :func:`scatter_rows` take either layout of :mod:`warp_subdiv.kernels.layout`;
:func:`project_rows` and :func:`vertex_normals` (dot and cross products) take vec3 positions.
"""
from typing import Any

import warp as wp

from .layout import columns, data_types, load, store

wp.set_module_options({"enable_backward": False})


@wp.kernel
def displace_rows(
    targets: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    indices: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    src: Any,
    out: Any,
):
    """One thread per moved point (any width)."""
    i = wp.tid()
    t = targets[i]
    start = offsets[i]
    end = offsets[i + 1]
    for c in range(columns(out)):
        acc = load(src, t, c)
        for j in range(start, end):
            acc += weights[j] * load(src, indices[j], c)
        store(out, i, c, acc)


@wp.kernel
def project_rows(
    targets: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    indices: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    normal_ids: wp.array(dtype=wp.int32),
    normals: wp.array(dtype=Any),
    src: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """One thread per moved point of vec3 positions: each entry adds w * n (n . src[idx]) for its own
    normal n."""
    i = wp.tid()
    acc = src[targets[i]]
    for j in range(offsets[i], offsets[i + 1]):
        n = normals[normal_ids[j]]
        acc += (weights[j] * wp.dot(n, src[indices[j]])) * n
    out[i] = acc


@wp.kernel
def scatter_rows(targets: wp.array(dtype=wp.int32), values: Any, dst: Any):
    """dst[targets[i]] = values[i] (any width)."""
    i = wp.tid()
    for c in range(columns(dst)):
        store(dst, targets[i], c, load(values, i, c))


@wp.func
def smallest_normal(like: wp.float32) -> wp.float32:
    """The smallest normal float32 (2^-126): a squared length below it has lost precision to underflow."""
    return wp.float32(1.1754943508222875e-38)


@wp.func
def smallest_normal(like: wp.float64) -> wp.float64:  # noqa: F811 (Warp overloads a function by its types)
    """The smallest normal float64 (2^-1022)."""
    return wp.float64(2.2250738585072014e-308)


@wp.func
def unit_cross(u: Any, v: Any):
    """normalize(u x v) whatever the scale of u and v (zero where they are parallel or one is zero).

    The squared length of u x v is of the order of |u|^2 |v|^2: positions near 1e10 in float32 (1e80 in float64)
    overflow it, and near 1e-10 (1e-80) underflow it, and the plain normalisation gives (0, 0, 0). There (only
    there: elsewhere the plain formula runs, its results unchanged) each tangent is divided by its largest
    component first, and the cross product by its own, so every value stays near 1."""
    n = wp.cross(u, v)
    length_sq = wp.length_sq(n)
    if wp.isfinite(length_sq) and length_sq >= smallest_normal(length_sq):
        return wp.normalize(n)
    scale_u = wp.max(wp.abs(u))
    scale_v = wp.max(wp.abs(v))
    if scale_u == 0.0 or scale_v == 0.0:
        return n  # a zero tangent: no normal (n is zero)
    w = wp.cross(u / scale_u, v / scale_v)
    largest = wp.max(wp.abs(w))
    if largest == 0.0:
        return w
    return wp.normalize(w / largest)


@wp.kernel
def vertex_normals(
    vertex_offsets: wp.array(dtype=wp.int32),
    tangent_u: wp.array(dtype=Any),
    tangent_v: wp.array(dtype=Any),
    zero: Any,
    out: wp.array(dtype=Any),
):
    """Unit normal per vertex (vec3): the normalised sum of the unit normals tu x tv of its contributions
    (:func:`unit_cross`: at any scale of the positions); where they cancel exactly, the first non-zero one
    (docs/rules.md section 9)."""
    i = wp.tid()
    acc = zero
    first = zero
    for j in range(vertex_offsets[i], vertex_offsets[i + 1]):
        n = unit_cross(tangent_u[j], tangent_v[j])
        if wp.length_sq(first) == wp.length_sq(zero):
            first = n
        acc += n
    if wp.length_sq(acc) == wp.length_sq(zero):
        acc = first
    out[i] = wp.normalize(acc)


# Explicit instantiations, so that the module compiles once whatever the data's width: the generic kernels for
# both layouts of both precisions, the vec3 ones for both precisions.
PROJECTION_OVERLOADS = []
_i = wp.array(dtype=wp.int32)
for _s, _a in data_types():
    PROJECTION_OVERLOADS += [
        wp.overload(displace_rows, [_i, _i, _i, wp.array(dtype=_s), _a, _a]),
        wp.overload(scatter_rows, [_i, _a, _a]),
    ]
for _s, _v in ((wp.float32, wp.vec3f), (wp.float64, wp.vec3d)):
    _a = wp.array(dtype=_v)
    PROJECTION_OVERLOADS += [
        wp.overload(project_rows, [_i, _i, _i, wp.array(dtype=_s), _i, _a, _a, _a]),
        wp.overload(vertex_normals, [_i, _a, _a, _v, _a]),
    ]
