"""The five-bar's calibration report, the same page as every serial robot's.

:func:`fivebar_report` turns a :class:`~kincal.parallel.calibration.FiveBarCalibration`
into the serial report of :func:`kincal.report.html.render_html`: the before/after table
of the end-point position error (the task-space residual ``dX = X_m - R^T (FK(q) - t)``
[m] with the nominal and the calibrated model, measurement frame included), the
parameter table in mm and degrees with standard errors, what the data cannot identify,
and the plots (parameters against the iteration, error distributions, per-measurement
errors, correlation).  :class:`ReportView` is the adapter that gives a five-bar result
the interface the report reads.

Layer rule: part of :mod:`kincal.parallel`; imports :mod:`kincal.report` and below.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.parallel import residuals as res
from kincal.parallel.calibration import FiveBarCalibration
from kincal.report.metrics import ErrorComparison

__all__ = ["fivebar_report", "fivebar_comparison", "ReportView"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class _Step:
    theta: Array
    stage: str
    cost: float
    rms: float


@dataclass(frozen=True)
class _Problem:
    names: tuple[str, ...]
    units: tuple[str, ...]
    roles: tuple[str, ...]


@dataclass(frozen=True)
class _Identifiability:
    """The five-bar's identifiability in the serial report's terms."""

    names: tuple[str, ...]
    identifiable: tuple[str, ...]
    not_identifiable: tuple[str, ...]
    unobservable: tuple[str, ...] = ()
    dependent: Mapping[str, list[str]] = field(default_factory=dict)
    lines: tuple[str, ...] = ()
    condition: float = float("nan")

    def describe(self) -> list[str]:
        return list(self.lines)

    def to_dict(self) -> dict[str, Any]:
        return {"identifiable": list(self.identifiable),
                "not_identifiable": list(self.not_identifiable),
                "unobservable": list(self.unobservable), "dependent": dict(self.dependent),
                "cond_scaled": self.condition}


class ReportView:
    """A five-bar calibration seen through the serial report's interface."""

    def __init__(self, result: FiveBarCalibration) -> None:
        self._r = result
        self.names = tuple(result.names)
        units = dict(zip(res.ALL_NAMES, res.ALL_UNITS, strict=True))
        roles = tuple("instrument" if n.startswith("frame.") else
                      "offset" if n.startswith("offset") else
                      "angle" if units[n] == "rad" else "length" for n in self.names)
        self.problem = _Problem(self.names, tuple(units[n] for n in self.names), roles)
        ident = result.identifiability
        requested = tuple(ident.requested)
        self.identifiability = _Identifiability(
            requested, tuple(ident.kept), tuple(ident.held),
            tuple(ident.no_effect), {n: sorted(v) for n, v in ident.absorbed.items()},
            tuple(ident.describe()), float(ident.condition))
        self.estimated = list(result.free)
        self.robot = result.robot
        self.theta = np.asarray(result.values, dtype=float)
        self.message = ""
        self.held_by_prior: list[str] = []
        idx = [self.names.index(n) for n in self.estimated]
        cov = np.asarray(result.covariance, dtype=float)
        self.correlation: Array | None = None
        if cov.shape == (len(idx), len(idx)) and len(idx) > 1:
            s = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
            small = cov / np.outer(s, s)
            self.correlation = np.eye(len(self.names))
            self.correlation[np.ix_(idx, idx)] = small
        self.history = [
            _Step(np.array([h["params"][n] for n in self.names], dtype=float), "all",
                  0.5 * float(h["rms"]) ** 2 * max(1, 2 * len(result.residuals)),
                  float(h["rms"])) for h in result.history]

    def to_dict(self) -> dict[str, Any]:
        r = self._r
        start = dict(zip(res.ALL_NAMES, np.asarray(r.start).tolist(), strict=True))
        ident = set(self.identifiability.identifiable)
        params = []
        for n, u in zip(self.names, self.problem.units, strict=True):
            est = n in self.estimated
            status = "estimated" if est else (
                "unobservable" if n in self.identifiability.unobservable else
                "dependent on " + ", ".join(self.identifiability.dependent.get(n, []))
                if n in self.identifiability.not_identifiable else "fixed")
            params.append({"name": n, "unit": u, "nominal": float(start[n]),
                           "estimate": float(r.params[n]),
                           "std": r.std_errors.get(n) if est else None,
                           "identifiable": n in ident, "estimated": est, "status": status})
        return {"parameters": params, "identifiable_count": len(ident),
                "estimated_count": len(self.estimated), "converged": bool(r.converged),
                "iterations": int(r.iterations), "method": r.method,
                "loss": f"linear ({r.residual} residual)", "sigma0": float(r.sigma),
                "stages": [{"stage": "all", "estimated": list(self.estimated)}],
                "identifiability": self.identifiability.to_dict(), "message": ""}


def fivebar_comparison(result: FiveBarCalibration, q: Array, x: Array, title: str = "train",
                       label: str | None = None) -> ErrorComparison:
    """End-point position errors |dX| [m] of the nominal and the calibrated five-bar on the
    measurements (each model in its own nearest assembly mode); ``label`` (default the
    title): ``train`` or ``validation``."""
    q, x = np.asarray(q, dtype=float), np.asarray(x, dtype=float)
    start = np.asarray(result.start, dtype=float)
    end = np.array([result.params[n] for n in res.ALL_NAMES], dtype=float)
    out = []
    for theta in (start, end):
        sigma = res.fk_assembly_nearest(theta, q, x)
        dx = res.fk_model(theta, q, x, sigma)[0]
        out.append({"position_m": np.linalg.norm(dx, axis=1)})
    return ErrorComparison(title if label is None else label, title, out[0], out[1],
                           "before: the nominal five-bar and measurement frame; after: the "
                           "calibrated ones (end-point position in the measurement frame)")


def fivebar_report(result: FiveBarCalibration, q: Array, x: Array, data_name: str,
                   inputs: Mapping[str, str] | None = None,
                   truth: Mapping[str, float] | None = None,
                   sections: Sequence[str] = (),
                   comparisons: Sequence[ErrorComparison] | None = None) -> str:
    """The HTML report of a five-bar calibration (:func:`kincal.report.html.render_html`);
    ``comparisons``: the before/after tables (default: the training file ``q``, ``x``)."""
    from kincal.report.html import render_html

    comps = list(comparisons) if comparisons is not None else [
        fivebar_comparison(result, q, x, f"train ({data_name})")]
    return render_html(ReportView(result), comps,
                       title=f"kincal calibration of {result.nominal.name} (five-bar)",
                       inputs=inputs, truth=truth, extra_sections=list(sections))
