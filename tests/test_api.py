"""The public API: ``import kincal`` is cheap and gives the names a notebook needs, and the
README's Python example runs against them."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import kincal

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.parametrize("name", [n for n in kincal.__all__ if n != "__version__"])
def test_every_public_name_resolves_to_a_documented_object(name: str) -> None:
    obj = getattr(kincal, name)
    assert callable(obj), name
    assert (obj.__doc__ or "").strip(), f"kincal.{name} has no docstring"
    assert name in dir(kincal)


def test_unknown_names_are_attribute_errors() -> None:
    with pytest.raises(AttributeError, match="no attribute 'calibrat'"):
        kincal.calibrat  # noqa: B018


def test_import_kincal_loads_no_numerics_and_help_lists_the_api() -> None:
    code = ("import sys, pydoc, kincal;"
            "print(sorted(m for m in ('numpy', 'scipy', 'matplotlib') if m in sys.modules));"
            "print(pydoc.render_doc(kincal, renderer=pydoc.plaintext))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    first, _, text = out.partition("\n")
    assert first == "[]"
    for name in ("load_robot", "read_measurements", "calibrate", "Calibration", "validate",
                 "compensate", "solve_ik", "plan_poses", "CalibrationResult"):
        assert name in text, name


def test_the_readme_python_example_runs_on_kincal_names_only(capsys) -> None:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert blocks, "the README has no Python example"
    for code in blocks:
        imports = re.findall(r"^\s*(?:from|import)\s+(\S+)", code, re.M)
        assert all(m in ("numpy", "kincal") for m in imports), imports
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    out = capsys.readouterr().out
    assert "cannot be told apart" in out and "Compensation(5/5" in out


def test_results_display_as_tables_in_a_notebook() -> None:
    rng = np.random.default_rng(1)
    robot = kincal.load_robot("puma560")
    truth = kincal.perturb_robot(robot, rng)
    q = kincal.random_configurations(robot, 30, rng)
    data = kincal.simulate_positions(truth, q, rng, noise_std=1e-5)
    result = kincal.calibrate(robot, [data], prior="tolerances")
    html = result._repr_html_()
    assert html.startswith("<table>") and "d[4]" in html and "MAP" in html
    assert "converged" in repr(result)
    comp = kincal.compensate(result.robot, truth.fk(q[:3]), nominal=robot)
    # nothing failed: the headline only, no empty "target / why it failed" table
    assert "3/3" in repr(comp) and "3/3" in comp._repr_html_()
    assert "<table>" not in comp._repr_html_()
    ik = kincal.solve_ik(robot, robot.fk(q[:2]))
    assert "2/2 solved" in repr(ik) and "<table>" not in ik._repr_html_()
    plan = kincal.plan_poses(robot, poses=12, candidates=120, grid=2)
    assert plan.q.shape == (12, 6) and "predicted RMS" in repr(plan)
    assert "<table>" in plan._repr_html_()


def test_names_in_html_displays_are_escaped() -> None:
    from kincal.io import html_table

    assert "&lt;b&gt;" in html_table(["<b>"], [["x"]])


def test_the_readme_python_example_is_the_tutorials() -> None:
    """The README's example and the Python tutorial's (examples/tutorials/python-api.py,
    run when the site is built) are one text, so neither can drift from the other."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    script = (README.parent / "examples" / "tutorials" / "python-api.py").read_text(
        encoding="utf-8")
    step = re.search(r"# --8<-- \[start:example\]\n(.*?)# --8<-- \[end:example\]", script, re.S)
    assert step and blocks == [step.group(1)]


def test_plan_repr_quotes_the_median_random_design_of_its_tables():
    import kincal

    plan = kincal.plan_poses(kincal.load_robot("puma560"), poses=12, candidates=120, grid=2)
    assert f"median random design {plan.random_prediction.rms * 1e3:.4g} mm" in repr(plan)
    assert f"{plan.random_prediction.rms * 1e3:.4g} mm)</p>" in plan._repr_html_()
