"""The fleet page: one HTML file with the accuracy of every robot, the flagged robots and
the history of the parameters that moved.

:func:`fleet_page` renders, from the history (:class:`~kincal.fleet.store.HistoryStore`)
and the drift comparisons (:func:`~kincal.fleet.drift.fleet_drift`):

* a summary (robots, sessions, failed sessions with their reasons);
* accuracy per robot: the latest calibration's position RMS on its training data, on
  held-out files and by cross-validation where the manifest asked for them, and the
  previous calibration's RMS on the latest data (a plot, then the table);
* the flagged robots with the parameters that moved (value, σ, what it suggests);
* for each flagged robot, every moved parameter against the session date with its
  ±2σ band (all of the robot's sessions).

Images are embedded PNG (matplotlib); values are shown in mm and degrees.
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from kincal._version import __version__
from kincal.report.html import _CSS, _img
from kincal.report.plots import _plt, _png, fit_layout
from kincal.units import display_scale

__all__ = ["fleet_page", "accuracy_plot", "history_plot"]

_MAX_HISTORY_ROBOTS = 30


def _mm(v: float | None) -> str:
    return "-" if v is None else f"{v * 1e3:.4f}"


def accuracy_plot(serials: Sequence[str], series: Mapping[str, Sequence[float | None]],
                  flagged: set[str]) -> bytes:
    """Position RMS [mm] per robot (sorted by the first series), one marker per series;
    flagged robots' labels in red."""
    plt = _plt()
    first = next(iter(series.values()))
    order = sorted(range(len(serials)), key=lambda i: (first[i] is None, first[i] or 0.0))
    width = min(16.0, max(6.0, 0.18 * len(serials) + 2))
    fig, ax = plt.subplots(figsize=(width, 3.6))
    for (label, values), marker in zip(series.items(), "os^vD", strict=False):
        y = np.array([np.nan if (v := values[i]) is None else v * 1e3 for i in order])
        if np.isfinite(y).any():
            ax.plot(np.arange(len(order)), y, marker, ms=4, label=label)
    ax.set_ylabel("position RMS [mm]")
    _plain_log_axis(ax)
    if len(serials) <= 60:
        ax.set_xticks(np.arange(len(order)))
        ax.set_xticklabels([serials[i] for i in order], rotation=90, fontsize=7)
        for t, i in zip(ax.get_xticklabels(), order, strict=True):
            if serials[i] in flagged:
                t.set_color("#c0504d")
    ax.set_xlabel(f"robot (serial number; {len(serials)} robots sorted by training RMS"
                  + ("; flagged in red)" if len(serials) <= 60 and flagged else ")"))
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fit_layout(fig)
    return _png(fig)


def _plain_log_axis(ax: Any) -> None:
    """A log y axis labelled with plain numbers (``0.02``, ``0.05``, ``0.1``), not
    ``2x10^-2``: within a decade matplotlib labels the minor ticks in powers of ten, which
    read badly and were clipped."""
    from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

    ax.set_yscale("log")
    lo, hi = ax.get_ylim()
    decades = np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
    nice = [m * 10.0 ** d for d in decades for m in (1.0, 2.0, 5.0) if lo <= m * 10.0 ** d <= hi]
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)) if len(nice) >= 3
                               else MaxNLocator(7, steps=[1, 2, 2.5, 5, 10]))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.4g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())


