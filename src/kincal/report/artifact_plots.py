"""Artifact lengths from the joint readings, before and after calibration (the cross-bar
bar-length figures).

For every placement of an artifact block the known lengths (``|AC|``, ``|BD|`` of the
cross-bar, ``|AB|`` of a ball-bar, the socket distance of the two-socket tool) are
computed from the recorded joint readings through a model:

    L_hat = |X_b - X_a|,   X = mean of the probe tips seated in the socket

and plotted per placement against the known length, with the deviation of the
cross's right angle when there is one.  Figure 4 uses the nominal model, figure 5
the calibrated one (same axes scale in mm, so the improvement is visible).
matplotlib's Agg backend is selected inside the functions (no display needed).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from kincal.measure.artifacts.model import ArtifactMeasurement
    from kincal.robots.chain import Robot

__all__ = ["plot_lengths", "save_length_error_figures", "length_summary"]


def _agg() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def length_summary(block: ArtifactMeasurement, robot: Robot, extra: ArrayLike | None = None
                   ) -> dict[str, float]:
    """RMS and largest length error [m] and angle deviation [rad] of a block under ``robot``."""
    L = block.lengths(robot, extra)
    out = {"rms_length_error_m": float(np.sqrt(np.mean(L.error**2))) if len(L.error) else 0.0,
           "max_length_error_m": float(np.max(np.abs(L.error))) if len(L.error) else 0.0}
    A = block.angles(robot, extra)
    if len(A.value):
        out["rms_angle_deviation_rad"] = float(np.sqrt(np.mean(A.value**2)))
    return out


def plot_lengths(block: ArtifactMeasurement, robot: Robot, extra: ArrayLike | None = None,
                 title: str = "", ylim_mm: tuple[float, float] | None = None,
                 path: str | Path | None = None) -> Any:
    """Known lengths per placement computed from the joint readings with ``robot``.

    Upper axes: each length's error ``L_hat - L`` [mm] per placement (one marker
    series per constraint label), with the RMS in the legend; lower axes (cross-bar
    only): the deviation from the right angle [deg].  Returns the matplotlib Figure
    (and saves it to ``path`` when given).
    """
    plt = _agg()
    L = block.lengths(robot, extra)
    A = block.angles(robot, extra)
    places = list(block.placements)
    x_of = {p: i + 1 for i, p in enumerate(places)}
    rows = 2 if len(A.value) else 1
    fig, axes = plt.subplots(rows, 1, figsize=(7.0, 2.6 * rows + 0.6), sharex=True,
                             squeeze=False)
    ax = axes[0, 0]
    for label in dict.fromkeys(L.label):
        k = [i for i, s in enumerate(L.label) if s == label]
        err = 1e3 * L.error[k]
        ax.plot([x_of[L.placement[i]] for i in k], err, "o-", ms=4, lw=0.8,
                label=f"|{label}| (RMS {np.sqrt(np.mean(err**2)):.3f} mm)")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_ylabel("length error [mm]")
    if ylim_mm is not None:
        ax.set_ylim(*ylim_mm)
    ax.legend(fontsize=8, loc="best")
    lengths = sorted({round(v * 1e3, 6) for v in L.target})
    ax.set_title(title or f"{block.geometry.kind}: lengths from the joint readings "
                 f"(known {', '.join(f'{v:g}' for v in lengths)} mm)", fontsize=10)
    if rows == 2:
        ax2 = axes[1, 0]
        for label in dict.fromkeys(A.label):
            k = [i for i, s in enumerate(A.label) if s == label]
            dev = np.degrees(A.value[k])
            ax2.plot([x_of[A.placement[i]] for i in k], dev, "s-", ms=4, lw=0.8,
                     color="C3", label=f"{label} (RMS {np.sqrt(np.mean(dev**2)):.4f} deg)")
        ax2.axhline(0.0, color="k", lw=0.8)
        ax2.set_ylabel("angle - 90 [deg]")
        ax2.legend(fontsize=8, loc="best")
    axes[-1, 0].set_xlabel("placement (name)")
    axes[-1, 0].set_xticks(range(1, len(places) + 1))
    axes[-1, 0].set_xticklabels(places, fontsize=7, rotation=90 if len(places) > 20 else 0)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def save_length_error_figures(block: ArtifactMeasurement, nominal: Robot, calibrated: Robot,
                              directory: str | Path, extra_nominal: ArrayLike | None = None,
                              extra_calibrated: ArrayLike | None = None,
                              prefix: str = "artifact") -> dict[str, str]:
    """Write the artifact's length errors under the nominal and the calibrated model as
    PNG files (the bar-length figures).

    Both use the y range of the nominal one so they compare at a glance; the calibrated
    one is also written zoomed (``*_zoom.png``) to show the remaining errors.

    Returns ``{"lengths_nominal": path, "lengths_calibrated": path,
    "lengths_calibrated_zoom": path}``.
    """
    plt = _agg()
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    err = 1e3 * block.lengths(nominal, extra_nominal).error
    lim = float(np.max(np.abs(err))) * 1.15 if err.size else 1.0
    out = {"lengths_nominal": str(d / f"{prefix}_lengths_nominal.png"),
           "lengths_calibrated": str(d / f"{prefix}_lengths_calibrated.png"),
           "lengths_calibrated_zoom": str(d / f"{prefix}_lengths_calibrated_zoom.png")}
    figs = [plot_lengths(block, nominal, extra_nominal, "nominal model",
                         (-lim, lim), out["lengths_nominal"]),
            plot_lengths(block, calibrated, extra_calibrated, "calibrated model",
                         (-lim, lim), out["lengths_calibrated"]),
            plot_lengths(block, calibrated, extra_calibrated,
                         "calibrated model (zoomed)", None, out["lengths_calibrated_zoom"])]
    for f in figs:
        plt.close(f)
    return out
