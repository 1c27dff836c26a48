"""The prior (maximum a-posteriori) option of ``calibrate`` against closed forms.

A measurement block that is linear in its own parameters, ``r = (A beta - y) / sigma``
(the robot does not enter), makes the MAP estimate a ridge regression:

    beta_hat = argmin |A beta - y|^2 / sigma^2 + sum_j ((beta_j - c_j) / s_j)^2
             = (J^T J + P^-2)^-1 (J^T y_w + P^-2 c),     J = A / sigma, y_w = y / sigma,

``P = diag(s_j)`` (``1 / s_j = 0`` for a parameter without a prior) and ``c`` the
values before calibration (the block's initial guess, 0 here: the plain ridge
``(J^T J + P^-2)^-1 J^T y_w``).  The posterior covariance is ``(J^T J + P^-2)^-1``
(``trust_sigma=True``).  Every number below is checked against these formulas,
computed with numpy alone.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.identify.solver import calibrate
from kincal.measure.base import MeasurementModel, ParamSpec
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot

ROBOT = load_serial_robot("puma560")
SIGMA = 0.01


class LinearBlock(MeasurementModel):
    """``r_i = (A_i . beta - y_i) / sigma``: a block linear in its parameters ``beta``."""

    def __init__(self, A: np.ndarray, y: np.ndarray, sigma: float = SIGMA,
                 name: str = "lin", guess: np.ndarray | None = None) -> None:
        self.name = name
        self.A = np.asarray(A, dtype=float)
        self.y = np.asarray(y, dtype=float)
        self.sigma = float(sigma)
        self.q = np.zeros((len(self.y), ROBOT.n))
        self.guess = np.zeros(self.A.shape[1]) if guess is None else np.asarray(guess, float)

    def parameters(self) -> ParamSpec:
        k = self.A.shape[1]
        return ParamSpec(tuple(f"{self.name}.b{j}" for j in range(k)), np.zeros(k),
                         ("m",) * k, ("instrument",) * k)

    def initial_guess(self, robot) -> np.ndarray:
        return self.guess.copy()

    def evaluate(self, robot, extra, jacobian=True):
        r = (self.A @ np.asarray(extra, dtype=float) - self.y) / self.sigma
        if not jacobian:
            return r, None, None
        return r, np.zeros((len(r), robot.num_params)), self.A / self.sigma

    def residual_owner(self) -> np.ndarray:
        return np.arange(len(self.y), dtype=np.intp)


def linear_data(rng: np.random.Generator, m: int = 60, k: int = 5, noise: float = 1.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A`` (m, k) with one weakly determined direction, ``beta_true``, noisy ``y``."""
    A = rng.normal(size=(m, k))
    A[:, -1] = A[:, -2] + 1e-3 * rng.normal(size=m)     # a weak combination
    beta = rng.normal(size=k) * 0.05
    y = A @ beta + noise * SIGMA * rng.normal(size=m)
    return A, beta, y


