"""Helpers shared by the command modules: parsing vectors, loading robots, printing."""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console, Group, RenderableType
from rich.measure import Measurement
from rich.table import Column, Table

from kincal.errors import KincalError

if TYPE_CHECKING:
    import numpy as np

#: Options shared by every command that takes a robot or writes JSON.
RobotArg = Annotated[str, typer.Argument(metavar="ROBOT", help="Built-in robot name (see "
                                         "`kincal robots`), or a path to a YAML robot file "
                                         "or a URDF file.")]
BaseLink = Annotated[str | None, typer.Option("--base-link", help="URDF only: first link of "
                                              "the chain (default: the URDF root).")]
TipLink = Annotated[str | None, typer.Option("--tip-link", help="URDF only: last link of the "
                                             "chain (default: the single leaf).")]
JsonOut = Annotated[str | None, typer.Option("--json", help="Also write the result as JSON "
                                             "to this path ('-' for stdout).")]

#: Widest layout measured: a table's natural width is taken at this many columns.
_UNLIMITED = 10_000


def _content_range(console: Console, column: Column, show_header: bool) -> tuple[int, int]:
    """(narrowest, widest) text width of one column without padding: the narrowest is its
    longest word (narrower breaks a word), the widest its longest line."""
    options = console.options.update_width(_UNLIMITED)
    cells: list[RenderableType] = [*column.cells, *([column.header] if show_header else [])]
    sizes = [Measurement.get(console, options, c) for c in cells] or [Measurement(1, 1)]
    return max(m.minimum for m in sizes), max(m.maximum for m in sizes)


def _with_columns(table: Table, keep: list[int], part: int) -> Table:
    """A copy of ``table`` with the columns ``keep`` only (its title on the first part, its
    caption on every part, "(continued)" after the first)."""
    new = copy.copy(table)
    new.columns, new.rows = [], []
    if part:
        new.title = f"{table.title} (continued)" if table.title else "(continued)"
    for i in keep:
        c = table.columns[i]
        new.add_column(c.header, footer=c.footer, header_style=c.header_style,
                       footer_style=c.footer_style, style=c.style, justify=c.justify,
                       vertical=c.vertical, overflow=c.overflow, width=c.width,
                       min_width=c.min_width, max_width=c.max_width, ratio=c.ratio,
                       no_wrap=c.no_wrap, highlight=c.highlight)
    cells = [list(table.columns[i].cells) for i in keep]
    for r, row in enumerate(table.rows):
        new.add_row(*(col[r] for col in cells), style=row.style, end_section=row.end_section)
    return new


