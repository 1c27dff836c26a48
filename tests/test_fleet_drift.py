"""Drift alarms: the detector's statistics, then a simulated fleet end to end.

The detector (:func:`kincal.fleet.drift.compare`) is checked first on synthetic
estimates drawn from known covariances, where the truth is exact: the false-alarm rate
stays within its budget and the detection rate of a drift of ``k`` combined standard
errors follows ``Phi(k - z_crit)``.  Then on a simulated fleet calibrated for real
(100 undrifted robots, 5 with a drift of 10 predicted σ): every drift is found, on the
parameter that moved, and at most 1 % of the undrifted robots are flagged.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from cli_helpers import run

pytest.importorskip("sqlalchemy", reason="the fleet extra (SQLAlchemy) is not installed")

from scipy.stats import binom, norm  # noqa: E402

from kincal.fleet.drift import compare, fleet_drift, z_threshold  # noqa: E402
from kincal.fleet.engine import SerialEngine  # noqa: E402
from kincal.fleet.manifest import load_fleet  # noqa: E402
from kincal.fleet.run import calibrate_fleet  # noqa: E402
from kincal.fleet.simulate import simulate_fleet  # noqa: E402
from kincal.fleet.store import HistoryStore  # noqa: E402

P = 17
ALPHA = 1e-3


def _record(rng, theta, C, i):
    est = rng.multivariate_normal(theta, C)
    names = [f"a[{k}]" for k in range(P)]
    return {"id": i, "serial": "S", "date": f"2026-01-{i + 1:02d}", "estimated": names,
            "covariance": C, "metrics": {},
            "parameters": [{"name": n, "unit": "m", "role": "length", "estimate": v,
                            "estimated": True} for n, v in zip(names, est, strict=True)]}


def _pair(rng, drift_sigmas: float = 0.0):
    J = rng.standard_normal((60, P)) * rng.uniform(0.5, 3, P)
    C = np.linalg.inv(J.T @ J) * 1e-8
    theta = rng.standard_normal(P) * 1e-3
    k = int(rng.integers(P))
    moved = theta.copy()
    moved[k] += drift_sigmas * math.sqrt(2 * C[k, k]) * rng.choice([-1, 1])
    return compare(_record(rng, theta, C, 0), _record(rng, moved, C, 1), ALPHA), f"a[{k}]"


def test_false_alarms_stay_within_the_budget():
    rng = np.random.default_rng(1)
    n = 3000
    flagged = sum(_pair(rng)[0].flagged for _ in range(n))
    # Bonferroni + a split budget are conservative: the rate is at most ALPHA; allow the
    # binomial spread of n robots (one-sided 99.9 %), far below the 1 % the issue allows.
    assert flagged <= binom.ppf(0.999, n, ALPHA), flagged


@pytest.mark.parametrize("sigmas", [5.0, 6.0, 8.0])
# measured with n = 2000 (same construction): 5σ 85.8 %, 6σ 98.5 %, 7σ 99.95 %, 8σ 99.95 %
def test_detection_rate_follows_the_threshold(sigmas):
    rng = np.random.default_rng(int(sigmas))
    n = 400
    results = [_pair(rng, sigmas) for _ in range(n)]
    hits = sum(d.flagged for d, _ in results)
    on_the_right_one = sum(d.flagged and d.moved[0].name == k for d, k in results)
    zc = z_threshold(P, ALPHA)
    expected = norm.sf(zc - sigmas)                    # the per-parameter test alone
    assert hits >= binom.ppf(0.001, n, expected), (hits, expected)
    assert on_the_right_one >= 0.97 * hits


@pytest.fixture(scope="module")
def drifted_fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("drift")
    fleet = simulate_fleet(root, robots=105, poses=30, drifted=5, broken=0, seed=7)
    with HistoryStore(str(root / "h.db")) as store:
        calibrate_fleet(load_fleet(fleet.manifest), store, SerialEngine())
        drifts = {d.serial: d for d in fleet_drift(store, ALPHA)}
    return fleet, drifts, root / "h.db"


def test_every_injected_drift_is_found_on_its_parameter(drifted_fleet):
    fleet, drifts, _ = drifted_fleet
    injected = {r["serial"]: r["drift"] for r in fleet.robots if r["drift"]}
    assert len(injected) == 5 and len(drifts) == 105
    for serial, truth in injected.items():
        d = drifts[serial]
        change = next(c for c in d.changes if c.name == truth["parameter"])
        # a drift above 5σ (of the change's standard error with the fleet's
        # session-to-session error, kincal.fleet.reproducibility) ...
        assert abs(truth["change"]) / change.sigma > 5
        assert d.flagged                                   # ... is found
        assert d.moved[0].name == truth["parameter"]       # on the parameter that moved
        assert change.change == pytest.approx(truth["change"], abs=4 * change.sigma)
        assert d.rms_previous_model_m > 1.5 * d.rms_latest_m


def test_at_most_one_percent_of_undrifted_robots_are_flagged(drifted_fleet):
    fleet, drifts, db = drifted_fleet
    clean = [r["serial"] for r in fleet.robots if not r["drift"]]
    flagged = [s for s in clean if drifts[s].flagged]
    assert len(flagged) <= 0.01 * len(clean), flagged
    # the calibrations' covariances are right: with them alone (no session-to-session
    # error: this simulation has none) chi2 / dof averages 1 over undrifted robots
    with HistoryStore(str(db)) as store:
        own = {d.serial: d for d in fleet_drift(store, ALPHA, reproducibility=False)}
    ratio = np.mean([own[s].chi2 / own[s].dof for s in clean])
    dof = own[clean[0]].dof
    tol = 4 * math.sqrt(2 / (dof * len(clean)))
    assert abs(ratio - 1) < tol, ratio
    # the fleet's estimate of that error (zero here, estimated from noise and kept positive
    # semi-definite) only makes the test more cautious, never less
    with_t = np.mean([drifts[s].chi2 / drifts[s].dof for s in clean])
    assert with_t < 1 + tol, with_t


def test_drift_command_lists_flagged_robots_and_writes_the_page(drifted_fleet, tmp_path,
                                                                capsys):
    fleet, drifts, db = drifted_fleet
    page = tmp_path / "fleet.html"
    code, out, err = run(capsys, "fleet", "drift", "--db", db, "--report", page, "--json",
                         tmp_path / "d.json")
    flagged = sorted(s for s, d in drifts.items() if d.flagged)
    assert code == 1 and "robot(s) drifted" in err
    for s in flagged:
        assert s in out
    text = " ".join(out.split())
    for r in fleet.robots:
        if r["drift"]:
            assert f"{r['serial']}: {r['drift']['parameter']} " in text
    html = page.read_text()
    assert html.count("<img") >= 1 + len(flagged) and "Flagged robots" in html
    import json

    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["flagged"] == len(flagged) and len(doc["robots"]) == 105
