"""Two files, one tool: ``--shared-marker``.

Several measurement files may see the same physical point on the tool: the same
reflector measured by a tracker from two placements, the same ball seated in an
artifact moved to another place.  Each file's block has its own copy of that point
(``{block}.marker.x ...``, ``{block}.probe.x ...``) unless they share it.

:func:`share_tool_point` makes the point part of the robot: the robot's tool frame is
moved onto it (``tool.x/y/z`` += ``R_tool m0``, ``m0`` the first file's closed-form guess
of the point, or the probe given in its file), and every block measures the tool
origin itself:

* a position block (one marker) inside :class:`ToolPointBlock`, its marker parameters
  held at 0 (the block's evaluation with the marker columns removed);
* an artifact block with the probe ``tool`` (:class:`~kincal.measure.artifacts.probe.Probe`).

The shared point is then ``tool.x``, ``tool.y``, ``tool.z``: one set of parameters,
estimated with the robot (no tolerance, no prior: a tool is whatever was mounted; kept
before the last link's lengths and offset that it could also be told as, which carry
the manufacturing prior: ``calibrate(prefer=...)``), and written into the calibrated
robot file as its tool frame.  Held-out files of the same
tool are wrapped the same way, so they use it too.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import CHUNK_ROWS, BlockWrapper, ParamSpec
from kincal.robots.workspace import ChainWorkspace

Array = NDArray[np.float64]

__all__ = ["ToolPointBlock", "share_tool_point"]


class ToolPointBlock(BlockWrapper):
    """A position block whose marker is the robot's tool origin (marker held at 0).

    Parameters: the inner block's without its marker (``{name}.marker.*``); residuals,
    Jacobians and errors are the inner block's at marker 0.
    """

    inner: Any          # a position block (its ``subset`` and ``{name}.marker.*``)

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name = inner.name
        self.q = inner.q
        spec = inner.parameters()
        self._keep = np.array([not n.startswith(f"{inner.name}.marker")
                               for n in spec.names], dtype=bool)

    @property
    def N(self) -> int:
        return int(self.inner.q.shape[0])

    def _full(self, extra: ArrayLike) -> Array:
        full = np.zeros(len(self._keep))
        full[self._keep] = np.asarray(extra, dtype=float).reshape(-1)
        return full

    def parameters(self) -> ParamSpec:
        s = self.inner.parameters()
        k = self._keep
        return ParamSpec(tuple(n for n, ok in zip(s.names, k, strict=True) if ok),
                         s.values[k], tuple(u for u, ok in zip(s.units, k, strict=True) if ok),
                         tuple(r for r, ok in zip(s.roles, k, strict=True) if ok))

    def initial_guess(self, robot: Any) -> Array:
        guess: Array = np.asarray(self.inner.initial_guess(robot), dtype=float)[self._keep]
        return guess

    def evaluate(self, robot: Any, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        r, Jr, Je = self.inner.evaluate(robot, self._full(extra), jacobian)
        return r, Jr, None if Je is None else Je[:, self._keep]

    def evaluate_chunks(self, robot: Any, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        for sl, r, Jr, Je in self.inner.evaluate_chunks(robot, self._full(extra), rows):
            yield sl, r, Jr, Je[:, self._keep]

    def system_pieces(self, robot: Any, extra: Array, robot_columns: NDArray[np.intp],
                      own_columns: NDArray[np.intp], rows: int = CHUNK_ROWS, *,
                      robot_out: Callable[[int], Array | None] | None = None,
                      workspace: ChainWorkspace | None = None
                      ) -> Iterator[tuple[slice, NDArray[np.intp] | None, Array, Array, Array]]:
        """The inner block's pieces (its fast path), own columns mapped past the marker."""
        own = np.flatnonzero(self._keep)[np.asarray(own_columns, dtype=np.intp)]
        yield from self.inner.system_pieces(robot, self._full(extra), robot_columns, own, rows,
                                            robot_out=robot_out, workspace=workspace)

    def residuals_into(self, robot: Any, extra: Array, out: Array, *,
                       workspace: ChainWorkspace | None = None) -> None:
        self.inner.residuals_into(robot, self._full(extra), out, workspace=workspace)

    def residual_owner(self) -> NDArray[np.intp]:
        owner: NDArray[np.intp] = self.inner.residual_owner()
        return owner

    def num_residuals(self) -> int:
        return int(self.inner.num_residuals())

    def errors(self, robot: Any, extra: Array) -> dict[str, Array]:
        errors: dict[str, Array] = self.inner.errors(robot, self._full(extra))
        return errors

    def subset(self, rows: ArrayLike) -> ToolPointBlock:
        return ToolPointBlock(self.inner.subset(rows))

    def with_q(self, q: ArrayLike) -> ToolPointBlock:
        inner = copy.copy(self.inner)
        inner.q = np.asarray(q, dtype=float)
        return ToolPointBlock(inner)


