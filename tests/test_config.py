"""Setup files (kincal.workflow.config): typed, checked, with file:line:key errors; the
command line's --config with flags overriding it; kincal init; held joints."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import run

from kincal.errors import KincalError
from kincal.robots.files import load_serial_robot
from kincal.robots.hold import hold_joints
from kincal.workflow.config import (
    CALIBRATION_KEYS,
    SetupError,
    load_setup,
    parse_setup,
    read_yaml,
)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A simulated PUMA 560 experiment in mm / deg (training and held-out files)."""
    d = tmp_path_factory.mktemp("setup")
    code = run_plain("simulate", "puma560", "-o", d / "train.csv", "--holdout",
                     d / "hold.csv", "--poses", "40", "--holdout-poses", "20", "--seed", "3",
                     "--length-unit", "mm", "--angle-unit", "deg", "--truth", d / "truth.yaml")
    assert code == 0
    return d


def run_plain(*args):
    from cli_helpers import invoke

    return invoke(*args)


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_setup_file_reads_into_a_typed_setup(sim):
    p = write(sim / "setup.yaml", """
robot: puma560
data:
  - file: train.csv
    units: {"x?": mm}
    ignore: [pose_id]
    name: tracker
validate:
  - {file: hold.csv, frames: training}
hold: {q6: 0deg}
calibration:
  free: [role:offset, "tracker.*"]
  prior: {"*": 1mm}
  cross_validate: 5
  tolerance: 0.1um
outputs: {output: out/cal.yaml, json: out/res.json}
""")
    s = load_setup(p)
    assert s.robot == "puma560" and s.base_dir == sim
    assert [Path(d.path) for d in s.data] == [sim / "train.csv"]
    assert s.data[0].units == {"x?": "mm"} and s.data[0].ignore == ("pose_id",)
    assert s.data[0].name == "tracker" and s.validate[0].frames == "training"
    assert s.hold == {"q6": (0.0, "angle")}
    assert s.calibration == {"free": "role:offset,tracker.*", "prior": "*=1mm",
                             "cross_validate": 5, "tolerance": "0.1um"}
    assert s.outputs["output"] == str(sim / "out" / "cal.yaml")
    assert s.where("calibration", "free") == f"{p}: line 12: calibration.free"


@pytest.mark.parametrize("text, where, words", [
    ("robot: puma560\ndata: [nope.csv]\n", "line 2: data[0]", "no such file 'nope.csv'"),
    ("robot: puma560\ndata:\n  - file: train.csv\n    unit: {x: mm}\n", "line 4: data[0].unit",
     "did you mean 'units'"),
    ("robot: puma56\n", "line 1: robot", "did you mean 'puma560'"),
    ("robot: puma560\ncalibration:\n  cross_validate: ten\n", "line 3: calibration.cross_validate",
     "whole number"),
    ("robot: puma560\ncalibration:\n  method: newton\n", "line 3: calibration.method",
     "'newton' is not"),
    ("robot: puma560\ncalibration:\n  tolerance: 0.1\n", "line 3: calibration.tolerance",
     "needs its unit"),
    ("robot: puma560\nhold: {q6: 10}\n", "line 2: hold.q6", "needs its unit"),
    ("robot: puma560\nhold: {q6: 1arcsecs}\n", "line 2: hold.q6", "unknown unit"),
    ("robot: puma560\ndata:\n  - file: train.csv\n    units: {x: feet}\n",
     "line 4: data[0].units.x", "unknown unit 'feet'"),
    ("robot: puma560\ndata:\n  - file: train.csv\n    frames: training\n",
     "line 4: data[0].frames", "unknown key"),
    ("robot: puma560\noutputs: {report: r.html, pdf: r.pdf}\n", "outputs.pdf", "unknown key"),
    ("robot: [puma560]\n", "line 1: robot", "must be text"),
    ("- a\n- b\n", "setup.yaml", "must be a mapping"),
    ("robot: puma560\n  bad: indentation\n", "line 2", "not valid YAML"),
    ("robot: puma560\ndata:\n  - file: train.csv\n    instrument: tracker\n",
     "line 4: data[0].instrument", "unknown instrument 'tracker'"),
])
def test_bad_setup_is_one_line_with_file_line_and_key(sim, text, where, words):
    p = write(sim / "setup.yaml", text)
    with pytest.raises(SetupError) as e:
        load_setup(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)), msg
    assert where in msg and words in msg, msg


def test_empty_binary_and_missing_setup_files(tmp_path):
    for name, data in (("empty.yaml", b""), ("bin.yaml", b"\x00\xff\xfe\x01"),
                       ("latin.yaml", "robot: pümä".encode("latin-1"))):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(SetupError, match=name):
            load_setup(tmp_path / name)
    with pytest.raises(SetupError, match="no such setup file"):
        load_setup(tmp_path / "missing.yaml")
    with pytest.raises(SetupError, match="is a folder"):
        load_setup(tmp_path)


