"""docs/architecture.md stays in step with the package: every layer is in its table, and
every module it names exists in the folder it is listed under."""

from __future__ import annotations

import re
from pathlib import Path

from test_layers import LAYERS

import kincal

SRC = Path(kincal.__file__).parent
PAGE = (Path(__file__).resolve().parents[1] / "docs" / "architecture.md").read_text()
_TABLE = PAGE.split("| tier | package |", 1)[1].split("\n\n", 1)[0]
ROWS = [line for line in _TABLE.splitlines() if re.match(r"\| \d+ \|", line)]


def test_every_layer_has_a_row_in_its_tier():
    for tier, names in enumerate(LAYERS):
        row = next((r for r in ROWS if r.startswith(f"| {tier} |")), None)
        assert row is not None, f"docs/architecture.md: no row for tier {tier}"
        for name in names:
            shown = f"`{name}/`" if (SRC / name).is_dir() else f"`{name}.py`"
            assert shown in row, f"docs/architecture.md: tier {tier} does not show {shown}"


def test_named_modules_exist():
    missing = []
    for row in ROWS:
        cells = [c.strip() for c in row.strip()[1:-1].split("|")]
        packages = re.findall(r"`(\w+)/`", cells[1])
        for name in re.findall(r"`(\w+)/?`", cells[3]):
            if not any((SRC / pkg / f"{name}.py").exists() or (SRC / pkg / name).is_dir()
                       for pkg in packages):
                missing.append(f"{packages}: {name}")
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"
