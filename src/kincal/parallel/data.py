"""Five-bar measurement files: joint readings and measured end points, units in headers.

CSV with a header naming each column with its unit::

    # comment lines start with '#'
    q1_deg,q2_deg,x_mm,y_mm
    34.2,120.9,215.3,3051.2

Readings: ``q1_<unit>``, ``q2_<unit>`` (or ``beta1_``/``beta2_``), unit ``rad``
or ``deg`` (encoder readings; the model adds the offsets).  Points: ``x_<unit>``,
``y_<unit>``, unit ``m`` or ``mm``, measured J3 in the measurement frame.
Other columns (e.g. ``id``) are ignored.  Readers convert to SI; problems raise
:class:`MeasurementFileError` naming the file and line.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kincal.errors import MeasurementFileError
from kincal.io import read_text
from kincal.parallel.files import write_text_atomic
from kincal.robots.files import ANGLE_UNITS, LENGTH_UNITS

_QUANTITIES = {
    "q1": "angle",
    "q2": "angle",
    "beta1": "angle",
    "beta2": "angle",
    "x": "length",
    "y": "length",
}
_ALIASES = {"beta1": "q1", "beta2": "q2"}


@dataclass(frozen=True)
class FiveBarMeasurements:
    """Readings q (N,2) [rad], measured J3 x (N,2) [m], file lines of each row."""

    q: np.ndarray
    x: np.ndarray
    lines: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return int(self.q.shape[0])


def _columns(header: list[str], name: str, line: int) -> dict[str, tuple[int, float]]:
    """Map q1, q2, x, y to (column index, factor to SI); errors name the column."""
    found: dict[str, tuple[int, float]] = {}
    for k, raw in enumerate(header):
        col = raw.strip()
        base, _, unit = col.rpartition("_")
        if not base:
            base, unit = col, ""
        if col in _QUANTITIES:
            kind = _QUANTITIES[col]
            choices = ANGLE_UNITS if kind == "angle" else LENGTH_UNITS
            raise MeasurementFileError(
                f"line {line}: column '{col}' has no unit (use "
                + " or ".join(f"{col}_{u}" for u in choices)
                + ")",
                source=name,
            )
        if base not in _QUANTITIES:
            continue
        table = ANGLE_UNITS if _QUANTITIES[base] == "angle" else LENGTH_UNITS
        if unit not in table:
            raise MeasurementFileError(
                f"line {line}: column '{col}' has unknown unit '{unit}' (use {', '.join(table)})",
                source=name,
            )
        key = _ALIASES.get(base, base)
        if key in found:
            raise MeasurementFileError(f"line {line}: column '{col}' repeats {key}", source=name)
        found[key] = (k, table[unit])
    missing = [c for c in ("q1", "q2", "x", "y") if c not in found]
    if missing:
        raise MeasurementFileError(
            f"line {line}: missing column(s) {', '.join(missing)} with units "
            "(expected q1_deg|q1_rad, q2_deg|q2_rad, x_m|x_mm, y_m|y_mm)",
            source=name,
        )
    return found


def read_fivebar_csv(path: str | Path) -> FiveBarMeasurements:
    """Read a five-bar measurement CSV (see module doc) into SI arrays."""
    path = Path(path)
    name = path.name
    text = read_text(path, "measurement file", MeasurementFileError)
    numbered = [
        (k + 1, line)
        for k, line in enumerate(text.splitlines())
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise MeasurementFileError("no header line", source=name)
    rows = list(csv.reader(io.StringIO("\n".join(line for _, line in numbered))))
    header_line = numbered[0][0]
    cols = _columns(rows[0], name, header_line)
    if len(rows) < 2:
        raise MeasurementFileError(f"line {header_line}: header but no measurements", source=name)
    order = ("q1", "q2", "x", "y")
    values = np.empty((len(rows) - 1, 4))
    for r, row in enumerate(rows[1:]):
        line = numbered[r + 1][0]
        if len(row) != len(rows[0]):
            raise MeasurementFileError(
                f"line {line}: {len(row)} fields, the header has {len(rows[0])}", source=name
            )
        for c, key in enumerate(order):
            cell = row[cols[key][0]].strip()
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise MeasurementFileError(
                    f"line {line}: column '{rows[0][cols[key][0]].strip()}' value {cell!r} "
                    "is not a finite number",
                    source=name,
                )
            values[r, c] = v
    factors = np.array([cols[k][1] for k in order])
    values *= factors
    lines = np.array([n for n, _ in numbered[1:]])
    return FiveBarMeasurements(values[:, :2], values[:, 2:], lines, str(path))


def write_fivebar_csv(
    path: str | Path,
    q: np.ndarray,
    x: np.ndarray,
    angle_unit: str = "deg",
    length_unit: str = "mm",
    comment: str = "",
) -> Path:
    """Write readings q [rad] and points x [m] as CSV in the given units (atomic)."""
    a, s = 1.0 / ANGLE_UNITS[angle_unit], 1.0 / LENGTH_UNITS[length_unit]
    data = np.column_stack([np.asarray(q) * a, np.asarray(x) * s])
    buf = io.StringIO()
    for line in comment.splitlines():
        buf.write(f"# {line}\n")
    buf.write(f"q1_{angle_unit},q2_{angle_unit},x_{length_unit},y_{length_unit}\n")
    np.savetxt(buf, data, delimiter=",", fmt="%.17g")
    return write_text_atomic(path, buf.getvalue())
