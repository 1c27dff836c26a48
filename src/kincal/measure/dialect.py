"""CSV dialects of measurement files: the delimiter and the decimal mark, sniffed.

kincal writes ``,``-separated files with ``.`` decimals; instruments and spreadsheets
write others as well, and a file is read as it was recorded:

* **delimiter** ``,`` ``;`` or a tab: the one that splits the header into more than one
  column and every data row into as many fields as the header (checked on every row);
  ``,`` wins a tie (kincal's own files), then ``;``, then tab.
* **decimal mark** ``.`` or ``,`` (only with ``;`` or tab delimiters, as European
  instruments write ``0,5``): ``,`` when numeric cells use a comma and none uses a
  point. A file with both ``1.5`` and ``1,5`` cells is refused (one line naming the
  line and the column): a number must never be read as another.

:func:`sniff` returns the :class:`Dialect` and :func:`normalise` rewrites the body
lines in kincal's dialect (``,``, ``.``) so that the rest of the reader is the same for
every file; :attr:`Dialect.note` is the one line a command prints for an unusual file.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Sequence
from dataclasses import dataclass

from kincal.errors import MeasurementFileError

__all__ = ["Dialect", "sniff", "normalise", "split_line"]

#: Candidate delimiters, in the order they win a tie.
DELIMITERS = (",", ";", "\t")

_COMMA_DECIMAL = re.compile(r"[+-]?\d+,\d+([eE][+-]?\d+)?")
_POINT_DECIMAL = re.compile(r"[+-]?(\d+\.\d*|\.\d+)([eE][+-]?\d+)?")
_NAMES = {",": "comma", ";": "semicolon", "\t": "tab"}

#: Rows looked at to choose the delimiter (all rows are checked when read).
SNIFF_ROWS = 50


@dataclass(frozen=True)
class Dialect:
    """How a file's lines split into cells.

    Attributes:
        delimiter: ``,`` ``;`` or ``\\t``.
        decimal: ``.`` or ``,``.
    """

    delimiter: str = ","
    decimal: str = "."

    @property
    def usual(self) -> bool:
        """True for kincal's own dialect (``,``-separated, ``.`` decimals)."""
        return self.delimiter == "," and self.decimal == "."

    @property
    def note(self) -> str:
        """One line for an unusual dialect (``""`` for the usual one)."""
        if self.usual:
            return ""
        return (f"read as {_NAMES[self.delimiter]}-separated with '{self.decimal}' as the "
                "decimal mark")


def split_line(line: str, delimiter: str = ",") -> list[str]:
    """The cells of one CSV line (quotes honoured), stripped of blanks."""
    return [c.strip() for c in next(csv.reader([line], delimiter=delimiter), [])]


def _fits(header: str, rows: Sequence[str], delimiter: str) -> bool:
    width = len(split_line(header, delimiter))
    if width < 2:
        return False
    return all(len(split_line(r, delimiter)) == width for r in rows[:SNIFF_ROWS])


def sniff(header: str, rows: Sequence[str], source: str = "",
          header_line: int = 1, lines: Sequence[int] = ()) -> Dialect:
    """The dialect of a file from its header line and data lines.

    Args:
        header: the header line as written.
        rows: the data lines as written (comments and blank lines removed).
        source: the file, for messages.
        header_line: the header's line number (1-based), for messages.
        lines: the line number of each data row, for messages.

    A file whose header has a single column under every delimiter is read as ``,``
    (the usual messages then say what is wrong with it).
    """
    delimiter = next((d for d in DELIMITERS if _fits(header, rows, d)), None)
    if delimiter is None:
        # no delimiter fits every row: keep the one that splits the header best, so that
        # the error names the row whose field count differs
        counts = {d: len(split_line(header, d)) for d in DELIMITERS}
        delimiter = max(DELIMITERS, key=lambda d: (counts[d], -DELIMITERS.index(d)))
        if counts[delimiter] < 2:
            delimiter = ","
    if delimiter == ",":
        return Dialect(",", ".")
    comma_at = point_at = None
    for k, row in enumerate(rows):
        for c, cell in enumerate(split_line(row, delimiter)):
            if comma_at is None and _COMMA_DECIMAL.fullmatch(cell):
                comma_at = (k, c)
            elif point_at is None and _POINT_DECIMAL.fullmatch(cell):
                point_at = (k, c)
        if comma_at is not None and point_at is not None:
            k, c = max(comma_at, point_at)
            names = split_line(header, delimiter)
            line = lines[k] if k < len(lines) else header_line + 1 + k
            col = names[c] if c < len(names) else str(c + 1)
            raise MeasurementFileError(
                f"line {line}: column {c + 1} ({col}): the file has both ',' and '.' "
                "decimal marks; write every number with one of them", source=source)
    return Dialect(delimiter, "," if comma_at is not None else ".")


def normalise(lines: Sequence[str], dialect: Dialect) -> list[str]:
    """``lines`` rewritten in kincal's dialect (``,``-separated, ``.`` decimals).

    Each cell keeps its text except the decimal mark (``0,5`` -> ``0.5``, only for
    cells that are numbers written with a comma); cells are quoted when needed.
    """
    if dialect.usual:
        return list(lines)
    out = []
    for line in lines:
        cells = split_line(line, dialect.delimiter)
        if dialect.decimal == ",":
            cells = [c.replace(",", ".") if _COMMA_DECIMAL.fullmatch(c) else c for c in cells]
        buf = io.StringIO()
        csv.writer(buf, lineterminator="").writerow(cells)
        out.append(buf.getvalue())
    return out
