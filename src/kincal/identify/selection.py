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

Folds: every training block is split into ``K`` folds of its units (rows; an artifact's
placements, whose seatings share their socket points) with a permutation drawn from
``seed`` (0); fold ``k`` holds out the ``k``-th part of every block that has at least
``K`` units, blocks with fewer are always in training.  When no block can be split the
selection says why and chooses nothing.

The folds are independent pure tasks: :class:`FoldSpec` in, :class:`FoldResult` out,
:func:`run_fold` a module-level function of plain values, so any ``mapper`` with the
signature of the builtin :func:`map` runs them (``concurrent.futures`` executors'
``map``; a Dask client's ``map``, whose futures are gathered with ``.result()``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError

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
def _units(block: Any) -> tuple[list[Any], str]:
    if hasattr(block, "subset_placements"):
        return list(block.placements), "placements"
    if hasattr(block, "subset"):
        return list(range(block.q.shape[0])), "rows"
    return [], "rows"


def _subset(block: Any, units: Sequence[Any]) -> Any:
    if hasattr(block, "subset_placements"):
        return block.subset_placements(list(units))
    return block.subset(np.asarray(units, dtype=np.intp))


def split_kind(blocks: Sequence[Any]) -> str:
    """``"rows"``, ``"placements"`` or ``"rows / placements"``: what the folds hold out."""
    kinds = sorted({_units(b)[1] for b in blocks})
    return " / ".join(kinds)


def fold_units(blocks: Sequence[Any], folds: int,
               seed: int | np.random.Generator | None = 0
               ) -> tuple[list[list[Any] | None], list[str]]:
    """Per block, its units in ``folds`` parts (None: too few units, always trained on),
    and why blocks are not split.  Permutations from ``numpy.random.default_rng(seed)``
    (or the generator given), one per block in order; ``seed=None``: the units in their
    order, consecutive parts."""
    rng = seed if isinstance(seed, np.random.Generator) else \
        None if seed is None else np.random.default_rng(seed)
    parts: list[list[Any] | None] = []
    notes = []
    for b in blocks:
        units, what = _units(b)
        if len(units) < max(folds, 2):
            parts.append(None)
            notes.append(f"{b.name}: {len(units)} {what}, fewer than {folds} folds: always "
                         "in training")
            continue
        order = np.arange(len(units)) if rng is None else rng.permutation(len(units))
        parts.append([[units[i] for i in np.sort(p)] for p in np.array_split(order, folds)])
    return parts, notes


@dataclass(frozen=True)
class FoldSpec:
    """One fit of one candidate: plain values, picklable.

    Attributes:
        candidate: index of the candidate in the selection.
        fold: fold index, or -1 for the fit on all the training data (no held-out part).
        robot: the nominal robot.
        blocks: the training blocks inside the candidate's joint model (whole sessions:
            a row keeps its approach direction and load when the block is split).
        train, test: per block, the units (rows or placements) fitted / held out; None
            = the whole block (train) or nothing (test).
        options: keyword arguments of :func:`~kincal.identify.solver.calibrate`
            (``prior`` already scaled).
        tolerances: ``{name: tolerance}`` for the plausibility of the full fit.
        keep: return the fit itself in :attr:`FoldResult.result` (in-process use: a
            whole calibration result is heavy to send back from a worker).
    """

    candidate: int
    fold: int
    robot: Any
    blocks: tuple[Any, ...]
    train: tuple[Any, ...]
    test: tuple[Any, ...]
    options: Mapping[str, Any]
    tolerances: Mapping[str, float] = field(default_factory=dict)
    keep: bool = False


@dataclass
class FoldResult:
    """What one :class:`FoldSpec` gave.

    Attributes:
        candidate, fold: as in the spec.
        errors: ``{kind: held-out errors}`` (position_m, coincidence_m ...), pooled over
            the held-out blocks; empty for the full fit.
        converged: the fit converged.
        trusted: the full fit converged and is plausible (folds: same as converged).
        reason: why not (empty when trusted).
        estimated: number of estimated parameters; ``sigma0``: the fit's noise scale.
        result: the fit (a :class:`~kincal.identify.solver.CalibrationResult`) when
            the spec asked to ``keep`` it, else None.
    """

    candidate: int
    fold: int
    errors: dict[str, Array]
    converged: bool
    trusted: bool
    reason: str = ""
    estimated: int = 0
    sigma0: float = float("nan")
    result: Any = None


def run_fold(spec: FoldSpec) -> FoldResult:
    """Fit ``spec``'s training part and predict its held-out part (module docstring).

    Held-out blocks are predicted with every block parameter from the fit (frames,
    markers, joint-model coefficients); an artifact's held-out placements get their own
    socket points fitted with the robot fixed (:func:`~kincal.identify.validation.validate`).
    """
    from kincal.identify.checks import judge
    from kincal.identify.solver import calibrate
    from kincal.identify.validation import validate

    train = [b if u is None else _subset(b, u) for b, u in zip(spec.blocks, spec.train,
                                                                strict=True)]
    try:
        res = calibrate(spec.robot, train, **dict(spec.options))
    except KincalError as exc:
        return FoldResult(spec.candidate, spec.fold, {}, False, False, f"failed: {exc}")
    errors: dict[str, list[Array]] = {}
    for b, u in zip(spec.blocks, spec.test, strict=True):
        if u is None:
            continue
        held = _subset(b, u)
        v = validate(res.robot, [held], extras=res.extras())
        e = np.array([v["extras"][held.name][n] for n in held.parameters().names])
        for k, x in held.errors(res.robot, e).items():
            errors.setdefault(k, []).append(np.ravel(np.asarray(x, dtype=float)))
    verdict = judge(res, spec.tolerances)
    trusted = verdict.trusted if spec.fold < 0 else bool(res.converged)
    return FoldResult(spec.candidate, spec.fold, {k: np.concatenate(v) for k, v in
                                                   errors.items()},
                      bool(res.converged), trusted, "" if trusted else verdict.short(),
                      len(res.estimated), float(res.sigma0), res if spec.keep else None)


def _fold_parts(parts: Sequence[list[Any] | None], k: int
                ) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
    """Per block, the units trained on and held out in fold ``k`` (None: the whole block /
    nothing)."""
    train = tuple(None if p is None else [u for j, q in enumerate(p) if j != k for u in q]
                  for p in parts)
    test = tuple(None if p is None else list(p[k]) for p in parts)
    return train, test


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
        names = set(tolerances)
        prior = {n: s * cand.scale for n, s in tolerances.items()} if cand.scale else {}
        opts["prior"] = {n: s for n, s in prior.items() if n in names} or None
        full = (None,) * len(blocks)
        specs.append(FoldSpec(c, -1, robot, tuple(blocks), full, full, opts,
                              dict(tolerances)))
        for k in range(folds):
            train, test = _fold_parts(parts, k)
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

    @property
    def choice(self) -> Candidate | None:
        return None if self.chosen is None else self.candidates[self.chosen]

    def to_dict(self) -> dict[str, Any]:
        return {"rule": RULE, "folds": self.folds, "seed": self.seed, "kind": self.kind,
                "chosen": None if self.choice is None else self.choice.label,
                "notes": list(self.notes),
                "candidates": [{**c.to_dict(), f"rms_{self.kind}": self.rms[i],
                                **{f"rms_{k}": v for k, v in self.rms_all[i].items()},
                                "eligible": self.trusted[i], "reason": self.reasons[i]}
                               for i, c in enumerate(self.candidates)]}


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


def _gather(results: Iterable[Any]) -> list[FoldResult]:
    """Results of a mapper, resolving futures (objects with ``.result()``)."""
    out = []
    for r in results:
        res = getattr(r, "result", None)
        out.append(res() if callable(res) and not isinstance(r, FoldResult) else r)
    return out


def _pool(results: Sequence[FoldResult], n: int) -> list[dict[str, list[Array]]]:
    """Per candidate, ``{kind: [held-out errors per fold, in fold order]}``."""
    out: list[dict[str, list[Array]]] = [{} for _ in range(n)]
    for r in sorted(results, key=lambda r: (r.candidate, r.fold)):
        for k, v in r.errors.items():
            out[r.candidate].setdefault(k, []).append(v)
    return out


def run_folds(robot: Any, blocks: Sequence[Any], parts: Sequence[list[Any] | None],
              options: Mapping[str, Any], mapper: Callable[..., Iterable[Any]] = map,
              candidate: int = 0, keep: bool = False) -> list[FoldResult]:
    """One fit per fold of ``blocks`` as they are (``options`` as given, ``prior``
    included): the :class:`FoldResult` of every fold, in fold order."""
    folds = max((len(p) for p in parts if p is not None), default=0)
    specs = [FoldSpec(candidate, k, robot, tuple(blocks), *_fold_parts(parts, k),
                      dict(options), keep=keep) for k in range(folds)]
    return sorted(_gather(mapper(run_fold, specs)), key=lambda r: r.fold)


def _rms(errors: Mapping[str, Sequence[Array]]) -> dict[str, float]:
    return {k: float(np.sqrt(np.mean(np.concatenate([np.ravel(x) for x in v]) ** 2)))
            for k, v in errors.items()}


def gather_folds(robot: Any, blocks_by_candidate: Sequence[Sequence[Any]],
                 cands: Sequence[Candidate], parts: Sequence[list[Any] | None],
                 tolerances: Mapping[str, float], options: Mapping[str, Any],
                 mapper: Callable[..., Iterable[Any]] = map) -> list[dict[str, float]]:
    """Cross-validate blocks as they are (e.g. already inside a joint model): per
    candidate, ``{kind: pooled held-out RMS}`` (``options["prior"]`` as given, the
    candidates' scale and ``tolerances`` ignored).  What ``--cross-validate K`` runs."""
    out = []
    for c, blocks in enumerate(blocks_by_candidate[: len(cands)]):
        pooled = _pool(run_folds(robot, blocks, parts, options, mapper, c), len(cands))[c]
        out.append(_rms(pooled))
    return out


def cross_validate(robot: Any, block: Any, folds: int = 5,
                   rng: np.random.Generator | None = None, *,
                   mapper: Callable[..., Iterable[Any]] = map,
                   **calibrate_options: Any) -> dict[str, Any]:
    """K-fold cross-validation of a calibration on one block, through :func:`run_fold`.

    The block is split by rows (blocks with ``subset(rows)``: a tracker's points) or,
    for an artifact block, by *placements* (``subset_placements``): the rows of one
    placement share its socket points and frames, so they are held out together; in
    consecutive parts of the block's order, or of a permutation drawn from ``rng``.
    Each fold calibrates on the other folds (``calibrate(robot, [train],
    **calibrate_options)``) and predicts the held-out fold with the fit's frames and
    parameters (an artifact's held-out placements get their own socket points fitted
    with the robot fixed).  A fold whose fit fails raises its one-line error.

    Returns:
        ``{"rms_k": pooled RMS of error kind k over all held-out errors (e.g.
        rms_position_m, rms_distance_m), "folds": [per-fold statistics
        (:func:`~kincal.identify.validation.error_statistics`)], "results": [the folds'
        CalibrationResult], "split": "rows" | "placements", "held_out": [per fold, the
        held-out rows / placements], "errors": {kind: [per fold, its held-out errors,
        flattened]}}``.
    """
    from kincal.identify.validation import error_statistics

    units, split = _units(block)
    if not (hasattr(block, "subset") or hasattr(block, "subset_placements")):
        raise KincalError(f"block {block.name!r} cannot be split into folds")
    if not 2 <= folds <= len(units):
        raise KincalError(f"cross-validation of block {block.name!r}: folds must be between "
                          f"2 and its number of {split} ({len(units)}), got {folds}")
    parts, _ = fold_units([block], folds, rng)
    results = run_folds(robot, [block], parts, calibrate_options, mapper, keep=True)
    failed = [r for r in results if r.result is None]
    if failed:
        raise KincalError(f"cross-validation of block {block.name!r}, fold {failed[0].fold}: "
                          f"{failed[0].reason}")
    errors = _pool(results, 1)[0]
    out: dict[str, Any] = {f"rms_{k}": v for k, v in _rms(errors).items()}
    out.update({"folds": [error_statistics(r.errors) for r in results],
                "results": [r.result for r in results], "split": split,
                "held_out": [list((parts[0] or [])[r.fold]) for r in results],
                "errors": errors})
    return out


def select_model(robot: Any, blocks: Sequence[Any], tolerances: Mapping[str, float],
                 cands: Sequence[Candidate] | None = None, *, masses: Sequence[Any] | None = None,
                 folds: int = 10, seed: int = 0,
                 mapper: Callable[..., Iterable[Any]] = map,
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
        folds, seed: K and the permutation seed of the folds.
        mapper: runs :func:`run_fold` over the :class:`FoldSpec` list (``map``, an
            executor's ``map``, a Dask client's ``map``).
        options: further :func:`~kincal.identify.solver.calibrate` options (free, fixed,
            method, loss, stages, max_iter ...).
    """
    from kincal.measure.joints.terms import with_joint_model

    cands = list(cands) if cands is not None else candidates(bool(masses))
    if folds < 2:
        raise KincalError(f"model selection needs at least 2 folds (got {folds})")
    parts, notes = fold_units(blocks, folds, seed)
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
                         None, notes)
    specs = fold_specs(robot, [wrapped[c.terms] for c in cands], cands, parts, tolerances,
                       options)
    results = _gather(mapper(run_fold, specs))
    by: dict[int, list[FoldResult]] = {i: [] for i in range(n)}
    for r in results:
        by[r.candidate].append(r)
    kinds: list[str] = []
    for r in results:
        kinds += [k for k in r.errors if k not in kinds]
    first = [k for k in ("position_m", "coincidence_m") if k in kinds]
    kind = (first + kinds)[0] if kinds else ""
    rms, rms_all, errs, trusted, reasons = [], [], [], [], []
    for i in range(n):
        rs = sorted(by[i], key=lambda r: r.fold)
        full = next(r for r in rs if r.fold < 0)
        folds_ok = all(r.converged for r in rs if r.fold >= 0)
        pooled: dict[str, list[Array]] = {}
        for r in rs:
            for k, v in r.errors.items():
                pooled.setdefault(k, []).append(v)
        every = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in pooled.items()}
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
                     notes)
