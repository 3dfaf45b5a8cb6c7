"""Sphinx configuration of the warp-subdiv documentation site: Markdown pages through MyST, the API reference from the
package's docstrings through autodoc.

Build from the repository root (the package is imported from the checkout, so PYTHONPATH names it):

    PYTHONPATH=$PWD .venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html
"""
from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import pkgutil
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from warp_subdiv.version import __version__  # noqa: E402

project = "warp-subdiv"
author = "the warp-subdiv authors"
copyright = "the warp-subdiv authors"
release = __version__
version = ".".join(__version__.split(".")[:2])

extensions = ["myst_parser", "sphinx.ext.autodoc"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]

html_theme = "furo" if importlib.util.find_spec("furo") else "alabaster"
html_title = f"warp-subdiv {release}"

# Relative links between the pages (``[USD](usd.md)``) work on GitHub and in the site alike; heading anchors let
# ``usd.md#primvars`` links resolve too.
myst_heading_anchors = 3

# The reference documents the package-level interfaces (each module's ``__all__``), never the modules they are
# defined in, which are internal and may be renamed. Cross references in docstrings to internal modules
# (:mod:`warp_subdiv.tables`) are left as plain text where no target exists: nitpicky mode stays off.
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# Members a public class inherits from the package's own private bases (Refiner's views, gradient and
# face-varying methods) are documented with it; what Python's and numpy's classes provide is not.
autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": False,
                           "inherited-members": "object,BaseException,Exception,Warning,UserWarning,str,int,Enum,"
                                                "tuple,dict,list"}
# The adapters import their framework at module level; a framework that is not installed is mocked.
autodoc_mock_imports = [name for name in ("torch", "jax", "jaxlib") if importlib.util.find_spec(name) is None]


def _comment_in_defining_module(package: str, name: str, value) -> list[str]:
    """The ``#:`` comment of a constant a package re-exports, read from the module that defines it.

    autodoc reads ``#:`` comments from the module it documents; a package's ``__init__`` only imports the constant,
    so the comment is looked up in the modules that bind the same object under that name, the package's own
    submodules first (a small int is the same object wherever it is bound). No module name is written here, so
    internal renames need no change."""
    from sphinx.pycode import ModuleAnalyzer

    import warp_subdiv

    names = [info.name for info in pkgutil.walk_packages(warp_subdiv.__path__, prefix="warp_subdiv.",
                                                         onerror=lambda _name: None)]
    for module_name in sorted(names, key=lambda m: not m.startswith(package + ".")):
        try:
            module = importlib.import_module(module_name)
        except Exception:  # noqa: BLE001 - an adapter whose framework is missing binds nothing to look at
            continue
        if getattr(module, name, None) is not value:
            continue
        try:
            docs = ModuleAnalyzer.for_module(module_name).find_attr_docs()
        except Exception:  # noqa: BLE001 - a module without readable source has no comment to offer
            continue
        if ("", name) in docs:
            return list(docs[("", name)])
    return []


def _document_reexported_constants(app, what, name, obj, options, lines):
    """A re-exported constant gets its defining module's comment instead of nothing, or instead of the docstring
    of its type (autodoc falls back to ``dict.__doc__`` for a dict)."""
    if what != "data":
        return
    own = [line for line in lines if line.strip()]
    type_doc = [line.strip() for line in (inspect.getdoc(type(obj)) or "").splitlines() if line.strip()]
    if not own or [line.strip() for line in own] == type_doc:
        package, _, attr = name.rpartition(".")
        lines[:] = _comment_in_defining_module(package, attr, obj)


def setup(app):
    app.connect("autodoc-process-docstring", _document_reexported_constants)
