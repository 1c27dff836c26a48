"""Five-bar commands and the helpers the generic show/fk/ik/calibrate commands call."""

from __future__ import annotations

import io
import json
import subprocess
import sys

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from kincal.cli import app
from kincal.cli.fivebar import calibrate_fivebar_file, fk_fivebar, ik_fivebar, show_fivebar
from kincal.parallel.files import load_fivebar

runner = CliRunner()


def test_fivebar_thesis_command_writes_plots_and_history(tmp_path) -> None:
    out = tmp_path / "plots"
    res = runner.invoke(app, ["fivebar-demo", "--out-dir", str(out), "--json",
                              str(tmp_path / "h.json")])
    assert res.exit_code == 0, res.output
    assert "converged: True" in res.output
    assert sorted(p.name for p in out.glob("*.png")) == [
        f"fivebar_demo_l{k}.png" for k in range(1, 5)]
    data = json.loads((tmp_path / "h.json").read_text())
    assert data["experiment"]["bases_m"] == {"base1": [1.0, 0.0], "base2": [-1.0, 0.0]}
    last = data["history"][-1]["params"]
    assert [round(last[k], 9) for k in ("l1", "l2", "l3", "l4")] == [1.86, 2.2, 2.8, 3.3]


def test_workspace_and_mobility_commands(tmp_path) -> None:
    res = runner.invoke(app, ["fivebar-workspace", "fivebar", "-o", str(tmp_path / "w.png"),
                              "--mode", "+-", "--resolution", "60"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "w.png").stat().st_size > 1000
    res = runner.invoke(app, ["fivebar-mobility"])
    assert res.exit_code == 0
    rows = [line for line in res.output.splitlines() if "│" in line]
    assert any(r.split("│")[-3].strip() == "4" for r in rows)  # dual SCARA, Kutzbach
    assert any(r.split("│")[-3].strip() == "2" for r in rows)  # planar five-bar


def test_show_fk_ik_helpers(tmp_path) -> None:
    robot = load_fivebar("fivebar_thesis")
    buf = io.StringIO()
    show_fivebar(robot, Console(file=buf, width=120))
    assert "base2.x" in buf.getvalue() and "F = 2" in buf.getvalue()
    fk_fivebar(robot, np.array([0.6, 2.5]), str(tmp_path / "fk.json"))
    fk = json.loads((tmp_path / "fk.json").read_text())
    assert np.allclose(fk["x"], robot.fk([0.6, 2.5]), atol=1e-15)
    ik_fivebar(robot, np.array(fk["x"]), "-+", str(tmp_path / "ik.json"))
    ik = json.loads((tmp_path / "ik.json").read_text())
    assert np.allclose(ik["q"], [0.6, 2.5], atol=1e-12) and ik["working_mode"] == "-+"
    ik_fivebar(robot, np.array(fk["x"]), "all", str(tmp_path / "all.json"))
    assert set(json.loads((tmp_path / "all.json").read_text())) == {"++", "+-", "-+", "--"}


def test_generic_show_and_fk_commands_reach_the_fivebar() -> None:
    res = runner.invoke(app, ["show", "fivebar"])
    assert res.exit_code == 0, res.output
    assert "offset2" in res.output
    res = runner.invoke(app, ["fk", "fivebar_thesis", "--q", "0.6,2.5", "--json", "-"])
    assert res.exit_code == 0, res.output
    assert np.allclose(json.loads(res.stdout)["x"], load_fivebar("fivebar_thesis").fk([0.6, 2.5]))


def test_simulate_then_calibrate_a_measurement_file(tmp_path) -> None:
    data = tmp_path / "d.csv"
    res = runner.invoke(app, ["fivebar-simulate", "fivebar_thesis", "-o", str(data),
                              "--set", "l1=1.86m", "--set", "l2=2200mm", "--set", "l3=2.8m",
                              "--set", "l4=3.3m", "--set", "offset1=0.01rad", "-n", "40"])
    assert res.exit_code == 0, res.output
    robot = load_fivebar("fivebar_thesis")
    result = calibrate_fivebar_file(robot, data, tmp_path / "cal.yaml", str(tmp_path / "c.json"),
                                    tmp_path / "c.html", "lm",
                                    console=Console(file=io.StringIO(), width=120))
    truth = robot.with_params({"l1": 1.86, "l2": 2.2, "l3": 2.8, "l4": 3.3, "offset1": 0.01})
    # the file stores 17 significant digits of deg and mm: recovery to ~1e-12
    assert np.max(np.abs(result.robot.param_values - truth.param_values)) < 1e-9
    calibrated = load_fivebar(tmp_path / "cal.yaml")
    assert calibrated.name == "fivebar_thesis_calibrated"
    assert np.allclose(calibrated.param_values, result.robot.param_values, atol=1e-15)
    assert json.loads((tmp_path / "c.json").read_text())["converged"] is True
    # the report is the serial robots' page: before/after table, parameters in mm / deg
    page = (tmp_path / "c.html").read_text()
    assert "Errors before and after calibration" in page and ">l1</td><td>mm</td>" in page
    assert "<h2>Estimated parameters against the iteration</h2>" in page


def test_fivebar_calibrate_prints_like_a_serial_robot(tmp_path, capsys) -> None:
    from cli_helpers import run

    data = tmp_path / "d.csv"
    assert runner.invoke(app, ["fivebar-simulate", "fivebar_thesis", "-o", str(data),
                               "--set", "l1=1.86m", "-n", "30"]).exit_code == 0
    code, out, err = run(capsys, "calibrate", "fivebar_thesis", "--data", data, "--report",
                         tmp_path / "r.html")
    assert code == 0, err
    assert "Errors before -> after calibration" in out and "position [mm]" in out
    assert "Estimated parameters (mm, deg)" in out
    l1 = next(ln for ln in out.splitlines() if ln.startswith("│ l1 "))
    assert "1860.0000" in l1 and "2000.0000" in l1           # mm, 4 decimals, not 12 digits


def test_user_errors_exit_with_code_2_and_one_line(tmp_path) -> None:
    bad = tmp_path / "fivebar.yaml"
    bad.write_text("kind: fivebar\nunits: {length: m, angle: rad}\n"
                   "links: {l1: 2, l2: 2, l3: -3, l4: 3}\n"
                   "bases: {base1: {x: 1, y: 0}, base2: {x: -1, y: 0}}\n")
    proc = subprocess.run([sys.executable, "-c", "from kincal.cli import main; main()",
                           "fivebar-workspace", str(bad), "-o", str(tmp_path / "w.png")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "error: fivebar.yaml: field 'links.l3' must be a positive number")
    assert not (tmp_path / "w.png").exists()


@pytest.mark.parametrize("method", ["gauss-newton", "lm"])
def test_calibrate_rejects_bad_method_and_files(tmp_path, method: str) -> None:
    from kincal.errors import KincalError, MeasurementFileError

    robot = load_fivebar("fivebar_thesis")
    with pytest.raises(KincalError, match="method must be one of"):
        calibrate_fivebar_file(robot, tmp_path / "x.csv", None, None, None, "newton")
    with pytest.raises(MeasurementFileError, match="no such measurement file"):
        calibrate_fivebar_file(robot, tmp_path / "missing.csv", None, None, None, method)
