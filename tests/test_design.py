"""Experiment design: observability indices O1-O5, pose selection, the design Jacobian.

Indices are checked against their definitions on matrices with known singular
values; the selection algorithms against brute force (every single swap, every
subset) on small synthetic problems; and the whole chain on the PUMA 560 with a
simulated laser tracker by a Monte Carlo of calibrations, paired over the same true
robots (one-sided paired t-test at the 1 % level per criterion).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from scipy import stats

from kincal.errors import KincalError
from kincal.identify.design import (
    instrument_candidates,
    random_candidates,
    random_design,
    read_configurations,
    select_poses,
    within_limits,
    write_poses,
)
from kincal.identify.identifiability import analyze
from kincal.identify.observability import (
    CRITERIA,
    DEFAULT_INSTRUMENT,
    DEFAULT_MARKER,
    DesignProblem,
    criterion_score,
    design_problem,
    indices_from_eigenvalues,
    observability_indices,
)
from kincal.identify.prediction import predict_accuracy
from kincal.identify.solver import calibrate
from kincal.measure.base import stack
from kincal.measure.files import read_table
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def synthetic(N: int, r: int, L: int, seed: int) -> DesignProblem:
    """A design problem with random rows (no robot): enough for the selection algorithms."""
    rng = np.random.default_rng(seed)
    J = rng.standard_normal((N, r, L)) * rng.uniform(0.2, 2.0, L)
    q = rng.uniform(-1.0, 1.0, (N, 3))
    return bare_problem(q, J)


def bare_problem(q: np.ndarray, J: np.ndarray) -> DesignProblem:
    """Candidates ``q`` with rows ``J`` (N, r, L), identity scaling, no robot behind them."""
    nothing: Any = None
    L = J.shape[2]
    return DesignProblem(nothing, q, J, np.eye(L), [f"p{i}" for i in range(L)], ["m"] * L,
                         "unit", nothing, nothing, nothing, 1.0)


def score_of(dp: DesignProblem, sel, criterion: str) -> float:
    return float(criterion_score(np.linalg.eigvalsh(dp.information(sel)), criterion))


# --------------------------------------------------------------------------- indices
def test_indices_of_a_known_matrix_equal_their_definitions() -> None:
    # A = U diag(4, 2, 1) V^T with exact orthogonal U (6x3 block) and V: s = 4, 2, 1
    c, s = 0.6, 0.8
    V = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    U = np.zeros((6, 3))
    U[0, 0], U[3, 0] = 1 / math.sqrt(2), 1 / math.sqrt(2)
    U[1, 1], U[4, 1] = 1 / math.sqrt(2), -1 / math.sqrt(2)
    U[2, 2] = 1.0
    A = U @ np.diag([4.0, 2.0, 1.0]) @ V.T
    m = 2                                                    # two poses of three rows
    ind = observability_indices(np.linalg.svd(A, compute_uv=False), m)
    assert ind.O1 == pytest.approx(8 ** (1 / 3) / math.sqrt(2), rel=1e-12)   # = sqrt(2)
    assert ind.O2 == pytest.approx(1 / 4, rel=1e-12)
    assert ind.O3 == pytest.approx(1.0, rel=1e-12)
    assert ind.O4 == pytest.approx(1 / 4, rel=1e-12)
    assert ind.O5 == pytest.approx(1 / (1 / 4 + 1 / 2 + 1), rel=1e-12)      # = 4/7
    assert ind.kappa == pytest.approx(4.0, rel=1e-12)
    # the same through a design problem: two candidates of three rows, identity scaling
    dp = bare_problem(np.zeros((2, 1)), A.reshape(2, 3, 3))
    assert np.allclose(dp.indices([0, 1]).singular_values, [4, 2, 1], rtol=1e-12)
    assert dp.indices([0, 1]).as_dict() == pytest.approx(ind.as_dict(), rel=1e-12)


def test_indices_of_random_matrices_equal_their_definitions() -> None:
    rng = np.random.default_rng(1)
    for m, L in ((5, 4), (12, 9)):
        A = rng.standard_normal((3 * m, L)) @ np.diag(rng.uniform(0.1, 10, L))
        s = np.linalg.svd(A, compute_uv=False)
        ind = indices_from_eigenvalues(np.linalg.eigvalsh(A.T @ A), m)
        assert ind.O1 == pytest.approx(np.prod(s) ** (1 / L) / np.sqrt(m), rel=1e-9)
        assert ind.O2 == pytest.approx(s.min() / s.max(), rel=1e-9)
        assert ind.O3 == pytest.approx(s.min(), rel=1e-9)
        assert ind.O4 == pytest.approx(s.min() ** 2 / s.max(), rel=1e-9)
        assert ind.O5 == pytest.approx(1 / np.sum(1 / s), rel=1e-9)
        assert ind.kappa == pytest.approx(s.max() / s.min(), rel=1e-9)
    sing = observability_indices([3.0, 0.0], 2)
    assert sing.O3 == 0.0 and sing.O1 == 0.0 and math.isinf(sing.kappa)


def test_criterion_scores_rank_designs_like_the_indices() -> None:
    dp = synthetic(60, 3, 6, seed=2)
    rng = np.random.default_rng(3)
    designs = [rng.choice(60, 5, replace=False) for _ in range(30)]
    for crit in CRITERIA:
        score = [score_of(dp, d, crit) for d in designs]
        value = [dp.indices(d)[crit] for d in designs]
        if crit == "kappa":
            value = [-v for v in value]
        assert np.array_equal(np.argsort(score), np.argsort(value)), crit


# --------------------------------------------------------------------------- algorithms
def test_greedy_steps_are_the_best_addition() -> None:
    dp = synthetic(30, 2, 5, seed=4)          # 30 <= shortlist: every candidate is exact
    A = dp.A
    for crit in ("O1", "kappa", "O3"):
        for m in (4, 6, 9):                      # rank is reached after 3 poses
            d = select_poses(dp, m, crit, exchange=False)
            before, last = list(d.selected[:-1]), int(d.selected[-1])
            M = dp.information(before)
            rest = [j for j in range(30) if j not in before]
            lam = np.linalg.eigvalsh(np.stack([M + A[j].T @ A[j] for j in rest]))
            best = rest[int(np.argmax(criterion_score(lam, crit)))]
            assert last == best, (crit, m)


def test_exchange_ends_in_a_local_optimum_and_detmax_improves_greedy() -> None:
    dp = synthetic(28, 2, 5, seed=5)
    for crit in ("O1", "O2", "O3", "O4", "O5"):
        d = select_poses(dp, 6, crit)
        g = select_poses(dp, 6, crit, exchange=False)
        cur = score_of(dp, d.selected, crit)
        assert cur >= score_of(dp, g.selected, crit) - 1e-12
        for pos, i in itertools.product(range(6), range(28)):
            if i in d.selected:
                continue
            trial = d.selected.copy()
            trial[pos] = i
            assert score_of(dp, trial, crit) <= cur + 1e-7, (crit, pos, i)


SMALL = 12


def test_selection_reaches_the_exhaustive_optimum_on_small_problems() -> None:
    hits = dict.fromkeys(CRITERIA, 0)
    subsets = np.array(list(itertools.combinations(range(12), 4)))
    for seed in range(SMALL):
        dp = synthetic(12, 2, 4, seed)
        A = dp.A[subsets]
        lam = np.linalg.eigvalsh(np.einsum("snri,snrj->sij", A, A))
        for crit in CRITERIA:
            best = criterion_score(lam, crit).max()
            got = score_of(dp, select_poses(dp, 4, crit).selected, crit)
            assert got <= best + 1e-9
            hits[crit] += bool(got >= best - 1e-9)
    print(f"exhaustive optimum reached (of {SMALL}):", hits)
    assert min(hits[c] for c in ("O1", "O2", "O3", "O4", "O5")) >= 8   # 2/3; 9-12 seen
    assert hits["kappa"] >= 1            # pure greedy (staged selection's rule): no guarantee


def test_min_distance_poses_are_distinct_and_errors(puma) -> None:
    dp = synthetic(200, 3, 6, seed=6)
    d = select_poses(dp, 12, "O1", min_distance=0.5)
    Q = dp.q[d.selected]
    dist = np.linalg.norm(Q[:, None] - Q[None], axis=-1)[np.triu_indices(12, 1)]
    assert dist.min() >= 0.5 and len(set(d.selected.tolist())) == 12
    r = random_design(dp, 12, np.random.default_rng(0), min_distance=0.5)
    Q = dp.q[r.selected]
    assert np.linalg.norm(Q[:, None] - Q[None], axis=-1)[np.triu_indices(12, 1)].min() >= 0.5
    with pytest.raises(KincalError, match="minimum distance"):
        select_poses(dp, 40, "O3", min_distance=1.5)
    with pytest.raises(KincalError, match="at least 2 poses"):
        select_poses(dp, 1, "O1")
    with pytest.raises(KincalError, match="unknown criterion"):
        select_poses(dp, 5, "O7")


# --------------------------------------------------------------------------- the problem
def test_design_jacobian_is_the_stacked_position_measurement(puma) -> None:
    q = random_candidates(puma, 60, np.random.default_rng(7))
    assert within_limits(puma, q).all()
    dp = design_problem(puma, q, "position", 2e-5)
    extra = np.concatenate([np.asarray(DEFAULT_INSTRUMENT, dtype=float), DEFAULT_MARKER])
    probe = PositionMeasurement(q, np.zeros((60, 3)), 2e-5)
    block = PositionMeasurement(q, probe.predict(puma, extra)[:, 0], 2e-5)
    prob, theta = stack(puma, [block])
    assert np.allclose(theta[prob.num_robot:], extra, atol=1e-9)   # closed form is exact
    r, J = prob.residuals_and_jacobian(np.concatenate([puma.param_values, extra]))
    assert np.abs(r).max() < 1e-6                                    # nominal observations
    rep = analyze(J, prob.names, roles=prob.roles)
    assert sorted(dp.names) == sorted(rep.identifiable)
    assert {"tracker.x", "tracker.rz", "tracker.marker.z"} <= set(dp.names)
    cols = [prob.names.index(n) for n in dp.names]
    assert np.allclose(dp.J, J[:, cols].reshape(60, 3, -1), rtol=1e-10, atol=1e-6)
    assert np.allclose(dp.base_rows(q[:5]), dp.J[:5], rtol=1e-10, atol=1e-6)
    # the workspace scaling whitens the mean information of one candidate
    H = np.einsum("nri,nrj->ij", dp.A, dp.A) / 60
    assert np.allclose(H, np.eye(dp.num_params), atol=1e-8)
    pose = design_problem(puma, q, "pose", 2e-5, orientation_noise=1e-5)
    assert pose.J.shape[1] == 6 and pose.num_params > dp.num_params
    inst = instrument_candidates(puma, "position", 40, np.random.default_rng(8))
    assert inst.num_candidates == 40 and within_limits(puma, inst.q).all()


def test_poses_csv_round_trip(puma, tmp_path) -> None:
    q = random_candidates(puma, 8, np.random.default_rng(9))
    path = tmp_path / "poses.csv"
    write_poses(path, puma, q, comments=["selected by a test"])
    header = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0]
    assert header == "q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad"
    assert np.allclose(read_table(path, puma, ()).q, q, rtol=1e-14, atol=1e-15)
    write_poses(path, puma, q, angle_unit="deg")
    text = path.read_text()
    assert "q1_deg" in text
    bad = text.rstrip("\n") + "\n" + ",".join(["170"] + ["0"] * 5) + "\n"   # q1 limit 160 deg
    path.write_text(bad)
    back, dropped = read_configurations(path, puma)
    assert dropped == 1 and np.allclose(back, q, rtol=1e-12, atol=1e-13)


# --------------------------------------------------------------------------- Monte Carlo
NOISE = 2e-5                      # laser tracker, 20 um per coordinate
TRIALS = 40
POSES = 25
#: true instrument placement (x, y, z, roll, pitch, yaw) and marker: not the design's
TRUE_INSTRUMENT = (1.6, -0.9, 0.3, 2.2, -0.05, 0.1)
TRUE_MARKER = np.asarray(DEFAULT_MARKER) + [5e-4, -3e-4, 8e-4]


def _validation_rms(nominal, true, q, q_val, rng) -> float:
    """Calibrate on ``q`` (noisy tracker data), RMS error on noise-free held-out ``q_val``."""
    block = simulate_positions(true, q, rng, NOISE, instrument=TRUE_INSTRUMENT,
                               markers=TRUE_MARKER)
    # LM stops after ~4 iterations, when the scaled step is below 1e-8 (0.01 um)
    res = calibrate(nominal, [block], max_iter=8, tol_step=1e-8, trust_sigma=True)
    assert res.converged
    truth = simulate_positions(true, q_val, rng, 0.0, instrument=TRUE_INSTRUMENT,
                               markers=TRUE_MARKER).positions
    held = PositionMeasurement(q_val, truth, NOISE)        # frames from training, no refit
    e = held.errors(res.robot, res.theta[res.problem.slices[0]])["position_m"]
    return float(np.sqrt(np.mean(e ** 2)))


def test_selected_poses_beat_random_poses_in_a_monte_carlo(puma) -> None:
    """25 of 2000 candidates by each criterion vs 25 random candidates, same true robots.

    Paired one-sided t-test on the per-trial validation RMS (random minus design) over
    40 true robots, each criterion at the 1 % level (the Wilcoxon signed-rank p is
    printed as a distribution-free check).
    """
    q = random_candidates(puma, 2000, np.random.default_rng(10))
    dp = design_problem(puma, q, "position", NOISE)
    designs = {c: select_poses(dp, POSES, c) for c in CRITERIA}
    q_val = random_candidates(puma, 100, np.random.default_rng(11))
    err = {c: np.empty(TRIALS) for c in [*CRITERIA, "random"]}
    for t in range(TRIALS):
        true = perturb_robot(puma, np.random.default_rng([12, t]))
        for k, c in enumerate(CRITERIA):
            err[c][t] = _validation_rms(puma, true, designs[c].q, q_val,
                                        np.random.default_rng([13, t, k]))
        rnd = random_design(dp, POSES, np.random.default_rng([14, t]))
        err["random"][t] = _validation_rms(puma, true, rnd.q, q_val,
                                           np.random.default_rng([15, t]))
    rand = err["random"]
    pred = {c: predict_accuracy(dp, designs[c], q_val).rms for c in CRITERIA}
    lines = [f"{'poses':8}{'mean RMS [um]':>14}{'vs random':>10}{'paired t p':>11}"
             f"{'Wilcoxon p':>11}{'MC/pred.':>9}{'O1':>7}{'O3':>7}{'kappa':>7}",
             f"{'random':8}{rand.mean() * 1e6:14.3f}"]
    pvals = {}
    for c in CRITERIA:
        e = err[c]
        pvals[c] = stats.ttest_rel(rand, e, alternative="greater").pvalue
        w = stats.wilcoxon(rand - e, alternative="greater").pvalue
        ind = designs[c].indices
        ratio = np.sqrt(np.mean(e ** 2)) / pred[c]
        lines.append(f"{c:8}{e.mean() * 1e6:14.3f}{e.mean() / rand.mean() - 1:+10.1%}"
                     f"{pvals[c]:11.1e}{w:11.1e}{ratio:9.3f}{ind.O1:7.3f}{ind.O3:7.3f}"
                     f"{ind.kappa:7.3f}")
    print("\n" + "\n".join(lines))
    for c in CRITERIA:
        assert err[c].mean() < rand.mean(), c
        assert pvals[c] < 0.01, (c, pvals[c])


def test_the_cli_baseline_count_is_the_library_one() -> None:
    from kincal.cli import plan as cli_plan
    from kincal.identify.plan import RANDOM_DESIGNS

    assert cli_plan.RANDOM_DESIGNS == RANDOM_DESIGNS
