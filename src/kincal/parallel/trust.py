"""Can a five-bar calibration be trusted?  The serial robots' verdict, for the five-bar.

A five-bar calibration is *not trusted* (:class:`~kincal.identify.checks.Verdict`) when

* the iteration did not converge (iteration limit reached);
* an estimate moved more than ``bound`` (10) tolerances from its nominal value,
  ``|xi_j - xi_N,j| > 10 s_j``, with ``s_j`` the manufacturing tolerance of its role
  (:data:`kincal.identify.tolerances.DEFAULT_TOLERANCES`: a length or base coordinate
  1 mm, an encoder offset 0.5 deg); the measurement frame ``frame.*`` has no tolerance;
* a standard error is absurd: above :data:`~kincal.identify.checks.ABSURD_STD` (1 m or
  1 rad), tolerance or not;
* (refusals, with the readings given) a reading beyond the five-bar's reading limits,
  with the slack of :mod:`kincal.measure.data_checks` (1 % of the range, at least
  1e-3 rad), named by file and line; no redundancy: fewer distinct equations (two per
  distinct reading row) than estimated parameters plus one, so the fit passes through
  any data and its residual checks nothing.

A drawing that is far from the built robot (the reference experiment's nominal lengths
are 0.3 m from the true ones) passes its own, wider tolerances.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from kincal.identify.checks import ABSURD_STD, Implausible, Refusal, Verdict
from kincal.identify.tolerances import DEFAULT_TOLERANCES, PLAUSIBLE
from kincal.measure.data_checks import LIMIT_SHARE, LIMIT_SLACK
from kincal.parallel import residuals as res
from kincal.parallel.calibration import FiveBarCalibration

__all__ = ["fivebar_tolerances", "judge_fivebar", "reading_refusals"]


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


def reading_refusals(result: FiveBarCalibration, q: np.ndarray, source: str,
                     lines: Sequence[int] | None = None) -> list[Refusal]:
    """The readings ``q`` (N, 2) [rad] the five-bar cannot have produced, and no
    redundancy (module docstring): one :class:`~kincal.identify.checks.Refusal` each."""
    q = np.asarray(q, dtype=float).reshape(-1, 2)
    out: list[Refusal] = []
    words: list[str] = []
    for j, (lo, hi) in enumerate(result.nominal.limits or ()):
        width = hi - lo if math.isfinite(hi - lo) else 0.0
        slack = max(LIMIT_SLACK["revolute"], LIMIT_SHARE * width)
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero((q[:, j] < lo - slack) | (q[:, j] > hi + slack))
        if bad.size:
            i = int(bad[0])
            where = f"line {int(lines[i])}" if lines is not None else f"row {i + 1}"
            more = f" ({bad.size} of {len(q)} rows beyond)" if bad.size > 1 else ""
            words.append(f"{where}: reading q{j + 1} = {math.degrees(q[i, j]):.4g} deg is "
                         f"beyond its limits [{math.degrees(lo):.4g} deg, "
                         f"{math.degrees(hi):.4g} deg]{more}")
    if words:
        out.append(Refusal("data", f"readings this five-bar cannot have produced: {source}: "
                           + "; ".join(words), "readings beyond limits"))
    p = len(result.free)
    distinct = int(np.unique(np.round(q, 12), axis=0).shape[0]) if len(q) else 0
    equations = 2 * distinct
    if p and equations - p < 1:
        out.append(Refusal(
            "redundancy", f"no redundancy: {equations} equations from {distinct} distinct "
            f"reading{'s' if distinct != 1 else ''} in {source} for {p} estimated parameters, "
            "so the fit passes through any data and its residual checks nothing (measure "
            "more, different poses, or estimate fewer parameters)", "no redundancy",
            {"equations": equations, "configurations": distinct, "estimated": p}))
    return out


def judge_fivebar(result: FiveBarCalibration, tolerances: Mapping[str, float] | None = None,
                  bound: float = PLAUSIBLE, refusals: Sequence[Refusal] = ()) -> Verdict:
    """The verdict on ``result``: converged, estimates within ``bound`` tolerances,
    standard errors below 1 m / 1 rad (module docstring).

    Args:
        result: the calibration.
        tolerances: ``{name: tolerance}`` [m / rad]; default :func:`fivebar_tolerances`.
        bound: implausible beyond ``bound`` tolerances from nominal.
        refusals: data the model cannot explain (:func:`reading_refusals`).
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
    return Verdict(bool(result.converged), message, [b for _, b in bad], bound,
                   refusals=list(refusals))
