"""Five-bar commands and the helpers the generic show/fk/ik/calibrate commands call."""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from kincal.cli import app
from kincal.cli.fivebar import fk_fivebar, ik_fivebar, show_fivebar
from kincal.parallel.file_calibration import calibrate_fivebar_file, write_fivebar_outputs
from kincal.parallel.files import load_fivebar

runner = CliRunner()


def test_fivebar_reference_command_writes_plots_and_history(tmp_path) -> None:
    out = tmp_path / "plots"
    res = runner.invoke(app, ["fivebar-demo", "--out-dir", str(out), "--json",
                              str(tmp_path / "h.json")])
    assert res.exit_code == 0, res.output
    assert "converged: True" in res.output
    assert sorted(p.name for p in out.glob("*.png")) == [
        f"fivebar_demo_l{k}.png" for k in range(1, 5)]
    assert re.search(r"largest length error \S+ mm", res.output)    # lengths in mm
    data = json.loads((tmp_path / "h.json").read_text())
    assert data["trust"]["trusted"] is True
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
    robot = load_fivebar("fivebar_reference")
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
    res = runner.invoke(app, ["fk", "fivebar_reference", "--q", "0.6,2.5", "--json", "-"])
    assert res.exit_code == 0, res.output
    assert np.allclose(json.loads(res.stdout)["x"],
                       load_fivebar("fivebar_reference").fk([0.6, 2.5]))


def test_simulate_then_calibrate_a_measurement_file(tmp_path) -> None:
    data = tmp_path / "d.csv"
    res = runner.invoke(app, ["fivebar-simulate", "fivebar_reference", "-o", str(data),
                              "--set", "l1=1.86m", "--set", "l2=2200mm", "--set", "l3=2.8m",
                              "--set", "l4=3.3m", "--set", "offset1=0.01rad", "-n", "40"])
    assert res.exit_code == 0, res.output
    robot = load_fivebar("fivebar_reference")
    result = calibrate_fivebar_file(robot, data, method="lm",
                                    tolerances=dict.fromkeys(("l1", "l2", "l3", "l4"), 0.05))
    assert result.trusted, result.verdict.line()
    write_fivebar_outputs(result, tmp_path / "cal.yaml", str(tmp_path / "c.json"),
                          tmp_path / "c.html")
    truth = robot.with_params({"l1": 1.86, "l2": 2.2, "l3": 2.8, "l4": 3.3, "offset1": 0.01})
    # the file stores 17 significant digits of deg and mm: recovery to ~1e-12
    assert np.max(np.abs(result.robot.param_values - truth.param_values)) < 1e-9
    calibrated = load_fivebar(tmp_path / "cal.yaml")
    assert calibrated.name == "fivebar_reference_calibrated"
    assert np.allclose(calibrated.param_values, result.robot.param_values, atol=1e-15)
    assert json.loads((tmp_path / "c.json").read_text())["converged"] is True
    # the report is the serial robots' page: before/after table, parameters in mm / deg
    page = (tmp_path / "c.html").read_text()
    assert "Errors before and after calibration" in page and ">l1</td><td>mm</td>" in page
    assert "<h2>Estimated parameters against the iteration</h2>" in page


