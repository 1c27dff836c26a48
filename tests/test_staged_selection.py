"""The staged-selection procedure: two stages, data selection by the condition number,
one dependent parameter per identification - compared with the one-stage solver.

Truth: a simulated PUMA 560 seated by IK in cross placements with 0.001 deg encoder
noise; held-out placements of the same robot judge the accuracy.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from kincal.identify.solver import CalibrationResult, calibrate
from kincal.identify.staged_selection import (
    calibrate_staged_selection,
    compare_results,
    dependent_groups,
    select_placements,
    staged_selection_runs,
)
from kincal.measure.artifacts import ArtifactGeometry, Probe
from kincal.measure.artifacts.simulate import simulate_artifact
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot

NOISE = np.radians(0.001)


@pytest.fixture(scope="module")
def data():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    true = perturb_robot(nominal, rng)
    cross = ArtifactGeometry.cross_bar(0.3)
    probe = Probe.length(0.1)
    train, _ = simulate_artifact(true, cross, 20, rng, probe, joint_std=NOISE,
                                 model_robot=nominal, name="cross")
    held, _ = simulate_artifact(true, cross, 40, rng, probe, joint_std=NOISE,
                                model_robot=nominal, name="cross", label_prefix="v")
    return nominal, train, held


def _rms_mm(block, robot) -> float:
    return float(np.sqrt(np.mean(block.lengths(robot).error ** 2)) * 1e3)


def test_two_stage_agrees_with_one_stage_within_uncertainty(data):
    nominal, train, held = data
    res = calibrate_staged_selection(nominal, [train], compare=True)
    assert isinstance(res, CalibrationResult) and res.method == "staged-selection" and res.converged
    info = res.procedure_record
    stage1, stage2 = info.estimated[0][2], info.estimated[1][2]
    units = dict(zip(res.names, res.problem.units, strict=True))
    assert stage1 and all(units[n] == "rad" for n in stage1)       # dtheta, dalpha
    assert stage2 and all(units[n] == "m" for n in stage2)         # dd, da
    assert set(res.estimated) == set(stage1) | set(stage2)
    one = calibrate(nominal, [train], free=res.estimated)
    assert one.estimated == res.estimated
    c = compare_results(res, one)
    literal = calibrate_staged_selection(nominal, [train], cycles=1)
    c1 = compare_results(literal, one)
    lm = calibrate(nominal, [train])
    print(f"\ntwo-stage cycled ({info.cycles} cycles) vs one-stage LM: largest difference "
          f"{c['max_sigmas']:.3f} std ({c['worst']}); the literal single pass: "
          f"{c1['max_sigmas']:.2f} std ({c1['worst']}), sigma0 {literal.sigma0:.2f} vs "
          f"{one.sigma0:.2f}")
    print(f"held-out bar-length RMS: nominal {_rms_mm(held, nominal):.3f} mm, one-stage "
          f"{_rms_mm(held, lm.robot):.4f} mm, two-stage cycled {_rms_mm(held, res.robot):.4f}"
          f" mm, single pass {_rms_mm(held, literal.robot):.4f} mm")
    assert c["max_sigmas"] <= 1.0
    assert info.comparison["same_parameters"]["max_sigmas"] == pytest.approx(c["max_sigmas"])
    assert info.comparison["automatic"]["estimated"] == len(lm.estimated)
    np.testing.assert_allclose(res.std, one.std, rtol=0.01, atol=1e-12)   # same covariance
    # the single pass stops short: its first stage absorbed the length errors
    assert literal.sigma0 > 2 * one.sigma0
    assert _rms_mm(held, res.robot) <= 1.1 * _rms_mm(held, lm.robot)
    json.dumps(res.to_dict())
    json.dumps(info.to_dict())
    assert "staged-selection procedure" in res.message and res.summary()


def test_condition_number_selection_keeps_fewer_placements(data):
    nominal, train, held = data
    full = calibrate_staged_selection(nominal, [train])
    sel = calibrate_staged_selection(nominal, [train], condition_growth=1.0)
    info = sel.procedure_record
    total = len(train.placements)
    assert len(info.kept) + len(info.discarded) == total and 0 < len(info.discarded)
    assert [c.kept for c in info.selection].count(True) == len(info.kept)
    assert all(c.condition > c.previous for c in info.selection if not c.kept)
    a, b = _rms_mm(held, full.robot), _rms_mm(held, sel.robot)
    print(f"\ncondition-number selection (growth 1.0): {len(info.kept)} of {total} "
          f"placements; held-out bar-length RMS {b:.4f} mm vs {a:.4f} mm with all")
    assert b <= 1.25 * a
    blocks, steps = select_placements(nominal, [train], 1e6)     # nothing grows that much
    assert blocks[0] is train and all(s.kept for s in steps)


def test_one_dependent_parameter_per_identification(data):
    """The staged-selection rule: of dependent columns identify one, another in the next run.
    The runs give alternatives: the data fix only their combination."""
    nominal, train, _ = data
    results, values = staged_selection_runs(nominal, [train], runs=2)
    groups = dependent_groups(results[0].identifiability)
    pair = next(g for g in groups if set(g) == {"d[2]", "d[3]"})   # parallel axes 2, 3
    assert pair[0] in results[0].estimated and pair[1] not in results[0].estimated
    assert pair[1] in results[1].estimated and pair[0] not in results[1].estimated
    d2 = values["d[2]"][0] - nominal.params()["d[2]"]
    d3 = values["d[3]"][1] - nominal.params()["d[3]"]
    print(f"\nd[2] run 0: {d2 * 1e3:+.4f} mm; d[3] run 1: {d3 * 1e3:+.4f} mm (one sum)")
    std = results[0].std[results[0].names.index("d[2]")]
    assert abs(d2 - d3) < 0.05 * std
    assert abs(results[0].cost - results[1].cost) < 0.05       # chi^2 units: the same fit
