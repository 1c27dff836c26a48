"""Accuracy predicted before measuring vs the definition, the solver and a Monte Carlo.

* the prediction's covariance is the one the solver reports on the same poses;
* with the workspace scaling the mean predicted variance over the candidates is
  ``sigma^2 sum 1/s_i^2`` exactly (the link between the indices and the accuracy);
* a Monte Carlo of calibrations of the PUMA 560 with a simulated laser tracker has an
  RMS error over a workspace grid within 15 % of the prediction; the Monte Carlo's
  own standard error (from the predicted covariance: the per-trial mean square error
  ``d^T H d``, ``d ~ N(0, C)``, has mean ``tr(HC)`` and variance ``2 tr((HC)^2)``) is
  checked to be small enough for that comparison to mean something.
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.identify.accuracy import predicted_position_std
from kincal.identify.design import random_candidates, select_poses
from kincal.identify.observability import (
    DEFAULT_INSTRUMENT,
    DEFAULT_MARKER,
    design_problem,
    design_problem_from_blocks,
)
from kincal.identify.prediction import predict_accuracy, prediction_figure, workspace_grid
from kincal.identify.solver import calibrate
from kincal.measure.instruments.pose import simulate_poses
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot

NOISE = 2e-5


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


@pytest.fixture(scope="module")
def planned(puma):
    q = random_candidates(puma, 2000, np.random.default_rng(20))
    dp = design_problem(puma, q, "position", NOISE)
    return dp, select_poses(dp, 25, "O1")


def test_grid_covers_the_joint_ranges(puma) -> None:
    g = workspace_grid(puma, 3, margin=0.1)
    lim = puma.joint_limits
    span = lim[:, 1] - lim[:, 0]
    assert g.shape == (3 ** 6, 6)
    assert np.allclose(g.min(0), lim[:, 0] + 0.1 * span) and np.allclose(
        g.max(0), lim[:, 1] - 0.1 * span)
    assert workspace_grid(puma, [2, 2, 2, 1, 1, 1]).shape == (8, 6)
    with pytest.raises(KincalError, match="too large"):
        workspace_grid(puma, 10)


def test_prediction_is_the_solver_covariance_on_the_same_poses(puma, planned) -> None:
    dp, design = planned
    q_eval = random_candidates(puma, 50, np.random.default_rng(21))
    pred = predict_accuracy(dp, design, q_eval)
    # noise-free measurements of the nominal robot from the design's instrument placement
    block = simulate_positions(puma, design.q, np.random.default_rng(0), 0.0,
                               instrument=DEFAULT_INSTRUMENT, markers=DEFAULT_MARKER,
                               sigma=NOISE)
    res = calibrate(puma, [block], trust_sigma=True)
    assert sorted(res.estimated) == sorted(pred.names)
    order = [pred.names.index(n) for n in res.estimated]
    C = pred.covariance[np.ix_(order, order)]
    assert np.allclose(res.covariance, C, rtol=1e-6, atol=1e-6 * np.abs(C).max())
    # and the uncertainty module's propagation to positions agrees
    assert np.allclose(predicted_position_std(res, q_eval), pred.position_std, rtol=1e-5)
    # the same design given as configurations; noise scales the covariance
    again = predict_accuracy(dp, design.q, q_eval, noise=2 * NOISE)
    assert np.allclose(again.covariance, 4 * pred.covariance, rtol=1e-8)
    assert again.rms == pytest.approx(2 * pred.rms, rel=1e-8)


def test_workspace_scaling_links_the_indices_to_the_accuracy(planned) -> None:
    dp, design = planned
    pred = predict_accuracy(dp, design, dp.q)           # evaluate over the candidates
    s = design.indices.singular_values
    assert pred.rms == pytest.approx(NOISE * np.sqrt(np.sum(1 / s ** 2)), rel=1e-9)
    L = dp.num_params
    assert pred.rms <= NOISE * np.sqrt(L) / design.indices.O3 * (1 + 1e-12)
    assert pred.rms <= NOISE / design.indices.O5 * (1 + 1e-12)


def test_pose_and_multi_block_predictions(puma) -> None:
    q = random_candidates(puma, 300, np.random.default_rng(22))
    dp = design_problem(puma, q, "pose", NOISE, orientation_noise=2e-5)
    d = select_poses(dp, 12, "O1")
    pred = predict_accuracy(dp, d, workspace_grid(puma, 2))
    assert pred.orientation_std is not None and np.all(pred.orientation_std > 0)
    assert 0 < pred.rms < 10 * NOISE
    # two instruments at the same configurations: one candidate per configuration
    rng = np.random.default_rng(23)
    pos = simulate_positions(puma, q[:80], rng, 0.0, instrument=DEFAULT_INSTRUMENT,
                             markers=DEFAULT_MARKER, name="tracker", sigma=NOISE)
    pose = simulate_poses(puma, q[:80], rng, 0.0, 0.0, instrument=(0, 2, 0.3, 1, 0, 0),
                          name="probe", sigma_position=NOISE, sigma_orientation=2e-5)
    both = design_problem_from_blocks(puma, [pos, pose])
    assert both.J.shape[:2] == (80, 9) and np.allclose(both.q, q[:80])
    pb = predict_accuracy(both, select_poses(both, 10, "O1"), q[:20])
    assert pb.frame == "base" and np.all(np.isfinite(pb.position_std))


def test_figure_is_a_png(puma, planned) -> None:
    dp, design = planned
    pred = predict_accuracy(dp, design, workspace_grid(puma, 2))
    png = prediction_figure(pred, pred, [design.indices.singular_values])
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


TRIALS = 40


def test_predicted_error_agrees_with_a_monte_carlo(puma, planned) -> None:
    dp, design = planned
    q_eval = workspace_grid(puma, 3)                          # 729 configurations
    pred = predict_accuracy(dp, design, q_eval)
    instrument = (1.6, -0.9, 0.3, 0.1, -0.05, 2.2)            # true placement (any)
    marker = np.asarray(DEFAULT_MARKER) + [5e-4, -3e-4, 8e-4]
    sq = np.empty(TRIALS)
    for t in range(TRIALS):
        rng = np.random.default_rng([24, t])
        true = perturb_robot(puma, rng)
        block = simulate_positions(true, design.q, rng, NOISE, instrument=instrument,
                                   markers=marker)
        # LM stops after 2-4 iterations, within 1e-3 standard errors of the minimum or
        # on a scaled step below 1e-8 (0.01 um)
        res = calibrate(puma, [block], max_iter=8, tol_step=1e-8, trust_sigma=True)
        assert res.converged, res.message
        truth = simulate_positions(true, q_eval, rng, 0.0, instrument=instrument,
                                   markers=marker).positions
        e = PositionMeasurement(q_eval, truth, NOISE).errors(
            res.robot, res.theta[res.problem.slices[0]])["position_m"]
        sq[t] = np.mean(e ** 2)
    mc = float(np.sqrt(sq.mean()))
    # standard error of the Monte Carlo RMS from the predicted covariance
    G = dp.base_rows(q_eval) * NOISE
    H = np.einsum("eri,erj->ij", G, G) / len(q_eval)
    HC = H @ pred.covariance
    rel_se = 0.5 * np.sqrt(2 * np.trace(HC @ HC) / TRIALS) / np.trace(HC)
    ratio = mc / pred.rms
    print(f"\nMonte Carlo RMS {mc * 1e6:.3f} um over {TRIALS} calibrations x "
          f"{len(q_eval)} grid configurations; predicted {pred.rms * 1e6:.3f} um; ratio "
          f"{ratio:.3f}; Monte Carlo standard error {rel_se:.1%}; observed per-trial RMS "
          f"spread {np.std(np.sqrt(sq)) / np.mean(np.sqrt(sq)):.1%}")
    assert 3 * rel_se < 0.15                                  # the 15 % test can fail
    assert abs(ratio - 1) < 0.15
