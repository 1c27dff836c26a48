"""Staged selection: condition-number-driven data selection, then staged linearised least
squares, for artifact (cross-bar) data; the procedure of the staged-selection procedure.

:func:`calibrate_staged_selection` follows the procedure step by step and returns the same
:class:`~kincal.identify.solver.CalibrationResult` as :func:`~kincal.identify.solver.calibrate`
(so reports and JSON work unchanged), with the procedure's own record in
``result.procedure_record`` (:class:`StagedSelectionRecord`).

1. **Data selection by the condition number** (``condition_growth`` = ``g``).  The
   placements are added one at a time, in data order, to the stacked whitened
   Jacobian ``A`` (columns: the identifiable base set of all the data, scaled to unit
   norm on all the data; rows of blocks without placements are always in).  While
   ``A`` is rank deficient every placement is kept; afterwards a placement is
   discarded when ``cond(A with it) > g * cond(A without it)`` (redundant data).
2. **Two stages** (``stages``; default: the robot's angular parameters, i.e. the
   joint offsets ``dtheta`` and twists ``dalpha`` [rad], then its lengths ``dd``,
   ``da`` [m]).  The artifact's own parameters (probe, socket points) are estimated
   in every stage.  Each stage solves ``A x = b`` by linearised least squares,
   ``x = (A^T A)^-1 A^T b`` (through the SVD of the column-scaled ``A``), updates the
   model and repeats until the largest change of a predicted probe point ``dP`` is
   below ``tolerance`` [m] (or ``max_iter``).  Parameters outside the stage stay at
   their current values (nominal in the first pass).
3. **Identifiability**, once, at the starting point (the original procedure analyses the form of
   ``A``): all-zero columns are dropped, and of linearly dependent columns one is
   kept (:func:`~kincal.identify.identifiability.analyze`); the second stage keeps only
   columns independent of those the first stage chose, so the union is identifiable
   jointly and has a covariance.  The sets stay fixed afterwards (re-analysing at a
   moved point would let near-parallel axes look separable).  ``run = k`` keeps the
   ``k``-th member of every group of dependent parameters instead of the first (several
   identifications recover all the dependent ones): the runs give
   *alternative* values that each explain the data alone; the data determine only
   their combination (:func:`staged_selection_runs` collects them).
4. **Cycles.**  The original procedure does one pass (``cycles=1``).  A single pass is biased when
   the first stage's angles absorb length errors held at nominal (joint offsets and
   link offsets of the same link are nearly collinear: canonical correlations of
   0.99+ between the two stages' columns are common).  By default (``cycles=None``)
   the stages are repeated until a whole cycle moves no predicted point by more than
   ``tolerance``: block-coordinate least squares, whose fixed point is the joint
   least-squares solution; plain repetition would converge at the rate ``rho^2`` per
   cycle, so the cycles are Anderson-accelerated (:meth:`_Procedure.until_converged`).

Uncertainty: ``Cov = sigma0^2 (J^T J)^-1`` over the union of the estimated parameters at
the final point, exactly as the one-stage solver reports it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from kincal.defaults import STAGE_MAX_ITER, STAGE_TOLERANCE_M
from kincal.errors import KincalError
from kincal.identify.identifiability import IdentifiabilityReport, analyze, default_priority
from kincal.identify.solver import CalibrationResult, IterationRecord, match_names
from kincal.identify.uncertainty import correlation, inverse_normal_matrix, standard_errors
from kincal.measure.base import (
    HasPlacements,
    MeasurementModel,
    PredictsPoints,
    StackedProblem,
    stack,
)
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["calibrate_staged_selection", "select_placements", "staged_selection_runs",
           "dependent_groups", "compare_results", "one_stage_comparison",
           "StagedSelectionRecord", "PlacementChoice",
           "DEFAULT_STAGES"]

#: Stage selectors: ``unit:rad`` / ``unit:m`` / ``role:offset`` pick robot parameters;
#: anything else is a name or ``*`` pattern over all names.
DEFAULT_STAGES: tuple[tuple[str, ...], ...] = (("unit:rad",), ("unit:m",))
_LABELS: dict[tuple[str, ...], str] = {("unit:rad",): "angles (dtheta, dalpha)",
                                        ("unit:m",): "lengths (dd, da)"}


def _finite_or_none(x: float) -> float | None:
    """``x`` as a float, or None (JSON null) when it is not finite."""
    return float(x) if np.isfinite(x) else None


@runtime_checkable
class _PlacedRows(Protocol):
    """A block whose residual rows belong to placements (an artifact block)."""

    placements: Sequence[str]

    def residual_placement(self) -> NDArray[np.intp]:
        """The placement index of every residual row."""
        ...


@runtime_checkable
class _PlacementSubsets(Protocol):
    """A block that can keep a subset of its placements."""

    placements: Sequence[str]

    def subset_placements(self, placements: Sequence[str]) -> MeasurementModel:
        """The block over the given placements only."""
        ...


@dataclass
class PlacementChoice:
    """One step of the condition-number data selection.

    Attributes:
        block, placement: the placement considered.
        condition: condition number of the scaled stacked matrix with it (inf while
            rank deficient).
        previous: the condition number before it.
        kept: whether it was kept.
    """

    block: str
    placement: str
    condition: float
    previous: float
    kept: bool

    def to_dict(self) -> dict[str, Any]:
        return {"block": self.block, "placement": self.placement,
                "condition": _finite_or_none(self.condition),
                "previous": _finite_or_none(self.previous),
                "kept": self.kept}


@dataclass
class StagedSelectionRecord:
    """What :func:`calibrate_staged_selection` did, beyond the :class:`CalibrationResult`.

    Attributes:
        stages: ``(label, candidate names)`` of each stage.
        estimated: ``(cycle, label, estimated names)`` per stage and cycle.
        selection: the condition-number steps (empty without selection).
        kept, discarded: ``(block, placement)`` pairs.
        corrections: ``(cycle, stage label, iteration, max point correction [m])``.
        cycles: cycles run; ``cycle_corrections[c]`` the largest point change of cycle c [m].
        converged: every stage and the cycles met ``tolerance``.
        tolerance: the point-correction tolerance [m].
        condition_growth: the selection factor (None: no selection).
        run: which member of each dependent group was identified.
        groups: the groups of mutually dependent parameters (the first is the one kept
            in ``run`` 0).
        comparison: with ``compare=True``, :func:`one_stage_comparison` of the result.
    """

    stages: list[tuple[str, list[str]]]
    estimated: list[tuple[int, str, list[str]]]
    selection: list[PlacementChoice]
    kept: list[tuple[str, str]]
    discarded: list[tuple[str, str]]
    corrections: list[tuple[int, str, int, float]]
    cycles: int
    cycle_corrections: list[float]
    converged: bool
    tolerance: float
    condition_growth: float | None
    run: int = 0
    groups: list[list[str]] = field(default_factory=list)
    comparison: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "stages": [{"stage": s, "candidates": list(n)} for s, n in self.stages],
            "estimated": [{"cycle": c, "stage": s, "estimated": list(n)}
                          for c, s, n in self.estimated],
            "selection": [c.to_dict() for c in self.selection],
            "kept": [{"block": b, "placement": p} for b, p in self.kept],
            "discarded": [{"block": b, "placement": p} for b, p in self.discarded],
            "corrections": [{"cycle": c, "stage": s, "iteration": i, "max_point_m": float(d)}
                            for c, s, i, d in self.corrections],
            "cycles": self.cycles, "cycle_corrections_m": [float(x) for x in
                                                           self.cycle_corrections],
            "converged": self.converged, "tolerance_m": self.tolerance,
            "condition_growth": self.condition_growth, "run": self.run,
            "groups": [list(g) for g in self.groups],
            "comparison": self.comparison,
        }


# --------------------------------------------------------------------------- helpers
def _points(prob: StackedProblem, theta: Array) -> Array:
    """All predicted probe / tool points of the problem (M, 3) [m]: the procedure's ``P``."""
    robot, extras = prob.split(theta)
    out = []
    for b, e in zip(prob.blocks, extras, strict=True):
        out.append(b.points(robot, e) if isinstance(b, PredictsPoints)
                   else robot.fk(b.q)[:, :3, 3])
    return np.concatenate(out)


