"""Estimating the parameters: iterative least squares and Levenberg-Marquardt, in stages.

:func:`calibrate` minimises the stacked whitened residuals of
:func:`kincal.measure.base.stack`,

    theta_hat = argmin 1/2 sum_i w_i r_i(theta)^2,      r = (model - observed) / sigma,

over the *estimated* parameters (the identifiable base set of the candidates; every
other parameter is held at its initial value: the robot's nominal value, or the
block's closed-form initial guess).

Where the parts live: one stage's iteration in :mod:`~kincal.identify.stage`, one module
per method (:mod:`~kincal.identify.gauss_newton`, :mod:`~kincal.identify.levenberg_marquardt`),
the reuse of triangles and residuals in :mod:`~kincal.identify.linearisation`, the stopping
rules in :mod:`~kincal.identify.stopping` and the stage statuses in
:mod:`~kincal.identify.status`, robust weights in :mod:`~kincal.identify.robust`, prior rows
and the noise scale in :mod:`~kincal.identify.prior`, the check at the solution in
:mod:`~kincal.identify.reselection`, the result in :mod:`~kincal.identify.result`; this
module orchestrates them.

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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.defaults import MAX_ITER
from kincal.errors import IdentifiabilityError, KincalError
from kincal.identify.identifiability import IdentifiabilityReport, analyze, default_priority
from kincal.identify.linearisation import KEEP_RESIDUALS_BYTES, half_weighted_ss
from kincal.identify.names import match_names
from kincal.identify.prior import (
    WithPrior,
    data_only_std,
    noise_scale,
    prior_sigmas,
    tolerance_prior,
)
from kincal.identify.reselection import columns_of, drop_from_report, reselections
from kincal.identify.result import CalibrationResult, ProcedureRecord, format_error
from kincal.identify.robust import RobustLoss
from kincal.identify.stage import IterationRecord, StageEnd, StageSettings, run_stage
from kincal.identify.status import StageStatus
from kincal.identify.uncertainty import correlation, inverse_normal_matrix, standard_errors
from kincal.measure.base import CompressedSystem, MeasurementModel, StackedProblem, stack
from kincal.robots.chain import Robot
from kincal.spatial import wrap_angle

Array = NDArray[np.float64]

__all__ = ["calibrate", "Calibration", "CalibrationResult", "IterationRecord", "match_names",
           "format_error", "METHODS", "LOSSES", "ProcedureRecord", "KEEP_RESIDUALS_BYTES"]

METHODS = ("lm", "gauss-newton")
LOSSES = ("linear", "huber", "cauchy")
STAGE_KEYWORDS = ("all", "offsets", "registration")
OUTLIER_WEIGHT = 0.5
#: Largest number of times one stage is solved again with a smaller base set.
MAX_RESELECT = 3
#: Re-solves of the last stage while the noise scale settles, and its relative tolerance.
MAX_NOISE_ITER = 20
NOISE_RTOL = 5e-3


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


# --------------------------------------------------------------------------- one calibration
class _Session:
    """What every stage of one :func:`calibrate` call shares: the problem, the prior, the
    settings, the history, and the noise scale ``scale`` the prior rows are weighed with
    (``sigma0`` of the measurements; 1 until it is estimated)."""

    def __init__(self, prob: StackedProblem, center: Array, prior_s: dict[int, float],
                 settings: StageSettings, scale: float) -> None:
        self.prob, self.center, self.prior_s = prob, center, prior_s
        self.settings, self.loss = settings, settings.loss
        self.scale = scale
        self.history: list[IterationRecord] = []
        self.M = prob.num_residuals()

    def with_prior(self, est: Sequence[int]) -> WithPrior:
        """The problem with the prior rows of the estimated parameters ``est``."""
        idx = [i for i in est if i in self.prior_s]
        sigma = np.array([self.prior_s[i] for i in idx]) / self.scale
        return WithPrior(self.prob, idx, sigma, self.center)

    def solve(self, idx: list[int], theta_start: Array, label: str,
              at: CompressedSystem | None) -> StageEnd:
        """Run a stage over ``idx`` from ``theta_start`` (``at``: the measurements'
        triangle there, over columns that include ``idx``, or None)."""
        aug = self.with_prior(idx)
        first = None if at is None else aug.extend(columns_of(at, idx), theta_start)
        return run_stage(aug, theta_start, idx, label, self.settings, self.history,
                         aug.rows, first)

    def ended(self, stage: StageEnd, columns: Sequence[int]) -> tuple[CompressedSystem, bool]:
        """The measurements' triangle (robust weights, no prior rows) where ``stage``
        ended, over ``columns``: the one the stage built when it is that one (uniform
        weights, the same columns); and whether it is at the stage's end (else it is
        where the stage's last step, shorter than tol_step, started: its ``R`` stands
        for the one at the end, not its ``z``; see ``StageEnd.exact``)."""
        cols = sorted(set(columns))
        C = stage.data
        if (C is not None and self.loss.linear and [int(j) for j in C.columns] == cols
                and (stage.exact or stage.converged)):
            return dataclasses.replace(C, r=None), stage.exact
        return self.prob.compressed(stage.theta, self.loss.weights(stage.r[:self.M]), cols,
                                    keep_residuals=False), True

    def triangle_at(self, theta: Array, columns: list[int]) -> CompressedSystem:
        """The measurements' triangle at ``theta`` over ``columns`` (robust weights there)."""
        w0 = None if self.loss.linear else self.loss.weights(self.prob.residuals(theta))
        return self.prob.compressed(theta, w0, columns, keep_residuals=False)


