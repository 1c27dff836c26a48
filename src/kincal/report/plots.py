"""Figures of the calibration report (matplotlib, Agg backend, PNG bytes).

Every function returns PNG images as ``bytes`` so the HTML report can embed them
(base64) and the caller never touches a display.  Values are shown for people:
lengths in mm, angles in degrees; the data passed in is SI (m, rad).

Readable at a glance: figures are at most :data:`MAX_WIDTH_IN` inches wide at
:data:`DPI`, so the report (1168 px of content in a 1280 px window) shows them at their
own size, and no text is smaller than :data:`MIN_TEXT_PT` points (11 px at 100 dpi).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from kincal.units import display_scale

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

Array = NDArray[np.float64]

_BEFORE, _AFTER, _TRUTH = "#c0504d", "#1f77b4", "#2ca02c"


#: Resolution of the report's figures [dots per inch].
DPI = 100
#: Widest figure [in]: DPI * MAX_WIDTH_IN fits the report's 1168 px of content.
MAX_WIDTH_IN = 11.6
#: Smallest text [pt]: 8 pt at 100 dpi is 11.1 px.
MIN_TEXT_PT = 8.0
_TEXT: dict[RcKeyType, float] = {"font.size": 9.5, "axes.titlesize": 10.5, "axes.labelsize": 9.5,
         "xtick.labelsize": 9.0, "ytick.labelsize": 9.0, "legend.fontsize": 9.0,
         "figure.titlesize": 11.0, "figure.labelsize": 10.0}


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    plt.rcParams.update(_TEXT)
    return plt


def MaxNLocator(n: int, integer: bool = False) -> Any:  # noqa: N802 - matplotlib's name
    from matplotlib.ticker import MaxNLocator as _Max

    return _Max(n, integer=integer)


def _png(fig: Any, dpi: int = DPI) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    _plt().close(fig)
    return buf.getvalue()


def fit_layout(fig: Any) -> None:
    """Move the axes so that every tick label, axis label and title lies inside the
    figure (matplotlib's tight layout): a fixed layout clips long tick labels such as
    a leading minus sign or ``2x10^-2``."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # "not compatible with tight_layout": best effort
        fig.tight_layout(pad=0.6)


@dataclass(frozen=True)
class SolverPass:
    """One run of the solver within a calibration: a stage, or the re-solve of a stage.

    Attributes:
        rows: slice of the history rows of the pass (its start, then each iteration).
        x: (rows,) position on the iteration axis: the iterations counted over every
            pass, so the last one equals the calibration's iteration count (a pass starts
            where the previous one ended, at the same parameter values).
        stage: the stage's label.
        label: how the legend names the pass.
        new_weights: the pass restarted from the previous pass's last point with another
            cost (the noise-scale re-solve weighs the prior rows by sigma0): costs on
            either side of its start are not comparable.
    """

    rows: slice
    x: Array
    stage: str
    label: str
    new_weights: bool


def solver_passes(stages: Sequence[str], iterations: Sequence[int] | None = None,
                  cost: Array | None = None, history: Array | None = None) -> list[SolverPass]:
    """The passes of a solver history: a new pass where the stage changes or the
    iteration counter restarts at 0.  A restart of the same stage at the same parameter
    values with another cost is a re-solve with new weights.

    Args:
        stages: stage label per history row.
        iterations: the solver's iteration number per row (0 = a pass's start); None:
            the rows are consecutive iterations (a new pass only where the stage changes).
        cost: cost per row (to tell a re-weighting); history: (rows, P) parameter values.
    """
    n = len(stages)
    its = list(range(n)) if iterations is None else [int(i) for i in iterations]
    starts = [0] + [i for i in range(1, n) if stages[i] != stages[i - 1]
                    or (iterations is not None and its[i] == 0)]
    out: list[SolverPass] = []
    offset = 0.0
    for k, a in enumerate(starts):
        b = starts[k + 1] if k + 1 < len(starts) else n
        base = its[a]
        x = offset + np.array([its[i] - base for i in range(a, b)], dtype=float)
        again = k > 0 and stages[a] == stages[a - 1]
        same_point = history is not None and k > 0 and bool(
            np.allclose(history[a], history[a - 1], rtol=1e-12, atol=1e-15))
        reweighted = bool(again and same_point and cost is not None
                          and not math.isclose(float(cost[a]), float(cost[a - 1]),
                                               rel_tol=1e-9))
        label = (f"pass {k + 1}: " + ("re-solve, prior weighed by sigma0" if reweighted
                                      else f"{stages[a]} again" if again
                                      else f"stage {stages[a]}"))
        out.append(SolverPass(slice(a, b), x, stages[a], label, reweighted))
        offset = float(x[-1])
    return out


_PASS_COLOURS = (_AFTER, "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def _draw_passes(ax: Any, passes: Sequence[SolverPass], y: Array, log: bool,
                 legend: bool) -> None:
    """``y`` per history row, one segment per pass, a dashed line at each pass start."""
    for k, p in enumerate(passes):
        colour = _PASS_COLOURS[k % len(_PASS_COLOURS)]
        draw = ax.semilogy if log else ax.plot
        draw(p.x, y[p.rows], "o-", ms=3, lw=1.2, color=colour, label=p.label)
        if k:
            ax.axvline(p.x[0], color="0.45", lw=0.9, ls="--")
    if legend and len(passes) > 1:
        ax.legend(loc="best", fontsize=8)


def parameter_history(history: Array, names: Sequence[str], units: Sequence[str],
                      stages: Sequence[str] | None = None,
                      truth: Mapping[str, float] | None = None,
                      per_figure: int = 24, columns: int = 3,
                      iterations: Sequence[int] | None = None) -> list[bytes]:
    """One small plot per parameter: its value [mm / deg] against the iteration.

    The estimate at iteration 0 (nominal / initial guess) and after every accepted step;
    a dotted line marks the true value when known (simulations), a dashed vertical line
    the start of each solver pass (:func:`solver_passes`: a stage, or a re-solve).

    Args:
        history: (iterations + 1, P) parameter values [SI], row 0 the start.
        names, units: the P parameters.
        stages: stage name per row (for the stage boundaries).
        truth: ``{name: true value}`` [SI], optional.
        iterations: the solver's iteration number per row (0 at each pass's start).
    """
    plt = _plt()
    H = np.asarray(history, dtype=float)
    P = H.shape[1]
    passes = solver_passes(list(stages) if stages else ["all"] * H.shape[0],
                           iterations if stages else None)
    out = []
    for start in range(0, P, per_figure):
        idx = list(range(start, min(P, start + per_figure)))
        rows = math.ceil(len(idx) / columns)
        height = 2.2 * rows + 0.5
        fig, axes = plt.subplots(rows, columns, figsize=(min(3.8 * columns, MAX_WIDTH_IN),
                                                         height), squeeze=False)
        for ax in axes.flat[len(idx):]:
            ax.axis("off")
        for ax, k in zip(axes.flat, idx, strict=False):
            s, lab = display_scale(units[k])
            _draw_passes(ax, passes, H[:, k] * s, log=False, legend=False)
            if truth and names[k] in truth:
                ax.axhline(truth[names[k]] * s, ls=":", color=_TRUTH, lw=1.5)
            ax.set_title(names[k])
            ax.set_ylabel(f"[{lab}]")
            ax.ticklabel_format(axis="y", useOffset=False)
            v = H[:, k] * s
            span, mid = float(np.ptp(v)), float(np.mean(v))
            if span <= 1e-9 * max(1.0, abs(mid)):   # a constant: no 12-digit tick labels
                half = max(1e-6 * abs(mid), 1e-6)
                ax.set_ylim(mid - half, mid + half)
                ax.set_yticks([mid], [f"{mid:.6g}" if abs(mid) > 1e-9 else "0"])
            else:
                ax.yaxis.set_major_locator(MaxNLocator(3))
            ax.xaxis.set_major_locator(MaxNLocator(5, integer=True))
        fig.supxlabel("solver iteration (counted over all passes)")
        fit_layout(fig)
        out.append(_png(fig))
    return out


def convergence(cost: Array, rms: Array, stages: Sequence[str],
                iterations: Sequence[int] | None = None, history: Array | None = None
                ) -> bytes:
    """Cost (log scale) and RMS of the whitened residuals against the iteration.

    Each solver pass (:func:`solver_passes`) is its own segment, with a dashed line where
    it starts and its name in the legend: a re-solve with new weights (the noise scale)
    restarts at the previous pass's last point with another cost, so the cost may jump
    there without the fit getting worse.  The iteration axis counts the iterations of
    every pass: its last value is the calibration's iteration count."""
    plt = _plt()
    passes = solver_passes(stages, iterations, np.asarray(cost, dtype=float), history)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    _draw_passes(a1, passes, np.maximum(np.asarray(cost, dtype=float), 1e-300), log=True,
                 legend=True)
    a1.set_title("cost")
    a1.set_ylabel("0.5 sum w r² (whitened, dimensionless)")
    _draw_passes(a2, passes, np.maximum(np.asarray(rms, dtype=float), 1e-300), log=True,
                 legend=False)
    a2.axhline(1.0, color=_TRUTH, ls=":", lw=1.2)
    a2.set_title("RMS of whitened residuals (1 = at the noise level)")
    a2.set_ylabel("RMS (dimensionless)")
    total = int(round(passes[-1].x[-1])) if passes else 0
    for ax in (a1, a2):
        ax.set_xlabel(f"solver iteration ({total} over {len(passes)} "
                      f"pass{'es' * (len(passes) > 1)})")
        ax.xaxis.set_major_locator(MaxNLocator(8, integer=True))
    fit_layout(fig)
    return _png(fig)


def _quantities(sets: Sequence[tuple[str, Mapping[str, Array], Mapping[str, Array]]]
                ) -> list[str]:
    from kincal.report.metrics import error_keys

    keys = error_keys(*[b for _, b, _ in sets], *[a for _, _, a in sets])
    return [k for k in keys if all(k in b and k in a for _, b, a in sets if k in b or k in a)]


def _label(key: str) -> tuple[float, str]:
    from kincal.report.metrics import quantity

    name, f, unit = quantity(key)
    return f, f"{name} error [{unit}]"


def error_histograms(sets: Sequence[tuple[str, Mapping[str, Array], Mapping[str, Array]]]
                     ) -> bytes:
    """Histograms (log-spaced bins) of the errors before and after, one panel per data set.

    ``sets``: ``(label, errors before, errors after)`` with error arrays [m] / [rad].
    """
    def draw(ax: Any, b: Array, a: Array, lab: str) -> None:
        both = np.concatenate([b, a])
        pos = both[both > 0]
        lo = float(np.min(pos)) if pos.size else 1e-9
        hi = max(float(np.max(both, initial=0)), lo * 10)
        bins = np.geomspace(lo * 0.9, hi * 1.1, 41)
        ax.hist(np.maximum(b, lo), bins=bins, alpha=0.55, color=_BEFORE, label="before")
        ax.hist(np.maximum(a, lo), bins=bins, alpha=0.75, color=_AFTER, label="after")
        ax.set_xscale("log")
        ax.set_xlabel(lab)
        ax.set_ylabel("count (measurements)")

    return _before_after_grid(sets, draw, np.ravel)


def per_pose_errors(sets: Sequence[tuple[str, Mapping[str, Array], Mapping[str, Array]]]
                    ) -> bytes:
    """Error of every measurement before and after calibration (log scale), per data set."""
    def draw(ax: Any, b: Array, a: Array, lab: str) -> None:
        i = np.arange(len(b))
        ax.semilogy(i, np.maximum(b, 1e-9), ".", color=_BEFORE, label="before", ms=4)
        ax.semilogy(i, np.maximum(a, 1e-9), ".", color=_AFTER, label="after", ms=4)
        ax.set_xlabel("measurement (row)")
        ax.set_ylabel(lab)

    return _before_after_grid(sets, draw, _per_row)


def _before_after_grid(sets: Sequence[tuple[str, Mapping[str, Array], Mapping[str, Array]]],
                       draw: Callable[[Any, Array, Array, str], None],
                       reduce: Callable[[Array], Array]) -> bytes:
    """One panel per (error kind, data set): ``draw(ax, before, after, axis label)`` with
    ``reduce(|error|)`` in display units (mm, deg ...); kinds missing from a set stay blank."""
    plt = _plt()
    keys = _quantities(sets)
    fig, axes = plt.subplots(len(keys), len(sets), squeeze=False,
                             figsize=(min(4.6 * len(sets), MAX_WIDTH_IN), 3.1 * len(keys)))
    for r, key in enumerate(keys):
        scale, lab = _label(key)
        for c, (name, before, after) in enumerate(sets):
            ax = axes[r, c]
            if key not in before or key not in after:
                ax.axis("off")
                continue
            draw(ax, reduce(np.abs(before[key])) * scale, reduce(np.abs(after[key])) * scale,
                 lab)
            ax.set_title(name)
            ax.legend()
    fit_layout(fig)
    return _png(fig)


def _per_row(e: Array) -> Array:
    """One error per row: RMS over the markers of a row when there are several."""
    e = np.asarray(e, dtype=float)
    return np.sqrt(np.mean(e.reshape(len(e), -1) ** 2, axis=1)) if e.ndim > 1 else e


def correlation(C: Array, names: Sequence[str]) -> bytes:
    """Heat map of the estimated parameters' correlation matrix (every name labelled
    while they fit at the smallest text size, else every k-th)."""
    plt = _plt()
    n = len(names)
    row_in = MIN_TEXT_PT * 1.35 / 72                       # one label's height [in]
    size = min(max(5.0, 2.8 + row_in * n), MAX_WIDTH_IN - 1.2)
    step = max(1, math.ceil(n * row_in / (size - 2.8)))
    fig, ax = plt.subplots(figsize=(size + 1.2, size))
    im = ax.imshow(np.asarray(C), vmin=-1, vmax=1, cmap="RdBu_r")
    ticks = list(range(0, n, step))
    ax.set_xticks(ticks, [names[i] for i in ticks], rotation=90, fontsize=MIN_TEXT_PT)
    ax.set_yticks(ticks, [names[i] for i in ticks], fontsize=MIN_TEXT_PT)
    bar = fig.colorbar(im, ax=ax, shrink=0.8)
    bar.set_label("correlation (dimensionless, -1 to 1)")
    ax.set_xlabel("estimated parameter (name)")
    ax.set_ylabel("estimated parameter (name)")
    ax.set_title("correlation of the estimates" + (f" (every {step}th name)" if step > 1
                                                   else ""))
    fit_layout(fig)
    return _png(fig)
