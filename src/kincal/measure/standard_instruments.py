"""The ``position`` and ``pose`` instruments: simulation, CSV writing and reading.

``position`` (laser tracker, motion capture, CMM): K points on the tool measured in
an unknown instrument frame, :class:`~kincal.measure.models.PositionMeasurement`.
File columns: joints, ``x y z`` (one point) or ``x1 y1 z1 ... xK yK zK``, optional
per-row ``sigma`` (or ``sigma1 ... sigmaK``) [length].

``pose`` (tracker with 6-DOF probe, CMM with a probed frame): a frame on the tool,
:class:`~kincal.measure.models.PoseMeasurement`.  Columns: joints, ``x y z`` [length],
``rx ry rz`` [angle] (roll-pitch-yaw, ``R = Rz(rz) Ry(ry) Rx(rx)``), optional
``sigma`` [length] and ``sigma_rot`` [angle].

Simulation draws joint configurations uniformly inside the limits (shrunk by a
margin), places the instrument 1.5-2.5 m from the robot base with a random
orientation and the marker / target within ~0.1 m of the tool origin, and adds
independent Gaussian noise to every measured coordinate (rotation noise as a random
rotation vector).  The observations are computed from the robot's forward
kinematics directly: ``y = R_I^T (p_e(q) + R_e(q) m - t_I)``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import MeasurementFileError
from kincal.measure.base import Provenance
from kincal.measure.files import (
    Field,
    MeasurementTable,
    read_table,
    tag_quantities,
    tag_quantity,
    write_table,
)
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.spatial import exp_so3, homogeneous, matrix_to_rpy, rpy_to_matrix

Array = NDArray[np.float64]

#: Name of the block of a position / pose file that names no instrument (``name=`` tag or
#: a setup file's ``name:``): its parameters are ``instrument.x`` ... (it may be a laser
#: tracker, a motion-capture system, a CMM: the file does not say).
UNNAMED = "instrument"

#: Default standard deviation when a file has no sigma column [m] / [rad].
DEFAULT_SIGMA = 1e-5

POSITION_FIELDS = (
    Field(r"[xyz]", "length", "x, y, z (one point)"),
    Field(r"[xyz]\d+", "length", "x1, y1, z1, x2, ... (several points)"),
    Field(r"sigma\d*", "length", "sigma or sigma1.. (standard deviation per row)"),
)
POSE_FIELDS = (
    Field(r"[xyz]", "length", "x, y, z"),
    Field(r"r[xyz]", "angle", "rx, ry, rz (roll-pitch-yaw)"),
    Field(r"sigma", "length", "sigma (position standard deviation)"),
    Field(r"sigma_rot", "angle", "sigma_rot (orientation standard deviation)"),
)


# --------------------------------------------------------------------------- simulation
def _random_instrument(rng: np.random.Generator) -> Array:
    """A plausible instrument frame ``(x, y, z, rz, ry, rx)``: 1.5-2.5 m away, any heading."""
    az = rng.uniform(-np.pi, np.pi)
    dist = rng.uniform(1.5, 2.5)
    pos = [dist * np.cos(az), dist * np.sin(az), rng.uniform(-0.2, 0.6)]
    ang = [rng.uniform(-np.pi, np.pi), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)]
    return np.array(pos + ang)


def _frame_T(v: Array) -> Array:
    """``Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` from ``(x, y, z, rz, ry, rx)``."""
    return homogeneous(rpy_to_matrix(np.asarray(v)[[5, 4, 3]]), np.asarray(v)[:3])


def _truth_values(truth: Mapping[str, float], names: Sequence[str]) -> Array:
    missing = [n for n in names if n not in truth]
    if missing:
        raise MeasurementFileError(f"instrument truth lacks {missing[0]!r}")
    return np.array([float(truth[n]) for n in names])


def simulate_position(true_robot: Any, rng: np.random.Generator, n_poses: int, noise: float,
                      markers: int = 1, name: str = "tracker", margin: float = 0.05,
                      truth: Mapping[str, float] | None = None
                      ) -> tuple[list[Any], dict[str, float]]:
    """Simulate a position instrument measuring ``markers`` points on ``true_robot``.

    ``y_ik = R_I^T (p_e(q_i) + R_e(q_i) m_k - t_I) + noise`` with ``noise ~ N(0, noise^2)``
    per coordinate [m].  ``truth`` reuses a previous placement (held-out data).

    Returns ``([PositionMeasurement], {parameter name: true value})``.
    """
    from kincal.measure.models import PositionMeasurement

    K = int(markers)
    if K < 1:
        raise MeasurementFileError("option markers must be >= 1")
    q = random_configurations(true_robot, n_poses, rng, margin)
    probe = PositionMeasurement(q[:1], np.zeros((1, K, 3)) if K > 1 else np.zeros((1, 3)),
                                name=name, markers=K)
    names = probe.parameters().names
    if truth is not None:
        values = _truth_values(truth, names)
    else:
        values = np.concatenate([_random_instrument(rng),
                                 rng.uniform(-0.08, 0.08, 3 * K) + np.tile([0, 0, 0.05], K)])
    TI = _frame_T(values[:6])
    m = values[6:].reshape(K, 3)
    T = true_robot.fk(q)
    world = T[:, None, :3, 3] + np.einsum("nij,kj->nki", T[:, :3, :3], m)
    y = (world - TI[:3, 3]) @ TI[:3, :3]
    y = y + rng.normal(0.0, noise, y.shape) if noise > 0 else y
    sigma = noise if noise > 0 else DEFAULT_SIGMA
    block = PositionMeasurement(q, y if K > 1 else y[:, 0], sigma=sigma, name=name, markers=K)
    return [block], dict(zip(names, values.tolist(), strict=True))


def simulate_pose(true_robot: Any, rng: np.random.Generator, n_poses: int, noise: float,
                  orientation_noise_deg: float = 0.005, name: str = "tracker",
                  margin: float = 0.05, truth: Mapping[str, float] | None = None
                  ) -> tuple[list[Any], dict[str, float]]:
    """Simulate a 6-DOF instrument measuring a frame on the tool of ``true_robot``.

    ``T_obs = T_I^-1 T_e(q) T_t`` perturbed by ``N(0, noise^2)`` per position coordinate
    [m] and a rotation ``exp(w)``, ``w ~ N(0, s^2)`` per component, ``s`` =
    ``orientation_noise_deg`` in radians.
    """
    from kincal.measure.models import PoseMeasurement

    q = random_configurations(true_robot, n_poses, rng, margin)
    so = np.deg2rad(float(orientation_noise_deg))
    probe = PoseMeasurement(q[:1], np.eye(4)[None], name=name)
    names = probe.parameters().names
    if truth is not None:
        values = _truth_values(truth, names)
    else:
        target = np.concatenate([rng.uniform(-0.05, 0.05, 3) + [0, 0, 0.05],
                                 rng.uniform(-0.3, 0.3, 3)])
        values = np.concatenate([_random_instrument(rng), target])
    TI, Tt = _frame_T(values[:6]), _frame_T(values[6:])
    P = np.linalg.inv(TI) @ true_robot.fk(q) @ Tt
    if noise > 0:
        P[:, :3, 3] += rng.normal(0.0, noise, (len(q), 3))
    if so > 0:
        P[:, :3, :3] = exp_so3(rng.normal(0.0, so, (len(q), 3))) @ P[:, :3, :3]
    block = PoseMeasurement(q, P, sigma_position=noise if noise > 0 else DEFAULT_SIGMA,
                            sigma_orientation=so if so > 0 else DEFAULT_SIGMA, name=name)
    return [block], dict(zip(names, values.tolist(), strict=True))


# --------------------------------------------------------------------------- files
def _one(blocks: Sequence[Any], what: str) -> Any:
    if len(blocks) != 1:
        raise MeasurementFileError(f"a {what} file holds one measurement block; got "
                                   f"{len(blocks)} (write each to its own file)")
    return blocks[0]


def _units(units: Mapping[str, str] | None) -> tuple[str, str]:
    u = dict(units or {})
    return u.get("length", "m"), u.get("angle", "rad")


def write_position(blocks: Sequence[Any], path: str | Path,
                   units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """Write one :class:`PositionMeasurement` as a ``position`` CSV (atomically).

    ``units``: ``{"length": "m"|"mm"|..., "angle": "rad"|"deg"|...}`` (default SI).
    """
    b = _one(blocks, "position")
    length, angle = _units(units)
    y = np.asarray(b.positions, dtype=float)
    y3 = y[:, None, :] if y.ndim == 2 else y
    K = y3.shape[1]
    sig = np.asarray(b.sigma, dtype=float).reshape(len(b.q), K)
    obs: list[tuple[str, Array, str]] = []
    for k in range(K):
        tag = "" if K == 1 else str(k + 1)
        obs += [(f"{c}{tag}", y3[:, k, i], "length") for i, c in enumerate("xyz")]
    if K == 1 or np.allclose(sig, sig[:, :1], rtol=1e-12, atol=0):
        obs.append(("sigma", sig[:, 0], "length"))
    else:
        obs += [(f"sigma{k + 1}", sig[:, k], "length") for k in range(K)]
    write_table(path, b.q, obs, robot, {"instrument": "position", "name": b.name},
                angle_unit=angle, length_unit=length,
                comments=[f"{len(b.q)} measurements of {K} point(s); sigma = standard "
                          "deviation of each coordinate"])


def write_pose(blocks: Sequence[Any], path: str | Path, units: Mapping[str, str] | None = None,
               robot: Any = None) -> None:
    """Write one :class:`PoseMeasurement` as a ``pose`` CSV (rpy angles), atomically."""
    b = _one(blocks, "pose")
    length, angle = _units(units)
    P = np.asarray(b.poses, dtype=float)
    rpy = matrix_to_rpy(P[:, :3, :3])
    obs = [(c, P[:, i, 3], "length") for i, c in enumerate("xyz")]
    obs += [(c, rpy[:, i], "angle") for i, c in enumerate(("rx", "ry", "rz"))]
    obs += [("sigma", np.broadcast_to(b.sigma_position, (len(P),)), "length"),
            ("sigma_rot", np.broadcast_to(b.sigma_orientation, (len(P),)), "angle")]
    write_table(path, b.q, obs, robot, {"instrument": "pose", "name": b.name},
                angle_unit=angle, length_unit=length,
                comments=["pose of the target frame in the instrument frame; rx, ry, rz "
                          "roll-pitch-yaw: R = Rz(rz) Ry(ry) Rx(rx)"])


def _tag_sigma(t: MeasurementTable, key: str) -> float:
    """The file's stated standard deviation for rows without a sigma column: tag
    ``sigma_<unit>`` (``sigma_mm=0.5``; ``sigma_rot_<angle unit>`` for orientations),
    else :data:`DEFAULT_SIGMA`."""
    dim = "angle" if key == "sigma_rot" else "length"
    value = tag_quantity(tag_quantities(t.tags, t.path), key, dim, t.path, DEFAULT_SIGMA)
    if not value > 0:
        raise t.error(f"tag {key}: a standard deviation must be positive", 1)
    return value


def _sigma_scalar(s: Array | None, default: float) -> Array | float:
    if s is None:
        return default
    return float(s[0]) if np.all(s == s[0]) else s


def _check_positive(t: MeasurementTable, base: str) -> None:
    v = t.values.get(base)
    if v is not None and np.any(v <= 0):
        i = int(np.argmax(v <= 0))
        raise t.error(f"column {t.columns[base]}: a standard deviation must be positive",
                      int(t.lines[i]))


def marker_positions(t: MeasurementTable) -> tuple[Array, Array | None]:
    """Positions (N, 3) or (N, K, 3) and sigma (N,) / (N, K) from a position table."""
    numbered = sorted({int(m.group(1)) for b in t.values
                       if (m := re.fullmatch(r"[xyz](\d+)", b))})
    single = any(b in t.values for b in ("x", "y", "z"))
    if single and numbered:
        raise t.error("both x, y, z and numbered marker columns (x1, ...): use one scheme")
    if not single and not numbered:
        raise t.error("no position columns (x, y, z or x1, y1, z1, ...)")
    if single:
        for c in "xyz":
            if c not in t.values:
                raise t.error(f"missing column {c!r} (with its unit, e.g. {c}_mm)")
        y = np.stack([t.values[c] for c in "xyz"], axis=1)
    else:
        if numbered != list(range(1, len(numbered) + 1)):
            raise t.error(f"markers must be numbered 1..K; got {numbered}")
        for k in numbered:
            for c in "xyz":
                if f"{c}{k}" not in t.values:
                    raise t.error(f"marker {k} lacks column {c}{k!s}")
        y = np.stack([np.stack([t.values[f"{c}{k}"] for c in "xyz"], axis=1)
                      for k in numbered], axis=1)
    K = 1 if single else len(numbered)
    sig_cols = sorted(b for b in t.values if re.fullmatch(r"sigma\d+", b))
    for b in sig_cols + ["sigma"]:
        _check_positive(t, b)
    if sig_cols:
        want = [f"sigma{k + 1}" for k in range(K)]
        if sig_cols != sorted(want) or "sigma" in t.values:
            raise t.error(f"per-marker sigma columns must be {', '.join(want)} (or one sigma)")
        sigma: Array | None = np.stack([t.values[w] for w in want], axis=1)
    else:
        sigma = t.values.get("sigma")
    return y, sigma


def read_position(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                  ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``position`` CSV into one :class:`PositionMeasurement` (SI units)."""
    from kincal.measure.models import PositionMeasurement

    t = read_table(path, robot, POSITION_FIELDS, units, ignore)
    y, sigma = marker_positions(t)
    K = 1 if y.ndim == 2 else y.shape[1]
    block = PositionMeasurement(t.q, y, sigma=_sigma_scalar(sigma, _tag_sigma(t, "sigma")),
                                name=name or t.tags.get("name") or UNNAMED, markers=K)
    block.provenance = Provenance(str(path), t)
    return [block]


def pose_matrices(t: MeasurementTable) -> Array:
    """(N, 4, 4) poses from the ``x y z rx ry rz`` columns of a table."""
    for c in ("x", "y", "z", "rx", "ry", "rz"):
        if c not in t.values:
            unit = "deg" if c.startswith("r") else "mm"
            raise t.error(f"missing column {c!r} (with its unit, e.g. {c}_{unit})")
    rpy = np.stack([t.values[c] for c in ("rx", "ry", "rz")], axis=1)
    p = np.stack([t.values[c] for c in "xyz"], axis=1)
    return homogeneous(rpy_to_matrix(rpy), p)


def read_pose(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
              ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``pose`` CSV into one :class:`PoseMeasurement` (SI units)."""
    from kincal.measure.models import PoseMeasurement

    t = read_table(path, robot, POSE_FIELDS, units, ignore)
    P = pose_matrices(t)
    for b in ("sigma", "sigma_rot"):
        _check_positive(t, b)
    block = PoseMeasurement(t.q, P, sigma_position=_sigma_scalar(t.values.get("sigma"),
                                                                 _tag_sigma(t, "sigma")),
                            sigma_orientation=_sigma_scalar(t.values.get("sigma_rot"),
                                                            _tag_sigma(t, "sigma_rot")),
                            name=name or t.tags.get("name") or UNNAMED)
    block.provenance = Provenance(str(path), t)
    return [block]


#: Simulation options every tracker-like instrument takes.
_COMMON_OPTIONS: dict[str, tuple[object, str]] = {
    "name": ("tracker", "block name (prefix of the instrument's parameters)"),
    "margin": (0.05, "fraction of each joint range kept away from the limits"),
}

POSITION = register(Instrument(
    name="position",
    description="points on the tool in an instrument frame (laser tracker, motion capture)",
    simulate=simulate_position, write=write_position, read=read_position,
    options={"markers": (1, "number of points measured on the tool per pose"),
             **_COMMON_OPTIONS},
    noise_unit="m"))

POSE = register(Instrument(
    name="pose",
    description="full pose of a frame on the tool in an instrument frame (6-DOF tracker)",
    simulate=simulate_pose, write=write_pose, read=read_pose,
    options={"orientation_noise_deg": (0.005, "orientation noise (deg, per axis)"),
             **_COMMON_OPTIONS},
    noise_unit="m"))
