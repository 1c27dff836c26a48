"""``kincal plan``: poses CSV read back by the measurement reader, report, JSON, errors."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from kincal.cli import app
from kincal.errors import KincalError
from kincal.identify.design import random_candidates, within_limits, write_poses
from kincal.measure.files import read_table
from kincal.robots.files import load_serial_robot

runner = CliRunner()


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def test_plan_writes_poses_report_and_json(puma, tmp_path) -> None:
    out, rep, js = tmp_path / "poses.csv", tmp_path / "plan.html", tmp_path / "plan.json"
    res = runner.invoke(app, ["plan", "puma560", "--instrument", "position", "--poses", "14",
                              "--criterion", "o3", "--candidates", "400", "--grid", "2",
                              "--seed", "3", "-o", str(out), "--report", str(rep),
                              "--json", str(js)], terminal_width=140)
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "Observability indices" in text and "O3 *" in text
    assert "Predicted position error" in text and "tracker.marker.x" in text
    table = read_table(out, puma, ())                      # the measurement-file reader
    assert table.q.shape == (14, 6) and within_limits(puma, table.q).all()
    assert [c for c in out.read_text().splitlines() if not c.startswith("#")][0] == \
        "q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad"
    data = json.loads(js.read_text())
    assert np.allclose(data["poses"], table.q, rtol=1e-13, atol=1e-14)
    assert data["criterion"] == "O3" and data["method"].startswith("greedy + exchange")
    assert data["indices"]["O3"] > data["random_indices_median"]["O3"]
    assert data["prediction"]["rms_position_m"] < data["random_prediction_rms_position_m"]
    # one "median random design" everywhere: the JSON, the table's "random (median)" row
    random_row = next(line for line in res.output.splitlines() if "random (median)" in line)
    assert f"{data['random_prediction_rms_position_m'] * 1e3:.4g}" in random_row
    assert len(set(data["candidate_indices"])) == 14
    html = rep.read_text()
    assert "<img" in html and "Observability indices" in html and "Poses (deg / mm)" in html


def test_plan_from_a_candidate_file_in_degrees(puma, tmp_path) -> None:
    cand = tmp_path / "cand.csv"
    q = random_candidates(puma, 150, np.random.default_rng(4))
    write_poses(cand, puma, q, angle_unit="deg")
    with cand.open("a") as f:
        f.write("170,0,0,0,0,0\n")                          # q1 beyond its 160 deg limit
    out = tmp_path / "sel.csv"
    res = runner.invoke(app, ["plan", "puma560", "--candidates-file", str(cand), "-n", "12",
                              "-c", "kappa", "--grid", "2", "--min-distance", "20deg",
                              "--angle-unit", "deg", "-o", str(out)], terminal_width=140)
    assert res.exit_code == 0, res.output
    assert "(1 row outside the joint limits dropped)" in " ".join(res.output.split())
    assert "q1_deg" in out.read_text()
    sel = read_table(out, puma, ()).q
    match = np.abs(sel[:, None, :] - q[None]).max(axis=2).min(axis=1)
    assert match.max() < 1e-12                               # every pose is a candidate
    d = np.linalg.norm(sel[:, None] - sel[None], axis=-1)[np.triu_indices(12, 1)]
    assert np.degrees(d.min()) >= 20.0


def test_plan_help_and_errors(tmp_path) -> None:
    res = runner.invoke(app, ["plan", "--help"], terminal_width=140)
    assert res.exit_code == 0 and "--criterion" in res.output and "--report" in res.output
    out = tmp_path / "x.csv"
    # the console script: one line on stderr, exit code 2, nothing written
    proc = subprocess.run([sys.executable, "-c", "from kincal.cli import main; main()", "plan",
                           "puma560", "--candidates", "100", "-o", str(out), "-c", "O9"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == ("error: option --criterion: unknown criterion 'O9'; use one "
                                   "of O1, O2, O3, O4, O5, kappa")
    for args, message in ((["-n", "3"], "ask for at least 9 poses"),
                          (["--instrument", "sonar"], "unknown instrument 'sonar'"),
                          (["--angle-unit", "mm"], "is not an angle unit")):
        res = runner.invoke(app, ["plan", "puma560", "--candidates", "100", "-o", str(out),
                                  *args])
        assert isinstance(res.exception, KincalError), res.output
        assert message in str(res.exception)
    assert not out.exists()
