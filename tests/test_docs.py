"""The documentation's files stay linked: every relative link in README.md, BENCHMARKS.md and docs/*.md names a file
that exists (as GitHub shows them), every page of docs/ is in the site's table of contents, and the README links to
every page. The site itself is built with warnings as errors by CI (.ci/run), which also checks the anchors."""
from __future__ import annotations

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(p for p in DOCS.glob("*.md"))
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def links(path: pathlib.Path) -> list[str]:
    """Relative link targets of a Markdown file, outside code blocks and code spans."""
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    return [t for t in LINK.findall(text) if not re.match(r"[a-z]+:", t) and not t.startswith("#")]


@pytest.mark.parametrize("path", [ROOT / "README.md", ROOT / "BENCHMARKS.md", *PAGES], ids=lambda p: p.name)
def test_relative_links_name_existing_files(path):
    missing = [t for t in links(path) if not (path.parent / t.split("#", 1)[0]).exists()]
    assert not missing, f"{path.name} links to missing files: {missing}"


def test_every_page_is_in_the_table_of_contents():
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"^([\w-]+)$", "\n".join(re.findall(r"```\{toctree\}(.*?)```", index, re.S)), re.M))
    pages = {p.stem for p in PAGES} - {"index"}
    assert pages <= listed, f"pages missing from docs/index.md: {sorted(pages - listed)}"


def test_the_readme_links_every_page():
    linked = {pathlib.PurePosixPath(t.split("#", 1)[0]).name for t in links(ROOT / "README.md")}
    pages = {p.name for p in PAGES} - {"index.md", "benchmarks.md"}  # the site's landing page, BENCHMARKS.md itself
    assert pages <= linked, f"pages the README does not link: {sorted(pages - linked)}"


#: The public interfaces the API reference documents (docs/api.md).
DOCUMENTED = ["warp_subdiv", "warp_subdiv.usd", "warp_subdiv.gradients", "warp_subdiv.limit", "warp_subdiv.batch",
              "warp_subdiv.jax", "warp_subdiv.runtime.allocator", "warp_subdiv.io.obj"]


def undocumented(module_names):
    """Public names of ``module_names`` (their ``__all__``; for classes, their public methods and properties)
    without a docstring: the API reference would list them bare."""
    import importlib
    import inspect

    missing = []
    for name in module_names:
        module = importlib.import_module(name)
        if not (module.__doc__ or "").strip():
            missing.append(name)
        for public in getattr(module, "__all__", []):
            obj = getattr(module, public)
            if not (inspect.isclass(obj) or inspect.isfunction(obj)):
                continue
            if not (obj.__doc__ or "").strip():
                missing.append(f"{name}.{public}")
            if inspect.isclass(obj):
                own = {}  # public members defined by the package's classes, inherited ones included
                for base in reversed(obj.__mro__):
                    if base.__module__.split(".")[0] in (name.split(".")[0], obj.__module__.split(".")[0]):
                        own.update(vars(base))
                for attr, member in own.items():
                    if attr.startswith("_"):
                        continue
                    if isinstance(member, property):
                        doc = member.__doc__
                    elif inspect.isfunction(member) or isinstance(member, (staticmethod, classmethod)):
                        doc = inspect.getdoc(member)
                    else:
                        continue
                    if not (doc or "").strip():
                        missing.append(f"{name}.{public}.{attr}")
    return missing


def test_every_public_name_has_a_docstring():
    pytest.importorskip("jax")
    assert undocumented(DOCUMENTED) == []


def test_the_docstring_check_sees_a_bare_property(tmp_path, monkeypatch):
    (tmp_path / "bare_api.py").write_text(
        '"""A module."""\n__all__ = ["Thing"]\n\n\nclass Thing:\n    """A thing."""\n\n'
        '    @property\n    def size(self):\n        return 1\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    assert undocumented(["bare_api"]) == ["bare_api.Thing.size"]
