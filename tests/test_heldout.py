"""Held-out files one at a time, predicted accuracy where the model is used, fallback.

Simulated PUMA 560 measured by a tracker with four markers on the hand (the TIAGo
layout), the training poses in a box of the joint space:

* a one-marker file validates against the four-marker fit (same session);
* a file from a moved tracker is re-registered: frame and marker refitted, or the
  marker kept from training when the file's poses cannot separate it, and the note
  says so;
* ``validate`` and ``calibrate --validate`` give the same rows, the same "before";
* poses outside the training box are flagged, with their predicted error;
* ``compensate --result`` warns where the calibrated model is predicted worse than the
  nominal one, and ``--fallback nominal`` sends those targets uncompensated.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_helpers import run, write_tracker
from test_compliance import perturbed_puma

from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot, write_robot_yaml
from kincal.spatial import matrix_from_frame

NOISE = 2e-5
INSTRUMENT = [1.4, -0.6, 0.3, 2.1, -0.3, 0.2]
MARKERS = np.array([[0.05, 0.0, 0.1], [-0.05, 0.0, 0.1], [0.0, 0.05, 0.12],
                    [0.0, -0.05, 0.08]])


def in_box(robot, n, rng, width=0.3):
    lim = robot.joint_limits
    mid, half = lim.mean(axis=1), width / 2 * (lim[:, 1] - lim[:, 0])
    return mid + rng.uniform(-1, 1, (n, robot.n)) * half


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("held")
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(51)
    true = perturbed_puma(nominal, rng)
    q_train = in_box(nominal, 40, rng)
    y = simulate_positions(true, q_train, rng, NOISE, INSTRUMENT, MARKERS).positions
    write_tracker(d / "train.csv", nominal, q_train, y)
    q_val = np.vstack([in_box(nominal, 10, rng, 0.2), random_configurations(nominal, 10, rng)])
    y1 = simulate_positions(true, q_val, rng, NOISE, INSTRUMENT, MARKERS[:1]).positions
    write_tracker(d / "one_marker.csv", nominal, q_val, y1.reshape(-1, 1, 3))
    # the tracker moved by 0.3 m and 25 deg
    M = matrix_from_frame(np.array([0.3, -0.1, 0.05, math.radians(25), math.radians(3), 0.0]))
    q_m = in_box(nominal, 25, rng)
    ym = simulate_positions(true, q_m, rng, NOISE, INSTRUMENT, MARKERS[:1]).positions
    ym = ym.reshape(-1, 1, 3) @ M[:3, :3].T + M[:3, 3]
    write_tracker(d / "moved.csv", nominal, q_m, ym)
    # moved, and only the first joint turns: the marker's height along its axis is not
    # separable from the tracker frame
    q_f = in_box(nominal, 25, rng)
    q_f[:, 1:] = q_f[0, 1:]
    yf = simulate_positions(true, q_f, rng, NOISE, INSTRUMENT, MARKERS[:1]).positions
    write_tracker(d / "fixed_wrist.csv", nominal, q_f,
                  yf.reshape(-1, 1, 3) @ M[:3, :3].T + M[:3, 3])
    write_robot_yaml(true, d / "true.yaml")
    return d


@pytest.fixture(scope="module")
def calibrated(files):
    from cli_helpers import invoke

    args = ["calibrate", "puma560", "--data", files / "train.csv", "--validate",
            files / "one_marker.csv", "--validate", files / "moved.csv", "--validate",
            files / "fixed_wrist.csv", "-o", files / "cal.yaml", "--json", files / "res.json",
            "--report", files / "report.html"]
    assert invoke(*args) == 0
    return json.loads((files / "res.json").read_text())


def test_one_row_per_file_and_the_protocol_of_each(files, calibrated):
    rows = {f["file"]: f for f in calibrated["metrics"]["validation_files"]}
    assert list(rows) == ["one_marker.csv", "moved.csv", "fixed_wrist.csv"]
    # a one-marker file against the four-marker fit: same session, at the noise level
    one = rows["one_marker.csv"]
    assert one["protocol"] == "training" and "no refit" in one["note"]
    # the other two files' blocks were renamed (tracker2, tracker3: one name per file),
    # so 'auto' re-registers them
    for name in ("moved.csv", "fixed_wrist.csv"):
        assert rows[name]["protocol"] == "register"
    assert calibrated["metrics"]["validation"]["files"] == 3
    html = (files / "report.html").read_text()
    assert "Can this calibration be trusted?" in html
    assert "Held-out files: measured against predicted" in html
    # the table, then 'before' for each protocol the files used (as under the errors table)
    table = html.index("<th class='l'>protocol note</th>")
    for line in ("before (same session) =", "before (re-registered) ="):
        assert html.rindex(line) > table > html.index(line)
    assert "before (artifact)" not in html
    assert "lie outside the training joint ranges" in html
    assert "before = the nominal robot" in calibrated["metrics"]["validation"][
        "before_definition"]


def test_register_refits_frame_and_marker_or_says_why_not(files, capsys, tmp_path):
    j = tmp_path / "v.json"
    code, out, err = run(capsys, "calibrate", "puma560", "--data", files / "train.csv",
                         "--validate", files / "moved.csv", "--validate",
                         files / "fixed_wrist.csv", "--validation-frames", "register",
                         "--json", j)
    assert code == 0, err
    rows = {f["file"]: f for f in json.loads(j.read_text())["metrics"]["validation_files"]}
    moved, fixed = rows["moved.csv"], rows["fixed_wrist.csv"]
    assert moved["protocol"] == fixed["protocol"] == "register"
    assert moved["note"] == "instrument re-registered on this file: frame and marker fitted"
    assert moved["rms_position_m"] < 1.5 * math.sqrt(3) * NOISE
    # only joint 1 turns: part of the marker cannot be told from the frame, kept from
    # training, and the note says which and why
    assert "marker." in fixed["note"] and "kept the training value" in fixed["note"]
    assert fixed["rms_position_m"] < 1.5 * math.sqrt(3) * NOISE
    # a circle about the first axis: any robot fits it once re-registered (no test of
    # the robot at all), unlike the moved file's poses
    assert fixed["before"]["rms_position_m"] < 1.5 * math.sqrt(3) * NOISE
    assert moved["before"]["rms_position_m"] > 10 * moved["rms_position_m"]


def test_validate_gives_the_same_rows_and_flags_the_poses_outside(files, calibrated, capsys,
                                                                 tmp_path):
    j = tmp_path / "v.json"
    code, out, err = run(capsys, "validate", files / "cal.yaml", "--data",
                         files / "one_marker.csv", "--result", files / "res.json",
                         "--before", "puma560", "--json", j)
    assert code == 0, err
    doc = json.loads(j.read_text())
    (row,) = doc["files"].values()
    cal_row = calibrated["metrics"]["validation_files"][0]
    for key in ("rms_position_m", "max_position_m"):
        assert row[key] == pytest.approx(cal_row[key], rel=1e-9)
        assert row["before"][key] == pytest.approx(cal_row["before"][key], rel=1e-9)
    pred = row["predicted"]
    assert pred["outside_n"] >= 10 and pred["inside_n"] <= 10    # 10 in the box, 10 anywhere
    assert pred["predicted_rms_outside_m"] > pred["predicted_rms_inside_m"]
    text = " ".join(out.split())
    assert "lie outside the training joint ranges; predicted error there up to" in text
    assert "nominal" in text
    flags = doc["predicted"][str(files / "one_marker.csv")]["outside_joint_ranges"]
    assert sum(flags) == pred["outside_joint_ranges"]



def test_prediction_sentences_follow_the_console_units(files, calibrated, capsys):
    """With --si the sentences under the held-out table give metres like the table, and
    the numbers are the same lengths as without it."""
    import re

    texts = {}
    for flag in ((), ("--si",)):
        code, out, err = run(capsys, "validate", files / "cal.yaml", "--data",
                             files / "one_marker.csv", "--result", files / "res.json",
                             "--before", "puma560", *flag)
        assert code == 0, err
        texts[flag] = " ".join(out.split())
    pat = r"predicted error there up to ([0-9.e+-]+) (mm|m), nominal ([0-9.e+-]+) (mm|m)"
    mm, si = re.search(pat, texts[()]), re.search(pat, texts[("--si",)])
    assert mm and si, texts
    assert (mm.group(2), mm.group(4), si.group(2), si.group(4)) == ("mm", "mm", "m", "m")
    assert float(si.group(1)) == pytest.approx(float(mm.group(1)) / 1e3, rel=1e-2)
    assert float(si.group(3)) == pytest.approx(float(mm.group(3)) / 1e3, rel=1e-2)


def _targets(path, robot, q):
    T = robot.fk(q)
    rows = [",".join(f"{v:.9f}" for v in T[i, :3, 3] * 1e3) for i in range(len(q))]
    path.write_text("x_mm,y_mm,z_mm\n" + "\n".join(rows) + "\n")


def test_compensate_predicts_and_falls_back_to_nominal(files, calibrated, capsys, tmp_path):
    """A robot calibrated from data of the nominal robot itself: every correction is
    noise, smaller than its uncertainty, so the calibrated model is predicted no better
    than the nominal one and --fallback nominal sends the targets uncompensated; the
    perturbed robot's calibration is predicted better everywhere in its box."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(9)
    q_t = in_box(nominal, 8, rng, 0.2)
    targets = tmp_path / "t.csv"
    _targets(targets, nominal, q_t)
    j = tmp_path / "c.json"
    code, out, err = run(capsys, "compensate", files / "cal.yaml", "--targets", targets,
                         "-o", tmp_path / "q.csv", "--nominal", "puma560", "--result",
                         files / "res.json", "--json", j)
    assert code == 0, err
    doc = json.loads(j.read_text())
    assert not any(doc["predicted"]["worse_than_nominal"]) and not any(doc["fallback_nominal"])
    assert "targets inside the training region: predicted error up to" in " ".join(out.split())
    # calibrate on data of the nominal robot: nothing to correct
    q = in_box(nominal, 40, rng)
    y = simulate_positions(nominal, q, rng, NOISE, INSTRUMENT, MARKERS).positions
    write_tracker(tmp_path / "nom.csv", nominal, q, y)
    code, _, err = run(capsys, "calibrate", "puma560", "--data", tmp_path / "nom.csv", "-o",
                       tmp_path / "same.yaml", "--json", tmp_path / "same.json")
    assert code == 0, err
    code, out, err = run(capsys, "compensate", tmp_path / "same.yaml", "--targets", targets,
                         "-o", tmp_path / "q2.csv", "--nominal", "puma560", "--result",
                         tmp_path / "same.json", "--json", j, "--filtered",
                         tmp_path / "f.csv")
    assert code == 0, err
    doc = json.loads(j.read_text())
    worse = np.array(doc["predicted"]["worse_than_nominal"])
    flat = " ".join(out.split())                    # the console wraps lines at its width
    assert worse.mean() > 0.5 and "--fallback nominal sends them uncompensated" in flat
    code, out, err = run(capsys, "compensate", tmp_path / "same.yaml", "--targets", targets,
                         "-o", tmp_path / "q3.csv", "--nominal", "puma560", "--result",
                         tmp_path / "same.json", "--json", j, "--fallback", "nominal",
                         "--filtered", tmp_path / "f3.csv")
    assert code == 0, err
    doc = json.loads(j.read_text())
    back = np.array(doc["fallback_nominal"])
    assert np.array_equal(back, worse) and "sent uncompensated" in " ".join(out.split())
    qc = np.array(doc["q"])
    np.testing.assert_allclose(nominal.fk(qc[back])[:, :3, 3], nominal.fk(q_t[back])[:, :3, 3],
                               atol=1e-9)                   # the nominal commands
    F = np.loadtxt(tmp_path / "f3.csv", delimiter=",", skiprows=2, ndmin=2)
    np.testing.assert_allclose(F[back] * 1e-3, nominal.fk(q_t[back])[:, :3, 3], atol=1e-9)
    code, _, err = run(capsys, "compensate", tmp_path / "same.yaml", "--targets", targets,
                       "-o", tmp_path / "q4.csv", "--fallback", "nominal")
    assert code == 2 and "--fallback nominal needs --nominal" in err
