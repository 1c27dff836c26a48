"""Estimating the parameters: iterative least squares and Levenberg-Marquardt, in stages.

:func:`calibrate` minimises the stacked whitened residuals of
:func:`kincal.measure.base.stack`,

    theta_hat = argmin 1/2 sum_i w_i r_i(theta)^2,      r = (model - observed) / sigma,

over the *estimated* parameters (the identifiable base set of the candidates; every
other parameter is held at its initial value: the robot's nominal value, or the
block's closed-form initial guess).

Methods (each step solves the linearised problem with the SVD of ``J D^-1``, ``D`` the
column norms, so the step is the same in any units; ``J`` is never formed: the weighted
problem is compressed piece by piece to its QR triangle ``[W^1/2 J | W^1/2 r] = Q [[R, z],
[0, rho]]`` (:meth:`~kincal.measure.base.StackedProblem.compressed`), and ``R D^-1`` has
the singular values and right singular vectors of ``W^1/2 J D^-1``, ``g = U^T z``):

* ``"gauss-newton"``: exactly the lecture's iterative linearised least squares,
  ``dphi = pinv(Phi) dr``, ``phi <- phi + dphi``, recompute ``Phi``, iterate;
* ``"lm"`` (default): Levenberg-Marquardt with Marquardt's column scaling,
  ``(J^T J + lambda D^2) dx = -J^T r``; ``lambda`` adapted from the gain ratio
  ``rho = actual / predicted reduction``: a step is accepted when ``rho > 1e-4``;
  ``lambda / 10`` when ``rho > 0.75``, ``lambda * 2`` when ``rho < 0.25``; a rejected
  step multiplies ``lambda`` by 2, 4, 8 ... (starting value ``1e-3 S_max^2``).  The
  first iteration of a stage, and every one after a very successful step
  (``rho > 0.75``), first tries the undamped Gauss-Newton step and keeps it when
  ``rho > 0.25``: from a nominal robot the problem is nearly linear and the full step
  lands next to the minimum, where a damped first step costs one more linearisation.

Stopping (per stage): the remaining Gauss-Newton step is statistically negligible,
``|z| <= tol_std s0``, with ``z`` the triangle's right-hand side at the current point and
``s0^2 = min(2 cost / (M - p), 1)`` (the a-posteriori variance factor, or the stated
sigmas' when that is smaller): the step's length in the metric of the covariance,
``|R dx| = |z|``, is then at most ``tol_std`` standard errors, so with the default
``1e-3`` the minimum is a thousandth of a standard error away in any direction and the
next linearisation is not built (plain least squares only: the robust losses' weights
must settle as well, so they stop by the other rules; ``tol_std=0`` turns it off); or
the step is small, ``|dx_j| <= tol_step (1 + |x_j|)`` for every estimated ``j``
(parameters in m / rad); or the relative cost change is below ``tol_cost``; or a
Levenberg-Marquardt trial step that fails is already that small (every more damped one
is shorter still, so the stage is at a minimum to within ``tol_step``: one evaluation
instead of a dozen doublings of ``lambda``); or ``max_iter`` iterations.

Robust losses (``"huber"``, ``"cauchy"``) are iteratively reweighted least squares
per *measurement* (all residuals of one point / pose share a weight): with
``e_i = sqrt(mean_k r_ik^2)`` the RMS whitened residual of measurement ``i`` and
``c = loss_scale * s``, ``s`` a robust scale (the median of ``e_i`` divided by its
value for Gaussian noise, so ``s ~ 1`` when the stated sigmas are right),
Huber ``w = min(1, c / e)``, Cauchy ``w = 1 / (1 + (e / c)^2)``.  Measurements whose
final weight is below 0.5 are reported as outliers ``(block, row)``.

Uncertainty: ``Cov = sigma0^2 (J^T J)^-1`` over the estimated parameters at the
solution (weighted ``J``; when the last step was shorter than ``tol_step``, ``J`` where
it started: the step that ends a stage is not linearised again, and ``J`` moves by less
than the step).  By default ``sigma0^2 = sum w r^2 / (M - p)`` (the
a-posteriori variance factor: honest even when the stated sigmas are only nominal);
``trust_sigma=True`` uses ``sigma0 = 1`` (the Cramér-Rao bound of the stated noise).

Prior (MAP, optional): ``prior={name or pattern: s}`` adds, for every *estimated*
parameter it names, the pseudo-observation ``(theta_j - c_j) / s_j`` to the residuals,
``c_j`` the parameter's value before calibration (the robot's value, or the block's
closed-form guess; ``initial`` moves the start, not the centre).  The minimiser is then
the maximum a-posteriori estimate under independent Gaussian priors
``theta_j ~ N(c_j, s_j^2)`` and Gaussian measurement noise of standard deviation
``sigma0`` times the stated sigmas:

    theta_hat = argmin 1/2 [ sum_i w_i r_i^2 + sum_j (sigma0 (theta_j - c_j) / s_j)^2 ].

The noise scale ``sigma0`` is estimated before the prior is weighed (default): the
stated sigmas are often only nominal (a file without a sigma column gets 10 um while
motion capture is good to a millimetre), and with the stated ones the data would weigh
``sigma0^2`` times too much against the prior.  It is the fixed point of

    sigma0^2 = sum_i w_i r_i^2 / (M - p_eff),
    p_eff = trace((J^T J + sigma0^2 P^-2)^-1 J^T J) = p - sum_j [(J_a^T J_a)^-1]_jj sigma0^2 / s_j^2

(``J_a`` the augmented whitened Jacobian, ``p_eff`` the parameters the data fix: the
a-posteriori variance factor with the prior's share of the parameters removed): solve
with ``sigma0 = 1``, estimate ``sigma0``, solve the last stage again with the prior rows
scaled by it, until ``sigma0`` changes by less than 0.5 %.  ``noise_scale=`` a number
uses that scale instead; ``trust_sigma=True`` uses 1.

With a prior, the covariance is the posterior one, ``sigma0^2 (J^T J + sigma0^2
P^-2)^-1``, and ``data_std`` the standard errors of the measurements alone,
``sigma0 sqrt(diag (J^T J)^-1)``; a parameter whose ``data_std`` exceeds its ``s_j`` is
*held by the prior* (``held_by_prior``): the data cannot fix it to its tolerance.

Use it with standard deviations that come from outside the data, e.g. manufacturing
tolerances (1 mm on link lengths, 0.1 deg on origin angles): parameters that the data
determine well hardly move from their least-squares values, weakly determined
combinations (which a least-squares fit sets from noise) stay near their nominal
values.  The prior does not change *which* parameters are estimated: the base set is
chosen from the measurements alone, as without a prior.  ``cost`` is that of the
augmented problem; ``residuals`` are the measurements' only.

Parameter selection: ``free=None`` (automatic) makes every robot and block
parameter a candidate; ``free`` lists names or glob patterns (``theta_offset[*]``,
``tracker.*``; brackets are literal, only ``*`` and ``?`` are wildcards); ``fixed``
removes names.  Stages: ``["offsets", "all"]`` first estimates the encoder offsets
and the block parameters, then the automatic (or ``free``) set; a stage may also be
a list of names / patterns; ``"registration"`` estimates block parameters only.  In
every stage :func:`~kincal.identify.identifiability.analyze` keeps the identifiable
base set of the stage's candidates and names the rest.

Identifiability at the solution.  The base set is chosen at the stage's start, where
the model does not fit yet, and the Jacobian there can see directions that it cannot
see at a solution.  So it is checked where the stage ends, and when it fails there the
stage is solved again *from its start* with a smaller set (at most ``MAX_RESELECT``
times; the parameters dropped keep their initial values and are named in
``identifiability`` and ``message``):

* at a converged solution, estimated columns that have become dependent are dropped;
* a direction ``v`` whose only effect beyond the other parameters is to rescale the
  residual, ``J v = c r``, makes ``r(theta + e v) = (1 + c e) r``: the cost falls
  without end and there is no least-squares solution with ``r != 0``.  The scale of a
  scene seen only through contacts with planes of unknown offset is one (shrink the
  robot, the marker and the planes together: every contact distance shrinks).  At a
  consistent point ``r = 0`` hides it; away from one ``|J v| = |r|`` makes it look
  identifiable, and the solver shrinks the robot towards zero size.  Such directions
  are the dependencies of ``(I - u u^T) J``, ``u = r / |r|``, at the stage's start;
  when the stage does not converge (or its set collapses at the "solution"), the
  parameters that complete them are dropped, and the smaller set is kept if the stage
  then converges.  (With a prior the augmented problem has a minimum and no symptom
  shows: the prior then holds such a direction.)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dtrcon
from scipy.special import gammaincinv

from kincal.errors import IdentifiabilityError, KincalError
from kincal.identify.identifiability import (
    DEFAULT_TOL,
    ZERO_TOL,
    IdentifiabilityReport,
    analyze,
    default_priority,
)
from kincal.identify.names import match_names
from kincal.identify.status import StageStatus, stage_message
from kincal.identify.stopping import (
    cost_change_below,
    no_further_decrease,
    step_below,
    step_within_standard_errors,
)
from kincal.identify.uncertainty import correlation, inverse_normal_matrix, standard_errors
from kincal.measure.base import CompressedSystem, MeasurementModel, StackedProblem, stack
from kincal.robots.chain import Robot
from kincal.spatial import wrap_angle
from kincal.units import display_scale

Array = NDArray[np.float64]
#: measurement index per residual row
IndexArray = NDArray[np.integer[Any]]

__all__ = ["calibrate", "Calibration", "CalibrationResult", "IterationRecord", "match_names",
           "format_error", "METHODS", "LOSSES"]

METHODS = ("lm", "gauss-newton")
LOSSES = ("linear", "huber", "cauchy")
STAGE_KEYWORDS = ("all", "offsets", "registration")
OUTLIER_WEIGHT = 0.5
#: Largest number of times one stage is solved again with a smaller base set.
MAX_RESELECT = 3
#: Re-solves of the last stage while the noise scale settles, and its relative tolerance.
MAX_NOISE_ITER = 20
NOISE_RTOL = 5e-3
#: A stage keeps the residual vector of its current point next to its triangle when the
#: vector is at most this large [bytes], so a stage that ends there does not evaluate
#: it again; larger problems keep one residual vector at a time (memory O(P^2 + piece)
#: beyond the data and that vector).
KEEP_RESIDUALS_BYTES = 8 << 20


# --------------------------------------------------------------------------- names
def _stage_candidates(spec: str | Sequence[str], prob: StackedProblem,
                      free: Sequence[int]) -> list[int]:
    if isinstance(spec, str) and spec in STAGE_KEYWORDS:
        if spec == "all":
            return list(free)
        blocks = list(range(prob.num_robot, len(prob.names)))
        if spec == "registration":
            return blocks
        return [i for i in range(prob.num_robot) if prob.roles[i] == "offset"] + blocks
    return match_names(prob.names, spec)


def _stage_label(spec: str | Sequence[str]) -> str:
    if isinstance(spec, str):
        return spec
    text = ",".join(spec)
    return text if len(text) <= 40 else text[:37] + "..."


# --------------------------------------------------------------------------- display
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


# --------------------------------------------------------------------------- records
@dataclass
class IterationRecord:
    """One iteration of the solver.

    Attributes:
        stage: the stage's label (``"all"``, ``"offsets"`` ...).
        iteration: 0 for the starting point of the stage, then 1, 2 ...
        theta: the full parameter vector after the iteration (over ``problem.names``).
        cost: ``1/2 sum w r^2`` (whitened, robust-weighted).
        rms: RMS of the whitened residuals (dimensionless; ~1 at the noise floor).
        step: largest scaled step ``|dx_j| / (1 + |x_j|)`` of the iteration.
        damping: Levenberg-Marquardt ``lambda`` (0 for Gauss-Newton).
    """

    stage: str
    iteration: int
    theta: Array
    cost: float
    rms: float
    step: float = 0.0
    damping: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "iteration": self.iteration, "cost": float(self.cost),
                "rms": float(self.rms), "step": float(self.step),
                "damping": float(self.damping)}


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
        caption = (f"{state} after {self.iterations} iterations ({self.message}); "
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


# --------------------------------------------------------------------------- robust weights
def _robust_weights(r: Array, ids: IndexArray | None, dims: Array | None, loss: str,
                    loss_scale: float, n_fixed: int = 0) -> Array:
    """Per-residual IRLS weights from per-measurement RMS whitened residuals.

    The last ``n_fixed`` residuals (prior rows) always weigh 1 and do not enter the
    robust scale.  For ``loss="linear"`` every weight is 1 and the result is a read-only
    view (``ids``, ``dims`` are not needed and may be None).
    """
    if loss == "linear":                  # all ones: a read-only view, no (M,) array
        return np.broadcast_to(np.float64(1.0), np.shape(r))
    assert ids is not None and dims is not None
    if n_fixed:
        w = np.ones_like(r)
        w[:-n_fixed] = _robust_weights(r[:-n_fixed], ids, dims, loss, loss_scale)
        return w
    sq = np.bincount(ids, weights=r * r, minlength=len(dims))
    e = np.sqrt(sq / dims)
    # Gaussian reference: median of sqrt(chi2_d / d); the chi-square median with d degrees
    # of freedom is 2 P^-1(d/2, 1/2) (P the regularised lower incomplete gamma function)
    ref = np.sqrt(2.0 * gammaincinv(dims / 2.0, 0.5) / dims)
    s = float(np.median(e / ref))
    if not np.isfinite(s) or s <= 0:
        return np.ones_like(r)
    c = loss_scale * s
    with np.errstate(divide="ignore"):
        if loss == "huber":
            w = np.where(e <= c, 1.0, c / np.maximum(e, 1e-300))
        else:
            w = 1.0 / (1.0 + (e / c) ** 2)
    return np.asarray(w[ids], dtype=np.float64)


# --------------------------------------------------------------------------- the loop
class _WithPrior:
    """A stacked problem with prior rows ``(theta_j - c_j) / s_j`` appended (j in ``idx``).

    Offers the two methods the iteration uses (``residuals``, ``compressed``); with an
    empty ``idx`` it is the problem itself.
    """

    def __init__(self, prob: StackedProblem, idx: Sequence[int], sigma: Array,
                 center: Array) -> None:
        self.prob = prob
        self.idx = np.asarray(idx, dtype=np.intp)
        self.inv = 1.0 / np.asarray(sigma, dtype=float)
        self.center = center[self.idx]
        # the measurements' triangles (no prior rows) of the last two builds, by theta
        self._data: list[tuple[Array, CompressedSystem]] = []

    @property
    def rows(self) -> int:
        return len(self.idx)

    def _prior(self, theta: Array) -> Array:
        return (theta[self.idx] - self.center) * self.inv

    def residuals(self, theta: Array) -> Array:
        """The measurements' residuals with the prior rows after them (one vector)."""
        if not self.rows:
            return self.prob.residuals(theta)
        r = self.prob.residuals(theta, spare_rows=self.rows)
        r[-self.rows:] = self._prior(theta)
        return r

    def compressed(self, theta: Array, weights: Array, columns: Sequence[int]
                   ) -> CompressedSystem:
        """The weighted problem over ``columns`` as a QR triangle: the measurements
        compressed piece by piece (:meth:`StackedProblem.compressed`), then the prior
        rows folded in (``weights``: measurements, then prior rows, which have 1)."""
        M = len(weights) - self.rows
        # the residual vector has room for the prior rows: extend writes them, no copy
        data = self.prob.compressed(theta, weights[:M], columns, spare_rows=self.rows)
        if self.rows:
            self._data = [*self._data[-1:], (theta.copy(), dataclasses.replace(data, r=None))]
        return self.extend(data, theta)

    def num_residuals(self) -> int:
        """Measurement residuals and prior rows."""
        return self.prob.num_residuals() + self.rows

    def measurements_at(self, theta: Array) -> CompressedSystem | None:
        """The measurements' own triangle (no prior rows, without ``r``) of a recent
        :meth:`compressed` at ``theta``, if there was one."""
        for t, c in self._data:
            if np.array_equal(t, theta):
                return c
        return None

    def extend(self, c: CompressedSystem, theta: Array) -> CompressedSystem:
        """The measurements' triangle ``c`` with the prior rows (weight 1) folded in."""
        if not self.rows:
            return c
        pos = {int(j): k for k, j in enumerate(c.columns)}
        A = np.zeros((self.rows, len(pos)))
        for k, j in enumerate(self.idx):
            A[k, pos[int(j)]] = self.inv[k]
        prior = self._prior(theta)
        out = dataclasses.replace(c, r=None).with_rows(A, prior)
        if c.r is None:
            return out
        M = self.prob.num_residuals()
        if c.r.size == M + self.rows:          # room left for the prior rows (compressed)
            r = c.r
            r[M:] = prior
        else:
            r = np.concatenate([c.r, prior])
        return dataclasses.replace(out, r=r)


