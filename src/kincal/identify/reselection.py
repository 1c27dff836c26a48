"""Checking a stage's base set where the stage ended, and the smaller sets to try.

The base set of a stage is chosen at its start, where the model does not fit yet; the
Jacobian there can see directions it cannot see at a solution.  :func:`reselections`
names the parameters to drop when the set fails where the stage ended (dependent at the
solution, or completing a direction that only rescales the residuals, ``J v = c r``);
:func:`drop_from_report` records them in the identifiability report.  See
:mod:`kincal.identify.solver` ("Identifiability at the solution").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from kincal.identify.identifiability import (
    DEFAULT_TOL,
    ZERO_TOL,
    IdentifiabilityReport,
    analyze,
)
from kincal.measure.base import CompressedSystem, StackedProblem

Array = NDArray[np.float64]


def columns_of(c: CompressedSystem, idx: Sequence[int]) -> CompressedSystem:
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


def reselections(prob: StackedProblem, est: list[int], at_start: CompressedSystem,
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
    c = columns_of(at_end, est)
    if converged and not report and _independent(c.R, tol):
        return [], None
    end = analyze(c.R if converged else c.residual_free(), names, tol=tol, roles=roles)
    lost = [i for i, n in zip(est, names, strict=True) if n not in set(end.identifiable)]
    if converged and not lost:
        return [], end
    start = analyze(columns_of(at_start, est).residual_free(), names, tol=tol, roles=roles)
    suspects = [i for i, n in zip(est, names, strict=True) if n not in set(start.identifiable)]
    options = []
    if suspects:
        options.append((suspects, start, "only rescale(s) the residuals (a direction with "
                        "J v = c r at the stage's start)", True))
    if lost:
        where = "at the solution" if converged else "where the stage stopped"
        options.append((lost, end, f"became dependent {where}", not converged))
    return options, end


def drop_from_report(report: IdentifiabilityReport, check: IdentifiabilityReport,
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
