"""Numerical IK: batched Levenberg-Marquardt checked by FK and against the closed forms."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.motion.ik import (
    IKSolution,
    IKSolutions,
    check_solutions,
    default_q0,
    project_to_limits,
    reach_bound,
    solve_ik,
)
from kincal.motion.ik_closed_form import ik_puma560, ik_scara, ik_spherical_rrp
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import load_serial_robot
from kincal.spatial import pose_error, xyzrpy_to_matrix

TOL = 1e-9


def _wrapped_distance(a: np.ndarray, b: np.ndarray, revolute: np.ndarray) -> np.ndarray:
    d = a - b
    return np.where(revolute, np.abs(np.pi - np.mod(np.pi - d, 2 * np.pi)), np.abs(d))


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


@pytest.fixture(scope="module")
def puma_run(puma):
    """10 000 random reachable poses (FK of configurations inside the limits), solved once."""
    rng = np.random.default_rng(20240601)
    lim = puma.joint_limits
    q_true = rng.uniform(lim[:, 0], lim[:, 1], size=(10_000, 6))
    T = puma.fk(q_true)
    t0 = time.perf_counter()
    sol = solve_ik(puma, T)
    elapsed = time.perf_counter() - t0
    print(f"\nPUMA 560, 10 000 poses: {sol.success_rate:.2%} solved in {elapsed:.2f} s "
          f"({elapsed / 1e4 * 1e6:.0f} us per target), mean iterations "
          f"{sol.iterations.mean():.1f}, restart rounds {np.bincount(sol.restarts).tolist()}")
    return q_true, T, sol


def test_puma_10000_poses_all_solved_and_checked_by_fk(puma, puma_run):
    _, T, sol = puma_run
    assert sol.success.all(), [sol.reason[i] for i in sol.failures()[:5]]
    # every returned solution, checked by FK independently of the solver's bookkeeping
    ep, eo = check_solutions(puma, T, sol.q)
    assert ep.max() <= TOL and eo.max() <= TOL
    e = pose_error(T, puma.fk(sol.q))
    assert np.linalg.norm(e[:, :3], axis=1).max() <= TOL
    assert np.linalg.norm(e[:, 3:], axis=1).max() <= TOL
    np.testing.assert_allclose(sol.position_error, ep, rtol=0, atol=1e-15)
    np.testing.assert_allclose(sol.orientation_error, eo, rtol=0, atol=1e-15)
    lim = puma.joint_limits
    assert np.all((sol.q >= lim[:, 0]) & (sol.q <= lim[:, 1]))
    assert all(r == "" for r in sol.reason)


def test_puma_numerical_solutions_are_closed_form_branches(puma, puma_run):
    _, T, sol = puma_run
    cf = ik_puma560(puma, T)
    # each closed-form branch's FK equals the target
    Tb = puma.fk(cf.q.reshape(-1, 6)).reshape(-1, 8, 4, 4)
    eb = pose_error(T[:, None], Tb)
    assert cf.reachable.all()
    assert np.abs(eb).max() <= 1e-10
    # each numerical solution is one of the 8 branches (angles modulo 2 pi); the
    # distance allowed is what the pose tolerance permits: |dq| <= |e| / sigma_min(J)
    rev = np.ones(6, bool)
    d = _wrapped_distance(sol.q[:, None, :], cf.q, rev).max(axis=2)
    nearest = d.min(axis=1)
    s_min = np.linalg.svd(puma.jacobian(sol.q), compute_uv=False)[:, -1]
    allowed = 2 * math.sqrt(2) * TOL / s_min + 1e-12
    assert np.all(nearest <= allowed), np.max(nearest / allowed)
    # ... and one that respects the joint limits
    branch = np.argmin(d, axis=1)
    assert cf.within_limits[np.arange(len(T)), branch].all()


def test_iksolutions_record_interface(puma, puma_run):
    _, T, sol = puma_run
    assert isinstance(sol, IKSolutions) and len(sol) == 10_000
    one = sol[3]
    assert isinstance(one, IKSolution)
    assert one.q.shape == (6,) and one.success is True and one.reason == ""
    assert one.iterations == sol.iterations[3] and one.restarts == sol.restarts[3]
    assert one.position_error == sol.position_error[3]
    assert sol.q.shape == (10_000, 6) and sol.success.dtype == bool
    assert "10000/10000 solved" in repr(sol)


def test_q0_near_a_solution_returns_that_solution(puma):
    rng = np.random.default_rng(1)
    lim = puma.joint_limits
    q = rng.uniform(lim[:, 0] + 0.2, lim[:, 1] - 0.2, size=(800, 6))
    # away from singularities, where a 0.05 rad nudge cannot cross to another branch
    q = q[np.linalg.svd(puma.jacobian(q), compute_uv=False)[:, -1] > 0.1][:500]
    sol = solve_ik(puma, puma.fk(q), q0=q + rng.normal(0, 0.05, q.shape))
    assert sol.success.all()
    assert np.abs(sol.q - q).max() < 1e-6
    assert (sol.restarts == 0).all()
    assert sol.iterations.max() <= 10


def test_single_target_and_single_q0(puma):
    q = np.array([0.3, 1.2, -0.8, 0.4, 0.9, -0.2])
    sol = solve_ik(puma, puma.fk(q), q0=q + 0.01)
    assert len(sol) == 1 and sol.success[0]
    np.testing.assert_allclose(sol.q[0], q, atol=1e-8)


def test_unreachable_far_target_has_reason_with_distance(puma):
    centre, radius = reach_bound(puma)
    assert radius == pytest.approx(0.4318 + 0.0203 + 0.15005 + 0.4318)
    T = np.tile(np.eye(4), (2, 1, 1))
    T[0, :3, 3] = [2.0, 0.0, 0.0]
    T[1, :3, 3] = [0.0, 0.0, -1.5]
    sol = solve_ik(puma, T)
    assert not sol.success.any()
    for i, dist in enumerate((2.0, 1.5)):
        assert sol.reason[i] == f"unreachable: {dist - radius:.3g} m beyond reach"
        assert sol.iterations[i] == 0
    assert np.all(sol.position_error > 0.9)


def test_unreachable_within_bound_is_a_failure_never_a_success(puma):
    # 0.95 m from the shoulder: inside the crude bound (1.034 m) but beyond the true
    # reach (sqrt((a2 + |(a3, d4)|)^2 + d3^2) = 0.877 m)
    T = np.eye(4)
    T[:3, 3] = [0.95, 0.0, 0.0]
    sol = solve_ik(puma, T, restarts=2)
    assert not sol.success[0]
    assert sol.reason[0] != ""
    assert sol.position_error[0] > 0.95 - 0.8771


def test_joint_limits_block_the_only_solutions(puma):
    q = np.array([1.5, 0.8, -0.5, 0.4, 0.9, 0.2])
    narrow = [DHLink(a=L.a, d=L.d, alpha=L.alpha, lower=L.lower, upper=L.upper)
              for L in _puma_links(puma)]
    narrow[0] = DHLink(a=0.0, d=0.0, alpha=math.pi / 2, lower=-0.2, upper=0.2)
    robot = from_dh(narrow, name="puma_narrow")
    sol = solve_ik(robot, puma.fk(q), restarts=3)
    assert not sol.success[0]
    assert sol.reason[0].startswith(("joint limits", "unreachable", "no convergence"))
    assert -0.2 <= sol.q[0, 0] <= 0.2
    # without limits the same target is solved
    free = solve_ik(robot, puma.fk(q), respect_limits=False)
    assert free.success[0]
    assert check_solutions(robot, puma.fk(q), free.q)[0][0] <= TOL


def _puma_links(puma):
    from kincal.robots.dh import dh_links

    return dh_links(puma)


def test_position_only_spherical_arm_matches_closed_form():
    robot = load_serial_robot("spherical_rrp")
    rng = np.random.default_rng(3)
    q = np.column_stack([rng.uniform(-3, 3, 2000), rng.uniform(-3, 3, 2000),
                         rng.uniform(0.05, 1.0, 2000)])
    p = robot.fk(q)[:, :3, 3]
    sol = solve_ik(robot, p, mask="position")
    assert sol.success.all()
    ep, eo = check_solutions(robot, p, sol.q, mask="position")
    assert ep.max() <= TOL and np.all(eo == 0) and np.all(sol.orientation_error == 0)
    cf = ik_spherical_rrp(robot, p)
    rev = np.array([True, True, False])
    d = _wrapped_distance(sol.q[:, None, :], cf.q, rev).max(axis=2).min(axis=1)
    s_min = np.linalg.svd(robot.jacobian(sol.q)[:, :3], compute_uv=False)[:, -1]
    assert np.all(d <= 2 * TOL / s_min + 1e-12)


def test_position_target_inside_the_spherical_arms_hole_fails():
    robot = load_serial_robot("spherical_rrp")
    # rho = 0.5 m < d2 = 1 m: no joint values reach it
    sol = solve_ik(robot, np.array([[0.5, 0.0, 0.2]]), mask="position", restarts=2)
    assert not sol.success[0] and sol.reason[0]
    assert sol.position_error[0] >= 0.5 - 1e-9


def test_scara_pose_ik_matches_closed_form_and_tilt_fails():
    robot = load_serial_robot("scara")
    rng = np.random.default_rng(4)
    lim = robot.joint_limits
    q = np.column_stack([rng.uniform(lim[0, 0], lim[0, 1], 500),
                         rng.uniform(lim[1, 0], lim[1, 1], 500),
                         rng.uniform(lim[2, 0], lim[2, 1], 500), rng.uniform(-3, 3, 500)])
    T = robot.fk(q)
    sol = solve_ik(robot, T)
    assert sol.success.all()
    cf = ik_scara(robot, T)
    rev = np.array([True, True, False, True])
    d = _wrapped_distance(sol.q[:, None, :], cf.q, rev).max(axis=2).min(axis=1)
    J = robot.jacobian(sol.q)[:, [0, 1, 2, 5]]          # the 4 controllable rows
    s_min = np.linalg.svd(J, compute_uv=False)[:, -1]
    assert np.all(d <= 2 * math.sqrt(2) * TOL / s_min + 1e-12)
    tilted = T[:3] @ xyzrpy_to_matrix([0, 0, 0, 0.1, 0, 0])
    bad = solve_ik(robot, tilted, restarts=1)
    assert not bad.success.any() and all(bad.reason)
    assert np.all(bad.orientation_error > 0.05)


def test_six_bool_mask_selects_rows(puma):
    q = np.array([[0.2, 1.0, -1.0, 0.3, 0.7, 0.1], [-0.4, 1.4, -0.6, -0.5, -0.8, 2.0]])
    T = puma.fk(q)
    mask = [True, True, True, False, False, True]
    sol = solve_ik(puma, T, mask=mask)
    assert sol.success.all()
    e = pose_error(T, puma.fk(sol.q))
    assert np.abs(e[:, [0, 1, 2, 5]]).max() <= TOL
    assert sol.mask == tuple(mask)


def test_respect_limits_false_may_leave_limits_but_solves(puma):
    rng = np.random.default_rng(5)
    lim = puma.joint_limits
    q = rng.uniform(lim[:, 0], lim[:, 1], size=(300, 6))
    sol = solve_ik(puma, puma.fk(q), respect_limits=False)
    assert sol.success.all()
    ep, eo = check_solutions(puma, puma.fk(q), sol.q)
    assert ep.max() <= TOL and eo.max() <= TOL


def test_tolerances_are_on_the_error_itself(puma):
    q = np.array([0.2, 1.0, -1.0, 0.3, 0.7, 0.1])
    T = puma.fk(q)
    loose = solve_ik(puma, T, tol_position=1e-3, tol_orientation=1e-3)
    assert loose.success[0]
    assert loose.position_error[0] <= 1e-3 and loose.orientation_error[0] <= 1e-3
    ep, eo = check_solutions(puma, T, loose.q)
    assert ep[0] == pytest.approx(loose.position_error[0], abs=1e-15)


def test_error_jacobian_is_minus_geometric_jacobian_at_a_solution(puma):
    """d e / d q = -J at e = 0 (central differences), which the LM step relies on."""
    q = np.array([0.3, 0.9, -0.7, 0.5, 1.1, -0.4])
    T = puma.fk(q)
    h = 1e-6
    num = np.empty((6, 6))
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        num[:, j] = (pose_error(T, puma.fk(q + dq)) - pose_error(T, puma.fk(q - dq))) / (2 * h)
    np.testing.assert_allclose(num, -puma.jacobian(q), atol=1e-8)


def test_bad_inputs_raise_kincal_errors(puma):
    with pytest.raises(KincalError, match="mask"):
        solve_ik(puma, np.eye(4), mask="elbow")
    with pytest.raises(KincalError, match="mask"):
        solve_ik(puma, np.eye(4), mask=[True, False])
    with pytest.raises(KincalError, match="position targets"):
        solve_ik(puma, np.zeros((2, 3)))
    with pytest.raises(KincalError, match="shape"):
        solve_ik(puma, np.zeros((2, 5)))
    with pytest.raises(KincalError, match="q0"):
        solve_ik(puma, np.tile(np.eye(4), (3, 1, 1)), q0=np.zeros((2, 6)))
    with pytest.raises(KincalError, match="finite"):
        solve_ik(puma, np.full((4, 4), np.nan))


def test_helpers(puma):
    lim = puma.joint_limits
    np.testing.assert_allclose(default_q0(puma), lim.mean(axis=1))
    rev = np.ones(6, bool)
    q = np.array([3.5, 0.0, 0.0, 0.0, 2.0, 0.0])   # q1 > 160 deg; q5 > 100 deg
    p = project_to_limits(q, lim[:, 0], lim[:, 1], rev)
    assert p[0] == pytest.approx(3.5 - 2 * np.pi)  # shifted by 2 pi, inside
    assert p[4] == pytest.approx(lim[4, 1])          # no shift fits: clipped


# ---------------------------------------------------------------- CLI


def test_cli_ik_pose_and_position(puma):
    import json

    from typer.testing import CliRunner

    from kincal.cli import app

    runner = CliRunner()
    q = np.array([0.3, 1.2, -0.8, 0.4, 0.9, -0.2])
    T = puma.fk(q)
    from kincal.spatial import matrix_to_xyzrpy

    v = matrix_to_xyzrpy(T)
    res = runner.invoke(app, ["ik", "puma560", "--pose", ",".join(f"{x:.17g}" for x in v),
                              "--all-branches", "--json", "-"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["success"] and out["fk_check"]["position_error_m"] <= TOL
    assert out["fk_check"]["orientation_error_rad"] <= TOL
    assert len(out["branches"]) == 8
    assert sum(b["within_limits"] for b in out["branches"]) >= 1
    res = runner.invoke(app, ["ik", "spherical_rrp", "--position", "0.3,1.0,0.4"])
    assert res.exit_code == 0, res.output
    assert "solved" in res.output and "theta1" in res.output


def test_cli_ik_unreachable_exits_2_with_one_line():
    import subprocess
    import sys

    cmd = [sys.executable, "-c", "from kincal.cli import main; main()", "ik", "puma560",
           "--position", "3,0,0"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: puma560: unreachable:")
    assert "beyond reach" in err[0]


def test_cli_ik_fivebar_branch(tmp_path):
    import json

    from typer.testing import CliRunner

    from kincal.cli import app
    from kincal.workflow.robots import load_any_robot

    runner = CliRunner()
    robot = load_any_robot("fivebar_reference")
    x = robot.fk([0.6, 2.5])
    xy = f"{float(x[0])!r},{float(x[1])!r}"
    res = runner.invoke(app, ["ik", "fivebar_reference", "--position", xy, "--mode", "-+",
                              "--json", str(tmp_path / "ik.json")])
    assert res.exit_code == 0, res.output
    out = json.loads((tmp_path / "ik.json").read_text())
    assert np.allclose(out["q"], [0.6, 2.5], atol=1e-12)
