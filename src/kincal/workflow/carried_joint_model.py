"""The calibrated joint model, carried in the calibrated robot file.

A calibration with ``--joint-model hysteresis,compliance`` estimates, beside the
geometry, one coefficient per joint and term (``{block}.h[<joint>]`` [rad / m],
``{block}.k[<joint>]`` [rad / (N m)]): the link sits at

    q_eff = q + h (.) d + k (.) tau

(:mod:`kincal.measure.joints.deflection`).  Without those coefficients the geometry alone
is a different model, and a held-out error computed from it is not the number the
calibration reported.  The calibrated robot file therefore carries a ``joint_model:``
section beside its ``calibration:`` envelope::

    joint_model:
      terms: [hysteresis]
      coefficients:                 # per training block (file), by block name
        tracker: {"h[j1]": -2.1e-4, "h[j2]": 1.3e-4, ...}
      masses:                       # compliance only: the link masses the loads came from
        - {joint: 1, mass: 8.4, com: [0.1, 0, 0.02], name: upper_arm}
      loads_from: {a[2]: 1.2e-3, ...}   # compliance only: nominal - calibrated, the
                                        # geometry the loads were computed with

``kincal validate`` (and any command that evaluates measurements with that robot)
wraps every block in the same terms (:func:`wrap_carried`) and holds the coefficients
of the training block with the same name (else of the only training block) at their
calibrated values (:func:`carried_values`), so the same model gives the same number in
``calibrate --validate`` and ``validate``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from kincal.errors import KincalError

__all__ = ["joint_model_document", "with_joint_model_document", "carried_terms",
           "wrap_carried", "carried_values", "link_side"]


def _terms_of(block: Any) -> tuple[list[str], Any]:
    """The joint-model terms around ``block`` (wrapping order) and the masses of its
    compliance term (None without one)."""
    from kincal.measure.joints.compliance import JointCompliance
    from kincal.measure.joints.deflection import JointDeflection
    from kincal.measure.joints.hysteresis import JointHysteresis

    terms: list[str] = []
    masses = None
    b = block
    while isinstance(b, JointDeflection):
        if isinstance(b, JointCompliance):
            terms.append("compliance")
            masses = getattr(b, "masses", None)
        elif isinstance(b, JointHysteresis):
            terms.append("hysteresis")
        b = b.inner
    return terms[::-1], masses


def joint_model_document(train: Sequence[Any], values: Mapping[str, Any],
                         nominal: Any = None, calibrated: Any = None
                         ) -> dict[str, Any] | None:
    """The ``joint_model:`` section of the calibrated robot file (module docstring), from
    the training blocks and their estimated parameter vectors ``{block name: values}``;
    None when the blocks carry no joint model.  With compliance, ``nominal`` (the robot
    the calibration started from, whose geometry the gravity loads were computed with)
    is written as ``loads_from: {parameter: nominal - calibrated}`` (the parameters that
    moved), so a reader computes the loads at the same geometry."""
    from kincal.identify.identifiability import NON_GEOMETRIC_ROLES

    terms: list[str] = []
    masses = None
    coefficients: dict[str, dict[str, float]] = {}
    for b in train:
        t, m = _terms_of(b)
        if not t or b.name not in values:
            continue
        terms = terms or t
        masses = masses if masses is not None else m
        spec = b.parameters()
        coefficients[b.name] = {
            n[len(b.name) + 1:]: float(v)
            for n, v, r in zip(spec.names, np.asarray(values[b.name], dtype=float),
                               spec.roles, strict=True) if r in NON_GEOMETRIC_ROLES}
    if not terms:
        return None
    doc: dict[str, Any] = {"terms": list(terms), "coefficients": coefficients}
    if masses:
        doc["masses"] = [{"joint": int(p.joint), "mass": float(p.mass),
                          "com": [float(c) for c in p.com], "name": str(p.name)}
                         for p in masses]
        if nominal is not None and calibrated is not None:
            cal = dict(zip(calibrated.param_names, calibrated.param_values, strict=True))
            doc["loads_from"] = {str(n): float(v - cal[n]) for n, v in
                                 zip(nominal.param_names, nominal.param_values, strict=True)
                                 if n in cal and v != cal[n]}
    return doc


def with_joint_model_document(robot: Any, doc: Mapping[str, Any] | None) -> Any:
    """``robot`` carrying ``doc`` as ``meta["joint_model"]`` (None: without one)."""
    import dataclasses

    meta = {k: v for k, v in dict(robot.meta).items() if k != "joint_model"}
    if doc is not None:
        meta["joint_model"] = dict(doc)
    return dataclasses.replace(robot, meta=meta)


def _section(robot: Any) -> Mapping[str, Any] | None:
    sec = getattr(robot, "meta", {}).get("joint_model")
    if sec is None:
        return None
    where = str(getattr(robot, "meta", {}).get("file", robot.name))
    if not isinstance(sec, Mapping) or not isinstance(sec.get("coefficients"), Mapping):
        raise KincalError(f"robot {where}: 'joint_model' needs 'terms' and 'coefficients'")
    return sec


def carried_terms(robot: Any) -> tuple[str, ...]:
    """The joint-model terms ``robot``'s file carries (empty: geometry only)."""
    from kincal.measure.joints.terms import parse_joint_model

    sec = _section(robot)
    if sec is None:
        return ()
    terms = sec.get("terms")
    if not isinstance(terms, list | tuple) or not terms:
        raise KincalError(f"robot {robot.name}: 'joint_model.terms' must be a list "
                          "(hysteresis, compliance)")
    return parse_joint_model(",".join(str(t) for t in terms))


