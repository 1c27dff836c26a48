"""The calibration report's extra HTML sections: the staged-selection procedure and the
artifact figures.

* :func:`artifact_figures` - the bar-length figures of every training artifact
  block, rendered in memory (PNG bytes and the path next to the report);
* :func:`staged_selection_section_html` - the staged-selection procedure: stages, kept and discarded
  placements with their condition numbers, the comparison with one-stage LM;
* :func:`figures_section_html` - figures 4 and 5 embedded as a section;
* :func:`trust_section_html` - can the calibration be trusted: the verdict, the
  tolerances, the parameters the prior holds, the model selection table.

:func:`kincal.workflow.flow.render_outputs` hands these sections to
:func:`kincal.report.html.render_html`; :mod:`kincal.workflow.flow` re-exports the two HTML
functions.  The report shows mm and degrees.
"""

from __future__ import annotations

import base64
import html
import math
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from kincal.units import display_scale
from kincal.workflow.result import FlowResult

__all__ = ["artifact_figures", "staged_selection_section_html", "figures_section_html",
           "trust_section_html"]


def artifact_figures(flow: FlowResult, report: str) -> dict[str, tuple[str, bytes]]:
    """The bar-length figures of every training artifact block, rendered in memory:
    ``{key: (path next to the report, PNG bytes)}``."""
    from kincal.measure.artifacts.model import ArtifactMeasurement

    blocks = [b for b in flow.train if isinstance(b, ArtifactMeasurement)]
    if not blocks or flow.nominal is None:
        return {}
    from kincal.report.artifact_plots import save_length_error_figures

    folder, stem = Path(report).parent, Path(report).stem
    out: dict[str, tuple[str, bytes]] = {}
    with tempfile.TemporaryDirectory(prefix="kincal-figures-") as tmp:
        for b in blocks:
            prefix = stem if len(blocks) == 1 else f"{stem}_{b.name}"
            made = save_length_error_figures(b, flow.nominal, flow.result.robot, tmp,
                                             flow.before.get(b.name), flow.after.get(b.name),
                                             prefix=prefix)
            for key, p in made.items():
                tag = key if len(blocks) == 1 else f"{b.name}.{key}"
                out[tag] = (str(folder / Path(p).name), Path(p).read_bytes())
    return out


def _fmt_cond(v: float | None) -> str:
    """A condition number; None / inf (JSON null) is a rank-deficient matrix."""
    return "inf" if v is None or not math.isfinite(v) else f"{v:.4g}"


def _rms_cells(summary: Mapping[str, Any], keys: Sequence[str]) -> str:
    from kincal.report.metrics import quantity

    cells = []
    for k in keys:
        v = summary.get(k)
        _, f, _ = quantity(k[4:])
        cells.append(f"<td>{'-' if v is None else f'{v * f:.4f}'}</td>")
    return "".join(cells)


