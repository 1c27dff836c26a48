"""Uncertainty: the reported standard errors and predicted accuracy match a Monte Carlo.

One fixed design (true robot, tracker, poses); only the noise changes between seeds,
so the spread of the estimates over seeds is what the covariance predicts.
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.identify.accuracy import predicted_position_std, predicted_rms
from kincal.identify.identifiability import analyze
from kincal.identify.solver import calibrate
from kincal.identify.uncertainty import (
    correlation,
    covariance,
    cramer_rao,
    standard_errors,
)
from kincal.identify.validation import cross_validate, error_statistics, validate
from kincal.measure.base import stack
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.dh import dh_links, from_dh
from kincal.robots.files import load_serial_robot

SEEDS = 200            # >= 50; 200 keeps the chance fluctuation of the worst ratio small
NOISE = 2e-5           # m per coordinate
INSTRUMENT = [1.5, 0.4, -0.2, 2.0, -0.15, 0.1]
MARKER = [0.03, -0.02, 0.06]


def test_covariance_helpers():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((60, 4)) * [1, 10, 1e3, 1e-2]
    C = covariance(J, 2.0)
    assert np.allclose(C, 4.0 * np.linalg.inv(J.T @ J), rtol=1e-9)
    assert np.allclose(cramer_rao(J), np.linalg.inv(J.T @ J), rtol=1e-9)
    assert np.allclose(standard_errors(C), np.sqrt(np.diag(C)))
    R = correlation(C)
    assert np.allclose(np.diag(R), 1) and np.all(np.abs(R) <= 1 + 1e-12)


@pytest.fixture(scope="module")
def monte_carlo():
    rng = np.random.default_rng(2024)
    robot = from_dh(dh_links(load_serial_robot("puma560")), name="puma560",
                    tool=[0.0, 0.0, 0.08, 0, 0, 0])
    q = random_configurations(robot, 30, rng)
    q_val = random_configurations(robot, 30, rng)
    probe = simulate_positions(robot, q, rng, 0.0, INSTRUMENT, MARKER)
    prob, theta = stack(robot, [probe])
    _, J = prob.residuals_and_jacobian(theta)
    base = [n for n in analyze(J, prob.names, roles=prob.roles).identifiable
            if n in robot.param_names]
    true = perturb_robot(robot, rng, names=base)
    truth = np.concatenate([true.param_values, np.asarray(INSTRUMENT), MARKER])
    errors, stds, val_ms, pred_ms, point_err, point_pred = [], [], [], [], [], []
    first = None
    tool_point = np.array(MARKER)
    for seed in range(SEEDS):
        r = np.random.default_rng(seed)
        train = simulate_positions(true, q, r, NOISE, INSTRUMENT, MARKER)
        held = simulate_positions(true, q_val, r, NOISE, INSTRUMENT, MARKER)
        res = calibrate(robot, [train], method="gauss-newton", max_iter=10, tol_step=1e-9)
        if first is None:
            first = res
        est = [res.names.index(n) for n in res.estimated]
        errors.append(res.theta[est] - truth[est])
        stds.append(res.std[est])
        v = validate(res.robot, [held], extras=res.extras())
        val_ms.append(v["overall"]["rms_position_m"] ** 2)
        pred_ms.append(predicted_rms(res, q_val) ** 2)
        T_est, T_true = res.robot.fk(q_val), true.fk(q_val)
        pe = T_est[:, :3, 3] + T_est[:, :3, :3] @ tool_point
        pt = T_true[:, :3, 3] + T_true[:, :3, :3] @ tool_point
        point_err.append(np.sum((pe - pt) ** 2, axis=1))
        point_pred.append(predicted_position_std(res, q_val, point=tool_point) ** 2)
    return dict(first=first, errors=np.array(errors), stds=np.array(stds),
                val_ms=np.array(val_ms), pred_ms=np.array(pred_ms),
                point_err=np.array(point_err), point_pred=np.array(point_pred))


def test_monte_carlo_standard_errors(monte_carlo):
    res = monte_carlo["first"]
    rms_err = np.sqrt(np.mean(monte_carlo["errors"] ** 2, axis=0))
    reported = np.sqrt(np.mean(monte_carlo["stds"] ** 2, axis=0))
    ratio = rms_err / reported
    worst = int(np.argmax(ratio))
    print(f"\nMonte Carlo ({SEEDS} seeds, {len(ratio)} estimated parameters): worst RMS error / "
          f"reported std = {ratio[worst]:.3f} ({res.estimated[worst]}), best {ratio.min():.3f}")
    assert ratio.max() <= 1.2, f"{res.estimated[worst]}: ratio {ratio[worst]:.3f}"
    # and not grossly pessimistic either
    assert ratio.min() >= 0.8, f"{res.estimated[int(np.argmin(ratio))]}: {ratio.min():.3f}"
    # the estimates are unbiased at this noise level
    bias = np.abs(monte_carlo["errors"].mean(axis=0)) / reported
    assert bias.max() < 4.0 / np.sqrt(SEEDS) * 1.5 + 0.05


def test_monte_carlo_validation_noise_floor(monte_carlo):
    measured = np.sqrt(np.mean(monte_carlo["val_ms"]))
    predicted = np.sqrt(np.mean(monte_carlo["pred_ms"]))
    floor = np.sqrt(3) * NOISE
    print(f"\nvalidation RMS {measured * 1e6:.2f} um, predicted {predicted * 1e6:.2f} um, "
          f"noise floor {floor * 1e6:.2f} um")
    # each seed's mean square over 90 coordinates has relative sd sqrt(2/90) ~ 0.15;
    # over the seeds the mean is known to ~1 %: 5 % is a 5-sigma band on the RMS
    assert measured == pytest.approx(predicted, rel=0.05)
    assert floor < measured < 1.5 * floor


def test_predicted_position_std_of_a_tool_point(monte_carlo):
    measured = np.sqrt(np.mean(monte_carlo["point_err"]))
    predicted = np.sqrt(np.mean(monte_carlo["point_pred"]))
    print(f"\ntool point error RMS {measured * 1e6:.2f} um, predicted {predicted * 1e6:.2f} um")
    assert measured == pytest.approx(predicted, rel=0.1)


def test_validation_protocols():
    rng = np.random.default_rng(5)
    robot = load_serial_robot("puma560")
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, 40, rng)
    train = simulate_positions(true, q, rng, 1e-5, INSTRUMENT, MARKER)
    res = calibrate(robot, [train])
    # a second session from another tracker placement: register, robot fixed
    moved = simulate_positions(true, random_configurations(robot, 30, rng), rng, 1e-5,
                               [0.2, 1.1, 0.1, 0.3, 0.0, -1.0], MARKER, name="session2")
    v = validate(res.robot, [moved])
    assert v["overall"]["n"] == 30
    assert v["overall"]["rms_position_m"] < 3 * np.sqrt(3) * 1e-5
    assert set(v["blocks"]) == {"session2"}
    nominal = validate(robot, [moved])
    assert nominal["overall"]["rms_position_m"] > 5 * v["overall"]["rms_position_m"]
    # frames from training, passed three ways
    same = simulate_positions(true, random_configurations(robot, 30, rng), rng, 1e-5,
                              INSTRUMENT, MARKER)
    a = validate(res.robot, [same], extras=res.extras())
    b = validate(res.robot, [same], extras=res)
    c = validate(res.robot, [same], extras={"tracker": res.theta[robot.num_params:]})
    assert a["overall"] == b["overall"] == c["overall"]
    stats = error_statistics({"position_m": np.array([3.0, 4.0])})
    assert stats == {"rms_position_m": pytest.approx(np.sqrt(12.5)), "mean_position_m": 3.5,
                     "max_position_m": 4.0, "n": 2}
    cv = cross_validate(robot, train, folds=4, rng=np.random.default_rng(0))
    assert len(cv["folds"]) == 4 and cv["rms_position_m"] < 3 * np.sqrt(3) * 1e-5


def test_propagated_variance_is_the_trace_of_the_propagated_covariance():
    from kincal.identify.uncertainty import propagated_variance

    rng = np.random.default_rng(3)
    G = rng.normal(size=(4, 2, 3, 5))
    A = rng.normal(size=(5, 5))
    C = A @ A.T
    want = np.array([[np.trace(G[a, b] @ C @ G[a, b].T) for b in range(2)] for a in range(4)])
    assert np.allclose(propagated_variance(G, C), want, rtol=1e-12, atol=0)
