"""The base class of the point instruments and the block-only Gauss-Newton refinement.

:class:`PointBlock` turns "observations as functions of the tool point" into the
:class:`~kincal.measure.base.MeasurementModel` contract: it adds the marker parameters
(``marker="own"``), evaluates the tool point and chains the Jacobians::

    r = (obs(p(q; robot, m), own) - obs_measured) / sigma
    dr/d(robot) = (d obs/dp)(dp/d(robot)) / sigma,   dr/dm = (d obs/dp) R_e / sigma

Large blocks are evaluated in pieces of configurations (:meth:`PointBlock.evaluate_chunks`
on a view of the rows, :meth:`PointBlock._rows`), and the initial guess's refinement folds
its pieces into a QR triangle (:func:`refine_block`), so neither holds an (M, P) array.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.measure.base import (
    CHUNK_ROWS,
    MeasurementModel,
    ParamSpec,
    Triangle,
    configuration_slices,
)
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


def _own_pieces(model: MeasurementModel, robot: Robot, x: Array, jacobian: bool
                ) -> Iterator[tuple[Array, Array | None]]:
    """The block's residuals and (``jacobian``) its own columns, piece by piece."""
    if isinstance(model, PointBlock):
        yield from model.own_pieces(robot, x, jacobian)
    elif jacobian:
        for _, r, _, Je in model.evaluate_chunks(robot, x):
            yield r, Je
    else:
        yield model.evaluate(robot, x, jacobian=False)[0], None


def refine_block(model: MeasurementModel, robot: Robot, x0: Array, iterations: int = 30
                 ) -> Array:
    """Gauss-Newton on the block's own parameters with the robot held fixed.

    Minimum-norm steps (so parameters the block alone cannot see stay where they are;
    singular values below 1e-10 of the largest are dropped), halved until the cost
    drops.  Used by ``initial_guess`` after a closed form.  Each linearisation is the
    QR triangle of ``[J | r]`` folded piece by piece (memory independent of the rows).
    """
    x = np.asarray(x0, dtype=float).copy()
    E = x.size
    if E == 0:
        return x

    def system(x: Array) -> tuple[Triangle, float]:
        tri, cost = Triangle(E + 1), 0.0
        for r, Je in _own_pieces(model, robot, x, True):
            assert Je is not None                     # jacobian=True
            tri.add(np.column_stack([Je, r]))
            cost += float(r @ r)
        return tri, cost

    def cost_at(x: Array) -> float:
        return sum(float(r @ r) for r, _ in _own_pieces(model, robot, x, False))

    tri, cost = system(x)
    for _ in range(iterations):
        step = -tri.solve(E, rcond=1e-10)[:, 0]
        for _ in range(30):
            cand = x + step
            cc = cost_at(cand)
            if np.isfinite(cc) and cc <= cost:
                break
            step = step / 2
        else:
            break
        done = cost - cc <= 1e-12 * max(cost, 1e-300)
        x, cost = cand, cc
        if done:
            break
        tri, _ = system(x)
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
    #: attributes with one entry per row, cut by :meth:`_rows`; a subclass with others
    #: adds them (a block with an undeclared one is evaluated whole, never cut wrongly)
    row_fields: tuple[str, ...] = ("q", "obs", "sigma", "station_index", "station_labels")

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
        return int(N)

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
    def measurement_sigma(self) -> Array:
        """Stated standard deviation of each measured quantity [SI: m, rad or px]: (N,)."""
        return self.sigma

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
        assert dodp is not None and dp is not None and dodown is not None
        Jr = chain_rows(dodp, dp, self.sigma)
        parts = [(dodown / self.sigma[:, None, None]).reshape(r.size, -1)]
        if dpm is not None:
            parts.append(chain_rows(dodp, dpm, self.sigma))
        return r, Jr, np.hstack(parts)

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.q.shape[0]), self.obs.shape[1])

    def _rows(self, cs: slice) -> PointBlock:
        """The block restricted to the rows ``cs`` (views of its per-row arrays, the same
        parameters): what one piece of :meth:`evaluate_chunks` evaluates."""
        view = copy.copy(self)
        for f in self.row_fields:
            if hasattr(self, f):
                setattr(view, f, getattr(self, f)[cs])
        return view

    def _undeclared_rows(self) -> list[str]:
        """Attributes with one entry per row (by their length) not in ``row_fields``."""
        N = self.q.shape[0]
        out = []
        for key, v in vars(self).items():
            n = (v.shape[0] if isinstance(v, np.ndarray) and v.ndim else
                 len(v) if isinstance(v, (list, tuple)) else None)
            if n == N and key not in self.row_fields:
                out.append(key)
        return out

    def _pieces(self, rows: int = CHUNK_ROWS) -> Iterator[tuple[slice, PointBlock]]:
        N, k = self.q.shape[0], self.obs.shape[1]
        if N * k <= rows or self._undeclared_rows():
            yield slice(0, N), self
            return
        for cs in configuration_slices(N, k, rows):
            yield cs, self._rows(cs)

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        """:meth:`evaluate` over pieces of about ``rows`` residual rows."""
        k = self.obs.shape[1]
        for cs, part in self._pieces(rows):
            r, Jr, Je = part.evaluate(robot, extra, jacobian=True)
            yield slice(k * cs.start, k * cs.stop), r, Jr, Je  # type: ignore[misc]

    def own_pieces(self, robot: Robot, extra: Array, jacobian: bool, rows: int = CHUNK_ROWS
                   ) -> Iterator[tuple[Array, Array | None]]:
        """Residuals and (``jacobian``) the block's own columns ``dr/d(block params)``, piece
        by piece, without the robot's columns (the robot held fixed)."""
        for _, part in self._pieces(rows):
            own, m = part._split(extra)
            p, R, _, _ = tool_point(robot, part.q, m, False)
            pred, dodp, dodown = part.observe(p, own, jacobian)
            r = (part.difference(pred) / part.sigma[:, None]).reshape(-1)
            if not jacobian:
                yield r, None
                continue
            cols = [(dodown / part.sigma[:, None, None]).reshape(r.size, -1)]  # type: ignore[operator]
            if m is not None:
                cols.append(chain_rows(dodp, R, part.sigma))  # type: ignore[arg-type]
            yield r, np.hstack(cols)

    def tool_points(self, robot: Robot, rows: int = CHUNK_ROWS) -> Array:
        """The tool origin (N, 3) at every row [m], in pieces."""
        p = np.empty((self.q.shape[0], 3))
        for cs in configuration_slices(self.q.shape[0], 3, rows):
            p[cs] = tool_point(robot, self.q[cs], None, False)[0]
        return p

    def initial_guess(self, robot: Robot) -> Array:
        """Closed form with the marker at the tool origin, then Gauss-Newton on the block."""
        p = self.tool_points(robot)
        x0 = self.own_guess(robot, p)
        if self.marker == "own":
            x0 = np.concatenate([x0, np.zeros(3)])
        return refine_block(self, robot, x0)
