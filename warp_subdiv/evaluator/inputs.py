"""Vertex data handed in by a caller, checked once where it comes in (the refiner's and the gradients' entry
points); the evaluator's methods take data checked here and check it no further.

Host data (numpy arrays, lists) is checked by :func:`host_rows`, device arrays by
:func:`~warp_subdiv.evaluator.interop.device_rows` (shape and precision only: reading the values back to check
them would cost a transfer); :func:`vertex_rows` tells the two apart.
"""
from __future__ import annotations

import numpy as np

from ..errors import SubdivInputError
from ..mesh import DATA_BOUND, check_rows
from .interop import device_rows


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