def _select(prob: StackedProblem, spec: Sequence[str], free: list[int]) -> list[int]:
    """Robot parameters picked by the selectors of one stage, plus every block parameter."""
    hit: set[int] = set()
    nr = prob.num_robot
    for s in spec:
        if s.startswith("unit:"):
            hit |= {i for i in range(nr) if prob.units[i] == s[5:]}
        elif s.startswith("role:"):
            hit |= {i for i in range(nr) if prob.roles[i] == s[5:]}
        else:
            hit |= set(match_names(prob.names, s))
    hit |= set(range(nr, len(prob.names)))
    return [i for i in free if i in hit]


def _label(spec: Sequence[str]) -> str:
    return _LABELS.get(tuple(spec), ",".join(spec))


def dependent_groups(report: IdentifiabilityReport) -> list[list[str]]:
    """Groups of parameters the data cannot tell apart (connected by dependencies).

    Each group lists its base (identifiable) member first, then the dependent ones in
    column order.  Unobservable parameters form no group.
    """
    parent: dict[str, str] = {}

    def find(a: str) -> str:
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    for dep, bases in report.dependent.items():
        for b in bases:
            parent[find(dep)] = find(b)
    groups: dict[str, list[str]] = {}
    for n in report.names:
        if n in parent:
            groups.setdefault(find(n), []).append(n)
    ident = set(report.identifiable)
    return [sorted(g, key=lambda n: (n not in ident, report.names.index(n)))
            for g in groups.values() if len(g) > 1]


