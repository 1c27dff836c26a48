"""The calibration workflow from Python (:mod:`kincal.workflow.flow`), without the CLI.

Truth: simulated robots with known parameters; the calibrated model is compared with
the true robot by forward kinematics on held-out configurations.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.measure.registry import simulate_measurements, write_measurements
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot
from kincal.workflow.flow import (
    _render_report,
    block_values,
    check_flow_options,
    parse_selection,
    parse_stages,
    read_blocks,
    run_flow,
    validate_blocks,
    write_outputs,
)

NOISE = 1e-5   # m per coordinate


@pytest.fixture(scope="module")
def sim():
    """PUMA 560 + errors measured by a simulated tracker: training and held-out blocks."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(11)
    true = perturb_robot(nominal, rng, length_std=5e-4, angle_std=math.radians(0.05),
                         offset_std=math.radians(0.1))
    train, truth = simulate_measurements("position", true, rng, 60, NOISE, {"name": "tracker"})
    held, _ = simulate_measurements("position", true, rng, 30, NOISE, {"name": "tracker"},
                                    truth=truth)
    return nominal, true, truth, train, held


@pytest.fixture(scope="module")
def flow(sim):
    nominal, _, _, train, held = sim
    return run_flow(nominal, train, held, stages=["offsets", "all"])


def test_run_flow_recovers_the_truth_on_held_out_configurations(sim, flow):
    nominal, true, truth, _, held = sim
    res = flow.result
    assert res.converged and flow.seconds > 0 and not flow.warnings
    h = held[0]
    y_true = h.predict(true, block_values(truth, h))
    y_cal = h.predict(res.robot, res.theta[res.problem.block_slice("tracker")])
    y_nom = h.predict(nominal, block_values(truth, h))
    dev = np.linalg.norm((y_cal - y_true).reshape(-1, 3), axis=1)
    dev_nom = np.linalg.norm((y_nom - y_true).reshape(-1, 3), axis=1)
    # model error below the per-point noise (sqrt(3) sigma), the nominal far above
    assert np.sqrt(np.mean(dev**2)) < NOISE * math.sqrt(3)
    assert np.sqrt(np.mean(dev_nom**2)) > 50 * NOISE
    train_c, valid_c = flow.comparisons
    assert train_c.label == "train" and valid_c.label == "validation"
    rms_after = float(np.sqrt(np.mean(valid_c.after["position_m"] ** 2)))
    assert rms_after == pytest.approx(NOISE * math.sqrt(3), rel=0.3)
    # same session (name=tracker in both): frames from training, no refit
    assert "same session" in valid_c.note


def test_write_outputs_writes_every_file_and_the_json_lists_them(flow, tmp_path):
    paths = {k: tmp_path / v for k, v in (("robot", "cal.yaml"), ("json", "r.json"),
                                          ("report", "r.html"))}
    written = write_outputs(flow, str(paths["robot"]), None, str(paths["json"]),
                            str(paths["report"]), {"robot": "puma560"}, None, {"seconds": 1.0})
    assert written == {"robot": str(paths["robot"]), "report": str(paths["report"])}
    doc = json.loads(paths["json"].read_text())
    assert doc["outputs"] == written and doc["inputs"] == {"robot": "puma560"}
    assert "staged_selection" not in doc and doc["metrics"]["validation"]["n"] == 30
    cal = load_serial_robot(paths["robot"])
    q = np.zeros((2, 6))
    np.testing.assert_allclose(cal.fk(q), flow.result.robot.fk(q), atol=1e-12)
    assert paths["report"].read_text().rstrip().endswith("</html>")
    assert not list(tmp_path.glob("*figure*"))          # no artifact data, no figures


def test_a_failure_while_rendering_writes_nothing(flow, tmp_path, monkeypatch):
    import kincal.report.html

    def broken(*args, **kwargs):
        raise KincalError("rendering failed")

    monkeypatch.setattr(kincal.report.html, "render_html", broken)
    with pytest.raises(KincalError, match="rendering failed"):
        write_outputs(flow, str(tmp_path / "cal.yaml"), None, str(tmp_path / "r.json"),
                      str(tmp_path / "r.html"))
    assert list(tmp_path.iterdir()) == []


def test_extra_sections_go_before_the_footer(flow):
    out = _render_report(flow.result, flow.comparisons, {}, None, ["<h2>EXTRA</h2>"])
    footer = out.rindex("<p class='small'>kincal")
    assert out.index("<h2>Parameters</h2>") < out.index("<h2>EXTRA</h2>") < footer
    assert out.count("<h2>EXTRA</h2>") == 1


def test_validate_blocks_before_and_after(sim, flow):
    nominal, _, _, _, held = sim
    (comp,) = validate_blocks(flow.result.robot, held, before=nominal)
    a = float(np.sqrt(np.mean(comp.after["position_m"] ** 2)))
    b = float(np.sqrt(np.mean(comp.before["position_m"] ** 2)))
    assert a < 2 * NOISE * math.sqrt(3) and b > 10 * a
    assert "re-registered" in comp.note


def test_read_blocks_renames_clashing_blocks(sim, tmp_path):
    nominal, _, _, train, _ = sim
    path = tmp_path / "a.csv"
    write_measurements("position", train, path, {"length": "mm", "angle": "deg"}, nominal)
    blocks = read_blocks([path, path], nominal)
    assert [b.name for b in blocks] == ["tracker", "tracker2"]
    assert all(b.provenance.path == str(path) for b in blocks)
    with pytest.raises(KincalError, match="no such measurement file"):
        read_blocks([tmp_path / "missing.csv"], nominal)


def test_option_parsing():
    names = ["theta_offset[1]", "a[1]", "a[2]", "tracker.x"]
    roles = ["offset", "length", "length", "instrument"]
    assert parse_selection(names, roles, "role:offset,a[*]", "a[2]") == (
        ["theta_offset[1]", "a[1]", "a[2]"], ["a[2]"])
    assert parse_selection(names, roles, None, None) == (None, [])
    with pytest.raises(KincalError, match="no parameter has role 'tool'"):
        parse_selection(names, roles, "role:tool", None)
    assert parse_stages("offsets, all") == ["offsets", "all"] and parse_stages(None) is None
    with pytest.raises(KincalError, match="unknown stage 'first'"):
        parse_stages("first")


@pytest.mark.parametrize("options, fragment", [
    ({"procedure": "staged-selection", "loss": "huber"},
     "the staged-selection procedure has its own two stages"),
    ({"cycles": 2}, "need --procedure staged-selection"),
    ({"procedure": "staged-selection", "cycles": 0}, "--cycles: must be >= 1"),
    ({"procedure": "staged-selection", "tolerance": -1e-6},
     "--tolerance: must be > 0 (got -0.001 mm)"),
    ({"method": "newton"}, "--method: 'newton' is not lm or gauss-newton"),
    ({"validation_frames": "same"}, "--validation-frames"),
])
def test_check_flow_options(options, fragment):
    with pytest.raises(KincalError) as info:
        check_flow_options(**options)
    assert fragment in str(info.value)
    check_flow_options(procedure="staged-selection", condition_growth=1.0, cycles=1, tolerance=1e-7)
