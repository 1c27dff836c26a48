"""The memory reuse of a solver stage (:class:`kincal.identify.linearisation.Linearisation`):
what it keeps, when it drops, and that a reused triangle equals a fresh one."""

from __future__ import annotations

import numpy as np
import pytest

import kincal.identify.linearisation as linearisation
from kincal.identify.gauss_newton import gauss_newton_step
from kincal.identify.levenberg_marquardt import Damping, levenberg_marquardt_step, triangular_step
from kincal.identify.linearisation import Linearisation, half_weighted_ss
from kincal.identify.status import StageStatus
from kincal.measure.base import stack
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot


class Counting:
    """A stacked problem that counts its residual evaluations and triangle builds."""

    def __init__(self, prob) -> None:
        self.prob = prob
        self.residual_calls = 0
        self.triangle_calls = 0

    def residuals(self, theta):
        self.residual_calls += 1
        return self.prob.residuals(theta)

    def compressed(self, theta, weights, columns):
        self.triangle_calls += 1
        return self.prob.compressed(theta, weights, columns)

    def num_residuals(self) -> int:
        return self.prob.num_residuals()


@pytest.fixture(scope="module")
def problem():
    """A puma560 seen by a position tracker from 30 poses of a perturbed robot."""
    rng = np.random.default_rng(11)
    nominal = load_serial_robot("puma560")
    true = perturb_robot(nominal, rng)
    q = random_configurations(nominal, 30, rng)
    prob, theta0 = stack(nominal, [simulate_positions(true, q, rng, 1e-5)])
    est = [prob.names.index(n) for n in prob.names if n.startswith("tracker.")]
    return prob, theta0, est


def ones(prob):
    return np.broadcast_to(np.float64(1.0), (prob.num_residuals(),))


def test_a_small_residual_vector_is_kept_beside_its_triangle(problem):
    prob, theta0, est = problem
    counting = Counting(prob)
    lin = Linearisation(counting, theta0, None, reuse_trials=True)
    assert lin.keep_residuals
    C = lin.linearise(ones(prob), est)
    assert C.r is None and lin.exact                 # the triangle without its residuals
    lin.drop_residuals()
    assert lin.r is None
    calls = counting.residual_calls
    r = lin.residuals()                             # the kept vector, not evaluated again
    assert counting.residual_calls == calls and r is lin.kept
    np.testing.assert_allclose(r, prob.residuals(theta0), rtol=1e-12, atol=0)
    # while dropped, the triangle's cost stands for the residuals'
    lin.drop_residuals()
    assert lin.cost(ones(prob)) == pytest.approx(half_weighted_ss(r, ones(prob)), rel=1e-12)
    assert lin.r is None


def test_a_large_residual_vector_is_evaluated_again(problem, monkeypatch):
    prob, theta0, est = problem
    monkeypatch.setattr(linearisation, "KEEP_RESIDUALS_BYTES", 0)
    counting = Counting(prob)
    lin = Linearisation(counting, theta0, None, reuse_trials=True)
    assert not lin.keep_residuals
    lin.linearise(ones(prob), est)
    lin.drop_residuals()
    calls = counting.residual_calls
    lin.residuals()
    assert counting.residual_calls == calls + 1


def test_robust_weights_neither_reuse_trials_nor_keep_residuals(problem):
    prob, theta0, est = problem
    counting = Counting(prob)
    lin = Linearisation(counting, theta0, None, reuse_trials=False)
    assert not lin.keep_residuals and lin.r is not None   # residuals first: the weights
    new = theta0.copy()
    new[est] += 1e-4
    C, r = lin.trial(new, ones(prob), est, build=True)
    assert C is None and counting.triangle_calls == 0
    lin.linearise(ones(prob), est)
    lin.move(new, r, None, tiny=True)
    assert lin.triangle is None                     # built again at the new point