def _analyze(J: Array, prob: StackedProblem, cols: list[int], first: list[int], run: int,
             tol: float | None) -> tuple[list[int], IdentifiabilityReport]:
    """Base set of ``cols``; columns in ``first`` are taken before any other.

    With ``run = k`` the ``k``-th member of every dependent group is preferred.
    """
    names = [prob.names[i] for i in cols]
    roles = [prob.roles[i] for i in cols]
    pri = default_priority(names, roles)
    pri[[c in first for c in cols]] = -10.0
    rep = analyze(J[:, cols], names, tol=tol, priority=pri)
    if run:
        for g in dependent_groups(rep):
            pick = g[run % len(g)]
            if prob.names.index(pick) not in first:
                pri[names.index(pick)] = -5.0
        rep = analyze(J[:, cols], names, tol=tol, priority=pri)
    return [prob.names.index(n) for n in rep.identifiable], rep


def _svd(A: Array) -> tuple[Array, Array, Array]:
    """Thin SVD; a tall matrix goes through its QR factor (fast with busy BLAS threads)."""
    if A.shape[0] > A.shape[1] > 0:
        Q, R = np.linalg.qr(A)
        U, S, Vt = np.linalg.svd(R)
        return Q @ U, S, Vt
    return np.linalg.svd(A, full_matrices=False)


def _gn_step(r: Array, J: Array) -> Array:
    """Least-squares step ``-pinv(J) r`` through the SVD of the column-scaled ``J``."""
    D = np.linalg.norm(J, axis=0)
    D = np.where(D > 0, D, 1.0)
    U, S, Vt = _svd(J / D)
    keep = S > S[0] * 1e-12 if S.size else S > 0
    return -(Vt[keep].T @ ((U[:, keep].T @ r) / S[keep])) / D


# --------------------------------------------------------------------------- selection
def _placement_rows(prob: StackedProblem) -> list[tuple[str, str, NDArray[np.intp]]]:
    """``(block, placement, residual rows)`` of every placement, and ``("", "", rows)``
    for the rows of blocks without placements (always kept)."""
    out: list[tuple[str, str, NDArray[np.intp]]] = []
    start = 0
    fixed: list[NDArray[np.intp]] = []
    for b in prob.blocks:
        m = len(b.residual_owner())
        rows = np.arange(start, start + m)
        if isinstance(b, _PlacedRows):
            rp = b.residual_placement()
            for i, p in enumerate(b.placements):
                out.append((b.name, p, rows[rp == i]))
        else:
            fixed.append(rows)
        start += m
    if fixed:
        out.insert(0, ("", "", np.concatenate(fixed)))
    return out


