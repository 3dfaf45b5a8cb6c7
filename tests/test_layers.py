"""The package's floors (docs/architecture.md): every import in warp_subdiv/ and kernels/, at module level or
inside a function, goes to a lower floor; no module imports itself back through others; no private name is used
across packages; heavy or optional frameworks are imported only by the modules that adapt them.

The rules are read from the source with ``ast``, so a violation is caught even on a path no other test runs.
Each rule is also checked against a small planted violation, so a broken checker cannot pass silently.
"""
from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = "warp_subdiv"

#: Floor of each unit: a root module or a subpackage. A unit imports only from units on lower floors (and
#: from itself). The facade ``warp_subdiv/__init__.py`` is the top: nothing inside imports it.
FLOORS = {
    "warp_subdiv.version": 1, "warp_subdiv.errors": 1, "warp_subdiv.checks": 1, "warp_subdiv.options": 2, "warp_subdiv.mesh": 2,
    "warp_subdiv.runtime": 3,
    "warp_subdiv.rules": 4, "warp_subdiv.io": 4, "warp_subdiv.kernels": 4,
    "warp_subdiv.topology": 5,
    "warp_subdiv.tables": 6,
    "warp_subdiv.evaluator": 7,
    "warp_subdiv.limit": 8, "warp_subdiv.gradients": 8,
    "warp_subdiv.refiner": 9,
    "warp_subdiv.batch": 10, "warp_subdiv.tiled": 10,
    "warp_subdiv.tiled_tessellation": 11,
    "warp_subdiv.usd": 12,
    "warp_subdiv.render": 13, "warp_subdiv.jax": 13, "warp_subdiv.torch": 13,
    "warp_subdiv.cli": 14,
    "warp_subdiv.__main__": 15,
    "warp_subdiv": 16,
}

#: Units that must not import some lower units even so: the evaluator applies tables and never knows what a
#: crease or a level is.
NEVER = {"warp_subdiv.evaluator": {"warp_subdiv.topology", "warp_subdiv.rules"}}

#: Third-party modules allowed only in some units (imported anywhere else, at any depth, is a violation).
ONLY_IN = {
    "pxr": {"warp_subdiv.io", "warp_subdiv.usd", "warp_subdiv.render", "warp_subdiv.cli"},
    "torch": {"warp_subdiv.torch"},
    "jax": {"warp_subdiv.jax"},
    "jaxlib": {"warp_subdiv.jax"},
    "dask": {"warp_subdiv.usd"},
    "distributed": {"warp_subdiv.usd"},
    "warp": {"warp_subdiv.kernels", "warp_subdiv.evaluator", "warp_subdiv.gradients", "warp_subdiv.limit",
             "warp_subdiv.refiner", "warp_subdiv.batch", "warp_subdiv.usd", "warp_subdiv.cli", "warp_subdiv.render",
             "warp_subdiv.jax", "warp_subdiv.torch"},
    # state is passed as arguments; only the phase timer is ambient (like logging), in one module
    "contextvars": {"warp_subdiv.runtime.phases"},
}


def module_files() -> dict[str, tuple[pathlib.Path, bool]]:
    """Dotted module name -> (file, is a package's __init__), for warp_subdiv/ and kernels/ (installed as
    warp_subdiv.kernels)."""
    mods = {}
    for base, prefix in ((ROOT / "warp_subdiv", [PACKAGE]), (ROOT / "kernels", [PACKAGE, "kernels"])):
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base).with_suffix("").parts
            if base.name == "warp_subdiv" and rel and rel[0] == "kernels":
                continue  # the source checkout's link to ../kernels
            init = rel[-1] == "__init__"
            parts = prefix + list(rel[:-1] if init else rel)
            mods[".".join(parts)] = (path, init)
    return mods


def unit_of(module: str) -> str:
    """The floor unit of a module: its subpackage (warp_subdiv.X), or the root module itself."""
    parts = module.split(".")
    return ".".join(parts[:2])


class Import:
    def __init__(self, source: str, line: int, target: str, names: tuple[str, ...], third_party: bool):
        self.source, self.line, self.target, self.names, self.third_party = source, line, target, names, third_party

    def __repr__(self):
        return f"{self.source}:{self.line} -> {self.target} {self.names}"


def imports_of(module: str, tree: ast.AST, is_init: bool, known: set[str]) -> list[Import]:
    """Every import statement of ``module`` (any depth), resolved to absolute module names. ``from X import n``
    where X.n is a module counts as an import of X.n."""
    package = module if is_init else module.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                out.append(Import(module, node.lineno, alias.name, (), not alias.name.startswith(PACKAGE)))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith(PACKAGE):
                out.append(Import(module, node.lineno, target, (), True))
                continue
            plain = []
            for alias in node.names:
                if f"{target}.{alias.name}" in known:
                    out.append(Import(module, node.lineno, f"{target}.{alias.name}", (), False))
                else:
                    plain.append(alias.name)
            if plain:
                out.append(Import(module, node.lineno, target, tuple(plain), False))
    return out


