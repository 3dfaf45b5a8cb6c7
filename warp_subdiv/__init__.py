"""warp-subdiv: Loop and Catmull-Clark subdivision with the piecewise-smooth rules of Biermann, Levin and
Zorin (SIGGRAPH 2000) and an OpenSubdiv-compatible rule set.

Pipeline: mesh -> topology -> rules -> tables -> kernels (Warp) -> USD.
"""
import os as _os

# In a source checkout the kernels live in the top-level kernels/ folder; an installed package has them as
# warp_subdiv/kernels. Let the checkout import them under the same name.
_here = _os.path.dirname(_os.path.abspath(__file__))
if not _os.path.isdir(_os.path.join(_here, "kernels")) and _os.path.isfile(
    _os.path.join(_os.path.dirname(_here), "kernels", "__init__.py")
):
    __path__.append(_os.path.dirname(_here))  # noqa: F821 (package __path__)

from .errors import NonManifoldWarning, SubdivInputError  # noqa: E402
from .mesh import Mesh  # noqa: E402
from .refiner import Refined, Refiner, default_device, refine  # noqa: E402

__all__ = ["Mesh", "Refiner", "Refined", "refine", "default_device", "SubdivInputError", "NonManifoldWarning"]
__version__ = "0.1.0"
