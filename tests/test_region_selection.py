"""``--select auto`` judges models where they were not fitted: folds by file, placement or
workspace region (random folds only when none applies, and said so).  On a simulated
robot whose joint 2 carries an unmodelled smooth error, random folds of one recording
choose the over-parameterised model (+ compliance, which bends to the error where the
data are), the region split keeps the geometric one, and the geometric one is indeed the
better model on a workspace region neither saw."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.identify.region_folds import group_folds, workspace_regions
from kincal.identify.selection import Candidate, select_model
from kincal.identify.solver import calibrate
from kincal.identify.validation import validate
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.joints.terms import with_joint_model
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot
from kincal.robots.gravity import PointMass

INSTRUMENT = [1.0, 0.2, 0.3, 0.1, 0.0, 0.0]
MARKER = [0.0, 0.0, 0.05]
MASSES = [PointMass(1, 10.0, (0.3, 0.0, 0.0)), PointMass(2, 5.0, (0.0, 0.0, 0.3))]


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def _block(robot, true, q, rng, name="tracker"):
    """Positions of ``true`` whose joint 2 sits ``5 mrad sin(2.5 q2)`` off its reading
    (a smooth error no candidate models), stated sigma 0.5 mm."""
    qt = q.copy()
    qt[:, 1] += 5e-3 * np.sin(2.5 * q[:, 1])
    b = simulate_positions(true, qt, rng, 3e-5, INSTRUMENT, MARKER, name=name, sigma=5e-4)
    return b.with_q(q)


def test_regions_are_the_clusters_of_the_joint_space():
    rng = np.random.default_rng(0)
    q = np.concatenate([rng.normal(-1.0, 0.05, (20, 3)), rng.normal(1.0, 0.05, (30, 3))])
    lab = workspace_regions(q, 2, seed=4)
    assert lab[0] == 0 and set(lab[:20]) == {0} and set(lab[20:]) == {1}
    np.testing.assert_array_equal(lab, workspace_regions(q, 2, seed=9))   # start-free


def test_the_split_follows_the_data(puma):
    rng = np.random.default_rng(1)
    q = random_configurations(puma, 40, rng)
    one = simulate_positions(puma, q, rng, 1e-5, INSTRUMENT, MARKER)
    plan = group_folds([one], 5)
    assert plan.kind == "regions" and plan.folds == 5 and "workspace region" in plan.text
    held = sorted(i for p in plan.parts[0] for i in p)
    assert held == list(range(40))                           # every row held out once
    # four files: one file out per fold, each held-out file's frame registered on it
    a, b, c = (simulate_positions(puma, q[i::3], rng, 1e-5, INSTRUMENT, MARKER, name=f"t{i}")
               for i in range(3))
    lone = simulate_positions(puma, q[:9], rng, 1e-5, [0.3, -1.0, 0.2, 1.0, 0.0, 0.1],
                              MARKER, name="other")
    plan = group_folds([a, b, c, lone], 10)
    assert plan.kind == "files" and plan.folds == 4
    assert [len(p[k]) for k, p in enumerate(plan.parts)] == [a.N, b.N, c.N, lone.N]
    tol = {n: 1e-3 for n in puma.param_names}
    sel = select_model(puma, [a, b, c, lone], tol, [Candidate((), 1.0)], folds=10)
    assert sel.split.startswith("split by file: 4 folds") and sel.chosen == 0
    assert sel.rms[0] < 1e-4                          # exact robot, 10 um noise: no fold failed
    # too few rows for regions: random folds, and the line says why
    plan = group_folds([one.subset(np.arange(12))], 10)
    assert plan.kind == "random" and "too few rows" in plan.text
    assert group_folds([one], 5, split="random").kind == "random"


def test_region_split_refuses_the_model_that_extrapolates_badly(puma):
    rng = np.random.default_rng(5)
    true = perturb_robot(puma, rng)
    q = random_configurations(puma, 60, rng)
    q[:, 1] = rng.uniform(-0.7, 0.9, 60)                      # one part of joint 2's range
    far = random_configurations(puma, 60, rng)
    far[:, 1] = rng.uniform(0.9, 2.5, 60)                     # a part the data never saw
    train, test = _block(puma, true, q, rng), _block(puma, true, far, rng)
    cands = [Candidate((), None), Candidate(("compliance",), None)]
    tol = {n: (2e-3 if u == "m" else 0.02) for n, u in zip(puma.param_names, puma.param_units,
                                                          strict=True)}
    random = select_model(puma, [train], tol, cands, masses=MASSES, folds=5, split="random")
    region = select_model(puma, [train], tol, cands, masses=MASSES, folds=5)
    assert random.choice == cands[1] and region.choice == cands[0]
    assert region.split.startswith("split by workspace region")
    far_rms = []
    for c in cands:
        fit = calibrate(puma, with_joint_model([train], puma, c.terms, MASSES))
        held = with_joint_model([test], puma, c.terms, MASSES)
        far_rms.append(validate(fit.robot, held, extras=fit).overall["rms_position_m"])
    assert far_rms[1] > 1.05 * far_rms[0]                     # compliance: > 5 % worse
