"""Can a five-bar calibration be trusted?  The serial robots' verdict, for the five-bar.

A five-bar calibration is *not trusted* (:class:`~kincal.identify.checks.Verdict`) when

* the iteration did not converge (iteration limit reached);
* an estimate moved more than ``bound`` (10) tolerances from its nominal value,
  ``|xi_j - xi_N,j| > 10 s_j``, with ``s_j`` the manufacturing tolerance of its role
  (:data:`kincal.identify.tolerances.DEFAULT_TOLERANCES`: a length or base coordinate
  1 mm, an encoder offset 0.5 deg); the measurement frame ``frame.*`` has no tolerance;
* a standard error is absurd: above :data:`~kincal.identify.checks.ABSURD_STD` (1 m or
  1 rad), tolerance or not.

A drawing that is far from the built robot (the reference experiment's nominal lengths
are 0.3 m from the true ones) passes its own, wider tolerances.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from kincal.identify.checks import ABSURD_STD, Implausible, Verdict
from kincal.identify.tolerances import DEFAULT_TOLERANCES, PLAUSIBLE
from kincal.parallel import residuals as res
from kincal.parallel.calibration import FiveBarCalibration

__all__ = ["fivebar_tolerances", "judge_fivebar"]


def fivebar_tolerances(overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """One standard deviation [m / rad] per robot parameter of the five-bar.

    Lengths ``l1..l4`` and base coordinates: the length tolerance (1 mm); encoder
    offsets: the offset tolerance (0.5 deg); ``overrides`` replace entries by name.
    """
    out: dict[str, float] = {}
    for name, unit in zip(res.ALL_NAMES[: res.N_ROBOT], res.ALL_UNITS[: res.N_ROBOT],
                          strict=True):
        role = "offset" if name.startswith("offset") else "length"
        out[name] = DEFAULT_TOLERANCES[role][unit]
    for name, value in (overrides or {}).items():
        if name not in res.ALL_NAMES:
            raise ValueError(f"unknown five-bar parameter {name!r} in the tolerances")
        out[name] = float(value)
    return out


def judge_fivebar(result: FiveBarCalibration, tolerances: Mapping[str, float] | None = None,
                  bound: float = PLAUSIBLE) -> Verdict:
    """The verdict on ``result``: converged, estimates within ``bound`` tolerances,
    standard errors below 1 m / 1 rad (module docstring).

    Args:
        result: the calibration.
        tolerances: ``{name: tolerance}`` [m / rad]; default :func:`fivebar_tolerances`.
        bound: implausible beyond ``bound`` tolerances from nominal.
    """
    tol = dict(tolerances) if tolerances is not None else fivebar_tolerances()
    units = dict(zip(res.ALL_NAMES, res.ALL_UNITS, strict=True))
    start = dict(zip(res.ALL_NAMES, result.start.tolist(), strict=True))
    params = result.params
    bad: list[tuple[float, Implausible]] = []
    for name in result.free:
        offset = name.startswith("offset")
        change = params[name] - start[name]
        if offset:
            change = math.remainder(change, 2 * math.pi)
        std = result.std_errors.get(name, math.nan)
        t = tol.get(name)
        if t and abs(change) > bound * t:
            bad.append((abs(change) / t, Implausible(name, units[name], change, t, std,
                                                     "change", offset)))
        elif not std <= ABSURD_STD[units[name]]:
            bad.append((math.inf, Implausible(name, units[name], change, t, std, "std",
                                              offset)))
    bad.sort(key=lambda b: -b[0])
    message = "" if result.converged else "iteration limit reached"
    return Verdict(bool(result.converged), message, [b for _, b in bad], bound)
