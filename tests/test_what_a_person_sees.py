"""What a person sees: plots that tell the truth (solver passes marked, the iteration axis
agreeing with the headline, a unit on every axis, no tick label outside its figure),
tables that fit a terminal without a broken word (80 and 120 columns, COLUMNS set or
not), and printouts a notebook user meets (blocks, validation, empty tables)."""

from __future__ import annotations

import re
import shutil
import types
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run, write_tracker
from rich.console import Console
from rich.table import Table
from rich.text import Text

import kincal
from kincal.cli import common
from kincal.identify.validation import error_statistics
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.report import plots

PROGRAMS = Path(__file__).parent / "data" / "programs"
UNIT = re.compile(r"[\[(][^\])]+[\])]")      # "[mm]", "(dimensionless)", "(date)"


# --------------------------------------------------------------------------- figures
@pytest.fixture
def figures(monkeypatch):
    """Every figure the report and fleet page save, drawn, instead of its PNG."""
    import kincal.fleet.page as page

    caught = []

    def keep(fig, dpi=plots.DPI):
        fig.canvas.draw()
        caught.append(fig)
        return b""

    monkeypatch.setattr(plots, "_png", keep)
    monkeypatch.setattr(page, "_png", keep)
    return caught


def _drawn_ticks(axis) -> list:
    """The tick labels matplotlib draws: those of ticks inside the view limits."""
    lo, hi = sorted(axis.get_view_interval())
    span = (hi - lo) * 1e-9
    return [t.label1 for t in axis.get_major_ticks() + axis.get_minor_ticks()
            if lo - span <= t.get_loc() <= hi + span and t.label1.get_visible()]


def _check_figure(fig) -> None:
    """Every drawn axes has x and y labels naming a unit (in brackets or parentheses;
    the figure's common x label counts for all) and every tick label, axis label and
    title lies inside the figure."""
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    common_x = fig._supxlabel.get_text() if getattr(fig, "_supxlabel", None) else ""
    for ax in fig.axes:
        if not ax.axison:
            continue
        assert UNIT.search(ax.get_ylabel()), (ax.get_title(), ax.get_ylabel())
        if ax.get_label() != "<colorbar>":                  # a colour bar has one axis
            assert UNIT.search(ax.get_xlabel() or common_x), (ax.get_title(), ax.get_xlabel())
        texts = [ax.title, ax.xaxis.label, ax.yaxis.label, *_drawn_ticks(ax.xaxis),
                 *_drawn_ticks(ax.yaxis)]
        for t in texts:
            if not t.get_visible() or not t.get_text():
                continue
            e = t.get_window_extent(renderer)
            inside = (e.x0 >= box.x0 - 0.5 and e.x1 <= box.x1 + 0.5 and e.y0 >= box.y0 - 0.5
                      and e.y1 <= box.y1 + 0.5)
            assert inside, f"{t.get_text()!r} of {ax.get_title()!r} is cut: {e} vs {box}"


@pytest.fixture(scope="module")
def map_fit():
    """A default (MAP) calibration whose data are twice as noisy as stated: the noise
    scale sigma0 ~ 2 makes the solver re-solve with the prior re-weighted."""
    robot = kincal.load_robot("puma560")
    rng = np.random.default_rng(3)
    truth = perturb_robot(robot, rng)
    q = random_configurations(robot, 40, rng)
    block = simulate_positions(truth, q, rng, 2e-5)
    block.sigma = np.full_like(block.sigma, 1e-5)               # stated: half the noise
    return robot, truth, block, kincal.calibrate(robot, [block], prior="tolerances")


