"""Gradients of a refinement: the refinement and limit evaluation as sparse linear operators (CSR matrices), their
adjoints evaluated with the transposed tables, and recording under wp.Tape.
"""
from .operators import (Adjoint, CSRMatrix, adjoint, evaluate, evaluate_vjp, limit_normals, limit_normals_vjp,
                        limit_points, limit_points_vjp, matrix)

__all__ = ["Adjoint", "CSRMatrix", "adjoint", "evaluate", "evaluate_vjp", "limit_normals", "limit_normals_vjp",
           "limit_points", "limit_points_vjp", "matrix"]
