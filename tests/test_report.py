"""The report: metrics against hand computations, the JSON, the single-file HTML."""

from __future__ import annotations

import base64
import math
import re

import numpy as np
import pytest

from kincal.identify.solver import calibrate
from kincal.measure.registry import simulate_measurements
from kincal.measure.simulate import perturb_robot
from kincal.report.html import (
    identifiability_details,
    identifiability_summary,
    render_html,
    write_html_report,
)
from kincal.report.metrics import ErrorComparison, error_metrics, merge_errors, result_json
from kincal.report.plots import display_scale, parameter_history
from kincal.robots.files import load_serial_robot

PNG = b"\x89PNG\r\n\x1a\n"


def test_error_metrics_by_hand():
    e = {"position_m": np.array([3e-3, 4e-3]), "orientation_rad": np.array([0.0, 2e-3])}
    m = error_metrics(e)
    assert m["n"] == 2
    assert m["rms_position_m"] == pytest.approx(math.sqrt((9e-6 + 16e-6) / 2))
    assert m["mean_position_m"] == pytest.approx(3.5e-3)
    assert m["max_position_m"] == pytest.approx(4e-3)
    assert m["rms_orientation_rad"] == pytest.approx(math.sqrt(2e-6))
    # several markers per pose: every point counts
    two = error_metrics({"position_m": np.array([[1.0, 3.0]])})
    assert two["n"] == 2 and two["rms_position_m"] == pytest.approx(math.sqrt(5))
    merged = merge_errors([{"position_m": np.ones(2)}, {"position_m": np.zeros((1, 2))}])
    np.testing.assert_array_equal(merged["position_m"], [1, 1, 0, 0])


@pytest.fixture(scope="module")
def small_result():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(4)
    true = perturb_robot(nominal, rng)
    blocks, truth = simulate_measurements("position", true, rng, 40, 1e-5)
    res = calibrate(nominal, blocks, stages=["offsets", "all"])
    before = blocks[0].errors(nominal, blocks[0].initial_guess(nominal))
    after = blocks[0].errors(res.robot, res.theta[res.problem.block_slice("tracker")])
    comp = ErrorComparison("train", "training data", before, after, "note")
    return res, comp, {**true.params(), **truth}


def test_result_json_keys_and_missing_validation(small_result):
    res, comp, _ = small_result
    d = result_json(res, [comp], {"inputs": {"robot": "puma560"}})
    assert d["metrics"]["validation"] is None
    t = d["metrics"]["train"]
    assert t["rms_position_m"] == pytest.approx(error_metrics(comp.after)["rms_position_m"])
    assert t["before"]["rms_position_m"] > 10 * t["rms_position_m"]
    assert d["inputs"]["robot"] == "puma560"
    assert {"name", "nominal", "estimate", "std", "identifiable"} <= set(d["parameters"][0])


def test_identifiability_sentences_name_the_hidden_parameters(small_result):
    res, _, _ = small_result
    s = identifiability_summary(res) + identifiability_details(res)
    assert s[0].startswith(f"{len(res.identifiability.identifiable)} of {len(res.names)}")
    assert any(x.startswith("base.x cannot be told apart from tracker.x") for x in s)
    assert any("Condition number" in x for x in s)


def test_html_report_single_file(small_result, tmp_path):
    res, comp, truth = small_result
    path = tmp_path / "r.html"
    write_html_report(path, res, [comp], title="test", inputs={"robot": "puma560"},
                      truth=truth)
    text = path.read_text()
    assert list(tmp_path.iterdir()) == [path]
    srcs = re.findall(r'src="([^"]*)"', text)
    assert len(srcs) >= 5
    for s in srcs:
        head, data = s.split(",", 1)
        assert head == "data:image/png;base64" and base64.b64decode(data)[:8] == PNG
    # one table row per parameter, with the true value column
    rows = re.findall(r"<tr( class=\"no\")?><td class=\"l\">([^<]+)</td>", text)
    names = [r[1] for r in rows if r[1] in res.names]
    assert names == list(res.names)
    assert "<th>true</th>" in text
    fixed = sum(1 for r in rows if r[0] and r[1] in res.names)
    assert fixed == len(res.names) - len(res.estimated)
    # no plots: still a valid page
    bare = render_html(res, [], plots=False)
    assert "<img" not in bare and "Parameters" in bare


def test_parameter_history_one_plot_per_parameter():
    H = np.cumsum(np.full((5, 6), 1e-4), axis=0)
    units = ["m"] * 3 + ["rad"] * 3
    pngs = parameter_history(H, [f"p{i}" for i in range(6)], units, ["a"] * 2 + ["b"] * 3,
                             {"p0": 1e-4}, per_figure=4, columns=2)
    assert len(pngs) == 2 and all(p[:8] == PNG for p in pngs)
    assert display_scale("m") == (1e3, "mm") and display_scale("rad")[1] == "deg"