def test_a_reused_trial_triangle_equals_a_fresh_one(problem):
    prob, theta0, est = problem
    w = ones(prob)
    counting = Counting(prob)
    lin = Linearisation(counting, theta0, None, reuse_trials=True)
    lin.linearise(w, est)
    new = theta0.copy()
    new[est] += 1e-3
    C, r = lin.trial(new, w, est, build=True)
    assert C is not None
    lin.move(new, r, C, tiny=False)
    builds = counting.triangle_calls
    reused = lin.linearise(w, est)
    assert counting.triangle_calls == builds        # no second pass over the data
    fresh = prob.compressed(new, w, est)
    np.testing.assert_array_equal(reused.R, fresh.R)
    np.testing.assert_array_equal(reused.z, fresh.z)
    assert reused.cost == fresh.cost and reused.rho == fresh.rho
    np.testing.assert_array_equal(lin.residuals(), fresh.r)


def test_a_tiny_step_keeps_the_triangle_where_it_started(problem):
    prob, theta0, est = problem
    w = ones(prob)
    lin = Linearisation(prob, theta0, None, reuse_trials=True)
    before = lin.linearise(w, est)
    new = theta0.copy()
    new[est] += 1e-13
    C, r = lin.trial(new, w, est, build=False)
    assert C is None
    lin.move(new, r, None, tiny=True)
    assert lin.triangle is before and not lin.exact
    np.testing.assert_array_equal(lin.residuals(), r)


def test_the_methods_reach_the_minimum_of_the_registration(problem):
    """From the closed-form guess the tracker frame is nearly linear: Gauss-Newton's
    and Levenberg-Marquardt's first steps both lower the cost and agree."""
    prob, theta0, est = problem
    w = ones(prob)
    steps = []
    for method in ("gauss-newton", "lm"):
        lin = Linearisation(prob, theta0.copy(), None, reuse_trials=True)
        here = lin.linearise(w, est)
        cost = lin.cost(w)
        D = np.linalg.norm(here.R, axis=0)
        A = here.R / D
        lin.drop_residuals()
        if method == "gauss-newton":
            step = gauss_newton_step(lin, A, D, here.z, est, w, 1e-10)
        else:
            step = levenberg_marquardt_step(lin, Damping(), A, D, here.z, est, w, cost, 1e-10)
        assert step.stop is None and step.cost <= cost
        steps.append(step.theta)
    np.testing.assert_allclose(steps[0], steps[1], rtol=1e-9, atol=1e-12)


def test_triangular_step_is_the_undamped_svd_step():
    rng = np.random.default_rng(2)
    A = np.triu(rng.normal(size=(5, 5))) + 3 * np.eye(5)
    z = rng.normal(size=5)
    step = triangular_step(A, z)
    assert step is not None
    np.testing.assert_allclose(step, -np.linalg.solve(A, z), rtol=1e-12)
    singular = A.copy()
    singular[4, 4] = 0.0
    assert triangular_step(singular, z) is None


def test_a_step_that_cannot_lower_the_cost_ends_the_stage(problem):
    """At the minimum, a damped step within tol_step that does not descend stops with
    NO_DESCENT_STEP (one evaluation, not a dozen doublings of lambda)."""
    prob, theta0, est = problem
    w = ones(prob)
    lin = Linearisation(prob, theta0.copy(), None, reuse_trials=True)
    for _ in range(4):                              # walk to the minimum
        here = lin.linearise(w, est)
        D = np.linalg.norm(here.R, axis=0)
        step = gauss_newton_step(lin, here.R / D, D, here.z, est, w, 0.0)
        lin.move(step.theta, step.r, step.triangle, False)
    here = lin.linearise(w, est)
    D = np.linalg.norm(here.R, axis=0)
    cost = lin.cost(w)
    step = levenberg_marquardt_step(lin, Damping(lam=1.0, good=False), here.R / D, D, here.z,
                                    est, w, cost, tol_step=1.0)
    assert step.tiny
    assert step.stop in (None, StageStatus.NO_DESCENT_STEP)
    assert (step.stop is None) == (step.cost < cost)
