"""Joint hysteresis: approach directions against a per-row reference, Jacobians (alone and
nested with a compliance) vs central differences, exact and noisy recovery of a known
play, and what the data cannot tell apart."""

from __future__ import annotations

import numpy as np
import pytest
from test_compliance import (
    INSTRUMENT,
    K_TRUE,
    MARKERS,
    PUMA_MASSES,
    perturbed_puma,
)
from test_models import central_differences

from kincal.errors import KincalError
from kincal.identify.solver import calibrate
from kincal.measure.base import stack
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.joints.compliance import JointCompliance
from kincal.measure.joints.hysteresis import JointHysteresis, approach_directions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot
from kincal.robots.gravity import gravity_torques

#: A play on every PUMA joint [rad]: the link lags its motor by |h| (h < 0).
H_TRUE = np.array([-1.5e-3, -4e-3, -2.5e-3, -6e-3, 3e-3, -8e-3])


def _directions_by_rows(q, min_move):
    """Reference: walk the postures one by one, remembering each joint's last move."""
    d = np.zeros_like(q)
    last = np.zeros(q.shape[1])
    for k in range(1, q.shape[0]):
        for j in range(q.shape[1]):
            step = q[k, j] - q[k - 1, j]
            if abs(step) > min_move:
                last[j] = np.sign(step)
            d[k, j] = last[j]
    return d


@pytest.mark.parametrize("seed", range(5))
def test_approach_directions_match_a_posture_by_posture_walk(seed):
    rng = np.random.default_rng(seed)
    q = np.cumsum(rng.normal(0, 0.3, (40, 5)), axis=0)
    still = rng.random(q.shape) < 0.3                 # joints that stay put (encoder jitter)
    for k in range(1, q.shape[0]):
        q[k, still[k]] = q[k - 1, still[k]] + rng.uniform(-5e-4, 5e-4, still[k].sum())
    d = approach_directions(q, 1e-3)
    np.testing.assert_array_equal(d, _directions_by_rows(q, 1e-3))
    assert np.all(d[0] == 0) and set(np.unique(d)) <= {-1.0, 0.0, 1.0}
    # with no threshold every jitter counts as a move
    np.testing.assert_array_equal(approach_directions(q, 0.0), _directions_by_rows(q, 0.0))


def _sequence(robot, n, rng):
    """A measurement session: random postures visited one after the other."""
    return random_configurations(robot, n, rng)


def _simulate(true, nominal, q, h, rng, noise=0.0, k=None):
    """Positions of the true robot at ``q + h d (+ k tau)``, recorded with readings ``q``."""
    q_eff = q + h * approach_directions(q)
    if k is not None:
        q_eff = q_eff + k * gravity_torques(nominal, q, PUMA_MASSES)
    sim = simulate_positions(true, q_eff, rng, noise, INSTRUMENT, MARKERS)
    return PositionMeasurement(q, sim.positions, max(noise, 1e-5), "tracker", markers=3)


@pytest.mark.parametrize("nested", [False, True])
def test_jacobian_matches_central_differences(nested):
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(3)
    q = _sequence(robot, 11, rng)
    inner = _simulate(robot, robot, q, H_TRUE, rng)
    block = JointHysteresis(inner, robot)
    if nested:
        block = JointCompliance.gravity(block, robot, PUMA_MASSES)
    prob, theta = stack(robot, [block])
    theta = theta + 1e-3 * rng.standard_normal(theta.size)
    h_idx = [prob.index(f"tracker.h[{j}]") for j in robot.joint_names]
    theta[h_idx] = rng.uniform(-0.01, 0.01, robot.n)
    if nested:
        assert prob.names[-12:-6] == tuple(f"tracker.h[{j}]" for j in robot.joint_names)
        assert prob.names[-6:] == tuple(f"tracker.k[{j}]" for j in robot.joint_names)
    r, J = prob.residuals_and_jacobian(theta)
    Jn = central_differences(prob, theta)
    scale = np.maximum(np.abs(Jn).max(0), 1e-3 * np.abs(Jn).max())
    assert np.max(np.abs(J - Jn) / scale) < 1e-6
    assert np.all(np.abs(J[:, h_idx]).max(0) > 0)


