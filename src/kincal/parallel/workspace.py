"""Workspace of a five-bar working mode: grid evaluation and plot.

A point x belongs to the workspace of working mode (s1, s2) when both arms
reach it, ``|l_i - l_{i+2}| <= |x - B_i| <= l_i + l_{i+2}`` (the two annuli),
when the inverse kinematics in that mode respects the reading limits (if the
robot has any), and, optionally, when the resulting configuration has a given
assembly mode and stays a distance ``margin`` away from both singularities.
Each point carries the singularity measures of
:func:`kincal.parallel.kinematics.singularity_measures`; Type-2
(direct-kinematics) singular curves split the region into the parts a
trajectory can cross without losing control.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kincal.parallel import kinematics as kin

if TYPE_CHECKING:
    from kincal.parallel.fivebar import FiveBar


@dataclass(frozen=True)
class Workspace:
    """Grid evaluation of a working mode's workspace (arrays of shape (ny, nx)).

    ``reachable``: mask of the region; ``type1`` (min over arms) and ``type2``:
    singularity measures (NaN outside the annuli); ``assembly``: +-1 of the
    configuration reached; ``area``: reachable area [m^2].
    """

    mode: str
    xs: np.ndarray
    ys: np.ndarray
    reachable: np.ndarray
    type1: np.ndarray
    type2: np.ndarray
    assembly: np.ndarray
    area: float

    def to_dict(self, robot: str, output: str | None = None) -> dict[str, Any]:
        """The summary for JSON: robot, working mode, area [m^2], the plot written."""
        return {"robot": robot, "working_mode": self.mode, "area_m2": self.area,
                "output": output}


def workspace(
    robot: FiveBar,
    mode: str | None = None,
    resolution: int = 200,
    assembly: int | None = None,
    margin: float = 0.0,
    use_limits: bool = True,
) -> Workspace:
    """Evaluate the workspace of a working mode on a ``resolution`` x ``resolution`` grid.

    Args:
        robot: the five-bar.
        mode: working mode (default: the robot's).
        resolution: grid points per axis.
        assembly: keep only points whose configuration has this assembly mode.
        margin: keep only points with both singularity measures >= margin.
        use_limits: apply the robot's reading limits, if it has any.
    """
    mode = robot.working_mode if mode is None else mode
    p = robot.param_values
    b = np.array([[robot.base1_x, robot.base1_y], [robot.base2_x, robot.base2_y]])
    reach = np.array([robot.l1 + robot.l3, robot.l2 + robot.l4])
    lo = np.max(b - reach[:, None], axis=0)
    hi = np.min(b + reach[:, None], axis=0)
    if np.any(hi <= lo):
        lo, hi = np.min(b - reach[:, None], axis=0), np.max(b + reach[:, None], axis=0)
    xs = np.linspace(lo[0], hi[0], resolution)
    ys = np.linspace(lo[1], hi[1], resolution)
    gx, gy = np.meshgrid(xs, ys)
    x = np.column_stack([gx.ravel(), gy.ravel()])
    modes = np.tile(kin.mode_signs(mode), (x.shape[0], 1))
    q, ok = kin.ik(p, x, modes)
    qs = np.where(ok[:, None], q, 0.0)
    t1, t2 = kin.singularity_measures(p, qs, x)
    sigma, _ = kin.signs(p, qs, x)
    t1m = np.where(ok, np.min(t1, axis=1), np.nan)
    t2m = np.where(ok, t2, np.nan)
    keep = ok.copy()
    if use_limits and robot.limits is not None:
        for i, (qmin, qmax) in enumerate(robot.limits):
            # readings are wrapped to [-pi, pi); compare modulo 2 pi from qmin
            rel = (qs[:, i] - qmin) % (2.0 * np.pi)
            keep &= rel <= (qmax - qmin)
    if assembly is not None:
        keep &= sigma == assembly
    if margin > 0.0:
        keep &= (t1m >= margin) & (t2m >= margin)
    shape = gx.shape
    cell = (xs[1] - xs[0]) * (ys[1] - ys[0]) if resolution > 1 else 0.0
    return Workspace(
        mode=mode,
        xs=xs,
        ys=ys,
        reachable=keep.reshape(shape),
        type1=t1m.reshape(shape),
        type2=t2m.reshape(shape),
        assembly=np.where(ok, sigma, 0).reshape(shape),
        area=float(np.count_nonzero(keep) * cell),
    )


def plot_workspace(
    robot: FiveBar,
    path: str | Path,
    mode: str | None = None,
    resolution: int = 250,
    assembly: int | None = None,
    margin: float = 0.0,
) -> Path:
    """Plot the workspace of a working mode and write it to ``path`` (PNG, SVG, PDF).

    Shaded: reachable points coloured by the Type-2 measure |sin(beta4 - beta3)|;
    light grey: within both arms' reach but excluded (limits, assembly, margin);
    red curve: Type-2 singular locus; dashed: the arms' reach circles (Type-1
    boundaries); markers: the bases.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ws = workspace(robot, mode, resolution, assembly=assembly, margin=margin)
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    shown = np.where(ws.reachable, ws.type2, np.nan)
    excluded = np.where(~ws.reachable & ~np.isnan(ws.type2), 1.0, np.nan)
    ax.pcolormesh(ws.xs, ws.ys, excluded, shading="auto", cmap="Greys", vmin=0, vmax=4)
    mesh = ax.pcolormesh(ws.xs, ws.ys, shown, shading="auto", cmap="viridis", vmin=0, vmax=1)
    fig.colorbar(mesh, ax=ax, label="Type-2 measure |sin(beta4 - beta3)|")
    signed = ws.type2 * np.where(ws.assembly > 0, 1.0, -1.0)  # = (J3-J1) x (J3-J2) / (l3 l4)
    if np.nanmin(signed) < 0.0 < np.nanmax(signed):
        ax.contour(
            ws.xs, ws.ys, np.ma.masked_invalid(signed), levels=[0.0], colors="red", linewidths=1.2
        )
    t = np.linspace(0, 2 * np.pi, 361)
    arms = (
        (robot.base1_x, robot.base1_y, robot.l1, robot.l3),
        (robot.base2_x, robot.base2_y, robot.l2, robot.l4),
    )
    for k, (bx, by, lp, ld) in enumerate(arms):
        for radius in (lp + ld, abs(lp - ld)):
            ax.plot(bx + radius * np.cos(t), by + radius * np.sin(t), "--", color="0.5", lw=0.8)
        ax.plot(bx, by, "ks")
        ax.annotate(f"B{k + 1}", (bx, by), textcoords="offset points", xytext=(4, -12))
    ax.set_xlim(ws.xs[0], ws.xs[-1])
    ax.set_ylim(ws.ys[0], ws.ys[-1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    extra = f", assembly {assembly:+d}" if assembly is not None else ""
    ax.set_title(
        f"{robot.name}: workspace of working mode {ws.mode}{extra}, area {ws.area:.4g} m²",
        fontsize=9,
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)
    return path