@dataclass
class _StageOutcome:
    """A stage's solve as kept: its estimated set, its analysis, where it ended."""

    est: list[int]
    report: IdentifiabilityReport
    last: StageEnd
    #: the measurements' triangle where it ended, over its and the next stage's columns
    end_c: CompressedSystem
    end_exact: bool
    iterations: int
    #: the parameters dropped at the solution, one sentence per re-selection
    messages: list[str] = field(default_factory=list)


def _base_set(session: _Session, at_start: CompressedSystem, stage_cand: list[int],
              tol_rank: float | None, preferred: set[int]
              ) -> tuple[IdentifiabilityReport, list[int]]:
    """The identifiable base set of the stage's candidates at its start (the ``prefer``
    ones first, then every role's default priority)."""
    names = session.prob.names
    cand_roles = [session.prob.roles[i] for i in stage_cand]
    priority = default_priority([names[i] for i in stage_cand], cand_roles)
    priority[[k for k, i in enumerate(stage_cand) if i in preferred]] = -1
    report = analyze(at_start.R, [names[i] for i in stage_cand],
                     tol=tol_rank, roles=cand_roles, priority=priority)
    return report, sorted(names.index(n) for n in report.identifiable)


def _reselect(session: _Session, out: _StageOutcome, start: Array, label: str,
              at_start: CompressedSystem, after: list[int], tol_rank: float | None) -> None:
    """Check the base set where the stage ended and, while it fails there, solve the
    stage again from its start with a smaller set (:func:`reselections`; at most
    ``MAX_RESELECT`` times; an attempt that needs convergence and does not converge is
    forgotten).  Updates ``out``."""
    names, history = session.prob.names, session.history
    reselected = False
    for _ in range(MAX_RESELECT):
        options, end = reselections(session.prob, out.est, at_start, out.end_c,
                                    out.last.converged, tol_rank, report=reselected)
        if not options and reselected:      # the final set's conditioning, at its end
            assert end is not None
            out.report = dataclasses.replace(out.report, cond_scaled=end.cond_scaled,
                                             cond_unscaled=end.cond_unscaled)
        accepted = False
        for drop, check, why, needs_convergence in options:
            lost = [names[i] for i in drop]
            kept = [i for i in out.est if i not in drop]
            n_hist = len(history)
            again = session.solve(kept, start, label, at_start)
            if needs_convergence and not again.converged:
                del history[n_hist:]        # did not help: forget that attempt
                continue
            out.messages.append(f"stage {label!r}: {', '.join(lost[:6])}"
                                f"{' ...' if len(lost) > 6 else ''} {why}; solved the stage "
                                f"again from its start with {len(kept)} parameters")
            out.report = drop_from_report(out.report, check, lost)
            out.est, out.last = kept, again
            out.end_c, out.end_exact = session.ended(again, [*kept, *after])
            out.iterations += again.iterations
            reselected = accepted = True
            break
        if not accepted:
            break


