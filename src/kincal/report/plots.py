"""Figures of the calibration report (matplotlib, Agg backend, PNG bytes).

Every function returns PNG images as ``bytes`` so the HTML report can embed them
(base64) and the caller never touches a display.  Values are shown for people:
lengths in mm, angles in degrees; the data passed in is SI (m, rad).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

_BEFORE, _AFTER, _TRUTH = "#c0504d", "#1f77b4", "#2ca02c"


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def MaxNLocator(n: int, integer: bool = False) -> Any:  # noqa: N802 - matplotlib's name
    from matplotlib.ticker import MaxNLocator as _Max

    return _Max(n, integer=integer)


def _png(fig: Any, dpi: int = 80) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    _plt().close(fig)
    return buf.getvalue()


def _layout(fig: Any) -> None:
    """A fixed layout (tight_layout costs seconds on many axes)."""
    fig.subplots_adjust(left=0.09, right=0.97, bottom=0.16, top=0.9, hspace=0.45, wspace=0.3)


def display_scale(unit: str) -> tuple[float, str]:
    """Factor and label to show an SI value to people: m -> mm, rad -> deg."""
    if unit == "m":
        return 1e3, "mm"
    if unit == "rad":
        return 180.0 / math.pi, "deg"
    return 1.0, unit


def parameter_history(history: Array, names: Sequence[str], units: Sequence[str],
                      stages: Sequence[str] | None = None,
                      truth: Mapping[str, float] | None = None,
                      per_figure: int = 24, columns: int = 4) -> list[bytes]:
    """One small plot per parameter: its value [mm / deg] against the iteration.

    Like the thesis's figures 4.1-4.4: the estimate at iteration 0 (nominal / initial
    guess) and after every accepted step; a dotted line marks the true value when
    known (simulations), vertical lines the start of each stage.

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
        fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 1.9 * rows + 0.4),
                                 squeeze=False)
        fig.subplots_adjust(left=0.07, right=0.98, bottom=0.4 / (1.9 * rows + 0.4) + 0.02,
                            top=1 - 0.25 / (1.9 * rows + 0.4), hspace=0.55, wspace=0.42)
        for ax in axes.flat[len(idx):]:
            ax.axis("off")
        for ax, k in zip(axes.flat, idx, strict=False):
            s, lab = display_scale(units[k])
            ax.plot(it, H[:, k] * s, "o-", ms=3, lw=1.2, color=_AFTER)
            if truth and names[k] in truth:
                ax.axhline(truth[names[k]] * s, ls=":", color=_TRUTH, lw=1.5)
            for b in bounds:
                ax.axvline(b - 0.5, color="0.6", lw=0.8, ls="--")
            ax.set_title(names[k], fontsize=9)
            ax.set_ylabel(lab, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.ticklabel_format(axis="y", useOffset=False)
            ax.yaxis.set_major_locator(MaxNLocator(3))
            ax.xaxis.set_major_locator(MaxNLocator(5, integer=True))
        fig.supxlabel("iteration", fontsize=9)
        out.append(_png(fig))
    return out


def convergence(cost: Array, rms: Array, stages: Sequence[str]) -> bytes:
    """Cost (log scale) and RMS of the whitened residuals against the iteration."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3))
    it = np.arange(len(cost))
    a1.semilogy(it, np.maximum(cost, 1e-300), "o-", ms=3, color=_AFTER)
    a1.set_title("cost 0.5 |r|^2 (whitened)", fontsize=9)
    a2.semilogy(it, np.maximum(rms, 1e-300), "o-", ms=3, color=_AFTER)
    a2.axhline(1.0, color=_TRUTH, ls=":", lw=1.2)
    a2.set_title("RMS of whitened residuals (1 = at the noise level)", fontsize=9)
    for ax in (a1, a2):
        ax.set_xlabel("iteration", fontsize=8)
        ax.tick_params(labelsize=7)
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
        ax.set_xlabel(lab, fontsize=8)
        ax.set_ylabel("count", fontsize=8)

    return _before_after_grid(sets, draw, np.ravel)


def per_pose_errors(sets: Sequence[tuple[str, Mapping[str, Array], Mapping[str, Array]]]
                    ) -> bytes:
    """Error of every measurement before and after calibration (log scale), per data set."""
    def draw(ax: Any, b: Array, a: Array, lab: str) -> None:
        i = np.arange(len(b))
        ax.semilogy(i, np.maximum(b, 1e-9), ".", color=_BEFORE, label="before", ms=4)
        ax.semilogy(i, np.maximum(a, 1e-9), ".", color=_AFTER, label="after", ms=4)
        ax.set_xlabel("measurement (row)", fontsize=8)
        ax.set_ylabel(lab, fontsize=8)

    return _before_after_grid(sets, draw, _per_row)


def _before_after_grid(sets: Sequence[tuple[str, Mapping[str, Array], Mapping[str, Array]]],
                       draw: Callable[[Any, Array, Array, str], None],
                       reduce: Callable[[Array], Array]) -> bytes:
    """One panel per (error kind, data set): ``draw(ax, before, after, axis label)`` with
    ``reduce(|error|)`` in display units (mm, deg ...); kinds missing from a set stay blank."""
    plt = _plt()
    keys = _quantities(sets)
    fig, axes = plt.subplots(len(keys), len(sets), figsize=(4.2 * len(sets), 2.8 * len(keys)),
                             squeeze=False)
    for r, key in enumerate(keys):
        scale, lab = _label(key)
        for c, (name, before, after) in enumerate(sets):
            ax = axes[r, c]
            if key not in before or key not in after:
                ax.axis("off")
                continue
            draw(ax, reduce(np.abs(before[key])) * scale, reduce(np.abs(after[key])) * scale,
                 lab)
            ax.set_title(name, fontsize=9)
            ax.tick_params(labelsize=7)
            ax.legend(fontsize=7)
    _layout(fig)
    return _png(fig)


def _per_row(e: Array) -> Array:
    """One error per row: RMS over the markers of a row when there are several."""
    e = np.asarray(e, dtype=float)
    return np.sqrt(np.mean(e.reshape(len(e), -1) ** 2, axis=1)) if e.ndim > 1 else e


def correlation(C: Array, names: Sequence[str]) -> bytes:
    """Heat map of the estimated parameters' correlation matrix."""
    plt = _plt()
    n = len(names)
    size = min(3 + 0.22 * n, 14)
    fig, ax = plt.subplots(figsize=(size + 1, size))
    im = ax.imshow(np.asarray(C), vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(n), names, rotation=90, fontsize=6)
    ax.set_yticks(range(n), names, fontsize=6)
    fig.colorbar(im, ax=ax, shrink=0.8)
    ax.set_title("correlation of the estimates", fontsize=9)
    _layout(fig)
    return _png(fig)
