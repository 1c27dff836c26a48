"""The five-bar's calibration workflow: measurement files in, a judged result out.

:func:`calibrate_fivebar_file` reads a training file (joint readings + measured J3,
:mod:`kincal.parallel.data`), estimates the chosen parameters
(:func:`kincal.parallel.calibration.calibrate`), compares the end-point position error
``|dX|`` [m] of the nominal and the calibrated robot on the training file and on every
held-out file (:func:`kincal.parallel.report.fivebar_comparison`) and judges the result
(:func:`kincal.parallel.trust.judge_fivebar`).  :func:`write_fivebar_outputs` writes the
calibrated robot (only when trusted, unless forced), the JSON of
:meth:`FiveBarFileCalibration.to_dict` and the HTML report.  The command line
(``kincal calibrate FIVEBAR``) parses options, calls these and prints.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.defaults import FIVEBAR_MAX_ITER
from kincal.errors import KincalError
from kincal.identify.checks import Verdict
from kincal.parallel import residuals as res
from kincal.parallel.calibration import ROBOT_FREE, FiveBarCalibration, calibrate
from kincal.parallel.fivebar import FiveBar
from kincal.parallel.report import fivebar_comparison
from kincal.parallel.trust import judge_fivebar, reading_refusals
from kincal.report.metrics import ErrorComparison

__all__ = ["FIVEBAR_METHODS", "FiveBarFileCalibration", "calibrate_fivebar_file",
           "fivebar_method", "select_fivebar_parameters", "write_fivebar_outputs"]

Array = NDArray[np.float64]

#: Spellings of the two methods -> the name :func:`~kincal.parallel.calibration.calibrate`
#: takes ("thesis": the iterative linearised least squares of the dual SCARA thesis).
FIVEBAR_METHODS: dict[str, str] = {
    "gauss-newton": "gauss-newton", "gn": "gauss-newton", "ils": "gauss-newton",
    "iterative": "gauss-newton", "thesis": "gauss-newton",
    "lm": "lm", "levenberg-marquardt": "lm",
}


def fivebar_method(name: str, where: str = "method") -> str:
    """``"gn"`` -> ``"gauss-newton"``: the method a spelling names (one-line error)."""
    key = FIVEBAR_METHODS.get(name.lower())
    if key is None:
        raise KincalError(f"{where} must be one of {', '.join(FIVEBAR_METHODS)}, not {name!r}")
    return key


def _matching(patterns: Sequence[str], where: str) -> list[str]:
    out: list[str] = []
    for pattern in patterns:
        hits = [n for n in res.ALL_NAMES if fnmatch.fnmatchcase(n, pattern)]
        if not hits:
            raise KincalError(f"{where}: {pattern!r} names no five-bar parameter (known: "
                              f"{', '.join(res.ALL_NAMES)})")
        out += [n for n in hits if n not in out]
    return out


def select_fivebar_parameters(free: Sequence[str] | None = None,
                              fix: Sequence[str] | None = None, frame_free: bool = False,
                              where: tuple[str, str] = ("free", "fix")) -> list[str]:
    """The parameters to estimate: ``free`` (names or ``*`` patterns; default the ten
    robot parameters, plus ``frame.*`` when ``frame_free``) without ``fix``.

    ``where`` names the two lists in the one-line errors (e.g. ``"option --free"``).
    """
    names = _matching(free, where[0]) if free else list(ROBOT_FREE)
    if frame_free:
        names += [n for n in res.FRAME_NAMES if n not in names]
    held = set(_matching(fix, where[1])) if fix else set()
    names = [n for n in names if n not in held]
    if not names:
        raise KincalError(f"{where[1]}: every parameter is fixed; nothing to estimate")
    return names


@dataclass(frozen=True)
class FiveBarFileCalibration:
    """A five-bar calibration from measurement files, compared and judged.

    Attributes:
        calibration: the estimate (:class:`~kincal.parallel.calibration.FiveBarCalibration`).
        data: the training file; ``q`` (N,2) [rad] and ``x`` (N,2) [m] its rows.
        comparisons: end-point errors before/after: the training file (label ``train``),
            then each held-out file (label ``validation``).
        verdict: converged, estimates within 10 tolerances, standard errors sane.
    """

    calibration: FiveBarCalibration
    data: str
    q: Array
    x: Array
    comparisons: tuple[ErrorComparison, ...]
    verdict: Verdict

    @property
    def trusted(self) -> bool:
        """The verdict: may the calibrated robot be used?"""
        return self.verdict.trusted

    @property
    def robot(self) -> FiveBar:
        """The calibrated robot."""
        return self.calibration.robot

    def to_dict(self) -> dict[str, Any]:
        """The calibration's :meth:`~FiveBarCalibration.to_dict` plus ``data``, ``metrics``
        (``train``: the training file, ``validation``: one entry per held-out file, SI) and
        ``trust`` (the verdict)."""
        held = [c for c in self.comparisons if c.label == "validation"]
        train = next(c for c in self.comparisons if c.label == "train")
        return {**self.calibration.to_dict(), "data": self.data,
                "metrics": {"train": train.metrics(),
                            "validation": [{"title": c.title, **c.metrics()} for c in held]},
                "trust": self.verdict.to_dict()}


def calibrate_fivebar_file(
    robot: FiveBar,
    data: str | Path,
    *,
    validate: Sequence[str | Path] = (),
    free: Sequence[str] | None = None,
    fix: Sequence[str] | None = None,
    method: str = "gauss-newton",
    residual: str = "ik",
    frame_free: bool = False,
    max_iter: int = FIVEBAR_MAX_ITER,
    tolerances: Mapping[str, float] | None = None,
) -> FiveBarFileCalibration:
    """Calibrate ``robot`` from the measurement file ``data``; held-out files ``validate``.

    Args:
        robot: the nominal five-bar.
        data: training CSV (joint readings and measured J3, with units).
        validate: held-out CSVs: end-point errors before/after, not fitted.
        free, fix: parameters to estimate / hold (:func:`select_fivebar_parameters`).
        method: ``gauss-newton`` or ``lm`` (or a spelling of :data:`FIVEBAR_METHODS`).
        residual: ``ik`` (joint space) or ``fk`` (task space).
        frame_free: also estimate the measurement frame ``frame.x, frame.y, frame.theta``.
        max_iter: iteration limit.
        tolerances: ``{name: tolerance}`` [m / rad] for the verdict (default 1 mm, 0.5 deg).
    """
    from kincal.parallel.data import read_fivebar_csv

    key = fivebar_method(method)
    names = select_fivebar_parameters(free, fix, frame_free)
    train = read_fivebar_csv(data)
    held = [(Path(p).name, read_fivebar_csv(p)) for p in validate]
    labels = [f"{Path(data).name} line {n}" for n in train.lines]
    result = calibrate(robot, train.q, train.x, free=names, residual=residual, method=key,
                       max_iter=max_iter, labels=labels)
    comparisons = [fivebar_comparison(result, train.q, train.x, f"train ({Path(data).name})",
                                      label="train")]
    comparisons += [fivebar_comparison(result, d.q, d.x, f"validation ({name})",
                                       label="validation") for name, d in held]
    return FiveBarFileCalibration(result, str(data), train.q, train.x, tuple(comparisons),
                                  judge_fivebar(result, tolerances, refusals=reading_refusals(
                                      result, train.q, str(data), list(train.lines))))


def write_fivebar_outputs(result: FiveBarFileCalibration, output: str | Path | None = None,
                          json_path: str | None = None, report: str | Path | None = None,
                          force: bool = False, truth: FiveBar | None = None,
                          inputs: Mapping[str, str] | None = None) -> dict[str, str]:
    """Write the calibrated robot (YAML; only when trusted, unless ``force``), the JSON
    (``-``: stdout) and the HTML report; returns ``{what: path}`` of what was written.

    ``truth``: the true robot of a simulation, shown in the report.
    """
    from kincal.io import atomic_write_text, write_json
    from kincal.parallel.files import write_fivebar
    from kincal.parallel.report import fivebar_report

    cal, written = result.calibration, {}
    if output and (result.trusted or force):
        nominal = cal.nominal
        write_fivebar(replace(cal.robot, name=f"{nominal.name}_calibrated",
                              source=f"kincal calibration of {nominal.name} from "
                              f"{Path(result.data).name}"), output)
        written["calibrated robot"] = str(output)
    if json_path:
        write_json(json_path, result.to_dict())
        if json_path != "-":
            written["json"] = json_path
    if report:
        true_values = None if truth is None else dict(
            zip(res.ALL_NAMES[: res.N_ROBOT], truth.param_values.tolist(), strict=True))
        atomic_write_text(report, fivebar_report(
            cal, result.q, result.x, Path(result.data).name,
            inputs=inputs or {"robot": cal.nominal.name, "data": result.data,
                              "method": cal.method, "residual": cal.residual,
                              "free": ", ".join(cal.free)},
            truth=true_values, comparisons=result.comparisons))
        written["report"] = str(report)
    return written