def test_effective_configurations_and_subsets():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    q = _sequence(robot, 9, rng)
    inner = _simulate(robot, robot, q, H_TRUE, rng)
    block = JointHysteresis(inner, robot, joints=["q2", "q6"])
    spec = block.parameters()
    assert spec.names[-2:] == ("tracker.h[q2]", "tracker.h[q6]")
    assert spec.units[-2:] == ("rad", "rad") and spec.roles[-1] == "hysteresis"
    extra = np.concatenate([inner.initial_guess(robot), [-0.004, 0.002]])
    d = approach_directions(q)
    q_eff = block.effective_q(robot, extra)
    np.testing.assert_allclose(q_eff[:, 1], q[:, 1] - 0.004 * d[:, 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(q_eff[:, 5], q[:, 5] + 0.002 * d[:, 5], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(q_eff[:, [0, 2, 3, 4]], q[:, [0, 2, 3, 4]])
    # a subset keeps each row's direction from the whole session (not recomputed)
    sub = block.subset([2, 7, 8])
    np.testing.assert_array_equal(sub.directions, d[[2, 7, 8]])
    np.testing.assert_array_equal(sub.errors(robot, extra)["position_m"],
                                  block.errors(robot, extra)["position_m"][[2, 7, 8]])
    assert isinstance(sub, JointHysteresis) and sub.joints == ("q2", "q6")


def test_noise_free_recovery_of_known_play_with_geometry_and_compliance():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(11)
    true = perturbed_puma(nominal, rng)
    k_true = K_TRUE
    q = _sequence(nominal, 80, rng)
    inner = _simulate(true, nominal, q, H_TRUE, rng, k=k_true)
    block = JointCompliance.gravity(JointHysteresis(inner, nominal), nominal, PUMA_MASSES,
                                    joints=["q2", "q3", "q4", "q5"])
    res = calibrate(nominal, [block], tol_step=1e-14)
    assert res.converged, res.message
    h = np.array([res.params[f"tracker.h[q{j}]"] for j in range(1, 7)])
    k = np.array([res.params[f"tracker.k[q{j}]"] for j in (2, 3, 4, 5)])
    np.testing.assert_allclose(h, H_TRUE, rtol=0, atol=1e-11)          # rad
    np.testing.assert_allclose(k, k_true[1:5], rtol=0, atol=1e-11)     # rad/(N m)
    assert res.rms()["rms_position_m"] < 1e-12
    # without the hysteresis term the play is left in the residuals
    plain = calibrate(nominal, [JointCompliance.gravity(inner, nominal, PUMA_MASSES)])
    assert plain.rms()["rms_position_m"] > 1e-4


def test_noisy_recovery_within_the_reported_uncertainty():
    """50 noisy sessions: the RMS error of each h over the reported std is near 1."""
    nominal = load_serial_robot("puma560")
    noise = 50e-6
    ratios = []
    for seed in range(50):
        rng = np.random.default_rng(100 + seed)
        q = _sequence(nominal, 60, rng)
        inner = _simulate(nominal, nominal, q, H_TRUE, rng, noise=noise)
        res = calibrate(nominal, [JointHysteresis(inner, nominal)], trust_sigma=True)
        i = [res.names.index(f"tracker.h[q{j}]") for j in range(1, 7)]
        ratios.append((res.theta[i] - H_TRUE) / res.std[i])
    z = np.sqrt(np.mean(np.square(ratios), axis=0))
    print("\nhysteresis RMS error / reported std, q1..q6:", np.round(z, 2))
    # chi-distributed with 50 samples: 0.8-1.2 holds with > 99 % probability per joint
    assert np.all((z > 0.75) & (z < 1.25)), z


def test_a_joint_always_approached_from_one_side_is_named_not_guessed():
    """If joint 3 always arrives moving up, its play is a constant: its offset."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(12)
    q = _sequence(nominal, 40, rng)
    d = approach_directions(q)
    d[:, 2] = 1.0
    inner = _simulate(nominal, nominal, q, np.zeros(6), rng)
    res = calibrate(nominal, [JointHysteresis(inner, nominal, directions=d)])
    rep = res.identifiability
    assert "tracker.h[q3]" not in res.estimated
    assert rep.dependent["tracker.h[q3]"] == ["theta_offset[3]"]
    assert res.params["tracker.h[q3]"] == 0.0
    assert np.all(np.isfinite(res.theta))


def test_clear_errors():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(4)
    q = _sequence(robot, 6, rng)
    inner = _simulate(robot, robot, q, np.zeros(6), rng)
    with pytest.raises(KincalError, match="directions must be -1, 0 or \\+1"):
        JointHysteresis(inner, robot, directions=np.full((6, 6), 0.5))
    with pytest.raises(KincalError, match=r"directions must be \(N, n\) = \(6, 6\)"):
        JointHysteresis(inner, robot, directions=np.ones((6, 5)))
    with pytest.raises(KincalError, match="not all finite"):
        approach_directions(np.array([[0.0], [np.nan]]))
    with pytest.raises(KincalError, match="min_move must be >= 0"):
        approach_directions(q, -1.0)
    twice = JointHysteresis(JointHysteresis(inner, robot), robot)
    with pytest.raises(KincalError, match="lists parameter 'tracker.h\\[q1\\]' twice"):
        stack(robot, [twice])
