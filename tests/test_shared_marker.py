"""``--shared-marker``: two files that see one physical tool point share its parameters.

Truth: a simulated PUMA 560 whose reflector (in the flange frame) is seen by a tracker
from two placements, one file each.  Shared, the point is one set of parameters, the
robot's ``tool.x/y/z``, estimated within its standard error of the true reflector;
separate, each file has its own marker (three more parameters).  Real data: the Panda's
ball seated in the artifact at both placements.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run, write_tracker
from test_compliance import perturbed_puma

from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot

NOISE = 2e-5
MARKER = np.array([[0.06, -0.02, 0.11]])
PANDA = Path(__file__).resolve().parents[2] / "shared" / "data" / "panda_two_socket"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("shared")
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(61)
    true = perturbed_puma(nominal, rng)
    for name, frame in (("a", [1.4, -0.6, 0.3, 0.2, -0.3, 2.1]),
                        ("b", [-0.8, 1.2, 0.1, -1.0, 0.2, 0.4]),
                        ("c", [0.3, 1.5, -0.2, 0.5, 0.1, -0.7])):
        q = random_configurations(nominal, 30, rng)
        y = simulate_positions(true, q, rng, NOISE, frame, MARKER).positions
        write_tracker(d / f"{name}.csv", nominal, q, y, f"tracker_{name}")
    return d


def _calibrate(capsys, d, *extra):
    j = d / f"r{len(extra)}.json"
    code, out, err = run(capsys, "calibrate", "puma560", "--data", d / "a.csv", "--data",
                         d / "b.csv", "--validate", d / "c.csv", "--validation-frames",
                         "register", "--json", j, "-o", d / f"c{len(extra)}.yaml", *extra)
    assert code == 0, err
    return out, json.loads(j.read_text())


def test_two_files_one_reflector(files, capsys):
    out, shared = _calibrate(capsys, files, "--shared-marker")
    _, separate = _calibrate(capsys, files)
    assert "shared tool point: the files tracker_a, tracker_b see one point" in \
        " ".join(out.split())
    ps = {p["name"]: p for p in shared["parameters"]}
    est_s = [n for n, p in ps.items() if p["estimated"]]
    est_p = [p["name"] for p in separate["parameters"] if p["estimated"]]
    assert not any(".marker." in n for n in est_s)
    assert sum(".marker." in n for n in est_p) == 6
    assert len(est_s) == len(est_p) - 3                  # one point instead of two
    # the shared point is the robot's tool origin, estimated as such (not as the last
    # link's lengths, which carry a prior): the reflector, up to the flange's own errors
    # (d[6], a[6] and the offset it absorbs are off by millimetres in the true robot)
    for k, c in enumerate("xyz"):
        p = ps[f"tool.{c}"]
        assert p["estimated"] and abs(p["estimate"] - MARKER[0, k]) < 5e-3, p
    # the point lives in the robot now (its tool frame, or the last link's d, a, theta
    # offset that absorb it): the calibrated robot file carries the reflector
    cal = load_serial_robot(files / "c1.yaml")
    nominal = load_serial_robot("puma560")
    q = random_configurations(nominal, 5, np.random.default_rng(1))
    T_flange_nom = nominal.fk(q)
    P_cal = cal.fk(q)[:, :3, 3]
    P_nom = T_flange_nom[:, :3, 3] + T_flange_nom[:, :3, :3] @ MARKER[0]
    assert np.max(np.linalg.norm(P_cal - P_nom, axis=1)) < 5e-3     # robot errors: mm
    # a third placement of the tracker, frame re-registered, nothing else: the shared
    # point predicts it at the noise level
    v = shared["metrics"]["validation"]
    assert v["rms_position_m"] < 1.5 * np.sqrt(3) * NOISE, v
    (row,) = shared["metrics"]["validation_files"]
    assert row["note"] == "instrument re-registered on this file: frame and marker fitted"


def test_a_multi_marker_file_cannot_share(files, capsys, tmp_path):
    bad = tmp_path / "two.csv"
    bad.write_text("# kincal measurements: instrument=position\nq1_deg,q2_deg,q3_deg,q4_deg,"
                   "q5_deg,q6_deg,x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm\n"
                   + "\n".join(",".join(["1"] * 12) for _ in range(12)) + "\n")
    code, _, err = run(capsys, "calibrate", "puma560", "--data", files / "a.csv", "--data",
                       bad, "--shared-marker")
    assert code == 2 and "has 2 markers; a shared tool point needs one marker per file" in err


@pytest.mark.skipif(not PANDA.is_dir(), reason=f"Panda two-socket data not found at {PANDA}")
def test_panda_both_placements_with_one_ball(capsys, tmp_path):
    """Both placements of the artifact in one calibration, the ball shared: one ball
    offset (tool.x/y/z) instead of one per placement; each placement's sockets gather."""
    opts = ["--instrument", "two-socket", "--option", "length=50mm", "--option",
            "length_std=0.1mm", "--option", "point_std=0.05mm", "--option", "probe=vector",
            "--option", "probe_x=0.0777mm", "--option", "probe_y=-0.0421mm", "--option",
            "probe_z=30.128mm", "--option", "estimate_probe=true"]
    out = {}
    for label, extra in (("shared", ["--shared-marker"]), ("separate", [])):
        j = tmp_path / f"{label}.json"
        code, text, err = run(capsys, "calibrate", PANDA / "panda.urdf", "--base-link",
                              "panda_link0", "--tip-link", "panda_hand_tcp", "--data",
                              PANDA / "front", "--data", PANDA / "left", *opts, *extra,
                              "--json", j)
        assert code == 0, err
        out[label] = json.loads(j.read_text())
    ps = {p["name"]: p for p in out["shared"]["parameters"]}
    sep = {p["name"]: p for p in out["separate"]["parameters"]}
    assert not any(".probe." in n and p["estimated"] for n, p in ps.items())
    balls = sorted({n.rsplit(".", 2)[0] for n, p in sep.items()
                    if ".probe." in n and p["estimated"]})
    assert len(balls) == 2                                   # one ball per placement
    tool = np.array([ps[f"tool.{c}"]["estimate"] for c in "xyz"])
    sh, se = out["shared"]["metrics"]["train"], out["separate"]["metrics"]["train"]
    print(f"\nPanda, both placements, one ball: ball {np.round(tool * 1e3, 3)} mm from the "
          f"TCP; training coincidence RMS {sh['rms_coincidence_m'] * 1e3:.3f} mm, distance "
          f"max {sh['max_distance_m'] * 1e3:.3f} mm (separate balls: "
          f"{se['rms_coincidence_m'] * 1e3:.3f} / {se['max_distance_m'] * 1e3:.3f} mm)")
    for b in balls:
        other = np.array([sep[f"{b}.probe.{c}"]["estimate"] for c in "xyz"])
        assert np.linalg.norm(other - tool) < 2e-3               # the same ball, within mm
    assert out["shared"]["metrics"]["train"]["rms_coincidence_m"] < 0.3e-3