def test_alias_bombs_cost_nothing(tmp_path):
    """YAML aliases (a "billion laughs") are walked once, not expanded."""
    lol = ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 12):
        lol.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}" if i > 1 else "*a"] * 10) + "]")
    p = write(tmp_path / "bomb.yaml", "\n".join(lol) + "\n")
    doc = read_yaml(p)
    assert len(doc.lines) < 400
    with pytest.raises(SetupError, match="unknown key"):
        load_setup(p)


def test_parse_setup_from_a_mapping_with_a_prefix(sim):
    from kincal.fleet.manifest import layer

    """What a fleet manifest does: a sub-mapping with the lines of its own file."""
    p = write(sim / "fleet.yaml", """
defaults: {robot: puma560, calibration: {max_iter: 50}}
robots:
  - serial: R1
    data: [train.csv]
    calibration: {cross_validate: ten}
""")
    doc = read_yaml(p)
    defaults = parse_setup(doc.data["defaults"], sim)
    assert layer(defaults, parse_setup({"data": ["train.csv"], "calibration": {
        "cross_validate": 10}}, sim)).calibration == {"max_iter": 50, "cross_validate": 10}
    with pytest.raises(SetupError) as e:
        parse_setup(doc.data["robots"][0], sim, source=str(p), lines=doc.lines,
                    prefix=("robots", 0), extra_keys=("serial",))
    assert str(e.value) == (f"{p}: line 6: robots[0].calibration.cross_validate: must be a "
                            "whole number, got 'ten'")
    ok = layer(defaults, parse_setup({"data": ["train.csv"]}, sim))
    assert ok.calibration == {"max_iter": 50} and ok.source is None


def test_every_calibrate_option_is_a_setup_key():
    """The schema of calibration: follows kincal calibrate's options (and back)."""
    import typer

    from kincal.cli import app

    cmd = typer.main.get_command(app).commands["calibrate"]
    opts = {o[2:].replace("-", "_") for p in cmd.params for o in getattr(p, "opts", [])
            if o.startswith("--") and not getattr(p, "hidden", False)}
    files = {"data", "validate", "units", "ignore", "config", "output", "urdf", "json",
             "report", "base_link", "tip_link", "hold", "instrument", "option", "help", "si",
             "scheduler", "workers",     # where the fold fits run, not what is calibrated
             "joint_names"}              # a reading option: data: entries have it
    assert set(CALIBRATION_KEYS) <= opts
    assert opts - files <= set(CALIBRATION_KEYS), opts - files - set(CALIBRATION_KEYS)


def test_calibrate_with_a_setup_file_and_flags_overriding_it(sim, capsys, tmp_path):
    write(sim / "run.yaml", """
robot: puma560
data: [train.csv]
validate: [hold.csv]
calibration: {stages: [offsets, all], max_iter: 1}
outputs: {output: out/cal.yaml, json: out/res.json}
""")
    code, out, err = run(capsys, "calibrate", "--config", sim / "run.yaml", "--max-iter", "50",
                         "--json", tmp_path / "res.json")
    assert code == 0, err
    doc = json.loads((tmp_path / "res.json").read_text())          # the flag won
    assert not (sim / "out" / "res.json").exists()
    assert (sim / "out" / "cal.yaml").is_file()                     # the file's output
    assert doc["stages"] and doc["iterations"] > 1                  # --max-iter 50, not 1
    assert doc["metrics"]["validation"]["rms_position_m"] < 5e-5
    assert [s["stage"] for s in doc["stages"]][:1] == ["offsets"]


def test_calibrate_needs_a_robot_and_data(capsys, tmp_path):
    code, _, err = run(capsys, "calibrate")
    assert code == 2 and "needs ROBOT" in err
    write(tmp_path / "s.yaml", "robot: puma560\n")
    code, _, err = run(capsys, "calibrate", "--config", tmp_path / "s.yaml")
    assert code == 2 and "needs --data" in err
    write(tmp_path / "b.yaml", "robot: puma560\ndata: [x.csv]\n")
    code, _, err = run(capsys, "calibrate", "--config", tmp_path / "b.yaml")
    assert code == 2 and err.startswith(f"error: {tmp_path / 'b.yaml'}: line 2: data[0]")
    assert err.count("\n") == 1


def test_output_equal_to_an_input_is_refused(sim, capsys):
    before = (sim / "train.csv").read_bytes()
    code, out, err = run(capsys, "calibrate", "puma560", "--data", sim / "train.csv",
                         "-o", sim / "train.csv")
    assert code == 2 and "is also the input of --data" in err
    assert (sim / "train.csv").read_bytes() == before


