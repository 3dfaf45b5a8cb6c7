"""Kernels for displacement tables (flatness, normal control) and limit normals.

A displacement table moves a few target points: out[i] = src[t_i] + sum_j w_j src[idx_j] (scalar weights),
or + sum_j w_j n_j (n_j . src[idx_j]) (projections onto given normals). Results go to a small buffer first
and are scattered back afterwards, so every row reads unmodified points.
"""
from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def displace_rows(
    targets: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    indices: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    src: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """One thread per moved point; points are vec3 or vec3d."""
    i = wp.tid()
    acc = src[targets[i]]
    for j in range(offsets[i], offsets[i + 1]):
        acc += weights[j] * src[indices[j]]
    out[i] = acc


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
    """One thread per moved point: each entry adds w * n (n . src[idx]) for its own normal n."""
    i = wp.tid()
    acc = src[targets[i]]
    for j in range(offsets[i], offsets[i + 1]):
        n = normals[normal_ids[j]]
        acc += (weights[j] * wp.dot(n, src[indices[j]])) * n
    out[i] = acc


@wp.kernel
def scatter_rows(targets: wp.array(dtype=wp.int32), values: wp.array(dtype=Any), dst: wp.array(dtype=Any)):
    """dst[targets[i]] = values[i]."""
    i = wp.tid()
    dst[targets[i]] = values[i]


@wp.kernel
def vertex_normals(
    vertex_offsets: wp.array(dtype=wp.int32),
    tangent_u: wp.array(dtype=Any),
    tangent_v: wp.array(dtype=Any),
    zero: Any,
    out: wp.array(dtype=Any),
):
    """Unit normal per vertex: the normalised sum of the unit normals tu x tv of its contributions."""
    i = wp.tid()
    acc = zero
    for j in range(vertex_offsets[i], vertex_offsets[i + 1]):
        acc += wp.normalize(wp.cross(tangent_u[j], tangent_v[j]))
    out[i] = wp.normalize(acc)


PROJECTION_OVERLOADS = []
for _s, _v in ((wp.float32, wp.vec3f), (wp.float64, wp.vec3d)):
    _i = wp.array(dtype=wp.int32)
    PROJECTION_OVERLOADS += [
        wp.overload(displace_rows, [_i, _i, _i, wp.array(dtype=_s), wp.array(dtype=_v), wp.array(dtype=_v)]),
        wp.overload(project_rows, [_i, _i, _i, wp.array(dtype=_s), _i, wp.array(dtype=_v), wp.array(dtype=_v),
                                   wp.array(dtype=_v)]),
        wp.overload(scatter_rows, [_i, wp.array(dtype=_v), wp.array(dtype=_v)]),
        wp.overload(vertex_normals, [_i, wp.array(dtype=_v), wp.array(dtype=_v), _v, wp.array(dtype=_v)]),
    ]
