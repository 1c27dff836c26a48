"""The package's layering: lower layers never import higher ones, and no import circles.

Every ``kincal`` import of every module counts, including imports inside functions
and under ``TYPE_CHECKING``: a lazy import is still a dependency.  The layers, from
the bottom (docs/architecture.md says what each one is):
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import kincal

SRC = Path(kincal.__file__).parent

#: Tiers from the bottom.  A module may import its own package and anything in a lower
#: tier; packages of the same tier do not import each other.
LAYERS: list[tuple[str, ...]] = [
    ("errors", "_version", "defaults"),
    ("spatial", "io", "units"),
    ("robots",),
    ("motion",),
    ("measure",),
    ("identify",),
    ("report", "compensation"),
    ("parallel",),
    ("workflow",),
    ("fleet",),
    ("cli",),
]
TIER = {name: i for i, names in enumerate(LAYERS) for name in names}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in SRC.rglob("*.py")}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """The kincal modules ``path`` imports (``from a import b`` counts ``a.b`` when it is a
    module, else ``a``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "kincal"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.rsplit(".", node.level - 1)[0] if node.level > 1 else pkg
                mod = f"{base}.{node.module}" if node.module else base
            else:
                mod = node.module or ""
            if mod.split(".")[0] != "kincal":
                continue
            for a in node.names:
                sub = f"{mod}.{a.name}"
                out.add(sub if sub in known else mod)
    return {m for m in out if m != name}


def _package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


GRAPH = {m: _imports(p, m, set(_modules())) for m, p in _modules().items()}


def test_every_module_has_a_layer() -> None:
    missing = sorted(m for m in GRAPH if m != "kincal" and _package(m) not in TIER)
    assert not missing, f"modules outside every layer (add them to LAYERS): {missing}"


def test_the_package_root_holds_only_shared_modules() -> None:
    root = sorted(p.stem for p in SRC.glob("*.py") if p.stem != "__init__")
    assert set(root) <= {"errors", "_version", "defaults", "spatial", "io", "units"}, root


@pytest.mark.parametrize("module", sorted(m for m in GRAPH if m != "kincal"))
def test_no_upward_or_sideways_import(module: str) -> None:
    own = _package(module)
    bad = []
    for dep in sorted(GRAPH[module]):
        if dep == "kincal":
            bad.append(f"{dep} (the package face imports everything; import the module)")
            continue
        other = _package(dep)
        if other != own and TIER[other] >= TIER[own]:
            bad.append(f"{dep} (layer {other!r} is not below {own!r})")
    assert not bad, f"{module} imports " + "; ".join(bad)


def test_no_import_circles() -> None:
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    circles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:                      # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in GRAPH.get(v, ()):
            if w not in GRAPH:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert not circles, f"import circles: {circles}"


def test_every_layer_says_what_it_is_and_what_it_may_import() -> None:
    for names in LAYERS:
        for name in names:
            init = SRC / name / "__init__.py"
            if not init.exists():
                continue
            doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8"))) or ""
            assert len(doc) > 80 and "import" in doc, f"{init}: describe the layer"