def history_plot(serial: str, records: Sequence[Mapping[str, Any]], names: Sequence[str]
                 ) -> bytes:
    """Each parameter of ``names`` against the session date: estimate ±2σ."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(names), figsize=(3.4 * len(names) + 0.6, 2.8),
                             squeeze=False)
    dates = [r["date"] for r in records]
    for ax, name in zip(axes[0], names, strict=True):
        vals, errs, unit = [], [], "m"
        for r in records:
            p = next((p for p in r["parameters"] if p["name"] == name), None)
            vals.append(np.nan if p is None else p["estimate"])
            errs.append(np.nan if p is None or p["std"] is None else p["std"])
            unit = p["unit"] if p is not None else unit
        f, u = display_scale(unit)
        ax.errorbar(np.arange(len(dates)), np.array(vals) * f, yerr=2 * np.array(errs) * f,
                    fmt="o-", ms=4, capsize=3)
        ax.set_xticks(np.arange(len(dates)))
        ax.set_xticklabels(dates, rotation=30, fontsize=7)
        ax.set_title(f"{serial}: {name}", fontsize=9)
        ax.set_ylabel(f"{name} [{u}] (±2σ)", fontsize=8)
        ax.set_xlabel("session (date)", fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.grid(alpha=0.3)
    fit_layout(fig)
    return _png(fig)


def fleet_page(summaries: Sequence[Mapping[str, Any]], drifts: Sequence[Any],
               histories: Mapping[str, Sequence[Mapping[str, Any]]], title: str = "",
               false_alarm: float = 1e-3) -> str:
    """The fleet page as one HTML document (see the module docstring).

    Args:
        summaries: every record without parameters (:meth:`HistoryStore.summaries`).
        drifts: :class:`~kincal.fleet.drift.Drift` of every robot with two dates.
        histories: full records (with parameters) of the flagged robots, oldest first.
    """
    esc = html.escape
    latest: dict[str, Mapping[str, Any]] = {}
    for s in summaries:
        if s["status"] == "ok":
            latest[s["serial"]] = s
    serials = sorted({s["serial"] for s in summaries})
    failed = [s for s in summaries if s["status"] != "ok"]
    by_serial = {d.serial: d for d in drifts}
    flagged = [d for d in drifts if d.flagged]
    fleets = sorted({s.get("fleet") or "" for s in summaries} - {""})
    name = title or ", ".join(fleets) or "fleet"
    dates = sorted({s["date"] for s in summaries})
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(name)}: kincal "
             f"fleet</title><style>{_CSS}td.l:first-child{{white-space:nowrap}}</style>"
             "</head><body>",
             f"<h1>{esc(name)}: calibration history</h1>",
             f"<p>{len(serials)} robots, {len(summaries)} calibration records"
             + (f", sessions {esc(dates[0])} to {esc(dates[-1])}" if dates else "")
             + f". <b class='{'bad' if flagged else 'ok'}'>{len(flagged)} robot(s) flagged "
             f"for drift</b> of {len(drifts)} with two calibrated sessions (false-alarm "
             f"probability {false_alarm:g} per robot); "
             f"<b class='{'bad' if failed else 'ok'}'>{len(failed)} failed session(s)</b>."
             "</p>"]
    if flagged:
        parts.append("<h2>Flagged robots</h2><table><tr><th class='l'>robot</th>"
                     "<th class='l'>sessions</th><th>max |z|</th><th>χ² / dof</th>"
                     "<th>p</th><th>RMS latest [mm]</th><th>previous model on latest "
                     "data [mm]</th><th class='l'>what moved</th></tr>")
        for d in flagged:
            parts.append(
                f"<tr><td class='l'>{esc(d.serial)}</td><td class='l'>{esc(d.previous[1])} "
                f"→ {esc(d.latest[1])}</td><td>{d.z_max:.1f}</td>"
                f"<td>{d.chi2:.1f} / {d.dof}</td><td>{d.p_value:.2g}</td>"
                f"<td>{_mm(d.rms_latest_m)}</td><td>{_mm(d.rms_previous_model_m)}</td>"
                f"<td class='l'>{'<br>'.join(esc(n) for n in d.notes())}</td></tr>")
        parts.append("</table>")
    if failed:
        parts.append("<h2>Failed sessions</h2><table><tr><th class='l'>robot</th>"
                     "<th class='l'>date</th><th class='l'>status</th>"
                     "<th class='l'>reason</th></tr>")
        for s in failed:
            parts.append(f"<tr><td class='l'>{esc(s['serial'])}</td><td class='l'>"
                         f"{esc(s['date'])}</td><td class='l bad'>{esc(s['status'])}</td>"
                         f"<td class='l'>{esc(s.get('reason') or '')}</td></tr>")
        parts.append("</table>")
    if latest:
        order = sorted(latest)
        prev = [by_serial[s].rms_previous_model_m if s in by_serial else None for s in order]
        series = {"training": [latest[s].get("rms_train_m") for s in order],
                  "held-out files": [latest[s].get("rms_validation_m") for s in order],
                  "cross-validation": [latest[s].get("rms_cv_m") for s in order],
                  "previous calibration on latest data": prev}
        parts.append("<h2>Accuracy per robot (latest calibration)</h2>")
        parts.append(_img(accuracy_plot(order, series, {d.serial for d in flagged}),
                          "position RMS per robot"))
        present = [k for k, label in (("rms_train_m", "training"),
                                      ("rms_validation_m", "held-out"), ("rms_cv_m", "CV"))
                   if any(latest[s].get(k) is not None for s in order)]
        heads = {"rms_train_m": "training", "rms_validation_m": "held-out", "rms_cv_m": "CV"}
        parts.append("<table><tr><th class='l'>robot</th><th class='l'>latest session</th>"
                     + "".join(f"<th>{heads[k]} [mm]</th>" for k in present)
                     + "<th>previous model [mm]</th><th>max |z|</th><th class='l'>drift</th>"
                     "</tr>")
        for serial, previous in zip(order, prev, strict=True):
            rec, d = latest[serial], by_serial.get(serial)
            mark = ("<span class='bad'>flagged</span>" if d is not None and d.flagged else
                    "no" if d is not None else "<span class='small'>one session</span>")
            parts.append(
                f"<tr><td class='l'>{esc(serial)}</td><td class='l'>{esc(rec['date'])}</td>"
                + "".join(f"<td>{_mm(rec.get(k))}</td>" for k in present)
                + f"<td>{_mm(previous)}</td><td>{'-' if d is None else f'{d.z_max:.1f}'}</td>"
                f"<td class='l'>{mark}</td></tr>")
        parts.append("</table>")
    shown = [d for d in flagged if d.serial in histories][:_MAX_HISTORY_ROBOTS]
    if shown:
        parts.append("<h2>Parameter history of the flagged robots</h2><p class='small'>"
                     "estimate ±2σ at each calibrated session</p>")
        for d in shown:
            parts.append(_img(history_plot(d.serial, histories[d.serial],
                                           [c.name for c in d.moved[:4]]),
                              f"parameter history of {d.serial}"))
    parts.append(f"<p class='small'>kincal {esc(__version__)} · kincal fleet drift</p>"
                 "</body></html>")
    return "\n".join(parts)