def select_placements(robot: Robot, blocks: Sequence[MeasurementModel], growth: float,
                      tol_rank: float | None = None, fixed: Sequence[str] = ()
                      ) -> tuple[list[MeasurementModel], list[PlacementChoice]]:
    """The staged-selection data selection: drop placements that make ``cond(A)`` grow ``> growth``.

    Returns the blocks holding only the kept placements (blocks without placements
    unchanged) and the record of every step.
    """
    if not growth >= 1.0:
        raise KincalError(f"condition_growth must be >= 1 (got {growth})")
    prob, theta = stack(robot, list(blocks))
    _, J = prob.residuals_and_jacobian(theta)
    names = list(prob.names)
    fixed_idx = set(match_names(names, fixed)) if fixed else set()
    cand = [i for i in range(len(names)) if i not in fixed_idx]
    rep = analyze(J[:, cand], [names[i] for i in cand], tol=tol_rank,
                  roles=[prob.roles[i] for i in cand])
    cols = [names.index(n) for n in rep.identifiable]
    A = J[:, cols]
    A = A / np.where(np.linalg.norm(A, axis=0) > 0, np.linalg.norm(A, axis=0), 1.0)
    tol = 1e-8 if tol_rank is None else tol_rank

    def cond(rows: NDArray[np.intp]) -> float:
        sub = A[rows]
        active = np.linalg.norm(sub, axis=0) > 0
        sub = sub[:, active]
        if sub.shape[0] < sub.shape[1] or not sub.size:
            return np.inf
        s = _svd(sub / np.linalg.norm(sub, axis=0))[1]
        return float(s[0] / s[-1]) if s[-1] > tol * s[0] else np.inf

    chosen = np.zeros(0, dtype=np.intp)
    steps: list[PlacementChoice] = []
    current = np.inf
    keep: dict[str, list[str]] = {}
    for bname, pl, rows in _placement_rows(prob):
        new = np.concatenate([chosen, rows])
        c = cond(new)
        if bname == "":
            chosen, current = new, c
            continue
        ok = not np.isfinite(current) or c <= growth * current
        steps.append(PlacementChoice(bname, pl, c, current, bool(ok)))
        if ok:
            chosen, current = new, c
            keep.setdefault(bname, []).append(pl)
    out: list[MeasurementModel] = []
    for b in prob.blocks:
        if isinstance(b, _PlacementSubsets):
            kept = keep.get(b.name, [])
            if not kept:
                continue
            out.append(b.subset_placements(kept) if len(kept) < len(b.placements) else b)
        else:
            out.append(b)
    return out, steps


# --------------------------------------------------------------------------- procedure
def _stage_sets(J0: Array, prob: StackedProblem, stage_cands: Sequence[Sequence[int]], run: int,
                tol_rank: float | None) -> tuple[list[list[int]], list[int], list[list[str]]]:
    """The estimated set of every stage, chosen once at the starting point (as the original
    procedure analyses ``A`` once): each stage keeps the base set of its candidates given the
    parameters earlier stages chose.  Returns ``(per stage, union, dependent groups)``
    (the groups only when ``run`` picks a member of each)."""
    stage_est: list[list[int]] = []
    chosen: list[int] = []
    groups: list[list[str]] = []
    for sc in stage_cands:
        est, rep = _analyze(J0, prob, sorted(set(sc) | set(chosen)), chosen, run, tol_rank)
        est = [i for i in est if i in sc]
        if run:
            groups += [g for g in dependent_groups(rep) if g not in groups]
        stage_est.append(est)
        chosen = sorted(set(chosen) | set(est))
    return stage_est, chosen, groups


