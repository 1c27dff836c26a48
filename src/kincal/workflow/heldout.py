"""Held-out files, one at a time: the protocol, the errors before and after, the prediction.

Used by ``kincal calibrate --validate`` and ``kincal validate``: both evaluate each
held-out file with :func:`evaluate_file`, so "before" and "after" mean the same in both.

**Protocols** (the instrument's own parameters on a held-out file; the robot is never
refitted):

* ``training`` - same session (the instrument did not move): every block parameter
  (frame, marker, joint-model coefficients) from the training fit, matched by name
  (``marker`` and ``marker1`` are the same point, so a one-marker file validates against
  a four-marker fit); checked against the file itself (:data:`FRAMES_CONTRADICTED`):
  a file whose own registration fits it far better says so in a warning;
* ``register`` - the instrument moved: its frame *and* marker are fitted on the held-out
  file with the robot held, as far as that file can identify them
  (:func:`~kincal.identify.solver.calibrate` with the block's parameters free selects
  the identifiable ones); what it cannot identify keeps its training value and the note
  says why (e.g. "marker.x cannot be separated from the frame with these poses");
  joint-model coefficients are the model's, never refitted;
* ``artifact`` - an artifact's held-out placements: their sockets are points of the new
  placement (the means of their seatings, or fitted), the probe is the model's.

**Before** = the nominal robot under the *same* protocol: ``training``, the frames and
markers fitted to the nominal robot on the training data (the "registration only" fit);
``register``, frame and marker fitted to the nominal robot on the held-out file;
``artifact``, the plain nominal robot with its nominal probe.  The joint model of the
nominal robot is none (coefficients 0).

Artifact metrics (as the literature reports them): the spread of each socket (RMS
distance of the probe tips to their mean) and the signed error of every known distance.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.identifiability import NON_GEOMETRIC_ROLES

Array = NDArray[np.float64]

__all__ = ["HeldOutFile", "evaluate_file", "map_values", "known_by_name", "BEFORE_DEFINITION",
           "PROTOCOLS", "BEFORE_BY_PROTOCOL", "before_lines"]

PROTOCOLS = ("training", "register", "artifact")

#: Same-session files are checked: re-registered on the file itself, the calibrated robot
#: misses it by ``again``; with the training frames by ``reused``.  The training frames add
#: ``sqrt(reused^2 - again^2)``; more than ``again`` itself (``reused > sqrt(2) again``)
#: contradicts the same set-up (registration's dozen parameters over hundreds of
#: coordinates take a few percent; measured on the real same-session splits: 1.06-1.17).
FRAMES_CONTRADICTED = 2.0 ** 0.5

#: One definition of "before" on held-out data, stated under every table.
BEFORE_DEFINITION = ("before = the nominal robot under the same protocol (same session: "
                     "frames and markers registered to it on the training data; re-registered: "
                     "frame and marker fitted to it on the held-out file; artifact: its "
                     "nominal probe)")

#: The same definition, one short line per protocol: the console and the report show the
#: lines of the protocols their files used (the JSON keeps :data:`BEFORE_DEFINITION`).
BEFORE_BY_PROTOCOL = {
    "training": "before (same session) = the nominal robot, the training session's frames "
                "and markers registered to it",
    "register": "before (re-registered) = the nominal robot, the file's frame and marker "
                "fitted to it",
    "artifact": "before (artifact) = the nominal robot with its nominal probe"}


def before_lines(protocols: Iterable[str]) -> list[str]:
    """The :data:`BEFORE_BY_PROTOCOL` lines of the ``protocols`` used, in
    :data:`PROTOCOLS` order, each once."""
    used = set(protocols)
    return [BEFORE_BY_PROTOCOL[p] for p in PROTOCOLS if p in used]


def _suffix(block: Any, name: str) -> str:
    return name[len(block.name) + 1:]


def _aliases(suffix: str) -> list[str]:
    """``marker.x`` and ``marker1.x`` name the same point."""
    if suffix.startswith("marker."):
        return [suffix, "marker1." + suffix[7:]]
    if suffix.startswith("marker1."):
        return [suffix, "marker." + suffix[8:]]
    return [suffix]


def map_values(h: Any, twin: Any, values: Any) -> dict[str, float]:
    """``{h's parameter name: value}`` from the training ``twin``'s parameter ``values``,
    matched by the name after the block prefix (``marker`` = ``marker1``)."""
    if twin is None or values is None:
        return {}
    return known_by_name(h, {f"{h.name}.{_suffix(twin, n)}": float(v)
                             for n, v in zip(twin.parameters().names, values, strict=True)})


@dataclass
class HeldOutFile:
    """One held-out file, evaluated.

    Attributes:
        file: the file's name; ``block``: its block.
        protocol: ``training`` / ``register`` / ``artifact``.
        note: what the protocol did with the block's parameters, in words.
        before, after: ``{kind: errors}`` of the nominal / calibrated robot.
        prediction: the calibrated model's predicted accuracy at the file's
            configurations (:class:`~kincal.identify.accuracy.Prediction`), None for
            blocks without a measured point.
        point_errors: (N,) the measured point's (marker 1's) error per configuration,
            after [m], to hold against the prediction.
        artifact: ``{"before" | "after": {"spread_m": {socket: RMS}, "distances":
            [{"placement", "label", "error_m"}]}}`` for artifact blocks.
        warning: a sentence when the training frames look wrong for this file.
    """

    file: str
    block: Any
    protocol: str
    note: str
    before: dict[str, Array]
    after: dict[str, Array]
    prediction: Any = None
    point_errors: Array | None = None
    artifact: dict[str, Any] | None = None
    warning: str = ""
    values: dict[str, Array] = field(default_factory=dict)

    def prediction_metrics(self) -> dict[str, Any] | None:
        """Predicted against measured, inside and outside the training region [m]."""
        p, e = self.prediction, self.point_errors
        if p is None or e is None or len(e) != len(p.predicted_m):
            return None
        out: dict[str, Any] = {"n": len(e), "predicted_rms_m": _rms(p.predicted_m),
                               "measured_rms_m": _rms(e),
                               "outside_joint_ranges": int(p.outside_joint_ranges.sum()),
                               "outside_hull": int(p.outside_hull.sum()),
                               "worse_than_nominal": int(np.sum(p.worse_than_nominal))}
        for mask, key in ((~p.outside, "inside"), (p.outside, "outside")):
            out[f"{key}_n"] = int(mask.sum())
            out[f"predicted_rms_{key}_m"] = _rms(p.predicted_m[mask])
            out[f"measured_rms_{key}_m"] = _rms(e[mask])
            out[f"predicted_max_{key}_m"] = float(p.predicted_m[mask].max()) if mask.any() \
                else None
            if p.nominal_predicted_m is not None:
                out[f"nominal_predicted_max_{key}_m"] = (
                    float(p.nominal_predicted_m[mask].max()) if mask.any() else None)
        return out

    def metrics(self) -> dict[str, Any]:
        from kincal.report.metrics import error_metrics

        d: dict[str, Any] = {"file": self.file, "block": self.block.name,
                             "protocol": self.protocol, "note": self.note,
                             **error_metrics(self.after), "before": error_metrics(self.before)}
        pm = self.prediction_metrics()
        if pm is not None:
            d["predicted"] = pm
        if self.artifact is not None:
            d["artifact"] = self.artifact
        if self.warning:
            d["warning"] = self.warning
        return d


def _rms(x: Array) -> float | None:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else None


def _fit(robot: Any, h: Any, known: Mapping[str, float], refit: bool) -> tuple[Array, str]:
    """``h``'s parameters with ``robot`` held: known ones as given; with ``refit`` every
    geometric block parameter the file can identify is fitted (starting from the known
    values), the others keep them; without, only the unknown ones are fitted."""
    from kincal.identify.solver import calibrate

    spec = h.parameters()
    init: dict[str, float] = {}
    free: list[str] = []
    for n, role in zip(spec.names, spec.roles, strict=True):
        if role in NON_GEOMETRIC_ROLES:
            init[n] = float(known.get(n, 0.0))      # the joint model's, never refitted
        elif n in known and not refit:
            init[n] = float(known[n])
        else:
            free.append(n)
            if n in known:
                init[n] = float(known[n])
    if not free:
        return np.array([init[n] for n in spec.names], dtype=float), ""
    res = calibrate(robot, [h], free=free, initial=init or None, tol_step=1e-12, max_iter=200)
    held = [n for n in free if n not in res.estimated]
    note = ""
    if held:
        rep = res.identifiability
        partners = sorted({_suffix(h, p) for n in held for p in rep.dependent.get(n, [])})
        why = (f"this file's poses cannot separate {'it' if len(held) == 1 else 'them'} from "
               + ", ".join(partners) if partners else "no effect on this file's measurements")
        note = (f"{', '.join(_suffix(h, n) for n in held)} kept "
                + ("the training value" if all(n in known for n in held) else "the initial guess")
                + f" ({why})")
    return res.theta[res.problem.slices[0]], note


def _artifact_metrics(h: Any, robot: Any, values: Array) -> dict[str, Any]:
    spread = h.socket_spread(robot, values)
    sites = h.sites
    lengths = h.lengths(robot, values)
    return {"spread_m": {f"{p}/{s}": float(v) for p, s, v in
                         zip(sites.placement, sites.socket, spread, strict=True)},
            "distances": [{"placement": p, "label": lab, "error_m": float(e)} for p, lab, e in
                          zip(lengths.placement, lengths.label, lengths.error, strict=True)]}


def known_by_name(h: Any, values: Mapping[str, float] | None) -> dict[str, float]:
    """``{h's parameter name: value}`` from ``{parameter name: value}`` (e.g. a result
    JSON's estimates), ``marker`` = ``marker1``."""
    if not values:
        return {}
    out = {}
    for n in h.parameters().names:
        for a in _aliases(_suffix(h, n)):
            if f"{h.name}.{a}" in values:
                out[n] = float(values[f"{h.name}.{a}"])
                break
    return out


def evaluate_file(nominal: Any, calibrated: Any, h: Any, protocol: str, *,
                  known_before: Mapping[str, float] | None = None,
                  known_after: Mapping[str, float] | None = None,
                  accuracy: Any = None) -> HeldOutFile:
    """Evaluate held-out block ``h`` under ``protocol`` (module docstring).

    Args:
        nominal, calibrated: the robots before and after (``nominal`` None: no before).
        h: the held-out block.
        protocol: ``training``, ``register`` or ``artifact``.
        known_before, known_after: ``{h's parameter name: value}`` from training (the
            training block's values fitted to the nominal robot / estimated with the
            calibrated one; :func:`map_values`, :func:`known_by_name`).
        accuracy: the calibration's :class:`~kincal.identify.accuracy.AccuracyModel`.
    """
    from kincal.measure.artifacts.model import ArtifactMeasurement
    from kincal.measure.base import BlockWrapper

    if protocol not in PROTOCOLS:
        raise KincalError(f"unknown validation protocol {protocol!r}")
    file = Path(h.source_label).name
    known_b = dict(known_before or {})
    known_a = dict(known_after or {})
    before_robot = nominal if nominal is not None else calibrated
    inner = h.inner if isinstance(h, BlockWrapper) else h
    artifact = isinstance(inner, ArtifactMeasurement)
    if artifact:
        protocol = "artifact"
        probe = [n for n, r in zip(h.parameters().names, h.parameters().roles, strict=True)
                 if r == "tool_point"]
        # before: the plain nominal robot, its nominal probe (the block's own value)
        guess = dict(zip(h.parameters().names, h.initial_guess(before_robot), strict=True))
        xb, _ = _fit(before_robot, h, {n: guess[n] for n in probe}, refit=False)
        xa, _ = _fit(calibrated, h, {n: known_a[n] for n in probe if n in known_a},
                     refit=False)
        note = ("artifact: sockets of the held-out placement(s) from their seatings; probe "
                + ("from training" if all(n in known_a for n in probe) else
                   "fitted on this file (no training probe)" if probe else "known"))
    elif protocol == "training":
        if not known_a:
            raise KincalError(f"held-out block {h.name!r} has no training block of its kind "
                              "to take frames from")
        xb, nb = _fit(before_robot, h, known_b, refit=not known_b)
        xa, na = _fit(calibrated, h, known_a, refit=False)
        missing = [_suffix(h, n) for n in h.parameters().names if n not in known_a]
        note = ("same session: frames and markers from training (no refit)" if not missing
                else f"same session: frames from training; {', '.join(missing)} fitted on "
                     "this file (not in training)")
    else:
        xb, nb = _fit(before_robot, h, known_b, refit=True)
        xa, na = _fit(calibrated, h, known_a, refit=True)
        note = "instrument re-registered on this file: frame and marker fitted"
        if na:
            note += f"; {na}"
    before = {} if nominal is None else {k: np.asarray(v, dtype=float)
                                         for k, v in h.errors(nominal, xb).items()}
    after = {k: np.asarray(v, dtype=float) for k, v in h.errors(calibrated, xa).items()}
    out = HeldOutFile(file, h, protocol, note, before, after,
                      values={"before": xb, "after": xa})
    if artifact:
        out.artifact = {"before": _artifact_metrics(inner, before_robot, xb),
                        "after": _artifact_metrics(inner, calibrated, xa)}
        if nominal is None:
            out.artifact["before"] = out.artifact["after"]
    if accuracy is not None and "position_m" in after and hasattr(h, "q"):
        from kincal.identify.accuracy import predict

        out.prediction = predict(accuracy, calibrated, h.q, nominal=nominal)
        e = after["position_m"]
        out.point_errors = np.asarray(e).reshape(len(h.q), -1)[:, 0]
    if protocol == "training":
        fresh, _ = _fit(calibrated, h, known_a, refit=True)
        e1 = after.get("position_m")
        if e1 is not None:
            e2 = np.asarray(h.errors(calibrated, fresh)["position_m"])
            reused, again = _rms(e1) or 0.0, _rms(e2) or 0.0
            if reused > FRAMES_CONTRADICTED * again and reused > 1e-5:
                extra = (reused**2 - again**2) ** 0.5
                out.warning = (f"{file}: with the training frames the held-out RMS is "
                               f"{reused * 1e3:.3g} mm, after re-registering the instrument "
                               f"{again * 1e3:.3g} mm: the training frames add more error "
                               f"({extra * 1e3:.3g} mm) than everything else together, so "
                               "the instrument or the target probably moved between the "
                               "files, which the predicted error does not allow for; check "
                               "with --validation-frames register (frames: register)")
    return out