def _tolerance_prior(robot: Robot, prob: StackedProblem, which: str) -> dict[str, float]:
    """``prior="tolerances"``: ``{name: tolerance}`` of the problem's robot parameters."""
    from kincal.identify.tolerances import resolve_tolerances

    if which != "tolerances":
        raise KincalError(f"prior must be a mapping {{name: sigma}}, 'tolerances' or None; "
                          f"got {which!r}")
    meta = getattr(robot, "meta", {}) or {}
    return resolve_tolerances(prob.names, prob.units, prob.roles,
                              meta.get("tolerances"), None).prior()


def _prior_sigmas(names: Sequence[str], prior: Mapping[str, float] | None) -> dict[int, float]:
    """``{parameter index: sigma}`` from ``{name or pattern: sigma}`` (later keys win)."""
    out: dict[int, float] = {}
    for pattern, sigma in (prior or {}).items():
        s = float(sigma)
        if not (np.isfinite(s) and s > 0):
            raise KincalError(f"prior standard deviation of {pattern!r} must be positive and "
                              f"finite, got {sigma!r}")
        for i in match_names(names, pattern):
            out[i] = s
    return out


def _noise_scale(aug: _WithPrior, r: Array, data: CompressedSystem, theta: Array,
                 ids: IndexArray | None, dims: Array | None, loss: str, loss_scale: float,
                 scale: float
                 ) -> tuple[float | None, float | None]:
    """The measurements' noise scale ``sigma0`` at a MAP solution, and ``p_eff``.

    ``sigma0^2 = sum w r^2 / (M - p_eff)`` over the measurement rows,
    ``p_eff = p - sum_j [(J_a^T J_a)^-1]_jj (scale / s_j)^2`` (``J_a``: ``data`` with the
    prior rows of ``aug``, whose weights are ``scale / s_j``).  None when there is no
    redundancy left.
    """
    M = len(r) - aug.rows
    w = _robust_weights(r, ids, dims, loss, loss_scale, aug.rows)[:M]
    ss = float(np.sum(w * r[:M] ** 2))
    try:
        inv = inverse_normal_matrix(aug.extend(data, theta).R)
    except IdentifiabilityError:
        return None, None
    pos = {int(j): k for k, j in enumerate(data.columns)}
    shrink = sum(inv[pos[int(j)], pos[int(j)]] * aug.inv[k] ** 2
                 for k, j in enumerate(aug.idx))
    p_eff = len(data.columns) - float(shrink)
    if M - p_eff <= 0 or ss <= 0:
        return None, p_eff
    return float(np.sqrt(ss / (M - p_eff))), p_eff