def _final_statistics(prob: StackedProblem, theta: Array, J0: Array, cand: list[int],
                      all_est: list[int], tol_rank: float | None, trust_sigma: bool
                      ) -> tuple[Array, IdentifiabilityReport,
                                 tuple[list[str], float, Array, Array, Array], list[str]]:
    """Statistics over the union ``all_est`` of the estimated parameters at ``theta``:
    ``(r, report, (estimated names, sigma0, std, covariance, correlation), messages)``
    with ``sigma0 = sqrt(r^T r / (M - p))`` (1 under ``trust_sigma`` or without
    redundancy) and ``Cov = sigma0^2 (J^T J)^-1`` over the jointly identifiable part."""
    names = prob.names
    r, J = prob.residuals_and_jacobian(theta)
    pri = np.where(np.isin(np.arange(len(cand)), [cand.index(i) for i in all_est]), 0.0, 1.0)
    report = analyze(J0[:, cand], [names[i] for i in cand], tol=tol_rank, priority=pri)
    est_names = [names[i] for i in all_est]
    messages = []
    if set(report.identifiable) != set(est_names):
        messages.append("the estimated set is not jointly identifiable at the solution; "
                        "covariance over its identifiable part")
        all_est = sorted(names.index(n) for n in report.identifiable)
        est_names = [names[i] for i in all_est]
    dof = len(r) - len(all_est)
    sigma0 = 1.0 if trust_sigma or dof <= 0 else float(np.sqrt(r @ r / dof))
    std = np.zeros(len(names))
    if all_est:
        cov = sigma0**2 * inverse_normal_matrix(J[:, all_est])
        std[all_est] = standard_errors(cov)
        corr = correlation(cov)
    else:
        cov = corr = np.zeros((0, 0))
    return r, report, (est_names, sigma0, std, cov, corr), messages