def module_aliases(tree: ast.AST, module: str, is_init: bool, known: set[str]) -> dict[str, str]:
    """Local names bound to warp_subdiv modules by import statements (``from .. import x as y``)."""
    package = module if is_init else module.rsplit(".", 1)[0]
    names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package.split(".")[:len(package.split(".")) - node.level + 1]
            target = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:
                if f"{target}.{alias.name}" in known:
                    names[alias.asname or alias.name] = f"{target}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith(PACKAGE) and alias.asname:
                    names[alias.asname] = alias.name
    return names


def is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def violations(sources: dict[str, tuple[str, bool]]) -> list[str]:
    """Every broken rule among ``sources`` (module -> (source text, is __init__))."""
    known = set(sources)
    problems = []
    graph: dict[str, set[str]] = {m: set() for m in sources}
    for module, (text, is_init) in sources.items():
        tree = ast.parse(text)
        unit = unit_of(module)
        for imp in imports_of(module, tree, is_init, known):
            if imp.third_party:
                top = imp.target.split(".")[0]
                if top in ONLY_IN and unit not in ONLY_IN[top] and module not in ONLY_IN[top]:
                    problems.append(f"{imp.source}:{imp.line} imports {imp.target}, allowed only in "
                                    f"{sorted(ONLY_IN[top]) or 'no module'}")
                continue
            target_unit = unit_of(imp.target)
            if imp.target in known:
                graph[module].add(imp.target)
            if target_unit != unit:
                if target_unit not in FLOORS or unit not in FLOORS:
                    problems.append(f"{imp.source}:{imp.line} {unit} or {target_unit} has no floor")
                elif FLOORS[target_unit] >= FLOORS[unit]:
                    problems.append(f"{imp.source}:{imp.line} imports {imp.target} (floor {FLOORS[target_unit]}) "
                                    f"from floor {FLOORS[unit]}")
                if target_unit in NEVER.get(unit, ()):
                    problems.append(f"{imp.source}:{imp.line}: {unit} never imports {target_unit}")
                for name in imp.names:
                    if is_private(name):
                        problems.append(f"{imp.source}:{imp.line} uses {imp.target}.{name}, private to {target_unit}")
        aliases = module_aliases(tree, module, is_init, known)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
                target = aliases[node.value.id]
                if unit_of(target) != unit and is_private(node.attr):
                    problems.append(f"{module}:{node.lineno} uses {target}.{node.attr}, private to {unit_of(target)}")
    problems += [f"import circle: {' -> '.join(c)}" for c in circles(graph)]
    return problems


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each listed in order."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def current_sources() -> dict[str, tuple[str, bool]]:
    return {m: (path.read_text(), init) for m, (path, init) in module_files().items()}


def test_every_module_has_a_floor():
    missing = sorted({unit_of(m) for m in module_files()} - set(FLOORS))
    assert not missing, f"units without a floor in FLOORS: {missing}"


def test_the_package_keeps_its_floors():
    problems = violations(current_sources())
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("module, text, expected", [
    ("warp_subdiv.rules.weights", "from ..topology import Level\n", "floor"),
    ("warp_subdiv.topology.level", "def f():\n    from ..usd import refine_usd\n", "floor"),
    ("warp_subdiv.io.obj", "from ..runtime.threads import _pool\n", "private"),
    ("warp_subdiv.usd.refine", "from ..evaluator import evaluator as ev\nx = ev._lock\n", "private"),
    ("warp_subdiv.tables.stencil_builder", "import pxr\n", "allowed only"),
    ("warp_subdiv.topology.level", "import warp as wp\n", "allowed only"),
    ("warp_subdiv.mesh", "import contextvars\n", "allowed only"),
    ("warp_subdiv.runtime.threads", "import contextvars\n", "allowed only"),
    ("warp_subdiv.evaluator.evaluator", "from ..rules import SMOOTH\n", "never imports"),
    ("warp_subdiv.limit.surface", "from .. import LimitSurface\n", "floor"),
])
def test_the_checker_sees_a_planted_violation(module, text, expected):
    """Each rule fails on a violation added to the real sources (a checker that always passes is caught)."""
    sources = current_sources()
    own, init = sources.get(module, ("", False))
    sources[module] = (own + "\n" + text, init)
    assert any(expected in p for p in violations(sources)), expected


def test_the_checker_sees_a_planted_circle():
    sources = current_sources()
    sources["warp_subdiv.limit.planted_a"] = ("from . import planted_b\n", False)
    sources["warp_subdiv.limit.planted_b"] = ("def f():\n    from . import planted_a\n", False)
    assert any("circle" in p and "planted_a" in p for p in violations(sources))


def test_every_package_is_installed():
    """pyproject.toml lists the packages setuptools installs: a subpackage missing there is missing from the
    wheel (the checkout imports it, an installed copy does not)."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    packages = {m for m, (_, init) in module_files().items() if init}
    assert packages == listed, f"missing from pyproject: {sorted(packages - listed)}; extra: {sorted(listed - packages)}"
