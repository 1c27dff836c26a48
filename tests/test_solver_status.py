"""Why a stage stopped: the status enum, its message table, the pure stopping rules, and
the statuses a calibration carries."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.identify.solver import calibrate
from kincal.identify.status import MESSAGES, StageStatus, stage_message
from kincal.identify.stopping import (
    cost_change_below,
    no_further_decrease,
    step_below,
    step_within_standard_errors,
)
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot


def test_every_status_has_a_message_and_the_sign_says_converged():
    assert set(MESSAGES) == set(StageStatus)
    for status in StageStatus:
        assert status.converged == (status > 0)
    assert stage_message(StageStatus.MAX_ITER_REACHED, "all", max_iter=7) == \
        "stage 'all': max_iter=7 reached"
    assert stage_message(StageStatus.WITHIN_STANDARD_ERRORS, "s", tol_std=0.25) == \
        "stage 's': the remaining step is below tol_std = 0.25 standard errors"


def test_step_within_standard_errors():
    # s0^2 = min(2 cost / dof, 1): cost 2, dof 8 -> s0^2 = 0.5; tol_std 0.1 -> bound 0.005
    assert step_within_standard_errors(0.005, 2.0, 8, 0.1)
    assert not step_within_standard_errors(0.0051, 2.0, 8, 0.1)
    # a large cost never loosens the bound past the stated sigmas (s0^2 capped at 1)
    assert not step_within_standard_errors(0.02, 1e6, 8, 0.1)
    assert step_within_standard_errors(0.01, 1e6, 8, 0.1)
    assert not step_within_standard_errors(0.0, 1.0, 0, 0.1)     # no redundancy


def test_step_and_cost_rules():
    assert step_below(1e-9, 1e-9) and not step_below(1.1e-9, 1e-9)
    assert cost_change_below(1.0, 1.0 - 0.5e-8, 1e-8)
    assert not cost_change_below(1.0, 1.0 - 2e-8, 1e-8)
    assert not cost_change_below(1.0, 1.0 + 2e-8, 1e-8)           # a rise counts, absolute
    assert cost_change_below(1.0, 1.0 + 2e-8, 1e-8, absolute=False)
    assert cost_change_below(0.0, 0.0, 0.0)


def test_no_further_decrease():
    assert no_further_decrease(1e-31, 1.0, 1.0)
    assert not no_further_decrease(1e-29, 1.0, 1.0)
    assert no_further_decrease(1.0, 1.0, 2e30)


@pytest.mark.parametrize("method", ["lm", "gauss-newton"])
def test_calibration_carries_stage_statuses(method):
    rng = np.random.default_rng(5)
    robot = load_serial_robot("puma560")
    q = random_configurations(robot, 30, rng)
    blk = simulate_positions(perturb_robot(robot, rng), q, rng, 1e-5,
                             [1.5, 0.4, -0.2, 0.1, -0.15, 2.0], [0.03, -0.02, 0.06])
    res = calibrate(robot, blk, method=method, stages=["offsets", "all"])
    assert [label for label, _ in res.stage_status] == [label for label, _ in res.stages]
    assert all(isinstance(s, StageStatus) for _, s in res.stage_status)
    assert res.converged == all(s.converged for _, s in res.stage_status)
    for label, status in res.stage_status:
        assert stage_message(status, label, tol_std=0.0, max_iter=100).split(":")[0] in \
            res.message
    short = calibrate(robot, blk, method=method, max_iter=1)
    assert short.stage_status[-1][1] is StageStatus.MAX_ITER_REACHED
    assert not short.converged and "max_iter=1 reached" in short.message
