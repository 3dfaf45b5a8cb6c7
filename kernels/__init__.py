"""Warp kernels of warp-subdiv (installed as ``warp_subdiv.kernels``).

Kernels know nothing about creases or schemes: they apply tables that :mod:`warp_subdiv.tables` and
:mod:`warp_subdiv.tables.projections` built, to vertex data held as 2-D arrays (rows, width) of float32 or float64
(one compiled overload per precision serves every width).
"""
from .projection import (  # noqa: F401
    displace_rows,
    project_rows,
    scatter_rows,
    vertex_normals,
)
from .regular import (  # noqa: F401
    explicit_rows,
    quad_edge_points,
    quad_edge_points_expanded,
    quad_face_points,
    quad_vertex_points,
    quad_vertex_points_expanded,
    tri_edge_points,
    tri_vertex_points,
)
from .stencil import stencil_rows  # noqa: F401
from .limit import limit_evaluate  # noqa: F401
from .adjoint import (add_rows, explicit_rows_add, quad_face_adjoint, quad_vertex_adjoint,  # noqa: F401
                      tri_edge_adjoint, tri_ring_adjoint, tri_vertex_adjoint, vertex_normals_adjoint, zero_rows)
