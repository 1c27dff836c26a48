"""Accuracy predicted before measuring: parameter covariance and position error of a design.

Given the instrument noise and the chosen poses, linearised least squares at the
nominal parameters predicts what the calibration will achieve (Cramér-Rao bound of
the stated noise, ``sigma0 = 1``):

    Cov(theta_hat) = (J_S^T J_S)^-1                    [SI units^2]

with ``J_S`` the whitened Jacobian ``dr/dtheta`` (r = (model - observed) / sigma) of
the selected poses over the identifiable base set (robot *and* instrument/marker
parameters, as the solver estimates them).  At evaluation configurations ``q_e``
(a workspace grid, :func:`workspace_grid`) the predicted measured point moves by
``G_e d theta`` (``G_e = d y / d theta`` [m per parameter unit], the position rows of
the block's Jacobian times sigma), so its error after calibration has

    std_e = sqrt(trace(G_e Cov G_e^T))                  [m]

(the RMS length of the 3-D error of the predicted point: the error a held-out
measurement with the same instrument set-up would show, noise excluded), and the
expected RMS position error over the grid is ``sqrt(mean_e std_e^2)``.  For a pose
instrument the orientation rows give ``std`` of the orientation error [rad] the same
way.  For designs from other instruments (no position/pose block) the tool point
in the robot base frame is used, through the robot's parameters only.

Assumptions: Gaussian noise of the stated standard deviation, independent between
coordinates; errors small enough for the linearisation (true for millimetre-level
geometric errors); the model is complete (non-geometric errors are not predicted).
References: Cramér-Rao bound / linear least squares (e.g. Hollerbach & Wampler,
"The calibration index and taxonomy for robot kinematic calibration methods",
IJRR 15(6), 1996).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.identify.observability import DesignProblem
from kincal.identify.uncertainty import inverse_normal_matrix, propagated_variance
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["AccuracyPrediction", "predict_accuracy", "workspace_grid", "prediction_figure",
           "EvaluationRows", "evaluation_rows"]

#: Largest number of configurations :func:`workspace_grid` builds.
MAX_GRID = 50_000


@dataclass
class AccuracyPrediction:
    """Predicted accuracy of a calibration from a design, before measuring.

    Attributes:
        names, units: the estimated (base-set) parameters.
        covariance: (L, L) parameter covariance [SI^2].
        std: (L,) standard deviations [m or rad].
        q_eval: (E, n) evaluation configurations.
        points: (E, 3) the measured point at ``q_eval`` in the robot base frame (nominal)
            [m], for plots.
        position_std: (E,) predicted std of the position error at ``q_eval`` [m].
        orientation_std: (E,) the same for orientation [rad] (pose instruments), else None.
        noise: the instrument's position noise (std per coordinate) [m].
        poses: the number of poses of the design.
        frame: ``"instrument"`` (the measured point as the instrument sees it) or
            ``"base"`` (tool point in the robot base frame).
    """

    names: list[str]
    units: list[str]
    covariance: Array
    std: Array
    q_eval: Array
    points: Array
    position_std: Array
    orientation_std: Array | None
    noise: float
    poses: int
    frame: str = "instrument"

    @property
    def rms(self) -> float:
        """Expected RMS position error over the evaluation set, ``sqrt(mean std_e^2)`` [m]."""
        return float(np.sqrt(np.mean(self.position_std ** 2)))

    @property
    def max(self) -> float:
        """Largest predicted std over the evaluation set [m]."""
        return float(np.max(self.position_std))

    @property
    def p95(self) -> float:
        """95th percentile of the predicted std over the evaluation set [m]."""
        return float(np.percentile(self.position_std, 95))

    @property
    def rms_orientation(self) -> float | None:
        """Expected RMS orientation error [rad] (pose instruments)."""
        if self.orientation_std is None:
            return None
        return float(np.sqrt(np.mean(self.orientation_std ** 2)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (SI units)."""
        out: dict[str, Any] = {
            "poses": self.poses, "noise_m": self.noise, "frame": self.frame,
            "evaluation_configurations": int(len(self.q_eval)),
            "rms_position_m": self.rms, "p95_position_m": self.p95,
            "max_position_m": self.max,
            "parameters": [{"name": n, "unit": u, "std": float(s)}
                           for n, u, s in zip(self.names, self.units, self.std, strict=True)]}
        if self.orientation_std is not None:
            out["rms_orientation_rad"] = self.rms_orientation
        return out

    def __repr__(self) -> str:
        return (f"AccuracyPrediction(poses={self.poses}, noise={self.noise * 1e3:.4g} mm, "
                f"rms={self.rms * 1e3:.4g} mm, p95={self.p95 * 1e3:.4g} mm over "
                f"{len(self.q_eval)} configurations)")

    def _repr_html_(self) -> str:
        """Notebook display: RMS, 95 % and max of the predicted position error (mm)."""
        from kincal.io import html_table

        return html_table(["predicted position error", "mm"],
                          [["RMS", f"{self.rms * 1e3:.4g}"], ["95 %", f"{self.p95 * 1e3:.4g}"],
                           ["max", f"{self.max * 1e3:.4g}"]], repr(self))


