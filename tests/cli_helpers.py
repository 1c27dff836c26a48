"""Run the ``kincal`` console-script entry point in-process (fast: no interpreter start)."""

from __future__ import annotations

import sys
from typing import Any

from kincal.cli import main


def invoke(*args: object) -> int:
    """Run ``kincal ARGS`` through :func:`kincal.cli.main`; return its exit code."""
    old = sys.argv
    sys.argv = ["kincal", *map(str, args)]
    try:
        main()
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv = old
    return 0


def run(capsys: Any, *args: object) -> tuple[int, str, str]:
    """:func:`invoke`, then what it printed: ``(exit code, stdout, stderr)``."""
    code = invoke(*args)
    out, err = capsys.readouterr()
    return code, out, err
