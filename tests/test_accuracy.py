"""Predicted accuracy (:mod:`kincal.identify.accuracy`) against Monte Carlo.

A simulated PUMA 560 is measured in a small box of its joint space (each joint over the
middle 25 % of its range) and its calibrated model is used inside the box and all
over the workspace.  Over many simulated calibrations the RMS error of the prediction
must match the predicted ``sqrt(trace(G C G^T))`` within 15 %, inside and outside the
training region, for both things kincal predicts: what the tracker would measure
(calibrated robot, frame and marker against the true ones: the default) and a TCP in
the robot's base frame (``point=``, the robot parameters alone):

* least squares: one true robot, new noise each time (the covariance is the estimator's);
* MAP (the default): the true robot drawn from the prior (the tolerances) each time,
  so the posterior covariance is the expected squared error.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kincal.identify.accuracy import AccuracyModel, accuracy_model, predict
from kincal.identify.solver import calibrate
from kincal.identify.tolerances import resolve_tolerances
from kincal.measure.base import stack
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot

NOISE = 2e-5
INSTRUMENT = [1.4, -0.6, 0.3, 2.1, -0.3, 0.2]
MARKER = np.array([[0.05, 0.02, 0.1]])
REPS = 50


WIDTH = 0.25      # the training box: the middle 25 % of every joint range


def box(robot, n, rng, inside=True, shrink=1.0):
    """Configurations in the training box (inside; ``shrink`` < 1: well inside it) or over
    the whole ranges with at least one joint outside that box (outside)."""
    lim = robot.joint_limits
    mid, half = lim.mean(axis=1), WIDTH / 2 * (lim[:, 1] - lim[:, 0])
    if inside:
        return mid + rng.uniform(-1, 1, (n, robot.n)) * half * shrink
    q = random_configurations(robot, 4 * n, rng)
    out = np.any(np.abs(q - mid) > half, axis=1)
    return q[out][:n]


@pytest.fixture(scope="module")
def setup():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(41)
    q_train = box(nominal, 30, rng)
    q_in, q_out = box(nominal, 25, rng, shrink=0.7), box(nominal, 25, rng, inside=False)
    probe = simulate_positions(nominal, q_train, rng, NOISE, INSTRUMENT, MARKER, sigma=NOISE)
    prob, _ = stack(nominal, [probe])
    tol = resolve_tolerances(prob.names, prob.units, prob.roles)
    est = calibrate(nominal, [probe], prior=tol.prior()).estimated
    robot_est = [n for n in est if n in nominal.param_names]
    return nominal, q_train, q_in, q_out, tol, robot_est


def monte_carlo(setup, prior: bool):
    nominal, q_train, q_in, q_out, tol, robot_est = setup
    rng = np.random.default_rng(7 if prior else 8)
    base = nominal.params()
    fixed_truth = {n: base[n] + rng.normal() * tol.sigma[n] for n in robot_est}
    err = {k: [] for k in ("in", "out", "tcp in", "tcp out")}
    var = {k: [] for k in err}
    tcp = np.array([0.0, 0.02, 0.15])
    for _ in range(REPS):
        truth = {n: base[n] + rng.normal() * tol.sigma[n] for n in robot_est} if prior \
            else fixed_truth
        true = nominal.with_params(truth)
        data = simulate_positions(true, q_train, rng, NOISE, INSTRUMENT, MARKER, sigma=NOISE)
        res = calibrate(nominal, [data], prior=tol.prior() if prior else None)
        assert res.converged and set(res.estimated) >= set(robot_est)
        model = accuracy_model(res)
        for key, q in (("in", q_in), ("out", q_out)):
            p = predict(model, res.robot, q)
            y_true = simulate_positions(true, q, rng, 0.0, INSTRUMENT, MARKER).positions
            err[key].append(np.sum((p.position_m - y_true) ** 2, axis=1))
            var[key].append(p.std_position_m**2)
            t = predict(model, res.robot, q, point=tcp)
            T = true.fk(q)
            P_true = T[:, :3, 3] + T[:, :3, :3] @ tcp
            err[f"tcp {key}"].append(np.sum((t.position_m - P_true) ** 2, axis=1))
            var[f"tcp {key}"].append(t.std_position_m**2)
    return ({k: math.sqrt(np.mean(v)) for k, v in err.items()},
            {k: math.sqrt(np.mean(v)) for k, v in var.items()}, model)


@pytest.mark.parametrize("prior", [False, True], ids=["least squares", "MAP"])
def test_predicted_std_matches_monte_carlo_inside_and_outside(setup, prior):
    actual, predicted, model = monte_carlo(setup, prior)
    print(f"\n{'MAP' if prior else 'least squares'}, {REPS} calibrations, RMS error [mm] "
          "actual / predicted: " + ", ".join(f"{k} {actual[k] * 1e3:.4f} / "
                                             f"{predicted[k] * 1e3:.4f}" for k in actual))
    for key in actual:
        assert predicted[key] == pytest.approx(actual[key], rel=0.15), key
    # extrapolation is where the model is worse, and the prediction says so
    assert predicted["out"] > 2 * predicted["in"]
    assert predicted["tcp out"] > 2 * predicted["tcp in"]


def test_region_flags_floor_and_the_json_round_trip(setup):
    nominal, q_train, q_in, q_out, tol, _ = setup
    rng = np.random.default_rng(3)
    data = simulate_positions(nominal, q_train, rng, NOISE, INSTRUMENT, MARKER, sigma=NOISE)
    res = calibrate(nominal, [data], prior=tol.prior())
    model = accuracy_model(res)
    assert model.point == pytest.approx(MARKER[0], abs=1e-3)
    assert all(n and n.startswith("tracker.marker.") for n in model.point_parameters)
    # the floor from the training residuals is the noise: sqrt(3) NOISE per point
    assert model.floor_m == pytest.approx(math.sqrt(3) * NOISE, rel=0.25)
    p_in, p_out = predict(model, res.robot, q_in), predict(model, res.robot, q_out)
    assert not p_in.outside_joint_ranges.any() and p_out.outside_joint_ranges.all()
    assert p_in.outside_hull.mean() < p_out.outside_hull.mean()
    assert np.all(p_in.predicted_m >= model.floor_m)
    back = AccuracyModel.from_dict(json.loads(json.dumps(model.to_dict())))
    again = predict(back, res.robot, q_out)
    np.testing.assert_allclose(again.std_position_m, p_out.std_position_m, rtol=1e-12)
    np.testing.assert_array_equal(again.outside_hull, p_out.outside_hull)
    # against the nominal robot (here the truth): the calibrated model's correction is
    # within its uncertainty, so it is predicted no better than nominal there
    cmp = predict(model, res.robot, q_out, nominal=nominal)
    assert cmp.worse_than_nominal.mean() > 0.5
    text = " ".join(p_out.summary())
    assert f"{len(q_out)} of {len(q_out)} poses lie outside the training joint ranges" in text
    # a TCP given in the flange frame: the robot parameters only
    tcp = predict(model, res.robot, q_in, point=[0.0, 0.0, 0.2])
    assert tcp.std_position_m.shape == (len(q_in),) and np.all(tcp.std_orientation_rad > 0)
