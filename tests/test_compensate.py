"""Compensation: joint commands put the calibrated robot on target; filtered targets
drive a nominal controller to the same joint commands.

Truth: a "calibrated" robot made by perturbing the PUMA 560's parameters by ~1 mm /
0.05 deg; every check is an independent forward-kinematics evaluation.
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.compensation.compensate import compensate, require_all
from kincal.errors import KincalError, UnreachableError
from kincal.motion.ik import solve_ik
from kincal.robots.files import load_serial_robot
from kincal.spatial import log_so3


@pytest.fixture(scope="module")
def robots():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(11)
    lin = np.array([u == "m" for u in nominal.param_units])
    delta = np.where(lin, rng.normal(0, 1e-3, nominal.num_params),
                     rng.normal(0, np.deg2rad(0.05), nominal.num_params))
    return nominal, nominal.with_params(nominal.param_values + delta), rng


def _inside(robot, rng, n, frac=0.6):
    """Configurations inside the limits and away from singularities (stretched elbow,
    aligned wrist), where a mm-sized model change keeps the IK solution on its branch."""
    lim = robot.joint_limits
    mid, half = lim.mean(axis=1), (lim[:, 1] - lim[:, 0]) / 2
    q = rng.uniform(mid - frac * half, mid + frac * half, (20 * n, robot.n))
    smin = np.linalg.svd(robot.jacobian(q), compute_uv=False)[:, -1]
    return q[smin > 0.08][:n]


def test_pose_targets_are_reached_and_filtered_targets_round_trip(robots):
    nominal, calibrated, rng = robots
    q_true = _inside(nominal, rng, 40)
    assert len(q_true) == 40
    T = nominal.fk(q_true)
    comp = compensate(calibrated, T, nominal=nominal)
    assert comp.mask == "pose" and comp.success.all()
    assert np.max(comp.jump) < 0.5        # stayed on the nominal controller's branch
    # independent check: the calibrated robot at q_cmd is on target to 1e-9
    Tc = calibrated.fk(comp.q)
    assert np.max(np.linalg.norm(Tc[:, :3, 3] - T[:, :3, 3], axis=1)) < 1e-9
    ang = np.linalg.norm(log_so3(T[:, :3, :3] @ np.swapaxes(Tc[:, :3, :3], 1, 2)), axis=1)
    assert np.max(ang) < 1e-9
    # the filtered targets are the nominal FK of q_cmd ...
    np.testing.assert_allclose(comp.filtered, nominal.fk(comp.q), atol=1e-15)
    # ... so the nominal controller's IK (started where it would start for the original
    # target) gives q_cmd back
    seed = solve_ik(nominal, T).q
    back = solve_ik(nominal, comp.filtered, q0=seed, tol_position=1e-12, tol_orientation=1e-12)
    assert back.success.all()
    assert np.max(np.abs(back.q - comp.q)) < 1e-8
    # the compensation is as large as the model error (~mm), not zero
    assert 1e-4 < np.sqrt(np.mean(comp.correction**2)) < 2e-2


def test_position_targets(robots):
    nominal, calibrated, rng = robots
    p = nominal.fk(_inside(nominal, rng, 20))[:, :3, 3]
    comp = compensate(calibrated, p, nominal=nominal)
    assert comp.mask == "position" and comp.success.all()
    err = np.linalg.norm(calibrated.fk(comp.q)[:, :3, 3] - p, axis=1)
    assert np.max(err) < 1e-9
    assert np.all(comp.orientation_error == 0)
    np.testing.assert_allclose(comp.correction,
                               np.linalg.norm(nominal.fk(comp.q)[:, :3, 3] - p, axis=1))


def test_without_nominal_only_joint_commands(robots):
    _, calibrated, rng = robots
    q = _inside(calibrated, rng, 5)
    T = calibrated.fk(q)
    comp = compensate(calibrated, T, q0=q + 0.01)
    assert comp.filtered is None and comp.correction is None
    np.testing.assert_allclose(comp.q, q, atol=1e-8)


def test_unreachable_target_is_one_line_naming_it(robots):
    nominal, calibrated, rng = robots
    T = nominal.fk(_inside(nominal, rng, 3))
    T[1, :3, 3] = [5.0, 0.0, 0.0]   # 5 m away: beyond the PUMA's reach
    comp = compensate(calibrated, T, nominal=nominal, restarts=1)
    assert comp.success.tolist() == [True, False, True]
    with pytest.raises(UnreachableError, match=r"t.csv: line 4: the calibrated robot cannot "
                       r"reach this target \(unreachable.*1 of 3 targets failed"):
        require_all(comp, "t.csv", np.array([3, 4, 5]))


def test_mismatched_robots_and_shapes(robots):
    nominal, calibrated, _ = robots
    other = load_serial_robot("ur5")
    with pytest.raises(KincalError, match="has joints"):
        compensate(calibrated, np.eye(4), nominal=other)
    with pytest.raises(KincalError, match="position targets must have shape"):
        compensate(calibrated, np.zeros((3, 2)))


def test_compensate_targets_library_workflow_and_its_document(robots):
    from kincal.workflow.compensation import compensate_targets

    nominal, calibrated, rng = robots
    T = nominal.fk(_inside(nominal, rng, 5))
    run = compensate_targets(calibrated, T, nominal=nominal, source="t.csv", output="q.csv")
    direct = compensate(calibrated, T, nominal=nominal)
    np.testing.assert_array_equal(run.compensation.q, direct.q)
    assert run.predicted is None
    doc = run.to_dict()
    assert doc["robot"] == calibrated.name and doc["targets"] == "t.csv"
    assert doc["output"] == "q.csv" and doc["mask"] == "pose"
    assert doc["joint_names"] == list(calibrated.joint_names)
    np.testing.assert_array_equal(doc["filtered"], direct.filtered)
    assert "predicted" not in doc and "fallback_nominal" not in doc
    with pytest.raises(KincalError, match="not none or nominal"):
        compensate_targets(calibrated, T, fallback="always")  # type: ignore[arg-type]
    with pytest.raises(KincalError, match="needs the nominal robot and the accuracy"):
        compensate_targets(calibrated, T, nominal=nominal, fallback="nominal")
    far = T.copy()
    far[2, :3, 3] = [10.0, 0.0, 0.0]
    with pytest.raises(UnreachableError, match="line 7"):
        compensate_targets(calibrated, far, lines=np.arange(5, 10))
