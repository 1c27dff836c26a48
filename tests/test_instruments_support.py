"""Shared scenarios and the Monte Carlo harness of the instrument tests (no tests here).

A *scenario* simulates an instrument on the nominal robot to learn which parameters the
data can identify (noise-free data, so the analysis runs at zero residual), then makes
a "true" robot by perturbing exactly those robot parameters and simulates the same
instrument (same seed: same placement) on it.

The Monte Carlo harness re-uses the noise-free true data: adding noise ``n`` of
standard deviation ``sigma`` to the observations changes the whitened residuals by
``-n / sigma``, a standard normal vector ``e``, so each seed solves
``min |r(theta) - e|^2`` over the estimated parameters by Gauss-Newton from the truth
(a batched first step, then one more step per seed), and computes the standard errors
exactly as :func:`kincal.identify.solver.calibrate` reports them
(``sigma0^2 (J^T J)^-1``, ``sigma0`` a posteriori).  ``test_instruments_calibration``
checks on real noisy simulations that ``calibrate`` gives the same numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from kincal.identify.solver import calibrate
from kincal.measure.base import StackedProblem, stack
from kincal.measure.simulate import perturb_robot
from kincal.robots.chain import Robot
from kincal.robots.files import load_serial_robot

NOMINAL = load_serial_robot("puma560")


@dataclass
class Scenario:
    true: Robot
    blocks: list[Any]
    truth: dict[str, float]          # every parameter (robot and blocks) -> true value
    free: list[str]                  # the identifiable set (from nominal noise-free data)
    report: Any                      # identifiability report on nominal data


def scenario(simulate: Callable[..., Any], n: int, seed: int, noise: float,
             nominal: Robot = NOMINAL, **options: Any) -> Scenario:
    """Simulate on the nominal robot (identifiability), then on a perturbed true robot.

    The data are exact, but every block states ``noise`` as its standard deviation (the
    Monte Carlo harness adds that noise).
    """
    blocks0, _ = simulate(nominal, np.random.default_rng(seed), n, 0.0, **options)
    res0 = calibrate(nominal, blocks0)
    robot_free = [p for p in res0.estimated if p in nominal.param_names]
    true = perturb_robot(nominal, np.random.default_rng(seed + 7919), names=robot_free)
    blocks, truth = simulate(true, np.random.default_rng(seed), n, 0.0, **options)
    for b in blocks:
        b.sigma = np.full_like(b.sigma, noise)
    return Scenario(true, blocks, dict(true.params(), **truth), list(res0.estimated),
                    res0.identifiability)


@dataclass
class MonteCarlo:
    names: list[str]
    ratio: np.ndarray                # RMS(error / reported std) per parameter over seeds
    std: np.ndarray                  # mean reported std per parameter
    rms_error: np.ndarray            # RMS error per parameter
    last_step: float                 # largest further GN step / std (converged?)


def true_theta(prob: StackedProblem, truth: dict[str, float]) -> np.ndarray:
    return np.array([truth[n] for n in prob.names])


def _normal(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column norms ``D`` and ``(A^T A)^-1`` of the column-scaled ``A = J D^-1``."""
    D = np.linalg.norm(J, axis=0)
    A = J / D
    # einsum rather than A.T @ A: a multithreaded GEMM of this size thrashes on a loaded
    # 2-core machine (30 ms instead of 0.1 ms)
    return D, np.linalg.inv(np.einsum("ij,ik->jk", A, A))


def monte_carlo(true: Robot, blocks: Sequence[Any], truth: dict[str, float],
                free: Sequence[str], seeds: int, seed0: int = 10_000) -> MonteCarlo:
    """Errors of the least-squares estimate over ``seeds`` noise draws (see module doc).

    Steps solve the column-scaled normal equations (small p x p systems: fast and
    accurate for these well-conditioned base sets); the covariance is the solver's
    ``sigma0^2 (J^T J)^-1``.
    """
    prob, _ = stack(true, list(blocks))
    theta = true_theta(prob, truth)
    est = np.array([prob.names.index(n) for n in free])
    r0, J0 = prob.residuals_and_jacobian(theta)
    assert np.max(np.abs(r0)) < 1e-6, "the noise-free data must fit the truth"
    E = np.random.default_rng(seed0).standard_normal((r0.size, seeds))
    D0, N0 = _normal(J0[:, est])
    X1 = (N0 @ ((J0[:, est] / D0).T @ (E - r0[:, None]))) / D0[:, None]
    M, p = r0.size, len(est)
    z = np.empty((seeds, p))
    stds = np.empty((seeds, p))
    errs = np.empty((seeds, p))
    last = 0.0
    for s in range(seeds):
        th = theta.copy()
        th[est] += X1[:, s]
        r, J = prob.residuals_and_jacobian(th)
        Je = J[:, est]
        D, Ninv = _normal(Je)
        th[est] += (Ninv @ ((Je / D).T @ (E[:, s] - r))) / D
        r2 = prob.residuals(th) - E[:, s]
        sigma0 = np.sqrt(r2 @ r2 / (M - p))
        std = sigma0 * np.sqrt(np.diag(Ninv)) / D
        errs[s] = th[est] - theta[est]
        stds[s] = std
        z[s] = errs[s] / std
        dx3 = (Ninv @ ((Je / D).T @ -r2)) / D        # would a further step move it?
        last = max(last, float(np.max(np.abs(dx3) / std)))
    return MonteCarlo(list(free), np.sqrt(np.mean(z**2, axis=0)), stds.mean(0),
                      np.sqrt(np.mean(errs**2, axis=0)), last)


def cases() -> dict[str, tuple[Callable[..., Any], int, dict[str, Any], float]]:
    """Instrument cases: ``name -> (simulator, poses, options, noise in SI / px)``.

    Noise levels are realistic: 10 um for a range meter, 1 arcsec for a theodolite,
    0.1 px for a camera, 5 um for plane probing, 20 um for placing on a fixture.
    """
    from kincal.measure import instruments as S

    arcsec = np.pi / 180 / 3600
    return {
        "range": (S.simulate_range, 50, {}, 1e-5),
        "range-incremental": (S.simulate_range, 50, {"incremental": True}, 1e-5),
        "range-one-station": (S.simulate_range, 80, {"stations": 1}, 1e-5),
        "bearing": (S.simulate_bearing, 60, {}, arcsec),
        "camera": (S.simulate_camera, 60, {}, 0.1),
        "camera-hand": (S.simulate_camera, 12, {"mount": "hand"}, 0.1),
        "plane": (S.simulate_plane, 120, {}, 5e-6),
        "plane-known": (S.simulate_plane, 100, {"known": True}, 5e-6),
        "fixture": (S.simulate_fixture, 60, {}, 2e-5),
    }
