"""Held-out validation: how well does a (calibrated) robot predict new measurements?

:func:`validate` evaluates the physical errors (``errors()`` of each block: position
[m], orientation [rad] ...) of measurement blocks that were *not* used to calibrate,
with the robot held fixed.  The blocks' own parameters (instrument frame, marker)
come from one of two protocols:

* ``extras`` given: use them as they are, e.g. the frames estimated on the training
  data (FIGAROH's protocol when the tracker did not move between sessions);
* ``register=True`` (default, no ``extras``): re-estimate only the blocks' own
  parameters (closed-form guess, then least squares) with the robot fixed - the
  protocol for files measured from another tracker placement.  The registration
  absorbs part of any robot error, so it flatters the nominal robot less than it
  seems: compare robots under the same protocol.

With ``register=False`` and no ``extras`` the closed-form initial guesses are used.
A calibrated robot that carries its envelope (:mod:`kincal.identify.envelope`) adds
each block's predicted error and the poses outside its training region, and a warning
(:class:`UserWarning`, one line) when it is used outside that region.
A block without parameters of its own (an artifact whose socket points are the means
of their rows and whose probe is known) is evaluated as it is.  An artifact's socket
points and frames belong to its placements: held-out placements never have them in
``extras``, so they are fitted on the held-out data with the robot fixed (each
placement is an unknown position of the same artifact; with ``sockets="eliminate"``
the block does the same internally, a socket point being the mean of its tips).

Cross-validation holds out rows, or whole placements of an artifact, in independent
pure fold tasks - :class:`FoldSpec` in, :class:`FoldResult` out, :func:`run_fold` a
module-level function of plain values, run by any ``mapper`` with the signature of the
builtin :func:`map` (an executor's, a Dask client's: futures are gathered with
``.result()``) - shared by :func:`cross_validate` (one block), ``--cross-validate K`` and
``--select auto`` (:mod:`kincal.identify.selection`).

Statistics per block and overall: for each error kind ``k`` (``position_m``,
``orientation_rad`` ...): ``rms_k = sqrt(mean e^2)``, ``mean_k``, ``max_k``; and ``n``,
the number of measured points.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.measure.base import MeasurementModel
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["validate", "Validation", "error_statistics", "cross_validate", "PER_PLACEMENT_ROLE",
           "FoldSpec", "FoldResult", "fold_units", "run_fold", "run_folds", "split_kind"]

#: Role of block parameters that belong to one placement of an artifact (socket points,
#: socket frames): held-out placements have their own, fitted on the held-out data.
PER_PLACEMENT_ROLE = "artifact"


def error_statistics(errors: Mapping[str, Array]) -> dict[str, float]:
    """``rms_*``, ``mean_*``, ``max_*`` of each error array, and ``n`` (points)."""
    out: dict[str, float] = {}
    n = 0
    for k, v in errors.items():
        e = np.abs(np.ravel(np.asarray(v, dtype=float)))
        if e.size == 0:
            continue
        out[f"rms_{k}"] = float(np.sqrt(np.mean(e * e)))
        out[f"mean_{k}"] = float(np.mean(e))
        out[f"max_{k}"] = float(np.max(e))
        n = max(n, int(e.size))
    out["n"] = n
    return out


def _extras_for(block: MeasurementModel, extras: Any, index: int) -> dict[str, float]:
    """The values ``extras`` gives for ``block``'s parameters, ``{name: value}`` (a
    mapping by parameter name may leave some out)."""
    names = block.parameters().names
    if hasattr(extras, "extras") and callable(extras.extras):       # a CalibrationResult
        extras = extras.extras()
    if isinstance(extras, Mapping):
        if block.name in extras and not isinstance(extras[block.name], int | float):
            v = extras[block.name]
            if isinstance(v, Mapping):
                return {n: float(v[n]) for n in names if n in v}
            return dict(zip(names, np.asarray(v, dtype=float).reshape(len(names)).tolist(),
                            strict=True))
        return {n: float(extras[n]) for n in names if n in extras}
    if isinstance(extras, Sequence):
        return dict(zip(names, np.asarray(extras[index], dtype=float).reshape(len(names))
                        .tolist(), strict=True))
    raise KincalError("validation: extras must be a mapping {name: value}, a list of arrays "
                      "(one per block) or a CalibrationResult")


def _fit(robot: Robot, block: MeasurementModel, free: Sequence[str],
         known: Mapping[str, float]) -> Array:
    """``block``'s parameter vector: ``free`` ones estimated with ``robot`` fixed (closed-
    form guess, then least squares), the others at their ``known`` values."""
    names = block.parameters().names
    if not free:
        return np.array([known[n] for n in names], dtype=float)
    from kincal.identify.solver import calibrate

    res = calibrate(robot, [block], free=list(free), initial=dict(known) or None,
                    tol_step=1e-12, max_iter=200)
    return res.theta[res.problem.slices[0]]


def _parameters_of(robot: Robot, block: MeasurementModel, extras: Any, index: int,
                   register: bool) -> Array:
    """The block's parameters under the protocol of :func:`validate`."""
    spec = block.parameters()
    if extras is not None:
        known = _extras_for(block, extras, index)
        missing = [n for n in spec.names if n not in known]
        bad = [n for n, role in zip(spec.names, spec.roles, strict=True)
               if n in missing and role != PER_PLACEMENT_ROLE]
        if bad:
            raise KincalError(f"validation: no value for {bad[0]!r} of block "
                              f"{block.name!r} in extras")
        return _fit(robot, block, missing, known)
    if register:
        return _fit(robot, block, spec.names, {})
    return np.asarray(block.initial_guess(robot), dtype=float)