def _data_only_std(R: Array, sigma0: float) -> Array:
    """``sigma0 sqrt(diag (R^T R)^-1)``: the standard errors the measurements alone give
    (inf for parameters in a direction they cannot see)."""
    try:
        return sigma0 * standard_errors(inverse_normal_matrix(R))
    except IdentifiabilityError:
        D = np.linalg.norm(R, axis=0)
        D = np.where(D > 0, D, 1.0)
        _, S, Vt = np.linalg.svd(R / D, full_matrices=False)
        ok = S > S[0] * 1e-12 if S.size else S > 0
        var = np.sum((Vt[ok].T / S[ok]) ** 2, axis=1)
        blind = np.any(np.abs(Vt[~ok]) > 1e-8, axis=0)
        return np.where(blind, np.inf, sigma0 * np.sqrt(var) / D)


def _columns(c: CompressedSystem, idx: Sequence[int]) -> CompressedSystem:
    """The triangle ``c`` reduced to the parameters ``idx`` (a subset of its columns)."""
    if [int(j) for j in c.columns] == [int(i) for i in idx]:
        return c
    where = {int(j): k for k, j in enumerate(c.columns)}
    return c.select([where[int(i)] for i in idx])


def _independent(R: Array, tol: float | None) -> bool:
    """Whether :func:`analyze` of ``R`` would keep every column, known without it: no
    column is zero (``ZERO_TOL``) and the columns scaled to unit norm have a smallest
    singular value above twice the tolerance.  (The analysis keeps a column when its
    distance from the span of those kept before it, and the smallest singular value of
    the kept ones, exceed ``tol``; both are at least that of all the columns.)"""
    norms = np.linalg.norm(R, axis=0)
    big = float(norms.max()) if norms.size else 0.0
    if not big > 0 or np.any(norms <= ZERO_TOL * big):
        return False
    s = np.linalg.svd(R / norms, compute_uv=False)
    return bool(s[-1] > 2.0 * (DEFAULT_TOL if tol is None else tol))


