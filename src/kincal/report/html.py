"""The calibration report as a single-file HTML page.

The numbers it shows come from :mod:`kincal.report.metrics`.

* :func:`identifiability_summary` / :func:`identifiability_details` - what the data can
  and cannot identify, in words: a short summary, then every fact (folded).
* :func:`render_html` / :func:`write_html_report` - one HTML file, images embedded as
  base64 PNG: summary, before/after table, identifiability, parameter table
  (nominal, estimate, std, identifiable), convergence, one plot per parameter of its
  value against the iteration, error histograms and per-measurement errors before
  and after, correlation of the estimates.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from kincal.io import atomic_write_text
from kincal.report.metrics import ErrorComparison, error_keys, error_metrics, quantity

Array = NDArray[np.float64]


class IdentifiabilityView(Protocol):
    """The identifiability analysis as the report reads it: the candidate names and
    its facts, one sentence each."""

    @property
    def names(self) -> Sequence[str]: ...

    def describe(self) -> Sequence[str]: ...


class ProblemView(Protocol):
    """The parameters of the calibrated problem: names, units and roles, in order."""

    @property
    def names(self) -> Sequence[str]: ...

    @property
    def units(self) -> Sequence[str]: ...

    @property
    def roles(self) -> Sequence[str]: ...


class IterationView(Protocol):
    """One solver iteration: the parameter values after it, its stage, cost and RMS."""

    @property
    def theta(self) -> Array: ...

    @property
    def stage(self) -> str: ...

    @property
    def cost(self) -> float: ...

    @property
    def rms(self) -> float: ...


class RobotView(Protocol):
    @property
    def name(self) -> str: ...


class CalibrationView(Protocol):
    """What the report needs of a calibration: a serial
    :class:`~kincal.identify.solver.CalibrationResult` or a five-bar's report view
    (:class:`kincal.parallel.report.ReportView`)."""

    @property
    def names(self) -> Sequence[str]: ...

    @property
    def estimated(self) -> Sequence[str]: ...

    @property
    def theta(self) -> Array: ...

    @property
    def robot(self) -> RobotView: ...

    @property
    def problem(self) -> ProblemView: ...

    @property
    def identifiability(self) -> IdentifiabilityView | None: ...

    @property
    def held_by_prior(self) -> Sequence[str]: ...

    @property
    def history(self) -> Sequence[IterationView]: ...

    @property
    def correlation(self) -> Array | None: ...

    @property
    def message(self) -> str: ...

    def to_dict(self) -> dict[str, Any]: ...


# --------------------------------------------------------------------------- words
def _fmt(value: float | None, unit: str, digits: int = 4) -> str:
    if value is None or not np.isfinite(value):
        return "-"
    if unit == "m":
        return f"{value * 1e3:.{digits}f}"
    if unit == "rad":
        return f"{math.degrees(value):.{digits}f}"
    return f"{value:.{digits}g}"


def _disp_unit(unit: str) -> str:
    return {"m": "mm", "rad": "deg"}.get(unit, unit)


def identifiability_summary(result: CalibrationView) -> list[str]:
    """The identifiability facts in a few lines, for the top of the section: how many
    parameters the data identifies, which were left out by choice, and what absorbs the
    rest (grouped, one line per group)."""
    d = result.to_dict()
    params = d.get("parameters", [])
    rep = result.identifiability
    problem = result.problem
    candidates = set((rep.names if rep is not None else []) or [p["name"] for p in params])
    by_choice = [p["name"] for p in params if p["name"] not in candidates]
    est = [p for p in params if p.get("estimated")]
    ident = d.get("identifiability") or {}
    out = [f"{d.get('identifiable_count', len(est))} of {len(candidates)} candidate "
           f"parameters are identifiable from these measurements; {len(est)} were "
           "estimated, the others kept their nominal (or initial) values."]
    if by_choice:
        out.append(f"{len(by_choice)} parameter(s) were not candidates (left out by "
                   f"--free / --fix, by choice): {_short_list(by_choice)}.")
    if rep is not None:
        out += identifiability_groups(rep, problem.names, problem.roles)
    cs, cu = ident.get("cond_scaled"), ident.get("cond_unscaled")
    if cs is not None:
        out.append(f"Condition number of the column-scaled identification Jacobian: {cs:.3g}"
                   + (f" (unscaled {cu:.3g})" if cu is not None else "") + ".")
    return out


def identifiability_details(result: CalibrationView) -> list[str]:
    """Every fact of the identifiability analysis, one sentence each (folded in the
    report under the summary)."""
    if result.identifiability is not None:
        told = result.identifiability.describe()
        lines = told.splitlines() if isinstance(told, str) else list(told)
        return [str(ln).strip() for ln in lines if str(ln).strip()]
    ident = result.to_dict().get("identifiability") or {}
    out = []
    unobs = list(ident.get("unobservable", []))
    if unobs:
        out.append(f"{len(unobs)} parameter(s) have no effect on any measurement and cannot "
                   f"be identified at all: {', '.join(unobs)}.")
    for name, others in (ident.get("dependent", {}) or {}).items():
        out.append(f"{name} cannot be told apart from {', '.join(others)}: the data sees only "
                   "a combination of them, so it was held fixed.")
    return out


def _short_list(names: Sequence[str], limit: int = 12) -> str:
    more = len(names) - limit
    return ", ".join(names[:limit]) + (f" and {more} more" if more > 0 else "")


_ROBOT_ROLES = ("base", "tool", "offset", "length", "angle")
_BLOCK_PART = {"instrument": "frame", "tool_point": "marker", "target": "target"}


def identifiability_groups(report: Any, names: Sequence[str], roles: Sequence[str]
                           ) -> list[str]:
    """The non-identifiable parameters grouped by what absorbs them, one sentence each.

    E.g. "base.x, base.y, theta_offset[1] are absorbed by the frame of tracker" (an
    instrument in an unknown place hides the robot's base), "tool.x, d[6] are absorbed
    by the marker of tracker", "d[3] cannot be separated from d[2]".
    """
    role = dict(zip(names, roles, strict=True))
    groups: dict[str, list[str]] = {}
    singles: list[str] = []
    for n in report.not_identifiable:
        if n in report.unobservable:
            groups.setdefault("have no effect on the measurements", []).append(n)
            continue
        deps = list(report.dependent.get(n, []))
        if deps and all(role.get(d) not in _ROBOT_ROLES for d in deps):
            parts = sorted({f"{_BLOCK_PART.get(role.get(d, ''), 'parameters')} of "
                            f"{d.split('.')[0]}" for d in deps})
            groups.setdefault(f"are absorbed by the {' and the '.join(parts)}", []).append(n)
        elif deps:
            singles.append(f"{n} cannot be separated from {', '.join(deps)}")
        else:
            singles.append(f"{n} is not identifiable")
    out = [f"{', '.join(v)} {k}" if len(v) > 1 else
           f"{v[0]} {k.replace('are absorbed', 'is absorbed').replace('have no', 'has no')}"
           for k, v in groups.items()]
    return out + singles


# --------------------------------------------------------------------------- HTML
_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1200px;
margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{font-size:1.25em;margin-top:1.8em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.88em;margin:.6em 0}
th,td{border:1px solid #ddd;padding:3px 8px;text-align:right}
th{background:#f3f3f3}td.l,th.l{text-align:left}
tr.no td{color:#999}img{max-width:100%}
.ok{color:#1a7f37}.bad{color:#c0504d}.warn{color:#9a6700}.muted{color:#777}
.small{font-size:.85em;color:#555}
details{margin:.6em 0}summary{cursor:pointer;color:#333}
"""


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _metric_table(comparisons: Sequence[ErrorComparison]) -> str:
    head = ["data", "quantity", "n", "", "RMS", "mean", "max"]
    rows = []
    for c in comparisons:
        for k, key in enumerate(error_keys(c.before, c.after)):
            name, f, unit = quantity(key)
            for when, errs in (("before", c.before), ("after", c.after)):
                m = error_metrics({key: errs[key]}) if key in errs else {}
                first = when == "before"
                cells = [html.escape(c.title) if first and k == 0 else "",
                         f"{name} [{unit}]" if first else "",
                         str(m.get("n", "")) if first else "", when]
                cells += [_num(m.get(f"{s}_{key}"), f) for s in ("rms", "mean", "max")]
                rows.append("<tr>" + "".join(
                    f'<td class="l">{x}</td>' if i < 4 else f"<td>{x}</td>"
                    for i, x in enumerate(cells)) + "</tr>")
    notes = "".join(f"<li>{html.escape(c.title)}: "
                    f"{'<br>'.join(html.escape(x) for x in c.note.splitlines())}</li>"
                    for c in comparisons if c.note)
    return ("<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows)
            + "</table>" + (f'<ul class="small">{notes}</ul>' if notes else ""))


def _num(v: float | None, factor: float) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v * factor:.4f}"


