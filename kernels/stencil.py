"""Gather-stencil kernels: out[i] = sum_j weights[j] * src[indices[j]], j over row i of a CSR table."""
from typing import Any

import warp as wp

# Forward evaluation only: no adjoint code (faster compiles, smaller modules).
wp.set_module_options({"enable_backward": False})


@wp.kernel
def apply_stencils_vec(
    offsets: wp.array(dtype=wp.int32),
    indices: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    src: wp.array(dtype=Any),
    dst: wp.array(dtype=Any),
):
    """One thread per output point; points are vectors (vec3 or vec3d), weights scalars of the same type."""
    i = wp.tid()
    start = offsets[i]
    end = offsets[i + 1]
    acc = weights[start] * src[indices[start]]
    for j in range(start + 1, end):
        acc += weights[j] * src[indices[j]]
    dst[i] = acc


# Explicit instantiations, so that ahead-of-time compilation (and the cache) holds every variant we launch.
STENCIL_OVERLOADS = []
for _scalar, _vec in ((wp.float32, wp.vec3f), (wp.float64, wp.vec3d)):
    STENCIL_OVERLOADS.append(
        wp.overload(
            apply_stencils_vec,
            {"offsets": wp.array(dtype=wp.int32), "indices": wp.array(dtype=wp.int32),
             "weights": wp.array(dtype=_scalar), "src": wp.array(dtype=_vec), "dst": wp.array(dtype=_vec)},
        )
    )
