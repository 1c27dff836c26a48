"""Drift alarms on sessions that did not change but were recorded elsewhere.

Each simulated robot's two sessions share its true parameters; each session adds its own
placement effect ``u_s ~ N(0, T)`` (2-8 times the calibration's standard error, the
size seen between placements of one MUKCa Panda) and the measurement noise ``e_s ~ N(0,
C_s)``.  The truth is exact, so the false-alarm rate of :func:`kincal.fleet.drift.compare`
with the fleet's estimate of ``T`` (:mod:`kincal.fleet.reproducibility`) is checked
against its stated value over thousands of robots, and drifts of a few total standard
errors are still found.  Without ``T`` the same robots are flagged by the dozen.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import binom

from kincal.fleet.drift import EVIDENCE, compare, fleet_reproducibility, z_threshold
from kincal.fleet.reproducibility import (
    ReproducibilityPool,
    estimate_reproducibility,
    pair_terms,
)

P = 17
NAMES = [f"a[{k}]" for k in range(P)]


def _record(serial, i, est, C):
    return {"id": i, "serial": serial, "date": f"2026-01-{i + 1:02d}", "robot": "model",
            "estimated": NAMES, "covariance": C, "metrics": {},
            "parameters": [{"name": n, "unit": "m", "role": "length", "estimate": v,
                            "estimated": True} for n, v in zip(NAMES, est, strict=True)]}


def _fleet(rng, n, tau, correlated=False, drift=None, design=None):
    """``n`` robots x two sessions; ``drift = (robot, parameter, k)`` moves one parameter
    of one robot by ``k`` total standard errors of its change; ``design`` (``lambda_i``
    per parameter): the placement effect is the design effect instead, each session's
    error ``N(0, C)`` scaled by ``lambda_i`` (larger where the session fixes a parameter
    worse), and ``tau`` is not used."""
    mix = rng.standard_normal((P, P)) / math.sqrt(P) if correlated else np.eye(P)
    out = []
    for r in range(n):
        J = rng.standard_normal((60, P)) * rng.uniform(0.5, 3, P)
        C = np.linalg.inv(J.T @ J) * 1e-8
        theta = rng.standard_normal(P) * 1e-3
        recs = []
        for _ in range(2):
            e = rng.multivariate_normal(np.zeros(P), C)
            if design is not None:
                recs.append(theta + design * e)
                continue
            u = mix @ (tau * rng.standard_normal(P))
            recs.append(theta + u + e)
        if drift is not None and drift[0] == r:
            k = drift[1]
            sd = math.sqrt(2 * C[k, k] + 2 * np.sum((mix[k] * tau) ** 2))
            recs[1][k] += drift[2] * sd * rng.choice([-1, 1])
        out.append((_record(f"R{r}", 2 * r, recs[0], C), _record(f"R{r}", 2 * r + 1,
                                                                  recs[1], C)))
    return out


def _drifts(fleet, alpha, use=True):
    repro = fleet_reproducibility([pair_terms(a, b) for a, b in fleet], alpha)
    return [compare(a, b, alpha, repro[b["serial"]] if use else None) for a, b in fleet]


def _tau(rng):
    # 2-8 times a typical calibration standard error of this construction (~3e-5)
    return rng.uniform(2, 8, P) * 3e-5


@pytest.mark.parametrize(("robots", "alpha", "correlated"),
                         [(50, 0.01, False), (10, 0.01, False), (50, 0.001, False),
                          (50, 0.01, True)])
def test_false_alarm_rate_holds_with_a_placement_effect(robots, alpha, correlated):
    rng = np.random.default_rng(robots + int(1 / alpha) + correlated)
    fleets = 3000 // robots
    flagged = n = 0
    for _ in range(fleets):
        tau = _tau(rng)
        drifts = _drifts(_fleet(rng, robots, tau, correlated), alpha)
        flagged += sum(d.flagged for d in drifts)
        n += len(drifts)
    # at most the stated rate, within the binomial spread of n robots (one-sided 99.9 %)
    assert flagged <= binom.ppf(0.999, n, alpha), (flagged, n)


def test_false_alarm_rate_holds_when_the_placement_effect_is_a_design_effect():
    # the MUKCa Pandas' case: the placement effect grows with how weakly a session fixes
    # a parameter (each session's error scaled by lambda = 2-8); an additive T alone,
    # estimated from robots that fix the parameter better, flags the others
    rng = np.random.default_rng(11)
    alpha, robots, fleets = 0.01, 50, 20
    flagged = additive_only = n = 0
    for _ in range(fleets):
        fleet = _fleet(rng, robots, None, design=rng.uniform(2, 8, P))
        repro = fleet_reproducibility([pair_terms(a, b) for a, b in fleet], alpha)
        for a, b in fleet:
            r = repro[b["serial"]]
            flagged += compare(a, b, alpha, r).flagged
            additive_only += compare(a, b, alpha, dataclasses.replace(
                r, inflation=None, evidence=None)).flagged
            n += 1
    assert flagged <= binom.ppf(0.999, n, alpha), (flagged, n)
    assert additive_only > binom.ppf(0.999, n, alpha) * 3, (additive_only, n)


def test_the_evidence_picks_the_model_the_fleet_follows():
    rng = np.random.default_rng(12)
    fleets = {"additive": _fleet(rng, 200, _tau(rng)),
              "design effect": _fleet(rng, 200, None, design=rng.uniform(2, 8, P))}
    for model, fleet in fleets.items():
        terms = [pair_terms(a, b) for a, b in fleet]
        est = estimate_reproducibility(terms)
        assert est is not None
        evidence = sum(est.support(n) for n in NAMES)
        assert (evidence > 10 * EVIDENCE) if model == "additive" else (
            evidence < -10 * EVIDENCE), (model, evidence)
        # and each change of a robot is judged by that model (the JSON says which)
        a, b = fleet[0]
        d = compare(a, b, 1e-3, fleet_reproducibility(terms)[b["serial"]])
        labels = [c.placement for c in d.changes]
        assert labels.count(model) >= 0.8 * P, (model, labels)
        assert d.to_dict()["changes"][0]["placement"] in ("additive", "design effect")


def test_without_the_placement_error_unchanged_robots_are_flagged():
    rng = np.random.default_rng(3)
    tau = _tau(rng)
    fleet = _fleet(rng, 50, tau)
    assert sum(d.flagged for d in _drifts(fleet, 1e-3, use=False)) > 25
    assert sum(d.flagged for d in _drifts(fleet, 1e-3)) <= 2


def test_the_estimate_recovers_the_placement_variance():
    rng = np.random.default_rng(4)
    tau = _tau(rng)
    fleet = _fleet(rng, 400, tau)
    est = estimate_reproducibility([pair_terms(a, b) for a, b in fleet])
    assert est is not None and est.pairs == 400
    got = np.array([est.variance[n] for n in NAMES])
    # method of moments over 400 pairs: relative sd ~ sqrt(2 / 400) (plus the noise term)
    assert np.all(np.abs(got / tau**2 - 1) < 5 * math.sqrt(2 / 400) + 0.1), got / tau**2


@pytest.mark.parametrize("sigmas", [6.0, 8.0])
def test_a_drift_of_a_few_sigma_is_still_found(sigmas):
    rng = np.random.default_rng(int(sigmas))
    # 60 fleets: the 0.1 % binomial bound on ~0.9 expected power still fails any loss of
    # power below ~0.75 (200 fleets cost 20 s each; the full rates: test_false_alarm_*)
    n, robots, hits, right = 60, 50, 0, 0
    for _ in range(n):
        k = int(rng.integers(P))
        d = _drifts(_fleet(rng, robots, _tau(rng), drift=(0, k, sigmas)), 1e-3)[0]
        hits += d.flagged
        right += d.flagged and d.moved[0].name == NAMES[k]
    zc = z_threshold(P, 1e-3)      # normal-equivalent z; t tails with nu = robots - 1 below
    # the per-parameter test alone finds a drift of k total sigma with probability about
    # Phi(k - z_crit) (t tails: a little less); the chi-square test adds to it
    from scipy.stats import norm

    expected = norm.sf(zc - sigmas) - 0.05
    assert hits >= binom.ppf(0.001, n, expected), (hits, expected)
    assert right >= 0.95 * hits


def test_too_few_robots_give_no_estimate():
    rng = np.random.default_rng(5)
    fleet = _fleet(rng, 2, _tau(rng))
    terms = [pair_terms(a, b) for a, b in fleet]
    assert ReproducibilityPool(terms).without(terms[0], "model") is None
    assert estimate_reproducibility(terms) is not None