def _param_status(p: Mapping[str, Any], candidates: set[str], held: set[str]
                  ) -> tuple[str, str]:
    """(text, css class) of a parameter's status in the report's table."""
    if p.get("estimated"):
        if p["name"] in held:
            return "estimated, held by the prior (weakly identifiable)", "warn"
        return "estimated", "ok"
    if p["name"] not in candidates:
        return "not estimated (by choice)", "muted"
    status = str(p.get("status", ""))
    if status == "unobservable":
        return "not identifiable: no effect on the data", "bad"
    if status.startswith("dependent"):
        return f"not identifiable: {status}", "bad"
    if p.get("identifiable"):
        return "identifiable, not estimated (stage)", "muted"
    return "not identifiable", "bad"


def _param_table(result: CalibrationView, truth: Mapping[str, float] | None) -> str:
    params = result.to_dict()["parameters"]
    rep = result.identifiability
    candidates = set((rep.names if rep is not None else []) or [p["name"] for p in params])
    held = set(result.held_by_prior or [])
    head = ["parameter", "unit", "nominal", "estimate", "change", "std (1σ)", "status"]
    if truth:
        head.insert(5, "true")
    rows = []
    for p in params:
        u = p.get("unit", "")
        nom, est, std = p.get("nominal"), p.get("estimate"), p.get("std")
        change = None if nom is None or est is None else est - nom
        text, cls = _param_status(p, candidates, held)
        cells = [html.escape(p["name"]), _disp_unit(u), _fmt(nom, u), _fmt(est, u),
                 _fmt(change, u), _fmt(std, u) if p.get("estimated") else "-",
                 f'<span class="{cls}">{html.escape(text)}</span>']
        if truth:
            cells.insert(5, _fmt(truth.get(p["name"]), u))
        row_cls = "" if p.get("estimated") else ' class="no"'
        rows.append(f"<tr{row_cls}>" + "".join(
            f'<td class="l">{x}</td>' if i in (0, len(cells) - 1) else f"<td>{x}</td>"
            for i, x in enumerate(cells)) + "</tr>")
    return ("<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows)
            + "</table>")


