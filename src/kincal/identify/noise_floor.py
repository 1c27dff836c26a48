"""Stated noise that varies from row to row, and a residual it does not explain.

A file may state a standard deviation per row, or per row and instrument axis (a laser
tracker's ``sigma_x, sigma_y, sigma_z``).  Weights ``1 / sigma_i^2`` give the best
estimate when the stated noise is all the residual holds.  On a real robot the residual
also holds the model's floor: errors no parameter describes (compliance, thermal drift,
gear play), of about the same size at every pose whatever the instrument's precision
there.  A residual component's variance is then ``sigma_i^2 + f^2``, and the weights
``1 / sigma_i^2`` trust the most precise rows for what the model cannot do there (the
IPA UR10 series: residuals 37 times the tracker's stated per-axis sigmas; weighted by
them alone, the held-out error grows from 1.13 to 1.43 mm).

One step of variance-component estimation: from the fit with the stated sigmas, per
block and per kind of residual (positions [m], orientations [rad]),

    f^2 = max(0, (M / (M - p)) mean_i(e_i^2) - mean_i(sigma_i^2)),

``e_i`` the raw residual components (SI), ``sigma_i`` their stated standard deviations,
``M`` the problem's residual count and ``p`` its estimated parameters (the fit takes
``p`` degrees of freedom out of the residual).  The fit is then repeated with
``sigma_i'^2 = sigma_i^2 + f^2``.  When the stated noise explains the residual
(``f = 0``) nothing changes.  Blocks whose stated sigma is one number for every row and
axis are left as they are: a floor common to all their rows scales every weight alike.
Position and pose blocks (also inside a joint-model wrapper) are floored; other blocks
keep their stated sigmas.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.measure.instruments.pose import PoseMeasurement
from kincal.measure.instruments.position import PositionMeasurement

__all__ = ["NoiseFloor", "noise_floors", "floored_blocks", "fit_with_floor"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class NoiseFloor:
    """The floor added to one block's stated standard deviations.

    Attributes:
        block: the block's name.
        position_m: ``f`` of the positions [m].
        orientation_rad: ``f`` of the orientations [rad] (0 for position blocks).
        stated_m: the RMS of the stated position sigmas [m].
    """

    block: str
    position_m: float
    orientation_rad: float
    stated_m: float

    def sentence(self) -> str:
        """One line for the console."""
        rot = (f", orientations {np.degrees(self.orientation_rad):.3g} deg"
               if self.orientation_rad > 0 else "")
        return (f"{self.block}: the stated sigmas vary (RMS {self.stated_m * 1e3:.3g} mm) "
                f"and the residual exceeds them: an unmodelled floor of "
                f"{self.position_m * 1e3:.3g} mm{rot} added to every stated variance and "
                "the fit repeated (variance components)")


def _inner(block: Any) -> Any:
    while hasattr(block, "inner"):
        block = block.inner
    return block


def _varies(sigma: Array) -> bool:
    s = np.asarray(sigma, dtype=float)
    return s.size > 1 and float(np.ptp(s)) > 1e-9 * float(np.max(s))


def _floor(mean_e2: float, mean_s2: float, dof: float) -> float:
    return float(np.sqrt(max(0.0, dof * mean_e2 - mean_s2)))


def noise_floors(result: Any) -> list[NoiseFloor]:
    """The floors of the blocks of a calibration ``result`` whose stated sigma varies
    (module docstring); an empty list when none varies or the residual is explained."""
    prob = result.problem
    M = int(np.size(result.residuals))
    p = len(result.estimated)
    if M <= p:
        return []
    dof = M / (M - p)
    robot, extras = prob.split(np.asarray(result.theta, dtype=float))
    out = []
    for b, extra in zip(prob.blocks, extras, strict=True):
        inner = _inner(b)
        if isinstance(inner, PoseMeasurement):
            sp, so = inner.sigma_position, inner.sigma_orientation
            if not (_varies(sp) or _varies(so)):
                continue
            err = b.errors(robot, extra)
            fp = _floor(float(np.mean(err["position_m"] ** 2)) / 3, float(np.mean(sp**2)), dof)
            fo = _floor(float(np.mean(err["orientation_rad"] ** 2)) / 3,
                        float(np.mean(so**2)), dof)
        elif isinstance(inner, PositionMeasurement):
            sp = np.asarray(inner.sigma, dtype=float)
            if not _varies(sp):
                continue
            err = b.errors(robot, extra)
            fp = _floor(float(np.mean(np.asarray(err["position_m"]) ** 2)) / 3,
                        float(np.mean(sp**2)), dof)
            fo = 0.0
        else:
            continue
        if fp > 0 or fo > 0:
            out.append(NoiseFloor(b.name, fp, fo, float(np.sqrt(np.mean(sp**2)))))
    return out


def _with_floor(block: Any, floor: NoiseFloor) -> Any:
    """A copy of ``block`` whose stated variances carry ``floor``."""
    if hasattr(block, "inner"):
        out = copy.copy(block)
        out.inner = _with_floor(block.inner, floor)
        return out
    new: PoseMeasurement | PositionMeasurement
    if isinstance(block, PoseMeasurement):
        new = PoseMeasurement(block.q, block.poses,
                              np.sqrt(block.sigma_position**2 + floor.position_m**2),
                              np.sqrt(block.sigma_orientation**2 + floor.orientation_rad**2),
                              block.name, block.orientation_axes)
    elif isinstance(block, PositionMeasurement):
        pos = copy.copy(block)
        pos.sigma = np.sqrt(np.asarray(block.sigma, dtype=float) ** 2 + floor.position_m**2)
        new = pos
    else:
        return block
    new.provenance = block.provenance
    return new


def floored_blocks(blocks: Sequence[Any], floors: Sequence[NoiseFloor]) -> list[Any]:
    """``blocks`` with each one's floor (by name) added to its stated variances."""
    by_name = {f.block: f for f in floors}
    return [_with_floor(b, by_name[b.name]) if b.name in by_name else b for b in blocks]


def fit_with_floor(fit: Callable[[list[Any]], Any], blocks: Sequence[Any]
                   ) -> tuple[Any, list[Any], list[NoiseFloor]]:
    """``fit(blocks)``, then again on :func:`floored_blocks` when :func:`noise_floors`
    finds a floor: the result, the blocks it was fitted on, the floors (empty: one fit)."""
    res = fit(list(blocks))
    floors = noise_floors(res)
    if not floors:
        return res, list(blocks), []
    floored = floored_blocks(blocks, floors)
    return fit(floored), floored, floors