def calibrate_staged_selection(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
                     stages: Sequence[Sequence[str]] = DEFAULT_STAGES,
                     tolerance: float = STAGE_TOLERANCE_M,
                     condition_growth: float | None = None,
                     progress: Callable[[IterationRecord], Any] | None = None, *,
                     cycles: int | None = None, max_cycles: int = 200,
                     max_iter: int = STAGE_MAX_ITER,
                     run: int = 0, free: Sequence[str] | str | None = None,
                     fixed: Sequence[str] | str = (), tol_rank: float | None = None,
                     trust_sigma: bool = False, compare: bool = False) -> CalibrationResult:
    """Calibrate with the procedure's two-stage procedure (see the module docstring).

    Args:
        robot: the nominal robot.
        blocks: measurement blocks (any kind; artifact blocks also get the placement
            selection and give the probe points of the stopping rule).
        stages: one list of selectors per stage: ``unit:rad``, ``unit:m``,
            ``role:offset`` ... (robot parameters) or names / ``*`` patterns.
        tolerance: stop a stage (and the cycles) when no predicted point moves more
            than this [m].
        condition_growth: the selection factor ``g`` (None: keep every placement).
        progress: called with every :class:`IterationRecord`.
        cycles: number of passes through the stages; None = until converged
            (at most ``max_cycles``); 1 = a single pass.
        max_iter: Gauss-Newton iterations per stage and cycle.
        run: which member of each dependent group to identify (0 = kincal's choice).
        free, fixed: candidate names / patterns as in :func:`~kincal.identify.solver.calibrate`.
        tol_rank: tolerance of the identifiability analysis.
        trust_sigma: ``sigma0 = 1`` instead of the a-posteriori estimate.
        compare: also run the one-stage solver on the same data and store
            :func:`one_stage_comparison` in ``result.procedure_record.comparison``.

    Returns:
        A :class:`CalibrationResult` (``method="staged-selection"``) with
        ``result.procedure_record`` a :class:`StagedSelectionRecord`.
    """
    if isinstance(blocks, MeasurementModel):
        blocks = [blocks]
    if not tolerance > 0:
        raise KincalError("the point-correction tolerance must be > 0")
    if cycles is not None and cycles < 1:
        raise KincalError("cycles must be >= 1 (or None: until converged)")
    fixed_list = [fixed] if isinstance(fixed, str) else list(fixed)
    selection: list[PlacementChoice] = []
    if condition_growth is not None:
        blocks, selection = select_placements(robot, blocks, float(condition_growth),
                                              tol_rank, fixed_list)
    prob, theta0 = stack(robot, list(blocks))
    names = prob.names
    cand = list(range(len(names))) if free is None else match_names(names, free)
    if fixed_list:
        drop = set(match_names(names, fixed_list))
        cand = [i for i in cand if i not in drop]
    specs = [list(s) for s in stages]
    if not specs:
        raise KincalError("the staged-selection procedure needs at least one stage")
    stage_cands = [_select(prob, s, cand) for s in specs]
    labels = [_label(s) for s in specs]
    # identifiability once, at the starting point (as the original procedure analyses A once)
    _, J0 = prob.residuals_and_jacobian(theta0)
    stage_est, all_est, groups = _stage_sets(J0, prob, stage_cands, run, tol_rank)
    proc = _Procedure(prob, list(zip(labels, stage_est, strict=True)), max_iter, progress)
    if cycles is not None:
        theta = theta0.copy()
        for cyc in range(1, cycles + 1):
            theta, _ = proc.cycle(theta, cyc, tolerance)
        converged = proc.stages_ok
    else:
        D = np.linalg.norm(J0[:, all_est], axis=0)
        theta, converged = proc.until_converged(theta0, all_est, np.where(D > 0, D, 1.0),
                                                tolerance, max_cycles)
    history, corrections, estimated = proc.history, proc.corrections, proc.estimated
    cycle_moves = proc.cycle_moves
    r, report, stats, messages = _final_statistics(prob, theta, J0, cand, all_est, tol_rank,
                                                   trust_sigma)
    est_names, sigma0, std, cov, corr = stats
    kept, discarded = _kept(prob, selection)
    n_cyc = len(cycle_moves)
    how = "one pass" if cycles == 1 else (
        f"{n_cyc} cycle(s)" + (" (Anderson-accelerated)" if cycles is None else ""))
    messages.insert(0, (f"staged-selection procedure: {how} of {len(specs)} stage(s)"
                        + (", converged" if converged else ", NOT converged")
                        + f" (last cycle moved the points by {cycle_moves[-1]:.3g} m)"))
    if selection:
        messages.append(f"condition-number selection kept {len(kept)} of "
                        f"{len(kept) + len(discarded)} placements")
    stage_names = [(lb, [names[i] for i in sc])
                   for lb, sc in zip(labels, stage_cands, strict=True)]
    info = StagedSelectionRecord(stage_names, estimated, selection, kept, discarded,
                                 corrections, n_cyc, cycle_moves, bool(converged),
                                 float(tolerance), condition_growth, int(run), groups)
    robot_cal, _ = prob.split(theta)
    res = CalibrationResult(
        robot=robot_cal, robot_initial=robot, problem=prob, theta0=theta0, theta=theta,
        names=names, estimated=est_names, identifiability=report, std=std, covariance=cov,
        correlation=corr, sigma0=sigma0, residuals=r, weights=np.ones_like(r), outliers=[],
        history=history, converged=bool(converged),
        iterations=sum(1 for h in history if h.iteration > 0), message="; ".join(messages),
        stages=[(f"c{c}:{s}", n) for c, s, n in estimated[-len(specs):]], method="staged-selection",
        loss="linear", procedure_record=info)
    if compare:
        info.comparison = one_stage_comparison(res)
    return res


def one_stage_comparison(result: CalibrationResult) -> dict[str, Any]:
    """The staged-selection result against one-stage Levenberg-Marquardt on the same (kept) data.

    Two one-stage runs: on the same parameters (``free=result.estimated``; the
    parameter-by-parameter comparison of :func:`compare_results`) and with kincal's
    automatic identifiable set.  Returns ``{"same_parameters": compare_results(...),
    "staged_selection": {...}, "one_stage": {...}, "automatic": {...}}`` where each summary holds
    ``sigma0``, ``estimated`` (count) and the RMS physical errors (``rms_distance_m`` ...).
    """
    from kincal.identify.solver import calibrate

    blocks = result.problem.blocks
    same = calibrate(result.robot_initial, blocks, free=result.estimated)
    auto = calibrate(result.robot_initial, blocks)

    def summary(r: CalibrationResult) -> dict[str, Any]:
        return {"sigma0": float(r.sigma0), "estimated": len(r.estimated),
                "converged": bool(r.converged), **r.rms()}

    return {"same_parameters": compare_results(result, same), "staged_selection": summary(result),
            "one_stage": summary(same), "automatic": summary(auto)}


