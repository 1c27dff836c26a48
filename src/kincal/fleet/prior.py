"""The fleet prior: what the robots of one model say about the next one.

Robots of one model differ by their manufacturing errors, drawn from one population.  Each
calibrated robot ``r`` gives an estimate ``theta_hat_ri = theta_ri + e_ri`` of its
parameter ``i`` with variance ``v_ri`` (its calibration's standard error squared), and
the population is ``theta_ri ~ N(mu_i, tau_i^2)``.  Per parameter, the empirical-Bayes
estimate is the DerSimonian-Laird method of moments (random-effects meta-analysis):

    w_r = 1 / v_ri,   m = sum w_r theta_hat_ri / sum w_r,
    Q = sum w_r (theta_hat_ri - m)^2,
    tau_i^2 = max(0, (Q - (k - 1)) / (sum w_r - sum w_r^2 / sum w_r)),
    w*_r = 1 / (v_ri + tau_i^2),   mu_i = sum w*_r theta_hat_ri / sum w*_r,
    var(mu_i) = 1 / sum w*_r,

over the ``k`` robots whose calibration fixed the parameter from its data: estimated,
identifiable, and with a standard error below half of the prior it was calibrated with
(a parameter the default prior held would otherwise come back as a tight fleet prior
around the nominal value that held it).  The estimation variance ``v_ri`` is removed from
the spread (``tau_i^2`` is the robots' own spread, not their calibrations' noise).

The prior of a new robot's parameter is the predictive distribution of a new member of
the population.  With ``tau_i`` known it is ``N(mu_i, tau_i^2 + var(mu_i))``; estimated
from ``k`` robots it is a Student t with ``k - 1`` degrees of freedom, whose variance is
``(k - 1) / (k - 3)`` times larger (a factor 3 for four robots, 1.3 for ten).  The prior
is the Gaussian of that variance,

    sigma_i^2 = (tau_i^2 + var(mu_i)) (k - 1) / (k - 3)       (k >= MIN_ROBOTS = 4),

and its mean ``mu_i`` becomes the parameter's value in the robot file
:func:`write_fleet_prior` writes, its standard deviation the parameter's ``tolerances:``
entry (the 1-sigma of the calibration prior).  Parameters seen in fewer than
:data:`MIN_ROBOTS` robots keep the nominal value and the default tolerance.  The
population covariance between parameters is not used (each prior is independent, as the
calibration prior is).

``kincal calibrate prior.yaml -d DATA`` (or ``robot: prior.yaml`` in a setup file) then
calibrates a new robot with the fleet prior.  With few poses, free every parameter the
prior covers (``--free``: the prior's names and the instrument's), so that the prior, not
the data alone, decides what is estimated.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from kincal.errors import KincalError
from kincal.robots.chain import ROLES
from kincal.units import display_scale

__all__ = ["FleetPrior", "ParameterPrior", "fleet_prior", "fleet_prior_robot",
           "write_fleet_prior", "MIN_ROBOTS"]

#: Robots whose data fixed a parameter, needed to give it a fleet prior (the Student-t
#: predictive variance ``(k - 1) / (k - 3)`` needs ``k >= 4``).
MIN_ROBOTS = 4
#: A calibration fixed a parameter from its data when its standard error is below this
#: fraction of the prior it was calibrated with.
DATA_FRACTION = 0.5


@dataclasses.dataclass(frozen=True)
class ParameterPrior:
    """One parameter's population (SI): ``mean`` ``mu``, ``spread`` ``tau`` (between
    robots), ``mean_std`` ``sqrt(var(mu))``, from ``robots`` robots ``k``; ``std`` is the
    prior's standard deviation ``sqrt((tau^2 + var(mu)) (k - 1) / (k - 3))``."""

    name: str
    unit: str
    nominal: float
    mean: float
    spread: float
    mean_std: float
    robots: int

    @property
    def std(self) -> float:
        k = self.robots
        return math.hypot(self.spread, self.mean_std) * math.sqrt((k - 1) / max(k - 3, 1))


