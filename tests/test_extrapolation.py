"""A calibration used outside the region it was trained in, against the known truth.

Simulated PUMA 560s (errors drawn by :func:`perturb_robot`, a tracker with a marker),
trained in a small joint box about the middle of the joint ranges and checked, with the
training frames (same session), on poses spread over +-90 deg:

* trained in +-1 deg, the calibrated model can be worse than the nominal robot out
  there; the default flow must then say so before anyone uses it (``FlowResult.warnings``),
  and must not say it for a robot trained over its range;
* with an unmodelled cyclic joint error in the truth, the predicted held-out RMS outside
  the training region (parameter covariance and the floor growing with the distance from
  the region, measured by the region test) is within 1.5x of the measured one, pooled over
  robots (the prediction is an expectation over the parameter errors, so one robot's
  realisation scatters about it);
* the region's distance and the floor's growth follow their definitions and survive the
  result JSON.
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.identify.accuracy import AccuracyModel, TrainingRegion
from kincal.identify.extrapolation import inner_half
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot
from kincal.workflow.flow import run_flow

NOISE = 1e-5                                   # m, tracker noise per coordinate
FRAME = [1.5, 0.3, 0.2, 0.4, 0.1, -0.2]        # tracker pose in the base frame
MARKER = [0.003, -0.004, 0.06]                 # m, in the flange frame


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def _boxes(robot, rng, half_deg, n_train=60, n_out=200):
    lim = robot.joint_limits
    c = 0.5 * (lim[:, 0] + lim[:, 1])
    big = np.minimum(0.4 * (lim[:, 1] - lim[:, 0]), np.radians(90.0))
    qt = c + rng.uniform(-1, 1, (n_train, robot.n)) * np.radians(half_deg)
    qv = c + rng.uniform(-1, 1, (n_out, robot.n)) * big
    return qt, qv


def _held_out(flow):
    (f,) = flow.heldout
    nominal = float(np.sqrt(np.mean(f.before["position_m"] ** 2)))
    calibrated = float(np.sqrt(np.mean(f.after["position_m"] ** 2)))
    return f, nominal, calibrated


def _extrapolation_warned(flow):
    return any(w.startswith("extrapolation:") for w in flow.warnings)


def test_small_region_worse_than_nominal_is_warned_before_use(puma):
    rng = np.random.default_rng(0)
    true = perturb_robot(puma, rng)
    qt, qv = _boxes(puma, rng, 1.0)
    train = simulate_positions(true, qt, rng, NOISE, FRAME, MARKER, name="tracker")
    held = simulate_positions(true, qv, rng, NOISE, FRAME, MARKER, name="tracker")
    flow = run_flow(puma, [train], [held], validation_frames="training", max_iter=400)
    _, nominal, calibrated = _held_out(flow)
    print(f"\n+-1 deg box, held out in +-90 deg: nominal {nominal * 1e3:.3f} mm, calibrated "
          f"{calibrated * 1e3:.3f} mm; warnings: {flow.warnings}")
    # the case the warning is for: worse than nominal out there by far more than the noise
    assert calibrated > nominal + 10 * NOISE
    assert flow.trusted                          # nothing else is wrong with the fit
    assert _extrapolation_warned(flow)           # ... but it says so before use


def test_wide_region_is_not_warned_and_beats_nominal(puma):
    rng = np.random.default_rng(1)
    true = perturb_robot(puma, rng)
    lim = puma.joint_limits
    c = 0.5 * (lim[:, 0] + lim[:, 1])
    big = np.minimum(0.4 * (lim[:, 1] - lim[:, 0]), np.radians(90.0))
    qt = c + rng.uniform(-1, 1, (60, puma.n)) * big
    qv = c + rng.uniform(-1, 1, (100, puma.n)) * big
    train = simulate_positions(true, qt, rng, NOISE, FRAME, MARKER, name="tracker")
    held = simulate_positions(true, qv, rng, NOISE, FRAME, MARKER, name="tracker")
    flow = run_flow(puma, [train], [held], validation_frames="training", max_iter=400)
    _, nominal, calibrated = _held_out(flow)
    assert calibrated < nominal / 10
    assert not _extrapolation_warned(flow), flow.warnings
    # and its predicted held-out error is right
    pm = flow.heldout[0].prediction_metrics()
    assert 1 / 1.5 < pm["predicted_rms_m"] / pm["measured_rms_m"] < 1.5


def test_predicted_outside_the_region_within_1_5x(puma):
    """Truth: geometric errors and a cyclic joint error ``0.02 deg sin(2 q_j + j)`` the
    model does not have; 60 training poses in +-10 deg, 200 held out in +-90 deg."""
    pred, meas, const = [], [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        true = perturb_robot(puma, rng)
        qt, qv = _boxes(puma, rng, 10.0)

        def measured(q, rng=rng, true=true):
            dq = np.radians(0.02) * np.sin(2 * q + np.arange(puma.n))
            b = simulate_positions(true, q + dq, rng, NOISE, FRAME, MARKER, name="tracker")
            return PositionMeasurement(q, b.positions, NOISE, "tracker")

        flow = run_flow(puma, [measured(qt)], [measured(qv)], validation_frames="training",
                        max_iter=400)
        (f,) = flow.heldout
        out = f.prediction.outside
        assert out.all()
        pred.append(np.mean(f.prediction.predicted_m ** 2))
        meas.append(np.mean(f.point_errors ** 2))
        model = flow.accuracy.with_floor_growth(None)      # the floor of the training data
        from kincal.identify.accuracy import predict

        const.append(np.mean(predict(model, flow.result.robot, qv).predicted_m ** 2))
    ratio = float(np.sqrt(np.sum(pred) / np.sum(meas)))
    flat = float(np.sqrt(np.sum(const) / np.sum(meas)))
    print(f"\npredicted / measured outside: {ratio:.2f} (constant floor: {flat:.2f})")
    assert 1 / 1.5 < ratio < 1.5
    assert flat < 1 / 1.5                    # what the training floor alone would say


def test_distance_outside_the_training_ranges():
    reg = TrainingRegion(("a", "b"), np.array([-0.1, 0.0]), np.array([0.1, 0.4]))
    q = np.array([[0.0, 0.2],              # inside
                  [0.3, 0.2],              # a: 0.2 beyond, half-range 0.1 -> 2
                  [0.0, -0.1],             # b: 0.1 beyond, half-range 0.2 -> 0.5
                  [0.3, 0.8],              # max(2, 2)
                  [2 * np.pi, 0.2]])       # a turn away: inside
    assert reg.distance(q) == pytest.approx([0.0, 2.0, 0.5, 2.0, 0.0], abs=1e-12)


def test_floor_grows_with_the_distance_and_round_trips():
    reg = TrainingRegion(("a",), np.array([-0.1]), np.array([0.1]))
    model = AccuracyModel((), np.zeros((0, 0)), np.zeros(3), floor_m=3e-4, region=reg,
                          floor_growth_m=4e-4)
    floor = model.floor_at(np.array([[0.0], [0.2], [0.4]]))
    assert floor == pytest.approx([3e-4, 5e-4, np.hypot(3e-4, 1.2e-3)])
    back = AccuracyModel.from_dict(model.to_dict())
    assert back.floor_growth_m == pytest.approx(4e-4)
    assert AccuracyModel.from_dict({**model.to_dict(), "floor_growth_m": None}
                                   ).floor_at([[0.4]]) == pytest.approx([3e-4])


def test_inner_half_is_the_half_nearest_the_middle():
    q = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 1.0], [-1.0, 0.2], [0.1, -0.9], [0.0, 0.3]])
    inner = inner_half(q)
    # Chebyshev distances in half-ranges (middle (0, 0.05), half-ranges (1, 0.95))
    d = np.max(np.abs(q - [0.0, 0.05]) / [1.0, 0.95], axis=1)
    assert inner.tolist() == (d <= np.median(d)).tolist()
