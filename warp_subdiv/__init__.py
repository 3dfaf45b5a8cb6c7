"""warp-subdiv: Loop and Catmull-Clark subdivision with the piecewise-smooth rules of Biermann, Levin and
Zorin (SIGGRAPH 2000) and an OpenSubdiv-compatible rule set.

Pipeline (docs/architecture.md): mesh -> options -> hierarchy (topology, rules, tables) ->
evaluator (Warp kernels) -> USD.
"""
from .version import __version__
from .errors import NonManifoldWarning, SubdivInputError
from .evaluator import default_device
from .mesh import Mesh
from .options import (Boundary, CreaseMethod, FaceVaryingMode, LoopBeta, Options, Precision, RuleSet, Scheme,
                      TriangleSubdivision)
from .refiner import Refined, Refiner, refine
from .limit import LimitEvaluation, LimitSurface
from .tiled import Tile, TileFaceVarying, refine_tiled
from .tiled_tessellation import tessellate_tiled

__all__ = ["Mesh", "Options", "Refiner", "Refined", "refine", "default_device", "SubdivInputError",
           "NonManifoldWarning", "Scheme", "RuleSet", "Boundary", "Precision", "LoopBeta", "CreaseMethod",
           "TriangleSubdivision", "FaceVaryingMode", "LimitSurface", "LimitEvaluation", "refine_tiled", "Tile",
           "TileFaceVarying", "tessellate_tiled", "__version__"]