def _run_one_stage(session: _Session, label: str, stage_cand: list[int], after: list[int],
                   theta: Array, previous: _StageOutcome | None, tol_rank: float | None,
                   preferred: set[int]) -> _StageOutcome:
    """One stage from ``theta``: its base set at the start, the solve, the check where it
    ended (``after``: the next stage's candidates, which the end triangle also covers;
    ``previous``: the stage before, whose end triangle is this one's start when exact)."""
    start = theta.copy()
    if previous is None or not previous.end_exact:
        at_start = session.triangle_at(start, stage_cand)
    else:
        at_start = columns_of(previous.end_c, stage_cand)
    report, est = _base_set(session, at_start, stage_cand, tol_rank, preferred)
    last = session.solve(est, start, label, at_start)
    end_c, end_exact = session.ended(last, [*est, *after])
    out = _StageOutcome(est, report, last, end_c, end_exact, last.iterations)
    _reselect(session, out, start, label, at_start, after, tol_rank)
    return out


def _settle_noise_scale(session: _Session, out: _StageOutcome, label: str) -> bool:
    """Re-solve the last stage with the prior rows scaled by the estimated ``sigma0``
    until it changes by less than ``NOISE_RTOL`` (module docstring, "Prior"); updates
    ``session.scale`` and ``out``.  Returns whether it settled in ``MAX_NOISE_ITER``."""
    est = out.est
    for _ in range(MAX_NOISE_ITER):
        new, _ = noise_scale(session.with_prior(est), out.last.r, columns_of(out.end_c, est),
                             out.last.theta, session.loss)
        if new is None or abs(new / session.scale - 1.0) < NOISE_RTOL:
            return True
        session.scale = new
        out.last = session.solve(est, out.last.theta, label,
                                 out.end_c if out.end_exact else None)
        out.end_c, out.end_exact = session.ended(out.last, est)
        out.iterations += out.last.iterations
    return False


@dataclass
class _Statistics:
    """The uncertainty at the solution over the estimated set ``est``."""

    est: list[int]
    sigma0: float
    #: the scale of the covariance: ``sigma0``, or with a prior the one it was weighed with
    cov_scale: float
    std: Array
    covariance: Array
    correlation: Array
    weights: Array
    effective_parameters: float | None
    messages: list[str]
    rank_deficient: bool


def _statistics(session: _Session, out: _StageOutcome, trust_sigma: bool,
                estimate_noise: bool, tol_rank: float | None) -> _Statistics:
    """``sigma0`` and ``Cov = cov_scale^2 (J^T W J)^-1`` over the last stage's estimated
    set (prior rows included) at its solution, from its triangle (``R^T R = J^T W J``).

    ``sigma0``: 1 under ``trust_sigma``; with a prior the noise scale (estimated again
    here when ``estimate_noise``); else ``sqrt(sum w r^2 / (M - p))``.  A set still rank
    deficient reports only its independent subset.
    """
    prob, names, est = session.prob, session.prob.names, out.est
    aug = session.with_prior(est)
    r, theta = out.last.r, out.last.theta
    w = session.loss.weights(r, aug.rows)
    Jw = aug.extend(columns_of(out.end_c, est), theta).R
    dof = len(r) - len(est)
    messages: list[str] = []
    p_eff = None
    if trust_sigma:
        sigma0 = 1.0
    elif session.prior_s and est:
        sigma0 = session.scale
        if estimate_noise:
            got, p_eff = noise_scale(aug, r, columns_of(out.end_c, est), theta, session.loss)
            sigma0 = session.scale if got is None else got
    elif dof > 0:
        sigma0 = float(np.sqrt(2.0 * half_weighted_ss(r, w) / dof))
    else:
        sigma0 = 1.0
        messages.append("no redundancy (measurements <= parameters): sigma0 set to 1")
    std = np.zeros(len(names))
    cov = corr = np.zeros((0, 0))
    # with a prior the posterior covariance uses the scale the prior was weighed with
    cov_scale = session.scale if (session.prior_s and est and not trust_sigma) else sigma0
    deficient = False
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
            deficient = True
            cov = cov_scale**2 * inverse_normal_matrix(Jw[:, keep])
        std[est] = standard_errors(cov)
        corr = correlation(cov)
    return _Statistics(est, sigma0, cov_scale, std, cov, corr, w,
                       None if p_eff is None else float(p_eff), messages, deficient)