#: How the error kinds are shown: SI unit suffix of a statistic -> (factor, shown unit).
_SHOWN = {"m": (1e3, "mm"), "rad": (180 / np.pi, "deg"), "px": (1.0, "px")}


@dataclass(frozen=True, eq=False)
class Validation(Mapping[str, Any]):
    """What :func:`validate` returns: the errors of a robot on held-out blocks.

    Every statistic names its unit (SI): ``rms_position_m``, ``max_orientation_rad``,
    ``rms_distance_m``, ``rms_pixel_px`` ...; the properties ``rms_position_mm`` etc. give
    the common ones in mm and degrees.  Still reads as the dictionary it used to be:
    ``v["overall"]["rms_position_m"]``, ``v["blocks"]``, ``v["extras"]``
    (:meth:`to_dict`).

    Attributes:
        overall: statistics of all blocks pooled (:func:`error_statistics`): ``rms_k``,
            ``mean_k``, ``max_k`` per error kind ``k`` and ``n`` (measured points).
        blocks: the same statistics per block name.
        extras: each block's parameters used, ``{block: {parameter: value}}`` [SI].
        predicted: with a calibrated robot that carries its envelope, the predicted error
            of each block (:class:`~kincal.identify.accuracy.Prediction`); else empty.
        warnings: one sentence per block used outside the calibration's training region.
    """

    overall: dict[str, float]
    blocks: dict[str, dict[str, float]]
    extras: dict[str, dict[str, float]]
    predicted: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """``{"overall": ..., "blocks": ..., "extras": ...}`` (SI, as JSON takes it)."""
        return {"overall": dict(self.overall), "blocks": {k: dict(v) for k, v in
                                                          self.blocks.items()},
                "extras": {k: dict(v) for k, v in self.extras.items()}}

    def _keys(self) -> tuple[str, ...]:
        return ("overall", "blocks", "extras") + (("predicted", "warnings")
                                                  if self.predicted or self.warnings else ())

    def __getitem__(self, key: str) -> Any:
        if key not in self._keys():
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())

    def _stat(self, key: str, factor: float) -> float:
        v = self.overall.get(key)
        return float(v) * factor if v is not None else float("nan")

    @property
    def n(self) -> int:
        """Measured points, all blocks."""
        return int(self.overall.get("n", 0))

    @property
    def rms_position_mm(self) -> float:
        """RMS position error [mm] (NaN when no block measures positions)."""
        return self._stat("rms_position_m", 1e3)

    @property
    def max_position_mm(self) -> float:
        """Largest position error [mm] (NaN when no block measures positions)."""
        return self._stat("max_position_m", 1e3)

    @property
    def rms_orientation_deg(self) -> float:
        """RMS orientation error [deg] (NaN when no block measures orientations)."""
        return self._stat("rms_orientation_rad", 180 / np.pi)

    @property
    def max_orientation_deg(self) -> float:
        """Largest orientation error [deg] (NaN when no block measures orientations)."""
        return self._stat("max_orientation_rad", 180 / np.pi)

    @staticmethod
    def _kinds(stats: Mapping[str, float]) -> list[tuple[str, str, float, str]]:
        """``(kind, SI key suffix, factor, shown unit)`` of each error kind in ``stats``."""
        out = []
        for key in stats:
            if key.startswith("rms_"):
                kind, _, unit = key[4:].rpartition("_")
                factor, shown = _SHOWN.get(unit, (1.0, unit))
                out.append((kind, key[4:], factor, shown))
        return out

    def __repr__(self) -> str:
        parts = [f"{kind} RMS {self.overall[f'rms_{k}'] * f:.4g} {u}, max "
                 f"{self.overall[f'max_{k}'] * f:.4g} {u}"
                 for kind, k, f, u in self._kinds(self.overall)]
        return (f"Validation(n={self.n}, {'; '.join(parts) or 'no errors'}; "
                f"{len(self.blocks)} block(s): {', '.join(self.blocks)})")

    def _repr_html_(self) -> str:
        """Notebook display: one row per block and error kind, then all pooled."""
        from kincal.io import html_table

        rows = []
        for name, stats in [*self.blocks.items(), ("all blocks", self.overall)]:
            for kind, k, f, u in self._kinds(stats):
                rows.append([name, kind, int(stats.get("n", 0)), f"{stats[f'rms_{k}'] * f:.4g}",
                             f"{stats[f'max_{k}'] * f:.4g}", u])
        return html_table(["block", "error", "n", "RMS", "max", "unit"], rows, repr(self))


