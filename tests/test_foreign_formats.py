"""Foreign data from the command line: MUKCa socket folders; estimated encoder offsets
wrapped to (-180, 180] deg and a loud warning when one moves more than its tolerance."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot
from kincal.workflow.flow import run_flow

PANDA = Path(__file__).resolve().parents[2] / "shared" / "data" / "panda_two_socket"


@pytest.mark.skipif(not PANDA.is_dir(), reason=f"Panda two-socket data not found at {PANDA}")
def test_mukca_folders_from_the_command_line(tmp_path, capsys):
    """The README's Panda row from flags alone: folders, --instrument, --option."""
    opts = ["--option", "length=50mm", "--option", "length_std=0.1mm", "--option",
            "point_std=0.05mm", "--option", "probe=vector", "--option", "probe_x=0.0777mm",
            "--option", "probe_y=-0.0421mm", "--option", "probe_z=30.128mm", "--option",
            "estimate_probe=true"]
    code, out, err = run(capsys, "calibrate", PANDA / "panda.urdf", "--base-link",
                         "panda_link0", "--tip-link", "panda_hand_tcp", "--data",
                         PANDA / "front", "--validate", PANDA / "left", "--instrument",
                         "two-socket", *opts, "--json", tmp_path / "r.json", "-o",
                         tmp_path / "cal.yaml")
    assert code == 0, err
    val = json.loads((tmp_path / "r.json").read_text())["metrics"]["validation"]
    assert val["rms_coincidence_m"] < 0.3e-3          # README: 0.239 mm
    assert abs(val["max_distance_m"]) < 0.1e-3        # README: +0.012 mm


@pytest.mark.skipif(not PANDA.is_dir(), reason=f"Panda two-socket data not found at {PANDA}")
def test_an_offset_gone_round_is_wrapped_and_refused(tmp_path, capsys):
    """The hand-made tag line of the issue (probe = the tool, i.e. the ball link) once gave
    panda_joint7.offset = -7342 deg and a URDF turned 142 deg without a word: now the angle
    is reported in (-180, 180] and the calibration is refused as implausible."""
    code, out, err = run(capsys, "calibrate", PANDA / "panda.urdf", "--base-link",
                         "panda_link0", "--tip-link", "ball_link", "--data", PANDA / "front",
                         "--instrument", "two-socket", "--option", "length=50mm", "--option",
                         "probe=tool", "--prior", "none", "-o", tmp_path / "c.yaml",
                         "--json", tmp_path / "r.json")
    assert code == 1 and "panda_joint7.offset moved" in err
    assert not (tmp_path / "c.yaml").exists()
    par = {p["name"]: p for p in json.loads((tmp_path / "r.json").read_text())["parameters"]}
    assert -math.pi < par["panda_joint7.offset"]["estimate"] <= math.pi


def test_offsets_are_reported_in_one_turn():
    """A nominal offset a full turn away converges to the same robot, reported in
    (-pi, pi]."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(3)
    q = random_configurations(nominal, 40, rng)
    truth = nominal.with_params({"theta_offset[3]": 0.01})
    data = simulate_positions(truth, q, rng, noise_std=1e-6)
    start = nominal.with_params({"theta_offset[3]": 2 * math.pi})
    v = run_flow(start, [data], prior="none").result.params["theta_offset[3]"]
    v0 = run_flow(nominal, [data], prior="none").result.params["theta_offset[3]"]
    assert -math.pi < v <= math.pi and v == pytest.approx(v0, abs=1e-9)


def test_an_offset_beyond_its_tolerance_is_a_loud_warning():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    q = random_configurations(nominal, 50, rng)
    truth = nominal.with_params({"theta_offset[3]": math.radians(2.0)})  # 4 tolerances
    data = simulate_positions(truth, q, rng, noise_std=1e-5)
    flow = run_flow(nominal, [data])                          # the default: MAP
    text = " ".join(flow.warnings)
    assert re.search(r"encoder offset theta_offset\[3\] moved \+(1\.[89]\d*|2) deg", text), text
    assert "re-master" in text
    assert flow.verdict.trusted


def test_offsets_are_judged_once_a_warning_then_a_refusal():
    """One mechanism (identify.checks.judge) for an encoder offset beyond its tolerance:
    within the plausibility bound it is a warning naming the offset, its change and its
    tolerance; beyond the bound the same words and advice refuse the calibration."""
    from kincal.identify.checks import OFFSET_ADVICE

    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    q = random_configurations(nominal, 50, rng)
    for deg, trusted in ((2.0, True), (8.0, False)):
        truth = nominal.with_params({"theta_offset[3]": math.radians(deg)})
        flow = run_flow(nominal, [simulate_positions(truth, q, rng, noise_std=1e-6)])
        res, v = flow.result, flow.verdict
        change = math.degrees(res.params["theta_offset[3]"])
        assert (0.5 < change < 5.0) is trusted        # 1 to 10 tolerances: a warning
        words = (f"encoder offset theta_offset[3] moved +{change:.4g} deg "
                 f"({change / 0.5:.3g}x its tolerance 0.5 deg)")
        assert v.trusted is trusted, v.line()
        if trusted:
            assert f"{words}: {OFFSET_ADVICE}" in flow.warnings
            assert v.to_dict()["warnings"] == v.warnings()
        else:
            assert words in v.line() and OFFSET_ADVICE in v.line()
            assert not any("theta_offset[3]" in w for w in flow.warnings)