def _point_guess(block: Any, robot: Any) -> Array:
    """The tool point ``block`` sees, in the flange frame: its marker's closed-form guess,
    or its probe's given value."""
    from kincal.measure.artifacts.model import ArtifactMeasurement
    from kincal.measure.instruments.position import PositionMeasurement
    from kincal.measure.joints.deflection import JointDeflection

    if isinstance(block, JointDeflection):
        return _point_guess(block.inner, robot)
    if isinstance(block, ArtifactMeasurement):
        p = block.probe
        if p.mode == "vector":
            return np.asarray(p.value, dtype=float)
        if p.mode == "length":
            return np.array([0.0, 0.0, p.value[0]])
        return np.zeros(3)
    if isinstance(block, PositionMeasurement):
        if block.K != 1:
            raise KincalError(f"--shared-marker: block {block.name!r} has {block.K} markers; "
                              "a shared tool point needs one marker per file")
        return np.asarray(block.initial_guess(robot), dtype=float)[6:9]
    raise KincalError(f"--shared-marker: block {block.name!r} ({type(block).__name__}) has no "
                      "marker or probe to share (position and artifact files)")


def _shared(block: Any) -> Any:
    from kincal.measure.artifacts.model import ArtifactMeasurement
    from kincal.measure.artifacts.probe import Probe
    from kincal.measure.joints.deflection import JointDeflection

    if isinstance(block, JointDeflection):        # the joint model stays around it
        out = copy.copy(block)
        out.inner = _shared(block.inner)
        out._checked = False
        return out
    if isinstance(block, ArtifactMeasurement):
        return block.replace(probe=Probe("tool"))     # keeps the block's provenance
    return ToolPointBlock(block)


def share_tool_point(robot: Any, blocks: Sequence[Any], holdouts: Sequence[Any] = ()
                     ) -> tuple[Any, list[Any], list[Any], str]:
    """The robot with its tool frame on the shared point, the blocks measuring it, and a
    sentence saying what was done (module docstring).

    Raises a one-line error for a block with several markers or without a tool point.
    """
    from kincal.spatial import rpy_to_matrix

    if not blocks:
        raise KincalError("--shared-marker: no training files")
    m0 = _point_guess(blocks[0], robot)
    for b in [*blocks[1:], *holdouts]:
        _point_guess(b, robot)                               # checks every file
    p = robot.params()
    rpy = np.array([p.get("tool.rx", 0.0), p.get("tool.ry", 0.0), p.get("tool.rz", 0.0)])
    R = rpy_to_matrix(rpy)
    t = np.array([p.get(f"tool.{c}", 0.0) for c in "xyz"]) + R @ m0
    moved = robot.with_params({f"tool.{c}": float(v) for c, v in zip("xyz", t, strict=True)})
    names = ", ".join(b.name for b in blocks)
    note = (f"shared tool point: the files {names} see one point, the robot's tool origin "
            f"(tool.x/y/z, starting {m0[0] * 1e3:.2f}, {m0[1] * 1e3:.2f}, {m0[2] * 1e3:.2f} "
            "mm from the flange), instead of one marker or probe each")
    return moved, [_shared(b) for b in blocks], [_shared(h) for h in holdouts], note
