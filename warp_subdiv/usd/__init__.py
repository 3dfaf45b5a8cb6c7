"""The USD bake: planning a stage's meshes (instancing, identical meshes, memory), refining each into an output
layer that composes over the input (what a renderer draws), batching small meshes, the compact vertex order,
distributed bakes on Dask and stitching their chunks.

:func:`refine_usd` is the entry point; :func:`plan` tells what a bake would do without doing it.
"""
from ..io.usd_read import SUBDIV_ATTRIBUTES
from ..runtime.estimate import MemoryGuardError, check_memory
from .output_layout import layout
from .planning import Plan, PrimReport, estimate_prim, make_refiner, options_for, plan
from .refine import Result, refine_usd
from .refinement import linear_vertex_data
from .distributed import bake, stitch

__all__ = ["plan", "refine_usd", "options_for", "make_refiner", "estimate_prim", "layout", "linear_vertex_data",
           "bake", "stitch", "check_memory", "Plan", "Result", "PrimReport", "MemoryGuardError", "SUBDIV_ATTRIBUTES"]
