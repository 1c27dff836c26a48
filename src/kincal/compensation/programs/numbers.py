"""Numbers as a robot program writes them: read one, and write another in the same style.

A program's numbers are rewritten in place, so each new number copies the style of
the one it replaces: sign (``+`` or not), a leading zero or none (``-.350`` as FANUC
writes), the number of decimals (at least ``min_decimals``, so a compensation of a few
micrometres is not rounded away), a decimal point or none, and exponent notation
(``1.5E+02``: its letter, sign and digits).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

#: A decimal number as robot languages write it (no hex, no inf/nan).
NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


@dataclass(frozen=True)
class NumberStyle:
    """How one number was written.

    Attributes:
        plus: a ``+`` before non-negative values.
        lead_zero: ``0.5`` rather than ``.5`` (for values below 1 in magnitude).
        decimals: digits after the point (of the mantissa, with an exponent).
        point: a decimal point was written (``1.`` counts, with 0 decimals).
        exp: ``""``, ``"e"`` or ``"E"``.
        exp_plus: ``e+02`` rather than ``e02``.
        exp_digits: minimum digits of the exponent.
        int_digits: digits before the point (of the mantissa, with an exponent).
    """

    plus: bool = False
    lead_zero: bool = True
    decimals: int = 0
    point: bool = False
    exp: str = ""
    exp_plus: bool = False
    exp_digits: int = 1
    int_digits: int = 1


def style_of(text: str) -> NumberStyle:
    """The :class:`NumberStyle` of ``text`` (a match of :data:`NUMBER`)."""
    t = text.strip()
    plus = t.startswith("+")
    body = t.lstrip("+-")
    i = max(body.find("e"), body.find("E"))
    mant, ex = (body, "") if i < 0 else (body[:i], body[i + 1:])
    point = "." in mant
    decimals = len(mant.split(".", 1)[1]) if point else 0
    lead_zero = not mant.startswith(".")
    int_digits = len(mant.split(".", 1)[0].lstrip("0")) or 1
    if not ex:
        return NumberStyle(plus, lead_zero, decimals, point, int_digits=int_digits)
    letter = "E" if "E" in body else "e"
    digits = ex.lstrip("+-")
    return NumberStyle(plus, lead_zero, decimals, point, letter, ex.startswith("+"), len(digits),
                       int_digits)


def format_number(value: float, style: NumberStyle, min_decimals: int = 0) -> str:
    """``value`` written in ``style`` with at least ``min_decimals`` decimals."""
    d = max(style.decimals, min_decimals)
    if style.exp:
        # significant digits: at least the original's, and enough for min_decimals absolute
        e10 = math.floor(math.log10(abs(value))) if value else 0
        d = max(style.decimals + style.int_digits - 1, e10 + min_decimals, 0)
        text = f"{value:.{d}e}"
        mant, ex = text.split("e")
        e = int(ex)
        digits = f"{abs(e):0{style.exp_digits}d}"
        sign = "-" if e < 0 else ("+" if style.exp_plus else "")
        body = mant.lstrip("-")
        if d == 0 and style.point:
            body += "."
        if not style.lead_zero and body.startswith("0."):
            body = body[1:]
        neg = mant.startswith("-")
        return ("-" if neg else ("+" if style.plus else "")) + body + style.exp + sign + digits
    text = f"{value:.{d}f}"
    neg = text.startswith("-")
    body = text.lstrip("-")
    if float(body) == 0.0:
        neg = False
    if d == 0 and style.point:
        body += "."
    if not style.lead_zero and body.startswith("0.") and len(body) > 2:
        body = body[1:]
    return ("-" if neg else ("+" if style.plus else "")) + body


def resolution(style: NumberStyle, min_decimals: int = 0) -> float:
    """Half a unit of the last written decimal (for a value without exponent)."""
    return 0.5 * 10.0 ** -max(style.decimals, min_decimals)


def same_when_written(old: float, new: float, style: NumberStyle, min_decimals: int) -> bool:
    """True when ``new`` written in the style reads back as ``old`` would: keep the text."""
    if not (math.isfinite(old) and math.isfinite(new)):
        return False
    return float(format_number(new, style, min_decimals)) == float(
        format_number(old, style, min_decimals))
