"""Differential kinematics and CLIK, including the spherical-manipulator report's experiment."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from kincal.cli import app
from kincal.errors import KincalError
from kincal.motion.clik import (
    SPHERICAL_ARM_P_F,
    SPHERICAL_ARM_P_I,
    SPHERICAL_ARM_Q0,
    SPHERICAL_ARM_QF,
    clik,
    generalized_inverse,
    manipulability,
    run_spherical_arm,
    spherical_arm_robot,
)
from kincal.motion.ik_closed_form import ik_spherical_rrp
from kincal.motion.trajectory import CartesianMotion, LinePath, line_motion, quintic
from kincal.robots.files import load_serial_robot
from kincal.spatial import pose_error

runner = CliRunner()


@pytest.fixture(scope="module")
def seed_runs():
    return run_spherical_arm("inverse"), run_spherical_arm("dls", damping=0.1)


# ---------------------------------------------------------------- the spherical arm


def test_spherical_arm_endpoints_by_closed_form():
    robot = spherical_arm_robot()
    np.testing.assert_allclose(robot.fk(SPHERICAL_ARM_Q0)[:3, 3], SPHERICAL_ARM_P_I, atol=1e-15)
    np.testing.assert_allclose(robot.fk(SPHERICAL_ARM_QF)[:3, 3], SPHERICAL_ARM_P_F, atol=1e-15)
    cf = ik_spherical_rrp(robot, np.stack([SPHERICAL_ARM_P_I, SPHERICAL_ARM_P_F]))
    np.testing.assert_allclose(cf.q[0, 0], SPHERICAL_ARM_Q0, atol=1e-14)
    np.testing.assert_allclose(cf.q[1, 0], SPHERICAL_ARM_QF, atol=1e-7)
    # theta2 = 0 at q_f: the 3x3 position Jacobian is singular there (|det J| = d3^2 |s2|)
    J = robot.jacobian(SPHERICAL_ARM_QF)[:3]
    assert abs(np.linalg.det(J)) < 1e-15
    q = np.array([0.3, 0.7, 0.4])
    assert abs(np.linalg.det(robot.jacobian(q)[:3])) == pytest.approx(0.4**2 * math.sin(0.7))


def test_spherical_arm_dls_reaches_p_f_with_bounded_velocities(seed_runs):
    _, dls = seed_runs
    s = dls.summary()
    print(f"\nDLS (k = 0.1 m, K = 50/s): final |e| = {s['final_position_error_m']:.3e} m, "
          f"max |theta2_dot| = {s['max_abs_theta2_dot_rad_s']:.3f} rad/s, max distance from "
          f"the line {s['max_path_deviation_m']:.4f} m")
    assert dls.position_error[-1] < 1e-5
    assert np.abs(dls.qd).max() < 2.0                     # rad/s and m/s
    np.testing.assert_allclose(dls.q[-1], SPHERICAL_ARM_QF, atol=0.02)
    # the line enters the unreachable cylinder rho < d2 = 1 m; the closest reachable
    # point is on its wall, so no method can do better than 1 - 0.8698 m
    a, d = SPHERICAL_ARM_P_I[:2], SPHERICAL_ARM_P_F[:2] - SPHERICAL_ARM_P_I[:2]
    closest = abs(a[0] * d[1] - a[1] * d[0]) / np.linalg.norm(d)
    assert dls.path_deviation().max() == pytest.approx(1.0 - closest, abs=2e-4)
    rho = np.hypot(dls.position[:, 0], dls.position[:, 1])
    assert rho.min() > 1.0 - 1e-9                         # FK can never enter the cylinder


def test_spherical_arm_inverse_spikes_in_joint2(seed_runs):
    inv, dls = seed_runs
    t_enter = inv.meta["events"][0][0]
    assert 0.95 < t_enter < 1.05
    ratio = np.abs(inv.qd[:, 1]).max() / np.abs(dls.qd[:, 1]).max()
    # near theta2 -> 0, before the arm leaves the line: up to the first zero of theta2
    cross = int(np.flatnonzero(np.diff(np.sign(inv.q[:, 1])) != 0)[0]) + 2
    near = np.abs(inv.qd[:cross, 1]).max() / np.abs(dls.qd[:cross, 1]).max()
    print(f"\npeak |theta2_dot|: J^-1 {np.abs(inv.qd[:, 1]).max():.3g} rad/s vs DLS "
          f"{np.abs(dls.qd[:, 1]).max():.3g} rad/s, ratio {ratio:.3g}; up to the first "
          f"theta2 = 0 (t = {inv.t[cross - 1]:.3f} s) ratio {near:.3g}")
    assert ratio > 1e3
    assert near > 10
    assert abs(inv.q[cross - 2, 1]) < 0.2               # the spike is at theta2 -> 0
    assert inv.manipulability[: cross - 1].min() < 0.05 * inv.manipulability[0]
    # J^-1 tracks the line exactly while it can (error small before the cylinder)
    before = inv.t < t_enter - 0.1
    assert inv.position_error[before].max() < 1e-3


def test_feasible_line_all_inversions_track():
    robot = spherical_arm_robot()
    q0 = np.array([0.2, 0.9, 0.6])
    q1 = np.array([0.6, 1.2, 0.8])
    T0, T1 = robot.fk(q0), robot.fk(q1)
    motion = line_motion(T0, T1, "quintic", duration=2.0)
    errs = {}
    for m in ("inverse", "pinv", "dls", "adaptive", "transpose"):
        r = clik(robot, motion, q0, 0.004, gain=50, method=m, damping=0.01, threshold=0.05)
        errs[m] = r.position_error.max()
        if m == "adaptive":
            assert np.all(r.damping == 0)             # far from singular: no damping at all
    assert errs["inverse"] < 1e-4 and errs["pinv"] == pytest.approx(errs["inverse"], rel=1e-9)
    assert errs["adaptive"] == pytest.approx(errs["inverse"], rel=1e-9)
    assert errs["dls"] < 2e-4
    assert errs["transpose"] < 0.05                    # no feed-forward: lags the line


def test_rk4_is_more_accurate_than_euler():
    robot = spherical_arm_robot()
    q0 = np.array([0.2, 0.9, 0.6])
    motion = line_motion(robot.fk(q0), robot.fk(np.array([0.6, 1.2, 0.8])), "quintic",
                         duration=1.0)
    e_euler = clik(robot, motion, q0, 0.01, gain=5, integrator="euler").position_error.max()
    e_rk4 = clik(robot, motion, q0, 0.01, gain=5, integrator="rk4").position_error.max()
    assert e_rk4 < 0.05 * e_euler


@pytest.mark.parametrize("orientation", ["axis_angle", "zyz", "rpy"])
def test_pose_task_on_puma(orientation):
    robot = load_serial_robot("puma560")
    q0 = np.array([0.2, 0.9, -0.6, 0.3, 0.8, 0.1])
    q1 = q0 + np.array([0.2, -0.1, 0.15, 0.2, -0.2, 0.3])
    motion = line_motion(robot.fk(q0), robot.fk(q1), "quintic", duration=1.0)
    r = clik(robot, motion, q0, 0.002, gain=100, task="pose", orientation=orientation)
    e = pose_error(r.pose_desired, r.pose)
    assert np.abs(e).max() < 1e-4
    assert np.abs(e[-1]).max() < 1e-5


def test_generalized_inverses_against_independent_formulas():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(5, 3, 3))
    Jinv, _ = generalized_inverse(J, "inverse")
    np.testing.assert_allclose(Jinv @ J, np.tile(np.eye(3), (5, 1, 1)), atol=1e-10)
    np.testing.assert_allclose(generalized_inverse(J, "pinv")[0], Jinv, atol=1e-9)
    k = 0.3
    dls, lam2 = generalized_inverse(J, "dls", damping=k)
    JT = np.swapaxes(J, 1, 2)
    alt = np.linalg.solve(JT @ J + k**2 * np.eye(3), JT)   # (J^T J + k^2 I)^-1 J^T
    np.testing.assert_allclose(dls, alt, atol=1e-12)
    assert np.all(lam2 == k**2)
    # adaptive: k^2 = k_max^2 (1 - (s_min / eps)^2) below eps, 0 above
    Js = np.diag([1.0, 0.5, 0.02])[None]
    _, lam_a = generalized_inverse(Js, "adaptive", damping=0.2, threshold=0.1)
    assert lam_a[0] == pytest.approx(0.04 * (1 - 0.2**2))
    _, lam_b = generalized_inverse(np.eye(3)[None], "adaptive", damping=0.2, threshold=0.1)
    assert lam_b[0] == 0
    np.testing.assert_allclose(generalized_inverse(J, "transpose")[0], JT)
    with pytest.raises(KincalError, match="square"):
        generalized_inverse(rng.normal(size=(3, 4)), "inverse")
    with pytest.raises(KincalError, match="singular"):
        generalized_inverse(np.zeros((3, 3)), "inverse")


def test_manipulability_and_condition():
    J = np.diag([2.0, 0.5, 0.1])
    w, cond, smin = manipulability(J)
    assert w == pytest.approx(0.1) and cond == pytest.approx(20.0) and smin == pytest.approx(0.1)
    robot = spherical_arm_robot()
    q = np.array([[0.1, 0.5, 0.7], [0.4, -1.0, 0.3]])
    w2, _, _ = manipulability(robot.jacobian(q)[:, :3])
    np.testing.assert_allclose(w2, np.abs(np.linalg.det(robot.jacobian(q)[:, :3])))


def test_bad_settings_raise():
    robot = spherical_arm_robot()
    mo = CartesianMotion(LinePath(np.eye(4), np.eye(4)), quintic(1.0))
    with pytest.raises(KincalError, match="inversion"):
        clik(robot, mo, SPHERICAL_ARM_Q0, 0.01, method="magic")  # type: ignore[arg-type]
    with pytest.raises(KincalError, match="positive definite"):
        clik(robot, mo, SPHERICAL_ARM_Q0, 0.01, gain=-1.0)
    with pytest.raises(KincalError, match="integrator"):
        clik(robot, mo, SPHERICAL_ARM_Q0, 0.01, integrator="leapfrog")  # type: ignore[arg-type]


def test_result_csv_has_units(tmp_path, seed_runs):
    _, dls = seed_runs
    dls.to_csv(tmp_path / "c.csv")
    head = (tmp_path / "c.csv").read_text().splitlines()[0].split(",")
    assert head[:4] == ["t_s", "theta1_rad", "theta2_rad", "d3_m"]
    assert "theta2_dot_rad_s" in head and "d3_dot_m_s" in head and "position_error_m" in head
    data = np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)
    assert data.shape == (len(dls.t), len(head))


def test_cli_clik_writes_csv_plots_and_summary(tmp_path):
    """kincal clik ROBOT: the spherical arm's line p_i -> p_f, from the command line."""
    from kincal.motion.clik import SPHERICAL_ARM_P_F, SPHERICAL_ARM_P_I

    p_f = ",".join(f"{v * 1e3:.9f}" for v in SPHERICAL_ARM_P_F) + "mm"
    res = runner.invoke(app, ["clik", "spherical_rrp", "--start", "0,45deg,0.5m",
                              f"--end-position={p_f}", "--out-dir", str(tmp_path),
                              "--dt", "4ms", "--json", "-"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    inv, dls = out["runs"]
    assert inv["method"] == "inverse" and dls["method"] == "dls"
    assert inv["peak_speed_ratio_first_over_this"] == [1.0, 1.0, 1.0]
    assert dls["peak_speed_ratio_first_over_this"][1] > 1e3      # theta2 blows up with J^-1
    # what does not depend on the step: when J^-1's theta2 passes DLS's peak, and when
    # J^-1 leaves the path (the line meets the singularity at t ~ 1.0 s)
    ex = dls["first_exceeds_this_peak"]
    assert ex["joint"] == "theta2" and 0.85 < ex["time_s"] < 0.95
    assert 0.95 < inv["off_path_time_s"] < 1.05
    assert dls["final_position_error_m"] < 1e-5
    assert dls["max_path_deviation_m"] == pytest.approx(0.130, abs=2e-3)   # the least possible
    np.testing.assert_allclose(out["start_position_m"], SPHERICAL_ARM_P_I, atol=1e-15)
    np.testing.assert_allclose(out["end_position_m"], SPHERICAL_ARM_P_F, atol=1e-12)
    for name in ("clik_inverse.csv", "clik_dls.csv", "clik_compare.png"):
        assert (tmp_path / name).stat().st_size > 0


def test_cli_clik_joint_speed_units(tmp_path):
    """Joint speeds in deg/s by default and with --deg (also with --si), rad/s with --si
    alone; the printed numbers follow their unit."""
    from kincal.motion.clik import SPHERICAL_ARM_P_F

    p_f = ",".join(f"{v * 1e3:.9f}" for v in SPHERICAL_ARM_P_F) + "mm"
    args = ["clik", "spherical_rrp", "--start", "0,45deg,0.5m", f"--end-position={p_f}",
            "--out-dir", str(tmp_path), "--dt", "20ms"]
    for extra, unit in (([], "deg"), (["--si"], "rad"), (["--si", "--deg"], "deg")):
        res = runner.invoke(app, args + extra, env={"COLUMNS": "250"})
        assert res.exit_code == 0, res.output
        assert f"max |theta1'| [{unit}/s]" in res.stdout, (extra, res.stdout)
        assert "max |d3'| [m/s]" in res.stdout