def _outliers(prob: StackedProblem, loss: RobustLoss, w: Array) -> list[tuple[str, int]]:
    """``(block, row)`` of the measurements whose robust weight is below
    ``OUTLIER_WEIGHT`` (none for loss ``"linear"``)."""
    if loss.linear:
        return []
    ids, dims = loss.ids, loss.dims
    assert ids is not None and dims is not None
    wm = np.ones(len(dims))
    wm[ids] = w[:prob.num_residuals()]
    bnames = prob.block_names
    bi, rows = prob.owners()
    first = np.unique(ids, return_index=True)[1]
    return [(bnames[bi[first[m]]], int(rows[first[m]]))
            for m in np.flatnonzero(wm < OUTLIER_WEIGHT)]


def _held_by_prior(session: _Session, stats: _Statistics, end_c: CompressedSystem
                   ) -> tuple[dict[str, float], Array | None, list[str]]:
    """``(prior of the estimated names, data_std, held_by_prior)``: with a prior, the
    standard errors the measurements alone give, and the names whose exceed their prior
    standard deviation."""
    names, est = session.prob.names, stats.est
    pri = {names[i]: session.prior_s[i] for i in est if i in session.prior_s}
    if not pri:
        return pri, None, []
    data_std = np.full(len(names), np.nan)
    data_std[est] = data_only_std(columns_of(end_c, est).R, stats.cov_scale)
    held = [names[i] for i in est if names[i] in pri and not data_std[i] <= pri[names[i]]]
    return pri, data_std, held


def _wrapped_offsets(prob: StackedProblem, theta: Array) -> Array:
    """``theta`` with every encoder offset in (-pi, pi] (``c`` and ``c + 2 pi k`` are the
    same robot)."""
    for i, (role, unit) in enumerate(zip(prob.roles, prob.units, strict=True)):
        if role == "offset" and unit == "rad":
            theta[i] = float(wrap_angle(theta[i]))
    return theta


def _check_options(robot: object, method: str, loss: str, loss_scale: float,
                   noise_scale: float | None) -> None:
    """Raise :class:`KincalError` for a robot that is not serial, an unknown method or
    loss, or a loss or noise scale that is not a positive finite number."""
    if not isinstance(robot, Robot):
        raise KincalError(f"calibrate takes a serial Robot, not a {type(robot).__name__}; a "
                          "five-bar calibrates with kincal.parallel.file_calibration."
                          "calibrate_fivebar_file or kincal.parallel.calibration.calibrate")
    if not (isinstance(loss_scale, int | float) and np.isfinite(loss_scale)
            and loss_scale > 0):
        raise KincalError(f"loss_scale must be a positive finite number of standard "
                          f"deviations, got {loss_scale!r}")
    if method not in METHODS:
        raise KincalError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    if loss not in LOSSES:
        raise KincalError(f"unknown loss {loss!r}; use one of {', '.join(LOSSES)}")
    if noise_scale is not None and not (np.isfinite(noise_scale) and noise_scale > 0):
        raise KincalError(f"noise_scale must be positive and finite, got {noise_scale!r}")


def _start(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
           prior: Mapping[str, float] | str | None, initial: dict[str, float] | None
           ) -> tuple[StackedProblem, Array, Array, dict[int, float]]:
    """``(problem, theta0, prior centre, {index: prior sigma})``: the stacked problem, the
    starting values (``initial`` overriding nominal / closed-form ones) and the prior's
    centre (the values before ``initial``)."""
    if isinstance(blocks, MeasurementModel):
        blocks = [blocks]
    prob, theta0 = stack(robot, list(blocks))
    center = theta0.copy()
    if isinstance(prior, str):
        prior = tolerance_prior(robot, prob, prior)
    prior_s = prior_sigmas(prob.names, prior)
    if initial:
        for name, v in initial.items():
            theta0[prob.index(name)] = float(v)
    return prob, theta0, center, prior_s


def _candidates(prob: StackedProblem, free: Sequence[str] | str | None,
                fixed: Sequence[str] | str, stages: Sequence[str | Sequence[str]] | None
                ) -> tuple[list[str | Sequence[str]], list[list[int]]]:
    """``(stage specs, candidates per stage)``: ``free`` (None: all) without ``fixed``."""
    names = prob.names
    cand = list(range(len(names))) if free is None else match_names(names, free)
    fixed_idx = set(match_names(names, fixed)) if fixed else set()
    cand = [i for i in cand if i not in fixed_idx]
    specs: list[str | Sequence[str]] = list(stages) if stages else ["all"]
    return specs, [[i for i in _stage_candidates(spec, prob, cand) if i not in fixed_idx]
                   for spec in specs]