def _history(result: CalibrationView
             ) -> tuple[Array, list[str], Array, Array, list[int] | None]:
    """Parameter values per iteration (rows), stage names, cost, RMS and the solver's
    iteration number per row (0 at each pass's start; None when the history has none)."""
    hist = list(result.history or [])
    if not hist:
        theta = np.asarray(result.theta, dtype=float)
        return theta[None], ["final"], np.array([np.nan]), np.array([np.nan]), None
    H = np.array([np.asarray(h.theta, dtype=float) for h in hist])
    its: list[int] = [int(i) for h in hist if (i := getattr(h, "iteration", None)) is not None]
    return (H, [str(h.stage) for h in hist], np.array([float(h.cost) for h in hist]),
            np.array([float(h.rms) for h in hist]), its if len(its) == len(hist) else None)


def _passes_sentence(result: CalibrationView) -> str:
    """`` (2 solver passes: all; all, re-solved with new weights)`` when there are
    several, for the headline; empty otherwise."""
    from kincal.report.plots import solver_passes

    H, stages, cost, _, its = _history(result)
    if its is None or len(stages) < 2:
        return ""
    passes = solver_passes(stages, its, cost, H)
    if len(passes) < 2:
        return ""
    what: list[list[Any]] = []                  # [label, repeats], consecutive ones merged
    for p in passes:
        label = p.label.split(": ", 1)[1]
        if what and what[-1][0] == label:
            what[-1][1] += 1
        else:
            what.append([label, 1])
    return (f" in {len(passes)} solver passes ("
            + "; then ".join(f"{lab} (x{n})" if n > 1 else lab for lab, n in what)
            + "; see Convergence)")


