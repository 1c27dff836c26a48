"""Known fixtures: the tool point is placed on pre-calibrated points of the workspace.

A fixture plate (or a set of cones / nests) whose points ``f_j`` [m] are known in the
world frame (measured once, e.g. on a CMM).  Row ``i`` says the tool point sits on
``f_i`` at joint readings ``q_i``::

    e_i = p(q_i) - f_i = 0 (3 components)          residuals e_i / sigma_i

``de/dp = I``.  The only block parameters are the marker ``{name}.marker.x, y, z``
(``marker="own"``; none with ``marker="tool"``).  No instrument frame: the fixture *is*
the world reference, so unlike a tracker the robot's base frame is seen directly.

What fixtures cannot see: only the tool point (not the tool orientation); with the same
fixture point approached in one orientation the marker and the last links trade off --
approach each point in several orientations.

File columns: ``x, y, z, sigma`` per contact (the fixture point, world frame).
Simulator: :func:`simulate_fixture` (contacts solved on the true robot).
The module registers the ``fixture`` instrument (:mod:`kincal.measure.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.base import ParamSpec
from kincal.measure.files import Field
from kincal.measure.instruments.common import MARKER_MODES
from kincal.measure.instruments.csvio import (
    block_name,
    block_tags,
    build_block,
    one_block,
    read_block_table,
    stack_columns,
    write_block_table,
)
from kincal.measure.instruments.placement import (
    POINT_OPTIONS,
    marker_truth,
    solve_contacts,
    stated_sigma,
    tool_points,
    truth_values,
)
from kincal.measure.instruments.pointblock import PointBlock
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot

Array = NDArray[np.float64]


class FixtureMeasurement(PointBlock):
    """The tool point on known fixture points.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        points: (N, 3) the fixture point of each row in the world frame [m].
        sigma: standard deviation of each coordinate [m] (placement repeatability plus the
            fixture's own uncertainty), scalar or (N,).
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    def __init__(self, name: str, q: ArrayLike, points: ArrayLike, sigma: ArrayLike,
                 marker: str = "own") -> None:
        self._init_rows("fixture", name, q, points, 3, "points", sigma, marker)

    def own_parameters(self) -> ParamSpec:
        return ParamSpec.empty()

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        if not jacobian:
            return p, None, None
        N = p.shape[0]
        return p, np.broadcast_to(np.eye(3), (N, 3, 3)), np.zeros((N, 3, 0))

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 3)
        return {"position_m": np.linalg.norm(r, axis=1) * self.sigma}


# ---------------------------------------------------------------------------- file columns
FIXTURE_FIELDS = (*(Field(c, "length", f"{c} (fixture point, world frame)") for c in "xyz"),
                  Field("sigma", "length", "sigma (standard deviation per coordinate)"))


def write_fixture(blocks: Sequence[Any], path: str | Path,
                  units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """``x, y, z, sigma`` per contact: the fixture point in the world frame."""
    b: FixtureMeasurement = one_block(blocks, "fixture")
    cols = [(c, b.obs[:, i], "length") for i, c in enumerate("xyz")]
    cols.append(("sigma", b.sigma, "length"))
    write_block_table(path, block_tags("fixture", b, marker=b.marker), b.q, cols, units, robot,
                      ["x, y, z = the known fixture point the tool point sits on (world)"])


def read_fixture(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                 ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``fixture`` CSV into one block (SI units); a bad file raises one line
    naming the file and the line (:class:`~kincal.errors.MeasurementFileError`)."""
    tab = read_block_table(path, robot, "fixture", FIXTURE_FIELDS, ("x", "y", "z", "sigma"),
                           {}, units, ignore)
    marker = tab.option("marker", "own", MARKER_MODES)
    return [build_block(tab, lambda: FixtureMeasurement(
        block_name(tab, name, "fixture"), tab.q, stack_columns(tab.values, "xyz"),
        tab.values["sigma"], marker))]


# ---------------------------------------------------------------------------- simulation
def simulate_fixture(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                     points: int = 8, marker: str = "own", name: str = "fixture",
                     margin: float = 0.05, truth: Mapping[str, float] | None = None
                     ) -> tuple[list[Any], dict[str, float]]:
    """The tool marker placed on ``points`` known fixture points, ``n_poses`` contacts.

    Each point is approached in several orientations; the placement error is
    N(0, noise^2) per coordinate [m].  Fixture points are drawn inside the reachable
    workspace; their world coordinates are exact (pre-calibrated).
    """
    F = int(points)
    if F < 1:
        raise MeasurementFileError("option points must be >= 1")
    probe = FixtureMeasurement(name, np.zeros((1, true_robot.n)), np.zeros((1, 3)), 1.0,
                               marker)
    names = probe.parameters().names
    mt = marker_truth(rng)
    if truth is not None:
        values = truth_values(truth, names)
    else:
        values = mt if marker == "own" else np.zeros(0)
    m = values if marker == "own" else None
    anchors = random_configurations(true_robot, F, rng, 0.2)
    fix = tool_points(true_robot, anchors, m)
    which = np.arange(4 * n_poses) % F
    q0 = anchors[which] + rng.normal(0.0, 0.6, (len(which), true_robot.n))
    eps = rng.normal(0.0, noise, (len(which), 3)) if noise > 0 else np.zeros((len(which), 3))
    A = np.broadcast_to(np.eye(3), (len(which), 3, 3))
    q, ok = solve_contacts(true_robot, q0, m, A, fix[which] + eps)
    keep = np.flatnonzero(ok)[:n_poses]
    if len(keep) < n_poses:
        raise KincalError(f"only {len(keep)} of {n_poses} fixture contacts are reachable")
    block = FixtureMeasurement(name, q[keep], fix[which[keep]], stated_sigma(noise, "m"),
                               marker)
    return [block], dict(zip(names, values.tolist(), strict=True))


register(Instrument(
    name="fixture",
    description="the tool point on pre-calibrated fixture points of the workspace",
    simulate=simulate_fixture, write=write_fixture, read=read_fixture,
    options={"points": (8, "number of fixture points"),
             "name": ("fixture", "block name (prefix of its parameters)"), **POINT_OPTIONS},
    noise_unit="m"))
