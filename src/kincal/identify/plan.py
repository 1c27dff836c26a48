"""Plan a calibration experiment: choose the poses and predict the accuracy before measuring.

:func:`plan_poses` runs the whole planning pipeline on a robot:

1. candidates: random configurations within the joint limits (``candidates=N``), the
   configurations given (``candidates=q``), or those the instrument's simulator can
   measure (``reachable=True``);
2. the design Jacobian of the instrument over the identifiable base set
   (:func:`~kincal.identify.observability.design_problem`);
3. ``poses`` of them chosen by an observability criterion (O1 = D-optimal with DETMAX
   exchange, O2-O5, or the greedy condition number ``kappa``;
   :func:`~kincal.identify.design.select_poses`);
4. the parameter covariance ``(J_S^T J_S)^-1`` of the chosen poses and the position
   error it leaves over a joint-space grid
   (:func:`~kincal.identify.prediction.predict_accuracy`), next to the median of
   :data:`RANDOM_DESIGNS` random designs of the same size as the baseline.

Units are SI: noise in m (positions) and rad (orientations), distances in rad.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from kincal.identify.design import (
    instrument_candidates,
    random_candidates,
    random_design,
    select_poses,
)
from kincal.identify.observability import DEFAULT_MARKER, design_problem
from kincal.identify.prediction import evaluation_rows, predict_accuracy, workspace_grid
from kincal.robots.chain import Robot

__all__ = ["Plan", "plan_poses", "RANDOM_DESIGNS"]

#: Random designs drawn for the baseline column.
RANDOM_DESIGNS = 20


@dataclass
class Plan:
    """A planned calibration experiment (SI units).

    Attributes:
        problem: the candidates' :class:`~kincal.identify.observability.DesignProblem`.
        design: the chosen :class:`~kincal.identify.design.PoseDesign` (``design.q``
            holds the joint values of the chosen poses).
        prediction: its :class:`~kincal.identify.prediction.AccuracyPrediction`.
        random_indices, random_rms: observability indices and predicted RMS position
            error [m] of each random design of the same size.
        random_prediction: the prediction of the median random design (the design of
            rank ``len // 2`` by predicted RMS: one real design, so its RMS, 95 % and
            max belong together; every printout quotes it as "the median").
        random_singular_values: its singular values.
        inputs: the planning inputs in words, for reports.
        dropped: candidate rows dropped (outside the joint limits).
    """

    problem: Any
    design: Any
    prediction: Any
    random_indices: list[dict[str, float]]
    random_rms: list[float]
    random_prediction: Any
    random_singular_values: Any
    inputs: dict[str, str] = field(default_factory=dict)
    dropped: int = 0

    @property
    def q(self) -> np.ndarray:
        """Joint values of the chosen poses, (poses, n) [rad / m]."""
        return np.asarray(self.design.q)

    def to_dict(self, output: str | None = None, report: str | None = None) -> dict[str, Any]:
        """The JSON document of ``kincal plan --json``: the chosen poses [rad / m], their
        observability indices, the predicted accuracy (and the median random design's RMS
        position error [m]); ``output`` and ``report`` are the written file names."""
        d, robot = self.design, self.problem.robot
        return {
            "robot": robot.name, "instrument": self.inputs.get("instrument"),
            "criterion": d.criterion, "method": d.method, "poses": d.q.tolist(),
            "candidate_indices": d.selected.tolist(),
            "joint_names": list(robot.joint_names), "indices": d.indices.as_dict(),
            "random_indices_median": {k: float(np.median([x[k] for x in self.random_indices]))
                                      for k in d.indices.as_dict()},
            "identifiable": list(self.problem.problem.names),
            "not_identifiable": self.problem.report.not_identifiable,
            "prediction": self.prediction.to_dict(),
            "random_prediction_rms_position_m": float(self.random_prediction.rms),
            "output": output, "report": report}

    def __repr__(self) -> str:
        return (f"Plan({len(self.q)} poses of {self.problem.num_candidates} candidates, "
                f"{self.inputs.get('criterion', '')}: predicted RMS position error "
                f"{self.prediction.rms * 1e3:.4g} mm, median random design "
                f"{self.random_prediction.rms * 1e3:.4g} mm)")

    def _repr_html_(self) -> str:
        rows = "".join(f"<tr><th style='text-align:left'>{k}</th><td>{v}</td></tr>"
                       for k, v in self.inputs.items())
        return (f"<p><b>Plan</b>: {len(self.q)} poses; predicted RMS position error "
                f"<b>{self.prediction.rms * 1e3:.4g} mm</b> (median of {RANDOM_DESIGNS} "
                f"random designs: {self.random_prediction.rms * 1e3:.4g} mm)</p>"
                f"<table>{rows}</table>")


def plan_poses(robot: Robot, *, instrument: str = "position", poses: int = 30,
               criterion: str = "O1", candidates: int | ArrayLike = 2000,
               reachable: bool = False, noise: float = 1e-5,
               orientation_noise: float = 1e-5, marker: ArrayLike | None = None,
               scaling: str = "workspace", min_distance: float = 0.0, margin: float = 0.05,
               grid: int = 3, exchange: bool = True, seed: int = 0,
               progress: Callable[[str, int, int], Any] | None = None,
               source: str | None = None, dropped: int = 0) -> Plan:
    """Choose ``poses`` calibration poses for ``robot`` and predict the accuracy they give.

    Args:
        robot: the nominal robot.
        instrument: ``position`` (laser tracker), ``pose``, or any registered instrument
            with ``reachable=True``.
        poses: number of poses to choose.
        criterion: ``O1`` .. ``O5`` or ``kappa``.
        candidates: a number of random configurations within the joint limits, or the
            candidate configurations themselves, (N, n) [rad / m].
        reachable: candidates from the instrument's simulator (what it can measure).
        noise: instrument standard deviation per coordinate [m].
        orientation_noise: instrument standard deviation per axis [rad] (pose instrument).
        marker: the marker in the tool frame (3,) [m] (default: 0.1 m along z).
        scaling: ``workspace``, ``unit`` or ``errors`` (column scaling of the Jacobian).
        min_distance: smallest joint-space distance between chosen poses [rad].
        margin: fraction of each joint range kept away from the limits.
        grid: values per joint of the evaluation grid.
        exchange: improve the greedy choice by exchanges (DETMAX).
        seed: random seed.
        progress: called as ``progress(stage, done, total)``.
        source: how the candidates were obtained, for the plan's inputs.
        dropped: how many candidate rows were dropped (outside the joint limits).

    Returns:
        The :class:`Plan`.
    """
    rng = np.random.default_rng(seed)
    opts: dict[str, Any] = {"scaling": scaling}
    if instrument in ("position", "pose"):
        opts.update(noise=noise, orientation_noise=orientation_noise,
                    marker=DEFAULT_MARKER if marker is None else np.asarray(marker, float))
    if progress is not None:
        progress("candidate Jacobian", 0, 1)
    if reachable:
        from kincal.measure.registry import get_instrument

        if not isinstance(candidates, int):
            raise ValueError("reachable=True draws its own candidates: give their number")
        inst_opts = {"margin": margin} if "margin" in get_instrument(instrument).options else {}
        problem = instrument_candidates(robot, instrument, candidates, rng, inst_opts, **opts)
        source = source or f"{problem.num_candidates} configurations measurable by {instrument}"
    else:
        if isinstance(candidates, int):
            q = random_candidates(robot, candidates, rng, margin)
            source = source or f"{len(q)} random configurations within the joint limits"
        else:
            q = np.atleast_2d(np.asarray(candidates, dtype=float))
            source = source or f"{len(q)} given configurations"
        problem = design_problem(robot, q, instrument, **opts)
    design = select_poses(problem, poses, criterion, min_distance=min_distance,
                          exchange=exchange, progress=progress)
    q_eval = workspace_grid(robot, grid, margin=0.1)
    ev = evaluation_rows(problem, q_eval)          # the grid's rows: the same for every design
    pred = predict_accuracy(problem, design, ev)
    rnd, rms, preds = [], [], []
    for _ in range(RANDOM_DESIGNS):
        d = random_design(problem, poses, rng, min_distance=min_distance)
        p = predict_accuracy(problem, d, ev)
        rnd.append(d)
        rms.append(p.rms)
        preds.append(p)
    med = int(np.argsort(rms)[len(rms) // 2])
    inputs = {"robot": robot.name, "instrument": instrument, "candidates": source,
              "poses": str(poses), "criterion": f"{criterion} ({design.method})",
              "scaling": scaling, "noise": f"{noise * 1e3:g} mm per coordinate",
              "minimum distance": f"{math.degrees(min_distance):g} deg (joint space)",
              "evaluation": f"joint-space grid, {grid} values per joint "
                            f"({len(q_eval)} configurations)", "seed": str(seed)}
    return Plan(problem, design, pred, [d.indices.as_dict() for d in rnd], rms, preds[med],
                rnd[med].indices.singular_values, inputs, dropped)