def render_html(result: CalibrationView, comparisons: Sequence[ErrorComparison], title: str = "",
                inputs: Mapping[str, str] | None = None,
                truth: Mapping[str, float] | None = None, plots: bool = True,
                extra_sections: Sequence[str] = (), notice: str = "") -> str:
    """The report as one self-contained HTML document (images embedded).

    ``extra_sections`` are HTML fragments placed before the footer (e.g. the cross-bar
    staged-selection data selection and comparison tables); ``notice`` (plain text) is shown in red
    right under the title (e.g. a calibration that cannot be trusted).
    """
    from kincal.report import plots as rp

    d = result.to_dict()
    names = list(result.names)
    units = list(result.problem.units)
    chosen = set(result.estimated)
    est_mask = np.array([n in chosen for n in names], dtype=bool)
    title = title or f"kincal calibration of {result.robot.name}"
    parts = [_head(title, notice)]
    conv = '<span class="ok">converged</span>' if d.get("converged") else \
        '<span class="bad">did not converge</span>'
    parts.append(f"<p>{conv} after {d.get('iterations')} iterations"
                 f"{html.escape(_passes_sentence(result))}; "
                 f"{int(est_mask.sum())} parameters estimated; "
                 f"a-posteriori sigma0 = {d.get('sigma0', float('nan')):.3g} (1 = residuals at "
                 "the stated noise).</p>")
    parts.append(_inputs(inputs))
    if comparisons:
        parts.append("<h2>Errors before and after calibration</h2>")
        parts.append(_metric_table(comparisons))
    details = identifiability_details(result)
    parts.append("<h2>What the data can identify</h2><ul>" + "".join(
        f"<li>{html.escape(s)}</li>" for s in identifiability_summary(result)) + "</ul>"
        + (f"<details><summary>every fact of the analysis ({len(details)})</summary><ul>"
           + "".join(f"<li>{html.escape(s)}</li>" for s in details) + "</ul></details>"
           if details else ""))
    parts.append("<h2>Parameters</h2><p class='small'>lengths in mm, angles in degrees; "
                 "std is the 1-sigma uncertainty of the estimate (scaled by sigma0); grey "
                 "rows were held at their nominal values: <i>not estimated (by choice)</i> "
                 "for parameters left out by --free / --fix, <i>not identifiable</i> for "
                 "those the data cannot see.</p>")
    parts.append(_param_table(result, truth))
    if plots:
        H, stages, cost, rms, its = _history(result)
        if np.all(np.isfinite(cost)):
            parts.append("<h2>Convergence</h2><p class='small'>one segment per solver pass; "
                         "a dashed line where a pass starts. A re-solve with new weights "
                         "(the prior weighed by the noise scale sigma0) starts from the last "
                         "point with another cost: the cost may jump there. The iteration "
                         "axis ends at the count in the headline.</p>"
                         + _img(rp.convergence(cost, rms, stages, its, H), "convergence"))
        idx = np.flatnonzero(est_mask)
        parts.append("<h2>Estimated parameters against the iteration</h2><p class='small'>"
                     "dashed vertical lines: start of a solver pass; dotted horizontal lines: "
                     "true values (simulations only). A parameter that absorbs a dependent "
                     "one (see above) converges to their combination, not to its own true "
                     "value.</p>")
        for png in rp.parameter_history(H[:, idx], [names[i] for i in idx],
                                        [units[i] for i in idx], stages, truth,
                                        iterations=its):
            parts.append(_img(png, "parameter history"))
        parts.append(_error_plots(comparisons))
        C = result.correlation
        if C is not None and 1 < len(idx) <= 80:
            C = np.asarray(C, dtype=float)
            if C.shape == (len(names), len(names)):
                C = C[np.ix_(idx, idx)]
            if C.shape == (len(idx), len(idx)) and np.all(np.isfinite(C)):
                parts.append("<h2>Correlation of the estimates</h2>" + _img(
                    rp.correlation(C, [names[i] for i in idx]), "correlation"))
    parts.extend(extra_sections)
    parts.append(_solver_details(result, d))
    parts.append(_footer())
    return "\n".join(parts)


