"""Denavit-Hartenberg front ends: standard DH, modified DH (Craig), Hayati.

Each compiles to the elementary-transform chain of :mod:`kincal.robots.chain`,
between a base frame and a tool frame (6 parameters each):

* standard DH, link i:  ``Rz(theta_offset[i] + q_i) Tz(d[i]) Tx(a[i]) Rx(alpha[i])``
  (prismatic: ``Rz(theta_offset[i]) Tz(d[i] + q_i) Tx(a[i]) Rx(alpha[i])``);
* Hayati, for a link whose axis is nearly parallel to the next one:
  ``... Rx(alpha[i]) Ry(beta[i])`` (the extra twist about the new y axis);
* modified DH (Craig), link i: ``Rx(alpha[i]) Tx(a[i]) Rz(theta_offset[i] + q_i) Tz(d[i])``
  where ``alpha[i], a[i]`` are Craig's ``alpha_{i-1}, a_{i-1}``.

Parameter names are 1-based (``d[1]`` is the first link's offset).  Lengths in
metres, angles in radians.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.robots.chain import ChainBuilder, Robot
from kincal.spatial import frame_from_matrix, matrix_from_frame, rotx

Convention = Literal["standard", "modified"]


@dataclass(frozen=True)
class DHLink:
    """One row of a DH table [m, rad].

    Attributes:
        a, d, alpha, theta_offset: the DH values (for modified DH, ``a`` and ``alpha``
            are Craig's ``a_{i-1}``, ``alpha_{i-1}``).
        joint: ``"revolute"`` or ``"prismatic"``.
        beta: Hayati's extra twist about y (standard DH only), or None.
        name: the joint's name (defaults to ``q{i}``).
        lower, upper: joint limits [rad or m].
    """

    a: float = 0.0
    d: float = 0.0
    alpha: float = 0.0
    theta_offset: float = 0.0
    joint: Literal["revolute", "prismatic"] = "revolute"
    beta: float | None = None
    name: str | None = None
    lower: float = -np.inf
    upper: float = np.inf


def from_dh(links: Sequence[DHLink], convention: Convention = "standard", name: str = "robot",
            base: Sequence[float] | NDArray[np.float64] = (0, 0, 0, 0, 0, 0),
            tool: Sequence[float] | NDArray[np.float64] = (0, 0, 0, 0, 0, 0),
            meta: Mapping[str, Any] | None = None) -> Robot:
    """Compile a DH table to a :class:`Robot`.

    Args:
        links: the table, base to tip.
        convention: ``"standard"`` (with optional Hayati ``beta``) or ``"modified"``.
        base, tool: ``(x, y, z, rz, ry, rx)`` [m, rad] of the base frame (world ->
            frame 0) and the tool frame (last frame -> tool),
            ``Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` (:data:`kincal.spatial.FRAME_FIELDS`).
        meta: stored on the robot (``source``, ``description`` ...).
    """
    if convention not in ("standard", "modified"):
        raise KincalError(f"unknown DH convention {convention!r}; use 'standard' or 'modified'")
    b = ChainBuilder(name)
    b.frame("base", base)
    for i, L in enumerate(links, start=1):
        jn = L.name or f"q{i}"
        j = b.joint(jn, L.joint, L.lower, L.upper)
        rev = L.joint == "revolute"
        if convention == "modified":
            if L.beta is not None:
                raise KincalError(f"link {i}: Hayati's beta is defined for standard DH only")
            b.transform("Rx", f"alpha[{i}]", L.alpha, role="angle")
            b.transform("Tx", f"a[{i}]", L.a, role="length")
        b.transform("Rz", f"theta_offset[{i}]", L.theta_offset, role="offset" if rev else "angle",
                    joint=j if rev else -1)
        b.transform("Tz", f"d[{i}]", L.d, role="length" if rev else "offset",
                    joint=-1 if rev else j)
        if convention == "standard":
            b.transform("Tx", f"a[{i}]", L.a, role="length")
            b.transform("Rx", f"alpha[{i}]", L.alpha, role="angle")
            if L.beta is not None:
                b.transform("Ry", f"beta[{i}]", L.beta, role="angle")
    b.frame("tool", tool)
    m = {"convention": "standard_dh" if convention == "standard" else "modified_dh"}
    if any(L.beta is not None for L in links):
        m["convention"] = "hayati"
    m.update(meta or {})
    return b.build(meta=m)


def dh_links(robot: Robot) -> list[DHLink]:
    """Read the current DH table back from a robot built by :func:`from_dh`."""
    conv = robot.meta.get("convention")
    if conv not in ("standard_dh", "modified_dh", "hayati"):
        raise KincalError(f"robot {robot.name!r} is not a DH robot (convention {conv!r})")
    v = robot.params()
    out = []
    for i, jt in enumerate(robot.joints, start=1):
        beta = v.get(f"beta[{i}]")
        out.append(DHLink(a=v[f"a[{i}]"], d=v[f"d[{i}]"], alpha=v[f"alpha[{i}]"],
                          theta_offset=v[f"theta_offset[{i}]"], joint=jt.kind, beta=beta,
                          name=jt.name, lower=jt.lower, upper=jt.upper))
    return out


def standard_to_modified(robot: Robot) -> Robot:
    """Rewrite a standard-DH robot in modified DH with identical forward kinematics.

    ``prod_i Rz(th_i) Tz(d_i) Tx(a_i) Rx(al_i)`` regroups as
    ``Rz(th_1) Tz(d_1) prod_{i>1} [Rx(al_{i-1}) Tx(a_{i-1}) Rz(th_i) Tz(d_i)] Tx(a_n) Rx(al_n)``
    (Tx and Rx about the same axis commute); the trailing ``Tx(a_n) Rx(al_n)`` moves
    into the tool frame.  Hayati links have no modified-DH equivalent.
    """
    if robot.meta.get("convention") != "standard_dh":
        raise KincalError(f"robot {robot.name!r} is not in standard DH "
                          f"(convention {robot.meta.get('convention')!r})")
    std = dh_links(robot)
    mod = []
    for i, L in enumerate(std):
        prev_a, prev_alpha = (std[i - 1].a, std[i - 1].alpha) if i else (0.0, 0.0)
        mod.append(DHLink(a=prev_a, d=L.d, alpha=prev_alpha, theta_offset=L.theta_offset,
                          joint=L.joint, name=L.name, lower=L.lower, upper=L.upper))
    last = np.eye(4)
    last[:3, :3] = rotx(std[-1].alpha)
    last[0, 3] = std[-1].a
    tool = frame_from_matrix(last @ matrix_from_frame(robot.frame_parameters("tool")))
    meta = dict(robot.meta)
    meta["convention"] = "modified_dh"
    return from_dh(mod, "modified", robot.name, robot.frame_parameters("base"), tool, meta)