def _reselections(prob: StackedProblem, est: list[int], at_start: CompressedSystem,
                  at_end: CompressedSystem, converged: bool, tol: float | None,
                  report: bool = False
                  ) -> tuple[list[tuple[list[int], IdentifiabilityReport, str, bool]],
                             IdentifiabilityReport | None]:
    """Smaller base sets to try when the estimated set ``est`` fails where a stage ended.

    The base set is chosen at the stage's start, from the Jacobian ``J`` of a model that
    does not fit the data yet; there ``J`` can see directions that it cannot see at a
    solution.  Only the measurements decide (no prior rows; ``J``, ``r`` robust-weighted).

    * **Dependent at the solution**: :func:`analyze` of ``J`` over ``est`` where the
      stage ended (at a minimum ``J^T r = 0``); a column that has become dependent
      there cannot be estimated.
    * **Residual-rescaling directions**: a direction ``v`` of the estimated parameters
      that only rescales the residual, ``J v = c r``, gives ``r(theta + e v) =
      (1 + c e) r`` to first order; when that holds along the whole line (a
      homogeneous model) the cost falls without end, the least-squares problem has no
      minimum with ``r != 0``, and the solver walks towards a degenerate model (the
      stage does not converge, or "converges" where the base set collapses).  The
      scale of a scene seen only through contacts with planes of unknown offset is
      one: shrinking the robot, the marker and the planes together shrinks every
      contact distance, ``J v = r`` exactly everywhere.  Such a ``v`` is a dependency
      of the columns with the residual projected out, ``(I - u u^T) J``,
      ``u = r / |r|`` (:meth:`CompressedSystem.residual_free`, from the triangle:
      its Gram matrix is ``R^T R - (R^T z)(R^T z)^T / (|z|^2 + rho^2)``), at the
      stage's start, where the set
      was chosen; the parameter that completes it (last in the analysis' priority
      order) is the one to hold.  A consistent (noise-free, linear) model also
      has ``r`` in the range of ``J`` there, so this is only a *suspect*: it is tried
      when the stage shows a symptom (no convergence, or a set that shrinks at the
      solution), and kept only if the stage then converges.

    Args:
        prob: the stacked problem (names, roles).
        est: the estimated set (indices into ``prob.names``).
        at_start, at_end: the QR triangles (:meth:`StackedProblem.compressed`) of the
            measurements (no prior rows, robust weights ``W``) at the stage's start and
            where it ended, over columns that include ``est``.
        converged: whether the stage converged.
        tol: the analysis tolerance.

        report: always return the analysis where the stage ended (otherwise None
            when a converged stage's set plainly stands, :func:`_independent`).

    Returns:
        ``(options, analysis where the stage ended)``; each option is
        ``(indices to drop, the analysis that found them, why, needs convergence)``,
        the suspects first.  No options: the set stands.
    """
    names = [prob.names[i] for i in est]
    roles = [prob.roles[i] for i in est]
    c = _columns(at_end, est)
    if converged and not report and _independent(c.R, tol):
        return [], None
    end = analyze(c.R if converged else c.residual_free(), names, tol=tol, roles=roles)
    lost = [i for i, n in zip(est, names, strict=True) if n not in set(end.identifiable)]
    if converged and not lost:
        return [], end
    start = analyze(_columns(at_start, est).residual_free(), names, tol=tol, roles=roles)
    suspects = [i for i, n in zip(est, names, strict=True) if n not in set(start.identifiable)]
    options = []
    if suspects:
        options.append((suspects, start, "only rescale(s) the residuals (a direction with "
                        "J v = c r at the stage's start)", True))
    if lost:
        where = "at the solution" if converged else "where the stage stopped"
        options.append((lost, end, f"became dependent {where}", not converged))
    return options, end


def _drop_from_report(report: IdentifiabilityReport, check: IdentifiabilityReport,
                      lost: Sequence[str]) -> IdentifiabilityReport:
    """``report`` with the names ``lost`` moved from the base set to the not identifiable
    ones, with the dependencies ``check`` found for them."""
    gone = set(lost)
    dependent, combinations, residual = (dict(report.dependent), dict(report.combinations),
                                         dict(report.residual))
    unobservable = list(report.unobservable)
    for n in lost:
        if n in check.unobservable:
            unobservable.append(n)
        else:
            dependent[n] = list(check.dependent.get(n, []))
            combinations[n] = dict(check.combinations.get(n, {}))
            residual[n] = float(check.residual.get(n, 0.0))
    identifiable = [n for n in report.identifiable if n not in gone]
    return dataclasses.replace(
        report, identifiable=identifiable, unobservable=unobservable, dependent=dependent,
        combinations=combinations, residual=residual, rank=len(identifiable),
        cond_scaled=check.cond_scaled, cond_unscaled=check.cond_unscaled,
        weak={k: v for k, v in report.weak.items() if k not in gone})


def _half_weighted_ss(r: Array, w: Array) -> float:
    """``1/2 sum w r^2`` without an (M,) temporary when the weights are uniform."""
    if not r.size:
        return 0.0
    if w.ndim and w.strides[0] == 0:
        return 0.5 * float(w[0]) * float(r @ r)
    return 0.5 * float((w * r) @ r)


def _scaled_step(dx: Array, x: Array) -> float:
    return float(np.max(np.abs(dx) / (1.0 + np.abs(x)))) if dx.size else 0.0


class _StageEnd(NamedTuple):
    """What :func:`_run_stage` ends with; ``r`` (prior rows included) at ``theta``."""

    theta: Array
    status: StageStatus
    iterations: int
    message: str
    r: Array
    #: the triangle at ``theta`` over the stage's columns, when the stage has it (prior
    #: rows included, as the stage used it; without ``r``); None otherwise
    C: CompressedSystem | None = None
    #: the same without the prior rows (the measurements' own), when the stage has it
    data: CompressedSystem | None = None
    #: ``C`` and ``data`` were built at ``theta``; False when the stage ended on a step
    #: shorter than tol_step, whose triangle was not built: they are those where that
    #: step started (``R`` stands for the one at ``theta``; ``z``, ``rho``, ``cost`` do not)
    exact: bool = True

    @property
    def converged(self) -> bool:
        """Whether the stage ended at a minimum (derived from ``status``)."""
        return self.status.converged


