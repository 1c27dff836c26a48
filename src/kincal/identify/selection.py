"""Choosing the model by cross-validation on the training data: ``--select auto``.

Candidates (:func:`candidates`): the geometric model, ``+ hysteresis``, and, where the
robot has link masses, ``+ compliance`` and ``+ hysteresis + compliance``
(:mod:`kincal.measure.joints`), each with the prior at :data:`PRIOR_SCALES` times the
manufacturing tolerances (:mod:`kincal.identify.tolerances`) and without a prior (least
squares).  Every candidate is fitted on K-1 folds of the training files and predicts the
held-out fold with the frames and parameters of that fit (:func:`run_fold`); the score
is the pooled RMS of every held-out error of the primary kind (position when measured;
artifacts: the coincidence of a held-out placement's seatings).

The rule (:func:`choose`): **the candidate with the lowest cross-validated RMS, among
those whose fit on the whole training data converges with every estimate within 10
tolerances of nominal** (:mod:`kincal.identify.checks`).  The validation files never
choose anything.

Folds (:func:`~kincal.identify.region_folds.group_folds`): by default they judge each
model where it was not fitted: leave one file out among training files that share an
instrument name, else one placement out, else one workspace region out (k-means of the
joint configurations), and random folds of rows / placements only when none of these
applies (``split="random"`` asks for them); :attr:`Selection.split` says in one line
which was used.  When nothing can be held out the selection says why and chooses nothing.

The folds are independent pure tasks of :mod:`kincal.identify.validation` (the one fold
mechanism, also :func:`~kincal.identify.validation.cross_validate`'s): :class:`FoldSpec`
in, :class:`FoldResult` out, :func:`run_fold` a module-level function of plain values,
so any ``mapper`` with the signature of the builtin :func:`map` runs them
(``concurrent.futures`` executors' ``map``; a Dask client's ``map``, whose futures are
gathered with ``.result()``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.region_folds import group_folds
from kincal.identify.validation import (
    FoldResult,
    FoldSpec,
    cross_validate,
    fold_parts,
    fold_units,
    gather_results,
    pool_errors,
    pooled_rms,
    run_fold,
    run_folds,
    split_kind,
)

Array = NDArray[np.float64]

__all__ = ["Candidate", "FoldSpec", "FoldResult", "Selection", "candidates", "fold_units",
           "fold_specs", "run_fold", "run_folds", "select_model", "gather_folds",
           "cross_validate", "choose", "RULE", "split_kind",
           "PRIOR_SCALES", "JOINT_MODELS"]

#: Prior scales tried (times the tolerances); ``None`` is least squares.
PRIOR_SCALES: tuple[float | None, ...] = (1.0, 3.0, None)
#: Joint models tried, in order of complexity.
JOINT_MODELS: tuple[tuple[str, ...], ...] = ((), ("hysteresis",), ("compliance",),
                                             ("hysteresis", "compliance"))


@dataclass(frozen=True)
class Candidate:
    """One model: joint-model ``terms`` and the prior ``scale`` (None: least squares)."""

    terms: tuple[str, ...] = ()
    scale: float | None = 1.0

    @property
    def label(self) -> str:
        model = "geometric" + "".join(f" + {t}" for t in self.terms)
        prior = "least squares" if self.scale is None else f"prior x{self.scale:g}"
        return f"{model}, {prior}"

    @property
    def complexity(self) -> tuple[int, float]:
        """Fewer joint-model terms, then a tighter prior, is simpler."""
        return len(self.terms), math.inf if self.scale is None else self.scale

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label, "joint_model": list(self.terms),
                "prior_scale": self.scale}


def candidates(masses: bool = False, scales: Sequence[float | None] = PRIOR_SCALES,
               joint_models: Sequence[Sequence[str]] = JOINT_MODELS) -> list[Candidate]:
    """The candidate models: every joint model (compliance only with ``masses``) with
    every prior scale."""
    out = []
    for terms in joint_models:
        if "compliance" in terms and not masses:
            continue
        out += [Candidate(tuple(terms), s) for s in scales]
    return out


# --------------------------------------------------------------------------- folds
def fold_specs(robot: Any, blocks_by_candidate: Sequence[Sequence[Any]],
               cands: Sequence[Candidate], parts: Sequence[list[Any] | None],
               tolerances: Mapping[str, float], options: Mapping[str, Any]
               ) -> list[FoldSpec]:
    """Every task of a selection: per candidate, its full fit (fold -1) and one fit per
    fold (``parts`` from :func:`fold_units`)."""
    folds = max((len(p) for p in parts if p is not None), default=0)
    specs = []
    for c, (cand, blocks) in enumerate(zip(cands, blocks_by_candidate, strict=True)):
        opts = dict(options)
        opts["prior"] = {n: s * cand.scale for n, s in tolerances.items()} \
            if cand.scale and tolerances else None
        full = (None,) * len(blocks)
        specs.append(FoldSpec(c, -1, robot, tuple(blocks), full, full, opts,
                              dict(tolerances)))
        for k in range(folds):
            train, test = fold_parts(parts, k)
            specs.append(FoldSpec(c, k, robot, tuple(blocks), train, test, opts,
                                  dict(tolerances)))
    return specs


# --------------------------------------------------------------------------- choice
@dataclass
class Selection:
    """The cross-validation of every candidate and the choice.

    Attributes:
        candidates: the models compared.
        folds, seed: the folds and the permutation seed.
        kind: the error kind scored (``position_m``, ``coincidence_m`` ...).
        rms: per candidate, the pooled held-out RMS of ``kind`` [SI] (NaN: no data).
        rms_all: per candidate, ``{kind: pooled RMS}`` of every held-out kind.
        errors: per candidate, the held-out errors of ``kind`` (in fold order).
        trusted: per candidate, its full fit converged and is plausible.
        reasons: per candidate, why it is not eligible ("" if it is).
        chosen: index of the chosen candidate, or None (nothing could be split, or no
            candidate is eligible).
        notes: sentences (blocks always in training, why nothing was chosen).
        split: one line: what each fold holds out (files, placements, workspace regions
            or random rows; :func:`~kincal.identify.region_folds.group_folds`).
        split_by: the same in a word or two: ``file``, ``placement``, ``workspace
            region``, ``rows`` (random folds).
    """

    candidates: list[Candidate]
    folds: int
    seed: int
    kind: str
    rms: list[float]
    rms_all: list[dict[str, float]]
    errors: list[Array]
    trusted: list[bool]
    reasons: list[str]
    chosen: int | None
    notes: list[str] = field(default_factory=list)
    split: str = ""
    split_by: str = ""

    @property
    def choice(self) -> Candidate | None:
        return None if self.chosen is None else self.candidates[self.chosen]

    def to_dict(self) -> dict[str, Any]:
        return {"rule": RULE, "folds": self.folds, "seed": self.seed, "kind": self.kind,
                "split": self.split,
                "chosen": None if self.choice is None else self.choice.label,
                "notes": list(self.notes),
                "candidates": [{**c.to_dict(), f"rms_{self.kind}": self.rms[i],
                                **{f"rms_{k}": v for k, v in self.rms_all[i].items()},
                                "eligible": self.trusted[i], "reason": self.reasons[i]}
                               for i, c in enumerate(self.candidates)]}


#: What one fold holds out, by the kind of split.
_SPLIT_BY = {"files": "file", "placements": "placement", "regions": "workspace region",
             "random": "rows"}


#: The selection rule, in words (the JSON and the report state it).
RULE = ("lowest K-fold cross-validated RMS on the training files, among the candidates "
        "whose fit on all the training data converges with every estimate within 10 "
        "tolerances of nominal")


def choose(rms: Sequence[float], eligible: Sequence[bool]) -> int | None:
    """:data:`RULE`: the index of the lowest finite ``rms`` among the ``eligible``."""
    best = None
    for i, (r, ok) in enumerate(zip(rms, eligible, strict=True)):
        if ok and math.isfinite(r) and (best is None or r < rms[best]):
            best = i
    return best


def gather_folds(robot: Any, blocks_by_candidate: Sequence[Sequence[Any]],
                 cands: Sequence[Candidate], parts: Sequence[list[Any] | None],
                 tolerances: Mapping[str, float], options: Mapping[str, Any],
                 mapper: Callable[..., Iterable[Any]] = map) -> list[dict[str, float]]:
    """Cross-validate blocks as they are (e.g. already inside a joint model): per
    candidate, ``{kind: pooled held-out RMS}`` (``options["prior"]`` as given, the
    candidates' scale and ``tolerances`` ignored).  What ``--cross-validate K`` runs."""
    out = []
    for c, blocks in enumerate(blocks_by_candidate[: len(cands)]):
        pooled = pool_errors(run_folds(robot, blocks, parts, options, mapper, c), len(cands))[c]
        out.append(pooled_rms(pooled))
    return out


def select_model(robot: Any, blocks: Sequence[Any], tolerances: Mapping[str, float],
                 cands: Sequence[Candidate] | None = None, *, masses: Sequence[Any] | None = None,
                 folds: int = 10, seed: int = 0,
                 mapper: Callable[..., Iterable[Any]] = map, split: str = "auto",
                 **options: Any) -> Selection:
    """Cross-validate every candidate on the training ``blocks`` and choose one (:data:`RULE`).

    Args:
        robot: the nominal robot.
        blocks: the training blocks, *without* a joint model (each candidate wraps them
            in its own, :func:`~kincal.measure.joints.terms.with_joint_model`).
        tolerances: ``{name: tolerance}`` [m / rad]; the prior of a candidate is its
            scale times these.
        cands: the candidates (default :func:`candidates`, compliance when ``masses``).
        masses: link masses for the compliance term.
        folds, seed: K (at most; fewer with fewer files, placements or regions) and the
            seed of the folds.
        split: ``"auto"``: by files sharing a name, else placements, else workspace
            regions, random folds only when none applies; ``"random"``: random folds
            (:func:`~kincal.identify.region_folds.group_folds`).
        mapper: runs :func:`run_fold` over the :class:`FoldSpec` list (``map``, an
            executor's ``map``, a Dask client's ``map``).
        options: further :func:`~kincal.identify.solver.calibrate` options (free, fixed,
            method, loss, stages, max_iter ...).
    """
    from kincal.measure.joints.terms import with_joint_model

    cands = list(cands) if cands is not None else candidates(bool(masses))
    if folds < 2:
        raise KincalError(f"model selection needs at least 2 folds (got {folds})")
    plan = group_folds(blocks, folds, seed, split)
    parts: list[list[Any] | None] = list(plan.parts)
    notes, folds = list(plan.notes), plan.folds
    wrapped: dict[tuple[str, ...], list[Any]] = {}
    for c in cands:
        if c.terms not in wrapped:
            wrapped[c.terms] = with_joint_model(blocks, robot, c.terms, masses) \
                if c.terms else list(blocks)
    n = len(cands)
    if all(p is None for p in parts):
        notes.append(f"no training block has {folds} rows or placements to hold out: "
                     "nothing to cross-validate, no model chosen")
        nan = [math.nan] * n
        return Selection(cands, folds, seed, "", nan, [{} for _ in cands],
                         [np.zeros(0) for _ in cands], [False] * n, ["not cross-validated"] * n,
                         None, notes, plan.text, _SPLIT_BY[plan.kind])
    specs = fold_specs(robot, [wrapped[c.terms] for c in cands], cands, parts, tolerances,
                       options)
    results = gather_results(mapper(run_fold, specs))
    pooled_by = pool_errors(results, n)
    kinds: list[str] = []
    for r in results:
        kinds += [k for k in r.errors if k not in kinds]
    first = [k for k in ("position_m", "coincidence_m") if k in kinds]
    kind = (first + kinds)[0] if kinds else ""
    rms, rms_all, errs, trusted, reasons = [], [], [], [], []
    for i, pooled in enumerate(pooled_by):
        rs = [r for r in results if r.candidate == i]
        full = next(r for r in rs if r.fold < 0)
        folds_ok = all(r.converged for r in rs if r.fold >= 0)
        every = pooled_rms(pooled)
        e = np.concatenate(pooled[kind]) if kind in pooled else np.zeros(0)
        errs.append(e)
        rms.append(every.get(kind, math.nan))
        rms_all.append(every)
        ok = full.trusted and folds_ok
        trusted.append(ok)
        reasons.append("" if ok else full.reason or "a fold did not converge")
    chosen = choose(rms, trusted)
    if chosen is None:
        notes.append("no candidate is eligible (none converged with plausible estimates)")
    return Selection(cands, folds, seed, kind, rms, rms_all, errs, trusted, reasons, chosen,
                     notes, plan.text, _SPLIT_BY[plan.kind])
