"""Fast start: the light commands import neither SciPy nor Matplotlib (nor pydantic), and
``kincal --help`` / ``--version`` not even NumPy.  Times are measured in
benchmarks/startup.py, never asserted here; what makes them is."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("scipy", "matplotlib", "pydantic", "dask", "sqlalchemy")

PROBE = """
import contextlib, io, json, sys
sys.argv = ["kincal", *json.loads(sys.argv[1])]
from kincal.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main()
    except SystemExit as e:
        code = e.code
    else:
        code = 0
print(json.dumps({"code": code, "modules": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def _modules(*args: str) -> tuple[int, set[str]]:
    out = subprocess.run([sys.executable, "-c", PROBE, json.dumps(list(args))],
                         capture_output=True, text=True, check=True).stdout
    doc = json.loads(out.strip().splitlines()[-1])
    return doc["code"], set(doc["modules"])


@pytest.mark.parametrize("args", [["robots"], ["show", "puma560"],
                                  ["fk", "puma560", "--q", "0,0.5,0,0,0,0"],
                                  ["jacobian", "puma560", "--q", "0,0.5,0,0,0,0"],
                                  ["calibrate", "--help"], ["fleet", "--help"]])
def test_light_commands_import_nothing_heavy(args):
    code, mods = _modules(*args)
    assert code in (0, None)
    assert not mods & set(HEAVY), sorted(mods & set(HEAVY))


@pytest.mark.parametrize("args", [["--help"], ["--version"]])
def test_help_and_version_do_not_import_numpy(args):
    code, mods = _modules(*args)
    assert code in (0, None)
    assert "numpy" not in mods and not mods & set(HEAVY)


def test_version(capsys):
    from cli_helpers import run

    from kincal._version import __version__

    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.strip() == f"kincal {__version__}"


def test_the_robust_loss_reference_needs_no_scipy_stats():
    """chi2.ppf(0.5, d) = 2 P^-1(d/2, 1/2), what the solver uses (scipy.special)."""
    import numpy as np
    from scipy import stats
    from scipy.special import gammaincinv

    d = np.arange(1.0, 60.0)
    np.testing.assert_allclose(2 * gammaincinv(d / 2, 0.5), stats.chi2.ppf(0.5, d),
                               rtol=1e-13)


def _np_misses(node: object, have: bool, where: str) -> list[str]:
    """Uses of ``np`` in function bodies under ``node`` without an import in scope."""
    import ast

    out = []
    for child in ast.iter_child_nodes(node):                  # type: ignore[arg-type]
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
            here = have or any(isinstance(n, ast.Import) and any(a.asname == "np"
                                                                  for a in n.names)
                               for stmt in child.body for n in ast.walk(stmt))
            for stmt in child.body:
                out += _np_misses(stmt, here, f"{where}:{child.name}")
                if not here and isinstance(stmt, ast.Name) and stmt.id == "np":
                    out.append(f"{where}:{child.name}:{stmt.lineno}")
        else:
            if isinstance(child, ast.Name) and child.id == "np" and not have:
                out.append(f"{where}:{child.lineno}")
            out += _np_misses(child, have, where)
    return out


def test_lazy_numpy_is_imported_where_it_is_used():
    """The command modules import NumPy inside the functions that use it (fast start); a
    function that uses ``np`` without importing it would fail only when it runs."""
    import ast
    from pathlib import Path

    import kincal.cli

    bad = []
    for path in sorted(Path(kincal.cli.__file__).parent.glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if any(isinstance(n, ast.Import) and any(a.asname == "np" for a in n.names)
               for n in tree.body):
            continue
        for fn in (n for n in tree.body if isinstance(n, ast.FunctionDef)):
            bad += _np_misses(ast.Module(body=[fn], type_ignores=[]), False, path.name)
    assert not bad, f"np used without `import numpy as np` in the function: {bad}"
