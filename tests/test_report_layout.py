"""The report's layout: identifiability once (summary first, details folded), "not
estimated (by choice)" apart from "not identifiable", solver details folded, plot text at
least 11 px at a 1280 px window, names from input files escaped."""

from __future__ import annotations

import re

import numpy as np
import pytest

from kincal.identify.solver import calibrate
from kincal.measure.registry import simulate_measurements
from kincal.measure.simulate import perturb_robot
from kincal.report import plots
from kincal.report.html import render_html
from kincal.report.metrics import ErrorComparison
from kincal.robots.files import load_serial_robot

#: Content width of the report in a 1280 px window: body max-width 1200 px minus 2 em
#: of padding.
CONTENT_PX = 1168
MIN_PX = 11.0


@pytest.fixture(scope="module")
def free_result():
    """A calibration with --free: the offsets only (everything else left out by choice)."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(8)
    true = perturb_robot(nominal, rng)
    blocks, _ = simulate_measurements("position", true, rng, 30, 1e-5)
    res = calibrate(nominal, blocks, free=[n for n, r in zip(nominal.param_names,
                                                             nominal.param_roles, strict=True)
                                           if r == "offset"] + ["tracker.*"])
    before = blocks[0].errors(nominal, blocks[0].initial_guess(nominal))
    after = blocks[0].errors(res.robot, res.theta[res.problem.block_slice("tracker")])
    return res, ErrorComparison("train", "training data", before, after, "note")


def _text(page: str) -> str:
    return re.sub(r"<[^>]+>", " ", re.sub(r"<img[^>]*>", "", page))


def test_identifiability_once_summary_first_details_folded(free_result):
    res, comp = free_result
    page = render_html(res, [comp], plots=False)
    section = page[page.index("What the data can identify"):page.index("<h2>Parameters")]
    summary, _, folded = section.partition("<details>")
    assert folded, "the details are folded"
    facts = res.identifiability.describe()
    assert facts
    for fact in facts:                       # every fact once, in the folded part
        shown = fact.replace("'", "&#x27;")
        assert page.count(shown) == 1 and shown in folded and shown not in summary
    assert len(re.findall(r"<li>", summary)) <= 8
    assert "left out by --free / --fix, by choice" in summary


def test_by_choice_apart_from_not_identifiable(free_result):
    res, comp = free_result
    page = render_html(res, [comp], plots=False)
    rows = {m.group(1): m.group(0) for m in re.finditer(r"<tr[^>]*><td class=\"l\">([^<]+)</td>"
                                                         r".*?</tr>", page)}
    assert "not estimated (by choice)" in rows["a[2]"]        # not a candidate
    assert "not identifiable" not in rows["a[2]"]
    assert "estimated" in rows["theta_offset[2]"]
    assert "not identifiable" in rows["base.x"] or "not estimated" in rows["base.x"]


def test_solver_details_are_folded(free_result):
    res, comp = free_result
    page = render_html(res, [comp], plots=False)
    head = page[:page.index("<h2>")]
    assert "tol_step" not in head and "descent step" not in head
    assert "<details><summary>Solver details</summary>" in page
    if res.message:
        folded = page[page.index("Solver details"):]
        assert res.message.split(";")[0][:30].replace("'", "&#x27;") in folded


def test_plot_text_is_at_least_11_px_at_1280_px(free_result, monkeypatch):
    """Every figure of the report fits the content width (shown at its own size) and no
    text is smaller than 11 px."""
    import matplotlib.text

    res, comp = free_result
    seen = []
    real = plots._png

    def check(fig, dpi=plots.DPI):
        fig.canvas.draw()
        width_px = fig.get_figwidth() * dpi
        small = [(t.get_text(), t.get_fontsize() * dpi / 72)
                 for t in fig.findobj(matplotlib.text.Text)
                 if t.get_visible() and t.get_text().strip()
                 and t.get_fontsize() * dpi / 72 < MIN_PX]
        seen.append((width_px, small))
        return real(fig, dpi)

    monkeypatch.setattr(plots, "_png", check)
    render_html(res, [comp, ErrorComparison("validation", "held-out", comp.before,
                                            comp.after, "note")])
    assert len(seen) >= 4
    for width_px, small in seen:
        assert width_px <= CONTENT_PX, width_px
        assert not small, small[:5]


def test_many_parameters_keep_readable_correlation_labels(monkeypatch):
    import matplotlib.text

    names = [f"arm_{i}_joint.origin.x" for i in range(80)]
    C = np.eye(80)
    sizes = []
    real = plots._png

    def check(fig, dpi=plots.DPI):
        sizes.extend(t.get_fontsize() * dpi / 72 for t in fig.findobj(matplotlib.text.Text)
                     if t.get_visible() and t.get_text().strip())
        assert fig.get_figwidth() * dpi <= CONTENT_PX
        return real(fig, dpi)

    monkeypatch.setattr(plots, "_png", check)
    plots.correlation(C, names)
    assert min(sizes) >= MIN_PX


def test_names_from_input_files_are_escaped(tmp_path):
    """A block named in a file's tag line cannot inject HTML into the report."""
    from kincal.workflow.flow import read_blocks, render_outputs, run_flow

    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(2)
    blocks, _ = simulate_measurements("position", perturb_robot(nominal, rng), rng, 30,
                                      1e-5, {"name": "tracker"})
    from kincal.measure.registry import write_measurements

    f = tmp_path / "evil.csv"
    write_measurements("position", blocks, f, {"length": "mm", "angle": "deg"}, nominal)
    text = f.read_text().replace("name=tracker", "name=<script>alert(1)</script>")
    f.write_text(text)
    flow = run_flow(nominal, read_blocks([f], nominal))
    _, contents = render_outputs(flow, report=str(tmp_path / "r.html"),
                                 inputs={"data": "<img src=x onerror=alert(1)>"})
    page = str(contents["report"])
    assert "<script>alert(1)" not in page and "<img src=x" not in page
    assert "&lt;script&gt;" in page