def staged_selection_section_html(info: Any, figures: Mapping[str, tuple[str, bytes]] | None = None,
                        units: Mapping[str, str] | None = None) -> str:
    """The report's staged-selection section: the procedure, kept and discarded placements with
    their condition numbers, the comparison with one-stage LM and figures 4 and 5.

    Args:
        info: :class:`~kincal.identify.staged_selection.StagedSelectionRecord` (or its
            ``to_dict()``).
        figures: ``{key: (file, PNG bytes)}`` embedded at the end.
        units: ``{parameter: "m" | "rad"}`` to show lengths in mm and angles in deg.
    """
    d = info.to_dict() if hasattr(info, "to_dict") else dict(info)
    e = html.escape
    parts = ["<h2>The staged-selection procedure</h2>"]
    how = "one pass" if d["cycles"] == 1 else f"{d['cycles']} cycles"
    parts.append(f"<p>{how} through {len(d['stages'])} stage(s) (one pass = the original procedure "
                 "literally; more: repeated until no point moves): "
                 + "; then ".join(e(f"{s['stage']} ({len(s['candidates'])} candidates)")
                                  for s in d["stages"])
                 + f". Point-correction tolerance {d['tolerance_m'] * 1e3:g} mm; "
                 + ("converged" if d["converged"] else "<span class='bad'>NOT converged</span>")
                 + (f" (last cycle moved the points by {d['cycle_corrections_m'][-1] * 1e3:.3g}"
                    " mm)." if d["cycle_corrections_m"] else ".") + "</p>")
    sel = d["selection"]
    if d["condition_growth"] is None:
        parts.append("<p>No data selection: every placement kept.</p>")
    else:
        parts.append(f"<h3>Data selection by the condition number</h3><p>A placement is "
                     f"discarded when it makes the condition number of the scaled "
                     f"identification matrix grow by more than a factor "
                     f"{d['condition_growth']:g}. Kept {len(d['kept'])} of "
                     f"{len(d['kept']) + len(d['discarded'])} placements"
                     + (": discarded " + e(", ".join(f"{x['block']}:{x['placement']}"
                                                     for x in d["discarded"]))
                        if d["discarded"] else "") + ".</p>")
        rows = "".join(
            f"<tr class='{'' if s['kept'] else 'no'}'><td class='l'>{e(s['block'])}</td>"
            f"<td class='l'>{e(str(s['placement']))}</td><td>{_fmt_cond(s['previous'])}</td>"
            f"<td>{_fmt_cond(s['condition'])}</td>"
            f"<td class='l'>{'kept' if s['kept'] else 'discarded'}</td></tr>" for s in sel)
        parts.append("<table><tr><th class='l'>block</th><th class='l'>placement</th>"
                     "<th>cond before</th><th>cond with it</th><th class='l'>decision</th>"
                     f"</tr>{rows}</table><p class='small'>cond = inf while the matrix is "
                     "rank deficient (every placement is kept until it is not).</p>")
    comp = d.get("comparison")
    if comp:
        runs = [("staged selection", comp["staged_selection"]), ("one-stage LM, same parameters",
                                              comp["one_stage"]),
                ("one-stage LM, automatic parameters", comp["automatic"])]
        keys = sorted({k for _, s in runs for k in s if k.startswith("rms_")})
        from kincal.report.metrics import quantity

        head = "".join(f"<th>RMS {e(quantity(k[4:])[0])} [{e(quantity(k[4:])[2])}]</th>"
                       for k in keys)
        body = "".join(f"<tr><td class='l'>{e(n)}</td><td>{s['estimated']}</td>"
                       f"<td>{s['sigma0']:.4g}</td><td class='l'>"
                       f"{'yes' if s['converged'] else 'no'}</td>{_rms_cells(s, keys)}</tr>"
                       for n, s in runs)
        same = comp["same_parameters"]
        parts.append("<h3>Comparison with one-stage Levenberg-Marquardt (same data)</h3>"
                     "<table><tr><th class='l'>solver</th><th>estimated</th><th>sigma0</th>"
                     f"<th class='l'>converged</th>{head}</tr>{body}</table>"
                     f"<p>Same parameters: the largest difference is "
                     f"{same['max_sigmas']:.3g} standard errors"
                     + (f" ({e(same['worst'])})" if same["worst"] else "") + ".</p>")
        if same["rows"]:
            compared: list[str] = []
            for r in same["rows"]:
                unit = (units or {}).get(r["name"], "")
                f, u = display_scale(unit) if unit else (1.0, "SI")
                compared.append(f"<tr><td class='l'>{e(r['name'])}</td><td>{r['a'] * f:.5f}</td>"
                            f"<td>{r['b'] * f:.5f}</td><td>{r['diff'] * f:.2e}</td>"
                            f"<td class='l'>{u}</td><td>{r['sigmas']:.3g}</td></tr>")
            parts.append("<table><tr><th class='l'>parameter</th><th>staged selection</th>"
                         "<th>one-stage</th><th>difference</th><th class='l'>unit</th>"
                         f"<th>in std</th></tr>{''.join(compared)}</table>")
    if figures:
        parts.append(figures_section_html(figures, heading="h3"))
    return "\n".join(parts)


def figures_section_html(figures: Mapping[str, tuple[str, bytes]], heading: str = "h2") -> str:
    """The bar-length figures (``{key: (file, PNG bytes)}``) as a report section."""
    e = html.escape
    parts = [f"<{heading}>Artifact lengths from the joint readings</{heading}>"
             "<p class='small'>The length errors of the artifact seen through the nominal "
             "and the calibrated model, on the same scale (then zoomed); the files are next "
             "to the report.</p>"]
    for key, (path, png) in figures.items():
        b64 = base64.b64encode(png).decode("ascii")
        parts.append(f"<p class='small'>{e(key)} ({e(Path(path).name)})</p>"
                     f"<img alt='{e(key)}' src='data:image/png;base64,{b64}'>")
    return "\n".join(parts)


def _si(value: float, unit: str, digits: int = 3) -> str:
    from kincal.identify.checks import show_quantity

    return show_quantity(value, unit, digits)


