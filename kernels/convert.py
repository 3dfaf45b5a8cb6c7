"""Copy of vertex data between device arrays of any strides and precisions (for data that stays on the device).

:func:`cast_rows` copies a (rows, width) array into another of the same shape, converting the scalar type:
control points that arrive as a device array (a Warp array, a torch or JAX tensor, any DLPack or
``__cuda_array_interface__`` producer, of either precision and any row stride) are copied into the level-0
buffer, and results into an output array the caller gives. The conversion is the C cast (round to nearest),
which is what numpy's ``astype`` does on the host path, so both paths give bitwise the same input.
"""
from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def cast_rows(src: wp.array2d(dtype=Any), dst: wp.array2d(dtype=Any)):
    """dst[i, j] = src[i, j] converted to dst's precision (one thread per row)."""
    i = wp.tid()
    for j in range(dst.shape[1]):
        dst[i, j] = dst.dtype(src[i, j])


# Every (source, destination) pair of precisions, compiled once with the module.
CONVERT_OVERLOADS = [
    wp.overload(cast_rows, [wp.array2d(dtype=s), wp.array2d(dtype=d)])
    for s in (wp.float32, wp.float64) for d in (wp.float32, wp.float64)
]