def _triangular_step(A: Array, z: Array) -> Array | None:
    """The undamped step ``-A^-1 z`` for the upper-triangular ``A`` (p, p) when ``A`` is
    safely nonsingular, else None.

    "Safely": LAPACK's estimate of the reciprocal 1-norm condition number above
    ``1e-9 p``, so that the 2-norm condition number (at most ``p`` times the 1-norm one)
    stays three orders below the ``1e12`` at which the SVD step drops singular values:
    the step is then the SVD step with every singular value kept.
    """
    p = A.shape[0]
    if p == 0:
        return None
    rcond, info = dtrcon(A)
    if info != 0 or not rcond > 1e-9 * p:
        return None
    dx = solve_triangular(A, -z, check_finite=False)
    return dx if np.all(np.isfinite(dx)) else None


def _run_stage(prob: StackedProblem | _WithPrior, theta: Array, est: list[int], label: str,
               method: str, loss: str, loss_scale: float, max_iter: int, tol_step: float,
               tol_cost: float,
               ids: IndexArray | None, dims: Array | None, history: list[IterationRecord],
               progress: Callable[[IterationRecord], Any] | None, n_fixed: int = 0,
               start: CompressedSystem | None = None, tol_std: float = 0.0) -> _StageEnd:
    """Iterate one stage to convergence from ``theta`` over the columns ``est``.

    ``prob`` is a :class:`StackedProblem` or a :class:`_WithPrior` whose ``n_fixed``
    trailing prior rows keep weight 1.  Each linearisation is the QR triangle of the
    weighted problem over ``est`` (``prob.compressed``; ``start``: the one at ``theta``
    if the caller has it), never the (M, P) Jacobian.  Returns the final ``theta``,
    whether it converged, the iterations, a message, and ``r`` (prior rows included)
    at that ``theta``.
    """
    # With weights that do not depend on the residuals (loss "linear"), the triangle at a
    # trial point is the next linearisation if the step is taken: it is built with the
    # trial's residuals in the same pass over the data (no forward kinematics evaluated
    # twice at the same theta).  The current residuals are dropped while a step is tried
    # (one residual vector in memory; the triangle ``here`` at the current point is kept,
    # and its cost stands for theirs) and evaluated again only on the exits that end the
    # stage at the current point, unless the vector is small enough to keep
    # (KEEP_RESIDUALS_BYTES: ``r_here``, the residuals where ``here`` was built).
    speculate = loss == "linear"
    keep_r = speculate and 8 * prob.num_residuals() <= KEEP_RESIDUALS_BYTES
    C, start = start, None                  # no reference to a residual vector is kept
    r: Array | None = None if C is None else C.r
    r_here = r if keep_r else None
    if r is None and not (speculate and C is not None):
        r = prob.residuals(theta)
    w = (np.broadcast_to(np.float64(1.0), (prob.num_residuals(),)) if speculate
         else _robust_weights(r, ids, dims, loss, loss_scale, n_fixed))  # type: ignore[arg-type]
    # the triangle at theta without its residual vector, while theta stays
    here = None if C is None else dataclasses.replace(C, r=None)
    # where ``here`` was built: theta, except after a last step shorter than tol_step,
    # which the stage takes without building its triangle (it ends there; the triangle
    # where that step started stands for it: J differs by the step, < tol_step)
    here_theta = theta

    def current() -> Array:
        nonlocal r
        if r is None:
            r = r_here if r_here is not None and here_theta is theta else prob.residuals(theta)
        return r

    def done(status: StageStatus, iterations: int) -> _StageEnd:
        data = prob.measurements_at(here_theta) if isinstance(prob, _WithPrior) and prob.rows \
            else here
        message = stage_message(status, label, tol_std=tol_std, max_iter=max_iter)
        return _StageEnd(theta, status, iterations, message, current(), here, data,
                         here_theta is theta)

    cost_of = _half_weighted_ss

    def cost_here() -> float:
        """``1/2 sum w r^2`` at theta: from the residuals, or (uniform weights) the
        triangle's cost when they were dropped."""
        if r is None and here is not None and speculate:
            return float(here.cost)
        return cost_of(current(), w)

    def record(it: int, step: float, lam: float) -> None:
        cost = cost_here()
        size = w.size
        rms = (float(np.sqrt(2.0 * cost / float(w[0]) / size)) if r is None and size
               else float(np.sqrt(r @ r / size)) if size else 0.0)  # type: ignore[operator]
        rec = IterationRecord(label, it, theta.copy(), cost, rms, step, lam)
        history.append(rec)
        if progress is not None:
            progress(rec)

    record(0, 0.0, 0.0)
    if not est:
        return done(StageStatus.NOTHING_TO_ESTIMATE, 0)
    lam, nu = -1.0, 2.0
    Dmax = np.zeros(len(est))
    C_new: CompressedSystem | None = None
    r_new: Array | None = None
    dof = prob.num_residuals() - len(est)
    for it in range(1, max_iter + 1):
        if here is None:
            C = prob.compressed(theta, w, est)
            r, here, here_theta = C.r, dataclasses.replace(C, r=None), theta
            r_here = r if keep_r else None
        # [W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]]: R D^-1 = U S V^T, g = U^T z
        D = np.linalg.norm(here.R, axis=0)
        Dmax = np.maximum(Dmax, D)
        Ds = np.where(Dmax > 0, Dmax, 1.0)
        A = here.R / Ds
        cost = cost_here()
        if not np.isfinite(cost):
            return done(StageStatus.NON_FINITE_RESIDUALS, it - 1)
        # the full Gauss-Newton step moves |R dx| = |z| (at most): within tol_std
        # standard errors the stage is at its minimum (s0^2 = 2 cost / dof, or 1 if
        # smaller: never looser than the stated sigmas' standard errors)
        if (speculate and here_theta is theta
                and step_within_standard_errors(float(here.z @ here.z), cost, dof, tol_std)):
            return done(StageStatus.WITHIN_STANDARD_ERRORS, it - 1)
        C = r = C_new = r_new = None                        # see `speculate` above
        if method == "gauss-newton":
            U_gn, S_gn, Vt_gn = np.linalg.svd(A)
            g_gn = U_gn.T @ here.z
            kept = S_gn > S_gn[0] * 1e-12
            z = -Vt_gn[kept].T @ (g_gn[kept] / S_gn[kept])
            dx = z / Ds
            new = theta.copy()
            new[est] += dx
            step = _scaled_step(dx, theta[est])
            # a step within tol_step ends the stage: no triangle there (see here_theta)
            C_new = prob.compressed(new, w, est) if speculate and step > tol_step else None
            r_new = prob.residuals(new) if C_new is None else C_new.r
            assert r_new is not None            # C_new.r: built with its residuals
            c_new = cost_of(r_new, w)
            if not np.isfinite(c_new):
                return done(StageStatus.GAUSS_NEWTON_DIVERGED, it - 1)
            theta, r = new, r_new
            if C_new is not None:
                here, here_theta = dataclasses.replace(C_new, r=None), theta
                r_here = r if keep_r else None
            elif not (speculate and step <= tol_step):
                here = None
            w = _robust_weights(r, ids, dims, loss, loss_scale, n_fixed)
            record(it, step, 0.0)
            if step_below(step, tol_step):
                return done(StageStatus.STEP_BELOW_TOL, it)
            if cost_change_below(cost, c_new, tol_cost):
                return done(StageStatus.COST_CHANGE_BELOW_TOL, it)
            continue
        # Levenberg-Marquardt
        if lam < 0:
            S0 = float(np.linalg.svd(A, compute_uv=False)[0]) if A.size else 1.0
            lam = 1e-3 * S0**2
            good = True                     # the first trial is the Gauss-Newton step
        # the SVD of A = R D^-1 (U S V^T, g = U^T z) serves every damped trial; an
        # undamped trial on a well-conditioned A is the triangular solve A dx = -z (the
        # same step: every singular value kept), so the SVD is made only when needed
        S: Array | None = None
        S2: Array | None = None
        g: Array | None = None
        Vt: Array | None = None
        keep: NDArray[np.bool_] | None = None
        tiny = False
        # After a very successful step, first try the undamped Gauss-Newton step: in a
        # long curved valley (a weakly determined direction) it saves many iterations.
        try_gn = good
        first = True
        for _ in range(60):
            lam_k = 0.0 if try_gn else lam
            step_gn = _triangular_step(A, here.z) if try_gn and S is None else None
            if step_gn is not None:
                dx = step_gn / Ds
                pred = 0.5 * float(here.z @ here.z)
            else:
                if S is None:
                    U, S, Vt = np.linalg.svd(A)
                    g = U.T @ here.z
                    S2 = S * S
                    keep = S > S[0] * 1e-12
                assert S2 is not None and keep is not None and g is not None and Vt is not None
                f = np.where(keep, S / np.where(keep, S2 + lam_k, 1.0), 0.0)
                dx = -(Vt.T @ (f * g)) / Ds
                pred = 0.5 * float(np.sum(g * g) - np.sum(
                    np.where(keep, g * lam_k / (S2 + lam_k), g) ** 2))
            new = theta.copy()
            new[est] += dx
            # A trial step within tol_step ends the stage whether it is taken or not: if
            # it fails, every further (more damped) one is shorter still (in the scaled
            # norm), so whatever it found would end the stage on the step rule with theta
            # changed by about tol_step at most; stop here (one evaluation rather than a
            # dozen doublings of lambda).  Its triangle is not built (see here_theta).
            tiny = _scaled_step(dx, theta[est]) <= tol_step
            # the first trial of an iteration is usually taken: build its triangle now
            C_new = prob.compressed(new, w, est) if speculate and first and not tiny else None
            first = False
            r_new = prob.residuals(new) if C_new is None else C_new.r
            assert r_new is not None            # C_new.r: built with its residuals
            c_new = cost_of(r_new, w)
            rho = (cost - c_new) / pred if pred > 0 else (0.0 if c_new > cost else 1.0)
            if try_gn:
                try_gn = False
                if np.isfinite(c_new) and rho > 0.25:
                    good = rho > 0.75
                    break
                if tiny:
                    break
                continue
            if np.isfinite(c_new) and rho > 1e-4:
                good = rho > 0.75
                # Marquardt's rule with a fast decrease: a weakly determined direction
                # (small singular value) is only reached once lambda is below it.
                if rho > 0.75:
                    lam = max(lam / 10.0, 1e-300)
                elif rho < 0.25:
                    lam *= 2.0
                nu = 2.0
                break
            if tiny:
                break
            lam *= nu
            nu *= 2.0
            if no_further_decrease(pred, cost, lam):
                record(it, 0.0, lam)
                return done(StageStatus.NO_FURTHER_DECREASE, it)
        else:
            return done(StageStatus.DAMPING_FAILED, it)
        if tiny and not (np.isfinite(c_new) and c_new < cost):
            record(it, 0.0, lam)
            return done(StageStatus.NO_DESCENT_STEP, it)
        step = _scaled_step(dx, theta[est])
        theta, r = new, r_new                    # C_new: the triangle there, if built
        if C_new is not None:
            here, here_theta = dataclasses.replace(C_new, r=None), theta
            r_here = r if keep_r else None
        elif not (speculate and tiny):
            here = None
        w_old = w
        w = _robust_weights(r, ids, dims, loss, loss_scale, n_fixed)
        record(it, step, lam)
        if step_below(step, tol_step):
            return done(StageStatus.STEP_BELOW_TOL, it)
        if (cost_change_below(cost, c_new, tol_cost, absolute=False)
                and np.allclose(w, w_old, atol=1e-6)):
            return done(StageStatus.COST_CHANGE_BELOW_TOL, it)
        if c_new == 0.0:
            return done(StageStatus.ZERO_RESIDUAL, it)
    return done(StageStatus.MAX_ITER_REACHED, max_iter)