def workspace_grid(robot: Robot, per_joint: int | Sequence[int] = 3,
                   margin: float = 0.1) -> Array:
    """A regular grid of configurations over the joint ranges: (prod(per_joint), n).

    Joint j takes ``per_joint[j]`` evenly spaced values in its range shrunk by
    ``margin`` of the range at both ends (unlimited revolute joints: [-pi, pi]; a
    single value is the range's middle).  Every configuration is a point of the
    workspace, so the grid covers it with all wrist orientations.
    """
    counts = np.broadcast_to(np.asarray(per_joint, dtype=int), (robot.n,))
    if np.any(counts < 1):
        raise KincalError("the grid needs at least one value per joint")
    total = int(np.prod(counts.astype(float)))
    if total > MAX_GRID:
        raise KincalError(f"a grid of {total} configurations is too large (max {MAX_GRID}); "
                          "use fewer values per joint")
    axes = []
    for j, joint in enumerate(robot.joints):
        lo, hi = joint.lower, joint.upper
        if not (np.isfinite(lo) and np.isfinite(hi)):
            if joint.kind == "prismatic":
                raise KincalError(f"prismatic joint {joint.name!r} has no limits")
            lo, hi = -np.pi, np.pi
        pad = margin * (hi - lo)
        axes.append(np.linspace(lo + pad, hi - pad, counts[j]) if counts[j] > 1
                    else np.array([0.5 * (lo + hi)]))
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


def _selected_rows(problem: DesignProblem, poses: Any) -> Array:
    """Whitened base-set rows (m, r, L) of a design (indices, PoseDesign or q)."""
    if hasattr(poses, "selected"):
        return problem.J[np.asarray(poses.selected, dtype=np.intp)]
    arr = np.asarray(poses)
    if arr.ndim == 1 and np.issubdtype(arr.dtype, np.integer):
        if arr.size and (arr.min() < 0 or arr.max() >= problem.num_candidates):
            raise KincalError("pose index outside the candidate set")
        out: Array = problem.J[arr]
        return out
    return problem.base_rows(np.atleast_2d(arr.astype(float)))


def _row_weights(problem: DesignProblem, r: int, noise: float | None,
                 orientation_noise: float | None) -> Array:
    """Factors turning rows whitened by the problem's sigmas into rows whitened by new ones."""
    w = np.ones(r)
    if noise is not None:
        w[:] = problem.sigma / noise
    if problem.kind == "pose":
        so = problem.sigma_orientation or 1.0
        w[3:] = so / orientation_noise if orientation_noise is not None else 1.0
    return w


@dataclass(frozen=True)
class EvaluationRows:
    """What :func:`predict_accuracy` needs of the evaluation configurations, whatever the
    design (:func:`evaluation_rows`; one for many designs of one problem).

    Attributes:
        q: (E, n) the configurations; ``points``: (E, 3) the measured point there [m].
        G: ``d y / d theta`` [m per parameter unit]: (E, K, 3, L) in the instrument frame,
            or (E, 3, L_r) in the base frame over the robot parameters ``columns``.
        Go: (E, 3, L) the orientation rows [rad per unit] (pose instruments), else None.
        frame: ``"instrument"`` or ``"base"``.
        columns: base frame: the robot parameters' indices among the problem's names.
    """

    q: Array
    points: Array
    G: Array
    Go: Array | None
    frame: str
    columns: NDArray[np.intp] | None = None


def evaluation_rows(problem: DesignProblem, q_eval: ArrayLike) -> EvaluationRows:
    """The :class:`EvaluationRows` of ``problem`` at the configurations ``q_eval``."""
    q_eval = np.atleast_2d(np.asarray(q_eval, dtype=float))
    if q_eval.shape[1] != problem.robot.n:
        raise KincalError(f"evaluation configurations must have {problem.robot.n} joint values")
    T = problem.robot.fk(q_eval)
    marker = np.asarray(problem.meta.get("marker", [[0.0, 0.0, 0.0]]), dtype=float)[0]
    points = T[:, :3, 3] + T[:, :3, :3] @ marker
    if problem.rows_for is not None:
        G = problem.base_rows(q_eval) * problem.sigma          # [m per parameter unit]
        Go = None
        if problem.kind == "pose":
            Go = G[:, 3:6] * ((problem.sigma_orientation or 1.0) / problem.sigma)
            G = G[:, :3]
        E, L = len(q_eval), G.shape[-1]
        return EvaluationRows(q_eval, points, G.reshape(E, -1, 3, L), Go, "instrument")
    robot = problem.robot
    idx = np.array([i for i, n in enumerate(problem.names) if n in robot.param_names],
                   dtype=np.intp)
    Jp = robot.param_jacobian(q_eval, [problem.names[i] for i in idx])
    G = Jp[:, :3] + np.cross(Jp[:, 3:], (T[:, :3, :3] @ marker)[:, :, None], axis=1)
    return EvaluationRows(q_eval, points, G, None, "base", idx)


