"""The tables of a refinement, built from the topology and the rules: each step's stencils (smooth rows as index tables,
irregular rows as explicit stencils), the paper's projection tables (flatness, normal control, limit masks), the
hierarchy that builds them level by level, face-varying channels and the map from refined to control faces.

Numpy only: no Warp array and no USD prim. The evaluator applies these tables without knowing what a crease is.
"""
from .face_map import FaceMap, corners_to_vertices, vertices_used
from .facevarying import FaceVaryingChannel, check_value_indices, value_mesh
from .hierarchy import Hierarchy
from .stencil_builder import build_stencils
from .stencil_table import RegularTables, StencilTable, rows_of

__all__ = ["FaceMap", "FaceVaryingChannel", "Hierarchy", "RegularTables", "StencilTable", "build_stencils",
           "check_value_indices", "corners_to_vertices", "rows_of", "value_mesh", "vertices_used"]