def calibrate(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
              free: Sequence[str] | str | None = None, fixed: Sequence[str] | str = (),
              method: str = "lm", stages: Sequence[str | Sequence[str]] | None = None,
              loss: str = "linear", loss_scale: float = 3.0, max_iter: int = 100,
              tol_step: float = 1e-10, tol_cost: float = 1e-14,
              progress: Callable[[IterationRecord], Any] | None = None, *,
              tol_std: float = 1e-3,
              trust_sigma: bool = False, tol_rank: float | None = None,
              initial: dict[str, float] | None = None,
              prior: Mapping[str, float] | str | None = None,
              noise_scale: float | None = None,
              prefer: Sequence[str] | str = ()) -> CalibrationResult:
    """Calibrate ``robot`` from measurement ``blocks``.

    Args:
        robot: the nominal robot (initial values of its parameters).
        blocks: one or more :class:`~kincal.measure.base.MeasurementModel`.
        free: ``None`` = automatic (all parameters are candidates, the identifiable
            base set is estimated); or names / glob patterns of the candidates.
        fixed: names / patterns removed from the candidates.
        method: ``"lm"`` (Levenberg-Marquardt, default) or ``"gauss-newton"``.
        stages: e.g. ``["offsets", "all"]``; each entry a keyword (``all``,
            ``offsets``, ``registration``) or a list of names / patterns.
        loss: ``"linear"``, ``"huber"`` or ``"cauchy"`` (IRLS per measurement).
        loss_scale: robust threshold in units of the robust residual scale.
        max_iter, tol_step, tol_cost: stopping rules per stage (see module docstring).
        tol_std: a stage stops when its remaining Gauss-Newton step is at most this
            many standard errors long (module docstring, "Stopping"); 0 turns it off.
        progress: called with every :class:`IterationRecord`.
        trust_sigma: use ``sigma0 = 1`` for the covariance instead of the a-posteriori
            estimate.
        tol_rank: tolerance of the identifiability analysis (default 1e-8).
        initial: starting values ``{name: value}`` overriding nominal / closed-form
            initial guesses.
        prior: prior standard deviations ``{name or pattern: s}`` [m / rad] of a
            maximum a-posteriori estimate centred on the values before calibration
            (see the module docstring); a later key overrides an earlier one for
            the names both match.  Only estimated parameters are affected.
            ``"tolerances"``: the manufacturing tolerances of every robot parameter
            (role defaults, then the robot file's ``tolerances:`` section;
            :mod:`kincal.identify.tolerances`) as prior standard deviations, which is
            what ``kincal calibrate`` does by default.  None: plain least squares.
        noise_scale: with a prior, the factor ``sigma0`` of the stated measurement
            sigmas used to weigh it; None (default) estimates it (module docstring,
            "Prior"), 1 under ``trust_sigma``.
        prefer: names / patterns kept first when the base set is chosen (before every
            role's default priority): of a dependent group, these are estimated and the
            others held, e.g. a shared tool point as ``tool.x/y/z`` rather than the last
            link's lengths, which carry a prior.

    Returns:
        A :class:`CalibrationResult`.  Parameters that cannot be identified are never
        estimated: they keep their initial value, ``std`` 0 and are named with the
        reason in ``result.identifiability``.  That includes parameters found
        non-identifiable where a stage ended (dependent at the solution, or completing
        a direction that only rescales the residuals); the stage is then solved again
        from its start without them (module docstring, "Identifiability at the
        solution").
    """
    if not isinstance(robot, Robot):
        raise KincalError(f"calibrate takes a serial Robot, not a {type(robot).__name__}; a "
                          "five-bar calibrates with kincal.parallel.file_calibration."
                          "calibrate_fivebar_file or kincal.parallel.calibration.calibrate")
    if method not in METHODS:
        raise KincalError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    if loss not in LOSSES:
        raise KincalError(f"unknown loss {loss!r}; use one of {', '.join(LOSSES)}")
    if isinstance(blocks, MeasurementModel):
        blocks = [blocks]
    prob, theta0 = stack(robot, list(blocks))
    center = theta0.copy()
    if isinstance(prior, str):
        prior = _tolerance_prior(robot, prob, prior)
    prior_s = _prior_sigmas(prob.names, prior)
    if noise_scale is not None and not (np.isfinite(noise_scale) and noise_scale > 0):
        raise KincalError(f"noise_scale must be positive and finite, got {noise_scale!r}")
    estimate_noise = bool(prior_s) and noise_scale is None and not trust_sigma
    # sigma0 of the measurements while the prior is weighed (prior rows scaled by it)
    scale = [1.0 if noise_scale is None else float(noise_scale)]

    def with_prior(est: Sequence[int]) -> _WithPrior:
        idx = [i for i in est if i in prior_s]
        return _WithPrior(prob, idx, np.array([prior_s[i] for i in idx]) / scale[0], center)

    if initial:
        for name, v in initial.items():
            theta0[prob.index(name)] = float(v)
    names = prob.names
    cand = list(range(len(names))) if free is None else match_names(names, free)
    preferred = set(match_names(names, prefer)) if prefer else set()
    fixed_idx = set(match_names(names, fixed)) if fixed else set()
    cand = [i for i in cand if i not in fixed_idx]
    specs: list[str | Sequence[str]] = list(stages) if stages else ["all"]
    M = prob.num_residuals()
    # measurement ids and sizes only for a robust loss (weights per measurement)
    ids = prob.measurement_ids() if loss != "linear" else None
    dims = np.bincount(ids).astype(float) if ids is not None else None
    history: list[IterationRecord] = []
    theta = theta0.copy()
    stage_info: list[tuple[str, list[str]]] = []
    messages: list[str] = []
    stage_status: list[tuple[str, StageStatus]] = []
    converged = True
    total_it = 0
    report: IdentifiabilityReport | None = None
    est: list[int] = []

    def weights_of(res: Array) -> Array:
        return _robust_weights(res, ids, dims, loss, loss_scale)

    def solve(idx: list[int], theta_start: Array, label: str, at: CompressedSystem | None
              ) -> _StageEnd:
        """Run a stage over ``idx`` from ``theta_start`` (``at``: the measurements'
        triangle there, over columns that include ``idx``, or None)."""
        aug = with_prior(idx)
        first = None if at is None else aug.extend(_columns(at, idx), theta_start)
        return _run_stage(aug, theta_start, idx, label, method, loss, loss_scale, max_iter,
                          tol_step, tol_cost, ids, dims, history, progress, aug.rows, first,
                          tol_std)

    def ended(stage: _StageEnd, columns: Iterable[int]) -> tuple[CompressedSystem, bool]:
        """The measurements' triangle (robust weights, no prior rows) where ``stage``
        ended, over ``columns``: the one the stage built when it is that one (uniform
        weights, the same columns); and whether it is at the stage's end (else it is
        where the stage's last step, shorter than tol_step, started: its ``R`` stands
        for the one at the end, not its ``z``; see ``_StageEnd.exact``)."""
        cols = sorted(set(columns))
        C = stage.data
        if (C is not None and loss == "linear" and [int(j) for j in C.columns] == cols
                and (stage.exact or stage.converged)):
            return dataclasses.replace(C, r=None), stage.exact
        return prob.compressed(stage.theta, weights_of(stage.r[:M]), cols,
                               keep_residuals=False), True

    all_cand = [[i for i in _stage_candidates(spec, prob, cand) if i not in fixed_idx]
                for spec in specs]
    last: _StageEnd | None = None
    end_c: CompressedSystem | None = None
    end_exact = True
    for k, spec in enumerate(specs):
        label = _stage_label(spec)
        stage_cand = all_cand[k]
        # the next stage starts where this one ends: its triangle covers both
        after = all_cand[k + 1] if k + 1 < len(specs) else []
        start = theta.copy()
        # the weighted measurements at the stage's start, compressed to a triangle
        if end_c is None or not end_exact:
            w0 = None if loss == "linear" else weights_of(prob.residuals(start))
            at_start = prob.compressed(start, w0, stage_cand, keep_residuals=False)
        else:
            at_start = _columns(end_c, stage_cand)
        cand_roles = [prob.roles[i] for i in stage_cand]
        priority = default_priority([names[i] for i in stage_cand], cand_roles)
        priority[[k for k, i in enumerate(stage_cand) if i in preferred]] = -1
        report = analyze(at_start.R, [names[i] for i in stage_cand],
                         tol=tol_rank, roles=cand_roles, priority=priority)
        est = sorted(names.index(n) for n in report.identifiable)
        last = solve(est, start, label, at_start)
        end_c, end_exact = ended(last, [*est, *after])
        total_it += last.iterations
        # The base set was chosen at the stage's start; check it where the stage ended
        # and, if it fails there, solve the stage again from its start with a smaller
        # set (see _reselections).
        reselected = False
        for _ in range(MAX_RESELECT):
            options, end = _reselections(prob, est, at_start, end_c, last.converged, tol_rank,
                                         report=reselected)
            if not options and reselected:      # the final set's conditioning, at its end
                assert end is not None
                report = dataclasses.replace(report, cond_scaled=end.cond_scaled,
                                             cond_unscaled=end.cond_unscaled)
            accepted = False
            for drop, check, why, needs_convergence in options:
                lost = [names[i] for i in drop]
                kept = [i for i in est if i not in drop]
                n_hist = len(history)
                again = solve(kept, start, label, at_start)
                if needs_convergence and not again.converged:
                    del history[n_hist:]        # did not help: forget that attempt
                    continue
                messages.append(f"stage {label!r}: {', '.join(lost[:6])}"
                                f"{' ...' if len(lost) > 6 else ''} {why}; solved the stage "
                                f"again from its start with {len(kept)} parameters")
                report = _drop_from_report(report, check, lost)
                est, last = kept, again
                end_c, end_exact = ended(last, [*est, *after])
                total_it += again.iterations
                reselected = accepted = True
                break
            if not accepted:
                break
        theta = last.theta
        stage_info.append((label, [names[i] for i in est]))
        earlier_ok = converged
        converged &= last.converged
        messages.append(last.message)
        stage_status.append((label, last.status))
    assert report is not None and last is not None and end_c is not None
    p_eff = None
    if estimate_noise and est:
        # the noise scale before the prior is weighed: re-solve the last stage with the
        # prior rows scaled by the estimated sigma0 until it settles
        label = stage_info[-1][0]
        for _ in range(MAX_NOISE_ITER):
            new, p_eff = _noise_scale(with_prior(est), last.r, _columns(end_c, est), theta,
                                      ids, dims, loss, loss_scale, scale[0])
            if new is None or abs(new / scale[0] - 1.0) < NOISE_RTOL:
                break
            scale[0] = new
            last = solve(est, theta, label, end_c if end_exact else None)
            theta = last.theta
            end_c, end_exact = ended(last, est)
            total_it += last.iterations
            converged = earlier_ok and last.converged
            messages[-1] = last.message
            stage_status[-1] = (label, last.status)
        else:
            messages.append(f"the noise scale did not settle in {MAX_NOISE_ITER} re-solves "
                            f"(sigma0 = {scale[0]:.4g})")
    # final statistics over the last stage's estimated set (prior rows included), at the
    # last stage's solution, from its triangle: R^T R = J^T W J over ``est``
    aug = with_prior(est)
    r = last.r
    w = _robust_weights(r, ids, dims, loss, loss_scale, aug.rows)
    Jw = aug.extend(_columns(end_c, est), theta).R
    dof = len(r) - len(est)
    if trust_sigma:
        sigma0 = 1.0
    elif prior_s and est:
        sigma0 = scale[0]
        if estimate_noise:
            got, p_eff = _noise_scale(aug, r, _columns(end_c, est), theta, ids, dims, loss,
                                      loss_scale, scale[0])
            sigma0 = scale[0] if got is None else got
    elif dof > 0:
        sigma0 = float(np.sqrt(2.0 * _half_weighted_ss(r, w) / dof))
    else:
        sigma0 = 1.0
        messages.append("no redundancy (measurements <= parameters): sigma0 set to 1")
    std = np.zeros(len(names))
    cov = corr = np.zeros((0, 0))
    # with a prior the posterior covariance uses the scale the prior was weighed with
    cov_scale = scale[0] if (prior_s and est and not trust_sigma) else sigma0
    if est:
        try:
            cov = cov_scale**2 * inverse_normal_matrix(Jw)
        except IdentifiabilityError:
            # still dependent after re-selection: report only the independent subset
            check = analyze(Jw, [names[i] for i in est], tol=tol_rank,
                            roles=[prob.roles[i] for i in est])
            keep = [k for k, i in enumerate(est) if names[i] in set(check.identifiable)]
            messages.append("the estimated set is rank deficient at the solution; "
                            f"{len(est) - len(keep)} parameter(s) have no standard error: "
                            + ", ".join(check.not_identifiable[:6]))
            est = [est[k] for k in keep]
            Jw = Jw[:, keep]
            converged = False
            cov = cov_scale**2 * inverse_normal_matrix(Jw)
        std[est] = standard_errors(cov)
        corr = correlation(cov)
    outliers = []
    if loss != "linear":
        assert ids is not None and dims is not None
        wm = np.ones(len(dims))
        wm[ids] = w[:M]
        bnames = prob.block_names
        bi, rows = prob.owners()
        first = np.unique(ids, return_index=True)[1]
        outliers = [(bnames[bi[first[m]]], int(rows[first[m]]))
                    for m in np.flatnonzero(wm < OUTLIER_WEIGHT)]
    held = [n for n in report.not_identifiable]
    if free is not None and held:
        messages.append(f"{len(held)} requested parameter(s) not identifiable, held at their "
                        f"initial values: {', '.join(held[:8])}{' ...' if len(held) > 8 else ''}")
    data_std, held_by_prior = None, []
    pri = {names[i]: prior_s[i] for i in est if i in prior_s}
    if pri:
        data_std = np.full(len(names), np.nan)
        data_std[est] = _data_only_std(_columns(end_c, est).R, cov_scale)
        held_by_prior = [names[i] for i in est
                         if names[i] in pri and not data_std[i] <= pri[names[i]]]
    # an encoder offset c and c + 2 pi k are the same robot: report it in (-pi, pi]
    for i, (role, unit) in enumerate(zip(prob.roles, prob.units, strict=True)):
        if role == "offset" and unit == "rad":
            theta[i] = float(wrap_angle(theta[i]))
    robot_cal, _ = prob.split(theta)
    return CalibrationResult(
        robot=robot_cal, robot_initial=robot, problem=prob, theta0=theta0, theta=theta,
        names=names, estimated=[names[i] for i in est], identifiability=report, std=std,
        covariance=cov, correlation=corr, sigma0=sigma0, residuals=r[:M], weights=w[:M],
        outliers=outliers, history=history, converged=bool(converged), iterations=total_it,
        message="; ".join(messages), stages=stage_info, method=method, loss=loss,
        prior=pri, data_std=data_std, held_by_prior=held_by_prior,
        noise_scale_estimated=estimate_noise, stage_status=stage_status,
        effective_parameters=None if p_eff is None else float(p_eff))


