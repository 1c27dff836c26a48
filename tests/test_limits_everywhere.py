"""Joint values beyond the robot's limits, in every command that reads joints; the five-bar
verdict's refusals; the reason of a target the nominal robot cannot reach.

The limits are the robot file's (PUMA 560: q2 in [-45, 225] deg); a value inside them is
accepted by the same command, so each refusal is the limit's and not something else's.
"""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.cli.common import robot_arg
from kincal.compensation.configuration import fanuc_configuration
from kincal.compensation.filter import TargetRequest, filter_targets
from kincal.measure.simulate import perturb_robot
from kincal.parallel.data import read_fivebar_csv
from kincal.parallel.file_calibration import calibrate_fivebar_file

PROGRAMS = Path(__file__).parent / "data" / "programs"


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("args, option", [
    (["ik", "puma560", "--position", "0.4,0.1,0.3m", "--deg", "--q0", "0,300,0,0,0,0"], "--q0"),
    (["trajectory", "puma560", "--start", "0,0,0,0,0,0", "--end", "0,4,0,0,0,0",
      "--duration", "1s"], "--end"),
    (["trajectory", "puma560", "--deg", "--start", "0,-60,0,0,0,0", "--end", "0,10,0,0,0,0",
      "--duration", "1s"], "--start"),
    (["clik", "puma560", "--deg", "--start", "0,300,0,0,0,0", "--end-position",
      "400,0,300mm", "--method", "dls", "--duration", "0.2s"], "--start"),
])
def test_options_beyond_the_limits_refused(capsys, tmp_path, args, option):
    out = tmp_path / "out"
    if args[0] in ("trajectory", "clik"):
        args = [*args, "--out-dir", str(out)]
    code, _, err = run(capsys, *args)
    line = _one_line(err)
    assert code == 1
    assert f"option {option}: joint q2" in line and "[-45 deg, 225 deg]" in line
    assert not out.exists()                     # nothing half-written
    # the same command inside the limits is answered
    fixed = [a.replace("300", "30").replace(",4,", ",1,").replace("-60", "-30") for a in args]
    code, _, err = run(capsys, *fixed)
    assert code == 0, err


def test_compensate_joint_seeds_beyond_the_limits(capsys, tmp_path):
    targets = tmp_path / "t.csv"
    targets.write_text("x_mm,y_mm,z_mm,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n"
                       "400,100,300,0,30,0,0,0,0\n400,100,300,0,300,0,0,0,0\n")
    out = tmp_path / "c.csv"
    code, _, err = run(capsys, "compensate", "puma560", "--targets", targets, "-o", out)
    line = _one_line(err)
    assert code == 1 and f"{targets}: line 3: joint q2 = 300 deg" in line
    assert not out.exists()
    targets.write_text(targets.read_text().replace(",300,", ",31,"))
    code, _, err = run(capsys, "compensate", "puma560", "--targets", targets, "-o", out)
    assert code == 0 and out.exists(), err


def test_filter_taught_joint_target_beyond_the_limits(capsys, tmp_path):
    shutil.copy(PROGRAMS / "fanuc_frames.yaml", tmp_path)
    prog = tmp_path / "deburr.ls"
    text = (PROGRAMS / "deburr.ls").read_text()
    assert "J2=     -.500 deg" in text
    prog.write_text(text.replace("J2=     -.500 deg", "J2=   400.000 deg"))
    code, _, err = run(capsys, "filter", prog, "--robot", "m10ia", "--nominal", "m10ia",
                       "-o", tmp_path / "out.ls", "--frames", tmp_path / "fanuc_frames.yaml")
    assert code == 1
    assert re.search(r"P\[4\], .*deburr.ls:41: joint q2 = 400 deg is beyond its limits", err)
    # as taught (J2 = -0.5 deg) the same target is kept, and the program filtered
    prog.write_text(text)
    code, _, err = run(capsys, "filter", prog, "--robot", "m10ia", "--nominal", "m10ia",
                       "-o", tmp_path / "out.ls", "--frames", tmp_path / "fanuc_frames.yaml")
    assert code == 0, err


