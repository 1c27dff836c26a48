"""Parameter names and the patterns that select them (``theta_offset[*]``, ``tracker.?``).

Shared by the solver (``free``, ``fixed``, ``stages``, ``prior``), the tolerances and
the command line's ``--free`` / ``--fix`` / ``--prior``.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Sequence

import numpy as np

from kincal.errors import KincalError

__all__ = ["match_names"]


def _regex(pattern: str) -> re.Pattern[str]:
    return re.compile(re.escape(pattern).replace(r"\*", ".*").replace(r"\?", ".") + r"\Z")


def match_names(names: Sequence[str], patterns: str | Iterable[str]) -> list[int]:
    """Indices of ``names`` matched by any of ``patterns`` (names or globs), in order.

    Only ``*`` and ``?`` are wildcards (``theta_offset[*]`` matches ``theta_offset[3]``).
    A pattern matching nothing raises a :class:`KincalError` naming close matches.
    """
    names = list(names)
    if isinstance(patterns, str):
        patterns = [patterns]
    hit = np.zeros(len(names), dtype=bool)
    for p in patterns:
        if p in names:
            hit[names.index(p)] = True
            continue
        rx = _regex(p)
        found = [i for i, n in enumerate(names) if rx.match(n)]
        if not found:
            close = difflib.get_close_matches(p, names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KincalError(f"no parameter matches {p!r}{hint}")
        hit[found] = True
    return [int(i) for i in np.flatnonzero(hit)]