def validate(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
             extras: Any = None, register: bool = True) -> Validation:
    """Errors of ``robot`` on held-out measurement ``blocks``.

    Args:
        robot: the robot to validate (held fixed).
        blocks: held-out measurement blocks.
        extras: the blocks' parameters to use as-is: ``{parameter name: value}``
            (e.g. ``result.extras()``), ``{block name: array}``, a list of arrays in
            block order, or a :class:`~kincal.identify.solver.CalibrationResult`.
            Parameters of an artifact's placements (role ``artifact``: socket points
            and frames) belong to the held-out placements, not to training: those
            missing from ``extras`` are fitted on the held-out data.
        register: without ``extras``, re-estimate each block's own parameters with the
            robot fixed (True) or take the closed-form initial guess (False).  A block
            without parameters of its own has nothing to re-estimate.

    Returns:
        a :class:`Validation`: ``overall`` stats, ``blocks`` ``{name: stats}`` and
        ``extras`` ``{name: {param: value}}``, where ``stats`` has ``rms_k``, ``mean_k``,
        ``max_k`` for every error kind ``k`` of the blocks, its SI unit in the name
        (``position_m``, ``orientation_rad``, ``distance_m`` ...), and ``n``; it still
        reads as the dictionary ``{"overall": ..., "blocks": ..., "extras": ...}``.
        With an envelope (the robot is a calibrated one) also ``predicted``
        ``{name: Prediction}`` and ``warnings`` (one sentence per block used outside the
        training region).
    """
    if isinstance(blocks, MeasurementModel):
        blocks = [blocks]
    per: dict[str, dict[str, float]] = {}
    used: dict[str, dict[str, float]] = {}
    pooled: dict[str, list[Array]] = {}
    for i, b in enumerate(blocks):
        e = _parameters_of(robot, b, extras, i, register)
        errs = b.errors(robot, e)
        per[b.name] = error_statistics(errs)
        used[b.name] = dict(zip(b.parameters().names, e.tolist(), strict=True))
        for k, v in errs.items():
            pooled.setdefault(k, []).append(np.ravel(v))
    overall = error_statistics({k: np.concatenate(v) for k, v in pooled.items()})
    more = (_envelope_predictions(robot, blocks) if robot.meta.get("calibration") is not None
            else {})
    return Validation(overall, per, used, **more)


def _envelope_predictions(robot: Robot, blocks: Sequence[MeasurementModel]
                          ) -> dict[str, Any]:
    """The predicted error of each block with joint readings from the envelope ``robot``
    carries, and one warning per block used outside its training region (also issued
    as a :class:`UserWarning`)."""
    import warnings

    from kincal.identify.envelope import outside_line, predict_with_envelope

    preds: dict[str, Any] = {}
    lines: list[str] = []
    for b in blocks:
        q = getattr(b, "q", None)
        if q is None or np.ndim(q) != 2 or np.shape(q)[1] != robot.n:
            continue
        pred = predict_with_envelope(robot, q)
        if pred is None:
            continue
        preds[b.name] = pred
        line = outside_line(pred, "poses", robot.name)
        if line:
            lines.append(f"{b.source_label}: {line}")
            warnings.warn(lines[-1], UserWarning, stacklevel=3)
    return {"predicted": preds, "warnings": lines}


