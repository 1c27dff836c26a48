"""``--select auto``: the model chosen by cross-validation on the training data alone.

Truth: a simulated PUMA 560 whose joints have play (the hysteresis of
test_cli_joint_model) and the same robot without play.  Cross-validation on the
training rows must choose the hysteresis model for the first and the geometric one
for the second; the fold tasks are pure and run the same through any mapper.
"""

from __future__ import annotations

import concurrent.futures
import json
import pickle

import numpy as np
import pytest
from cli_helpers import run, write_tracker
from test_cli_joint_model import H_TRUE, INSTRUMENT, MARKER, NOISE
from test_compliance import perturbed_puma

from kincal.errors import KincalError
from kincal.identify.selection import (
    Candidate,
    FoldResult,
    candidates,
    choose,
    cross_validate,
    fold_specs,
    fold_units,
    run_fold,
    select_model,
)
from kincal.identify.tolerances import resolve_tolerances
from kincal.measure.base import stack
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.joints.hysteresis import approach_directions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot

CANDS = candidates(False, scales=(1.0, None))


@pytest.fixture(scope="module")
def sim():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(31)
    true = perturbed_puma(nominal, rng)
    q = random_configurations(nominal, 50, rng)
    seen = simulate_positions(true, q + H_TRUE * approach_directions(q), rng, NOISE,
                              INSTRUMENT, MARKER)
    play = PositionMeasurement(q, seen.positions, NOISE, "tracker")   # encoder readings
    plain = simulate_positions(true, q, rng, NOISE, INSTRUMENT, MARKER)
    prob, _ = stack(nominal, [plain])
    tol = resolve_tolerances(prob.names, prob.units, prob.roles).sigma
    return nominal, play, plain, tol


def test_cross_validation_chooses_the_play_only_when_there_is_one(sim):
    nominal, play, plain, tol = sim
    with_play = select_model(nominal, [play], tol, CANDS, folds=5)
    without = select_model(nominal, [plain], tol, CANDS, folds=5)
    assert with_play.choice.terms == ("hysteresis",)
    assert without.choice.terms == ()
    assert with_play.kind == "position_m" and with_play.folds == 5
    # the geometric model misses the play by far more than the noise
    geo = with_play.rms[CANDS.index(Candidate((), 1.0))]
    best = with_play.rms[with_play.chosen]
    assert best < 1.5 * np.sqrt(3) * NOISE < geo / 3, (best, geo)
    assert all(with_play.trusted) and all(np.isfinite(with_play.rms))
    d = json.loads(json.dumps(with_play.to_dict()))
    assert d["chosen"] == with_play.choice.label and len(d["candidates"]) == len(CANDS)
    assert "lowest K-fold cross-validated RMS" in d["rule"]


def test_fold_tasks_are_pure_and_any_mapper_runs_them(sim):
    """The specs pickle; a process pool's map and futures (a Dask client's map returns
    futures) give exactly what the builtin map gives."""
    nominal, play, _, tol = sim
    parts, notes = fold_units([play], 3)
    assert not notes and sorted(np.concatenate(parts[0])) == list(range(play.N))
    specs = fold_specs(nominal, [[play]], [Candidate()], parts, tol, {})
    assert [s.fold for s in specs] == [-1, 0, 1, 2]
    again = pickle.loads(pickle.dumps(specs))
    local = list(map(run_fold, specs))
    with concurrent.futures.ProcessPoolExecutor(2) as pool:
        remote = list(pool.map(run_fold, again))
    for a, b in zip(local, remote, strict=True):
        assert isinstance(b, FoldResult) and (a.candidate, a.fold) == (b.candidate, b.fold)
        for k in a.errors:
            np.testing.assert_allclose(a.errors[k], b.errors[k], rtol=1e-9, atol=1e-15)
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        futures = select_model(nominal, [play], tol, [Candidate()], folds=3,
                               mapper=lambda f, xs: [pool.submit(f, x) for x in xs])
    plain = select_model(nominal, [play], tol, [Candidate()], folds=3)
    assert futures.rms == plain.rms