def predict_accuracy(problem: DesignProblem, poses: Any, q_eval: ArrayLike | EvaluationRows,
                     noise: float | None = None, orientation_noise: float | None = None
                     ) -> AccuracyPrediction:
    """Predict the parameter covariance and the position error after calibration.

    Args:
        problem: the design problem (base set, instrument, stated noise).
        poses: a :class:`~kincal.identify.design.PoseDesign`, candidate indices, or
            (m, n) configurations (position / pose designs only).
        q_eval: (E, n) evaluation configurations, e.g. :func:`workspace_grid`, or their
            :func:`evaluation_rows` (made once for many designs).
        noise: position noise (std per coordinate) [m]; default the problem's.
        orientation_noise: pose instruments: rotation noise per component [rad].

    Returns:
        An :class:`AccuracyPrediction`.
    """
    if noise is not None and not (np.isfinite(noise) and noise > 0):
        raise KincalError("the instrument noise must be positive")
    J = _selected_rows(problem, poses)
    m, r, L = J.shape
    Jw = (J * _row_weights(problem, r, noise, orientation_noise)[:, None]).reshape(m * r, L)
    cov = inverse_normal_matrix(Jw)
    ev = q_eval if isinstance(q_eval, EvaluationRows) else evaluation_rows(problem, q_eval)
    ori = None
    if ev.frame == "instrument":
        if ev.Go is not None:
            ori = np.sqrt(np.clip(propagated_variance(ev.Go, cov), 0.0, None))
        var = propagated_variance(ev.G, cov).mean(axis=1)
    else:
        assert ev.columns is not None       # evaluation rows in the robot's frame carry them
        var = propagated_variance(ev.G, cov[np.ix_(ev.columns, ev.columns)])
    std = np.sqrt(np.clip(var, 0.0, None))
    return AccuracyPrediction(list(problem.names), list(problem.units), cov,
                              np.sqrt(np.clip(np.diag(cov), 0.0, None)), ev.q, ev.points, std,
                              ori, float(noise if noise is not None else problem.sigma), m,
                              ev.frame)


def prediction_figure(pred: AccuracyPrediction, baseline: AccuracyPrediction | None = None,
                      singular_values: Sequence[Array] | None = None,
                      labels: Sequence[str] = ("design", "random"), dpi: int = 100) -> bytes:
    """PNG of the predicted accuracy: error over the workspace, its histogram, spectra.

    Panels: (1) top view of the evaluation points coloured by the predicted std [mm];
    (2) histogram of the predicted std [mm] (and of ``baseline``, e.g. random poses);
    (3) the scaled singular values of the designs (``singular_values``), when given.
    """
    import io

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    panels = 3 if singular_values else 2
    fig, axes = plt.subplots(1, panels, figsize=(min(4.6 * panels, 11.6), 4.0))
    ax = axes[0]
    sc = ax.scatter(pred.points[:, 0] * 1e3, pred.points[:, 1] * 1e3,
                    c=pred.position_std * 1e3, s=10, cmap="viridis")
    fig.colorbar(sc, ax=ax, label="predicted error std [mm]")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title("predicted error over the workspace (top view)", fontsize=10)
    ax.set_aspect("equal", adjustable="datalim")
    ax = axes[1]
    vals = [pred.position_std * 1e3] + ([baseline.position_std * 1e3] if baseline else [])
    bins = np.linspace(0.0, max(v.max() for v in vals) * 1.05, 30)
    for v, lab, col in zip(vals, labels, ("#1f77b4", "#c0504d"), strict=False):
        ax.hist(v, bins=bins, alpha=0.6, color=col,
                label=f"{lab}: RMS {np.sqrt(np.mean(v ** 2)):.4g} mm")
    ax.set_xlabel("predicted error std [mm]")
    ax.set_ylabel("configurations")
    ax.legend(fontsize=9)
    ax.set_title(f"after calibration with {pred.poses} poses", fontsize=10)
    if singular_values:
        ax = axes[2]
        for s, lab, col in zip(singular_values, labels, ("#1f77b4", "#c0504d"), strict=False):
            s = np.sort(np.asarray(s, dtype=float))[::-1]
            ax.semilogy(np.arange(1, s.size + 1), s, "o-", ms=3, color=col, label=lab)
        ax.set_xlabel("index i")
        ax.set_ylabel("scaled singular value s_i")
        ax.legend(fontsize=9)
        ax.set_title("singular values of the scaled Jacobian", fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()
