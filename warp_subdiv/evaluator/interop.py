"""Vertex data that is already a device array: Warp arrays, DLPack producers (torch, JAX, CuPy, ...) and
``__cuda_array_interface__`` producers, wrapped without a copy.

:func:`device_rows` tells host data (numpy arrays, lists: None) from a device array and returns the latter as
a Warp view of its memory, shaped (rows, width) of float32 or float64 with the producer's strides; the
evaluator copies it into its level-0 buffer on the device (a cast kernel, or ``np.copyto`` on the CPU), or
writes a result into it. Nothing here copies data or synchronises: a DLPack import orders the producer's work
before Warp's current stream of the device (the protocol's ``stream`` argument); a
``__cuda_array_interface__`` producer must have finished writing the data (the interface carries no stream
Warp waits on), and must keep it alive until the device work that reads it is done.

Device data is not checked for finite values (that would read it back to the host): a NaN refines to NaNs.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import SubdivInputError

#: DLPack device types whose memory the CPU can read (kDLCPU, kDLCUDAHost) and CUDA devices (kDLCUDA,
#: kDLCUDAManaged).
_DLPACK_CPU = (1, 3)
_DLPACK_CUDA = (2, 13)
_SCALARS = {np.dtype(np.float32): wp.float32, np.dtype(np.float64): wp.float64}


def is_device_array(obj) -> bool:
    """Whether ``obj`` is a device array this module wraps (not a numpy array, list or scalar)."""
    if isinstance(obj, wp.array):
        return True
    if isinstance(obj, (np.ndarray, np.generic, list, tuple)):
        return False
    return hasattr(obj, "__cuda_array_interface__") or (
        hasattr(obj, "__dlpack__") and hasattr(obj, "__dlpack_device__"))


def wrap(obj, device=None) -> wp.array | None:
    """A Warp array viewing ``obj``'s memory (no copy), or None when ``obj`` is host data (numpy, lists).

    ``device``: the CUDA device a ``__cuda_array_interface__`` pointer belongs to when the refiner's device is
    a CUDA device (the interface does not name one); else Warp's current CUDA device."""
    if isinstance(obj, wp.array):
        return obj
    if not is_device_array(obj):
        return None
    if hasattr(obj, "__dlpack__") and hasattr(obj, "__dlpack_device__"):
        kind = int(obj.__dlpack_device__()[0])
        if kind in _DLPACK_CPU + _DLPACK_CUDA:
            try:
                return wp.from_dlpack(obj)
            except Exception as exc:  # noqa: BLE001 (a producer Warp cannot import: say what it is)
                if not hasattr(obj, "__cuda_array_interface__"):
                    raise SubdivInputError(f"cannot import {type(obj).__name__} through DLPack: {exc}",
                                           element="data", value=type(obj).__name__) from None
    if hasattr(obj, "__cuda_array_interface__"):
        return _from_cuda_array_interface(obj, device)
    raise SubdivInputError(f"{type(obj).__name__} lives on a device warp-subdiv cannot read (DLPack device "
                           f"{tuple(obj.__dlpack_device__())}); pass a CPU or CUDA array", element="data",
                           value=type(obj).__name__)


def _from_cuda_array_interface(obj, device) -> wp.array:
    desc = obj.__cuda_array_interface__
    dtype = np.dtype(desc["typestr"])
    if dtype not in _SCALARS:
        raise SubdivInputError(f"device data must be float32 or float64, got {dtype}", element="data",
                               value=str(dtype))
    shape = tuple(int(s) for s in desc["shape"])
    strides = desc.get("strides")
    if strides is None:  # C-contiguous
        strides = tuple(int(np.prod(shape[i + 1:], dtype=np.int64)) * dtype.itemsize for i in range(len(shape)))
    dev = wp.get_device(device)
    if not dev.is_cuda:
        if wp.get_cuda_device_count() == 0:
            raise SubdivInputError("a __cuda_array_interface__ array needs CUDA, and Warp sees no CUDA device",
                                   element="data", value=type(obj).__name__)
        dev = wp.get_cuda_device()
    return wp.array(ptr=int(desc["data"][0]), dtype=_SCALARS[dtype], shape=shape, strides=tuple(strides),
                    device=dev)


def as_rows(arr: wp.array) -> wp.array:
    """A (rows, width) scalar view of a Warp array: (n,) scalars are (n, 1); (n,) vectors (vec3 ...) are
    (n, length); (n, d) scalars as they are. The memory and strides are the array's."""
    dtype = arr.dtype
    scalar = getattr(dtype, "_wp_scalar_type_", dtype)
    length = int(getattr(dtype, "_length_", 1)) if hasattr(dtype, "_wp_scalar_type_") else 1
    if hasattr(dtype, "_shape_") and len(dtype._shape_) != 1:
        raise SubdivInputError(f"device data must hold scalars or vectors, got {wp.types.type_repr(dtype)}",
                               element="data")
    if scalar not in (wp.float32, wp.float64):
        raise SubdivInputError(f"device data must be float32 or float64, got {wp.types.type_repr(scalar)}",
                               element="data", value=wp.types.type_repr(scalar))
    size = wp.types.type_size_in_bytes(scalar)
    if arr.ndim == 1:
        if length == 1 and scalar is dtype:
            shape, strides = (arr.shape[0], 1), (arr.strides[0], size)
        else:
            shape, strides = (arr.shape[0], length), (arr.strides[0], size)
    elif arr.ndim == 2 and scalar is dtype:
        return arr
    else:
        raise SubdivInputError(f"device data must have shape (n,) or (n, d), got {arr.shape} of "
                               f"{wp.types.type_repr(dtype)}", element="data", value=tuple(arr.shape))
    view = wp.array(ptr=arr.ptr, dtype=scalar, shape=shape, strides=strides, device=arr.device)
    view._ref = arr  # keep the viewed array alive with the view
    return view


def device_rows(obj, rows: int, what: str, device) -> wp.array | None:
    """``obj`` as a (rows, width) scalar Warp view when it is a device array (None for host data), checked:
    ``rows`` rows, width >= 1, float32 or float64."""
    arr = wrap(obj, device)
    if arr is None:
        return None
    view = as_rows(arr)
    check_row_shape(tuple(arr.shape), view.shape, rows, what)
    return view


def check_row_shape(shape: tuple, as_rows: tuple, rows: int, what: str) -> None:
    """Refuse data of ``shape`` (read as ``as_rows``, its (rows, width): 1-D data and vec3 rows differ from
    their shape) unless it is (rows, d) with d >= 1, in the words of the host data's check."""
    shape, as_rows = tuple(shape), tuple(as_rows)
    if len(as_rows) != 2 or as_rows[0] != rows or as_rows[1] < 1:
        raise SubdivInputError(f"{what} must have shape ({rows}, d) with d >= 1, got {shape}"
                               + ("" if as_rows == shape else f" ({as_rows} as rows)"),
                               element="data", value=shape)


def is_contiguous_rows(view: wp.array) -> bool:
    """Whether a (rows, width) view is row-major without gaps (a plain copy can replace the cast kernel)."""
    size = wp.types.type_size_in_bytes(view.dtype)
    return view.strides == (view.shape[1] * size, size)