class _Procedure:
    """The stages and cycles of :func:`calibrate_staged_selection`, with their records."""

    def __init__(self, prob: StackedProblem, stages: list[tuple[str, list[int]]],
                 max_iter: int, progress: Callable[[IterationRecord], Any] | None) -> None:
        self.prob, self.stages, self.max_iter, self.progress = prob, stages, max_iter, progress
        self.history: list[IterationRecord] = []
        self.corrections: list[tuple[int, str, int, float]] = []
        self.estimated: list[tuple[int, str, list[str]]] = []
        self.cycle_moves: list[float] = []
        self.stages_ok = True

    def _record(self, tag: str, it: int, theta: Array, r: Array, step: float) -> None:
        rec = IterationRecord(tag, it, theta.copy(), 0.5 * float(r @ r),
                              float(np.sqrt(np.mean(r * r))) if r.size else 0.0, step, 0.0)
        self.history.append(rec)
        if self.progress is not None:
            self.progress(rec)

    def stage(self, theta: Array, est: list[int], label: str, cyc: int, tol: float
              ) -> Array:
        """Gauss-Newton on ``est`` until no point moves more than ``tol`` [m]."""
        theta = theta.copy()
        tag = f"c{cyc}:{label}"
        r, J = self.prob.residuals_and_jacobian(theta)
        self.estimated.append((cyc, label, [self.prob.names[i] for i in est]))
        self._record(tag, 0, theta, r, 0.0)
        if not est:
            return theta
        P = _points(self.prob, theta)
        for it in range(1, self.max_iter + 1):
            dx = _gn_step(r, J[:, est])
            theta[est] += dx
            r, J = self.prob.residuals_and_jacobian(theta)
            P_new = _points(self.prob, theta)
            move = float(np.max(np.linalg.norm(P_new - P, axis=1)))
            P = P_new
            self.corrections.append((cyc, label, it, move))
            self._record(tag, it, theta, r, float(np.max(np.abs(dx) / (1 + np.abs(theta[est])))))
            if not np.isfinite(move):
                raise KincalError("the staged-selection procedure diverged in stage "
                                  f"{label!r} (cycle {cyc}); use the one-stage solver")
            if move < tol:
                return theta
        self.stages_ok = False
        return theta

    def cycle(self, theta: Array, cyc: int, tol: float) -> tuple[Array, float]:
        """All stages once; returns the new theta and the largest point change [m]."""
        P0 = _points(self.prob, theta)
        for label, est in self.stages:
            theta = self.stage(theta, est, label, cyc, tol)
        move = float(np.max(np.linalg.norm(_points(self.prob, theta) - P0, axis=1)))
        self.cycle_moves.append(move)
        return theta, move

    def until_converged(self, theta0: Array, est: list[int], scale: Array, tol: float,
                        max_cycles: int, depth: int = 6) -> tuple[Array, bool]:
        """Cycles until one moves no point by ``tol``, with Anderson acceleration.

        The cycle map ``G`` (all stages once) is a fixed-point iteration whose fixed
        point is the joint least-squares solution; plain repetition converges at the
        rate ``rho^2`` per cycle, ``rho`` the largest canonical correlation between the
        stages' Jacobian columns (often 0.99+), so the next point mixes the last
        ``depth`` cycles (Anderson / DIIS): ``x+ = x + f - (dX + dF) gamma`` with
        ``f = G(x) - x`` and ``gamma`` the least-squares fit ``dF gamma ~ f`` (in
        column-scaled coordinates).  A mixed point with a larger cost than ``G(x)`` is
        replaced by ``G(x)`` and the memory cleared.  Stages stop at ``tol / 10`` here.
        """
        x = theta0.copy()
        X: list[Array] = []
        F: list[Array] = []
        for cyc in range(1, max_cycles + 1):
            gx, move = self.cycle(x, cyc, 0.1 * tol)
            if move < tol:
                return gx, True
            f = (gx[est] - x[est]) * scale
            X.append(x[est] * scale)
            F.append(f)
            X, F = X[-depth - 1:], F[-depth - 1:]
            if len(F) < 2:
                x = gx
                continue
            dF = np.stack([F[i + 1] - F[i] for i in range(len(F) - 1)], 1)
            dX = np.stack([X[i + 1] - X[i] for i in range(len(X) - 1)], 1)
            gamma = np.linalg.lstsq(dF, f, rcond=None)[0]
            mixed = gx.copy()
            mixed[est] = (X[-1] + f - (dX + dF) @ gamma) / scale
            r_mix = self.prob.residuals(mixed)
            r_g = self.prob.residuals(gx)
            if np.all(np.isfinite(r_mix)) and r_mix @ r_mix <= r_g @ r_g:
                x = mixed
            else:
                x = gx
                X, F = [], []
        return x, False


