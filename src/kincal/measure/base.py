"""The contract between measurements and the identification machinery.

A calibration problem is a robot plus one or more *measurement blocks*.  Each block
holds the data of one instrument (joint readings ``q`` (N, n), observations, their
standard deviations) and has its own unknown parameters: the instrument's frame, the
measured point on the tool, artifact geometry, socket positions ...  Their names carry
the block's prefix (``tracker.x``, ``marker.z``, ``bar.L``) so that one parameter
vector ``theta = [robot params; block 1 params; block 2 params; ...]`` always
travels with its names.

Every block returns *whitened* residuals ``r_i = (model_i(theta) - observed_i) / sigma_i``
and their analytic Jacobian with respect to **all** robot parameters and **all** of
its own parameters.  The solver, the identifiability analysis, the uncertainty
propagation and the experiment design work only on the stacked whitened system
built by :func:`stack`, so any new instrument plugs in by implementing
:class:`MeasurementModel`.

Large problems never need the whole (M, P) Jacobian.  A block may hand out its
residuals and Jacobian in pieces (:meth:`MeasurementModel.evaluate_chunks`, a few
thousand rows each), and :meth:`StackedProblem.compressed` folds the pieces, as they
come, into the triangle of a QR factorisation (tall-skinny QR): with weights ``W``,

    [W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]],

``R`` (P, P) upper triangular, ``z = Q^T W^1/2 r``.  Everything the solver and the
identifiability analysis need follows from ``(R, z)``: ``J^T W J = R^T R``,
``J^T W r = R^T z``, the singular values and right singular vectors of ``W^1/2 J``
(those of ``R``), and the least-squares step ``argmin ||W^1/2 (J dx + r)||``
(= ``argmin ||R dx + z||``).  Memory is ``O(P^2)`` beyond the residuals, time
``O(M P^2)``.
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dtpqrt

from kincal.errors import KincalError
from kincal.robots.chain import Robot
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import FRAME_FIELDS

if TYPE_CHECKING:
    from kincal.measure.files import MeasurementTable

Array = NDArray[np.float64]

#: Residual rows per piece of :meth:`MeasurementModel.evaluate_chunks` (a piece's
#: Jacobian, a few thousand rows by a few dozen columns, stays in the CPU caches).
CHUNK_ROWS = 4096


@dataclass(frozen=True)
class ParamSpec:
    """Named parameters of a measurement block.

    Attributes:
        names: full names including the block prefix (``tracker.rz``).
        values: nominal / default values [m or rad].
        units: ``"m"``, ``"rad"`` (or ``"1"`` for dimensionless).
        roles: free-form role per parameter (``"instrument"``, ``"tool_point"``,
            ``"artifact"``, ``"target"``); used for reports and staging.
    """

    names: tuple[str, ...]
    values: Array
    units: tuple[str, ...]
    roles: tuple[str, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", np.asarray(self.values, dtype=float).reshape(-1))
        if not (len(self.names) == len(self.values) == len(self.units) == len(self.roles)):
            raise ValueError("ParamSpec fields differ in length")

    def __len__(self) -> int:
        return len(self.names)

    @staticmethod
    def empty() -> ParamSpec:
        return ParamSpec((), np.zeros(0), (), ())

    @staticmethod
    def frame(prefix: str, values: Array | None = None, role: str = "instrument") -> ParamSpec:
        """The six parameters ``{prefix}.x .y .z .rz .ry .rx`` of a frame (:data:`FRAME_FIELDS`)."""
        v = np.zeros(6) if values is None else np.asarray(values, dtype=float)
        return ParamSpec(tuple(f"{prefix}.{f}" for f in FRAME_FIELDS), v,
                         ("m", "m", "m", "rad", "rad", "rad"), (role,) * 6)

    @staticmethod
    def point(prefix: str, values: Array | None = None, role: str = "tool_point") -> ParamSpec:
        """The three parameters ``{prefix}.x .y .z`` of a point [m]."""
        v = np.zeros(3) if values is None else np.asarray(values, dtype=float)
        return ParamSpec(tuple(f"{prefix}.{f}" for f in "xyz"), v, ("m",) * 3, (role,) * 3)

    def __add__(self, other: ParamSpec) -> ParamSpec:
        return ParamSpec(self.names + other.names, np.concatenate([self.values, other.values]),
                         self.units + other.units, self.roles + other.roles)


def frame_rotation_axes(values: Array) -> Array:
    """Columns ``d omega / d(rz, ry, rx)`` of a frame's rotation, in its parent frame: (3, 3).

    With ``R = Rz(rz) Ry(ry) Rx(rx)``, ``dR = [omega]x R`` and
    ``omega = e_z drz + Rz(rz) e_y dry + Rz(rz) Ry(ry) e_x drx``, i.e. the columns are
    ``[0, 0, 1]``, ``[-sin rz, cos rz, 0]`` and
    ``[cos rz cos ry, sin rz cos ry, -sin ry]`` (dimensionless, rad/rad).
    """
    v = np.asarray(values, dtype=float)
    cz, sz = np.cos(v[3]), np.sin(v[3])
    cy, sy = np.cos(v[4]), np.sin(v[4])
    return np.array([[0.0, -sz, cz * cy],
                     [0.0, cz, sz * cy],
                     [1.0, 0.0, -sy]])


def configuration_slices(N: int, rows_per_configuration: int, rows: int = CHUNK_ROWS
                         ) -> Iterator[slice]:
    """Consecutive slices of N configurations, at most ``rows`` residual rows each (at
    least one configuration): the pieces a block evaluates at a time."""
    step = max(1, rows // max(rows_per_configuration, 1))
    for start in range(0, N, step):
        yield slice(start, min(N, start + step))


class SourceSpec(Protocol):
    """What a block keeps of the source it was read from (a workflow's ``DataSource``):
    the file and, for a held-out file, how its instrument frames are found."""

    @property
    def path(self) -> str: ...

    @property
    def frames(self) -> str | None: ...


@dataclass(frozen=True)
class Provenance:
    """Where a block's data came from.

    Attributes:
        path: the measurement file (or socket folder).
        table: the parsed file (its line numbers, tags and ignored columns), or None.
        source: the source specification it was read with (file options), or None.
    """

    path: str
    table: MeasurementTable | None = None
    source: SourceSpec | None = None


class MeasurementModel(ABC):
    """One instrument's block of measurements and its unknown parameters.

    Subclasses hold their data (``q`` (N, n) joint readings plus observations and
    standard deviations) and implement:

    * :meth:`parameters` - the block's own named parameters with defaults;
    * :meth:`initial_guess` - closed-form values of those parameters from the data
      and a robot model (e.g. Kabsch registration of the instrument frame), so the
      user never supplies one;
    * :meth:`evaluate` - whitened residuals and their analytic Jacobian.

    Attributes:
        name: the block's prefix for its parameter names and for reports.
        q: (N, n) joint readings [rad / m].
        provenance: the file the block was read from (:class:`Provenance`); None for
            simulated and in-memory blocks.  Wrappers (:class:`BlockWrapper`) share
            their inner block's.

    Optional capabilities are declared as protocols and tested with ``isinstance``:
    :class:`PredictsObservations`, :class:`PredictsPoints`, :class:`HasPlacements`,
    :class:`HasProbe`.
    """

    name: str
    q: Array
    _provenance: Provenance | None = None

    @property
    def provenance(self) -> Provenance | None:
        """The file the block was read from, or None (simulated / in memory)."""
        return self._provenance

    @provenance.setter
    def provenance(self, value: Provenance | None) -> None:
        self._provenance = value

    @property
    def source_label(self) -> str:
        """The block's file path when it was read from one, else its name."""
        return self.provenance.path if self.provenance is not None else self.name

    def measurement_sigma(self) -> Array | None:
        """Stated standard deviation of each measurement, in SI units (m for lengths,
        rad for angles, px for pixels): (N,) or (N, K) (e.g. a pose file's ``sigma_x,
        sigma_y, sigma_z``: one per row and instrument axis, each residual component
        divided by its own); the position sigma for blocks that measure several
        quantities (pose); None when the block states no single one (artifacts).  The
        whitening divisor ``sigma_i`` of :meth:`evaluate`: the fit weighs each residual
        by ``1 / sigma_i^2``."""
        return None

    def with_q(self, q: Array) -> MeasurementModel:
        """A copy measuring the same rows at joint readings ``q`` (N, n) (the
        information of postures not measured: the Jacobian does not depend on the
        observations).  Default: a shallow copy with ``q`` replaced."""
        out = copy.copy(self)
        out.q = q
        return out

    #: SI unit of :meth:`measurement_sigma`: ``"m"``, ``"rad"`` (angle instruments) or
    #: ``"px"`` (cameras).
    SIGMA_UNIT: ClassVar[str] = "m"

    @property
    def sigma_unit(self) -> str:
        """SI unit of :meth:`measurement_sigma` (``m``, ``rad`` or ``px``)."""
        return self.SIGMA_UNIT

    @property
    def instrument(self) -> str:
        """What measured the block: the file's ``instrument=`` tag, else the block's kind
        (its class name without ``Measurement``: ``position``, ``pose`` ...)."""
        table = self.provenance.table if self.provenance is not None else None
        if table is not None and table.tags.get("instrument"):
            return table.tags["instrument"]
        kind = type(self).__name__.removesuffix("Measurement")
        return "".join(f"-{c.lower()}" if c.isupper() and i else c.lower()
                       for i, c in enumerate(kind))

    def sigma_text(self) -> str:
        """The stated standard deviation for people: lengths in mm, angles in arcsec,
        pixels in px; one value when all rows state the same, else ``lo to hi``;
        ``"not stated"`` for blocks without one (artifacts)."""
        sigma = self.measurement_sigma()
        finite = np.asarray(sigma, dtype=float) if sigma is not None else np.empty(0)
        finite = finite[np.isfinite(finite)]
        if not finite.size:
            return "not stated"
        factor, unit = _SIGMA_DISPLAY.get(self.sigma_unit, (1.0, self.sigma_unit))
        lo, hi = float(finite.min()) * factor, float(finite.max()) * factor
        return f"{lo:.3g} {unit}" if f"{lo:.3g}" == f"{hi:.3g}" else f"{lo:.3g} to {hi:.3g} {unit}"

    def summary(self) -> list[tuple[str, str]]:
        """``(field, value)`` rows shown by ``repr`` and in a notebook: name, instrument,
        rows, sigma (with its unit), source file, number of parameters."""
        return [("name", self.name), ("instrument", self.instrument),
                ("rows", str(len(self.q))), ("sigma", self.sigma_text()),
                ("source file", self.provenance.path if self.provenance is not None
                 else "none (simulated or in memory)"),
                ("parameters", str(len(self.parameters())))]

    def __repr__(self) -> str:
        src = f", from {self.provenance.path!r}" if self.provenance is not None else ""
        return (f"{type(self).__name__}({self.name!r}: {self.instrument}, {len(self.q)} rows, "
                f"sigma {self.sigma_text()}, {len(self.parameters())} parameters{src})")

    def _repr_html_(self) -> str:
        """The block in a notebook: a small table of :meth:`summary`, then its parameters
        with units and roles."""
        from html import escape

        spec = self.parameters()
        head = "".join(f"<tr><th style='text-align:left'>{escape(k)}</th><td>{escape(v)}</td>"
                       "</tr>" for k, v in self.summary())
        rows = "".join(f"<tr><td>{escape(n)}</td><td>{escape(u)}</td><td>{escape(r)}</td></tr>"
                       for n, u, r in zip(spec.names, spec.units, spec.roles, strict=True))
        return (f"<table><caption style='text-align:left'><b>{escape(type(self).__name__)}"
                f"</b></caption>{head}</table><details><summary>{len(spec)} parameters"
                f"</summary><table><tr><th>parameter</th><th>unit</th><th>role</th></tr>"
                f"{rows}</table></details>")

    @abstractmethod
    def parameters(self) -> ParamSpec:
        """The block's own parameters (names prefixed by ``self.name``) with defaults."""

    @abstractmethod
    def initial_guess(self, robot: Robot) -> Array:
        """Values for :meth:`parameters` estimated in closed form from the data."""

    @abstractmethod
    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        """Whitened residuals and Jacobians.

        Args:
            robot: the robot with its current parameter values.
            extra: current values of this block's parameters (order of :meth:`parameters`).
            jacobian: when False only the residuals are computed.

        Returns:
            ``(r, J_robot, J_extra)``: ``r`` (M,) = (predicted - observed) / sigma;
            ``J_robot`` (M, robot.num_params) = dr / d(robot params);
            ``J_extra`` (M, len(parameters())) = dr / d(block params).
        """

    @abstractmethod
    def residual_owner(self) -> NDArray[np.intp]:
        """For each residual, the row (measurement) it comes from: (M,) ints.

        Used to flag outlier measurements by index and to hold out rows.
        """

    def num_residuals(self) -> int:
        """Number of residuals ``M`` of the block (default: ``len(residual_owner())``)."""
        return len(self.residual_owner())

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        """:meth:`evaluate` with the Jacobian in consecutive pieces of about ``rows`` rows.

        Yields ``(sl, r, J_robot, J_extra)``: the residual rows ``sl`` of the block and
        their values and Jacobians as :meth:`evaluate` defines them, the pieces in order
        and covering all rows.  The default yields :meth:`evaluate`'s result as one
        piece; blocks with many rows override it so that no (M, P) array is formed.
        """
        r, Jr, Je = self.evaluate(robot, extra, jacobian=True)
        yield slice(0, r.size), r, Jr, Je  # type: ignore[misc]

    def system_pieces(self, robot: Robot, extra: Array, robot_columns: NDArray[np.intp],
                      own_columns: NDArray[np.intp], rows: int = CHUNK_ROWS, *,
                      robot_out: Callable[[int], Array | None] | None = None,
                      workspace: ChainWorkspace | None = None
                      ) -> Iterator[tuple[slice, NDArray[np.intp] | None, Array, Array, Array]]:
        """The residuals and the Jacobian columns a least-squares step needs, in pieces.

        Yields ``(sl, order, r, Jr, Je)``: the piece covers the block's residual rows
        ``sl``; its ``n`` rows are taken in the order ``order`` (positions within ``sl``,
        None for the natural order); ``r`` (n,) their whitened residuals, ``Jr``
        (len(robot_columns), n) and ``Je`` (len(own_columns), n) the columns
        ``robot_columns`` of ``J_robot`` and ``own_columns`` of ``J_extra``,
        *transposed* (one row per parameter, so that a piece is written column by
        column), in that row order.  The default takes them from
        :meth:`evaluate_chunks`; blocks with a faster path override it.  A piece's
        arrays may be working memory the next piece reuses (from ``workspace``): use
        them before asking for the next.

        ``robot_out``, when given, maps a piece's ``n`` to a C-contiguous
        (len(robot_columns), n) array (or None) that a block may compute ``Jr`` into
        and yield (the caller's own buffer: no copy); blocks are free to ignore it.
        ``workspace``: the caller's working memory
        (:class:`~kincal.robots.workspace.ChainWorkspace`, e.g. the stacked problem's),
        reused between calls; None: the block makes its own for the call.  Blocks are
        free to ignore it.
        """
        for sl, r, Jr, Je in self.evaluate_chunks(robot, extra, rows):
            yield sl, None, r, Jr[:, robot_columns].T, Je[:, own_columns].T

    def residuals_into(self, robot: Robot, extra: Array, out: Array, *,
                       workspace: ChainWorkspace | None = None) -> None:
        """The whitened residuals of :meth:`evaluate` written into ``out`` (M,).  The
        default copies them; blocks that can compute them in place override it (with
        the caller's working memory ``workspace`` when given, as in
        :meth:`system_pieces`)."""
        out[...] = self.evaluate(robot, extra, jacobian=False)[0]

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        """Physical errors per measurement for reports, e.g. ``{"position_m": (N,)}``.

        The keys end in their unit (``_m``, ``_rad``).  Default: none.
        """
        return {}


#: How :meth:`MeasurementModel.sigma_text` shows a sigma: (factor from SI, unit).
_SIGMA_DISPLAY = {"m": (1e3, "mm"), "rad": (180 / np.pi * 3600, "arcsec")}


class BlockWrapper(MeasurementModel):
    """A block built around another (joint-model terms, a shared tool point): it
    measures the inner block's rows, so it has its name and provenance by construction.
    """

    inner: MeasurementModel

    @property
    def provenance(self) -> Provenance | None:
        return self.inner.provenance

    @provenance.setter
    def provenance(self, value: Provenance | None) -> None:
        self.inner.provenance = value

    def measurement_sigma(self) -> Array | None:
        return self.inner.measurement_sigma()

    @property
    def sigma_unit(self) -> str:
        return self.inner.sigma_unit

    @property
    def instrument(self) -> str:
        return self.inner.instrument


# --------------------------------------------------------------------------- capabilities
@runtime_checkable
class PredictsObservations(Protocol):
    """A block that predicts its observations: ``predict(robot, extra) -> (N, ...)``
    in the units of its data (e.g. (N, K, 3) positions [m])."""

    def predict(self, robot: Robot, extra: Array) -> Array: ...


@runtime_checkable
class PredictsPoints(Protocol):
    """A block whose measured points can be listed: ``points(robot, extra) -> (M, 3)``
    [m] in the base frame (artifact probe points)."""

    def points(self, robot: Robot, extra: Array | None = None) -> Array: ...


@runtime_checkable
class HasPlacements(Protocol):
    """A block measured in several placements of an artifact (labels in order)."""

    @property
    def placements(self) -> tuple[str, ...]: ...

    def residual_placement(self) -> NDArray[np.intp]:
        """(M,) index into :attr:`placements` of every residual."""
        ...

    def subset_placements(self, placements: Sequence[str]) -> MeasurementModel: ...


@runtime_checkable
class HasProbe(Protocol):
    """A block measured through a probe on the flange (an artifact's ball or stylus)."""

    @property
    def probe(self) -> ProbeLike: ...


class ProbeLike(Protocol):
    """A probe: ``mode`` (``tool``, ``vector``, ``length`` ...) and its known values [m]."""

    @property
    def mode(self) -> str: ...

    @property
    def value(self) -> tuple[float, ...]: ...


@dataclass
class StackedProblem:
    """All blocks of a calibration stacked into one whitened least-squares problem.

    ``theta`` = robot parameters followed by every block's parameters; ``free`` is a
    boolean mask over ``theta`` naming what is estimated.
    """

    robot: Robot
    blocks: list[MeasurementModel]
    names: tuple[str, ...]
    units: tuple[str, ...]
    roles: tuple[str, ...]
    slices: list[slice]          # slice of theta owned by each block
    #: working memory of repeated evaluations, lent to the blocks and the chain (each
    #: problem has its own: one problem is evaluated by one thread at a time)
    workspace: ChainWorkspace = field(default_factory=ChainWorkspace, init=False,
                                      repr=False, compare=False)

    @property
    def num_robot(self) -> int:
        return self.robot.num_params

    def split(self, theta: Array) -> tuple[Robot, list[Array]]:
        """The robot with ``theta``'s robot part, and each block's parameter values."""
        theta = np.asarray(theta, dtype=float)
        values = theta[: self.num_robot]
        # the robot itself when its values are unchanged (robots are immutable): its
        # compiled chain is reused
        robot = self.robot if np.array_equal(values, self.robot.param_values) \
            else self.robot.with_params(values)
        return robot, [theta[s] for s in self.slices]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            import difflib

            close = difflib.get_close_matches(name, self.names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KincalError(f"no parameter named {name!r} in this problem{hint}") from None

    @property
    def block_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.blocks)

    def block(self, name: str) -> MeasurementModel:
        """The block called ``name``."""
        for b in self.blocks:
            if b.name == name:
                return b
        raise KincalError(f"no measurement block named {name!r}; blocks: "
                          f"{', '.join(self.block_names)}")

    def block_slice(self, name: str) -> slice:
        """The slice of ``theta`` holding block ``name``'s parameters."""
        return self.slices[self.block_names.index(self.block(name).name)]

    def owners(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """For every stacked residual: (index of its block, row within that block)."""
        bi = [np.full(len(b.residual_owner()), i, dtype=np.intp)
              for i, b in enumerate(self.blocks)]
        rows = [np.asarray(b.residual_owner(), dtype=np.intp) for b in self.blocks]
        return np.concatenate(bi), np.concatenate(rows)

    def measurement_ids(self) -> NDArray[np.intp]:
        """A unique integer per (block, row) for every residual, 0 .. num_measurements - 1.

        Residuals with the same id belong to one physical measurement (the three
        coordinates of a point, the six of a pose).  Ids follow the blocks' order, then
        the rows' order within a block (``O(M)`` when a block's rows are sorted).
        """
        out = []
        base = 0
        for b in self.blocks:
            rows = np.asarray(b.residual_owner(), dtype=np.intp)
            if rows.size == 0:
                continue
            if np.all(rows[1:] >= rows[:-1]):               # sorted: rank by run starts
                new = np.empty(rows.size, dtype=bool)
                new[0] = True
                np.not_equal(rows[1:], rows[:-1], out=new[1:])
                ids = np.cumsum(new, dtype=np.intp) - 1
            else:
                _, ids = np.unique(rows, return_inverse=True)
            out.append(ids.reshape(-1) + base)
            base += int(ids.max()) + 1
        return np.concatenate(out) if out else np.zeros(0, dtype=np.intp)

    def errors(self, theta: Array) -> dict[str, dict[str, Array]]:
        """Physical errors of every block at ``theta``: ``{block name: block.errors(...)}``."""
        robot, extras = self.split(theta)
        return {b.name: b.errors(robot, e) for b, e in zip(self.blocks, extras, strict=True)}

    def residuals(self, theta: Array, spare_rows: int = 0) -> Array:
        """Stacked whitened residuals r(theta): (M,).

        ``spare_rows``: the vector gets that many more entries at its end, left for the
        caller (e.g. a prior's rows), so that it need not be copied to append them.
        """
        robot, extras = self.split(theta)
        out = np.empty(self.num_residuals() + spare_rows)
        start = 0
        for b, e in zip(self.blocks, extras, strict=True):
            m = b.num_residuals()
            b.residuals_into(robot, e, out[start: start + m], workspace=self.workspace)
            start += m
        return out

    def num_residuals(self) -> int:
        """Total number of stacked residuals ``M``."""
        return sum(b.num_residuals() for b in self.blocks)

    def _pieces(self, theta: Array, rows: int
                ) -> Iterator[tuple[int, int, slice, Array, Array, Array]]:
        """Every block's residual/Jacobian pieces: (block index, row offset, sl, r, Jr, Je)."""
        robot, extras = self.split(theta)
        offset = 0
        for i, (b, e) in enumerate(zip(self.blocks, extras, strict=True)):
            m = b.num_residuals()
            for sl, r, Jr, Je in b.evaluate_chunks(robot, e, rows):
                if sl.stop > m:
                    raise KincalError(f"measurement block {b.name!r} returned more residuals "
                                      f"than its residual_owner() lists ({m})")
                yield i, offset, sl, r, Jr, Je
            offset += m

    def residuals_and_jacobian(self, theta: Array) -> tuple[Array, Array]:
        """Stacked ``r`` (M,) and the full Jacobian ``dr/dtheta`` (M, len(theta)).

        Built piece by piece (:meth:`MeasurementModel.evaluate_chunks`) into one array;
        for large problems prefer :meth:`compressed`, which never forms it.
        """
        M = self.num_residuals()
        r = np.empty(M)
        J = np.zeros((M, len(self.names)))
        P = self.num_robot
        for i, off, sl, rc, Jr, Je in self._pieces(np.asarray(theta, dtype=float), CHUNK_ROWS):
            rows = slice(off + sl.start, off + sl.stop)
            r[rows] = rc
            J[rows, :P] = Jr
            J[rows, self.slices[i]] = Je
        return r, J

    def compressed(self, theta: Array, weights: ArrayLike | None = None,
                   columns: Sequence[int] | None = None, rows: int = CHUNK_ROWS,
                   keep_residuals: bool = True, spare_rows: int = 0) -> CompressedSystem:
        """The weighted least-squares problem at ``theta`` compressed to a triangle.

        With ``W = diag(weights)`` (default 1) and ``J`` the columns ``columns`` of
        ``dr/dtheta`` (default all), factorises ``[W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]]``
        piece by piece: each block hands out pieces of about ``rows`` rows with only
        the selected columns (:meth:`MeasurementModel.system_pieces`), and each piece is
        folded into the triangle as it comes, ``R <- triangle of [R; piece]`` (LAPACK's
        ``dtpqrt``, :func:`_fold`), so neither ``J`` nor ``Q`` is ever formed (memory
        ``O(P^2 + rows P)`` beyond the residuals, time ``O(M P^2)``).

        Everything a Gauss-Newton / Levenberg-Marquardt step, the identifiability
        analysis and the covariance need follows from the triangle:
        ``||W^1/2 (J dx + r)||^2 = ||R dx + z||^2 + rho^2``, ``J^T W J = R^T R``,
        ``J^T W r = R^T z``, and ``W^1/2 J = Q_1 R`` with orthonormal ``Q_1``, so ``R``
        has the singular values, right singular vectors and column norms of ``W^1/2 J``
        (``analyze(R, ...)`` gives the same report as ``analyze(W^1/2 J, ...)``).

        Uniform weights (a zero-stride array such as ``np.broadcast_to(1.0, M)``) cost
        nothing.  ``keep_residuals=False`` returns ``r = None`` (memory independent of
        ``M``; the cost is summed piece by piece); ``spare_rows`` gives ``r`` that many
        more entries at its end, left for the caller (not in the triangle or the cost).

        Returns:
            A :class:`CompressedSystem` (``R``, ``z``, ``rho``, ``r``, ``cost``).
        """
        theta = np.asarray(theta, dtype=float)
        cols = np.arange(len(self.names)) if columns is None else np.asarray(columns, np.intp)
        p = cols.size
        M = self.num_residuals()
        w = None if weights is None else np.asarray(weights, dtype=float).reshape(-1)
        if w is not None and w.size != M:
            raise ValueError(f"{w.size} weights for {M} residuals")
        w0 = 1.0                                    # uniform weights: a factor, not a vector
        if w is not None and M and w.strides[0] == 0:
            w0, w = float(w[0]), None
        # where each block's robot / own columns go among the selected ones
        P = self.num_robot
        where = np.full(len(self.names), -1, dtype=np.intp)
        where[cols] = np.arange(p)
        rob_src = np.flatnonzero(where[:P] >= 0)
        rob_dst = where[rob_src]
        dst_r = _as_slice(rob_dst)
        r = np.empty(M + spare_rows) if keep_residuals else None
        rw2 = 0.0
        # [W^1/2 J | W^1/2 r]^T piece by piece into B (p + 1, n) (row-major, i.e. the
        # piece in LAPACK's column-major order), folded into the triangle by dtpqrt
        T = np.zeros((p + 1, p + 1), order="F")
        nb = min(FOLD_BLOCK, p + 1)
        robot, extras = self.split(theta)
        ws = self.workspace
        # the robot columns go straight into the fold buffer when they are a run of its
        # rows (a block may compute them there: no copy)
        handed: list[Array] = []

        def robot_rows(n: int) -> Array | None:
            handed[:] = [ws.array("compressed.B", (p + 1, n))[dst_r]]
            return handed[0]

        into = robot_rows if isinstance(dst_r, slice) and rob_src.size else None
        offset = 0
        for i, (b, e) in enumerate(zip(self.blocks, extras, strict=True)):
            m = b.num_residuals()
            own = self.slices[i]
            own_src = np.flatnonzero(where[own] >= 0)
            own_dst = where[own][own_src]
            dst_o = _as_slice(own_dst)
            # rows of B that neither the robot's nor this block's columns fill
            idle = np.ones(p, dtype=bool)
            idle[rob_dst] = idle[own_dst] = False
            idle = np.flatnonzero(idle)
            for sl, order, rc, Jr, Je in b.system_pieces(robot, e, rob_src, own_src, rows,
                                                         robot_out=into, workspace=ws):
                if sl.stop > m:
                    raise KincalError(f"measurement block {b.name!r} returned more residuals "
                                      f"than its residual_owner() lists ({m})")
                n = rc.size
                if n == 0:
                    continue
                idx = slice(offset + sl.start, offset + sl.stop) if order is None \
                    else offset + sl.start + order
                if r is not None:
                    r[idx] = rc
                rw2 += float(rc @ rc) if w is None else float((w[idx] * rc) @ rc)
                B = ws.array("compressed.B", (p + 1, n))
                if idle.size:
                    B[idle] = 0.0
                if rob_src.size and not (handed and Jr.shape == handed[0].shape
                                         and Jr.ctypes.data == handed[0].ctypes.data):
                    B[dst_r] = Jr
                if own_src.size:
                    B[dst_o] = Je
                B[p] = rc
                if w is not None:
                    B *= np.sqrt(w[idx])
                elif w0 != 1.0:
                    B *= np.sqrt(w0)
                T = _fold(T, B, nb)
            offset += m
        return CompressedSystem._from_triangle(T, r, 0.5 * w0 * rw2, cols)

    def normal_equations(self, theta: Array, weights: ArrayLike | None = None,
                         columns: Sequence[int] | None = None) -> tuple[Array, Array, float]:
        """``(J^T W J, J^T W r, cost)`` over ``columns``, ``cost = 1/2 r^T W r``.

        Formed from the triangle of :meth:`compressed` (``R^T R``, ``R^T z``), i.e. in
        pieces of configurations, never from the (M, P) Jacobian.  Solving with them
        squares the condition number; prefer the triangle itself for the step.
        """
        c = self.compressed(theta, weights, columns)
        return c.R.T @ c.R, c.R.T @ c.z, c.cost


@dataclass(frozen=True)
class CompressedSystem:
    """A weighted least-squares problem ``min ||W^1/2 (J dx + r)||`` reduced to a triangle.

    ``[W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]]`` (see :meth:`StackedProblem.compressed`).

    Attributes:
        R: (p, p) upper triangular: ``R^T R = J^T W J``; same singular values, right
            singular vectors and column norms as ``W^1/2 J``.
        z: (p,) ``Q^T W^1/2 r``: ``R^T z = J^T W r``.
        rho: ``||W^1/2 r||`` outside the range of ``W^1/2 J`` (the residual norm of the
            linearised least-squares solution; ``rho^2 + ||z||^2 = r^T W r``).
        r: (M,) the unweighted whitened residuals at ``theta`` (None when not kept).
        cost: ``1/2 r^T W r``.
        columns: the indices of ``theta`` the columns of ``R`` stand for.
    """

    R: Array
    z: Array
    rho: float
    r: Array | None
    cost: float
    columns: NDArray[np.intp]

    def _triangle(self) -> Array:
        """``[[R, z], [0, rho]]`` (p + 1, p + 1)."""
        p = self.z.size
        T = np.zeros((p + 1, p + 1))
        T[:p, :p], T[:p, p], T[p, p] = self.R, self.z, self.rho
        return T

    @staticmethod
    def _from_triangle(T: Array, r: Array | None, cost: float, columns: NDArray[np.intp]
                       ) -> CompressedSystem:
        p = T.shape[1] - 1
        F = np.zeros((p + 1, p + 1))
        F[: T.shape[0]] = T[: p + 1]
        return CompressedSystem(R=F[:p, :p], z=F[:p, p], rho=abs(float(F[p, p])), r=r,
                                cost=cost, columns=columns)

    def select(self, positions: Sequence[int]) -> CompressedSystem:
        """The system over a subset of its columns (positions into ``columns``), without
        re-evaluating: ``[W^1/2 J_S | W^1/2 r] = Q [[R_S, z], [0, rho]]``, so its triangle
        is that of ``[[R_S, z], [0, rho]]`` (a (p + 1)-row QR)."""
        pos = np.asarray(positions, dtype=np.intp)
        T = self._triangle()
        A = np.concatenate([T[:, pos], T[:, -1:]], axis=1)
        return self._from_triangle(qr_triangle(A), self.r, self.cost,
                                   self.columns[pos])

    def with_rows(self, J_rows: ArrayLike, r_rows: ArrayLike,
                  weights: ArrayLike | None = None) -> CompressedSystem:
        """The system with more rows ``(J_rows, r_rows)`` (e.g. a prior's pseudo-
        observations; ``J_rows`` (m, p) over the same columns): the triangle of
        ``[[R, z], [0, rho]; W^1/2 [J_rows, r_rows]]``; ``r`` and ``cost`` extended."""
        Jx = np.asarray(J_rows, dtype=float).reshape(-1, self.z.size)
        rx = np.asarray(r_rows, dtype=float).reshape(-1)
        wx = np.ones(rx.size) if weights is None else np.asarray(weights, float).reshape(-1)
        A = np.concatenate([Jx, rx[:, None]], axis=1) * np.sqrt(wx)[:, None]
        T = qr_triangle(np.concatenate([self._triangle(), A]))
        return self._from_triangle(T, None if self.r is None else np.concatenate([self.r, rx]),
                                   self.cost + 0.5 * float(np.sum(wx * rx * rx)), self.columns)

    def residual_free(self) -> Array:
        """The triangle of ``(I - u u^T) W^1/2 J``, ``u = W^1/2 r / |W^1/2 r|``: the columns
        without their component along the residual (``R`` itself when ``r = 0``).

        In the coordinates of ``Q`` the columns are ``[R; 0]`` and the residual is
        ``t = [z; rho]``, so the projected columns are ``Q (I - t t^T / |t|^2) [R; 0]``;
        its triangle (:func:`r_factor`) has their Gram matrix
        ``R^T R - (R^T z)(R^T z)^T / (|z|^2 + rho^2)``, so the identifiability analysis
        (``analyze``) of it equals that of the projected (M, p) columns.
        """
        T = self._triangle()
        t = T[:, -1]
        n2 = float(t @ t)
        if not np.isfinite(n2) or n2 == 0.0:
            return self.R.copy()
        C = T[:, :-1]
        return r_factor(C - np.outer(t, (t @ C) / n2))

    def solve(self, rcond: float = 1e-12) -> Array:
        """The Gauss-Newton step ``dx = -argmin ||R dx + z||`` (minimum norm, singular
        values of ``R D^-1`` below ``rcond`` times the largest dropped; ``D`` the column
        norms, so the cut is unit-free)."""
        D = np.linalg.norm(self.R, axis=0)
        Ds = np.where(D > 0, D, 1.0)
        Ur, S, Vt = np.linalg.svd(self.R / Ds)
        keep = S > rcond * (S[0] if S.size else 0.0)
        value: Array = -(Vt[keep].T @ ((Ur[:, keep].T @ self.z) / S[keep])) / Ds
        return value


def stack(robot: Robot, blocks: Sequence[MeasurementModel]) -> tuple[StackedProblem, Array]:
    """Stack ``blocks`` measured on ``robot``.

    Returns the problem and the initial ``theta``: the robot's current parameters
    followed by each block's :meth:`~MeasurementModel.initial_guess`.
    """
    if not blocks:
        raise KincalError("no measurements given")
    names = list(robot.param_names)
    units = list(robot.param_units)
    roles = list(robot.param_roles)
    theta = [np.asarray(robot.param_values, dtype=float)]
    slices = []
    seen_prefix: set[str] = set()
    for b in blocks:
        if b.name in seen_prefix:
            raise KincalError(f"two measurement blocks are both named {b.name!r}; give each "
                              "instrument its own name")
        seen_prefix.add(b.name)
        if b.q.ndim != 2 or b.q.shape[1] != robot.n:
            raise KincalError(f"measurements {b.name!r} have {b.q.shape[-1]} joint values per "
                              f"row; robot {robot.name!r} has {robot.n} joints")
        spec = b.parameters()
        if len(set(spec.names)) != len(spec.names):
            twice = next(n for n in spec.names if spec.names.count(n) > 1)
            raise KincalError(f"block {b.name!r} lists parameter {twice!r} twice (e.g. the "
                              "same deflection model wrapped around it twice)")
        clash = set(spec.names) & set(names)
        if clash:
            raise KincalError(f"parameter name {sorted(clash)[0]!r} of block {b.name!r} is "
                              "already used")
        start = len(names)
        names += spec.names
        units += spec.units
        roles += spec.roles
        slices.append(slice(start, len(names)))
        theta.append(np.asarray(b.initial_guess(robot), dtype=float).reshape(-1))
    prob = StackedProblem(robot, list(blocks), tuple(names), tuple(units), tuple(roles), slices)
    return prob, np.concatenate(theta)


# --------------------------------------------------------------------------- linear algebra
def qr_triangle(A: Array) -> Array:
    """``R`` of ``A = Q R`` (numpy's ``qr(A, mode="r")``; stacked for (..., M, p))."""
    R: Array = np.linalg.qr(A, mode="r")  # type: ignore[assignment]  # numpy's stubs: QRResult
    return R


#: Rows per tile of the tall-skinny QR (:func:`r_factor`, :func:`svd_thin`): a tile of
#: ``TILE_ROWS x p`` doubles stays in the CPU cache while LAPACK factorises it.  A
#: performance setting only; the factors do not depend on it beyond round-off.
TILE_ROWS = 1024
#: Tiles factorised per LAPACK call (bounds the working copy to a few MB).
_TILE_GROUP = 32


def _tile_rows(p: int) -> int:
    return max(TILE_ROWS, 4 * p)


def _as_slice(idx: NDArray[np.intp]) -> slice | NDArray[np.intp]:
    """``idx`` as a slice when it is a run of consecutive integers (a view, not a copy)."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


#: Block size of LAPACK's ``dtpqrt`` in :func:`_fold`.  A performance setting only: on
#: pieces of up to 4096 rows and 27-56 columns, starting from cold caches, 4 is 1-11 %
#: faster than 8 and 30-50 % faster than 12 (medians of 15, 2-core Xeon, one BLAS thread).
FOLD_BLOCK = 4


def _fold(T: Array, B: Array, nb: int) -> Array:
    """The triangle of ``[T; B^T]`` for an upper-triangular ``T`` (p, p) (column-major)
    and more rows ``B^T`` (``B`` (p, n), row-major: ``B^T`` is column-major).

    LAPACK's ``dtpqrt`` (blocked Householder QR of a triangle on top of a rectangle)
    does it in ``2 n p^2`` flops without touching the zeros of ``T``; ``B`` is
    overwritten.  ``R^T R`` grows by ``B B^T``, the same as a QR of all rows at once.
    """
    out, _, _, info = dtpqrt(0, nb, T, B.T, overwrite_a=1, overwrite_b=1)
    if info != 0:                                   # pragma: no cover - LAPACK argument check
        raise RuntimeError(f"dtpqrt failed (info {info})")
    value: Array = out
    return value


class Triangle:
    """The triangle ``R`` of ``A = Q R`` for rows ``A`` (n, p) that arrive piece by piece.

    ``add(rows)`` folds more rows in (:func:`_fold`); memory ``O(p^2)`` whatever the
    number of rows, and ``R^T R = A^T A`` at every moment.  With the last columns of
    ``A`` right-hand sides ``[A_x | B]``, :meth:`solve` gives the minimum-norm least-
    squares solution of ``A_x X = B`` as :func:`lstsq` does.
    """

    def __init__(self, p: int) -> None:
        self.p = int(p)
        self.R = np.zeros((self.p, self.p), order="F")
        self.rows = 0

    def add(self, rows: ArrayLike) -> None:
        """Fold the rows ``rows`` (n, p) into the triangle."""
        A = np.asfortranarray(rows, dtype=float)
        if A.ndim != 2 or A.shape[1] != self.p:
            raise ValueError(f"rows of {self.p} columns expected, got shape {A.shape}")
        if A.shape[0] == 0:
            return
        if A is rows:
            A = A.copy(order="F")                      # dtpqrt overwrites its input
        self.R = _fold(self.R, A.T, min(FOLD_BLOCK, self.p))
        self.rows += A.shape[0]

    def add_transposed(self, B: Array) -> None:
        """Fold the rows ``B^T`` in, given their transpose ``B`` (p, n) in C order (each
        column of the system one contiguous row of ``B``: no copy); ``B`` is overwritten."""
        if B.ndim != 2 or B.shape[0] != self.p or not B.flags.c_contiguous:
            raise ValueError(f"a C-ordered array of {self.p} rows expected, got shape {B.shape}")
        if B.shape[1] == 0:
            return
        self.R = _fold(self.R, B, min(FOLD_BLOCK, self.p))
        self.rows += B.shape[1]

    def solve(self, nx: int, rcond: float = 1e-10) -> Array:
        """``X`` (nx, p - nx): the minimum-norm least-squares solution of ``A_x X = B``
        for ``A = [A_x | B]``; singular values of ``A_x`` below ``rcond`` times the
        largest are treated as zero."""
        Ur, S, Vt = np.linalg.svd(self.R[:nx, :nx])
        keep = S > rcond * (S[0] if S.size else 0.0)
        value: Array = Vt[keep].T @ ((Ur[:, keep].T @ self.R[:nx, nx:]) / S[keep][:, None])
        return value


def r_factor(A: ArrayLike) -> Array:
    """Upper-triangular ``R`` of ``A = Q R`` for a tall (M, p) matrix, by tiles (TSQR).

    The rows are cut into tiles ``A_1 .. A_k`` of :data:`TILE_ROWS` rows; each tile is
    factorised on its own, ``A_i = Q_i R_i``, and the stacked triangles are factorised
    again (recursively): ``[R_1; ...; R_k] = Q' R``.  Then ``A = diag(Q_i) Q' R`` with
    ``diag(Q_i) Q'`` orthonormal, so ``R^T R = A^T A``: ``R`` has the singular values,
    right singular vectors, column norms and column inner products of ``A`` (it is
    LAPACK's ``R`` up to the signs of its rows).  Cost ``O(M p^2)``, memory a few tiles.

    Returns:
        ``R`` (min(M, p), p), upper triangular.
    """
    A = np.asarray(A, dtype=float)
    M, p = A.shape
    m = _tile_rows(p)
    if p == 0:
        return np.zeros((0, 0))
    if M <= 2 * m:
        return qr_triangle(A)
    k = M // m
    parts = []
    for start in range(0, k, _TILE_GROUP):
        stop = min(k, start + _TILE_GROUP)
        tiles = A[start * m: stop * m].reshape(stop - start, m, p)
        parts.append(qr_triangle(tiles).reshape(-1, p))
    if k * m < M:
        parts.append(qr_triangle(A[k * m:]))
    return r_factor(np.concatenate(parts))


def svd_thin(A: ArrayLike) -> tuple[Array, Array, Array]:
    """Thin SVD ``A = U diag(S) V^T`` of a tall (M, p) matrix through a tiled QR.

    With the tiles of :func:`r_factor`, ``A_i = Q_i R_i`` and ``[R_1; ...; R_k] = U' S V^T``
    (itself by this function, recursively), ``U_i = Q_i U'_i``: the same factors as
    ``numpy.linalg.svd(A, full_matrices=False)`` (up to the signs of singular vector
    pairs), at the cost of one cache-resident QR per tile instead of LAPACK's tall SVD,
    which is slow when the BLAS threads compete for few cores.
    """
    A = np.asarray(A, dtype=float)
    M, p = A.shape
    if M <= 2 * p or p == 0:                    # short (e.g. a triangle): a QR first
        return np.linalg.svd(A, full_matrices=False)   # would only add work
    m = _tile_rows(p)
    if M <= 2 * m:
        Q, R = np.linalg.qr(A, mode="reduced")
        Ur, S, Vt = np.linalg.svd(R)
        return Q @ Ur, S, Vt
    k = M // m
    U = np.empty((M, p))
    Ut = U[: k * m].reshape(k, m, p)
    parts = []
    for start in range(0, k, _TILE_GROUP):
        stop = min(k, start + _TILE_GROUP)
        Q, R = np.linalg.qr(A[start * m: stop * m].reshape(stop - start, m, p))
        Ut[start:stop] = Q
        parts.append(R.reshape(-1, p))
    tail = None
    if k * m < M:
        tail, Rt = np.linalg.qr(A[k * m:])
        parts.append(Rt)
    U2, S, Vt = svd_thin(np.concatenate(parts))
    W = U2[: k * p].reshape(k, p, p)
    for start in range(0, k, _TILE_GROUP):
        stop = min(k, start + _TILE_GROUP)
        Ut[start:stop] = Ut[start:stop] @ W[start:stop]
    if tail is not None:
        U[k * m:] = tail @ U2[k * p:]
    return U, S, Vt


def singular_values(A: ArrayLike) -> Array:
    """Singular values of ``A`` (descending), via :func:`r_factor` for tall matrices."""
    A = np.asarray(A, dtype=float)
    if A.size == 0:
        return np.zeros(0)
    if A.shape[0] > A.shape[1]:
        A = r_factor(A)
    return np.asarray(np.linalg.svd(A, compute_uv=False), dtype=np.float64)


def lstsq(A: ArrayLike, b: ArrayLike, rcond: float = 1e-10) -> Array:
    """Minimum-norm least-squares solution of ``A x = b`` (singular values below
    ``rcond * S_max`` are treated as zero).

    For tall ``A`` (M > p) through the triangle of ``[A b] = Q [[R, z], [0, rho]]``
    (:func:`r_factor`): ``z = Q^T b``, ``R = U_r S V^T`` and
    ``x = V S^+ U_r^T z``, the same solution as ``V S^+ U^T b`` with ``U = Q U_r``.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    M, p = A.shape
    if M <= p or p == 0:
        U, S, Vt = svd_thin(A)
        keep = S > rcond * (S[0] if S.size else 0.0)
        value: Array = Vt[keep].T @ ((U[:, keep].T @ b)
                                     / S[keep].reshape((-1,) + (1,) * (b.ndim - 1)))
        return value
    B = b.reshape(M, -1)
    Rab = r_factor(np.concatenate([A, B], axis=1))
    Ur, S, Vt = np.linalg.svd(Rab[:p, :p])
    keep = S > rcond * S[0]
    x = Vt[keep].T @ ((Ur[:, keep].T @ Rab[:p, p:]) / S[keep][:, None])
    solution: Array = x.reshape((p,) + b.shape[1:])
    return solution