def test_fivebar_calibrate_prints_like_a_serial_robot(tmp_path, capsys) -> None:
    from cli_helpers import run

    data = tmp_path / "d.csv"
    assert runner.invoke(app, ["fivebar-simulate", "fivebar_reference", "-o", str(data),
                               "--set", "l1=1.86m", "-n", "30"]).exit_code == 0
    code, out, err = run(capsys, "calibrate", "fivebar_reference", "--data", data, "--report",
                         tmp_path / "r.html", "-o", tmp_path / "cal.yaml")
    # 140 mm from a 2 m drawing is 140 tolerances of 1 mm: shown, not trusted, not written
    assert code == 1
    assert err.strip().splitlines() == [
        "error: calibration not trusted: implausible estimate (beyond 10x the tolerance): l1 "
        f"moved -140 mm (140x its tolerance 1 mm); no calibrated robot written "
        f"({tmp_path / 'cal.yaml'}; --force writes it)"]
    assert not (tmp_path / "cal.yaml").exists() and (tmp_path / "r.html").exists()
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

    robot = load_fivebar("fivebar_reference")
    with pytest.raises(KincalError, match="method must be one of"):
        calibrate_fivebar_file(robot, tmp_path / "x.csv", method="newton")
    with pytest.raises(MeasurementFileError, match="no such measurement file"):
        calibrate_fivebar_file(robot, tmp_path / "missing.csv", method=method)


@pytest.fixture(scope="module")
def small_files(tmp_path_factory) -> tuple:
    """Training and held-out files of the 150 mm five-bar (errors within tolerances)."""
    folder = tmp_path_factory.mktemp("fivebar")
    files = []
    for name, seed, n in (("r.csv", 2, 40), ("h.csv", 3, 20)):
        res = runner.invoke(app, ["fivebar-simulate", "fivebar", "-o", str(folder / name),
                                  "-n", str(n), "--noise", "0.01deg", "--seed", str(seed),
                                  "--set", "l1=150.8mm", "--set", "l2=149.5mm",
                                  "--set", "offset1=0.2deg"])
        assert res.exit_code == 0, res.output
        files.append(folder / name)
    return tuple(files)


# every option of `kincal calibrate` a five-bar cannot use, with a value
REFUSED = [("--urdf", "x.urdf"), ("--procedure", "staged-selection"), ("--stages", "offsets,all"),
           ("--loss", "huber"), ("--loss-scale", "2"), ("--condition-growth", "2"),
           ("--cycles", "1"), ("--tolerance", "1um"), ("--prior", "none"),
           ("--joint-model", "hysteresis"), ("--cross-validate", "3"), ("--select", "auto"),
           ("--folds", "3"), ("--shared-marker", None), ("--scheduler", "serial"),
           ("--workers", "1"), ("--units", "mm"), ("--ignore", "x"),
           ("--validation-frames", "training"), ("--base-link", "a"), ("--tip-link", "b"),
           ("--config", "setup.yaml"), ("--instrument", "tracker"), ("--option", "a=b")]


@pytest.mark.parametrize(("option", "value"), REFUSED)
def test_calibrate_refuses_each_option_a_fivebar_cannot_use(small_files, capsys, option,
                                                            value) -> None:
    from cli_helpers import run

    args = ["calibrate", "fivebar", "--data", small_files[0], option]
    if option == "--config":
        setup = small_files[0].parent / "setup.yaml"
        setup.write_text(f"robot: fivebar\ndata: {small_files[0]}\n")
        args = ["calibrate", option, setup]
    elif value is not None:
        args.append(value)
    code, out, err = run(capsys, *args)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: option {option} does not apply "
                                                   "to a five-bar"), err
    assert out == ""


def test_calibrate_refuses_hold_on_a_fivebar(small_files, capsys) -> None:
    from cli_helpers import run

    code, _, err = run(capsys, "calibrate", "fivebar", "--data", small_files[0], "--hold",
                       "q1=0deg")
    assert code == 2 and err.strip() == "error: hold: only serial robots have joints to hold"


