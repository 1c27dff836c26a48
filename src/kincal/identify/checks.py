"""Can this calibration be trusted?  Convergence and plausibility, in one verdict.

A calibration is *not trusted* when

* the solver did not converge (``result.converged`` is False: ``max_iter`` reached,
  no descent step, non-finite residuals, a base set still rank deficient at the end);
* an estimate is implausible: ``|theta_j - nominal_j| > PLAUSIBLE * s_j`` with ``s_j``
  the parameter's manufacturing tolerance (:mod:`kincal.identify.tolerances`;
  ``PLAUSIBLE`` = 10).  A real robot is not 10 tolerances away from its drawing: such
  an estimate is a weakly identifiable parameter set from noise, or a robot file that
  does not describe the robot;
* a standard error is absurd: more than :data:`ABSURD_STD` (1 m or 1 rad) for any
  length or angle, tolerance or not (an instrument frame known to a metre is not known).

:func:`judge` returns a :class:`Verdict` whose :meth:`~Verdict.line` is the one line the
command line prints (exit status 1, no calibrated robot written unless ``--force``).

**Data the model cannot explain** (:class:`Refusal`, before the reasons above):

* *joint data the robot cannot have produced*: readings beyond the joint limits, or a
  revolute column whose values only make sense in the other angle unit
  (:mod:`kincal.measure.data_checks`; checked on every training and held-out file);
* *nothing estimated*: no parameter was left to estimate;
* *no redundancy*: ``E - p < 1``, with ``E`` the equations of *distinct*
  measurements (:func:`distinct_equations`: a row copied, same joint readings and same
  residuals, repeats its equations, it does not add any) and ``p`` the parameters
  the data fix: the estimated ones, or with a prior the effective number ``p_eff``
  (``result.effective_parameters``; the prior holds the rest).  Then the fit passes
  through the data whatever they are and ``sigma0`` (1 by convention) checks nothing;
* *a residual beyond what the noise and the tolerances can explain*: with ``d = E - p``
  degrees of freedom and whitened residuals (stated noise 1), ``sigma0^2 d`` is
  chi-square with ``d`` degrees of freedom when the stated noise is right, so
  ``sigma0 <= sqrt(chi2_d^-1(1 - RESIDUAL_TAIL) / d)`` but for one fit in 10^6.  Real
  robots leave unmodelled errors (compliance, thermal drift, gear play), so the
  residual may also hold a *model floor*: up to :data:`MODEL_FLOOR` (one half) of the
  error the manufacturing tolerances produce on the nominal robot at the measured poses,
  ``v_tol = (1/M) sum_j s_j^2 ||J_j||^2`` (whitened, robot geometry only, ``J_j`` the
  Jacobian column of parameter ``j`` with tolerance ``s_j``).  The bound is

      sigma0_max = sqrt(chi2_d^-1(1 - RESIDUAL_TAIL) / d) * sqrt(1 + MODEL_FLOOR^2 v_tol).

  A good calibration takes most of the tolerance-level error out of the residual, so its
  sigma0 stays well below the bound however optimistic the stated noise.  Measured on the
  real data sets (sigma0 / bound): Motoman 6.70 / 909 (0.007), Panda two-socket 2.48 / 53.1
  (0.047), TIAGo with its joint model 0.74 / 4.30 (0.17), TIAGo without a sigma column
  (10 um stated, the worst) 178 / 439 (0.41).  Data that are not this robot's leave
  residuals larger than its whole tolerance budget produces (simulated, stated noise
  right): degrees under ``_rad`` headers on the PUMA 5.3e4 / 329 (161), one reading replaced
  by 300 deg 6.3e3 / 362 (17.5), two joint columns swapped on a Panda two-socket 1.4e5 /
  1.5e3 (92).  The margin is 2.4x on the good side, 17x on the bad side.  Without
  tolerances (``v_tol = 0``, e.g. the folds of a cross-validation) there is no stated
  floor and no residual check.

**Stated noise far too small** (a warning, not a refusal): a residual within the bound
but more than :data:`UNDERSTATED_NOISE` (10) times what the noise alone explains,
``sigma0 > 10 sqrt(chi2_d^-1(1 - RESIDUAL_TAIL) / d)``, says that the stated noise is an
order of magnitude too small (a sigma column of the instrument's resolution, a default
10 um where no sigma was given) or that errors the model lacks dominate the data.  The
estimate stands (the standard errors and the predicted accuracy are scaled by the
residual, not the stated noise), but a user who stated the noise should hear that the
data do not agree (sigma0 measured: Motoman 6.70, Panda two-socket 2.48, TIAGo with its
joint model 0.74: no warning; TIAGo without a sigma column 178, a 7-joint arm simulated
with 1 mm noise stated as 0.02 mm 54: warned).

An encoder offset is held to the same tolerances one step earlier: a robot's encoder
zeros are set to a fraction of a degree, so an offset that moved more than its tolerance
(but not beyond the bound) is a loud warning (:meth:`Verdict.warnings`): the zero was
lost (a re-mastered axis), or something else - the probe, the tool, the instrument - is
described wrongly and the offset absorbs it.  Beyond the bound the same sentence joins
the reasons the calibration is refused.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from kincal.identify.identifiability import NON_GEOMETRIC_ROLES
from kincal.identify.tolerances import PLAUSIBLE

__all__ = ["Verdict", "Implausible", "Refusal", "judge", "ABSURD_STD", "show_quantity",
           "OFFSET_ADVICE", "RESIDUAL_TAIL", "MODEL_FLOOR", "residual_bound",
           "distinct_equations", "require_free", "UNEXPLAINED_CAUSES", "UNDERSTATED_NOISE"]

#: Tail probability of the chi-square test of the residual (module docstring).
RESIDUAL_TAIL = 1e-6

#: Share of the tolerance-level error a good model may leave in the residual.
MODEL_FLOOR = 0.5

#: A residual this many times what the stated noise explains is warned about.
UNDERSTATED_NOISE = 10.0

#: What a residual beyond the bound usually means.
UNEXPLAINED_CAUSES = ("joint values in another unit, swapped or reordered columns, another "
                      "robot or tool link, or an instrument that moved during the measurements")

#: What an encoder offset beyond its tolerance says (warning and refusal alike).
OFFSET_ADVICE = ("the axis may have lost its zero (re-master it), or the probe, tool or "
                 "instrument is not what the files say")

#: A standard error above this (per unit) is absurd whatever the parameter.
ABSURD_STD = {"m": 1.0, "rad": 1.0}


def show_quantity(value: float, unit: str, digits: int = 4, signed: bool = False,
                  missing: str = "-") -> str:
    """``(0.0012, "m") -> "1.2 mm"``, ``(0.01, "rad") -> "0.573 deg"``: an SI value for
    people (``digits`` significant; ``missing`` for a value that is not finite)."""
    if not math.isfinite(value):
        return missing
    sign = "+" if signed else ""
    if unit == "m":
        return f"{value * 1e3:{sign}.{digits}g} mm"
    if unit == "rad":
        return f"{math.degrees(value):{sign}.{digits}g} deg"
    return f"{value:{sign}.{digits}g} {unit}"


_show = show_quantity


@dataclass(frozen=True)
class Implausible:
    """One implausible estimate.

    Attributes:
        name, unit: the parameter and its SI unit.
        change: ``estimate - nominal`` [m / rad].
        tolerance: its tolerance [m / rad] (None when judged by its std alone).
        std: its standard error [m / rad].
        reason: ``"change"`` (beyond the bound: refused; for an encoder offset, beyond its
            tolerance: a warning) or ``"std"`` (absurd uncertainty).
        offset: the parameter is an encoder offset (its words say so).
    """

    name: str
    unit: str
    change: float
    tolerance: float | None
    std: float
    reason: str
    offset: bool = False

    def words(self, bound: float = PLAUSIBLE) -> str:
        if self.reason == "change" and self.tolerance:
            what = "encoder offset " if self.offset else ""
            return (f"{what}{self.name} moved {_show(self.change, self.unit, signed=True)} "
                    f"({abs(self.change) / self.tolerance:.3g}x its tolerance "
                    f"{_show(self.tolerance, self.unit)})")
        return f"{self.name} has a standard error of {_show(self.std, self.unit, missing='inf')}"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "unit": self.unit, "change": self.change,
                "tolerance": self.tolerance, "std": self.std, "reason": self.reason}


@dataclass(frozen=True)
class Refusal:
    """Data the model cannot explain (module docstring): one reason to refuse.

    Attributes:
        kind: ``"data"`` (joint data), ``"nothing"`` (no parameter estimated),
            ``"redundancy"``, ``"residual"`` or ``"compliance"`` (a negative stiffness).
        sentence: the words of the one-line refusal.
        short: a few words for tables.
        numbers: what was measured (``sigma0``, ``bound``, ``dof`` ...), for the JSON.
    """

    kind: str
    sentence: str
    short: str
    numbers: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "reason": self.sentence, **self.numbers}


@dataclass
class Verdict:
    """Whether a calibration can be trusted, and why not.

    Attributes:
        converged: the solver's convergence flag.
        message: the solver's message (what stopped it).
        implausible: the implausible estimates, worst first.
        bound: the plausibility bound in tolerances.
        moved: encoder offsets beyond their tolerance but within the bound, worst first
            (trusted, with a warning).
        refusals: data the model cannot explain (:class:`Refusal`), first to report.
        noise: ``(sigma0, noise-only bound)`` when the residual is more than
            :data:`UNDERSTATED_NOISE` times what the stated noise explains (a warning).
    """

    converged: bool
    message: str = ""
    implausible: list[Implausible] = field(default_factory=list)
    bound: float = PLAUSIBLE
    moved: list[Implausible] = field(default_factory=list)
    refusals: list[Refusal] = field(default_factory=list)
    noise: tuple[float, float] | None = None

    @property
    def trusted(self) -> bool:
        return self.converged and not self.implausible and not self.refusals

    def reasons(self, limit: int = 4) -> list[str]:
        """Sentences: the data the model cannot explain, non-convergence, then the
        implausible estimates."""
        out = [r.sentence for r in self.refusals]
        if not self.converged:
            stop = [m.strip() for m in self.message.split(";") if m.strip()]
            out.append("did not converge" + (f" ({stop[-1]})" if stop else ""))
        if self.implausible:
            words = [p.words(self.bound) for p in self.implausible[:limit]]
            more = len(self.implausible) - limit
            out.append(f"implausible estimate{'s' if len(self.implausible) > 1 else ''} "
                       f"(beyond {self.bound:g}x the tolerance): " + ", ".join(words)
                       + (f" and {more} more" if more > 0 else ""))
            if any(p.offset for p in self.implausible[:limit]):
                out[-1] += f" ({OFFSET_ADVICE})"
        return out

    def warnings(self) -> list[str]:
        """One sentence per encoder offset that moved beyond its tolerance, and one when
        the residual is far beyond the stated noise (module docstring)."""
        out = [f"{p.words(self.bound)}: {OFFSET_ADVICE}" for p in self.moved]
        if self.noise is not None:
            sigma0, alone = self.noise
            out.append(f"the residuals are {sigma0:.3g} times the stated noise (the noise "
                       f"alone explains up to {alone:.3g}): the stated noise (sigma column, "
                       "sigma or point_std option) is too small, or errors the model lacks "
                       "dominate the data; the standard errors and predicted accuracy are "
                       "scaled by the residuals, not by the stated noise")
        return out

    def short(self) -> str:
        """A few words for tables: ``"did not converge"``, ``"d[3] 42x its tolerance"``."""
        if self.trusted:
            return ""
        if self.refusals:
            return self.refusals[0].short
        if not self.converged:
            return "did not converge"
        p = self.implausible[0]
        more = f" (+{len(self.implausible) - 1})" if len(self.implausible) > 1 else ""
        if p.reason == "change" and p.tolerance:
            return f"{p.name} {abs(p.change) / p.tolerance:.3g}x tolerance{more}"
        return f"{p.name} std {_show(p.std, p.unit)}{more}"

    def line(self) -> str:
        """One line for stderr: ``calibration not trusted: ...``."""
        if self.trusted:
            return "calibration converged and every estimate is plausible"
        return "calibration not trusted: " + "; ".join(self.reasons())

    def to_dict(self) -> dict[str, Any]:
        return {"trusted": self.trusted, "converged": self.converged,
                "bound_tolerances": self.bound, "reasons": self.reasons(limit=1000),
                "implausible": [p.to_dict() for p in self.implausible],
                "refusals": [r.to_dict() for r in self.refusals],
                "warnings": self.warnings()}


def judge(result: Any, tolerances: Mapping[str, float], bound: float = PLAUSIBLE,
          data: Sequence[str] | None = None) -> Verdict:
    """The :class:`Verdict` of a :class:`~kincal.identify.solver.CalibrationResult`.

    Args:
        result: the calibration (``theta``, ``theta0``, ``std``, ``estimated``).
        tolerances: ``{name: tolerance}`` [m / rad] (:class:`~kincal.identify.tolerances.
            Tolerances`' ``sigma``).
        bound: implausible beyond ``bound`` tolerances from nominal.
        data: one-line problems of the joint data (:func:`kincal.measure.data_checks.
            joint_data_line` of the training and held-out files); None: those of the
            training blocks (``result.problem.blocks``) are found here.

    Only estimated parameters are judged (the others keep their nominal values); an
    encoder offset's change is taken in (-pi, pi] (``c`` and ``c + 2 pi k``: one robot).
    """
    names = list(result.names)
    units = list(result.problem.units)
    bad: list[tuple[float, Implausible]] = []
    moved: list[tuple[float, Implausible]] = []
    for n in result.estimated:
        i = names.index(n)
        offset = result.problem.roles[i] == "offset"
        change = float(result.theta[i] - result.theta0[i])
        if offset and units[i] == "rad":
            change = math.remainder(change, 2 * math.pi)
        std = float(result.std[i])
        tol = tolerances.get(n)
        if tol and abs(change) > bound * tol:
            bad.append((abs(change) / tol, Implausible(n, units[i], change, tol, std, "change",
                                                       offset)))
        elif units[i] in ABSURD_STD and not std <= ABSURD_STD[units[i]]:
            bad.append((math.inf, Implausible(n, units[i], change, tol, std, "std", offset)))
        elif offset and tol and abs(change) > tol:
            moved.append((abs(change) / tol, Implausible(n, units[i], change, tol, std,
                                                         "change", True)))
    bad.sort(key=lambda x: -x[0])
    moved.sort(key=lambda x: -x[0])
    refusals, dof = _refusals(result, tolerances, data)
    return Verdict(bool(result.converged), str(result.message), [b for _, b in bad], bound,
                   [m for _, m in moved], refusals,
                   None if refusals else _understated_noise(result, dof))


def _understated_noise(result: Any, dof: float | None) -> tuple[float, float] | None:
    """``(sigma0, noise-only bound)`` when the residual exceeds the noise-only chi-square
    bound ``sqrt(chi2_d^-1(1 - RESIDUAL_TAIL) / d)`` with ``dof`` degrees of freedom (the
    residual check's) by :data:`UNDERSTATED_NOISE`; else None."""
    sigma0 = float(result.sigma0)
    if dof is None or dof < 1 or not math.isfinite(sigma0):
        return None
    alone = math.sqrt(float(chi2.isf(RESIDUAL_TAIL, dof)) / dof)
    return (sigma0, alone) if sigma0 > UNDERSTATED_NOISE * alone else None


def _refusals(result: Any, tolerances: Mapping[str, float], data: Sequence[str] | None
              ) -> tuple[list[Refusal], float | None]:
    """The data the model cannot explain (module docstring), in the order they explain
    each other: joint data, nothing estimated, no redundancy, the residual; and the
    residual's degrees of freedom (None when nothing was estimated)."""
    if data is None:
        from kincal.measure.data_checks import block_joint_problems, joint_data_line

        line = joint_data_line(block_joint_problems(result.robot_initial,
                                                    result.problem.blocks))
        data = [line] if line else []
    out = [Refusal("data", f"joint data this robot cannot have produced: {d}",
                   "joint data") for d in data if d]
    out += negative_compliance(result)
    p = len(result.estimated)
    if p == 0:
        out.append(Refusal("nothing", "no parameter was estimated (every candidate was "
                           "fixed or not identifiable from the data): the result is the "
                           "nominal robot", "nothing estimated"))
        return out, None
    equations, configurations = distinct_equations(result.problem.blocks,
                                                   result.residuals)
    p_eff = result.effective_parameters
    fixed_by_data = p if p_eff is None else min(float(p_eff), p)
    dof = equations - fixed_by_data
    if dof < 1:
        held = ("" if p_eff is None or fixed_by_data > p - 0.5 else
                f" (of which the data, not the prior, fix {fixed_by_data:.3g})")
        out.append(Refusal(
            "redundancy", f"no redundancy: {equations} equations from {configurations} "
            f"distinct joint configuration{'s' if configurations != 1 else ''} for {p} "
            f"estimated parameters{held}, so the fit passes through any data and sigma0 "
            "checks nothing (measure more, different poses, or estimate fewer parameters)",
            "no redundancy", {"equations": equations, "configurations": configurations,
                              "estimated": p, "effective": fixed_by_data}))
        return out, dof
    sigma0 = float(result.sigma0)
    limit = residual_bound(result, tolerances, dof)
    if limit is not None and not sigma0 <= limit:
        out.append(Refusal(
            "residual", f"the model cannot explain the data: residuals {sigma0:.3g} times "
            f"the stated noise, beyond the {limit:.3g} that the noise and half the errors "
            f"the tolerances allow can explain ({dof:.4g} degrees of freedom); likely causes: "
            f"{UNEXPLAINED_CAUSES}", f"sigma0 {sigma0:.3g} > {limit:.3g}",
            {"sigma0": sigma0, "bound": limit, "dof": dof}))
    return out, dof


#: A compliance estimate is refused when it is below zero by more than this many of its
#: standard errors (noise alone puts a true compliance of 0 there with odds 1 in 740).
NEGATIVE_COMPLIANCE_SIGMAS = 3.0


def negative_compliance(result: Any) -> list[Refusal]:
    """A refusal for the joint compliances estimated clearly below zero.

    ``--joint-model compliance`` models the joint as a spring under its gravity load,
    ``q_link = q + k tau`` with the compliance ``k = 1 / stiffness`` [rad/(N m) / m/N]:
    ``k < 0`` is a negative stiffness, a joint that moves against its load, which no
    gearbox does.  An estimate ``k + 3 std(k) < 0`` means the load model is wrong (link
    masses, the direction of gravity, a spring balancer) or the term absorbs another
    error; the calibration is then refused in one line."""
    roles = list(result.problem.roles)
    names = list(result.names)
    worst: tuple[float, str, float, float] | None = None
    for n in result.estimated:
        i = names.index(n)
        if roles[i] != "compliance":
            continue
        k, std = float(result.theta[i]), float(result.std[i])
        if not k < -NEGATIVE_COMPLIANCE_SIGMAS * std:
            continue
        z = -k / std if std > 0 else math.inf
        if worst is None or z > worst[0]:
            worst = (z, n, k, std)
    if worst is None:
        return []
    _, n, k, std = worst
    return [Refusal("compliance", f"negative joint stiffness: {n} = {k:.3g} +- {std:.2g} "
                    f"(a compliance below zero by {worst[0]:.3g} standard errors: the joint "
                    "would move against its gravity load); check the link masses and the "
                    "direction of gravity, or leave out --joint-model compliance",
                    "negative stiffness", {"compliance": k, "std": std})]


def distinct_equations(blocks: Sequence[Any], residuals: Any = None) -> tuple[int, int]:
    """``(E, K)``: the equations of distinct measurements, and how many distinct joint
    configurations (module docstring).

    A row (measurement) repeats another when its joint readings and its residuals are
    the same (with ``residuals``, the stacked whitened residuals of the fit; else the
    joint readings alone decide): a copied row adds no equation, while one pose seen
    from several instrument stations, or measured again with new noise, does.  ``E``
    sums the residuals of the first row of each kind."""
    equations = configurations = 0
    start = 0
    r_all = None if residuals is None else np.asarray(residuals, dtype=float)
    for b in blocks:
        m = int(b.num_residuals())
        q = np.asarray(getattr(b, "q", np.zeros((0, 0))), dtype=float)
        owner = np.asarray(b.residual_owner())
        r = None if r_all is None else r_all[start:start + m]
        start += m
        if (q.ndim != 2 or q.shape[0] == 0 or m == 0 or owner.size != m
                or owner.max() >= q.shape[0]):
            equations += m
            continue
        configurations += int(np.unique(q, axis=0).shape[0]) if q.shape[1] else 1
        n = q.shape[0]
        count = np.bincount(owner, minlength=n).astype(float)
        key = [q, count[:, None]]
        if r is not None:                       # a row's residuals, by their sum and squares
            key += [np.bincount(owner, weights=r, minlength=n)[:, None],
                    np.bincount(owner, weights=r * r, minlength=n)[:, None]]
        _, first = np.unique(np.round(np.hstack(key), 9), axis=0, return_index=True)
        equations += int(count[first].sum())
    return equations, configurations


def residual_bound(result: Any, tolerances: Mapping[str, float], dof: float) -> float | None:
    """``sigma0_max`` of the module docstring for ``dof`` degrees of freedom; None when
    no robot geometry parameter has a tolerance (no stated model floor)."""
    prob = result.problem
    robot, extras = prob.split(np.asarray(result.theta, dtype=float))
    cols = [j for j in range(prob.num_robot)
            if prob.roles[j] not in NON_GEOMETRIC_ROLES and tolerances.get(prob.names[j])]
    if not cols:
        return None
    s2 = np.array([float(tolerances[prob.names[j]]) ** 2 for j in cols])
    total, rows = 0.0, 0
    for b, e in zip(prob.blocks, extras, strict=True):
        for _, r, Jr, _ in b.evaluate_chunks(robot, e):
            total += float(np.sum(np.asarray(Jr)[:, cols] ** 2, axis=0) @ s2)
            rows += int(np.size(r))
    v_tol = total / max(rows, 1)
    quantile = float(chi2.isf(RESIDUAL_TAIL, dof)) / dof
    return math.sqrt(quantile * (1.0 + MODEL_FLOOR**2 * v_tol))


def require_free(names: Sequence[str], free: Sequence[str] | None, fixed: Sequence[str],
                 free_text: str | None, fix_text: str | None) -> None:
    """Raise :class:`~kincal.errors.KincalError` (bad input, exit 2) when ``--free`` /
    ``--fix`` leave no parameter to estimate (``free`` None: every parameter is a
    candidate)."""
    from kincal.errors import KincalError

    left = [n for n in (names if free is None else free) if n not in set(fixed)]
    if left:
        return
    if free is not None and not free:
        raise KincalError(f"option --free {free_text!r}: names no parameter, so there is "
                          "nothing to estimate (e.g. --free 'role:offset,tracker.*')")
    what = f"--free {free_text!r} and --fix {fix_text!r}" if free_text else f"--fix {fix_text!r}"
    raise KincalError(f"option {what}: every candidate parameter is fixed, so there is "
                      "nothing to estimate")
