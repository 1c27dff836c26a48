"""Timing laws, paths and trajectories: boundary conditions, derivatives, IK consistency."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from kincal.cli import app
from kincal.errors import KincalError, UnreachableError
from kincal.motion.trajectory import (
    CartesianMotion,
    LinePath,
    TimingLaw,
    arc_through,
    cartesian_trajectory,
    cartesian_via,
    cubic,
    cubic_coefficients,
    joint_trajectory,
    line_motion,
    polyval,
    quintic,
    quintic_coefficients,
    synchronized_trapezoidal,
    trapezoidal,
    via_trajectory,
)
from kincal.robots.files import load_serial_robot
from kincal.spatial import log_so3, pose_error, xyzrpy_to_matrix

runner = CliRunner()


def _fd(f, t, h=1e-6):
    return (f(t + h) - f(t - h)) / (2 * h)


# ---------------------------------------------------------------- timing laws


def test_cubic_boundary_conditions_exact():
    law = cubic(2.5)
    s, sd, sdd = law(np.array([0.0, 2.5]))
    assert s.tolist() == [0.0, 1.0] and sd.tolist() == [0.0, 0.0]
    assert sdd.tolist() == [6 / 2.5**2, -6 / 2.5**2]   # a cubic cannot start at zero acc.


def test_quintic_boundary_conditions_exact():
    law = quintic(4.0)
    s, sd, sdd = law(np.array([0.0, 4.0]))
    assert s.tolist() == [0.0, 1.0]
    assert sd.tolist() == [0.0, 0.0] and sdd.tolist() == [0.0, 0.0]
    s_mid, sd_mid, _ = law(np.array([2.0]))
    assert s_mid[0] == 0.5 and sd_mid[0] == pytest.approx(1.875 / 4.0, rel=1e-15)


@pytest.mark.parametrize("law", [cubic(1.7), quintic(3.0), trapezoidal(0.8, 0.5, 2.0),
                                 trapezoidal(0.05, 0.5, 2.0), trapezoidal(0.8, 0.5, 2.0, 3.0),
                                 TimingLaw("linear", 2.0)])
def test_timing_derivatives_match_finite_differences(law):
    T = law.duration
    t = np.linspace(0.01 * T, 0.99 * T, 97)
    s, sd, sdd = law(t)
    # the trapezoid's acceleration jumps at t_a and T - t_a: skip those instants
    ok = np.ones_like(t, bool)
    if law.kind == "trapezoidal":
        ok = (np.abs(t - law.t_acc) > 1e-4) & (np.abs(t - (T - law.t_acc)) > 1e-4)
    np.testing.assert_allclose(sd[ok], _fd(lambda x: law(x)[0], t)[ok], atol=1e-8)
    np.testing.assert_allclose(sdd[ok], _fd(lambda x: law(x)[1], t)[ok], atol=1e-7)


def test_trapezoidal_limits_and_boundaries():
    L, v, a = 0.8, 0.5, 2.0
    law = trapezoidal(L, v, a)
    assert law.duration == pytest.approx(L / v + v / a, rel=1e-15)
    assert law.t_acc == pytest.approx(v / a, rel=1e-15)
    t = np.linspace(0, law.duration, 20001)
    s, sd, sdd = law(t)
    assert s[0] == 0.0 and s[-1] == pytest.approx(1.0, abs=1e-15)
    assert sd[0] == 0.0 and sd[-1] == 0.0
    assert sdd[0] == pytest.approx(a / L) and sdd[-1] == pytest.approx(-a / L)
    assert np.max(sd * L) == pytest.approx(v, rel=1e-12)
    assert np.max(np.abs(sdd * L)) == pytest.approx(a, rel=1e-12)
    # short move: a triangle that never reaches v_max
    tri = trapezoidal(0.05, 0.5, 2.0)
    assert tri.duration == pytest.approx(2 * math.sqrt(0.05 / 2.0), rel=1e-15)
    assert tri.s_dot_max * 0.05 < 0.5
    assert tri(np.array([tri.duration]))[0][0] == pytest.approx(1.0, abs=1e-15)
    # a longer duration lowers the cruise speed at the same acceleration
    slow = trapezoidal(L, v, a, duration=3.0)
    assert slow.duration == 3.0 and slow.s_dot_max * L < v
    assert slow(np.array([3.0]))[0][0] == pytest.approx(1.0, abs=1e-14)
    with pytest.raises(KincalError, match="at least"):
        trapezoidal(L, v, a, duration=1.0)
    with pytest.raises(KincalError):
        trapezoidal(0.0, v, a)


def test_polynomial_coefficients_meet_boundary_conditions():
    q0, q1 = np.array([0.1, -1.0]), np.array([1.2, 0.5])
    v0, v1 = np.array([0.3, 0.0]), np.array([-0.2, 0.4])
    a0, a1 = np.array([1.0, -2.0]), np.array([0.5, 0.0])
    T = 1.7
    for c, check_acc in ((cubic_coefficients(q0, q1, v0, v1, T), False),
                         (quintic_coefficients(q0, q1, v0, v1, a0, a1, T), True)):
        p, v, a = polyval(c, np.array([0.0, T]))
        np.testing.assert_allclose(p, [q0, q1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(v, [v0, v1], rtol=0, atol=1e-13)   # roundoff
        if check_acc:
            np.testing.assert_allclose(a, [a0, a1], rtol=0, atol=1e-12)


# ---------------------------------------------------------------- joint space


def test_joint_trajectory_endpoints_and_rates():
    q0, q1 = np.array([0.0, 1.0, -0.5]), np.array([1.0, -0.5, 0.25])
    tr = joint_trajectory(q0, q1, quintic(2.0), 0.001)
    assert tr.t[0] == 0 and tr.t[-1] == pytest.approx(2.0)
    np.testing.assert_array_equal(tr.q[0], q0)
    np.testing.assert_allclose(tr.q[-1], q1, atol=1e-15)
    np.testing.assert_array_equal(tr.qd[[0, -1]], 0.0)
    # central differences of the samples (O(dt^2) = 1e-6 truncation)
    np.testing.assert_allclose(tr.qd[1:-1], (tr.q[2:] - tr.q[:-2]) / 0.002, atol=1e-5)


def test_synchronized_trapezoidal_respects_every_joint_limit():
    q0, q1 = np.array([0.0, 0.0, 0.0]), np.array([1.0, -2.0, 0.5])
    v, a = np.array([1.0, 1.5, 0.2]), np.array([2.0, 5.0, 3.0])
    law = synchronized_trapezoidal(q0, q1, v, a)
    tr = joint_trajectory(q0, q1, law, 0.0005)
    peak_v = np.abs(tr.qd).max(0)
    peak_a = np.abs(tr.qdd).max(0)
    assert np.all(peak_v <= v * (1 + 1e-12)) and np.all(peak_a <= a * (1 + 1e-12))
    # the slowest joint (joint 3 for speed) is at its limit
    assert peak_v[2] == pytest.approx(0.2, rel=1e-12)


def test_via_points_spline_and_heuristic_cubic():
    P = np.array([[0.0, 0.0], [1.0, 0.5], [0.5, 1.5], [2.0, 1.0]])
    tk = np.array([0.0, 1.0, 2.5, 4.0])
    for method in ("spline", "cubic"):
        tr = via_trajectory(P, tk, 0.0005, method)
        idx = np.searchsorted(tr.t, tk - 1e-12)
        np.testing.assert_allclose(tr.q[idx], P, atol=1e-12)
        np.testing.assert_allclose(tr.qd[[0, -1]], 0.0, atol=1e-12)
        # velocity continuous everywhere (no jumps between samples beyond qdd * dt)
        jumps = np.abs(np.diff(tr.qd, axis=0)).max()
        assert jumps < np.abs(tr.qdd).max() * 0.0005 * 1.01
    spline = via_trajectory(P, tk, 0.0005, "spline")
    assert np.abs(np.diff(spline.qdd, axis=0)).max() < 0.05     # C2: continuous acceleration
    with pytest.raises(KincalError, match="increase"):
        via_trajectory(P, np.array([0.0, 1.0, 1.0, 2.0]), 0.01)


# ---------------------------------------------------------------- paths


def test_line_path_slerp_and_derivatives():
    T0 = xyzrpy_to_matrix([0.1, 0.2, 0.3, 0.1, -0.2, 0.3])
    T1 = xyzrpy_to_matrix([0.5, -0.1, 0.6, 1.0, 0.4, -1.2])
    path = LinePath(T0, T1)
    T, d1, d2 = path.at(np.array([0.0, 1.0]))
    np.testing.assert_allclose(T[0], T0, atol=1e-15)
    np.testing.assert_allclose(T[1], T1, atol=1e-14)
    s = np.linspace(0.05, 0.95, 7)
    h = 1e-6
    Tp, Tm = path.at(s + h), path.at(s - h)
    Ts, d1, d2 = path.at(s)
    fd = np.concatenate([(Tp[0][:, :3, 3] - Tm[0][:, :3, 3]) / (2 * h),
                         log_so3(Tp[0][:, :3, :3] @ np.swapaxes(Tm[0][:, :3, :3], 1, 2))
                         / (2 * h)], 1)
    np.testing.assert_allclose(d1, fd, atol=1e-8)
    assert np.all(d2 == 0)
    assert path.angle == pytest.approx(np.linalg.norm(log_so3(T0[:3, :3].T @ T1[:3, :3])))


def test_arc_through_three_points():
    T0 = xyzrpy_to_matrix([0.5, 0.0, 0.2, 0, 0, 0])
    T1 = xyzrpy_to_matrix([0.0, 0.5, 0.2, 0, 0, 1.0])
    via = np.array([0.5 / math.sqrt(2), 0.5 / math.sqrt(2), 0.2])
    arc = arc_through(T0, via, T1)
    np.testing.assert_allclose(arc.centre, [0, 0, 0.2], atol=1e-15)
    assert arc.angle == pytest.approx(math.pi / 2) and arc.radius == pytest.approx(0.5)
    T, d1, d2 = arc.at(np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(T[:, :3, 3], [T0[:3, 3], via, T1[:3, 3]], atol=1e-15)
    np.testing.assert_allclose(T[2], T1, atol=1e-15)
    s = np.linspace(0.1, 0.9, 5)
    h = 1e-6
    np.testing.assert_allclose(d1[:, :3][:1], ((arc.at(np.array([0.0 + h]))[0][:, :3, 3]
                                                - arc.at(np.array([0.0 - h]))[0][:, :3, 3])
                                               / (2 * h)), atol=1e-8)
    p = lambda x: arc.at(x)[0][:, :3, 3]  # noqa: E731
    np.testing.assert_allclose(arc.at(s)[1][:, :3], _fd(p, s), atol=1e-8)
    np.testing.assert_allclose(arc.at(s)[2][:, :3], (p(s + 1e-4) - 2 * p(s) + p(s - 1e-4))
                               / 1e-8, atol=1e-5)
    # the arc through the via point the long way round
    far = arc_through(T0, np.array([-0.5, 0.0, 0.2]), T1)
    assert far.angle == pytest.approx(3 * math.pi / 2)
    with pytest.raises(KincalError, match="collinear"):
        arc_through(T0, np.array([0.25, 0.25, 0.2]), T1)


# ---------------------------------------------------------------- Cartesian


@pytest.fixture(scope="module")
def puma_line():
    robot = load_serial_robot("puma560")
    q0 = np.array([0.2, 0.9, -0.6, 0.3, 0.8, 0.1])
    T0 = robot.fk(q0)
    T1 = robot.fk(q0 + np.array([0.3, -0.2, 0.2, 0.3, -0.3, 0.4]))
    motion = line_motion(T0, T1, "quintic", duration=2.0)
    return robot, q0, motion, cartesian_trajectory(robot, motion, q0, 0.002)


def test_cartesian_line_joints_reproduce_the_poses(puma_line):
    robot, q0, motion, tr = puma_line
    e = pose_error(tr.x, robot.fk(tr.q))
    assert np.abs(e).max() <= 1e-9
    np.testing.assert_allclose(tr.q[0], q0, atol=1e-8)       # stays on q0's branch
    # the path is straight: positions on the segment
    a, b = tr.x[0, :3, 3], tr.x[-1, :3, 3]
    d = (b - a) / np.linalg.norm(b - a)
    r = tr.position - a
    assert np.abs(r - np.outer(r @ d, d)).max() < 1e-15


def test_cartesian_line_joint_rates(puma_line):
    robot, _, _, tr = puma_line
    J = robot.jacobian(tr.q)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", J, tr.qd), tr.xd, atol=1e-12)
    # q_ddot against central differences of q_dot (O(dt^2) truncation at dt = 2 ms)
    fd = (tr.qd[2:] - tr.qd[:-2]) / (2 * 0.002)
    np.testing.assert_allclose(tr.qdd[1:-1], fd, atol=2e-4 * np.abs(tr.qdd).max())


def test_cartesian_via_and_unreachable_line():
    robot = load_serial_robot("puma560")
    q0 = np.array([0.2, 0.9, -0.6, 0.3, 0.8, 0.1])
    T0 = robot.fk(q0)
    poses = [T0, T0 @ xyzrpy_to_matrix([0.05, 0, 0, 0, 0, 0]),
             T0 @ xyzrpy_to_matrix([0.05, 0.05, 0, 0, 0, 0.2])]
    tr = cartesian_via(robot, poses, q0, 0.01, durations=[1.0, 1.5])
    assert tr.duration == pytest.approx(2.5)
    np.testing.assert_allclose(tr.x[-1], poses[-1], atol=1e-12)
    assert np.abs(pose_error(tr.x, robot.fk(tr.q))).max() <= 1e-9
    far = T0.copy()
    far[:3, 3] = [2.0, 0.0, 0.0]
    with pytest.raises(UnreachableError, match="cannot be followed"):
        cartesian_trajectory(robot, line_motion(T0, far, "cubic", duration=1.0), q0, 0.01)


def test_trajectory_csv_and_plot(tmp_path, puma_line):
    *_, tr = puma_line
    tr.to_csv(tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    head = lines[0].split(",")
    assert head[:3] == ["t_s", "q1_rad", "q2_rad"]
    assert "q1_dot_rad_s" in head and "q6_ddot_rad_s2" in head
    assert "x_m" in head and "wz_rad_s" in head
    data = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:, 1:7], tr.q, atol=1e-11)
    tr.plot(tmp_path / "t.png")
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_motion_is_path_times_timing():
    T0, T1 = np.eye(4), xyzrpy_to_matrix([0.3, 0.0, 0.0, 0, 0, 0.5])
    mo = CartesianMotion(LinePath(T0, T1), quintic(2.0))
    _, v, a = mo(np.array([0.0, 1.0, 2.0]))
    assert np.all(v[[0, 2]] == 0) and np.all(a[[0, 2]] == 0)
    assert v[1, 0] == pytest.approx(0.3 * 1.875 / 2.0)
    assert v[1, 5] == pytest.approx(0.5 * 1.875 / 2.0)


# ---------------------------------------------------------------- CLI


def test_cli_trajectory_joint_and_line(tmp_path):
    res = runner.invoke(app, ["trajectory", "puma560", "--start", "0,80,-80,0,30,0",
                              "--end", "40,60,-100,20,50,10", "--deg", "--timing",
                              "trapezoidal", "--v-max", "1", "--a-max", "2", "--dt", "10ms",
                              "--out-dir", str(tmp_path / "j"), "--json", "-"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert max(out["max_abs_qd"]) <= 1 + 1e-12 and max(out["max_abs_qdd"]) <= 2 + 1e-12
    assert (tmp_path / "j" / "trajectory.csv").read_text().startswith("t_s,q1_rad,")
    assert (tmp_path / "j" / "trajectory.png").exists()
    res = runner.invoke(app, ["trajectory", "puma560", "--start", "0,80,-80,0,30,0",
                              "--end", "10,70,-90,0,40,0", "--deg", "--space", "line",
                              "--duration", "1s", "--dt", "20ms", "--out-dir", str(tmp_path / "l")])
    assert res.exit_code == 0, res.output
    assert "trajectory.csv" in res.output
    res = runner.invoke(app, ["trajectory", "puma560", "--start", "0,80,-80,0,30,0",
                              "--end", "10,70,-90,0,40,0", "--deg", "--space", "arc",
                              "--duration", "1s", "--out-dir", str(tmp_path / "a")])
    assert res.exit_code == 2 or "via-position" in str(res.exception)
