"""Checks of the Warp arrays the gradient passes take: positions where normals need them, the refiner's
precision and device (a kernel must never see another: see :func:`check_data`)."""
from __future__ import annotations

import warp as wp

from ..errors import SubdivInputError


def check_positions(x: wp.array) -> None:
    """Refuse data other than vec3 positions (in the kernel view) where limit normals need them."""
    if x.ndim != 1:
        raise SubdivInputError(f"limit normals take (n, 3) positions, got {tuple(x.shape)}", element="data",
                               value=tuple(x.shape))


def check_data(adj, *arrays: wp.array) -> None:
    """Refuse arrays of another precision or device than the refiner's before a kernel sees them: the kernels
    are generic, and a launch mixing the data's precision with the records' registers an overload that does not
    compile; Warp keeps it, and every later load of that kernel module (any refiner's, in this process) fails."""
    for a in arrays:
        if a.dtype not in (adj.scalar, adj.vec):
            name = wp.types.type_repr(a.dtype)
            raise SubdivInputError(f"the refiner's gradients take {adj.precision} data (its precision), got {name}",
                                   element="data", value=name)
        if a.device != adj.device:
            raise SubdivInputError(f"data on {a.device}, the refiner on {adj.device}", element="data",
                                   value=str(a.device))