def ridge(A: np.ndarray, y: np.ndarray, s: np.ndarray, c: np.ndarray | None = None,
          weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form MAP and posterior covariance: ``1 / s = 0`` means no prior."""
    J = A / SIGMA
    w = np.ones(len(y)) if weights is None else weights
    inv2 = np.where(np.isfinite(s), 1.0 / s**2, 0.0)
    c = np.zeros(A.shape[1]) if c is None else c
    N = J.T @ (w[:, None] * J) + np.diag(inv2)
    beta = np.linalg.solve(N, J.T @ (w * y / SIGMA) + inv2 * c)
    return beta, np.linalg.inv(N)


def names(k: int, block: str = "lin") -> list[str]:
    return [f"{block}.b{j}" for j in range(k)]


def block_part(res, block: str = "lin") -> np.ndarray:
    return res.theta[res.problem.block_slice(block)]


def test_map_is_the_ridge_closed_form_with_its_posterior_covariance():
    rng = np.random.default_rng(1)
    A, _, y = linear_data(rng)
    s = np.array([0.02, np.inf, 0.5, 0.01, 0.003])          # b1 without a prior
    prior = {f"lin.b{j}": s[j] for j in range(5) if np.isfinite(s[j])}
    res = calibrate(ROBOT, [LinearBlock(A, y)], prior=prior, trust_sigma=True)
    want, cov = ridge(A, y, s)
    assert res.converged, res.message
    assert res.estimated == names(5)
    assert np.allclose(block_part(res), want, rtol=1e-10, atol=1e-13)
    assert np.allclose(res.covariance, cov, rtol=1e-8, atol=1e-16)
    # cost: data rows plus prior rows, at the solution
    rp = np.array([want[j] / s[j] for j in range(5) if np.isfinite(s[j])])
    assert res.cost == pytest.approx(0.5 * (np.sum(((A @ want - y) / SIGMA) ** 2)
                                            + np.sum(rp**2)), rel=1e-10)
    assert res.residuals.shape == (60,)                      # the measurements' only
    # the weak direction: least squares lets it float, the prior holds it near 0
    ls = calibrate(ROBOT, [LinearBlock(A, y)], trust_sigma=True)
    assert np.allclose(block_part(ls), ridge(A, y, np.full(5, np.inf))[0], rtol=1e-8)
    assert res.std[res.names.index("lin.b4")] < 0.2 * ls.std[ls.names.index("lin.b4")]
    # ``initial`` moves the start, not the centre of the prior
    moved = calibrate(ROBOT, [LinearBlock(A, y)], prior=prior, trust_sigma=True,
                      initial={"lin.b0": 0.3, "lin.b4": -0.2})
    assert np.allclose(block_part(moved), want, rtol=1e-10, atol=1e-13)
    # the centre is the block's guess (the value before calibration)
    c = np.array([0.01, 0.0, -0.02, 0.03, 0.04])
    centred = calibrate(ROBOT, [LinearBlock(A, y, guess=c)], prior=prior, trust_sigma=True)
    assert np.allclose(block_part(centred), ridge(A, y, s, c)[0], rtol=1e-10, atol=1e-13)


def test_robust_loss_does_not_down_weight_the_prior_rows():
    """Huber with no outlying measurement gives every data row weight 1: the MAP is
    then the plain ridge even though a prior row is far beyond the Huber threshold
    (as a measurement it would be down-weighted and the estimate would move)."""
    rng = np.random.default_rng(2)
    k = 4
    A = rng.normal(size=(200, k))
    beta = np.array([0.05, -0.02, 0.01, 0.03])
    y = A @ beta + SIGMA * rng.uniform(-1.2, 1.2, size=200)  # bounded: no outliers
    s = np.array([1e-3, np.inf, np.inf, np.inf])             # b0: prior 50x too tight
    prior = {"lin.b0": s[0]}
    res = calibrate(ROBOT, [LinearBlock(A, y)], loss="huber", prior=prior, noise_scale=1.0)
    want, _ = ridge(A, y, s)
    assert res.converged, res.message
    assert np.all(res.weights == 1.0) and res.outliers == []
    assert abs(want[0] / s[0]) > 10 * 3.0                      # far beyond loss_scale
    assert np.allclose(block_part(res), want, rtol=1e-10, atol=1e-13)
    # one gross outlier: it is down-weighted, the prior row still is not; the solution
    # is the weighted ridge with the solver's final measurement weights
    y2 = y.copy()
    y2[7] += 50 * SIGMA
    res2 = calibrate(ROBOT, [LinearBlock(A, y2)], loss="huber", prior=prior,
                     noise_scale=1.0)
    assert res2.outliers == [("lin", 7)] and res2.weights[7] < 0.25
    assert np.all(np.delete(res2.weights, 7) == 1.0)
    want2, _ = ridge(A, y2, s, weights=res2.weights)
    assert np.allclose(block_part(res2), want2, rtol=1e-8, atol=1e-12)


def test_stages_with_a_prior():
    """Stage 1 estimates b0, b1 with the others held at their initial values (0);
    stage 2 all: each stage is the ridge of its own parameters (noise scale 1: the
    stated sigmas)."""
    rng = np.random.default_rng(3)
    A, _, y = linear_data(rng)
    s = np.array([0.01, 0.02, 0.5, 0.01, 0.003])
    prior = {"lin.b*": 0.5, "lin.b0": 0.01, "lin.b1": 0.02, "lin.b3": 0.01, "lin.b4": 0.003}
    res = calibrate(ROBOT, [LinearBlock(A, y)], prior=prior, noise_scale=1.0,
                    stages=[["lin.b0", "lin.b1"], "all"])
    assert [st for st, _ in res.stages] == ["lin.b0,lin.b1", "all"]
    assert res.stages[0][1] == names(2) and res.stages[1][1] == names(5)
    first = [h for h in res.history if h.stage == "lin.b0,lin.b1"][-1].theta
    want1, _ = ridge(A[:, :2], y, s[:2])
    b1 = first[res.problem.block_slice("lin")]
    assert np.allclose(b1[:2], want1, rtol=1e-10) and np.all(b1[2:] == 0.0)
    assert np.allclose(block_part(res), ridge(A, y, s)[0], rtol=1e-10, atol=1e-13)
    assert res.prior == {n: float(v) for n, v in zip(names(5), s, strict=True)}


def test_prior_std_in_the_result_dictionary():
    rng = np.random.default_rng(4)
    A, _, y = linear_data(rng)
    A[:, 2] = 0.0                                            # b2: no effect at all
    res = calibrate(ROBOT, [LinearBlock(A, y)], prior={"lin.b0": 0.02, "lin.b2": 0.1,
                                                        "theta_offset[*]": 1e-3})
    d = json.loads(json.dumps(res.to_dict()))
    by = {p["name"]: p for p in d["parameters"]}
    assert by["lin.b0"]["prior_std"] == 0.02
    assert by["lin.b1"]["prior_std"] is None                 # no prior given
    # a prior on parameters that are not estimated is not reported (nor used)
    assert by["lin.b2"]["prior_std"] is None and not by["lin.b2"]["estimated"]
    assert by["theta_offset[2]"]["prior_std"] is None
    assert res.prior == {"lin.b0": 0.02}
    text = res.summary()
    assert "MAP estimate: 1 estimated parameter(s)" in text and "prior" in text.splitlines()[2]


def test_a_prior_does_not_make_a_parameter_identifiable():
    """b3 duplicates b2 (the same column): the data cannot tell them apart, and a prior
    on both does not change that: b3 is held at its initial value, named dependent,
    and the estimated set is the one without a prior."""
    rng = np.random.default_rng(5)
    A, _, y = linear_data(rng)
    A[:, 3] = A[:, 2]
    plain = calibrate(ROBOT, [LinearBlock(A, y)])
    res = calibrate(ROBOT, [LinearBlock(A, y)], prior={"lin.*": 0.01}, trust_sigma=True)
    assert res.estimated == plain.estimated == ["lin.b0", "lin.b1", "lin.b2", "lin.b4"]
    assert res.identifiability.dependent["lin.b3"] == ["lin.b2"]
    i = res.names.index("lin.b3")
    assert res.theta[i] == 0.0 and res.std[i] == 0.0 and "lin.b3" not in res.prior
    keep = [0, 1, 2, 4]
    want, cov = ridge(A[:, keep], y, np.full(4, 0.01))
    assert np.allclose(block_part(res)[keep], want, rtol=1e-10, atol=1e-13)
    assert np.allclose(res.covariance, cov, rtol=1e-8, atol=1e-16)
    # the same on a robot: position data cannot separate d[3] from d[2] (parallel axes)
    from kincal.measure.instruments.position import simulate_positions
    from kincal.measure.simulate import perturb_robot, random_configurations

    rng = np.random.default_rng(6)
    q = random_configurations(ROBOT, 30, rng)
    blk = simulate_positions(perturb_robot(ROBOT, rng), q, rng, 1e-5,
                             [1.5, 0.4, -0.2, 0.1, -0.15, 2.0], [0.03, -0.02, 0.06])
    a = calibrate(ROBOT, [blk])
    b = calibrate(ROBOT, [blk], prior={"d[*]": 1e-3, "a[*]": 1e-3})
    assert b.estimated == a.estimated and "d[3]" not in b.estimated
    assert b.params["d[3]"] == ROBOT.params()["d[3]"]
    assert set(b.prior) == {n for n in b.estimated if n[:2] in ("d[", "a[")}


def noise_fixed_point(A: np.ndarray, y: np.ndarray, s: np.ndarray, sigma: float
                      ) -> tuple[float, np.ndarray, np.ndarray, float]:
    """The module docstring's fixed point, with numpy alone: the ridge with the prior
    rows scaled by ``k``, ``k^2 = RSS_w / (M - p_eff)``, iterated to convergence.
    Returns ``(k, beta, posterior covariance, p_eff)``."""
    J = A / sigma
    k = 1.0
    for _ in range(200):
        N = J.T @ J + np.diag(k**2 / s**2)
        beta = np.linalg.solve(N, J.T @ (y / sigma))
        p_eff = float(np.trace(np.linalg.solve(N, J.T @ J)))
        k_new = math.sqrt(np.sum(((A @ beta - y) / sigma) ** 2) / (len(y) - p_eff))
        if abs(k_new / k - 1) < 1e-12:
            break
        k = k_new
    N = J.T @ J + np.diag(k**2 / s**2)
    return k, np.linalg.solve(N, J.T @ (y / sigma)), k**2 * np.linalg.inv(N), p_eff


def test_the_noise_scale_is_estimated_before_the_prior_is_weighed():
    """Real noise 30x the stated sigma (a file without a sigma column): the noise scale
    is the fixed point sigma0^2 = RSS / (M - p_eff), the MAP is the ridge with the prior
    rows scaled by it, the covariance the posterior (J^T J / sigma0^2 + P^-2)^-1 ... and
    stating any other sigma gives the same estimate: the prior's weight no longer
    depends on a sigma nobody measured."""
    rng = np.random.default_rng(7)
    A, _, y = linear_data(rng, m=80, noise=30.0)
    s = np.array([0.02, 0.05, 0.05, 0.01, 0.003])
    prior = {f"lin.b{j}": s[j] for j in range(5)}
    res = calibrate(ROBOT, [LinearBlock(A, y)], prior=prior, tol_step=1e-14)
    k, want, cov, p_eff = noise_fixed_point(A, y, s, SIGMA)
    assert res.noise_scale_estimated and k > 20
    # the iteration stops when sigma0 changes by less than 0.5 %
    assert res.sigma0 == pytest.approx(k, rel=5e-3)
    assert res.effective_parameters == pytest.approx(p_eff, rel=1e-2)
    assert np.allclose(block_part(res), want, rtol=1e-2, atol=1e-6)
    assert np.allclose(res.covariance, cov, rtol=2e-2)
    # the stated sigma no longer matters: 100x larger, the same MAP and covariance
    big = calibrate(ROBOT, [LinearBlock(A, y, sigma=100 * SIGMA)], prior=prior,
                    tol_step=1e-14)
    assert np.allclose(block_part(big), block_part(res), rtol=1e-2, atol=1e-7)
    assert np.allclose(big.covariance, res.covariance, rtol=2e-2)
    assert big.sigma0 == pytest.approx(res.sigma0 / 100, rel=1e-2)
    # with the stated sigmas (noise_scale=1) the data weigh ~900x too much: the weak
    # combination b3 - b4 follows the noise far beyond its prior (0.05 and 0.003)
    stated = calibrate(ROBOT, [LinearBlock(A, y)], prior=prior, noise_scale=1.0)
    assert abs(block_part(stated)[-1]) > 3 * abs(block_part(res)[-1])


def test_data_only_standard_errors_name_the_parameters_the_prior_holds():
    """b4 follows b3 to 1e-3: the data alone fix b3 and b4 to ~sigma / 1e-3 each, far
    beyond their priors, so the prior holds them; b0..b2 are fixed by the data."""
    rng = np.random.default_rng(8)
    A, _, y = linear_data(rng, m=60)
    A[:, 3] = A[:, 4] + 1e-3 * rng.normal(size=60)
    s = np.full(5, 0.05)
    res = calibrate(ROBOT, [LinearBlock(A, y)], prior={"lin.*": 0.05}, trust_sigma=True)
    J = A / SIGMA
    want = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    got = res.data_std[[res.names.index(n) for n in names(5)]]
    assert np.allclose(got, want, rtol=1e-6)
    assert res.held_by_prior == [n for n, d, t in zip(names(5), want, s, strict=True) if d > t]
    assert res.held_by_prior == ["lin.b3", "lin.b4"]
    assert np.isnan(res.data_std[res.names.index("theta_offset[1]")])
    plain = calibrate(ROBOT, [LinearBlock(A, y)])
    assert plain.data_std is None and plain.held_by_prior == []


def test_prior_tolerances_is_what_the_command_line_uses_by_default() -> None:
    """``prior="tolerances"`` gives the same estimate as the explicit tolerance mapping the
    workflow builds for ``kincal calibrate``'s default."""
    from kincal.identify.tolerances import resolve_tolerances
    from kincal.measure.base import stack

    rng = np.random.default_rng(3)
    robot = load_serial_robot("puma560")
    truth = perturb_robot(robot, rng)
    q = random_configurations(robot, 40, rng)
    data = simulate_positions(truth, q, rng, noise_std=1e-5)
    prob, _ = stack(robot, [data])
    explicit = resolve_tolerances(prob.names, prob.units, prob.roles).prior()
    a = calibrate(robot, [data], prior="tolerances")
    b = calibrate(robot, [data], prior=explicit)
    assert a.prior == b.prior and a.prior
    assert np.array_equal(a.theta, b.theta)
    with pytest.raises(KincalError, match="'tolerances'"):
        calibrate(robot, [data], prior="tolerance")