def test_calibrate_fivebar_free_fix_validate_max_iter_all(small_files, capsys,
                                                          tmp_path) -> None:
    from cli_helpers import run

    train, held = small_files
    code, out, err = run(capsys, "calibrate", "fivebar", "--data", train, "--validate", held,
                         "--free", "l*,offset1", "--fix", "l2", "--json", tmp_path / "c.json",
                         "--all", "-o", tmp_path / "c.yaml")
    assert code == 0, err
    data = json.loads((tmp_path / "c.json").read_text())
    assert data["free"] == ["l1", "l3", "l4", "offset1"]            # --free minus --fix
    assert data["trust"]["trusted"] is True and (tmp_path / "c.yaml").exists()
    val = data["metrics"]["validation"]
    assert [v["title"] for v in val] == ["validation (h.csv)"]
    assert val[0]["rms_position_m"] < val[0]["before"]["rms_position_m"]   # held out: better
    assert "validation" in out and "│ base2.y " in out and "│ l2 " in out  # --all rows
    code, _, err = run(capsys, "calibrate", "fivebar", "--data", train, "--max-iter", "1",
                       "-o", tmp_path / "one.yaml")
    assert code == 1 and "did not converge" in err and not (tmp_path / "one.yaml").exists()
    code, _, err = run(capsys, "calibrate", "fivebar", "--data", train, "--max-iter", "1",
                       "-o", tmp_path / "one.yaml", "--force")
    assert code == 1 and "written anyway (--force)" in err and (tmp_path / "one.yaml").exists()
    code, _, err = run(capsys, "calibrate", "fivebar", "--data", train, "--free", "zz")
    assert code == 2 and err.strip().startswith("error: option --free: 'zz' names no five-bar")


def test_calibrate_fivebar_truth_goes_to_the_report(small_files, capsys, tmp_path) -> None:
    from cli_helpers import run

    truth = tmp_path / "true.yaml"
    from kincal.parallel.files import write_fivebar

    write_fivebar(load_fivebar("fivebar").with_params({"l1": 0.1508}), truth)
    code, _, err = run(capsys, "calibrate", "fivebar", "--data", small_files[0], "--truth",
                       truth, "--report", tmp_path / "r.html")
    assert code == 0, err
    assert "true" in (tmp_path / "r.html").read_text().lower()


def test_demo_with_huge_noise_is_not_trusted(tmp_path) -> None:
    res = runner.invoke(app, ["fivebar-demo", "--out-dir", "", "-n", "10", "--noise", "45deg",
                              "--json", str(tmp_path / "d.json")])
    assert res.exit_code == 1
    assert "calibration not trusted" in str(res.exception)
    assert json.loads((tmp_path / "d.json").read_text())["trust"]["trusted"] is False


def test_the_serial_calibrate_refuses_a_fivebar_in_one_line() -> None:
    import kincal
    from kincal.errors import KincalError

    with pytest.raises(KincalError, match="calibrate takes a serial Robot, not a FiveBar"):
        kincal.calibrate(kincal.load_robot("fivebar"), [])


def test_simulate_and_workspace_json_are_the_library_results(tmp_path) -> None:
    from kincal.parallel.data import read_fivebar_csv
    from kincal.parallel.reference_experiment import simulate_fivebar

    res = runner.invoke(app, ["fivebar-simulate", "fivebar", "-o", str(tmp_path / "s.csv"),
                              "-n", "12", "--seed", "4", "--set", "l1=150.8mm",
                              "--json", str(tmp_path / "s.json")])
    assert res.exit_code == 0, res.output
    robot = load_fivebar("fivebar")
    sim = simulate_fivebar(robot, {"l1": 150.8 * 1e-3}, 12, seed=4)   # as --set parses it
    assert json.loads((tmp_path / "s.json").read_text()) == json.loads(
        json.dumps(sim.to_dict(str(tmp_path / "s.csv"))))
    data = read_fivebar_csv(tmp_path / "s.csv")
    assert np.allclose(data.q, sim.q, atol=1e-12) and np.allclose(data.x, sim.x, atol=1e-12)
    res = runner.invoke(app, ["fivebar-workspace", "fivebar", "-o", str(tmp_path / "w.png"),
                              "--resolution", "30", "--json", str(tmp_path / "w.json")])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "w.json").read_text())
    assert set(doc) == {"robot", "working_mode", "area_m2", "output"} and doc["area_m2"] > 0
