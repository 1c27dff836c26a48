"""The documentation site documents what exists: every public name is on the API page,
and every page the site has is in its navigation."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

import kincal

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def test_every_public_name_is_on_the_api_page() -> None:
    text = (DOCS / "api.md").read_text(encoding="utf-8")
    # a Markdown heading, or mkdocstrings' root heading (``heading: "kincal.NAME"``, which
    # also shows the signature with its defaults: show_root_heading)
    headings = set(re.findall(r"^#+ `kincal\.(\w+)`", text, re.M))
    headings |= set(re.findall(r'^ +heading: "kincal\.(\w+)"', text, re.M))
    missing = [n for n in kincal.__all__ if n != "__version__" and n not in headings]
    assert not missing, f"docs/api.md has no section for: {', '.join(missing)}"
    assert "show_root_heading: false" not in text      # it hides the signature


def _nav_pages(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, dict):
        return [p for v in node.values() for p in _nav_pages(v)]
    return [p for v in node for p in _nav_pages(v)]


def test_every_page_is_in_the_navigation() -> None:
    config = yaml.load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"), Loader=yaml.BaseLoader)
    nav = set(_nav_pages(config["nav"]))
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    assert pages == nav, f"not in the nav: {sorted(pages - nav)}; missing: {sorted(nav - pages)}"


def test_the_readme_links_every_page_of_the_site() -> None:
    """The README is the short entry point: its documentation table links every page."""
    config = yaml.load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"), Loader=yaml.BaseLoader)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    linked = set(re.findall(r"\]\(docs/([\w/.-]+\.md)\)", readme))
    missing = sorted(set(_nav_pages(config["nav"])) - linked)
    assert not missing, f"README.md links no: {', '.join(missing)}"
    assert all((DOCS / p).is_file() for p in linked), "README.md links a page that is gone"


def test_the_readme_and_getting_started_give_the_same_two_commands() -> None:
    def commands(text: str) -> list[str]:
        block = re.search(r"```bash\n(.*?)```", text, re.S)
        assert block
        return block.group(1).splitlines()

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    assert commands(readme) == commands(index)
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert commands(readme)[1].split("&& ", 2)[-1] in ci   # pip install -e ".[test]" && pytest


def test_sphinx_roles_read_as_code_on_the_site() -> None:
    """The docs hook turns the docstrings' Sphinx roles into plain code (mkdocstrings
    renders Markdown, where ``:class:`` would show as text)."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("kincal_pages",
                                                  DOCS / "hooks" / "kincal_pages.py")
    assert spec is not None and spec.loader is not None
    hook = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = hook                  # its dataclasses look their module up
    spec.loader.exec_module(hook)
    html = ("A :class:<code>~kincal.robots.chain.Robot</code> from :func:"
            "<code>kincal.robots.files.load_serial_robot</code>; :mod:<code>kincal.io</code>.")
    assert hook.sphinx_roles(html) == ("A <code>Robot</code> from <code>kincal.robots.files"
                                       ".load_serial_robot</code>; <code>kincal.io</code>.")


def test_every_function_the_pages_name_exists() -> None:
    """A page that names a function (`` `name(...)` ``) names one kincal has: a renamed or
    removed function (e.g. a setup-merging helper that a refactoring replaced) must not
    stay in the prose. Mathematical notation, Python's and other libraries' functions are
    listed."""
    root = Path(__file__).resolve().parents[1]
    source = "\n".join(p.read_text(encoding="utf-8")
                       for p in (root / "src" / "kincal").rglob("*.py"))
    not_ours = {"sqrt", "least_squares", "Rx", "Ry", "Rz", "Tx", "Ty", "Tz", "exp", "log", "help",
                "floor"}
    missing = []
    #: pages about robot programs name the controllers' functions (``movej(...)``)
    controller_pages = {"robot-programs.md", "ur-calibration.md"}
    for page in sorted((root / "docs").rglob("*.md")):
        if page.name in controller_pages:
            continue
        for m in re.finditer(r"`(?:[A-Za-z_]\w*\.)*([A-Za-z_]\w*)\(", page.read_text("utf-8")):
            name = m.group(1)
            if name in not_ours:
                continue
            if not re.search(rf"^\s*(?:def|class) {name}\b|^{name}\b\s*[:=]", source, re.M):
                missing.append(f"{page.relative_to(root)}: {name}")
    assert not missing, "pages name functions kincal does not have:\n" + "\n".join(missing)
