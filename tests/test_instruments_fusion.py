"""Several instruments in one calibration: a range meter (4 stations) and two theodolites
watch the same physical marker (``marker="tool"``: the robot's tool origin).

Each block is whitened by its own noise (10 um ranges, 1 arcsec angles); the stations of
both are estimated with the robot; identifiability is analysed over the stacked set.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from test_instruments_support import NOMINAL, monte_carlo

from kincal.identify.identifiability import IdentifiabilityReport, analyze
from kincal.identify.solver import calibrate
from kincal.measure import instruments as S
from kincal.measure.base import stack
from kincal.measure.simulate import perturb_robot
from kincal.robots.chain import Robot

ARCSEC = np.pi / 180 / 3600
NOISE_RANGE, NOISE_ANGLE = 1e-5, ARCSEC
# the nominal marker offset lives in the robot's tool frame
ROBOT = NOMINAL.with_params({"tool.x": 0.03, "tool.y": -0.02, "tool.z": 0.09})
SEEDS = 200


def simulate(robot: Robot, marker: str = "tool") -> list:
    a, ta = S.simulate_range(robot, np.random.default_rng(21), 40, 0.0, marker=marker)
    b, tb = S.simulate_bearing(robot, np.random.default_rng(22), 40, 0.0, marker=marker)
    a[0].sigma = np.full_like(a[0].sigma, NOISE_RANGE)
    b[0].sigma = np.full_like(b[0].sigma, NOISE_ANGLE)
    return [a[0], b[0]], {**ta, **tb}


def report(robot: Robot, blocks: list) -> IdentifiabilityReport:
    prob, theta = stack(robot, blocks)
    _, J = prob.residuals_and_jacobian(theta)
    return analyze(J, prob.names, roles=prob.roles)


@cache
def setup() -> dict:
    nominal_blocks, _ = simulate(ROBOT)
    rep = {"range": report(ROBOT, nominal_blocks[:1]),
           "bearing": report(ROBOT, nominal_blocks[1:]),
           "fused": report(ROBOT, nominal_blocks)}
    robot_free = [p for p in rep["fused"].identifiable if p in ROBOT.param_names]
    true = perturb_robot(ROBOT, np.random.default_rng(5), names=robot_free)
    blocks, truth = simulate(true)
    truth = dict(true.params(), **truth)
    parts = {"range": blocks[:1], "bearing": blocks[1:], "fused": blocks}
    mc = {k: monte_carlo(true, parts[k], truth, rep[k].identifiable, SEEDS) for k in parts}
    return {"rep": rep, "true": true, "blocks": blocks, "truth": truth, "mc": mc,
            "robot_free": robot_free}


def test_fused_noise_free_calibration_recovers_everything() -> None:
    s = setup()
    res = calibrate(ROBOT, s["blocks"], free=s["rep"]["fused"].identifiable)
    assert res.converged
    assert {n for n in res.names if n.startswith(("range.", "theodolite."))} <= \
        set(res.estimated)                       # both instruments' stations estimated
    err = max(abs(res.params[n] - s["truth"][n]) for n in res.names)
    assert err < 1e-9


def test_fusion_reports_smaller_std_than_either_instrument() -> None:
    s = setup()
    std = {k: dict(zip(m.names, m.std, strict=True)) for k, m in s["mc"].items()}
    common = [p for p in s["robot_free"] if all(p in std[k] for k in std)]
    assert len(common) >= 15
    gain = np.array([std["fused"][p] / min(std["range"][p], std["bearing"][p])
                     for p in common])
    assert np.all(gain < 0.9), dict(zip(common, gain.round(3), strict=True))


def test_fusion_monte_carlo_agrees_with_reported_std() -> None:
    s = setup()
    for key, mc in s["mc"].items():
        assert mc.ratio.max() <= 1.2, (key, mc.names[int(np.argmax(mc.ratio))], mc.ratio.max())
        assert mc.last_step < 1e-3


def test_fusion_sees_what_each_instrument_alone_cannot() -> None:
    """Own markers: the theodolites alone miss the scale (one chain length is dependent on
    the others and the stations); with the ranges fused it is identified."""
    blocks, _ = simulate(NOMINAL, marker="own")
    alone = report(NOMINAL, blocks[1:])
    ranges = report(NOMINAL, blocks[:1])
    fused = report(NOMINAL, blocks)
    lost = [p for p in alone.not_identifiable if p in ranges.identifiable]
    assert len(lost) == 1 and NOMINAL.param_units[NOMINAL.param_index(lost[0])] == "m"
    assert lost[0] in fused.identifiable
    text = " ".join(alone.describe())
    assert lost[0] in text and "theodolite.t1.x" in text   # the scale involves the stations
    # fused: both instruments' unknown frames still hide the robot's base frame
    assert {f"base.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")} <= \
        set(fused.not_identifiable)
