"""Options every command shares, spelled one way (docs/conventions.md).

Quantities carry their unit in the value (``--noise 0.01mm``, ``--tolerance 0.1um``,
``--dt 2ms``): :func:`quantity` parses one, :func:`length_option` and
:func:`legacy_quantity` also accept an old unit-in-the-flag spelling
(``--tolerance-mm 1e-4``) kept as a hidden alias.  The annotated types below are the
options' one spelling: ``-o/--output``, ``--out-dir``, ``--json``, ``--deg``, ``--si``,
``--seed``.
"""

from __future__ import annotations

from typing import Annotated

import typer

from kincal.errors import KincalError

OutputOpt = Annotated[str | None, typer.Option("-o", "--output", help="The command's output "
                                               "file.")]
SiOpt = Annotated[bool, typer.Option("--si", help="Print lengths in m and angles in rad "
                                     "(default: mm and degrees).")]
DegOpt = Annotated[bool, typer.Option("--deg", help="Revolute joint values in degrees, in "
                                      "what is read and what is printed (default: rad; "
                                      "prismatic joints stay in m).")]
SeedOpt = Annotated[int, typer.Option("--seed", help="Seed of every random draw: the same "
                                      "command gives the same numbers.")]


def quantity(text: str | None, dimension: str | tuple[str, ...], option: str, *,
             positive: bool = False, minimum: float | None = None) -> float | None:
    """``"0.01mm" -> 1e-5`` (SI) for option ``option``; None stays None."""
    from kincal.units import parse_quantity

    if text is None:
        return None
    return parse_quantity(text, dimension, option, positive=positive, minimum=minimum)


def legacy_quantity(text: str | None, option: str, old: float | None, old_option: str,
                    dimension: str, old_unit: str, *, positive: bool = False,
                    minimum: float | None = None) -> float | None:
    """The SI value of ``option`` (a quantity with its unit) or of its hidden old
    spelling ``old_option`` (a bare number in ``old_unit``); both at once is an error."""
    if text is not None and old is not None:
        raise KincalError(f"give {option} (with its unit) or {old_option}, not both")
    if old is not None:
        text = f"{old!r}{old_unit}"
        option = old_option
    return quantity(text, dimension, option, positive=positive, minimum=minimum)


def length_option(text: str | None, option: str, old_mm: float | None = None,
                  old_option: str = "") -> float | None:
    """A length option [m]: ``--tolerance 0.1um``, or its old ``--tolerance-mm`` spelling."""
    return legacy_quantity(text, option, old_mm, old_option or f"{option}-mm", "length", "mm")
