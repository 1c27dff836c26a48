"""`kincal init` writes what the files say: held-out frames from shared ``name=`` tags (a
file of another set-up is re-registered), warnings for files without sigma and for
joints that never move; the setup it writes then runs, and its held-out protocol agrees
with the command line's.

The truth: a simulated robot measured twice by a tracker in two different places (a
held-out file of another set-up): kept in the training frame, its error would be the
distance the tracker moved, re-registered it is the noise.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml
from cli_helpers import run

from kincal.measure.files import write_table
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot


def _tracker_file(path: Path, robot, q, shift: float, name: str | None, sigma: bool) -> None:
    y = robot.fk(q)[:, :3, 3] + np.array([shift, 0.0, 0.0])
    obs = [(c, y[:, i], "length") for i, c in enumerate("xyz")]
    if sigma:
        obs.append(("sigma", np.full(len(q), 1e-5), "length"))
    tags = {"instrument": "position", **({"name": name} if name else {})}
    write_table(path, q, obs, robot=robot, tags=tags, length_unit="mm", angle_unit="deg")


def _files(tmp_path: Path, held_name: str | None, sigma: bool = True) -> tuple[Path, Path]:
    robot = load_serial_robot("puma560")
    q = random_configurations(robot, 40, np.random.default_rng(4))   # within the limits
    train, held = tmp_path / "train.csv", tmp_path / "held.csv"
    _tracker_file(train, robot, q, 0.0, "tracker", sigma)
    _tracker_file(held, robot, q[::-1].copy(), 0.5, held_name, sigma)   # the tracker moved
    return train, held


def test_held_out_file_of_another_set_up_is_re_registered(tmp_path, capsys):
    train, held = _files(tmp_path, held_name=None)
    setup = tmp_path / "setup.yaml"
    code, out, err = run(capsys, "init", "puma560", "--data", train, "--validate", held,
                         "-o", setup)
    assert code == 0, err
    doc = yaml.safe_load(setup.read_text())
    assert doc["validate"][0]["frames"] == "register"
    assert "CHECK: no name= shared with a training file" in setup.read_text()
    code, out, err = run(capsys, "calibrate", "--config", setup, "--json", tmp_path / "r.json",
                         "-o", tmp_path / "cal.yaml")
    assert code == 0, err
    res = json.loads((tmp_path / "r.json").read_text())
    # exact data: re-registered, the held-out error is ~0 (not the 500 mm the tracker moved)
    assert res["metrics"]["validation"]["rms_position_m"] < 1e-6


def test_shared_name_keeps_the_training_frames(tmp_path, capsys):
    train, held = _files(tmp_path, held_name="tracker")
    setup = tmp_path / "setup.yaml"
    code, _, err = run(capsys, "init", "puma560", "--data", train, "--validate", held,
                       "-o", setup)
    assert code == 0, err
    doc = yaml.safe_load(setup.read_text())
    assert doc["validate"][0]["frames"] == "training"
    assert "same instrument set-up: name=tracker as in train.csv" in setup.read_text()


def test_init_warns_for_no_sigma_and_a_joint_that_never_moves(tmp_path, capsys):
    robot = load_serial_robot("puma560")
    q = random_configurations(robot, 30, np.random.default_rng(5))
    q[:, 3] = np.radians(12.5)                                     # q4 never moves
    f = tmp_path / "m.csv"
    _tracker_file(f, robot, q, 0.0, "tracker", sigma=False)
    setup = tmp_path / "setup.yaml"
    code, out, err = run(capsys, "init", "puma560", "--data", f, "-o", setup)
    assert code == 0, err
    text = setup.read_text()
    assert "# CHECK: no sigma column or sigma_<unit> option" in text
    assert "# CHECK: joint q4 never moves (range 0 over 30 rows)" in text
    assert "hold: {q4: 12.5deg}" in text
    flat = " ".join(err.split())
    assert "warning:" in flat and "joint q4 never moves" in flat and "no sigma column" in flat
    _, held = _files(tmp_path, held_name="tracker", sigma=True)
    code, out, err = run(capsys, "init", "puma560", "--data", held, "-o", setup, "--force")
    assert code == 0 and "CHECK: no sigma" not in setup.read_text() and "never moves" not in err


def test_init_suggests_a_column_map_for_prefixed_measurements(tmp_path, capsys):
    f = tmp_path / "rec.csv"
    f.write_text("q1_deg;q2_deg;q3_deg;q4_deg;q5_deg;q6_deg;meas_x;meas_y;meas_z;meas_std_x;"
                 "meas_std_y;meas_std_z\n" + "1,5;2;3;4;5;6;100;200;300;0,01;0,01;0,02\n" * 3)
    setup = tmp_path / "setup.yaml"
    code, _, err = run(capsys, "init", "puma560", "--data", f, "-o", setup)
    assert code == 0, err
    text = setup.read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("    # columns: {"))
    doc = yaml.safe_load(line.split("# columns:", 1)[1].split("#", 1)[0])
    assert doc == {"meas_x": "x_mm", "meas_y": "y_mm", "meas_z": "z_mm",
                   "meas_std_x": "sigma_x_mm", "meas_std_y": "sigma_y_mm",
                   "meas_std_z": "sigma_z_mm"}
    assert sum(ln.startswith("    # columns: {") for ln in text.splitlines()) == 1
