"""The outcome of a calibration: :class:`CalibrationResult` and how it is shown.

A result holds the calibrated robot, the estimate ``theta`` over every parameter name
[m / rad], the estimated (identifiable base) set with its covariance
``sigma0^2 (J^T J)^-1``, the residuals, the iteration history and, per stage, the
:class:`~kincal.identify.status.StageStatus` that ended it.  Errors are shown for people
by their unit suffix (:func:`format_error`: ``_m`` in mm, ``_rad`` in deg, ``_px`` in px).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from kincal.identify.identifiability import IdentifiabilityReport
from kincal.identify.stage import IterationRecord
from kincal.identify.status import StageStatus
from kincal.measure.base import StackedProblem
from kincal.robots.chain import Robot
from kincal.units import display_scale

Array = NDArray[np.float64]


def format_error(key: str, value: float, what: str = "") -> str:
    """``"position_m", 1.2e-5 -> "position 0.0120 mm"``: a physical error for people.

    The key's unit suffix decides: ``_m`` -> mm (``x 1e3``), ``_rad`` -> deg
    (``x 180 / pi``), ``_px`` -> px; any other key is shown as it is, value unscaled.
    ``what`` (e.g. ``"RMS"``) goes between the name and the value.
    """
    name, _, unit = key.rpartition("_")
    mid = f" {what}" if what else ""
    if name and unit in ("m", "rad", "px"):
        f, u = display_scale(unit)
        digits = 5 if unit == "rad" else 4
        return f"{name}{mid} {value * f:.{digits}f} {u}"
    return f"{key}{mid} {value:.6g}"


class ProcedureRecord(Protocol):
    """What a calibration procedure records beside its result (see
    ``CalibrationResult.procedure_record``): anything that serialises itself."""

    def to_dict(self) -> dict[str, Any]:
        """The record as plain JSON-ready values."""
        ...


@dataclass
class CalibrationResult:
    """The outcome of :func:`calibrate` (shaped like scipy's ``OptimizeResult``).

    Attributes:
        robot: the calibrated robot.
        robot_initial: the robot the calibration started from.
        problem: the stacked problem (blocks, names, units, roles).
        theta0, theta: initial and final values over ``names`` [m / rad].
        names: every parameter of the problem (robot, then blocks).
        estimated: names estimated in the final stage (the identifiable base set).
        identifiability: the analysis of the final stage's candidates.
        std: standard error per name; 0.0 for parameters not estimated.
        covariance: (p, p) over ``estimated``; ``sigma0^2 (J^T J)^-1``.
        correlation: (p, p) over ``estimated``.
        sigma0: the variance factor used (a posteriori unless ``trust_sigma``).
        residuals: final whitened residuals (M,).
        weights: final robust weight per residual (1 for ``loss="linear"``).
        outliers: ``(block name, row)`` of measurements with a small robust weight.
        history: one :class:`IterationRecord` per iteration, all stages (a stage solved
            again with a smaller base set starts again at iteration 0; an attempt that
            was not kept is not recorded).
        stages: ``(label, estimated names)`` per stage.
        converged, iterations, message: as in scipy (``iterations`` counts every kept
            solve; ``message`` names the parameters dropped at a solution).
        prior: ``{name: prior standard deviation}`` of the estimated parameters that
            had a prior (empty for a plain least-squares fit).
        data_std: with a prior, the standard error per name the measurements alone
            would give, ``sigma0 sqrt(diag (J^T J)^-1)`` (inf where they cannot fix it,
            NaN for names not estimated); None without a prior.
        held_by_prior: estimated parameters whose ``data_std`` exceeds their prior
            standard deviation: the prior, not the data, holds them (weakly
            identifiable).
        noise_scale_estimated: ``sigma0`` was estimated before the prior was weighed
            (module docstring, "Prior").
        effective_parameters: with a prior, ``p_eff = trace((J^T J + sigma0^2 P^-2)^-1
            J^T J)``, the number of parameters the data actually fix.
        stage_status: ``(label, status)`` per stage: the rule that ended its last solve
            (:class:`~kincal.identify.status.StageStatus`; ``status.converged``,
            :func:`~kincal.identify.status.stage_message` for the sentence).
        procedure_record: what a staged procedure recorded beside the fit (e.g. the
            staged selection's per-stage condition numbers); None for :func:`calibrate`.
    """

    robot: Robot
    robot_initial: Robot
    problem: StackedProblem
    theta0: Array
    theta: Array
    names: tuple[str, ...]
    estimated: list[str]
    identifiability: IdentifiabilityReport
    std: Array
    covariance: Array
    correlation: Array
    sigma0: float
    residuals: Array
    weights: Array
    outliers: list[tuple[str, int]]
    history: list[IterationRecord]
    converged: bool
    iterations: int
    message: str
    stages: list[tuple[str, list[str]]] = field(default_factory=list)
    method: str = "lm"
    loss: str = "linear"
    prior: dict[str, float] = field(default_factory=dict)
    data_std: Array | None = None
    held_by_prior: list[str] = field(default_factory=list)
    noise_scale_estimated: bool = False
    effective_parameters: float | None = None
    stage_status: list[tuple[str, StageStatus]] = field(default_factory=list)
    procedure_record: ProcedureRecord | None = None

    # ------------------------------------------------------------------ access
    @property
    def params(self) -> dict[str, float]:
        """``{name: value}`` of every parameter after calibration [m / rad]."""
        return dict(zip(self.names, self.theta.tolist(), strict=True))

    @property
    def x(self) -> Array:
        """The estimated parameters' values (scipy-style), in ``estimated`` order."""
        return np.array([self.theta[self.names.index(n)] for n in self.estimated])

    @property
    def cost(self) -> float:
        return float(self.history[-1].cost) if self.history else float("nan")

    def block_values(self, name: str) -> dict[str, float]:
        """``{parameter name: value}`` of measurement block ``name``'s parameters."""
        sl = self.problem.block_slice(name)
        return dict(zip(self.names[sl], self.theta[sl].tolist(), strict=True))

    def extras(self) -> dict[str, float]:
        """All measurement-block parameter values ``{name: value}`` (frames, markers)."""
        k = self.problem.num_robot
        return dict(zip(self.names[k:], self.theta[k:].tolist(), strict=True))

    def errors(self) -> dict[str, dict[str, Array]]:
        """Physical errors of every training block at the solution (``position_m`` ...)."""
        return self.problem.errors(self.theta)

    @property
    def passes(self) -> int:
        """Solves the :attr:`iterations` add up over (stages, a stage solved again with a
        smaller base set, the re-solves that settle the noise scale): each starts at
        iteration 0 in :attr:`history`.  The solver's ``max_iter`` limits each pass, not
        the total."""
        return max(1, sum(1 for h in self.history if h.iteration == 0))

    def iterations_text(self) -> str:
        """``"12 iterations"``, or ``"119 iterations over 3 passes"``."""
        p = self.passes
        return f"{self.iterations} iterations" + (f" over {p} passes" if p > 1 else "")

    def rms(self) -> dict[str, float]:
        """RMS of each physical error kind over all training blocks, e.g. ``rms_position_m``."""
        acc: dict[str, list[Array]] = {}
        for errs in self.errors().values():
            for k, v in errs.items():
                acc.setdefault(k, []).append(np.ravel(v))
        return {f"rms_{k}": float(np.sqrt(np.mean(np.concatenate(v) ** 2)))
                for k, v in acc.items()}

    # ------------------------------------------------------------------ output
    def _status(self, name: str) -> str:
        if name in self.estimated:
            return "estimated"
        rep = self.identifiability
        if name in rep.unobservable:
            return "unobservable"
        if name in rep.dependent:
            deps = rep.dependent[name]
            return "dependent on " + (", ".join(deps[:2]) + (" ..." if len(deps) > 2 else "")
                                      if deps else "the base set")
        return "fixed"

    def to_dict(self) -> dict[str, Any]:
        """JSON-able result: parameters (SI units; ``std`` null when not estimated) and
        diagnostics."""
        est = set(self.estimated)
        ident = set(self.identifiability.identifiable)
        params = []
        for i, n in enumerate(self.names):
            params.append({
                "name": n, "unit": self.problem.units[i], "role": self.problem.roles[i],
                "nominal": float(self.theta0[i]), "estimate": float(self.theta[i]),
                "std": float(self.std[i]) if n in est else None,
                "identifiable": n in ident, "estimated": n in est,
                "status": self._status(n),
                "prior_std": self.prior.get(n),
            })
        return {
            "parameters": params,
            "identifiable_count": len(self.identifiability.identifiable),
            "estimated_count": len(self.estimated),
            "converged": bool(self.converged),
            "iterations": int(self.iterations),
            "passes": self.passes,
            "message": self.message,
            "method": self.method,
            "loss": self.loss,
            "sigma0": float(self.sigma0),
            "rms": self.rms(),
            "outliers": [{"block": b, "row": int(r)} for b, r in self.outliers],
            "stages": [{"stage": s, "estimated": list(n)} for s, n in self.stages],
            "history": [h.to_dict() for h in self.history],
            "identifiability": self.identifiability.to_dict(),
        }

    def summary(self, all_parameters: bool = False) -> str:
        """A plain-text table: value changes and standard errors in mm / deg.

        Lists the estimated parameters (and, with ``all_parameters``, every other one
        with the reason it was held); with a prior, its standard deviation per parameter.
        The training errors are shown by the unit suffix of their kind
        (:func:`format_error`: ``_m`` in mm, ``_rad`` in deg, ``_px`` in px).
        """
        lines = [repr(self), ""]
        prior_head = f"{'prior':>10}" if self.prior else ""
        head = f"{'parameter':<34}{'unit':>5}{'initial':>13}{'estimate':>13}{'change':>11}" \
               f"{'std':>10}{prior_head}  status"
        lines += [head, "-" * len(head)]
        for i, n in enumerate(self.names):
            if not all_parameters and n not in self.estimated:
                continue
            unit = self.problem.units[i]
            f, u = display_scale(unit)
            std = f"{self.std[i] * f:10.4f}" if n in self.estimated else f"{'-':>10}"
            if self.prior:
                std += f"{self.prior[n] * f:10.4f}" if n in self.prior else f"{'-':>10}"
            lines.append(f"{n:<34}{u:>5}{self.theta0[i] * f:13.5f}{self.theta[i] * f:13.5f}"
                         f"{(self.theta[i] - self.theta0[i]) * f:11.5f}{std}  "
                         f"{self._status(n)}")
        if self.prior:
            lines += ["", f"MAP estimate: {len(self.prior)} estimated parameter(s) have a "
                      "Gaussian prior centred on their initial value (column 'prior': its "
                      "standard deviation; cost and std include it)"]
        held = self.identifiability.describe()
        if held:
            lines += ["", "Not identifiable from these measurements:"]
            lines += [f"  - {s}" for s in held]
        r = self.rms()
        if r:
            lines += ["", "Training errors: " + ", ".join(
                format_error(k[4:], v, "RMS") for k, v in r.items())]
        if self.outliers:
            lines.append(f"Outliers ({len(self.outliers)}): "
                         + ", ".join(f"{b}[{r}]" for b, r in self.outliers[:20]))
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """Notebook display: the headline and the estimated parameters in mm / deg."""
        from kincal.io import html_table

        rows = []
        for i, n in enumerate(self.names):
            if n not in self.estimated:
                continue
            f, u = display_scale(self.problem.units[i])
            held = " (held by the prior)" if n in self.held_by_prior else ""
            rows.append([n, u, f"{self.theta0[i] * f:.5f}", f"{self.theta[i] * f:.5f}",
                         f"{(self.theta[i] - self.theta0[i]) * f:.5f}",
                         f"{self.std[i] * f:.4f}{held}"])
        r = self.rms()
        errors = ", ".join(format_error(k[4:], v, "RMS") for k, v in r.items())
        state = "converged" if self.converged else "NOT converged"
        estimator = "MAP (tolerance priors)" if self.prior else "least squares"
        caption = (f"{state} after {self.iterations_text()} ({self.message}); "
                   f"{estimator}; {len(self.estimated)} of {len(self.names)} parameters "
                   f"estimated; sigma0 = {self.sigma0:.4g}; training {errors}; "
                   f"{len(self.names) - len(self.estimated)} held (result.summary(True) "
                   "says why)")
        return html_table(["parameter", "unit", "initial", "estimate", "change", "std"],
                          rows, caption)

    def __repr__(self) -> str:
        rms = self.rms()
        pos = f", rms_position={rms['rms_position_m'] * 1e3:.4g} mm" \
            if "rms_position_m" in rms else ""
        return (f"CalibrationResult(converged={self.converged}, iterations={self.iterations}, "
                f"estimated={len(self.estimated)} of {len(self.names)}, "
                f"sigma0={self.sigma0:.4g}{pos}, message={self.message!r})")
