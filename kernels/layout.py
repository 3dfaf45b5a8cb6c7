"""Vertex-data layouts shared by the kernels: one kernel source serves data of any width.

Vertex data reaches a kernel in one of two layouts, both views of the same row-major (rows, width) buffer:

* ``wp.array2d`` of float32/float64, shape (rows, width): the general buffer descriptor, as OpenSubdiv's
  BufferDescriptor (the data pointer is the offset, ``shape[1]`` the length, ``strides[0]`` the stride); a
  kernel loops over the columns, doing per column the arithmetic of the vec3 layout, in the same order.
* ``wp.array`` of vec3f/vec3d, shape (rows,): width-3 data (positions), one "column" of 3-vectors. On Warp's
  CPU backend the kernels run 1.5-4x faster on it than on three scalar columns (measured when the width
  descriptor came in), so width 3 keeps it, as an overload of the same kernels.

Kernels reach the data only through :func:`columns`, :func:`load` and :func:`store`, whose overloads pick the
layout at compile time; every kernel is instantiated for both layouts of both precisions.
"""
from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def columns(a: wp.array(dtype=Any)):
    """Columns of vec3 data: one (of 3-vectors)."""
    return 1


@wp.func
def columns(a: wp.array2d(dtype=Any)):  # noqa: F811 (an overload: Warp picks it by the argument's type)
    """Columns of (rows, width) data: its width."""
    return a.shape[1]


@wp.func
def load(a: wp.array(dtype=Any), row: int, col: int):
    """Row ``row`` of vec3 data (``col`` is 0)."""
    return a[row]


@wp.func
def load(a: wp.array2d(dtype=Any), row: int, col: int):  # noqa: F811
    """Column ``col`` of row ``row`` of (rows, width) data."""
    return a[row, col]


@wp.func
def store(a: wp.array(dtype=Any), row: int, col: int, value: Any):
    """Write row ``row`` of vec3 data (``col`` is 0)."""
    a[row] = value


@wp.func
def store(a: wp.array2d(dtype=Any), row: int, col: int, value: Any):  # noqa: F811
    """Write column ``col`` of row ``row`` of (rows, width) data."""
    a[row, col] = value


def data_types():
    """(scalar, layout array type) pairs every generic kernel is instantiated for: per precision the vec3
    layout and the (rows, width) layout."""
    out = []
    for scalar, vec in ((wp.float32, wp.vec3f), (wp.float64, wp.vec3d)):
        out += [(scalar, wp.array(dtype=vec)), (scalar, wp.array2d(dtype=scalar))]
    return out