def _kept(prob: StackedProblem, selection: list[PlacementChoice]
          ) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    discarded = [(c.block, c.placement) for c in selection if not c.kept]
    kept = [(b.name, p) for b in prob.blocks if isinstance(b, HasPlacements)
            for p in b.placements]
    return kept, discarded


def staged_selection_runs(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
                runs: int | None = None, **options: Any
                ) -> tuple[list[CalibrationResult], dict[str, list[float]]]:
    """Repeat :func:`calibrate_staged_selection` with ``run = 0, 1, ...``.

    Returns the results and, for every parameter of a dependent group, its value in
    each run where it was the identified member (NaN where it was held).  The values
    are alternatives: each run explains the data with one member of a group; the
    data determine only their combination.
    """
    first = calibrate_staged_selection(robot, blocks, run=0, **options)
    groups = dependent_groups(first.identifiability)
    n = runs if runs is not None else max((len(g) for g in groups), default=1)
    results = [first] + [calibrate_staged_selection(robot, blocks, run=k, **options)
                         for k in range(1, n)]
    values: dict[str, list[float]] = {}
    for g in groups:
        for name in g:
            values[name] = [float(r.params[name]) if name in r.estimated else float("nan")
                            for r in results]
    return results, values


def compare_results(first: CalibrationResult, other: CalibrationResult) -> dict[str, Any]:
    """Compare two calibrations parameter by parameter (e.g. the staged selection vs one-stage LM).

    For every parameter both estimated: the difference [m / rad] and the difference in
    units of the larger of the two standard errors.  Compare like with like: run the
    one-stage solver with ``free=first.estimated`` so both estimate the same base set
    (different base sets absorb dependent parameters differently).

    Returns ``{"rows": [{name, a, b, diff, sigmas}], "max_sigmas", "worst", "only_a",
    "only_b", "sigma0": (a, b), "cost": (a, b)}``.
    """
    rows: list[dict[str, Any]] = []
    for n in first.estimated:
        if n not in other.estimated:
            continue
        i, j = first.names.index(n), other.names.index(n)
        s = max(float(first.std[i]), float(other.std[j]))
        d = float(first.theta[i] - other.theta[j])
        rows.append({"name": n, "a": float(first.theta[i]), "b": float(other.theta[j]),
                     "diff": d, "sigmas": abs(d) / s if s > 0 else float("inf")})
    worst = max(rows, key=lambda r: r["sigmas"]) if rows else None
    return {"rows": rows, "max_sigmas": worst["sigmas"] if worst else 0.0,
            "worst": worst["name"] if worst else "",
            "only_a": [n for n in first.estimated if n not in other.estimated],
            "only_b": [n for n in other.estimated if n not in first.estimated],
            "sigma0": (float(first.sigma0), float(other.sigma0)),
            "cost": (float(first.cost), float(other.cost))}
