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
