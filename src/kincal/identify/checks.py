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

An encoder offset is held to the same tolerances one step earlier: a robot's encoder
zeros are set to a fraction of a degree, so an offset that moved more than its tolerance
(but not beyond the bound) is a loud warning (:meth:`Verdict.warnings`): the zero was
lost (a re-mastered axis), or something else - the probe, the tool, the instrument - is
described wrongly and the offset absorbs it.  Beyond the bound the same sentence joins
the reasons the calibration is refused.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from kincal.identify.tolerances import PLAUSIBLE

__all__ = ["Verdict", "Implausible", "judge", "ABSURD_STD", "show_quantity", "OFFSET_ADVICE"]

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
    """

    converged: bool
    message: str = ""
    implausible: list[Implausible] = field(default_factory=list)
    bound: float = PLAUSIBLE
    moved: list[Implausible] = field(default_factory=list)

    @property
    def trusted(self) -> bool:
        return self.converged and not self.implausible

    def reasons(self, limit: int = 4) -> list[str]:
        """Sentences: non-convergence, then the implausible estimates."""
        out = []
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
        """One sentence per encoder offset that moved beyond its tolerance (module
        docstring)."""
        return [f"{p.words(self.bound)}: {OFFSET_ADVICE}" for p in self.moved]

    def short(self) -> str:
        """A few words for tables: ``"did not converge"``, ``"d[3] 42x its tolerance"``."""
        if self.trusted:
            return ""
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
                "warnings": self.warnings()}


def judge(result: Any, tolerances: Mapping[str, float], bound: float = PLAUSIBLE) -> Verdict:
    """The :class:`Verdict` of a :class:`~kincal.identify.solver.CalibrationResult`.

    Args:
        result: the calibration (``theta``, ``theta0``, ``std``, ``estimated``).
        tolerances: ``{name: tolerance}`` [m / rad] (:class:`~kincal.identify.tolerances.
            Tolerances`' ``sigma``).
        bound: implausible beyond ``bound`` tolerances from nominal.

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
    return Verdict(bool(result.converged), str(result.message), [b for _, b in bad], bound,
                   [m for _, m in moved])
