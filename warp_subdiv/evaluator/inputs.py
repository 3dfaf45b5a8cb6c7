"""Vertex data handed in by a caller, checked once where it comes in (the refiner's and the gradients' entry
points); the evaluator's methods take data checked here and check it no further.

Host data (numpy arrays, lists) is checked by :func:`host_rows`, device arrays by
:func:`~warp_subdiv.evaluator.interop.device_rows` (shape and precision only: reading the values back to check
them would cost a transfer); :func:`vertex_rows` tells the two apart. The framework adapters (JAX, PyTorch) check
their arrays by shape and element type with :func:`shaped_rows` before they cast them, hand them to Warp or
declare a callback's result (under ``jax.jit`` a value has a shape and no data yet).
"""
from __future__ import annotations

import numpy as np

from ..errors import SubdivInputError
from ..mesh import DATA_BOUND, check_rows
from .interop import check_row_shape, device_rows

#: Element types (by name, as numpy, JAX and PyTorch spell them) of real numbers, which an adapter casts to the
#: refiner's precision as :func:`host_rows` takes any real numpy array: booleans, integers, floats.
_REAL_PREFIXES = ("bool", "int", "uint", "float", "bfloat")


def host_rows(data, rows: int, what: str, precision: str) -> np.ndarray:
    """Host data as a checked (rows, d) array: real, finite and within the bound of ``precision``
    (:func:`~warp_subdiv.mesh.check_rows`, whose errors name ``what``; (rows,) becomes (rows, 1)). A float
    numpy array of that shape is checked in one min/max pass and returned as it is."""
    bound = DATA_BOUND[precision]
    if (isinstance(data, np.ndarray) and data.ndim == 2 and data.dtype.kind == "f" and data.shape[0] == rows
            and data.shape[1] >= 1 and data.size):
        lo, hi = float(data.min()), float(data.max())  # NaN fails the comparisons, infinity the bound
        if -bound <= lo and hi <= bound and -np.inf < lo and hi < np.inf:
            return data
    return check_rows(data, rows, what, bound=bound)


def shaped_rows(shape, dtype_name: str, rows: int, what: str, *, positions: bool = False) -> tuple[int, bool]:
    """(width, one_d) of data known by its ``shape`` and element type ``dtype_name`` ("float32", "int64",
    "complex64": numpy's, JAX's or PyTorch's name without the "torch." prefix), checked as :func:`host_rows`
    checks a numpy array's shape and type: (rows,) or (rows, d) with d >= 1, of real numbers; ``positions``:
    (rows, 3) only (limit normals). The values are not read (checked where they are read, if at all)."""
    shape = tuple(int(s) for s in shape)
    name = str(dtype_name)
    if not name.startswith(_REAL_PREFIXES):
        raise SubdivInputError(f"{what} must hold real numbers, got dtype {name}", element="data", value=name)
    as_rows = (shape[0], 1) if len(shape) == 1 else shape
    check_row_shape(shape, as_rows, rows, what)
    if positions and as_rows[1] != 3:
        raise SubdivInputError(f"limit normals take ({rows}, 3) {what}, got {shape}", element="data", value=shape)
    return as_rows[1], len(shape) == 1


def vertex_rows(data, rows: int, what: str, device, precision: str) -> tuple:
    """(data, one_d): a device array as a checked (rows, d) Warp view (:func:`~.interop.device_rows`), or host
    data checked by :func:`host_rows`; one_d: the data was (rows,)."""
    view = device_rows(data, rows, what, device)
    if view is not None:
        return view, getattr(data, "ndim", 2) == 1 and view.shape[1] == 1
    return host_rows(data, rows, what, precision), np.ndim(data) == 1


def normal_control_for(normal_control, width: int) -> bool:
    """Whether prescribed normals apply to data of ``width`` columns (``normal_control`` None: the default, on
    for (n, 3) positions only); asking for them on other widths is refused."""
    if normal_control is None:
        return width == 3
    if normal_control and width != 3:
        raise SubdivInputError("normal control applies to (n, 3) positions only", option="normal_control")
    return normal_control
