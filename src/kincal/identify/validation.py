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

Statistics per block and overall: for each error kind ``k`` (``position_m``,
``orientation_rad`` ...): ``rms_k = sqrt(mean e^2)``, ``mean_k``, ``max_k``; and ``n``,
the number of measured points.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.measure.base import MeasurementModel
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["validate", "error_statistics", "cross_validate"]


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


def _extras_for(block: MeasurementModel, extras: Any, index: int) -> Array:
    names = block.parameters().names
    if hasattr(extras, "extras") and callable(extras.extras):       # a CalibrationResult
        extras = extras.extras()
    if isinstance(extras, Mapping):
        if block.name in extras and not isinstance(extras[block.name], int | float):
            v = np.asarray(extras[block.name], dtype=float)
            if isinstance(extras[block.name], Mapping):
                v = np.array([extras[block.name][n] for n in names])
            return v.reshape(len(names))
        missing = [n for n in names if n not in extras]
        if missing:
            raise KincalError(f"validation: no value for {missing[0]!r} of block "
                              f"{block.name!r} in extras")
        return np.array([float(extras[n]) for n in names])
    if isinstance(extras, Sequence):
        return np.asarray(extras[index], dtype=float).reshape(len(names))
    raise KincalError("validation: extras must be a mapping {name: value}, a list of arrays "
                      "(one per block) or a CalibrationResult")


def _register(robot: Robot, block: MeasurementModel) -> Array:
    from kincal.identify.solver import calibrate

    res = calibrate(robot, [block], free=[f"{block.name}.*"], tol_step=1e-12, max_iter=200)
    return res.theta[res.problem.slices[0]]


def validate(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
             extras: Any = None, register: bool = True) -> dict[str, Any]:
    """Errors of ``robot`` on held-out measurement ``blocks``.

    Args:
        robot: the robot to validate (held fixed).
        blocks: held-out measurement blocks.
        extras: the blocks' parameters to use as-is: ``{parameter name: value}``
            (e.g. ``result.extras()``), ``{block name: array}``, a list of arrays in
            block order, or a :class:`~kincal.identify.solver.CalibrationResult`.
        register: without ``extras``, re-estimate each block's own parameters with the
            robot fixed (True) or take the closed-form initial guess (False).

    Returns:
        ``{"overall": stats, "blocks": {name: stats}, "extras": {name: {param: value}}}``
        where ``stats`` has ``rms_position_m``, ``mean_position_m``, ``max_position_m``,
        ``n`` (and ``*_orientation_rad`` when orientation is measured).
    """
    if isinstance(blocks, MeasurementModel):
        blocks = [blocks]
    per: dict[str, dict[str, float]] = {}
    used: dict[str, dict[str, float]] = {}
    pooled: dict[str, list[Array]] = {}
    for i, b in enumerate(blocks):
        if extras is not None:
            e = _extras_for(b, extras, i)
        elif register:
            e = _register(robot, b)
        else:
            e = np.asarray(b.initial_guess(robot), dtype=float)
        errs = b.errors(robot, e)
        per[b.name] = error_statistics(errs)
        used[b.name] = dict(zip(b.parameters().names, e.tolist(), strict=True))
        for k, v in errs.items():
            pooled.setdefault(k, []).append(np.ravel(v))
    overall = error_statistics({k: np.concatenate(v) for k, v in pooled.items()})
    return {"overall": overall, "blocks": per, "extras": used}


def cross_validate(robot: Robot, block: Any, folds: int = 5, rng: np.random.Generator | None = None,
                   **calibrate_options: Any) -> dict[str, Any]:
    """K-fold cross-validation of a calibration on one block that supports ``subset(rows)``.

    Each fold calibrates on the other folds (``calibrate(robot, [train],
    **calibrate_options)``) and validates on the fold with the training frames
    (``extras`` from training).  Returns ``{"rms_position_m": pooled RMS over all
    held-out points, "folds": [per-fold overall stats], "results": [...]}``.
    """
    from kincal.identify.solver import calibrate

    if not hasattr(block, "subset"):
        raise KincalError(f"block {block.name!r} cannot be split into folds")
    N = block.q.shape[0]
    idx = np.arange(N) if rng is None else rng.permutation(N)
    parts = np.array_split(idx, folds)
    stats, results, errs = [], [], []
    for k in range(folds):
        test = np.sort(parts[k])
        train = np.sort(np.concatenate([parts[j] for j in range(folds) if j != k]))
        res = calibrate(robot, [block.subset(train)], **calibrate_options)
        v = validate(res.robot, [block.subset(test)], extras=res.extras())
        stats.append(v["overall"])
        results.append(res)
        tb = block.subset(test)
        errs.append(np.ravel(tb.errors(res.robot, res.theta[res.problem.slices[0]])
                             ["position_m"]))
    e = np.concatenate(errs)
    return {"rms_position_m": float(np.sqrt(np.mean(e * e))), "folds": stats,
            "results": results}