def heldout_section_html(heldout: Sequence[Any], accuracy: Any = None) -> str:
    """The predicted accuracy (how it is computed) and the held-out files measured
    against it, one row each, with their protocol and the 'before' of the protocols used;
    their extrapolation sentences and artifact metrics.  Shared by the calibration report
    and ``kincal validate --report``."""
    e = html.escape
    parts: list[str] = []
    acc = accuracy
    if acc is not None:
        parts.append(f"<h3>Predicted accuracy</h3><p>Where the calibrated model is used, "
                     f"its predicted error at the measured point is sqrt(trace(G C G^T) + "
                     f"floor^2): C the covariance of the estimated parameters, the floor "
                     f"{acc.floor_m * 1e3:.3g} mm (what no parameter explains, from the "
                     f"{e(acc.floor_source)}). Outside the training joint ranges or the "
                     "convex hull of the training positions the model extrapolates.</p>")
    if heldout:
        from kincal.workflow.heldout import before_lines

        rows = []
        for f in heldout:
            pm = f.prediction_metrics() or {}

            def mm(v: float | None) -> str:
                return "-" if v is None else f"{v * 1e3:.4f}"

            rows.append(
                f"<tr><td class='l'>{e(f.file)}</td><td class='l'>{e(f.protocol)}</td>"
                f"<td>{pm.get('n', '')}</td><td>{pm.get('outside_n', '')}</td>"
                f"<td>{mm(pm.get('measured_rms_inside_m'))}</td>"
                f"<td>{mm(pm.get('predicted_rms_inside_m'))}</td>"
                f"<td>{mm(pm.get('measured_rms_outside_m'))}</td>"
                f"<td>{mm(pm.get('predicted_rms_outside_m'))}</td>"
                f"<td>{pm.get('worse_than_nominal', '')}</td>"
                f"<td class='l'>{e(f.note)}</td></tr>")
        parts.append("<h3>Held-out files: measured against predicted</h3><table><tr>"
                     "<th class='l'>file</th><th class='l'>protocol</th><th>poses</th>"
                     "<th>outside region</th><th>measured RMS inside [mm]</th>"
                     "<th>predicted inside</th><th>measured RMS outside [mm]</th>"
                     "<th>predicted outside</th><th>predicted worse than nominal</th>"
                     f"<th class='l'>protocol note</th></tr>{''.join(rows)}</table>"
                     + "".join(f"<p class='small'>{e(x)}</p>" for x in
                             before_lines(f.protocol for f in heldout if f.before)))
        for f in heldout:
            if f.prediction is not None:
                parts.append("<ul>" + "".join(f"<li>{e(f.file)}: {e(x)}</li>"
                                              for x in f.prediction.summary()) + "</ul>")
            if f.artifact is not None:
                a = f.artifact
                rows = [f"<tr><td class='l'>spread {e(k)}</td>"
                        f"<td>{a['before']['spread_m'][k] * 1e3:.3f}</td><td>{v * 1e3:.3f}</td>"
                        "</tr>" for k, v in a["after"]["spread_m"].items()]
                rows += [f"<tr><td class='l'>distance error {e(da['placement'])} "
                         f"{e(da['label'])}</td><td>{db['error_m'] * 1e3:+.3f}</td>"
                         f"<td>{da['error_m'] * 1e3:+.3f}</td></tr>"
                         for db, da in zip(a["before"]["distances"], a["after"]["distances"],
                                           strict=True)]
                parts.append(f"<h4>{e(f.file)}: artifact metrics (before = the plain nominal "
                             "robot)</h4><table><tr><th class='l'>socket / distance</th>"
                             f"<th>before [mm]</th><th>after [mm]</th></tr>{''.join(rows)}"
                             "</table>")
    return "\n".join(parts)


def iso9283_section_html(doc: Mapping[str, Any]) -> str:
    """The ISO 9283 figures of ``kincal validate --iso9283`` (its JSON ``iso9283``: per
    file, per position AP and RP before and after, and the P2-P4 distance accuracy AD and
    repeatability RD), as tables in mm and arcsec."""
    e = html.escape
    arcsec = 180.0 / math.pi * 3600.0

    def mm(v: Any) -> str:
        return "-" if v is None or not math.isfinite(float(v)) else f"{float(v) * 1e3:.4f}"

    def sec(v: Sequence[float]) -> str:
        return ", ".join(f"{x * arcsec:.1f}" for x in v)

    parts = ["<h2>ISO 9283 acceptance figures</h2><p class='small'>Per position (rows at "
             "the same joint values): pose accuracy AP = distance from the mean attained "
             "position to the commanded one, pose repeatability RP = mean + 3 standard "
             "deviations of the distances to the mean attained position (ISO 9283, 7.2); "
             "orientation AP a, b, c and RP +-3 S in arcsec about the base axes (pose data "
             "only). "
             "Before: the nominal robot; after: the robot validated.</p>"]
    for name, entry in doc.items():
        after = entry.get("after", [])
        before = {f["position"]: f for f in entry.get("before", [])}
        angles = any(math.isfinite(x) for f in after for x in f.get("RP_abc_rad", []))
        head = ["position", "cycles"] + (["AP before [mm]"] if before else []) + \
            ["AP [mm]", "RP [mm]"] + (["AP a, b, c [arcsec]", "RP a, b, c [arcsec]"]
                                      if angles else [])
        rows = []
        for f in after:
            cells = [e(str(f["position"])), str(f["cycles"])]
            if before:
                cells.append(mm(before.get(f["position"], {}).get("AP_m")))
            cells += [mm(f["AP_m"]), mm(f["RP_m"])]
            if angles:
                cells += [sec(f.get("AP_abc_rad", [])), sec(f.get("RP_abc_rad", []))]
            rows.append("<tr>" + "".join(f"<td class='l'>{c}</td>" if i == 0 else f"<td>{c}</td>"
                                         for i, c in enumerate(cells)) + "</tr>")
        dist = []
        for label in ("before", "after"):
            d = entry.get(f"distance_P2_P4_{label}")
            if d:
                dist.append(f"<li>distance P2-P4 ({label}): AD {mm(d.get('AD_m'))} mm, RD "
                            f"{mm(d.get('RD_m'))} mm over {mm(d.get('D_mean_m'))} mm</li>")
        parts.append(f"<h3>{e(name)}</h3><table><tr>"
                     + "".join(f"<th class='l'>{h}</th>" if i == 0 else f"<th>{h}</th>"
                               for i, h in enumerate(head))
                     + f"</tr>{''.join(rows)}</table>"
                     + (f"<ul>{''.join(dist)}</ul>" if dist else ""))
    return "\n".join(parts)


