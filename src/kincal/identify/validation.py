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
A block without parameters of its own (an artifact whose socket points are the means
of their rows and whose probe is known) is evaluated as it is.  An artifact's socket
points and frames belong to its placements: held-out placements never have them in
``extras``, so they are fitted on the held-out data with the robot fixed (each
placement is an unknown position of the same artifact; with ``sockets="eliminate"``
the block does the same internally, a socket point being the mean of its tips).

:func:`kincal.identify.selection.cross_validate` holds out rows, or whole placements
of an artifact, through the same fold tasks as ``--select auto``.

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

__all__ = ["validate", "error_statistics", "PER_PLACEMENT_ROLE"]

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


def validate(robot: Robot, blocks: MeasurementModel | Sequence[MeasurementModel],
             extras: Any = None, register: bool = True) -> dict[str, Any]:
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
        ``{"overall": stats, "blocks": {name: stats}, "extras": {name: {param: value}}}``
        where ``stats`` has ``rms_k``, ``mean_k``, ``max_k`` for every error kind ``k``
        of the blocks (``position_m``, ``orientation_rad``, ``distance_m`` ...) and ``n``.
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
    return {"overall": overall, "blocks": per, "extras": used}
