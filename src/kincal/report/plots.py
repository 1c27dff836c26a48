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


def _layout(fig: Any) -> None:
    """A fixed layout (tight_layout costs seconds on many axes)."""
    fig.subplots_adjust(left=0.09, right=0.97, bottom=0.16, top=0.9, hspace=0.45, wspace=0.3)


def parameter_history(history: Array, names: Sequence[str], units: Sequence[str],
                      stages: Sequence[str] | None = None,
                      truth: Mapping[str, float] | None = None,
                      per_figure: int = 24, columns: int = 3) -> list[bytes]:
    """One small plot per parameter: its value [mm / deg] against the iteration.

    The estimate at iteration 0 (nominal / initial guess) and after every accepted step;
    a dotted line marks the true value when known (simulations), vertical lines the
    start of each stage.

    Args:
        history: (iterations + 1, P) parameter values [SI], row 0 the start.
        names, units: the P parameters.
        stages: stage name per row (for the stage boundaries).
        truth: ``{name: true value}`` [SI], optional.
    """
    plt = _plt()
    H = np.asarray(history, dtype=float)
    P = H.shape[1]
    it = np.arange(H.shape[0])
    bounds = [i for i in range(1, len(stages or [])) if stages[i] != stages[i - 1]] \
        if stages else []
    out = []
    for start in range(0, P, per_figure):
        idx = list(range(start, min(P, start + per_figure)))
        rows = math.ceil(len(idx) / columns)
        height = 2.2 * rows + 0.5
        fig, axes = plt.subplots(rows, columns, figsize=(min(3.8 * columns, MAX_WIDTH_IN),
                                                         height), squeeze=False)
        fig.subplots_adjust(left=0.08, right=0.98, bottom=0.5 / height + 0.02,
                            top=1 - 0.3 / height, hspace=0.65, wspace=0.45)
        for ax in axes.flat[len(idx):]:
            ax.axis("off")
        for ax, k in zip(axes.flat, idx, strict=False):
            s, lab = display_scale(units[k])
            ax.plot(it, H[:, k] * s, "o-", ms=3, lw=1.2, color=_AFTER)
            if truth and names[k] in truth:
                ax.axhline(truth[names[k]] * s, ls=":", color=_TRUTH, lw=1.5)
            for b in bounds:
                ax.axvline(b - 0.5, color="0.6", lw=0.8, ls="--")
            ax.set_title(names[k])
            ax.set_ylabel(lab)
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
        fig.supxlabel("iteration")
        out.append(_png(fig))
    return out


def convergence(cost: Array, rms: Array, stages: Sequence[str]) -> bytes:
    """Cost (log scale) and RMS of the whitened residuals against the iteration."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4))
    it = np.arange(len(cost))
    a1.semilogy(it, np.maximum(cost, 1e-300), "o-", ms=3, color=_AFTER)
    a1.set_title("cost 0.5 |r|^2 (whitened)")
    a2.semilogy(it, np.maximum(rms, 1e-300), "o-", ms=3, color=_AFTER)
    a2.axhline(1.0, color=_TRUTH, ls=":", lw=1.2)
    a2.set_title("RMS of whitened residuals (1 = at the noise level)")
    for ax in (a1, a2):
        ax.set_xlabel("iteration")
        for i in range(1, len(stages)):
            if stages[i] != stages[i - 1]:
                ax.axvline(i - 0.5, color="0.6", lw=0.8, ls="--")
    _layout(fig)
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
        ax.set_ylabel("count")

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
    _layout(fig)
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
    fig.colorbar(im, ax=ax, shrink=0.8)
    ax.set_title("correlation of the estimates" + (f" (every {step}th name)" if step > 1
                                                   else ""))
    fig.subplots_adjust(left=0.3, right=0.95, bottom=0.3, top=0.93)
    return _png(fig)