def trust_section_html(flow: FlowResult) -> str:
    """The report's section "Can this calibration be trusted?": the verdict (convergence,
    estimates within 10 tolerances), the prior (tolerances, noise scale), the parameters
    the prior holds with what would identify them, and the ``--select auto`` table."""
    e = html.escape
    res = flow.result
    parts = ["<h2>Can this calibration be trusted?</h2>"]
    v = flow.verdict
    if v is not None:
        if v.trusted:
            parts.append(f"<p class='ok'>Converged; every estimate lies within "
                         f"{v.bound:g} tolerances of its nominal value.</p>")
        else:
            parts.append("<ul>" + "".join(f"<li class='bad'>{e(r)}</li>" for r in v.reasons(50))
                         + "</ul>")
    tol = flow.tolerances
    if tol is not None:
        how = (f"maximum a-posteriori: Gaussian priors centred on the nominal values, "
               f"{tol.scale:g} x the tolerances" if tol.use_prior else "plain least squares "
               "(no prior)")
        noise = (f"; the noise scale sigma0 = {res.sigma0:.3g} (residual / stated sigma) was "
                 "estimated before the prior was weighed"
                 if getattr(res, "noise_scale_estimated", False) else "")
        srcs: dict[str, int] = {}
        for src in tol.source.values():
            srcs[src] = srcs.get(src, 0) + 1
        parts.append(f"<p>Estimate: {e(how)}{e(noise)}. Tolerances of "
                     f"{len(tol.sigma)} parameters ("
                     + e(", ".join(f"{k}: {n}" for k, n in srcs.items())) + ").</p>")
    if flow.weak:
        rows = "".join(
            f"<tr><td class='l'>{e(w.name)}</td><td>{_si(w.data_std, w.unit)}</td>"
            f"<td>{_si(w.prior_std, w.unit)}</td><td class='l'>{e(w.sentence())}</td></tr>"
            for w in flow.weak)
        parts.append("<h3>Held by the prior (weakly identifiable)</h3><table><tr>"
                     "<th class='l'>parameter</th><th>data alone (1σ)</th><th>prior (1σ)</th>"
                     f"<th class='l'>what would identify it</th></tr>{rows}</table>")
    parts.append(heldout_section_html(flow.heldout, flow.accuracy))
    sel = flow.selection
    if sel is not None:
        from kincal.identify.selection import RULE
        from kincal.report.metrics import quantity

        name, f, unit = quantity(sel.kind) if sel.kind else ("error", 1.0, "")
        rows = "".join(
            f"<tr class='{'' if sel.trusted[i] else 'no'}'><td class='l'>{e(c.label)}</td>"
            f"<td>{'-' if not math.isfinite(sel.rms[i]) else f'{sel.rms[i] * f:.4f}'}</td>"
            f"<td class='l'>{'chosen' if i == sel.chosen else e(sel.reasons[i])}</td></tr>"
            for i, c in enumerate(sel.candidates))
        parts.append(f"<h3>Model selection ({sel.folds}-fold cross-validation on the training "
                     f"files)</h3><p>{e(sel.split)}. Rule: {e(RULE)}.</p><table><tr>"
                     f"<th class='l'>model</th><th>CV RMS {e(name)} [{e(unit)}]</th>"
                     f"<th class='l'>status</th></tr>{rows}</table>"
                     + "".join(f"<p class='small'>{e(n)}</p>" for n in sel.notes))
    return "\n".join(parts)
