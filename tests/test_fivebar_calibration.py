"""Five-bar calibration: analytic Jacobians, the thesis experiment, uncertainty, identifiability."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kincal.errors import KincalError, UnreachableError
from kincal.parallel import kinematics as kin
from kincal.parallel import residuals as res
from kincal.parallel.calibration import LENGTHS_FREE, ROBOT_FREE, calibrate
from kincal.parallel.reference_experiment import (
    EXPERIMENT_TRUE_LENGTHS,
    experiment_robots,
    run_reference_experiment,
    simulate,
)

# Central differences with step h have truncation error ~ h^2 |f'''| and rounding
# ~ eps |f| / h: with h = 1e-6 and |f|, |f'''| of order 1-10 both stay below ~1e-8.
FD_STEP = 1e-6
FD_TOL = 1e-7


def measured_points(true_theta: np.ndarray, q: np.ndarray, assembly: int) -> np.ndarray:
    """J3 of the true robot expressed in the measurement frame: R^T (x - t)."""
    x, ok = kin.fk(true_theta[:10], q, np.full(len(q), assembly))
    assert np.all(ok)
    return (x - true_theta[10:12]) @ res.rotation(true_theta[12])


def central_difference(model, theta, q, x, branch) -> np.ndarray:
    cols = []
    for k in range(theta.size):
        d = np.zeros_like(theta)
        d[k] = FD_STEP
        # residual = measured - model, so the model Jacobian is -d(residual)
        rp = model(theta + d, q, x, branch)[0]
        rm = model(theta - d, q, x, branch)[0]
        cols.append(-(rp - rm) / (2 * FD_STEP))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("kind", ["ik", "fk"])
def test_jacobians_equal_central_differences(kind: str) -> None:
    rng = np.random.default_rng(11)
    nominal, _ = experiment_robots()
    theta = np.r_[nominal.param_values, 0.1, -0.2, 0.05] + rng.normal(0.0, 0.02, 13)
    q = np.c_[rng.uniform(0.2, 1.3, 30), rng.uniform(1.8, 2.9, 30)]
    x = measured_points(theta, q, -1)
    if kind == "ik":
        model, branch = res.ik_model, res.ik_modes_nearest(theta, q, x)
    else:
        model, branch = res.fk_model, res.fk_assembly_nearest(theta, q, x)
    r, jac, ok = model(theta, q, x, branch)
    assert np.all(ok) and np.max(np.abs(r)) < 1e-12
    numeric = central_difference(model, theta, q, x, branch)
    assert np.max(np.abs(jac - numeric)) < FD_TOL * max(1.0, np.max(np.abs(jac)))


@pytest.mark.parametrize("method", ["gauss-newton", "lm"])
@pytest.mark.parametrize("residual", ["ik", "fk"])
def test_thesis_experiment_converges_to_the_true_lengths(method: str, residual: str) -> None:
    result, true = run_reference_experiment(n=50, seed=0, method=method, residual=residual)
    assert result.converged
    assert result.iterations <= 8  # measured: 5-6
    for name, value in EXPERIMENT_TRUE_LENGTHS.items():
        assert abs(result.params[name] - value) < 1e-9
        traj = result.trajectory(name)
        assert traj[0] == {"l1": 2.0, "l2": 2.0, "l3": 3.0, "l4": 3.0}[name]
        # by the second step every length is within 0.5 % of its true value
        assert abs(traj[2] - value) < 5e-3 * value
    assert result.history[-1]["step"] < 1e-10
    assert result.free == LENGTHS_FREE


def test_thesis_history_in_json(tmp_path) -> None:
    result, _ = run_reference_experiment()
    path = result.to_json(tmp_path / "thesis.json")
    data = json.loads(path.read_text())
    assert [h["iteration"] for h in data["history"]] == list(range(result.iterations + 1))
    assert data["history"][0]["params"]["l1"] == 2.0
    assert data["history"][-1]["params"]["l4"] == pytest.approx(3.3, abs=1e-12)
    assert data["units"]["l1"] == "m" and data["converged"] is True


def monte_carlo(free, method: str, seeds: int, noise: float):
    nominal, true = experiment_robots()
    idx = [true.param_names.index(n) for n in free]
    errors, stderrs = [], []
    for seed in range(seeds):
        q, x = simulate(true, nominal, 50, np.random.default_rng(seed), noise=noise)
        r = calibrate(nominal, q, x, free=free, method=method)
        assert r.converged and r.free == tuple(free)
        errors.append(r.robot.param_values[idx] - true.param_values[idx])
        stderrs.append([r.std_errors[n] for n in free])
    errors, stderrs = np.array(errors), np.array(stderrs)
    return np.sqrt(np.mean(errors**2, axis=0)) / np.sqrt(np.mean(stderrs**2, axis=0))


def test_joint_noise_errors_match_reported_standard_errors() -> None:
    # 200 seeds: the RMS of the errors is known to about 1/sqrt(400) = 5 %, so a
    # correct standard error gives a ratio within 1/1.2 .. 1.2 (4 sigma).  Measured:
    # 0.995, 1.026, 1.047, 1.077 for l1..l4.
    ratio = monte_carlo(LENGTHS_FREE, "gauss-newton", 200, 1e-3)
    assert np.all((ratio > 1 / 1.2) & (ratio < 1.2)), ratio


def test_joint_noise_all_ten_parameters_within_standard_errors() -> None:
    # measured ratios 0.94 .. 1.09 over the ten parameters (200 seeds)
    ratio = monte_carlo(ROBOT_FREE, "lm", 200, 1e-3)
    assert np.all((ratio > 1 / 1.2) & (ratio < 1.2)), dict(zip(ROBOT_FREE, ratio, strict=True))


def perturbed_truth():
    nominal, true = experiment_robots()
    true = true.with_params(
        {"base1.x": 1.03, "base1.y": -0.02, "base2.x": -0.97, "base2.y": 0.015,
         "offset1": 0.01, "offset2": -0.015}
    )
    q, x = simulate(true, nominal, 60, np.random.default_rng(3))
    return nominal, true, q, x


@pytest.mark.parametrize("residual", ["ik", "fk"])
def test_offsets_and_bases_recovered_when_free(residual: str) -> None:
    nominal, true, q, x = perturbed_truth()
    result = calibrate(nominal, q, x, free=ROBOT_FREE, method="lm", residual=residual)
    assert result.converged and result.identifiability.full_rank
    assert np.max(np.abs(result.robot.param_values - true.param_values)) < 1e-9


def test_free_measurement_frame_names_the_dependent_parameters() -> None:
    nominal, true, q, x_base = perturbed_truth()
    frame_true = np.array([0.3, -0.2, 0.05])
    x = (x_base - frame_true[:2]) @ res.rotation(frame_true[2])
    free = list(ROBOT_FREE) + list(res.FRAME_NAMES)
    result = calibrate(nominal, q, x, free=free, method="lm", frame=(0.28, -0.19, 0.04))
    ident = result.identifiability
    assert ident.held == ("base1.x", "base1.y", "base2.y")
    # a shift of base1.x is absorbed by frame.x and base2.x together (a translation)
    assert ident.absorbed["base1.x"] == pytest.approx({"frame.x": 1.0, "base2.x": 1.0})
    # base1.y and base2.y are absorbed by the frame's rotation and the two offsets
    for held in ("base1.y", "base2.y"):
        assert {"frame.theta", "offset1", "offset2"} <= set(ident.absorbed[held])
    assert any("base1.x" in line and "frame.x" in line for line in ident.describe())
    # what the data do fix is recovered: lengths, base distance, offset difference
    est = result.robot
    assert np.max(np.abs(est.param_values[:4] - true.param_values[:4])) < 1e-9
    dist = lambda r: np.hypot(r.base2_x - r.base1_x, r.base2_y - r.base1_y)  # noqa: E731
    assert dist(est) == pytest.approx(dist(true), abs=1e-9)
    assert est.offset1 - est.offset2 == pytest.approx(true.offset1 - true.offset2, abs=1e-9)
    assert result.rms < 1e-12


def test_translation_absorption_is_exact() -> None:
    # truth: base1.x off by +0.02 m and the measurement frame shifted; base1.x held
    nominal, true = experiment_robots()
    true = true.with_params({"base1.x": 1.02})
    q, x_base = simulate(true, nominal, 40, np.random.default_rng(4))
    frame_true = np.array([0.05, -0.03, 0.0])
    x = x_base - frame_true[:2]
    free = ["l1", "l2", "l3", "l4", "base1.x", "base2.x", "frame.x", "frame.y"]
    result = calibrate(nominal, q, x, free=free, method="lm")
    assert result.identifiability.held == ("base1.x",)
    shift = nominal.base1_x - true.base1_x  # (nominal - true) of the held parameter
    coeff = result.identifiability.absorbed["base1.x"]
    assert result.params["frame.x"] == pytest.approx(frame_true[0] + coeff["frame.x"] * shift,
                                                     abs=1e-9)
    assert result.params["base2.x"] == pytest.approx(true.base2_x + coeff["base2.x"] * shift,
                                                     abs=1e-9)


def test_errors_name_the_problem() -> None:
    nominal, true = experiment_robots()
    q, x = simulate(true, nominal, 20, np.random.default_rng(0))
    with pytest.raises(KincalError, match="unknown five-bar parameter 'l9'"):
        calibrate(nominal, q, x, free=["l9"])
    with pytest.raises(KincalError, match="too few"):
        calibrate(nominal, q[:2], x[:2], free=ROBOT_FREE)
    far = x.copy()
    far[5] = [0.0, 40.0]
    with pytest.raises(UnreachableError, match="data.csv line 9: the measured point is out"):
        calibrate(nominal, q, far, labels=[f"data.csv line {k + 4}" for k in range(20)])


def test_report_and_repr() -> None:
    result, _ = run_reference_experiment(noise=1e-3)
    text = result.report()
    assert "| l1 | 2000.0000 |" in text and "std error" in text    # 2 m nominal, in mm
    rows = [r.split("|")[2:4] for r in text.splitlines() if r.startswith("| l")]
    assert rows and all(len(x.strip().split(".")[1]) == 4 for r in rows for x in r)   # 0.1 um
    assert "l1=" in repr(result) and " mm" in repr(result)