@dataclasses.dataclass(frozen=True)
class FleetPrior:
    """The fleet prior of one robot model: ``robot`` (the model's robot spec), the serials
    it was estimated from and every parameter's :class:`ParameterPrior`."""

    robot: str
    serials: tuple[str, ...]
    parameters: tuple[ParameterPrior, ...]
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def values(self) -> dict[str, float]:
        return {p.name: p.mean for p in self.parameters}

    def tolerances(self) -> dict[str, str]:
        """``{name: 1-sigma with its unit}`` for a robot file's ``tolerances:``."""
        out = {}
        for p in self.parameters:
            f, u = display_scale(p.unit)
            out[p.name] = f"{p.std * f:.6g}{u}"
        return out


def _population(est: np.ndarray, var: np.ndarray) -> tuple[float, float, float]:
    """DerSimonian-Laird ``(mu, tau, sqrt(var(mu)))`` (module docstring)."""
    w = 1.0 / var
    m = float(np.sum(w * est) / np.sum(w))
    q = float(np.sum(w * (est - m) ** 2))
    denom = float(np.sum(w) - np.sum(w**2) / np.sum(w))
    tau2 = max(0.0, (q - (len(est) - 1)) / denom) if denom > 0 else 0.0
    ws = 1.0 / (var + tau2)
    mu = float(np.sum(ws * est) / np.sum(ws))
    return mu, math.sqrt(tau2), math.sqrt(1.0 / float(np.sum(ws)))


def fleet_prior(records: Sequence[Mapping[str, Any]]) -> FleetPrior:
    """The :class:`FleetPrior` of calibration records of one robot model (one record per
    robot: its latest ``ok`` calibration)."""
    if not records:
        raise KincalError("no calibrated robot to estimate a fleet prior from")
    models = {str(r["robot"]) for r in records}
    if len(models) > 1:
        raise KincalError("the records are of several robot models ("
                          + ", ".join(sorted(models)) + "): a fleet prior is of one model; "
                          "select its robots (--serial)")
    rows: dict[str, list[tuple[float, float]]] = {}
    info: dict[str, tuple[str, float]] = {}
    for rec in records:
        for p in rec["parameters"]:
            std, prior = p.get("std"), p.get("prior_std")
            if (p["role"] not in ROLES or not p["estimated"] or not p.get("identifiable")
                    or std is None or not std > 0):
                continue
            if prior is not None and not std < DATA_FRACTION * float(prior):
                continue
            rows.setdefault(p["name"], []).append((float(p["estimate"]), float(std) ** 2))
            info[p["name"]] = (p["unit"], float(p["nominal"]))
    params = []
    for name, vals in rows.items():
        if len(vals) < MIN_ROBOTS:
            continue
        est, var = (np.array(x) for x in zip(*vals, strict=True))
        mu, tau, mstd = _population(est, var)
        params.append(ParameterPrior(name, info[name][0], info[name][1], mu, tau, mstd,
                                     len(vals)))
    first = records[0]
    options = {k: first["options"][k] for k in ("base_link", "tip_link")
               if (first.get("options") or {}).get(k)}
    return FleetPrior(str(first["robot"]), tuple(str(r["serial"]) for r in records),
                      tuple(params), options)


def fleet_prior_robot(prior: FleetPrior) -> Any:
    """The model's nominal robot with the fleet means as values and the fleet prior's
    standard deviations as its tolerances."""
    from kincal.fleet.tasks import load_robot_cached

    nominal = load_robot_cached(prior.robot, prior.options)
    robot = nominal.with_params(prior.values())
    tol = {**dict(nominal.meta.get("tolerances") or {}), **prior.tolerances()}
    return dataclasses.replace(robot, meta={**dict(robot.meta), "tolerances": tol})


def write_fleet_prior(prior: FleetPrior, path: str) -> None:
    """Write the robot file of :func:`fleet_prior_robot` (YAML, SI values), with a header
    saying where the prior comes from."""
    from kincal.io import atomic_write_text
    from kincal.robots.files import robot_yaml_text

    head = (f"# Fleet prior of {prior.robot}: mean and spread of {len(prior.parameters)} "
            f"parameter(s) over {len(prior.serials)} robot(s) ({', '.join(prior.serials)}),\n"
            "# DerSimonian-Laird random effects (kincal.fleet.prior); values: the fleet "
            "means,\n# tolerances: the prior's 1-sigma sqrt(spread^2 + var(mean)).\n")
    atomic_write_text(path, head + robot_yaml_text(fleet_prior_robot(prior)))
