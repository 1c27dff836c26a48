"""Helpers shared by the command modules: parsing vectors, loading robots, printing."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

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

console = Console()
err_console = Console(stderr=True)


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