def test_filter_unreachable_target_says_why_and_how_far(capsys, tmp_path):
    """The LR Mate 200iD has no closed-form IK (its file is an ETS chain): its targets with
    a FANUC configuration went unsolved with an empty reason.  They lie beyond its reach:
    the reason says by whom and by how far, once."""
    code, _, err = run(capsys, "filter", PROGRAMS / "deburr.ls", "--robot", "lrmate200id",
                       "--nominal", "lrmate200id", "-o", tmp_path / "out.ls",
                       "--frames", PROGRAMS / "fanuc_frames.yaml")
    assert code == 1
    m = re.search(r"deburr.ls:22: unreachable by the nominal robot: ([0-9.]+) m beyond reach",
                  err)
    assert m, err
    assert err.count("unreachable") == 1
    assert float(m.group(1)) > 0.0


def test_filter_configured_pose_on_a_robot_without_closed_form():
    """A pose target with a FANUC configuration on the LR Mate 200iD (no closed-form IK) is
    solved by the numerical IK: the calibrated robot's joints reach the pose (closed loop
    through its FK), where before the target was dropped without a reason."""
    nominal = robot_arg("lrmate200id")
    calibrated = perturb_robot(nominal, np.random.default_rng(3))
    q_true = np.radians([10.0, 20.0, -15.0, 5.0, -40.0, 30.0])
    F = nominal.fk(q_true)
    req = TargetRequest("pose", flange=F, config=fanuc_configuration("N U T", (0, 0, 0)),
                        seed=q_true + 0.05)
    res = filter_targets(calibrated, nominal, [req])
    assert bool(res.ok[0]), res.reason[0]
    assert np.allclose(calibrated.fk(res.joints[0]), F, atol=1e-8)
    far = F.copy()
    far[:3, 3] *= 10.0                                   # ten times further: out of reach
    res = filter_targets(calibrated, nominal, [TargetRequest("pose", flange=far)])
    assert not res.ok[0] and res.reason[0].startswith("unreachable by the nominal robot: ")


def _fivebar_file(tmp_path: Path, capsys, rows: int, name: str = "fb.csv") -> Path:
    path = tmp_path / name
    code, _, err = run(capsys, "fivebar-simulate", "fivebar", "-o", path, "-n", rows,
                       "--noise", "0.01deg")
    assert code == 0, err
    return path


def test_fivebar_reading_beyond_its_limits(capsys, tmp_path):
    path = _fivebar_file(tmp_path, capsys, 30)
    data = read_fivebar_csv(path)
    q1 = np.degrees(data.q[:, 0])
    lo = float(np.sort(q1)[1]) - 1.0            # the smallest reading lies 1 deg beyond
    robot = dataclasses.replace(robot_arg("fivebar"),
                                limits=((math.radians(lo), math.pi), (-math.pi, math.pi)))
    verdict = calibrate_fivebar_file(robot, path).verdict
    assert not verdict.trusted
    first = int(data.lines[int(np.argmin(q1))])
    assert f"{path}: line {first}: reading q1 =" in verdict.line()
    wide = dataclasses.replace(robot, limits=((math.radians(lo - 5), math.pi),
                                              (-math.pi, math.pi)))
    assert calibrate_fivebar_file(wide, path).verdict.trusted


def test_fivebar_no_redundancy(capsys, tmp_path):
    path = _fivebar_file(tmp_path, capsys, 30)
    lines = path.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")] + [lines[2]]
    same = tmp_path / "same.csv"
    same.write_text("\n".join(head + [lines[3]] * 20 + [lines[4]] * 20) + "\n")
    code, _, err = run(capsys, "calibrate", "fivebar", "--data", same, "-o", tmp_path / "o.yaml")
    assert code == 1
    assert "no redundancy: 4 equations from 2 distinct readings" in err
    assert not (tmp_path / "o.yaml").exists()
    code, _, err = run(capsys, "calibrate", "fivebar", "--data", path, "-o", tmp_path / "o.yaml")
    assert code == 0, err