def _settle_last_stage(session: _Session, out: _StageOutcome, label: str, messages: list[str],
                       stage_status: list[tuple[str, StageStatus]]) -> int:
    """Estimate the noise scale before the prior is weighed (:func:`_settle_noise_scale`)
    and update the last stage's message and status in place; returns the extra iterations."""
    before = out.iterations
    settled = _settle_noise_scale(session, out, label)
    messages[-1] = out.last.message
    stage_status[-1] = (label, out.last.status)
    if not settled:
        messages.append(f"the noise scale did not settle in {MAX_NOISE_ITER} re-solves "
                        f"(sigma0 = {session.scale:.4g})")
    return out.iterations - before


def calibrate(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
              free: Sequence[str] | str | None = None, fixed: Sequence[str] | str = (),
              method: str = "lm", stages: Sequence[str | Sequence[str]] | None = None,
              loss: str = "linear", loss_scale: float = 3.0, max_iter: int = MAX_ITER,
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
        max_iter: most iterations per stage (module docstring, "Stopping").
        tol_step: step rule per stage (module docstring, "Stopping").
        tol_cost: cost-change rule per stage (module docstring, "Stopping").
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
    _check_options(robot, method, loss, loss_scale, noise_scale)
    prob, theta0, center, prior_s = _start(robot, blocks, prior, initial)
    estimate_noise = bool(prior_s) and noise_scale is None and not trust_sigma
    settings = StageSettings(method, RobustLoss.of(prob, loss, loss_scale), max_iter, tol_step,
                             tol_cost, tol_std, progress)
    session = _Session(prob, center, prior_s, settings,
                       1.0 if noise_scale is None else float(noise_scale))
    names = prob.names
    preferred = set(match_names(names, prefer)) if prefer else set()
    specs, all_cand = _candidates(prob, free, fixed, stages)
    theta = theta0.copy()
    stage_info: list[tuple[str, list[str]]] = []
    stage_status: list[tuple[str, StageStatus]] = []
    messages: list[str] = []
    out: _StageOutcome | None = None
    total_it = 0
    for k, spec in enumerate(specs):
        label = _stage_label(spec)
        # the next stage starts where this one ends: its triangle covers both
        after = all_cand[k + 1] if k + 1 < len(specs) else []
        out = _run_one_stage(session, label, all_cand[k], after, theta, out, tol_rank,
                             preferred)
        theta = out.last.theta
        total_it += out.iterations
        stage_info.append((label, [names[i] for i in out.est]))
        messages += [*out.messages, out.last.message]
        stage_status.append((label, out.last.status))
    assert out is not None
    if estimate_noise and out.est:
        total_it += _settle_last_stage(session, out, stage_info[-1][0], messages, stage_status)
    converged = all(status.converged for _, status in stage_status)
    stats = _statistics(session, out, trust_sigma, estimate_noise, tol_rank)
    messages += stats.messages
    held = out.report.not_identifiable
    if free is not None and held:
        messages.append(f"{len(held)} requested parameter(s) not identifiable, held at their "
                        f"initial values: {', '.join(held[:8])}{' ...' if len(held) > 8 else ''}")
    pri, data_std, held_by_prior = _held_by_prior(session, stats, out.end_c)
    theta = _wrapped_offsets(prob, out.last.theta)
    r, M = out.last.r, prob.num_residuals()
    robot_cal, _ = prob.split(theta)
    return CalibrationResult(
        robot=robot_cal, robot_initial=robot, problem=prob, theta0=theta0, theta=theta,
        names=names, estimated=[names[i] for i in stats.est], identifiability=out.report,
        std=stats.std, covariance=stats.covariance, correlation=stats.correlation,
        sigma0=stats.sigma0, residuals=r[:M], weights=stats.weights[:M],
        outliers=_outliers(prob, settings.loss, stats.weights), history=session.history,
        converged=bool(converged and not stats.rank_deficient), iterations=total_it,
        message="; ".join(messages), stages=stage_info, method=method, loss=loss,
        prior=pri, data_std=data_std, held_by_prior=held_by_prior,
        noise_scale_estimated=estimate_noise, stage_status=stage_status,
        effective_parameters=stats.effective_parameters)


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