def test_one_fold_mechanism_for_cross_validate_and_select(sim):
    """cross_validate (one block, its own folds) runs the same fold tasks as --select auto:
    the geometric candidate's pooled held-out RMS of select_model on the same parts is
    cross_validate's, each row is held out once, and the folds' fits come back."""
    nominal, play, _, tol = sim
    cv = cross_validate(nominal, play, folds=3, rng=np.random.default_rng(0),
                        prior=None)
    assert cv["split"] == "rows" and len(cv["results"]) == len(cv["folds"]) == 3
    assert sorted(u for part in cv["held_out"] for u in part) == list(range(play.N))
    assert all(r.problem.blocks[0].N == play.N - len(h)
               for r, h in zip(cv["results"], cv["held_out"], strict=True))
    sel = select_model(nominal, [play], tol, [Candidate((), None)], folds=3, seed=0,
                       split="random")
    assert cv["rms_position_m"] == pytest.approx(sel.rms[0], rel=1e-9)
    assert sum(f["n"] for f in cv["folds"]) == play.N
    with pytest.raises(KincalError, match="folds must be between 2 and its number of rows"):
        cross_validate(nominal, play, folds=play.N + 1)


def test_the_rule_skips_untrusted_candidates():
    assert choose([3.0, 1.0, 2.0], [True, False, True]) == 2
    assert choose([float("nan"), 2.0], [True, True]) == 1
    assert choose([1.0], [False]) is None


def test_nothing_to_split_chooses_nothing_and_says_why(sim):
    nominal, play, _, tol = sim
    few = play.subset(np.arange(3))
    sel = select_model(nominal, [few], tol, CANDS, folds=5)
    assert sel.chosen is None and "nothing to cross-validate" in " ".join(sel.notes)


def test_select_auto_from_the_command_line(capsys, tmp_path, sim):
    nominal, play, _, _ = sim
    path = tmp_path / "play.csv"
    write_tracker(path, nominal, play.q, play.positions)
    j = tmp_path / "res.json"
    code, out, err = run(capsys, "calibrate", "puma560", "--data", path, "--select", "auto",
                         "--folds", "4", "--prior", "scale=1", "--json", j)
    assert code == 0, err
    text = " ".join(out.split())
    assert "Model selection: 4-fold cross-validation on the training files" in text
    assert "<- chosen" in text and "joint model: hysteresis" in text
    doc = json.loads(j.read_text())
    assert doc["selection"]["chosen"] == "geometric + hysteresis, prior x1"
    assert [c["prior_scale"] for c in doc["selection"]["candidates"]] == [1.0, 1.0]
    assert doc["metrics"]["cross_validation"]["model"] == doc["selection"]["chosen"]
    assert any(p["name"].startswith("tracker.h[") and p["estimated"]
               for p in doc["parameters"])
    code, _, err = run(capsys, "calibrate", "puma560", "--data", path, "--select", "maybe")
    assert code == 2 and "--select" in err


def test_select_table_follows_si(capsys, tmp_path, sim):
    """--si: the selection table's cross-validated RMS in m, like the other tables."""
    nominal, play, _, _ = sim
    path = tmp_path / "play.csv"
    write_tracker(path, nominal, play.q, play.positions)
    code, out, err = run(capsys, "calibrate", "puma560", "--data", path, "--select", "auto",
                         "--folds", "4", "--prior", "scale=1", "--joint-model", "hysteresis",
                         "--si")
    assert code == 0, err
    table = out[out.index("Model selection"):]
    assert "[m]" in table.split("<- chosen")[0] and "[mm]" not in out


def test_split_option_chooses_what_a_fold_holds_out(tmp_path, capsys):
    """Two files of one tracker set-up: ``--split auto`` (default) holds out one file per
    fold, ``--split random`` random rows; anything else is one line, exit 2."""
    for seed, name in ((1, "a.csv"), (2, "b.csv")):
        code, _, err = run(capsys, "simulate", "puma560", "-o", tmp_path / name, "-n", "30",
                           "--seed", str(seed))
        assert code == 0, err
    base = ["calibrate", "puma560", "--data", tmp_path / "a.csv", "--data", tmp_path / "b.csv",
            "--select", "auto", "--folds", "2", "--prior", "none", "--json", "-"]
    code, out, err = run(capsys, *base)
    assert code == 0, err
    assert json.loads(out)["selection"]["split"].startswith("split by file: 2 folds")
    code, out, err = run(capsys, *base, "--split", "random")
    assert code == 0, err
    assert json.loads(out)["selection"]["split"].startswith("random 2-fold split")
    code, out, err = run(capsys, *base, "--split", "regions")
    assert code == 2 and err.strip().splitlines() == [
        "error: option --split: 'regions' is not auto or random"], err