def _masses(robot: Any) -> list[Any] | None:
    from kincal.robots.gravity import PointMass

    sec = _section(robot) or {}
    rows = sec.get("masses")
    if not rows:
        return None
    try:
        return [PointMass(int(m["joint"]), float(m["mass"]),
                          (float(m["com"][0]), float(m["com"][1]), float(m["com"][2])),
                          str(m.get("name", ""))) for m in rows]
    except (KeyError, TypeError, ValueError, IndexError):
        raise KincalError(f"robot {robot.name}: 'joint_model.masses' rows need joint, mass "
                          "and com [x, y, z]") from None


def wrap_carried(blocks: Sequence[Any], robot: Any,
                 masses: Sequence[Any] | None = None) -> list[Any]:
    """``blocks`` inside the joint model ``robot`` carries (unchanged without one);
    ``masses`` for compliance when the file has none (e.g. a URDF's)."""
    from kincal.measure.joints.terms import with_joint_model

    terms = carried_terms(robot)
    if not terms:
        return list(blocks)
    loads = (_section(robot) or {}).get("loads_from")
    at = robot
    if isinstance(loads, Mapping) and "compliance" in terms:
        now = dict(zip(robot.param_names, robot.param_values, strict=True))
        at = robot.with_params({str(k): now[str(k)] + float(v) for k, v in loads.items()
                                if str(k) in now})   # the calibration's loads: its geometry
    return with_joint_model(blocks, at, terms, _masses(robot) or masses)


def carried_values(block: Any, robot: Any) -> dict[str, float]:
    """``{block parameter name: value}`` of the joint-model coefficients ``robot``
    carries for ``block``: those of the training block with its name, else of the only
    training block ({} when the file has none for it)."""
    sec = _section(robot)
    if sec is None:
        return {}
    coef = sec["coefficients"]
    table = coef.get(block.name)
    if table is None and len(coef) == 1:
        table = next(iter(coef.values()))
    if not isinstance(table, Mapping):
        return {}
    names = set(block.parameters().names)
    return {f"{block.name}.{k}": float(v) for k, v in table.items()
            if f"{block.name}.{k}" in names}


def link_side(block: Any, robot: Any, values: Any) -> tuple[Any, Any]:
    """The measurement block inside ``block``'s joint model, read at the link-side joint
    values ``q + sum_terms c (.) u`` (with the coefficients in ``values``, ``block``'s
    parameter vector), and that block's own parameters (the prefix of ``values``).

    For figures computed from a plain block (ISO 9283): the joint model moves the joints,
    the block then measures as usual.  A block without a joint model is returned as is.
    """
    import copy

    from kincal.measure.joints.deflection import JointDeflection

    e = np.asarray(values, dtype=float).reshape(-1)
    b = block
    delta = np.zeros_like(np.asarray(block.q, dtype=float))
    while isinstance(b, JointDeflection):
        delta += b.effective_q(robot, e) - b.q
        e = e[: e.size - len(b.joints)]
        b = b.inner
    if b is block:
        return block, e
    inner = copy.copy(b)               # a copy: the block read from the file is unchanged
    inner.q = np.asarray(b.q, dtype=float) + delta
    return inner, e
