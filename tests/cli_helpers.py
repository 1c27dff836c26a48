"""Run the ``kincal`` console-script entry point in-process (fast: no interpreter start)."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from kincal.cli import main
from kincal.measure.files import write_table


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


def write_tracker(path: Any, robot: Any, q: Any, y: Any, name: str = "tracker") -> None:
    """A laser-tracker file (``instrument=position``, mm and deg) of points ``y``: (N, 3),
    one point per pose (columns x, y, z), or (N, K, 3), K markers (x1, y1, z1, x2 ...)."""
    y = np.asarray(y, dtype=float)
    y3 = y[:, None, :] if y.ndim == 2 else y
    K = y3.shape[1]
    cols = [(f"{c}{k + 1}" if K > 1 else c, y3[:, k, i], "length")
            for k in range(K) for i, c in enumerate("xyz")]
    write_table(path, q, cols, robot=robot, tags={"instrument": "position", "name": name},
                length_unit="mm", angle_unit="deg")