def _head(title: str, notice: str = "") -> str:
    """The document's head, the title and a notice in red (plain text) under it."""
    out = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
           f"</title><style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>")
    return out + (f"<p class='bad'><b>{html.escape(notice)}</b></p>" if notice else "")


def _inputs(inputs: Mapping[str, str] | None) -> str:
    if not inputs:
        return ""
    return "<table>" + "".join(
        f'<tr><th class="l">{html.escape(k)}</th><td class="l">{html.escape(str(v))}</td>'
        "</tr>" for k, v in inputs.items()) + "</table>"


def _error_plots(comparisons: Sequence[ErrorComparison]) -> str:
    """The before/after error histograms and the error of every measurement."""
    from kincal.report import plots as rp

    sets = [(c.title, c.before, c.after) for c in comparisons]
    if not sets:
        return ""
    return ("<h2>Error distributions</h2>" + _img(rp.error_histograms(sets), "histograms")
            + "<h2>Error of every measurement</h2>"
            + _img(rp.per_pose_errors(sets), "per-measurement errors"))


def _footer() -> str:
    from kincal._version import __version__

    now = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    return (f"<p class='small'>kincal {__version__}, {now}. Units inside kincal are SI "
            "(m, rad); the result JSON and robot files are SI.</p></body></html>")


def render_validation_html(title: str, comparisons: Sequence[ErrorComparison],
                           inputs: Mapping[str, str] | None = None,
                           sections: Sequence[str] = (), plots: bool = True) -> str:
    """The report of a validation (``kincal validate --report``), in the calibration
    report's family: the inputs, the before/after table of every held-out file, then
    ``sections`` (HTML fragments: held-out rows with the predicted accuracy, ISO 9283),
    then the error plots."""
    parts = [_head(title), _inputs(inputs)]
    if comparisons:
        parts += ["<h2>Errors before and after on held-out data</h2>",
                  _metric_table(comparisons)]
    parts.extend(sections)
    if plots:
        parts.append(_error_plots(comparisons))
    parts.append(_footer())
    return "\n".join(parts)


def _solver_details(result: CalibrationView, d: Mapping[str, Any]) -> str:
    """The solver's own account (stopping rule, stages, method), folded at the end."""
    rows = [("method", d.get("method")), ("loss", d.get("loss")),
            ("iterations", d.get("iterations")),
            ("stages", "; ".join(f"{s['stage']}: {len(s['estimated'])} parameters"
                                 for s in d.get("stages", [])) or "-"),
            ("stopping", result.message or "-")]
    return ("<details><summary>Solver details</summary><table>" + "".join(
        f'<tr><th class="l">{html.escape(str(k))}</th><td class="l">{html.escape(str(v))}'
        "</td></tr>" for k, v in rows) + "</table></details>")


def write_html_report(path: str | Path, result: CalibrationView,
                      comparisons: Sequence[ErrorComparison], title: str = "",
                      inputs: Mapping[str, str] | None = None,
                      truth: Mapping[str, float] | None = None,
                      extra_sections: Sequence[str] = ()) -> None:
    """Write :func:`render_html` to ``path`` atomically."""
    atomic_write_text(path, render_html(result, comparisons, title, inputs, truth,
                                        extra_sections=extra_sections))
