"""The non-geometric joint model of a calibration: ``--joint-model hysteresis,compliance``.

A geometric calibration assumes the link sits where its encoder says.  Two terms
describe how it does not (:mod:`kincal.measure.joints.deflection`):

* ``hysteresis`` (:class:`~kincal.measure.joints.hysteresis.JointHysteresis`): the link lags
  its encoder by ``h_j`` [rad / m] in the direction the joint last moved in (play held
  by friction).  The directions come from the order of the rows of each measurement
  file, which must be the order the postures were measured in;
* ``compliance`` (:class:`~kincal.measure.joints.compliance.JointCompliance`): the joint
  yields by ``k_j tau_j`` under its static gravity load ``tau_j`` [N m / N], computed
  from the link masses (a URDF's ``<inertial>`` elements).

:func:`with_joint_model` wraps every measurement block (training and held-out alike,
each with its own rows' directions and loads); the coefficients are block parameters
(``{block}.h[<joint>]``, ``{block}.k[<joint>]``), selected and estimated like the
instrument frame, listed in the parameter table and the result JSON.  The calibrated
robot file carries the terms and coefficients beside the geometry
(:mod:`kincal.workflow.carried_joint_model`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from kincal.errors import KincalError

__all__ = ["JOINT_MODEL_TERMS", "parse_joint_model", "with_joint_model"]

#: The terms ``--joint-model`` accepts, in the order they wrap a block (inside first).
JOINT_MODEL_TERMS = ("hysteresis", "compliance")


def parse_joint_model(text: str | None) -> tuple[str, ...]:
    """``--joint-model`` text (comma-separated terms) -> the terms, in wrapping order."""
    if not text:
        return ()
    terms = [t.strip() for t in text.split(",") if t.strip()]
    for t in terms:
        if t not in JOINT_MODEL_TERMS:
            raise KincalError(f"option --joint-model: unknown term {t!r} (known: "
                              f"{', '.join(JOINT_MODEL_TERMS)})")
    if len(set(terms)) != len(terms):
        raise KincalError(f"option --joint-model: a term is listed twice in {text!r}")
    return tuple(t for t in JOINT_MODEL_TERMS if t in terms)


def with_joint_model(blocks: Sequence[Any], robot: Any, terms: Sequence[str],
                     masses: Sequence[Any] | None = None) -> list[Any]:
    """Every block inside the joint model ``terms`` (:func:`parse_joint_model`).

    Args:
        blocks: measurement blocks read from files (rows in the order measured).
        robot: the robot they measure.
        terms: ``"hysteresis"`` and / or ``"compliance"``.
        masses: :class:`~kincal.robots.gravity.PointMass` list for ``compliance`` (e.g.
            :func:`kincal.robots.urdf.load_urdf_inertials`).

    The wrapped blocks share the provenance of the blocks they wrap
    (:class:`~kincal.measure.base.BlockWrapper`), so reports and held-out protocols
    treat them as the files' blocks.
    """
    from kincal.measure.joints.compliance import JointCompliance
    from kincal.measure.joints.hysteresis import JointHysteresis

    if "compliance" in terms and not masses:
        raise KincalError("--joint-model compliance needs the link masses: give the robot "
                          "as a URDF file with <inertial> elements")
    out = []
    for b in blocks:
        w = b
        if "hysteresis" in terms:
            w = JointHysteresis(w, robot)
        if "compliance" in terms:
            w = JointCompliance.gravity(w, robot, list(masses or ()))
        out.append(w)
    return out
