"""Options every command shares, spelled one way (docs/conventions.md).

Quantities carry their unit in the value (``--noise 0.01mm``, ``--tolerance 0.1um``,
``--dt 2ms``): :func:`quantity` parses one, :func:`length_option` a length.  The annotated
types below are the options' one spelling: ``-o/--output``, ``--out-dir``, ``--json``,
``--deg``, ``--si``, ``--seed``.
"""

from __future__ import annotations

import math
from typing import Annotated, overload

import typer

OutputOpt = Annotated[str | None, typer.Option("-o", "--output", help="The command's output "
                                               "file.")]
SiOpt = Annotated[bool, typer.Option("--si", help="Print lengths in m and angles in rad "
                                     "(default: mm and degrees).")]
DegOpt = Annotated[bool, typer.Option("--deg", help="Revolute joint values in degrees, in "
                                      "what is read and what is printed (default: rad; "
                                      "prismatic joints stay in m).")]
SeedOpt = Annotated[int, typer.Option("--seed", min=0, help="Seed of every random draw: the "
                                      "same command gives the same numbers.")]


@overload
def quantity(text: str, dimension: str | tuple[str, ...], option: str, *,
             positive: bool = False, minimum: float | None = None) -> float: ...
@overload
def quantity(text: str | None, dimension: str | tuple[str, ...], option: str, *,
             positive: bool = False, minimum: float | None = None) -> float | None: ...
def quantity(text: str | None, dimension: str | tuple[str, ...], option: str, *,
             positive: bool = False, minimum: float | None = None) -> float | None:
    """``"0.01mm" -> 1e-5`` (SI) for option ``option``; None stays None."""
    from kincal.units import parse_quantity

    if text is None:
        return None
    return parse_quantity(text, dimension, option, positive=positive, minimum=minimum)


def length_option(text: str | None, option: str) -> float | None:
    """A length option [m]: ``--tolerance 0.1um -> 1e-7``; None stays None."""
    return quantity(text, "length", option)


class Units:
    """How the console shows quantities: mm and degrees, or m and rad with ``--si``.

    Joint values follow ``--deg`` instead (rad, or deg with ``--deg``; prismatic in m),
    as they are read on the command line.
    """

    def __init__(self, si: bool = False, deg: bool = False) -> None:
        self.si, self.deg = si, deg
        self.length_unit = "m" if si else "mm"
        self.angle_unit = "rad" if si else "deg"
        self._lf = 1.0 if si else 1e3
        self._af = 1.0 if si else 180.0 / math.pi

    def length(self, v: float, digits: int = 4) -> str:
        """``v`` [m] as a number in the console's length unit (no unit)."""
        return f"{v * self._lf:.{digits if not self.si else digits + 3}f}"

    def angle(self, v: float, digits: int = 4) -> str:
        """``v`` [rad] as a number in the console's angle unit (no unit)."""
        return f"{v * self._af:.{digits if not self.si else digits + 2}f}"

    def scale(self, unit: str) -> tuple[float, str]:
        """SI ``unit`` (``m``, ``rad``, ``m/rad``...) -> (factor, console unit)."""
        if unit == "m":
            return self._lf, self.length_unit
        if unit == "rad":
            return self._af, self.angle_unit
        return 1.0, unit

    def value(self, v: float, unit: str, digits: int = 4) -> str:
        """``v`` in SI ``unit`` with the console's unit: ``"431.8000 mm"``."""
        f, u = self.scale(unit)
        return f"{v * f:.{digits + (3 if self.si and unit in ('m', 'rad') else 0)}f} {u}"

    def joint(self, v: float, kind: str, digits: int = 6) -> str:
        """A joint value as read on the command line: rad (deg with --deg) or m."""
        if kind == "revolute":
            return f"{math.degrees(v):.{digits}f}°" if self.deg else f"{v:.{digits + 3}f} rad"
        return f"{v:.{digits + 3}f} m"


#: The running command's console units (``--si``), read by the shared table printers.
CONSOLE = Units()


def use_si(si: bool, deg: bool = False) -> Units:
    """Set the console units of the running command (``--si``); returns them."""
    global CONSOLE
    CONSOLE = Units(si, deg)
    return CONSOLE


def console_units() -> Units:
    """The running command's console units (``--si``; set by :func:`use_si`)."""
    return CONSOLE


def console_quantity(key: str) -> tuple[str, float, str]:
    """``"position_m" -> ("position", 1e3, "mm")`` (``("position", 1.0, "m")`` with
    ``--si``): an error kind's name, SI-to-console factor and console unit."""
    name, _, unit = key.rpartition("_")
    f, u = CONSOLE.scale(unit)
    return name or key, f, u
