"""Gradients of a refinement: the refinement and limit evaluation as sparse linear operators (CSR matrices), their
adjoints evaluated with the transposed tables, and recording under wp.Tape.

Refinement is linear in the control data (:mod:`~warp_subdiv.gradients.sparse`: :func:`matrix`); limit normals are
non-linear (normalised sums of cross products of two tangent masks). The backward pass applies the transposed
tables (built on the host in :mod:`~warp_subdiv.gradients.transposed`, kept on the device per refiner in
:mod:`~warp_subdiv.gradients.records`) in :class:`Adjoint` (:mod:`~warp_subdiv.gradients.passes`): no atomics, so
gradients are bitwise equal run to run and for any thread count. :mod:`~warp_subdiv.gradients.tape` has the entry
points on Warp arrays (recorded on a ``wp.Tape``) and on numpy arrays (vector-Jacobian products).
"""
from .passes import Adjoint, adjoint
from .sparse import CSRMatrix, matrix
from .tape import (evaluate, evaluate_vjp, evaluate_with_limits, limit_normals, limit_normals_vjp, limit_points,
                   limit_points_vjp, recording)

__all__ = ["Adjoint", "CSRMatrix", "adjoint", "evaluate", "evaluate_vjp", "evaluate_with_limits", "limit_normals",
           "limit_normals_vjp", "limit_points", "limit_points_vjp", "matrix", "recording"]
