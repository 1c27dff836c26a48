"""The base class of the point instruments and the block-only Gauss-Newton refinement.

:class:`PointBlock` turns "observations as functions of the tool point" into the
:class:`~kincal.measure.base.MeasurementModel` contract: it adds the marker parameters
(``marker="own"``), evaluates the tool point and chains the Jacobians::

    r = (obs(p(q; robot, m), own) - obs_measured) / sigma
    dr/d(robot) = (d obs/dp)(dp/d(robot)) / sigma,   dr/dm = (d obs/dp) R_e / sigma
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.measure.base import MeasurementModel, ParamSpec
from kincal.measure.instruments.common import (
    as_q,
    as_sigma,
    chain_rows,
    check_marker_mode,
    check_shapes,
    concat_specs,
    label_index,
    marker_spec,
    tool_point,
)
from kincal.robots.chain import Robot

Array = NDArray[np.float64]


def refine_block(model: MeasurementModel, robot: Robot, x0: Array, iterations: int = 30
                 ) -> Array:
    """Gauss-Newton on the block's own parameters with the robot held fixed.

    Minimum-norm steps (so parameters the block alone cannot see stay where they are),
    halved until the cost drops.  Used by ``initial_guess`` after a closed form.
    """
    x = np.asarray(x0, dtype=float).copy()
    r, _, J = model.evaluate(robot, x)
    cost = float(r @ r)
    for _ in range(iterations):
        step = np.linalg.lstsq(J, -r, rcond=1e-10)[0]
        for _ in range(30):
            cand = x + step
            rc = model.evaluate(robot, cand, jacobian=False)[0]
            cc = float(rc @ rc)
            if np.isfinite(cc) and cc <= cost:
                break
            step = step / 2
        else:
            break
        done = cost - cc <= 1e-12 * max(cost, 1e-300)
        x, cost = cand, cc
        if done:
            break
        r, _, J = model.evaluate(robot, x)
    return x



class PointBlock(MeasurementModel):
    """A block whose observations are functions of the tool point ``p(q)`` only.

    Subclasses set ``name``, ``q`` (N, n), ``sigma`` (N,), ``obs`` (N, k), ``marker`` and
    implement :meth:`own_parameters` and :meth:`observe`; this class adds the marker
    parameters and chains the Jacobians: ``dr/d(robot) = (d obs/dp)(dp/d(robot)) / sigma``.
    """

    marker: str
    sigma: Array
    obs: Array

    # -- for the subclasses' constructors
    def _init_rows(self, kind: str, name: str, q: ArrayLike, obs: ArrayLike | None,
                   width: int, column: str, sigma: ArrayLike, marker: str) -> int:
        """Set ``name``, ``q``, ``obs`` (N, width; zeros when None), ``sigma`` (N,) and
        ``marker``, checking the row counts (``column`` names ``obs`` in messages).
        Returns N."""
        self.name = name
        self.q = as_q(q)
        N = self.q.shape[0]
        self.obs = (np.zeros((N, width)) if obs is None else
                    np.asarray(obs, dtype=float).reshape(-1, width))
        check_shapes(kind, name, N, **{column: self.obs})
        self.sigma = as_sigma(sigma, N, name)
        self.marker = check_marker_mode(marker)
        return N

    def _init_stations(self, labels: Sequence[str], what: str, rows: int | None = None
                       ) -> None:
        """Set ``station_labels`` and the distinct ``stations`` with each row's index."""
        self.station_labels = [str(s) for s in labels]
        self.stations, self.station_index = label_index(self.station_labels, what, self.name,
                                                        rows)

    # -- to implement
    def own_parameters(self) -> ParamSpec:
        """Parameters other than the marker (stations, offsets, planes)."""
        raise NotImplementedError

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        """Predicted observations (N, k), d obs/dp (N, k, 3), d obs/d own (N, k, E_own)."""
        raise NotImplementedError

    def difference(self, pred: Array) -> Array:
        """``pred - obs`` (N, k); angle instruments wrap it to (-pi, pi]."""
        return pred - self.obs

    def own_guess(self, robot: Robot, p: Array) -> Array:
        """Closed-form values of :meth:`own_parameters` from tool points ``p`` (N, 3)."""
        return self.own_parameters().values

    # -- the contract
    def parameters(self) -> ParamSpec:
        own = self.own_parameters()
        if self.marker == "own":
            return concat_specs([own, marker_spec(self.name)])
        return own

    def _split(self, extra: Array) -> tuple[Array, Array | None]:
        extra = np.asarray(extra, dtype=float)
        if self.marker == "own":
            return extra[:-3], extra[-3:]
        return extra, None

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        own, m = self._split(extra)
        p, _, dp, dpm = tool_point(robot, self.q, m, jacobian)
        pred, dodp, dodown = self.observe(p, own, jacobian)
        r = (self.difference(pred) / self.sigma[:, None]).reshape(-1)
        if not jacobian:
            return r, None, None
        Jr = chain_rows(dodp, dp, self.sigma)
        parts = [(dodown / self.sigma[:, None, None]).reshape(r.size, -1)]
        if dpm is not None:
            parts.append(chain_rows(dodp, dpm, self.sigma))
        return r, Jr, np.hstack(parts)

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.q.shape[0]), self.obs.shape[1])

    def initial_guess(self, robot: Robot) -> Array:
        """Closed form with the marker at the tool origin, then Gauss-Newton on the block."""
        p, _, _, _ = tool_point(robot, self.q, None, False)
        x0 = self.own_guess(robot, p)
        if self.marker == "own":
            x0 = np.concatenate([x0, np.zeros(3)])
        return refine_block(self, robot, x0)
