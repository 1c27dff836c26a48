"""Units: one table for every file, option and printout, and quantities with their unit.

Every number a user gives kincal carries its unit, in a file's column header
(``x_mm``), in a robot file (``units: {length: mm, angle: deg}``) or in an option's
value (``--noise 0.01mm``, ``--position 400,0,300mm``).  This module holds the one
table of units (:data:`UNITS`: suffix -> dimension and factor to SI) and parses such
values:

* :func:`parse_quantity` - ``"0.01mm" -> 1e-5`` [m], ``"1arcsec" -> 4.85e-6`` [rad];
* :func:`parse_quantities` - ``"400,0,300mm"`` (one unit at the end for every bare
  value) or ``"10deg,20deg,0.1m"`` (a unit on each value), one dimension per value.

A value is converted to SI as ``value * factor`` (``UNITS[unit][1]``): m for lengths,
rad for angles, s for times, px for pixels.  Bad text is one
:class:`~kincal.errors.KincalError` line naming the option and the units it takes.

Layer rule: a shared root module; imports only :mod:`kincal.errors` (and the standard
library).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

from kincal.errors import KincalError

__all__ = ["UNITS", "DIMENSIONS", "MAX_SI", "units_of", "factor", "to_si", "from_si", "unit_list",
           "display_scale", "split_value", "parse_quantity", "parse_quantities"]

#: Every unit kincal reads or writes: ``{suffix: (dimension, factor to SI)}``.
UNITS: dict[str, tuple[str, float]] = {
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "um": ("length", 1e-6),
    "cm": ("length", 1e-2),
    "rad": ("angle", 1.0),
    "deg": ("angle", math.pi / 180.0),
    "mrad": ("angle", 1e-3),
    "urad": ("angle", 1e-6),
    "arcsec": ("angle", math.pi / 648000.0),
    "arcmin": ("angle", math.pi / 10800.0),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "px": ("pixel", 1.0),
    "1": ("dimensionless", 1.0),
}

#: The SI unit of each dimension (what kincal computes in).
DIMENSIONS: dict[str, str] = {"length": "m", "angle": "rad", "time": "s", "pixel": "px",
                              "dimensionless": "1"}

#: Largest magnitude of a value in SI (m, rad, s, px): beyond it a number is a typo or a
#: unit error (1000 km, 160 000 turns), and it would overflow the linear algebra.
MAX_SI = 1e6

#: Spellings people type, read as the unit on the right.
_ALIASES = {"µm": "um", "μm": "um", "°": "deg", "degree": "deg", "degrees": "deg",
            "sec": "s", "msec": "ms", "pixel": "px", "pixels": "px"}

_VALUE = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\s\d.+-][^\s]*)?\s*\Z")


def units_of(dimension: str) -> list[str]:
    """The units of one dimension, in table order (``units_of("length") -> [m, mm, um, cm]``)."""
    return [u for u, (d, _) in UNITS.items() if d == dimension]


def unit_list(dimension: str) -> str:
    """``"m, mm, um, cm"``: the units of ``dimension`` for messages."""
    return ", ".join(units_of(dimension))


def factor(unit: str, dimension: str | None = None, what: str = "unit") -> float:
    """The factor to SI of ``unit``, checking its dimension when ``dimension`` is given."""
    unit = _ALIASES.get(unit, unit)
    if unit not in UNITS or (dimension is not None and UNITS[unit][0] != dimension):
        dims = f"{_a(dimension)} unit ({unit_list(dimension)})" if dimension else \
            f"a unit ({', '.join(UNITS)})"
        raise KincalError(f"{what}: {unit!r} is not {dims}")
    return UNITS[unit][1]


def to_si(value: float, unit: str) -> float:
    """``value`` in ``unit`` -> SI (``to_si(2, "mm") == 0.002``)."""
    return value * factor(unit)


def from_si(value: float, unit: str) -> float:
    """SI ``value`` -> ``unit`` (``from_si(0.002, "mm") == 2``)."""
    return value / factor(unit)


def display_scale(unit: str) -> tuple[float, str]:
    """Factor and label to show an SI value to people: m -> mm, rad -> deg; any other
    unit as it is (``display_scale("m") == (1e3, "mm")``)."""
    if unit == "m":
        return 1e3, "mm"
    if unit == "rad":
        return 180.0 / math.pi, "deg"
    return 1.0, unit


def _a(word: str | None) -> str:
    word = word or "unit"
    return ("an " if word[0] in "aeiou" else "a ") + word


def split_value(text: str, option: str) -> tuple[float, str | None]:
    """``"0.01mm" -> (0.01, "mm")``, ``"3" -> (3.0, None)``; an error naming ``option``."""
    if re.fullmatch(r"\s*[-+]?(nan|inf(inity)?)\s*[^\s\d]*\s*", text, re.IGNORECASE):
        raise KincalError(f"option {option}: {text.strip()!r} is not finite")
    m = _VALUE.match(text)
    if m is None:
        raise KincalError(f"option {option}: {text.strip()!r} is not a number with a unit "
                          "(e.g. 0.01mm, 1arcsec, 2ms)")
    try:
        number = float(m.group(1))
    except (ValueError, OverflowError):       # pragma: no cover - the regex admits floats
        raise KincalError(f"option {option}: {m.group(1)!r} is not a number") from None
    if not math.isfinite(number):
        raise KincalError(f"option {option}: {text.strip()!r} is not finite")
    unit = m.group(2)
    if unit is not None:
        unit = _ALIASES.get(unit, unit)
        if unit not in UNITS:
            raise KincalError(f"option {option}: unknown unit {m.group(2)!r} in "
                              f"{text.strip()!r} (units: {', '.join(UNITS)})")
    return number, unit


def _dims_text(dims: Sequence[str]) -> str:
    uniq = list(dict.fromkeys(dims))
    return " or ".join(f"{_a(d)} ({unit_list(d)})" for d in uniq)


def parse_quantity(text: str, dimension: str | Sequence[str], option: str, *,
                   bare: str | None = None, minimum: float | None = None,
                   positive: bool = False) -> float:
    """A quantity with its unit -> its SI value.

    Args:
        text: ``"0.01mm"``, ``"1 arcsec"``, ``"2ms"``.
        dimension: the dimension the option takes (``"length"``), or several
            (``("length", "angle")``: either is accepted).
        option: the option's name, for messages (``"--noise"``).
        bare: the unit of a bare number (``None``: a bare number is an error naming the
            units the option takes).
        minimum: smallest allowed SI value (inclusive); ``positive``: must be > 0.

    Returns ``value * factor`` (m, rad, s, px).
    """
    dims = [dimension] if isinstance(dimension, str) else list(dimension)
    number, unit = split_value(text, option)
    unit = unit or bare
    if unit is None:
        raise KincalError(f"option {option}: {text.strip()!r} needs a unit: "
                          f"{_dims_text(dims)}, e.g. {text.strip()}{units_of(dims[0])[0]}")
    dim, f = UNITS[unit]
    if dim not in dims:
        raise KincalError(f"option {option}: {text.strip()!r} is {_a(dim)}; {option} takes "
                          f"{_dims_text(dims)}")
    value = number * f
    if abs(value) > MAX_SI:
        raise KincalError(f"option {option}: {text.strip()} is out of any robot's range (more "
                          f"than {MAX_SI:g} {DIMENSIONS[dim]})")
    if positive and not value > 0:
        raise KincalError(f"option {option}: must be > 0 (got {text.strip()})")
    if minimum is not None and value < minimum:
        raise KincalError(f"option {option}: must be >= {minimum:g} {DIMENSIONS[dim]} "
                          f"(got {text.strip()})")
    return value


def parse_quantities(text: str, dimensions: str | Sequence[str], option: str, *,
                     count: int | None = None, bare: str | Sequence[str | None] | None = None
                     ) -> list[float]:
    """Comma-separated quantities -> SI values, one dimension per value.

    ``"400,0,300mm"``: bare values take the unit written after them (back to the
    previous value with a unit: ``"400,0,300mm,0,90,0deg"``); ``"10deg,20deg,0.1m"``:
    each value its own.  ``dimensions`` is one dimension for
    all values or one per value (a value may also be ``"length|angle"``); ``bare`` the
    unit of values without one when the text has no unit at all (one for all, or one
    per value; None: an error).  ``count`` checks the number of values.
    """
    parts = [p.strip() for p in text.replace(";", ",").split(",")]
    if not text.strip() or any(not p for p in parts):
        raise KincalError(f"option {option}: {text.strip()!r} is not a comma-separated list "
                          "of values")
    if count is not None and len(parts) != count:
        raise KincalError(f"option {option}: expected {count} comma-separated values, got "
                          f"{len(parts)}")
    n = len(parts)
    dims = [dimensions] * n if isinstance(dimensions, str) else list(dimensions)
    bares = [bare] * n if bare is None or isinstance(bare, str) else list(bare)
    if len(dims) != n or len(bares) != n:
        raise KincalError(f"option {option}: expected {len(dims)} comma-separated values, got "
                          f"{n}")
    split = [split_value(p, option) for p in parts]
    # a unit written on a value also applies to the bare values before it (back to the
    # previous value that has a unit): "400,0,300mm,0,90,0deg"
    carried: list[str | None] = [None] * n
    unit_after: str | None = None
    for i in range(n - 1, -1, -1):
        if split[i][1] is not None:
            unit_after = split[i][1]
        carried[i] = unit_after
    out = []
    for (_, unit), after, p, d, b in zip(split, carried, parts, dims, bares, strict=True):
        allowed = d.split("|")
        if unit is None and after is not None and UNITS[after][0] in allowed:
            p += after
        out.append(parse_quantity(p, allowed, option, bare=b))
    return out
