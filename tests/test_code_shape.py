"""The shape of the code a maintainer reads: no long functions without a stated reason.

A function of more than :data:`MAX_LINES` lines (decorators and docstring included) is
hard to change safely; one that must be that long (a table of cases, a kernel kept in
one piece for speed) says why in its docstring, in a paragraph that starts with
``Why this is long:``.  The test reads every module of ``src/kincal`` with :mod:`ast`,
so it also fails on a long function nobody calls.
"""

from __future__ import annotations

import ast
from pathlib import Path

import kincal

SRC = Path(kincal.__file__).parent
MAX_LINES = 120
REASON = "Why this is long:"


def _long_functions(root: Path = SRC) -> list[str]:
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            length = (node.end_lineno or node.lineno) - start + 1
            if length > MAX_LINES and REASON not in (ast.get_docstring(node) or ""):
                out.append(f"{path.relative_to(root.parent)}:{node.lineno} {node.name} "
                           f"({length} lines)")
    return out


def test_no_function_is_long_without_a_reason() -> None:
    long = _long_functions()
    assert not long, (f"functions over {MAX_LINES} lines without '{REASON}' in their "
                      "docstring:\n  " + "\n  ".join(long))


def _module(name: str, lines: int, doc: str) -> str:
    """A module holding one decorated function of ``lines`` lines in all."""
    body = "\n".join(f"    x{i} = {i}" for i in range(lines - 3))
    return f'@staticmethod\ndef {name}():\n    """{doc}"""\n{body}\n'


def test_the_rule_sees_a_long_function_and_its_reason(tmp_path: Path) -> None:
    """On a synthetic package: a 130-line function (decorator included) is reported, the
    same function with the reason paragraph is not, a 120-line one is not."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "a.py").write_text(_module("long_one", 130, "Doc."))
    (pkg / "b.py").write_text(_module("explained", 130, f"Doc.\n\n    {REASON} a table."))
    (pkg / "c.py").write_text(_module("at_limit", 120, "Doc."))
    assert _long_functions(pkg) == ["pkg/a.py:2 long_one (130 lines)"]