def test_tool_point_block_keeps_the_inner_fast_path():
    """The wrapped block's pieces (the position block's own system_pieces, in several
    pieces) give the triangle and residuals of its dense evaluation at marker 0."""
    from kincal.measure.base import stack
    from kincal.measure.instruments.position import PositionMeasurement
    from kincal.workflow.shared import ToolPointBlock

    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    q = random_configurations(robot, 25, rng)
    y = simulate_positions(robot, q, rng, NOISE, [1.0, 0.2, 0.3, 0.1, -0.2, 0.4]).positions
    block = ToolPointBlock(PositionMeasurement(q, y, NOISE, "tracker"))
    prob, theta = stack(robot, [block])
    theta = theta + rng.normal(0.0, 1e-3, theta.size)
    cols = [0, 3, 7, *range(prob.num_robot, len(theta))]
    c = prob.compressed(theta, columns=cols, rows=12)
    robot_t, (extra,) = prob.split(theta)
    r, Jr, Je = block.evaluate(robot_t, extra)
    J = np.hstack([Jr, Je])[:, cols]
    assert np.allclose(c.R.T @ c.R, J.T @ J, rtol=1e-9, atol=1e-6 * np.abs(J.T @ J).max())
    assert np.allclose(c.R.T @ c.z, J.T @ r, rtol=1e-9, atol=1e-9 * np.abs(J.T @ r).max())
    # both paths round the predicted positions (|y| ~ 1 m) to a few ulp; whitened by
    # sigma = 10 um that is ~1e-11 per residual, whatever the residual's size
    ulp = np.finfo(float).eps * np.abs(y).max() / NOISE
    assert np.allclose(prob.residuals(theta, spare_rows=2)[:-2], r, rtol=0, atol=20 * ulp)
    pieces = list(block.evaluate_chunks(robot_t, extra, rows=12))
    assert len(pieces) > 1
    assert np.allclose(np.concatenate([p[3] for p in pieces]), Je, rtol=1e-12, atol=1e-12)