def test_convergence_plot_marks_every_pass_and_ends_at_the_headline_count(map_fit, figures):
    from kincal.report.html import _history

    _, _, _, res = map_fit
    H, stages, cost, rms, its = _history(res)
    restarts = [i for i in range(1, len(its)) if its[i] == 0]
    assert restarts, "the noise scale re-solve restarts the solver"
    passes = plots.solver_passes(stages, its, cost, H)
    assert len(passes) == len(restarts) + 1
    # the iteration axis counts the iterations of all passes: the headline's number
    assert passes[-1].x[-1] == res.iterations
    assert all(p.new_weights for p in passes[1:])   # same point, another cost
    plots.convergence(cost, rms, stages, its, H)
    [fig] = figures
    _check_figure(fig)
    cost_ax = fig.axes[0]
    segments = [ln for ln in cost_ax.get_lines() if len(ln.get_xdata()) > 2 or
                ln.get_label().startswith("pass")]
    assert len(segments) == len(passes)                    # one curve per pass, not one
    marks = [ln for ln in cost_ax.get_lines() if ln.get_linestyle() == "--"]
    assert sorted(float(m.get_xdata()[0]) for m in marks) == [p.x[0] for p in passes[1:]]
    legend = [t.get_text() for t in cost_ax.get_legend().get_texts()]
    assert any("re-solve" in t and "sigma0" in t for t in legend)
    assert f"{res.iterations} over {len(passes)} passes" in cost_ax.get_xlabel()


def test_report_headline_names_the_passes(map_fit):
    from kincal.report.html import render_html

    _, _, _, res = map_fit
    page = render_html(res, [], plots=False)
    assert re.search(rf"after {res.iterations} iterations in \d+ solver passes", page)


def test_parameter_history_minus_signs_are_inside_the_figure(map_fit, figures):
    from kincal.report.html import _history

    robot, truth, _, res = map_fit
    H, stages, _, _, its = _history(res)
    idx = [res.names.index(n) for n in res.estimated]
    plots.parameter_history(H[:, idx], res.estimated,
                            [res.problem.units[i] for i in idx], stages,
                            truth.params(),
                            iterations=its)
    assert figures
    negative = 0
    for fig in figures:
        _check_figure(fig)
        negative += sum(t.get_text().startswith(("-", "\N{MINUS SIGN}"))
                        for ax in fig.axes for t in ax.get_yticklabels())
    assert negative, "the case checks negative tick labels"


def test_fleet_plots_have_units_and_uncut_labels(figures):
    from kincal.fleet.page import accuracy_plot, history_plot

    serials = [f"R-{i:05d}" for i in range(12)]
    rms = list(np.linspace(0.012e-3, 0.04e-3, 12))         # within one decade
    accuracy_plot(serials, {"training": rms, "previous": [v * 2 for v in rms]}, {"R-00003"})
    records = [{"date": f"2026-0{k + 1}-05", "parameters": [
        {"name": "alpha[5]", "estimate": np.radians(-90.05 - 0.01 * k), "std": 1e-5,
         "unit": "rad"},
        {"name": "d[4]", "estimate": -0.4318 + 1e-5 * k, "std": 2e-6, "unit": "m"}]}
        for k in range(3)]
    history_plot("R-00003", records, ["alpha[5]", "d[4]"])
    assert len(figures) == 2
    for fig in figures:
        _check_figure(fig)
    labels = [t.get_text() for t in _drawn_ticks(figures[0].axes[0].yaxis) if t.get_text()]
    assert labels and not any("10^" in t or "times" in t for t in labels)   # plain numbers
    assert all(float(t.replace("\N{MINUS SIGN}", "-")) > 0 for t in labels)


# --------------------------------------------------------------------------- tables
def _words(table: Table) -> list[str]:
    """Every word of the table's headers and cells, as printed (markup removed)."""
    out = []
    for col in table.columns:
        for cell in (col.header, *col.cells):
            text = cell.plain if isinstance(cell, Text) else Text.from_markup(str(cell)).plain
            out += text.split()
    return out


def _assert_fits(text: str, tables: list[Table], width: int) -> None:
    flat = " ".join(text.split())
    too_long = [line for line in text.splitlines() if len(line) > width]
    assert not too_long, too_long[:3]
    for t in tables:
        broken = [w for w in _words(t) if w not in flat]
        assert not broken, f"{t.title}: broken words {broken[:5]}"