def fit_table(console: Console, table: Table, width: int | None = None) -> RenderableType:
    """``table`` laid out for a terminal ``width`` columns wide (default: the console's)
    without breaking a word: rich narrows the widest columns first and folds their words
    even when narrower columns have room.  Each column gets at least its longest word and
    the room left is shared in proportion to what each still lacks; a table whose longest
    words do not fit side by side is printed in parts, each repeating the first column."""
    width = width or console.width
    if not table.columns or table.width is not None:
        return table
    options = console.options.update_width(_UNLIMITED)
    whole = Measurement.get(console, options, table)
    if whole.maximum <= width:
        return table
    ranges = [_content_range(console, c, table.show_header) for c in table.columns]
    overhead = whole.maximum - sum(hi for _, hi in ranges)      # padding and borders
    room = width - overhead - sum(lo for lo, _ in ranges)
    if room >= 0:
        lack = [hi - lo for lo, hi in ranges]
        total = sum(lack)
        for c, (lo, hi), short in zip(table.columns, ranges, lack, strict=True):
            c.width = min(hi, lo + (room * short) // total) if total else hi
        return table
    per_column = overhead / len(ranges)
    parts: list[list[int]] = [[0]]
    used = ranges[0][0] + 2 * per_column
    for i in range(1, len(ranges)):
        need = ranges[i][0] + per_column
        if used + need > width and len(parts[-1]) > 1:
            parts.append([0])
            used = ranges[0][0] + 2 * per_column
        parts[-1].append(i)
        used += need
    if len(parts) == 1:            # a word longer than the terminal: it cannot stay whole
        return table
    return Group(*(fit_table(console, _with_columns(table, keep, k), width)
                   for k, keep in enumerate(parts)))


class KincalConsole(Console):
    """The console every command prints to: tables fit the terminal without a broken word
    (:func:`fit_table`), and the width follows the terminal and ``COLUMNS`` when printing
    (rich reads ``COLUMNS`` once, when the console is made: here at import, before a test
    runner or a shell script sets it)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if "width" not in kwargs and not self.is_jupyter:
            self._width = None                  # measured whenever it prints

    def print(self, *objects: Any, **kwargs: Any) -> None:
        """:meth:`rich.console.Console.print`, with every table fitted to the width."""
        width = kwargs.get("width") or self.width
        super().print(*(fit_table(self, o, width) if isinstance(o, Table) else o
                        for o in objects), **kwargs)


console = KincalConsole()
err_console = KincalConsole(stderr=True)


def parse_vector(text: str, option: str, length: int | None = None) -> np.ndarray:
    """Parse ``"1, 2.5, -3"`` into a float array; one-line error naming the option."""
    import numpy as np

    parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    try:
        v = np.array([float(p) for p in parts])
    except ValueError:
        bad = next(p for p in parts if not _is_float(p))
        raise KincalError(f"option {option}: {bad.strip()!r} is not a number") from None
    if not np.all(np.isfinite(v)):
        raise KincalError(f"option {option}: values must be finite")
    if length is not None and v.size != length:
        raise KincalError(f"option {option}: expected {length} comma-separated values, "
                          f"got {v.size}")
    return v


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def is_fivebar(robot: Any) -> bool:
    """Whether ``robot`` is the five-bar parallel robot (its commands differ)."""
    return type(robot).__name__ == "FiveBar"


def robot_arg(spec: str, base_link: str | None = None, tip_link: str | None = None) -> Any:
    """Load ROBOT (library name, YAML or URDF path) for a command."""
    from kincal.workflow.robots import load_any_robot

    return load_any_robot(spec, base_link=base_link, tip_link=tip_link)


def joint_vector(robot: Any, text: str, deg: bool, option: str = "--q") -> np.ndarray:
    """Joint values from the command line [rad / m]: each with its unit (``10deg,0.1m``)
    or bare: rad for revolute joints (deg with ``--deg``), m for prismatic ones."""
    import numpy as np

    from kincal.units import parse_quantities

    kinds = [j.kind for j in getattr(robot, "joints", ())] or ["revolute"] * int(robot.n)
    dims = ["angle" if k == "revolute" else "length" for k in kinds]
    bare = [("deg" if deg else "rad") if k == "revolute" else "m" for k in kinds]
    return np.array(parse_quantities(text, dims, option, count=len(kinds), bare=bare))


def point_vector(text: str, option: str, dims: list[str], deg: bool = False) -> np.ndarray:
    """A position / pose on the command line [m, rad]: ``400,0,300mm`` or
    ``0.4,0,0.3,0,90,0deg``; bare lengths in m, bare angles in rad (deg with ``--deg``)."""
    import numpy as np

    from kincal.units import parse_quantities

    bare = ["m" if d == "length" else ("deg" if deg else "rad") for d in dims]
    return np.array(parse_quantities(text, dims, option, count=len(dims), bare=bare))


def matrix_table(M: np.ndarray, title: str, row_labels: list[str] | None = None,
                 col_labels: list[str] | None = None, digits: int = 6) -> Table:
    """A rich table showing a matrix with optional labels."""
    t = Table(title=title, show_header=col_labels is not None)
    if row_labels is not None:
        t.add_column("")
    for c in col_labels or [""] * M.shape[1]:
        t.add_column(c, justify="right")
    for i, row in enumerate(M):
        cells = [f"{v: .{digits}f}" for v in row]
        t.add_row(*(([row_labels[i]] if row_labels else []) + cells))
    return t

