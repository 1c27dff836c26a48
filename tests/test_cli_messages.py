"""Messages that are true (issue: a calibration engineer's first week): each reproduction
of a misleading message, fixed, with a test."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_helpers import invoke, run

from kincal.robots.files import load_serial_robot


def test_artifact_labels_are_read_not_reported_as_ignored(tmp_path, capsys):
    """`kincal simulate -i cross-bar` files: placement and point are read (labels)."""
    f = tmp_path / "cb.csv"
    assert invoke("simulate", "puma560", "-i", "cross-bar", "--placements", "4", "-o", f,
                  "--seed", "2") == 0
    capsys.readouterr()
    code, out, err = run(capsys, "identifiability", "puma560", "--data", f)
    assert code == 0, err
    assert "not read" not in out + err


def test_one_definition_of_before_for_held_out_data(tmp_path, capsys):
    """calibrate --validate and validate --result --before give the same before and after
    errors on the same file, and the table says what "before" is."""
    d = tmp_path
    assert invoke("simulate", "puma560", "-o", d / "t.csv", "--holdout", d / "h.csv", "-n",
                  "40", "--holdout-poses", "20", "--seed", "4") == 0
    capsys.readouterr()
    code, out, err = run(capsys, "calibrate", "puma560", "--data", d / "t.csv", "--validate",
                         d / "h.csv", "--validation-frames", "training", "-o", d / "c.yaml",
                         "--json", d / "r.json")
    assert code == 0, err
    cal = json.loads((d / "r.json").read_text())["metrics"]["validation"]
    shown = " ".join(out.split())
    assert "before (same session) = the nominal robot, the training session's frames and " \
        "markers registered to it" in shown
    assert "re-registered" not in shown and "before = the nominal robot under" not in shown
    code, out, err = run(capsys, "validate", d / "c.yaml", "--data", d / "h.csv", "--result",
                         d / "r.json", "--before", "puma560", "--json", d / "v.json")
    assert code == 0, err
    val = json.loads((d / "v.json").read_text())
    assert val["overall"]["rms_position_m"] == pytest.approx(cal["rms_position_m"], rel=1e-9)
    assert val["overall_before"]["rms_position_m"] == pytest.approx(
        cal["before"]["rms_position_m"], rel=1e-9)
    assert "the training session's frames and markers registered to it" in " ".join(out.split())
    assert "frames and markers registered to it on the training data" in val["before_definition"]


def test_ik_all_branches_with_a_position_says_what_to_give(capsys):
    code, _, err = run(capsys, "ik", "puma560", "--position", "400,100,300mm",
                       "--all-branches")
    assert code == 2 and err.count("\n") == 1
    assert "give --pose" in err and "(N, 4, 4)" not in err


def test_a_failed_ik_prints_no_joint_table_of_the_start_guess(capsys):
    code, out, err = run(capsys, "ik", "puma560", "--position", "5,0,0m")
    assert code == 2 and "beyond reach" in err
    assert "FAILED" not in out and "q1 =" not in out and "no solution" in out


def test_exported_urdf_invents_no_effort_or_velocity(tmp_path, capsys):
    f = tmp_path / "p.urdf"
    assert invoke("export", "puma560", "-o", f) == 0
    text = f.read_text()
    assert 'effort="0"' not in text and 'velocity="0"' not in text
    assert "effort and velocity unknown" in text


def test_trajectory_deg_prints_degrees(tmp_path, capsys):
    code, out, err = run(capsys, "trajectory", "puma560", "--start", "0,80,-80,0,30,0",
                         "--end", "10,70,-90,0,40,0", "--deg", "--duration", "1s",
                         "--out-dir", tmp_path)
    assert code == 0, err
    row = next(ln for ln in out.splitlines() if ln.startswith("│ q2"))
    assert "80.000000°" in row and "70.000000°" in row and "deg/s" in row
    code, out, err = run(capsys, "trajectory", "puma560", "--start", "0,80,-80,0,30,0",
                         "--end", "10,70,-90,0,40,0", "--deg", "--duration", "1s",
                         "--out-dir", tmp_path, "--json", "-")
    doc = json.loads(out)
    assert doc["max_abs_qd"][0] == pytest.approx(math.radians(18.75), rel=1e-3)   # JSON: SI


def test_show_prints_notes_and_consistent_units(capsys):
    code, out, _ = run(capsys, "show", "puma560")
    text = " ".join(out.split())
    assert code == 0 and "notes:" in text and "d1 = 0" in text and "base.z = 0.672 m" in text
    assert "│ m " not in out.replace("│ mm ", "")        # no value in mm labelled "m"


def test_plan_standard_errors_in_the_console_units(tmp_path, capsys):
    code, out, err = run(capsys, "plan", "puma560", "-o", tmp_path / "p.csv", "-n", "12",
                         "--candidates", "200", "--grid", "2")
    assert code == 0, err
    assert "arcsec" not in out


def test_compensate_writes_in_the_targets_units(tmp_path, capsys):
    robot = load_serial_robot("puma560")
    q = np.array([[0.1, 0.5, -0.3, 0.2, 0.4, 0.1]])
    p = robot.fk(q)[0, :3, 3] * 1e3
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm\n" + ",".join(f"{v:.9f}" for v in p)
                                    + "\n")
    code, out, err = run(capsys, "compensate", "puma560", "--targets", tmp_path / "t.csv",
                         "-o", tmp_path / "q.csv", "--nominal", "puma560", "--filtered",
                         tmp_path / "f.csv")
    assert code == 0, err
    assert (tmp_path / "q.csv").read_text().splitlines()[1].startswith("q1_deg")
    assert (tmp_path / "f.csv").read_text().splitlines()[1] == "x_mm,y_mm,z_mm"


def test_simulate_states_its_noise_in_the_console_units(tmp_path, capsys):
    """The noise simulate applied, in mm (m with --si) like every other console length,
    not in the instrument's SI unit; an artifact's encoder noise in deg (rad)."""
    code, out, err = run(capsys, "simulate", "puma560", "-o", tmp_path / "a.csv", "-n", "5",
                         "--noise", "0.01mm")
    assert code == 0, err
    assert "(noise 0.0100 mm)" in " ".join(out.split()) and "1e-05 m" not in out
    code, out, _ = run(capsys, "simulate", "puma560", "-o", tmp_path / "b.csv", "-n", "5",
                       "--noise", "0.01mm", "--si")
    assert code == 0 and "(noise 0.0000100 m)" in " ".join(out.split())
    code, out, err = run(capsys, "simulate", "puma560", "-i", "cross-bar", "-o",
                         tmp_path / "c.csv", "--encoder-noise", "0.001deg")
    assert code == 0, err
    assert "encoder noise 0.0010 deg per joint" in " ".join(out.split())
