"""Error metrics of a calibration and the result JSON.

* :func:`quantity` / :func:`error_keys` - names, display units and order of error kinds;
* :func:`error_metrics` - RMS / mean / max of per-measurement errors
  (``rms = sqrt(mean(e_i^2))`` over all measured points, [m] and [rad]);
* :class:`ErrorComparison` - errors of one data set before and after calibration;
* :func:`result_json` - ``CalibrationResult.to_dict()`` plus ``metrics.train`` and
  ``metrics.validation`` (each ``rms_position_m``, ``mean_position_m``,
  ``max_position_m``, ``n``, the twins of every other measured kind such as
  ``rms_orientation_rad`` or ``rms_range_m``, and the same under ``before``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def quantity(key: str) -> tuple[str, float, str]:
    """``"position_m" -> ("position", 1e3, "mm")``: name, SI-to-display factor, unit."""
    name, _, unit = key.rpartition("_")
    if unit == "m":
        return name or key, 1e3, "mm"
    if unit == "rad":
        return name or key, 180.0 / math.pi, "deg"
    return (name or key), 1.0, unit


def error_keys(*errors: Mapping[str, Array]) -> list[str]:
    """Error kinds present, ``position_m`` and ``orientation_rad`` first."""
    keys: list[str] = []
    for e in errors:
        keys += [k for k in e if k not in keys]
    first = [k for k in ("position_m", "orientation_rad") if k in keys]
    return first + [k for k in keys if k not in first]


def error_metrics(errors: Mapping[str, Array]) -> dict[str, float | int]:
    """Summary statistics of per-measurement errors, for every error kind.

    ``errors``: ``{"position_m": (N,) or (N, K), "orientation_rad": (N,), "range_m": ...}``
    (keys end in their SI unit).  Returns ``rms_<key> = sqrt(mean(e^2))``,
    ``mean_<key>`` and ``max_<key>`` of ``|e|`` for every key, and ``n``: the number of
    measured points of the first kind (``position_m`` when present).
    """
    out: dict[str, float | int] = {}
    for key in error_keys(errors):
        e = np.abs(np.ravel(np.asarray(errors[key], dtype=float)))
        if "n" not in out:
            out["n"] = int(e.size)
        if e.size == 0:
            continue
        out[f"rms_{key}"] = float(np.sqrt(np.mean(e**2)))
        out[f"mean_{key}"] = float(np.mean(e))
        out[f"max_{key}"] = float(np.max(e))
    return out


def merge_errors(parts: Sequence[Mapping[str, Array]]) -> dict[str, Array]:
    """Concatenate the per-measurement errors of several blocks (flattening markers)."""
    out: dict[str, list[Array]] = {}
    for p in parts:
        for k, v in p.items():
            out.setdefault(k, []).append(np.ravel(np.asarray(v, dtype=float)))
    return {k: np.concatenate(v) for k, v in out.items()}


@dataclass
class ErrorComparison:
    """Errors of one data set before and after calibration.

    Attributes:
        label: ``"train"`` or ``"validation"`` (keys of ``metrics`` in the JSON).
        title: for people, e.g. ``"training data (data.csv)"``.
        before: errors with the nominal robot ``{"position_m": ..., "orientation_rad": ...}``.
        after: errors with the calibrated robot.
        note: how the instrument was registered for this data set.
    """

    label: str
    title: str
    before: dict[str, Array]
    after: dict[str, Array]
    note: str = ""

    def metrics(self) -> dict[str, Any]:
        after = error_metrics(self.after)
        return {**after, "before": error_metrics(self.before), "note": self.note}


def result_json(result: Any, comparisons: Sequence[ErrorComparison],
                extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The result JSON: ``result.to_dict()`` + ``metrics`` (+ ``extra`` entries).

    ``metrics`` has one entry per comparison label (``train``, ``validation``); a label
    without data maps to None so the keys are always there.
    """
    d = dict(result.to_dict())
    metrics: dict[str, Any] = {"train": None, "validation": None}
    for c in comparisons:
        metrics[c.label] = c.metrics()
    d["metrics"] = metrics
    d.update(dict(extra or {}))
    return d