# --------------------------------------------------------------------------- folds
def _innermost(block: Any) -> Any:
    """The measurement block inside any joint-model wrappers."""
    from kincal.measure.joints.deflection import JointDeflection

    while isinstance(block, JointDeflection):
        block = block.inner
    return block


def _units(block: Any) -> tuple[list[Any], str]:
    inner = _innermost(block)       # a joint model around artifact data: its placements
    if hasattr(inner, "subset_placements"):
        return list(inner.placements), "placements"
    if hasattr(block, "subset"):
        return list(range(block.q.shape[0])), "rows"
    return [], "rows"


def _subset(block: Any, units: Sequence[Any]) -> Any:
    if hasattr(block, "subset_placements"):
        return block.subset_placements(list(units))
    if hasattr(_innermost(block), "subset_placements"):
        return block.subset_inner_placements([str(u) for u in units])
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
    from kincal.identify.noise_floor import fit_with_floor
    from kincal.identify.solver import calibrate

    train = [b if u is None else _subset(b, u) for b, u in zip(spec.blocks, spec.train,
                                                                strict=True)
             if u is None or len(u)]              # a file held out whole is not fitted
    try:
        res, _, _ = fit_with_floor(       # as the final fit: stated sigmas that vary
            lambda bs: calibrate(spec.robot, bs, **dict(spec.options)), train)
    except KincalError as exc:
        return FoldResult(spec.candidate, spec.fold, {}, False, False, f"failed: {exc}")
    errors: dict[str, list[Array]] = {}
    extras = res.extras()
    for b, u, t in zip(spec.blocks, spec.test, spec.train, strict=True):
        if u is None or not len(u):
            continue
        held = _subset(b, u)
        own = _extras_for(held, extras, 0)
        if t is not None and not len(t) and not all(     # a whole file out: its frame
                n in own for n, r in zip(held.parameters().names, held.parameters().roles,
                                         strict=True) if r != PER_PLACEMENT_ROLE):
            e = _parameters_of(res.robot, held, None, 0, True)   # registered on it
        else:
            e = _parameters_of(res.robot, held, extras, 0, True)  # as validate() takes them
        for k, x in held.errors(res.robot, e).items():
            errors.setdefault(k, []).append(np.ravel(np.asarray(x, dtype=float)))
    verdict = judge(res, spec.tolerances)
    trusted = verdict.trusted if spec.fold < 0 else bool(res.converged)
    return FoldResult(spec.candidate, spec.fold, {k: np.concatenate(v) for k, v in
                                                   errors.items()},
                      bool(res.converged), trusted, "" if trusted else verdict.short(),
                      len(res.estimated), float(res.sigma0), res if spec.keep else None)


def fold_parts(parts: Sequence[list[Any] | None], k: int
                ) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
    """Per block, the units trained on and held out in fold ``k`` (None: the whole block /
    nothing)."""
    train = tuple(None if p is None else [u for j, q in enumerate(p) if j != k for u in q]
                  for p in parts)
    test = tuple(None if p is None else list(p[k]) for p in parts)
    return train, test


def gather_results(results: Iterable[Any]) -> list[FoldResult]:
    """Results of a mapper, resolving futures (objects with ``.result()``)."""
    out = []
    for r in results:
        res = getattr(r, "result", None)
        out.append(res() if callable(res) and not isinstance(r, FoldResult) else r)
    return out


def pool_errors(results: Sequence[FoldResult], n: int) -> list[dict[str, list[Array]]]:
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
    specs = [FoldSpec(candidate, k, robot, tuple(blocks), *fold_parts(parts, k),
                      dict(options), keep=keep) for k in range(folds)]
    return sorted(gather_results(mapper(run_fold, specs)), key=lambda r: r.fold)


def pooled_rms(errors: Mapping[str, Sequence[Array]]) -> dict[str, float]:
    return {k: float(np.sqrt(np.mean(np.concatenate([np.ravel(x) for x in v]) ** 2)))
            for k, v in errors.items()}


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
    errors = pool_errors(results, 1)[0]
    out: dict[str, Any] = {f"rms_{k}": v for k, v in pooled_rms(errors).items()}
    out.update({"folds": [error_statistics(r.errors) for r in results],
                "results": [r.result for r in results], "split": split,
                "held_out": [list((parts[0] or [])[r.fold]) for r in results],
                "errors": errors})
    return out
