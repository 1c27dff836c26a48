"""CSV files of the instrument blocks, on top of :mod:`kincal.measure.files`.

The shared rules apply (units in every numeric header, joint columns named after the
robot's joints, one error line naming file/line/column, ``units``/``ignore``
options).  The instruments add:

* **text columns** without a unit -- ``station``, ``mode``, ``run``, ``plane`` -- read
  as labels;
* **constants on line 1**: a numeric quantity that is the same on every row may be
  given once as a tag instead of a column, with its unit, e.g.
  ``# kincal measurements: instrument=range; name=adm; sigma_mm=0.005``;
* block options as tags (``marker=own|tool``, ``mount=fixed|hand``).

**Columns the instrument does not read** follow the project rule of
:mod:`kincal.measure.files`: a column (or a line-1 constant) that looks like a joint,
a measurement or an instrument column -- the shared look-alikes (``q7``, ``x2``,
``sigma2`` ...) and every column name any instrument file uses (:data:`INSTRUMENT_WORDS`:
``az``, ``el``, ``range``, ``n_az``, ``d``, ``fx``, ``target_x``, ``station``, ``mode``,
``plane`` ... with or without a number) -- is an error naming the file, the line and
the column, unless it is listed in ``ignore``; plain bookkeeping columns
(``pose_id``, ``operator``) are skipped and reported in ``table.ignored``.  A text
column listed in ``ignore`` counts as absent.

One block per file.  Writers write the units they are asked (default SI) atomically.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.io import atomic_write_text
from kincal.measure.base import Provenance
from kincal.measure.files import (
    LOOKS_MEASURED,
    TAG_PREFIX,
    Field,
    MeasurementTable,
    glob_regex,
    joint_columns,
    read_table,
    split_unit,
)
from kincal.measure.instruments.common import label_index, label_index_raw
from kincal.units import UNITS

Array = NDArray[np.float64]

#: Column names (base names, without unit) used by some instrument file: in a file of
#: another instrument they are never dropped silently (a number suffix is allowed).
INSTRUMENT_WORDS = re.compile(
    r"(range|az|el|n_az|n_el|d|u|v|fx|fy|cx|cy|target_[xyz]|sigma|sigma_rot|station|mode"
    r"|run|plane|placement|point|socket)\d*", re.IGNORECASE)

#: Line-1 tags that are block options (no unit), never constants.
OPTION_TAGS = ("instrument", "name", "marker", "mount")


@dataclass
class BlockTable:
    """A parsed instrument file: the shared table plus text columns and line-1 tags."""

    table: MeasurementTable
    text: dict[str, list[str]]

    @property
    def q(self) -> Array:
        return self.table.q

    @property
    def tags(self) -> dict[str, str]:
        return self.table.tags

    @property
    def values(self) -> dict[str, Array]:
        return self.table.values

    def error(self, row: int, message: str) -> MeasurementFileError:
        """One-line error naming the file and the line of data row ``row``."""
        return self.at(int(self.table.lines[row]), message)

    def at(self, line: int, message: str) -> MeasurementFileError:
        """One-line error naming the file and ``line``."""
        return MeasurementFileError(f"line {line}: {message}", source=self.table.path)

    def option(self, key: str, default: str, choices: Sequence[str]) -> str:
        v = self.tags.get(key, default)
        if v not in choices:
            raise self.at(1, f"{key}={v!r} is not one of {', '.join(choices)}")
        return v


def _body(path: str | Path) -> list[tuple[int, str]]:
    text = Path(path).read_text(encoding="utf-8-sig")
    return [(i + 1, ln) for i, ln in enumerate(text.splitlines())
            if ln.strip() and not ln.lstrip().startswith("#")]


def read_block_table(path: str | Path, robot: Any, instrument: str, fields: Sequence[Field],
                     required: Sequence[str], text: Mapping[str, str | None],
                     units: Mapping[str, str] | None = None,
                     ignore: Sequence[str] = ()) -> BlockTable:
    """Read an instrument file.

    Args:
        fields: numeric observation columns (base name pattern and dimension).
        required: numeric bases that must be present (as a column or a line-1 constant).
        text: text columns ``{name: default}``; ``None`` as default means required.
    """
    t = read_table(path, robot, fields, units, ignore)
    tab = BlockTable(t, {})
    if t.tags and t.tags.get("instrument") != instrument:
        raise tab.at(1, f"instrument={t.tags.get('instrument')}, expected {instrument}")
    body = _body(path)
    header_line = body[0][0]
    names = [c.strip() for c in next(csv.reader([body[0][1]]))]
    dropped = {n for n in names if any(glob_regex(p).match(n) for p in ignore)}
    _check_unread(tab, names, dropped, fields, text, instrument, header_line)
    for tag, v in t.tags.items():
        base, unit = split_unit(tag)
        fld = next((f for f in fields if f.matches(base)), None)
        if tag in OPTION_TAGS or any(glob_regex(p).match(tag) for p in ignore):
            continue
        if fld is None and (unit is not None or INSTRUMENT_WORDS.fullmatch(base)):
            if _looks_like_data(base):
                raise tab.at(1, f"{tag} looks like a measurement constant, but this "
                                f"{instrument} file reads only: {_expected(fields, text)}; "
                                "list it in --ignore to drop it")
            t.ignored.append(f"{tag} (line 1)")
            continue
        if unit is None or fld is None:
            continue
        if UNITS[unit][0] != fld.dimension:
            raise tab.at(1, f"{tag}: unit {unit} is not a {fld.dimension}")
        if base in t.values:
            raise tab.at(1, f"{tag} repeats column {t.columns[base]}")
        try:
            value = float(v) * UNITS[unit][1]
        except ValueError:
            raise tab.at(1, f"{tag}={v!r} is not a number") from None
        if not np.isfinite(value):
            raise tab.at(1, f"{tag}={v!r} is not a finite number")
        t.values[base] = np.full(len(t), value)
        t.columns[base] = tag
    for base in required:
        if base not in t.values:
            fld = next(f for f in fields if f.matches(base))
            unit = {"length": "mm", "angle": "deg", "pixel": "px"}.get(fld.dimension, "1")
            raise tab.at(header_line, f"missing column {base!r} (with its unit, e.g. "
                                      f"{base}_{unit}; or {base}_{unit}=VALUE on line 1)")
    rows = list(csv.reader([ln for _, ln in body[1:]]))
    for key, default in text.items():
        if key in names and key not in dropped:
            k = names.index(key)
            vals = [r[k].strip() for r in rows]
            empty = [i for i, v in enumerate(vals) if not v]
            if empty:
                raise tab.error(empty[0], f"column {k + 1} ({key}) is empty")
            tab.text[key] = vals
        elif default is None:
            raise tab.at(header_line, f"missing column {key!r}")
        else:
            tab.text[key] = [default] * len(t)
    sig = t.values.get("sigma")
    if sig is not None and np.any(sig <= 0):
        i = int(np.argmax(sig <= 0))
        raise tab.error(i, f"column {t.columns['sigma']}: a standard deviation must be "
                           "positive")
    return tab


def _looks_like_data(base: str) -> bool:
    """True for names that look like a joint, a measurement or an instrument column."""
    return bool(LOOKS_MEASURED.fullmatch(base) or INSTRUMENT_WORDS.fullmatch(base))


def _expected(fields: Sequence[Field], text: Mapping[str, str | None]) -> str:
    return "; ".join([f.description or f.pattern for f in fields] + list(text))


def _check_unread(tab: BlockTable, names: Sequence[str], dropped: set[str],
                  fields: Sequence[Field], text: Mapping[str, str | None], instrument: str,
                  header_line: int) -> None:
    """Sort the columns :func:`read_table` did not read: the instrument's text columns
    are read (not reported); look-alikes of any instrument's columns are errors;
    the rest stay in ``table.ignored`` (bookkeeping, reported by the caller)."""
    t = tab.table
    kept: list[str] = []
    for name in t.ignored:
        if name in dropped:                         # --ignore: dropped on purpose
            kept.append(name)
            continue
        if name in text:                            # a text column of this instrument
            continue
        base = split_unit(name)[0]
        if _looks_like_data(base):
            col = list(names).index(name) + 1
            raise tab.at(header_line, f"column {col} ({name}) looks like an instrument "
                                      f"column, but this {instrument} file reads only: "
                                      f"{_expected(fields, text)}; list it in --ignore to "
                                      "drop it")
        kept.append(name)
    t.ignored[:] = kept


def write_block_table(path: str | Path, tags: Mapping[str, str], q: Array,
                      columns: Sequence[tuple[str, Any, str]], units: Mapping[str, str] | None,
                      robot: Any = None, comments: Sequence[str] = ()) -> None:
    """Write one block atomically.

    ``columns``: ``(base, values (N,), dimension)`` with dimension ``length``, ``angle``,
    ``pixel`` (SI values, converted to ``units``) or ``text`` (written as is).
    """
    u = dict(units or {})
    length, angle = u.get("length", "m"), u.get("angle", "rad")
    for unit, dim in ((angle, "angle"), (length, "length")):
        if unit not in UNITS or UNITS[unit][0] != dim:
            raise MeasurementFileError(f"unknown {dim} unit {unit!r}")
    unit_of = {"length": length, "angle": angle, "pixel": "px"}
    names: list[str] = []
    cells: list[list[str]] = []
    for k, (name, f) in enumerate(joint_columns(robot, q.shape[1], angle, length)):
        names.append(name)
        cells.append([repr(float(v)) for v in q[:, k] * f])
    for base, vals, dim in columns:
        if dim == "text":
            names.append(base)
            cells.append([str(v) for v in vals])
            continue
        unit = unit_of[dim]
        arr = np.asarray(vals, dtype=float).reshape(-1) / UNITS[unit][1]
        if not np.all(np.isfinite(arr)):
            raise MeasurementFileError(f"refusing to write non-finite values in {base!r}")
        names.append(f"{base}_{unit}")
        cells.append([repr(float(v)) for v in arr])
    lines = [TAG_PREFIX + " " + "; ".join(f"{k}={v}" for k, v in tags.items())]
    lines += [f"# {c}" for c in comments]
    lines.append(",".join(names))
    lines += [",".join(row) for row in zip(*cells, strict=True)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def one_block(blocks: Sequence[Any], instrument: str) -> Any:
    """The single block a file holds."""
    if len(blocks) != 1:
        raise MeasurementFileError(f"a {instrument} file holds one measurement block; got "
                                   f"{len(blocks)} (write each to its own file)")
    return blocks[0]


def per_group(tab: BlockTable, idx: NDArray[np.intp], values: Array, what: str) -> Array:
    """Per-group values (G, k) that must repeat identically on every row of the group."""
    values = np.asarray(values, dtype=float).reshape(len(idx), -1)
    G = int(idx.max()) + 1 if idx.size else 0
    first = np.array([int(np.argmax(idx == g)) for g in range(G)], dtype=np.intp)
    ref = values[first[idx]]
    bad = ~np.all(np.isclose(values, ref, rtol=1e-12, atol=0.0), axis=1)
    if np.any(bad):
        r = int(np.argmax(bad))
        raise tab.error(r, f"{what} differs from line {int(tab.table.lines[first[idx[r]]])} "
                           "of the same group (it must be constant per group)")
    return values[first]


def text_per_group(tab: BlockTable, idx: NDArray[np.intp], values: Sequence[str], what: str
                   ) -> list[str]:
    """Per-group text values that must be the same on every row of the group."""
    G = int(idx.max()) + 1 if len(idx) else 0
    first = np.array([int(np.argmax(idx == g)) for g in range(G)], dtype=np.intp)
    arr = np.array(values, dtype=str)
    bad = arr != arr[first[idx]]
    if np.any(bad):
        r = int(np.argmax(bad))
        f = int(first[idx[r]])
        raise tab.error(r, f"{what} {str(arr[r])!r} differs from {str(arr[f])!r} on line "
                           f"{int(tab.table.lines[f])} of the same group")
    return [str(arr[f]) for f in first]


# ---------------------------------------------------------------------------- readers' helpers
def label_column(tab: BlockTable, key: str, what: str) -> tuple[tuple[str, ...], NDArray[np.intp]]:
    """Labels of a text column, with the line of the first bad one in the error."""
    vals = tab.text[key]
    try:
        return label_index(vals, what, "file")
    except KincalError:
        distinct, idx = label_index_raw(vals)
        bad = [g for g, s in enumerate(distinct) if not _valid_label(s, what)]
        r = int(np.argmax(np.isin(idx, bad)))
        raise tab.error(r, f"column {key}: {what} label {vals[r]!r} must be a word (letters, "
                           "digits, _ - .) other than 'marker'") from None


def _valid_label(s: str, what: str) -> bool:
    try:
        label_index([s], what, "file")
    except KincalError:
        return False
    return True


def choice_column(tab: BlockTable, key: str, choices: Sequence[str]) -> list[str]:
    vals = tab.text[key]
    bad = ~np.isin(np.array(vals, dtype=str), list(choices))
    if np.any(bad):
        r = int(np.argmax(bad))
        raise tab.error(r, f"column {key}: {vals[r]!r} is not one of {', '.join(choices)}")
    return list(vals)


def build_block(tab: BlockTable, make: Any) -> Any:
    try:
        block = make()
        block.provenance = Provenance(str(tab.table.path), tab.table)  # the CLI lists the
        # bookkeeping columns it skipped
        return block
    except MeasurementFileError:
        raise
    except KincalError as exc:
        raise MeasurementFileError(str(exc), source=tab.table.path) from None


def block_name(tab: BlockTable, name: str | None, default: str) -> str:
    return name or tab.tags.get("name") or default


def block_tags(instrument: str, block: Any, **extra: str) -> dict[str, str]:
    return {"instrument": instrument, "name": block.name, **extra}


def stack_columns(values: Mapping[str, Array], keys: Sequence[str]) -> Array:
    return np.column_stack([values[k] for k in keys])