@pytest.mark.parametrize("width", [80, 120])
def test_fit_table_never_breaks_a_word(width):
    """Headers and cells whose longest words fit side by side are kept whole (rich
    narrows the widest column first and folds its words); wider tables come in parts."""
    t = Table(title="Estimated parameters (lengths mm, angles deg)")
    heads = ["parameter", "nominal", "estimate", "change", "std (1σ)", "prior (1σ)",
             "status", "predicted RMS [mm]", "quantity", "file"]
    for h in heads:
        t.add_column(h)
    for k in range(6):
        t.add_row(f"theta_offset[{k + 1}]", "-1065.0926", "-1065.3819", "-0.2893", "0.0054",
                  "1.0000", "dependent on tracker.x, tracker.y", "0.0186", "position [mm]",
                  f"right_arm_grid_6x6x6_session_{k}.csv")
    console = Console(width=width, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    console.print(common.fit_table(console, t))
    text = console.export_text()
    _assert_fits(text, [t], width)
    assert text.count("theta_offset[3]") >= 1 and "(continued)" in text


def test_a_word_wider_than_the_terminal_is_folded_not_looped():
    """Two columns whose longest words cannot sit side by side at 40 columns: no parts
    to split into, the table prints (the long word folds) instead of recursing."""
    t = Table()
    t.add_column("robot")
    t.add_column("reason")
    t.add_row("R-00002", "/tmp/pytest-of-root/pytest-121/fleet0/R-00002/tracker.csv: bad")
    console = Console(width=40, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    console.print(common.fit_table(console, t))
    assert "R-00002" in console.export_text()


def test_console_width_follows_columns_when_printing(monkeypatch):
    """rich reads COLUMNS once, when a console is made; the command line's console is
    made at import, so a COLUMNS exported before it must not stick."""
    monkeypatch.setenv("COLUMNS", "30")
    c = common.KincalConsole()
    monkeypatch.setenv("COLUMNS", "123")
    assert c.width == 123
    monkeypatch.delenv("COLUMNS")
    assert c.width == Console(file=c.file).width       # rich's own rule (terminal or 80)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """Small simulated data for every main command, with short relative paths."""
    root = tmp_path_factory.mktemp("see")
    robot = kincal.load_robot("puma560")
    rng = np.random.default_rng(5)
    truth = perturb_robot(robot, rng)
    for name, n in (("train.csv", 30), ("held.csv", 15)):
        q = random_configurations(robot, n, rng)
        write_tracker(root / name, robot, q, simulate_positions(truth, q, rng, 1e-5).positions)
    for f in PROGRAMS.iterdir():
        if f.stem == "weld_seam" or f.name == "krl_frames.yaml":
            shutil.copy(f, root / f.name)
    return root


COMMANDS = [
    ("calibrate", ["calibrate", "puma560", "--data", "train.csv", "--validate", "held.csv",
                   "-o", "cal.yaml", "--json", "cal.json"]),
    ("validate", ["validate", "cal.yaml", "--data", "held.csv", "--before", "puma560"]),
    ("identifiability", ["identifiability", "puma560", "--data", "train.csv"]),
    ("plan", ["plan", "puma560", "-n", "12", "--candidates", "80", "-o", "plan.csv"]),
    ("simulate", ["simulate", "puma560", "-n", "10", "-o", "sim.csv"]),
    ("instruments", ["instruments"]),
    ("fk", ["fk", "puma560", "--q", "0,0.1,0.2,0,0.3,0"]),
    ("show", ["show", "puma560"]),
    ("filter", ["filter", "weld_seam.src", "--robot", "cal6.yaml", "--nominal", "kr6",
                "--frames", "krl_frames.yaml", "-o", "out/weld_seam.src"]),
]


@pytest.mark.parametrize("columns", ["80", "120", None])
def test_main_commands_print_tables_without_broken_words(columns, workdir, capsys,
                                                         monkeypatch):
    monkeypatch.chdir(workdir)
    if columns is None:
        monkeypatch.delenv("COLUMNS", raising=False)    # captured: the terminal's, or 80
    else:
        monkeypatch.setenv("COLUMNS", columns)
    width = int(columns) if columns else common.console.width
    from kincal.measure.simulate import perturb_robot as perturb
    from kincal.robots.files import write_robot_yaml

    write_robot_yaml(perturb(kincal.load_robot("kr6"), np.random.default_rng(7)),
                     workdir / "cal6.yaml")
    tables: list[Table] = []
    original = common.fit_table

    def spy(console, table, w=None):
        tables.append(table)
        return original(console, table, w)

    monkeypatch.setattr(common, "fit_table", spy)
    for name, args in COMMANDS:
        tables.clear()
        code, out, err = run(capsys, *args)
        assert code == 0, (name, err)
        assert tables or name == "simulate", f"{name} printed no table"
        _assert_fits(out, tables, width)


@pytest.mark.parametrize("columns", ["80", None])
def test_fleet_commands_fit(columns, tmp_path, capsys, monkeypatch):
    pytest.importorskip("sqlalchemy")
    pytest.importorskip("distributed")
    monkeypatch.chdir(tmp_path)
    if columns is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", columns)
    tables: list[Table] = []
    original = common.fit_table
    monkeypatch.setattr(common, "fit_table",
                        lambda c, t, w=None: tables.append(t) or original(c, t, w))
    code, _, err = run(capsys, "fleet", "simulate", "puma560", "--out-dir", "fl", "-n", "4",
                       "--poses", "25", "--drifted", "1", "--broken", "1")
    assert code == 0, err
    for args, expect in ((["calibrate", "fl/fleet.yaml", "--db", "h.db", "--serial"], 1),
                         (["history", "--db", "h.db"], 0),
                         (["drift", "--db", "h.db", "--report", "fleet.html",
                           "--reproducibility", "none"], 1)):
        tables.clear()
        code, out, err = run(capsys, "fleet", *args)
        assert code == expect, err
        assert tables
        _assert_fits(out, tables, common.console.width)
    assert "[mm]" in " ".join(out.split())                 # units are not eaten as markup


# --------------------------------------------------------------------------- printouts
def test_blocks_show_instrument_rows_sigma_and_file(workdir):
    robot = kincal.load_robot("puma560")
    [block] = kincal.read_measurements(str(workdir / "train.csv"), robot)
    text = repr(block)
    assert "object at 0x" not in text
    for part in ("'tracker'", "position", "30 rows", "sigma 0.01 mm", "train.csv"):
        assert part in text, text
    html = block._repr_html_()
    for cell in ("<th style='text-align:left'>sigma</th><td>0.01 mm</td>", "train.csv",
                 "<td>30</td>", "<td>position</td>"):
        assert cell in html
    rng = np.random.default_rng(0)
    sim = simulate_positions(robot, random_configurations(robot, 4, rng), rng, 2e-6)
    assert "sigma 0.002 mm" in repr(sim) and "simulated or in memory" in sim._repr_html_()


def test_validate_returns_a_result_with_units_that_still_reads_as_the_dict(map_fit):
    robot, truth, block, res = map_fit
    v = kincal.validate(res.robot, [block], extras=res)
    assert isinstance(v, kincal.Validation)
    assert set(v) == {"overall", "blocks", "extras"} and v["overall"] is v.overall
    assert v.to_dict()["blocks"]["tracker"] == v["blocks"]["tracker"]
    # independent: the block's own errors at the parameters the validation used
    used = np.array([v["extras"]["tracker"][n] for n in block.parameters().names])
    e = block.errors(res.robot, used)
    direct = error_statistics(e)
    assert v.overall["rms_position_m"] == pytest.approx(direct["rms_position_m"], rel=1e-12)
    assert v.rms_position_mm == pytest.approx(1e3 * direct["rms_position_m"], rel=1e-12)
    assert v.max_position_mm == pytest.approx(1e3 * direct["max_position_m"], rel=1e-12)
    assert np.isnan(v.rms_orientation_deg) and v.n == 40
    assert f"position RMS {v.rms_position_mm:.4g} mm" in repr(v)
    assert "<td>tracker</td>" in v._repr_html_() and "<th>unit</th>" in v._repr_html_()


def test_no_empty_why_it_failed_table(map_fit):
    robot = kincal.load_robot("puma560")
    q = random_configurations(robot, 3, np.random.default_rng(2))
    targets = robot.fk(q)
    ok = kincal.solve_ik(robot, targets)
    assert "why it failed" not in ok._repr_html_() and "3/3 solved" in ok._repr_html_()
    far = targets.copy()
    far[1, :3, 3] = [5.0, 0.0, 0.0]                          # 5 m away: out of reach
    bad = kincal.solve_ik(robot, far)
    assert "why it failed" in bad._repr_html_() and "unreachable" in bad._repr_html_()


def test_filter_says_unreachable_once():
    from kincal.cli.filter import _warning_cell

    r = types.SimpleNamespace(warnings=["unreachable"], status="not filtered",
                              reason="unreachable: outside the robot's workspace")
    assert _warning_cell(r) == "unreachable: outside the robot's workspace"
    r = types.SimpleNamespace(warnings=["near a singularity", "not filtered"],
                              status="not filtered", reason="no joint solution")
    assert _warning_cell(r) == "near a singularity, not filtered: no joint solution"
    r = types.SimpleNamespace(warnings=[], status="filtered", reason="")
    assert _warning_cell(r) == ""


def test_every_documented_parameter_is_in_the_signature():
    """mkdocstrings takes a parameter's default from the signature by its name: a
    docstring entry ``base_link, tip_link:`` matches none and showed them as required."""
    import inspect

    griffe = pytest.importorskip("griffe")
    for name in kincal.__all__:
        obj = getattr(kincal, name)
        if not callable(obj) or isinstance(obj, type) and issubclass(obj, Exception):
            continue
        doc = inspect.getdoc(obj.__init__ if isinstance(obj, type) else obj) or ""
        parsed = griffe.Docstring(doc).parse("google", warnings=False)
        params = [p.name for s in parsed if s.kind.value == "parameters" for p in s.value]
        try:
            sig = inspect.signature(obj)
        except (TypeError, ValueError):
            continue
        missing = [p for p in params if p not in sig.parameters and not p.startswith("*")]
        assert not missing, f"kincal.{name}: documented {missing} not in {sig}"


def test_accuracy_results_print_in_mm(map_fit):
    robot, _, block, res = map_fit
    model = kincal.accuracy_model(res)
    assert "object at 0x" not in repr(model) and "array(" not in repr(model)
    assert f"floor {model.floor_m * 1e3:.3g} mm" in repr(model)
    assert "unmodelled floor [mm]" in model._repr_html_()
    pred = kincal.predict_accuracy(model, res.robot, block.q[:6])
    top = float(pred.predicted_m.max()) * 1e3
    assert f"up to {top:.3g} mm" in repr(pred) and "array(" not in repr(pred)
    assert "inside the training region" in pred._repr_html_()


def test_every_report_figure_has_units_and_uncut_labels(map_fit, figures):
    """The whole report of a MAP calibration: convergence, parameter histories, error
    histograms, per-measurement errors and the correlation map."""
    from kincal.report.html import render_html
    from kincal.report.metrics import ErrorComparison

    robot, _, block, res = map_fit
    before = block.errors(robot, block.initial_guess(robot))
    after = block.errors(res.robot, res.theta[res.problem.block_slice("tracker")])
    render_html(res, [ErrorComparison("train", "training data", before, after, "")])
    assert len(figures) >= 5
    for fig in figures:
        _check_figure(fig)


def test_robots_show_their_joints_and_parameters_in_mm_and_degrees():
    """A serial robot and a five-bar in a notebook: mm and degrees, never raw metres."""
    from kincal.parallel.files import load_fivebar

    robot = kincal.load_robot("puma560")
    html = robot._repr_html_()
    assert "Robot puma560" in html and html.count("<tr><td>q") == 6
    lo = np.degrees(robot.joint_limits[1, 0])
    assert f"{lo:.4g} deg" in html                                     # q2's lower limit
    d3 = robot.param_values[robot.param_index("d[3]")] * 1e3
    assert f"{d3:.4g} mm" in html                                      # a length in mm
    five = load_fivebar("fivebar_reference")
    text = repr(five)
    assert text.startswith("FiveBar('fivebar_reference', l1..l4 = 2000, 2000, 3000, 3000 mm")
    assert "deg" in text and "e-" not in text
    assert "2000, 2000 mm" in five._repr_html_()
