"""Each instrument alone calibrates the robot: exact data to 1e-9, noisy data within the
reported standard errors (Monte Carlo), and ``calibrate`` on real noisy simulations
reports the same uncertainty as the harness.

Every identifiable parameter (robot and instrument) is checked.  The true robot differs
from the nominal one in every identifiable robot parameter; non-identifiable ones are
left at their nominal (= true) value, as the solver holds them.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from test_instruments_support import NOMINAL, Scenario, cases, monte_carlo, scenario

from kincal.identify.solver import calibrate

CASES = cases()
SEEDS = 200            # RMS(error/std) over 200 draws has a sampling sd of ~0.05
RATIO_MAX = 1.2


@cache
def get(key: str) -> Scenario:
    sim, n, opts, noise = CASES[key]
    return scenario(sim, n, 11, noise, **opts)


@pytest.mark.parametrize("key", list(CASES))
def test_noise_free_data_recover_the_truth(key: str) -> None:
    sc = get(key)
    res = calibrate(NOMINAL, sc.blocks, free=sc.free)
    assert res.converged, res.message
    assert sorted(res.estimated) == sorted(sc.free)
    # every instrument parameter is identifiable on its own data
    block_names = [n for n in res.names if n not in NOMINAL.param_names]
    assert set(block_names) <= set(res.estimated)
    err = {n: abs(res.params[n] - sc.truth[n]) for n in res.names}
    worst = max(err, key=err.get)
    assert err[worst] < 1e-9, (worst, err[worst])
    # the start really was wrong: the robot moved by at least 0.1 mm / 0.01 deg somewhere
    moved = [abs(sc.truth[n] - NOMINAL.params()[n]) for n in NOMINAL.param_names]
    assert max(moved) > 1e-4


@pytest.mark.parametrize("key", list(CASES))
def test_monte_carlo_errors_match_reported_std(key: str) -> None:
    sc = get(key)
    mc = monte_carlo(sc.true, sc.blocks, sc.truth, sc.free, SEEDS)
    assert mc.last_step < 1e-3                      # every solution converged
    worst = int(np.argmax(mc.ratio))
    assert mc.ratio[worst] <= RATIO_MAX, (mc.names[worst], mc.ratio[worst])
    # not trivially small either: the reported std is not inflated
    assert np.mean(mc.ratio) > 0.85


@pytest.mark.parametrize("key", list(CASES))
def test_calibrate_on_noisy_simulation_matches_harness(key: str) -> None:
    """The real pipeline (simulator noise, closed-form start, LM) lands within a few
    reported std of the truth and reports the harness's uncertainty."""
    sim, n, opts, noise = CASES[key]
    sc = get(key)
    blocks, truth = sim(sc.true, np.random.default_rng(11), n, noise, **opts)
    res = calibrate(NOMINAL, blocks, free=sc.free)
    assert res.converged, res.message
    assert 0.7 < res.sigma0 < 1.3                   # the stated noise is the real noise
    est = [res.names.index(p) for p in res.estimated]
    z = (res.theta[est] - np.array([sc.truth[p] for p in res.estimated])) / res.std[est]
    assert np.max(np.abs(z)) < 4.5
    mc = monte_carlo(sc.true, sc.blocks, sc.truth, sc.free, 20)
    want = dict(zip(mc.names, mc.std, strict=True))
    got = np.array([res.std[res.names.index(p)] / want[p] for p in res.estimated])
    assert np.all((got > 0.75) & (got < 1.33))       # sigma0 differs per draw; J the same


def test_unknown_planes_with_automatic_selection_hold_the_scale() -> None:
    sim, n, opts, noise = CASES["plane"]
    sc = get("plane")
    blocks, _ = sim(sc.true, np.random.default_rng(11), n, noise, **opts)
    res = calibrate(NOMINAL, blocks)                # automatic parameter selection
    assert sorted(res.estimated) == sorted(sc.free)
    assert res.converged and 0.7 < res.sigma0 < 1.3
