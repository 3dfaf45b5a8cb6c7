"""Gather-stencil kernel: dst[i] = sum_j weights[j] * src[indices[j]], j over row i of a CSR table.

Used for the steps of non-uniform levels (every row explicit) and for limit masks. Vertex data comes in
either layout of :mod:`warp_subdiv.kernels.layout` (vec3 rows, or (rows, width) scalars). ``row0`` is the
first row of the launch (a launch may cover a contiguous range of rows, see :mod:`.regular`).
"""
from typing import Any

import warp as wp

from .layout import columns, data_types, load, store

# Forward evaluation only: no adjoint code (faster compiles, smaller modules).
wp.set_module_options({"enable_backward": False})


@wp.kernel
def stencil_rows(
    offsets: wp.array(dtype=wp.int32),
    indices: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    src: Any,
    dst: Any,
    row0: int,
):
    """One thread per output row (row ``row0 + tid``); weights are scalars of the data's precision."""
    i = wp.tid() + row0
    start = offsets[i]
    end = offsets[i + 1]
    for c in range(columns(dst)):
        acc = weights[start] * load(src, indices[start], c)
        for j in range(start + 1, end):
            acc += weights[j] * load(src, indices[j], c)
        store(dst, i, c, acc)


# Explicit instantiations (both layouts of both precisions), so that the module compiles once whatever the
# data's width, and ahead-of-time compilation and the kernel cache hold every variant we launch.
STENCIL_OVERLOADS = []
for _scalar, _data in data_types():
    STENCIL_OVERLOADS.append(
        wp.overload(
            stencil_rows,
            {"offsets": wp.array(dtype=wp.int32), "indices": wp.array(dtype=wp.int32),
             "weights": wp.array(dtype=_scalar), "src": _data, "dst": _data, "row0": int},
        )
    )
