"""Weakly identifiable parameters: which ones the prior holds, and what data would not.

A parameter is *held by the prior* when the measurements alone fix it less well than
its tolerance: its data-only standard error ``sigma0 sqrt(diag (J^T J)^-1)`` (the
solver's ``data_std``) exceeds its prior standard deviation (the solver's
``held_by_prior``).  It passed the rank test (it has an effect of its own), but the
estimate is the prior's, not the data's.

For each such parameter :func:`weak_parameters` says what would identify it:

* a **joint** that the data barely move (range under half its limits): the data's own
  configurations with that joint spread uniformly over its limits are added to the
  information (``R^T R`` of both sets, same parameters, same ``sigma0``); the joint
  that shrinks the parameter's data-only standard error most, by at least a factor
  :data:`IMPROVES`, is named with what it would give;
* otherwise the parameter the data confuse it with: the largest correlation of the
  data-only covariance (``(J^T J)^-1``), to be separated by poses that move the two
  differently.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.checks import show_quantity
from kincal.identify.uncertainty import correlation, inverse_normal_matrix, standard_errors
from kincal.measure.base import MeasurementModel, r_factor

Array = NDArray[np.float64]

__all__ = ["WeakParameter", "weak_parameters", "IMPROVES", "NARROW"]

#: A joint is named when spreading it over its limits shrinks the data-only standard
#: error by at least this factor.
IMPROVES = 2.0
#: Only joints whose range in the data is below this fraction of their limits are tried.
NARROW = 0.5


def _show(value: float, unit: str) -> str:
    return show_quantity(value, unit, 3, missing="nothing (no effect of its own)")


def _joint_amount(value: float, kind: str) -> str:
    return f"{math.degrees(value):.3g} deg" if kind == "revolute" else f"{value * 1e3:.3g} mm"


@dataclass(frozen=True)
class WeakParameter:
    """A parameter held by the prior, and what would identify it.

    Attributes:
        name, unit: the parameter and its SI unit.
        data_std: the standard error the measurements alone give [m / rad].
        prior_std: its prior standard deviation (the tolerance times the prior scale).
        joint: the joint whose motion would identify it (None: no such joint).
        joint_range: (its range in the data, its range of limits) [rad / m].
        joint_kind: ``revolute`` / ``prismatic``.
        with_joint: the data-only standard error with that joint spread over its limits.
        partner: the parameter the data confuse it with most, and their correlation.
    """

    name: str
    unit: str
    data_std: float
    prior_std: float
    joint: str | None = None
    joint_range: tuple[float, float] | None = None
    joint_kind: str = "revolute"
    with_joint: float | None = None
    partner: str | None = None
    correlation: float = 0.0

    def sentence(self) -> str:
        """``"d[3] is held by the prior (weakly identifiable): ..."`` in one sentence."""
        head = (f"{self.name} is held by the prior (weakly identifiable): the data alone fix "
                f"it to {_show(self.data_std, self.unit)}, its tolerance is "
                f"{_show(self.prior_std, self.unit)}")
        if self.joint is not None and self.joint_range is not None:
            have, full = self.joint_range
            return (f"{head}; joint {self.joint} moves over {_joint_amount(have, self.joint_kind)}"
                    f" in the data, of {_joint_amount(full, self.joint_kind)} between its "
                    f"limits: poses over its range would fix it to "
                    f"{_show(self.with_joint or math.nan, self.unit)}")
        if self.partner is not None:
            return (f"{head}; the data see it only together with {self.partner} (correlation "
                    f"{self.correlation:+.3f}): add poses that move them differently (other "
                    "orientations of the tool, another marker or instrument)")
        return head

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "unit": self.unit, "data_std": self.data_std,
                "prior_std": self.prior_std, "joint": self.joint,
                "joint_range": list(self.joint_range) if self.joint_range else None,
                "with_joint": self.with_joint, "partner": self.partner,
                "correlation": self.correlation, "sentence": self.sentence()}


def _with_q(block: MeasurementModel, q: Array) -> MeasurementModel:
    """``block`` with joint readings ``q`` (same rows): for the information of poses that
    were not measured (the Jacobian does not depend on the observations)."""
    return block.with_q(q)


def _limits(robot: Any) -> Array:
    lim = np.array(robot.joint_limits, dtype=float)
    for j, joint in enumerate(robot.joints):
        if not np.all(np.isfinite(lim[j])):
            lim[j] = (-math.pi, math.pi) if joint.kind == "revolute" else lim[j]
    return lim


def weak_parameters(result: Any, seed: int = 0) -> list[WeakParameter]:
    """The parameters the prior holds (``result.held_by_prior``) and what would identify
    them (module docstring).  Empty without a prior or when the data fix everything."""
    held = list(getattr(result, "held_by_prior", []) or [])
    if not held:
        return []
    prob = result.problem
    names = list(result.names)
    est = [names.index(n) for n in result.estimated]
    sigma0 = float(result.sigma0)
    R = prob.compressed(result.theta, None, est).R
    try:
        C = inverse_normal_matrix(R)
        corr = correlation(C)
    except KincalError:
        corr = np.zeros((len(est), len(est)))
    robot = prob.robot
    q = np.concatenate([np.asarray(b.q, dtype=float) for b in prob.blocks])
    have = np.ptp(q, axis=0)
    lim = _limits(robot)
    full = lim[:, 1] - lim[:, 0]
    rng = np.random.default_rng(seed)
    tried: dict[int, Array] = {}
    for k in range(robot.n):
        if not (np.isfinite(full[k]) and full[k] > 0 and have[k] < NARROW * full[k]):
            continue
        try:
            spread = []
            for b in prob.blocks:
                qb = np.array(b.q, dtype=float)
                qb[:, k] = rng.uniform(lim[k, 0], lim[k, 1], len(qb))
                spread.append(_with_q(b, qb))
            Rk = dataclasses.replace(prob, blocks=spread).compressed(result.theta, None, est).R
            both = r_factor(np.vstack([R, Rk]))
            tried[k] = sigma0 * standard_errors(inverse_normal_matrix(both))
        except (KincalError, ValueError, AttributeError, TypeError):
            continue
    out = []
    for n in held:
        i = names.index(n)
        col = est.index(i)
        d = float(result.data_std[i]) if result.data_std is not None else math.inf
        s = float(result.prior.get(n, math.nan))
        unit = prob.units[i]
        best = min(tried, key=lambda k: tried[k][col], default=None)
        if best is not None and tried[best][col] * IMPROVES <= d:
            out.append(WeakParameter(n, unit, d, s, robot.joints[best].name,
                                     (float(have[best]), float(full[best])),
                                     robot.joints[best].kind, float(tried[best][col])))
            continue
        c = np.abs(corr[col]).copy()
        c[col] = 0.0
        j = int(np.argmax(c)) if c.size else -1
        partner = names[est[j]] if j >= 0 and c[j] > 0 else None
        out.append(WeakParameter(n, unit, d, s, partner=partner,
                                 correlation=float(corr[col, j]) if partner else 0.0))
    return out