class Calibration:
    """scikit-learn-style estimator around :func:`calibrate`.

    Example::

        result = Calibration(robot, stages=["offsets", "all"]).fit([tracker_block]).result_
        print(result.summary())

    After :meth:`fit`, ``result_`` holds the :class:`CalibrationResult`.
    """

    def __init__(self, robot: Robot, free: Sequence[str] | str | None = None,
                 method: str = "lm", stages: Sequence[str | Sequence[str]] | None = None,
                 loss: str = "linear", **options: Any) -> None:
        self.robot = robot
        self.free = free
        self.method = method
        self.stages = stages
        self.loss = loss
        self.options = options
        self.result_: CalibrationResult | None = None

    def fit(self, blocks: MeasurementModel | Sequence[MeasurementModel]) -> Calibration:
        """Run the calibration on ``blocks``, keep the result in ``result_`` and return
        ``self`` (as scikit-learn's estimators do)."""
        self.result_ = calibrate(self.robot, blocks, free=self.free, method=self.method,
                                 stages=self.stages, loss=self.loss, **self.options)
        return self

    def __repr__(self) -> str:
        opts = "".join(f", {k}={v!r}" for k, v in self.options.items())
        return (f"Calibration({self.robot.name!r}, free={self.free!r}, method={self.method!r}, "
                f"stages={self.stages!r}, loss={self.loss!r}{opts})")