# --------------------------------------------------------------------------- held joints
def test_a_held_joint_is_a_constant_of_the_chain():
    r = load_serial_robot("puma560")
    h = hold_joints(r, {"q4": 0.3})
    q = np.random.default_rng(1).uniform(-1, 1, (20, 6))
    q[:, 3] = 0.3
    keep = [0, 1, 2, 4, 5]
    np.testing.assert_allclose(h.fk(q[:, keep]), r.fk(q), atol=1e-14)
    _, J, Jp = h.fk_with_jacobians(q[:, keep])
    _, J0, Jp0 = r.fk_with_jacobians(q)
    np.testing.assert_allclose(J, J0[:, :, keep], atol=1e-14)
    np.testing.assert_allclose(Jp, Jp0, atol=1e-14)
    assert h.param_names == r.param_names and h.joint_names == ("q1", "q2", "q3", "q5", "q6")
    with pytest.raises(KincalError, match="did you mean 'q4'"):
        hold_joints(r, {"q44": 0.0})
    with pytest.raises(KincalError, match="outside its limits"):
        hold_joints(r, {"q2": math.radians(-50)})


def test_hold_from_the_setup_file_and_held_columns_are_checked(sim, capsys, tmp_path):
    """A file whose q6 column is constant calibrates with q6 held; one where it moves
    is refused naming the line."""
    code = run_plain("export", "puma560", "-o", tmp_path / "fixed6.yaml")
    assert code == 0
    doc = yaml.safe_load((tmp_path / "fixed6.yaml").read_text())
    doc["joints"][5]["limits"] = [math.radians(12.5)] * 2          # q6 never moves
    (tmp_path / "fixed6.yaml").write_text(yaml.safe_dump(doc))
    still = tmp_path / "still.csv"
    assert run_plain("simulate", tmp_path / "fixed6.yaml", "-o", still, "-n", "40",
                     "--length-unit", "mm", "--angle-unit", "deg") == 0
    capsys.readouterr()
    write(tmp_path / "h.yaml", f"robot: puma560\nhold: {{q6: 12.5deg}}\ndata: [{still}]\n")
    code, out, err = run(capsys, "calibrate", "--config", tmp_path / "h.yaml", "--json", "-")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["converged"] and "q6_deg (held joint)" in err
    write(tmp_path / "m.yaml", f"robot: puma560\nhold: {{q6: 0deg}}\ndata: [{still}]\n")
    code, _, err = run(capsys, "calibrate", "--config", tmp_path / "m.yaml")
    assert code == 2 and "joint q6 is held at 0 deg" in err and "line " in err
    code, _, err = run(capsys, "calibrate", "puma560", "--data", still, "--hold", "q6=12.5deg",
                       "--json", "-")
    assert code == 0, err
    code, _, err = run(capsys, "calibrate", "puma560", "--data", still, "--hold", "q6=0.2m")
    assert code == 2 and "q6 is a revolute joint: give an angle" in err


# --------------------------------------------------------------------------- kincal init
def test_init_writes_a_setup_that_calibrates(sim, capsys, tmp_path):
    out = tmp_path / "setup.yaml"
    code, text, err = run(capsys, "init", "puma560", "--data", sim / "train.csv",
                          "--validate", sim / "hold.csv", "-o", out)
    assert code == 0, err
    body = out.read_text()
    assert "# kincal setup file" in body and "calibration:" in body
    s = load_setup(out)                                  # it is a valid setup file
    assert s.robot == "puma560" and len(s.data) == 1 and len(s.validate) == 1
    code, _, err = run(capsys, "init", "puma560", "--data", sim / "train.csv", "-o", out)
    assert code == 2 and "--force" in err
    code, _, err = run(capsys, "calibrate", "--config", out, "-o", tmp_path / "c.yaml")
    assert code == 0, err


def test_init_guesses_bare_units_and_says_so(tmp_path, capsys):
    tiago = Path(__file__).resolve().parents[2] / "shared" / "data" / "tiago_mocap"
    if not tiago.is_dir():
        pytest.skip(f"TIAGo data not found at {tiago}")
    out = tmp_path / "setup.yaml"
    code, _, err = run(capsys, "init", tiago / "tiago_48_schunk.urdf", "--tip-link",
                       "wrist_ft_tool_link", "--data", tiago / "train_2021-11-30.csv", "-o", out)
    assert code == 0, err
    doc = yaml.safe_load(out.read_text())
    assert doc["data"][0]["units"] == {"x?": "m", "y?": "m", "z?": "m"}
    assert "CHECK: guessed" in out.read_text()
    assert "do not read" not in capsys.readouterr().out
