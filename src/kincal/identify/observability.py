"""Observability indices of a calibration experiment and the design Jacobian they are read from.

A calibration experiment is a set of m poses.  Its *scaled identification Jacobian*
``A = J_w D^-1`` (whitened rows ``J_w = dr/dtheta``, r = (model - observed) / sigma,
over the identifiable base set of L parameters; ``D`` a diagonal column scaling) has
singular values ``s_1 >= ... >= s_L`` (``s_i^2`` the eigenvalues of the information
matrix ``M = A^T A``).  The five indices of the literature (larger is better):

====  ==================================  ==========================================
O1    ``(s_1 s_2 ... s_L)^(1/L) / sqrt(m)``  Borm & Menq (1991): volume of the output
                                          ellipsoid; D-optimality (``det M``)
O2    ``s_L / s_1``                       Driels & Pathre (1990): inverse condition number
O3    ``s_L``                             Nahvi, Hollerbach & Hayward (1994): minimum
                                          singular value; E-optimality
O4    ``s_L^2 / s_1``                     Nahvi & Hollerbach (1996): noise amplification index
O5    ``1 / (1/s_1 + ... + 1/s_L)``       Sun & Hollerbach (2008): related to A-optimality
====  ==================================  ==========================================

``kappa = s_1 / s_L = 1 / O2`` is the condition number the staged-selection procedure uses
(smaller is better).
References: J.-H. Borm, C.-H. Menq, IJRR 10(1) 1991; M. R. Driels, U. S. Pathre, IEEE
TRA 6(6) 1990; A. Nahvi, J. M. Hollerbach, V. Hayward, ICRA 1994; A. Nahvi, J. M.
Hollerbach, ICRA 1996; Y. Sun, J. M. Hollerbach, ICRA 2008.

**Scaling.**  ``A = J_w W`` with a fixed (design-independent) L x L matrix ``W``; the
indices depend on it (only O1's *ranking* of designs does not:
``det(A^T A) = det(J^T J) det(W)^2``).  All scalings are computed once over the N
*candidates*, so every design is measured on the same scale:

* ``"workspace"`` (default): ``W = H^(-1/2)`` with ``H = (1/N) sum_cand J_i^T J_i`` the
  information of one average candidate pose (the parameter space is whitened by
  what the workspace shows; the diagonal scalings below ignore the correlations
  between columns).  Then ``s_i^2`` is the information of the design in direction i
  counted in average poses: a random design of m poses has all ``s_i ~ sqrt(m)``
  (O1 ~ 1, kappa ~ 1 for large m), and the mean over the candidate distribution of
  the predicted position error variance is exactly
  ``sigma^2 trace(H M^-1) = sigma^2 sum_i 1/s_i^2`` (position instruments), so
  ``RMS error <= sigma sqrt(L) / s_L = sigma sqrt(L) / O3`` and ``<= sigma / O5``: the
  indices speak directly about the accuracy over the workspace.
* ``"unit"``: column scaling ``W = diag(1/D)``, ``D_j = ||J_j||_cand / sqrt(N)`` (the
  RMS of column j per candidate pose): the classical unit-norm columns.  Each
  scaled column has unit mean square per pose, so ``s_i`` grows like ``sqrt(m)``.
* ``"errors"``: ``W = diag(e_j)``, ``e_j`` the expected size (standard deviation) of
  parameter j's error (Hollerbach & Wampler 1996); ``s_i`` is the output change, in
  units of the noise, caused by a unit-size combination of expected errors.
  Defaults by role: joint offsets 0.1 deg, lengths 1 mm, angles 0.05 deg, base/tool
  frames 1 mm / 0.1 deg, instrument and marker parameters 1 mm / 0.1 deg
  (:func:`expected_errors`).

Measured on the PUMA 560 with a laser tracker (25 of 2000 random candidates, the
predicted RMS error over 300 random configurations, relative to the mean of 100 random
25-pose designs): with ``"workspace"`` scaling the designs of O1 ... O5 and kappa are
19.7, 16.9, 18.1, 16.7, 21.3 and 15.5 % below random; with ``"unit"`` scaling O2, O3,
O4 and kappa gain only 9.5, 6.6, 4.8 and 9.3 % (they buy the smallest singular value
of an arbitrarily scaled matrix at the expense of the others), and with ``"errors"``
scaling the O2 design is 23 % *worse* than random.  O1's ranking (D-optimality) does
not depend on the scaling.

**The design Jacobian** (:class:`DesignProblem`).  The design must see exactly what
the calibration will estimate: the robot's parameters *and* the measurement block's
own (the instrument frame and the marker of a laser tracker).  So a block is built
with the candidate configurations and the nominal robot's predicted observations
(noise-free), stacked with :func:`kincal.measure.base.stack`, and its whitened
Jacobian at the nominal parameters is split into one ``(r, P)`` row block per
candidate (r = 3 for one tracker marker, 6 for a pose).  The parameters designed for
are the identifiable base set of the *candidate set* chosen by
:func:`kincal.identify.identifiability.analyze` (the same rule the solver applies).
Units: SI (m, rad); whitened rows are dimensionless per parameter unit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.identify.identifiability import IdentifiabilityReport, analyze
from kincal.measure.base import MeasurementModel, StackedProblem, stack
from kincal.measure.instruments.pose import PoseMeasurement
from kincal.measure.instruments.position import PositionMeasurement
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["CRITERIA", "INDICES", "ObservabilityIndices", "observability_indices",
           "indices_from_eigenvalues", "criterion_score", "DesignProblem", "design_problem",
           "design_problem_from_blocks", "expected_errors", "scaling_matrix", "SCALINGS"]

#: Selection criteria: the five indices and the condition number (the staged-selection procedure).
CRITERIA = ("O1", "O2", "O3", "O4", "O5", "kappa")
#: Names of the reported indices.
INDICES = ("O1", "O2", "O3", "O4", "O5", "kappa")
SCALINGS = ("workspace", "unit", "errors")

#: Default instrument placement for designs (x, y, z, rz, ry, rx) [m, rad].  The
#: information about the robot does not depend on it: the instrument frame's six
#: parameters absorb any rigid placement.
DEFAULT_INSTRUMENT = (2.0, 0.0, 0.5, 0.0, 0.0, 0.0)
#: Default marker (tracker reflector) / target origin in the tool frame [m].
DEFAULT_MARKER = (0.02, 0.01, 0.05)


# --------------------------------------------------------------------------- indices
@dataclass(frozen=True)
class ObservabilityIndices:
    """O1-O5 and the condition number of one design (see the module docstring).

    Attributes:
        O1, O2, O3, O4, O5: the indices (larger is better; dimensionless for the
            ``unit`` scaling).
        kappa: condition number ``s_1 / s_L`` (smaller is better).
        singular_values: ``s_1 >= ... >= s_L`` of the scaled Jacobian.
        poses: m, the number of poses.
    """

    O1: float
    O2: float
    O3: float
    O4: float
    O5: float
    kappa: float
    singular_values: Array
    poses: int

    def as_dict(self) -> dict[str, float]:
        """``{"O1": ..., ..., "kappa": ...}``."""
        return {k: float(getattr(self, k)) for k in INDICES}

    def __getitem__(self, key: str) -> float:
        if key not in INDICES:
            raise KeyError(key)
        return float(getattr(self, key))


def _sigma_or_nan(block: MeasurementModel) -> Any:
    """The block's stated measurement sigma [SI], or NaN when it states none."""
    s = block.measurement_sigma()
    return np.nan if s is None else s


def observability_indices(singular_values: ArrayLike, poses: int) -> ObservabilityIndices:
    """The five observability indices and kappa from singular values of a scaled Jacobian.

    Args:
        singular_values: ``s_i`` of the scaled identification Jacobian (any order).
        poses: m, the number of poses (O1 is divided by ``sqrt(m)``).

    A singular design (``s_L = 0``) has O1 = O2 = O3 = O4 = O5 = 0 and kappa = inf.
    """
    s = np.sort(np.asarray(singular_values, dtype=float).ravel())[::-1]
    if s.size == 0:
        raise KincalError("no parameters: the observability indices are undefined")
    if poses < 1:
        raise KincalError("a design needs at least one pose")
    s1, sL = float(s[0]), float(s[-1])
    if sL <= 0.0:
        return ObservabilityIndices(0.0, 0.0, 0.0, 0.0, 0.0, np.inf, s, int(poses))
    o1 = float(np.exp(np.mean(np.log(s)))) / np.sqrt(poses)
    return ObservabilityIndices(o1, sL / s1, sL, sL * sL / s1, float(1.0 / np.sum(1.0 / s)),
                                s1 / sL, s, int(poses))


def indices_from_eigenvalues(eigenvalues: ArrayLike, poses: int) -> ObservabilityIndices:
    """:func:`observability_indices` from the eigenvalues ``s_i^2`` of ``M = A^T A``."""
    lam = np.clip(np.asarray(eigenvalues, dtype=float), 0.0, None)
    return observability_indices(np.sqrt(lam), poses)


def criterion_score(eigenvalues: ArrayLike, criterion: str) -> Array:
    """A larger-is-better score of each design from its information eigenvalues.

    ``eigenvalues``: (..., L) eigenvalues ``s_i^2`` of ``M = A^T A`` (any order).  For a
    fixed number of poses the score ranks designs like the criterion; it is its
    logarithm, for numerical range:

    * O1: ``sum log s_i^2`` (= ``2 L log O1 + L log m``), D-optimality;
    * O2 and kappa: ``log s_L - log s_1``;  O3: ``log s_L``;
    * O4: ``2 log s_L - log s_1``;  O5: ``-log sum 1/s_i``.

    Non-positive eigenvalues (a singular design) give ``-inf``.
    """
    lam = np.asarray(eigenvalues, dtype=float)
    lo = lam.min(axis=-1)
    hi = lam.max(axis=-1)
    ok = lo > 0.0
    safe = np.where(lam > 0.0, lam, 1.0)
    lo_s, hi_s = np.where(ok, lo, 1.0), np.where(ok, hi, 1.0)
    if criterion == "O1":
        val = np.sum(np.log(safe), axis=-1)
    elif criterion in ("O2", "kappa"):
        val = 0.5 * (np.log(lo_s) - np.log(hi_s))
    elif criterion == "O3":
        val = 0.5 * np.log(lo_s)
    elif criterion == "O4":
        val = np.log(lo_s) - 0.5 * np.log(hi_s)
    elif criterion == "O5":
        val = -np.log(np.sum(safe ** -0.5, axis=-1))
    else:
        raise KincalError(f"unknown criterion {criterion!r}; use one of {', '.join(CRITERIA)}")
    return np.where(ok, val, -np.inf)


# --------------------------------------------------------------------------- scaling
def expected_errors(names: Sequence[str], units: Sequence[str], roles: Sequence[str],
                    overrides: Mapping[str, float] | None = None) -> Array:
    """Expected error size (standard deviation) of each parameter [m or rad].

    Role-based defaults (those of :func:`kincal.measure.simulate.perturb_robot`):
    offsets 0.1 deg (1 mm if prismatic), lengths 1 mm, angles 0.05 deg, base/tool
    1 mm / 0.1 deg; measurement-block parameters 1 mm / 0.1 deg; dimensionless 1.
    ``overrides`` maps names to values.
    """
    deg = np.pi / 180.0
    out = np.empty(len(names))
    for i, (unit, role) in enumerate(zip(units, roles, strict=True)):
        if unit == "m":
            out[i] = 1e-3
        elif unit == "rad":
            out[i] = 0.05 * deg if role == "angle" else 0.1 * deg
        else:
            out[i] = 1.0
    for k, v in (overrides or {}).items():
        if k not in names:
            raise KincalError(f"expected error given for unknown parameter {k!r}")
        if not (np.isfinite(v) and v > 0):
            raise KincalError(f"expected error of {k} must be positive")
        out[list(names).index(k)] = float(v)
    return out


def scaling_matrix(J: Array, scaling: str, errors: Array | None = None) -> Array:
    """The scaling ``W`` (L, L) of candidate rows ``J`` (N, r, L); see the module docstring."""
    N = J.shape[0]
    if scaling == "workspace":
        H = np.einsum("nri,nrj->ij", J, J) / N
        lam, V = np.linalg.eigh(H)
        if lam[0] <= 1e-14 * lam[-1]:
            raise KincalError("the candidate poses do not identify the base set (singular "
                              "information); use more or more varied candidates")
        out: Array = (V / np.sqrt(lam)) @ V.T
        return out
    if scaling == "unit":
        return np.diag(1.0 / np.sqrt(np.einsum("nrj,nrj->j", J, J) / N))
    if scaling == "errors":
        if errors is None:
            raise KincalError("the 'errors' scaling needs the expected parameter errors")
        return np.diag(np.asarray(errors, dtype=float))
    raise KincalError(f"unknown scaling {scaling!r}; use one of {', '.join(SCALINGS)}")


# --------------------------------------------------------------------------- the problem
@dataclass
class DesignProblem:
    """Candidate poses and their scaled identification rows over the base set.

    Attributes:
        robot: the nominal robot.
        q: (N, n) candidate configurations [rad / m].
        J: (N, r, L) whitened Jacobian rows of every candidate over the base set
            (dimensionless per parameter unit; zero-padded rows when candidates
            contribute different numbers of residuals).
        W: (L, L) the scaling (``A = J W``; diagonal except for ``"workspace"``).
        names, units: the L base-set parameters designed for.
        scaling: ``"workspace"``, ``"unit"`` or ``"errors"``.
        report: the identifiability analysis of the candidate set (all parameters).
        problem: the stacked problem of the candidate blocks.
        theta: nominal values of every parameter of ``problem`` [SI].
        sigma: stated position noise used to whiten [m] (orientation for a pose block
            in ``sigma_orientation``).
        rows_for: builds ``(E, r, P_all)`` whitened rows for new configurations (None
            when the blocks cannot be rebuilt, e.g. instrument-simulated contacts).
        kind: ``"position"``, ``"pose"`` or ``"blocks"``.
    """

    robot: Robot
    q: Array
    J: Array
    W: Array
    names: list[str]
    units: list[str]
    scaling: str
    report: IdentifiabilityReport
    problem: StackedProblem
    theta: Array
    sigma: float
    rows_for: Callable[[Array], Array] | None = None
    kind: str = "blocks"
    sigma_orientation: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def A(self) -> Array:
        """(N, r, L) scaled rows ``J W``."""
        return self.J @ self.W

    @property
    def num_candidates(self) -> int:
        return int(self.q.shape[0])

    @property
    def num_params(self) -> int:
        return len(self.names)

    @property
    def base_index(self) -> NDArray[np.intp]:
        """Indices of the base-set parameters in ``problem.names``."""
        return np.array([self.problem.names.index(n) for n in self.names], dtype=np.intp)

    def information(self, selected: ArrayLike) -> Array:
        """Scaled information ``M = sum_i A_i^T A_i`` of candidates ``selected``: (L, L)."""
        A = self.A[np.asarray(selected, dtype=np.intp)]
        out: Array = np.einsum("nri,nrj->ij", A, A)
        return out

    def indices(self, selected: ArrayLike) -> ObservabilityIndices:
        """O1-O5 and kappa of the design made of candidates ``selected``."""
        sel = np.asarray(selected, dtype=np.intp)
        lam = np.linalg.eigvalsh(self.information(sel))
        return indices_from_eigenvalues(lam, len(sel))

    def base_rows(self, q: ArrayLike) -> Array:
        """Whitened rows ``(E, r, L)`` over the base set at new configurations ``q``."""
        if self.rows_for is None:
            raise KincalError("this design's measurements cannot be rebuilt at other "
                              "configurations; give the configurations as candidates")
        R = self.rows_for(np.atleast_2d(np.asarray(q, dtype=float)))
        return R[:, :, self.base_index]

    def __repr__(self) -> str:
        return (f"DesignProblem({self.robot.name!r}, {self.kind}, candidates="
                f"{self.num_candidates}, rows/pose={self.J.shape[1]}, base set="
                f"{self.num_params} of {len(self.problem.names)}, scaling={self.scaling!r})")


def _group_rows(J: Array, owner: NDArray[np.intp], N: int) -> Array:
    """Split residual rows (M, P) by candidate ``owner`` into a zero-padded (N, r, P)."""
    counts = np.bincount(owner, minlength=N)
    r = int(counts.max()) if N else 0
    order = np.argsort(owner, kind="stable")
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(owner)) - np.repeat(start, counts)
    out = np.zeros((N, r, J.shape[1]))
    out[owner[order], slot] = J[order]
    return out


def design_problem_from_blocks(robot: Robot, blocks: Sequence[MeasurementModel],
                              extras: ArrayLike | None = None, *, scaling: str = "workspace",
                              expected: Mapping[str, float] | None = None,
                              free: Sequence[str] | str | None = None,
                              fixed: Sequence[str] | str = (), tol: float | None = None,
                              rows_for: Callable[[Array], Array] | None = None,
                              kind: str = "blocks", sigma: float | None = None
                              ) -> DesignProblem:
    """A :class:`DesignProblem` from measurement blocks holding nominal observations.

    The candidates are the distinct configurations of the blocks (rows with equal
    joint values form one candidate, e.g. all points seen by a camera at one pose).

    Args:
        robot: the nominal robot.
        blocks: measurement blocks whose observations are the nominal robot's
            predictions (so their closed-form initial guess is exact).
        extras: the blocks' own parameter values (concatenated, :func:`stack` order);
            default their closed-form initial guess.
        scaling: ``"workspace"``, ``"unit"`` or ``"errors"`` (module docstring).
        expected: ``{name: expected error}`` overrides for ``"errors"``.
        free, fixed: names / patterns of the candidate parameters, as in
            :func:`kincal.identify.solver.calibrate` (default: all).
        tol: identifiability tolerance of :func:`analyze`.
        rows_for: rebuilds whitened rows ``(E, r, P)`` at new configurations (used by
            :func:`design_problem`); None when the blocks cannot be rebuilt.
        kind: ``"position"``, ``"pose"`` or ``"blocks"`` (how predictions are made).
        sigma: the stated position noise [m]; default the RMS of the blocks' sigmas.
    """
    from kincal.identify.names import match_names

    if scaling not in SCALINGS:
        raise KincalError(f"unknown scaling {scaling!r}; use one of {', '.join(SCALINGS)}")
    prob, theta = stack(robot, list(blocks))
    if extras is not None:
        theta[prob.num_robot:] = np.asarray(extras, dtype=float).reshape(-1)
    _, Jfull = prob.residuals_and_jacobian(theta)
    # candidate of every residual: distinct configurations
    bi, rows = prob.owners()
    qs = np.concatenate([b.q for b in blocks])
    offsets = np.concatenate([[0], np.cumsum([len(b.q) for b in blocks])[:-1]])
    q_of_res = qs[offsets[bi] + rows]
    uq, first, inv = np.unique(q_of_res, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)                       # keep the order of first appearance
    rank = np.empty(len(order), dtype=np.intp)
    rank[order] = np.arange(len(order))
    q, owner = uq[order], rank[inv.reshape(-1)]
    names = prob.names
    cand = list(range(len(names))) if free is None else match_names(names, free)
    drop = set(match_names(names, fixed)) if fixed else set()
    cand = [i for i in cand if i not in drop]
    report = analyze(Jfull[:, cand], [names[i] for i in cand], tol=tol,
                     roles=[prob.roles[i] for i in cand])
    if report.rank == 0:
        raise KincalError("the candidate poses identify no parameter")
    base = [names.index(n) for n in report.identifiable]
    base.sort()
    Jg = _group_rows(Jfull[:, base], owner, len(q))
    bnames = [names[i] for i in base]
    bunits = [prob.units[i] for i in base]
    W = scaling_matrix(Jg, scaling, expected_errors(bnames, bunits,
                                                    [prob.roles[i] for i in base], expected))
    if sigma is None:
        s = [np.sqrt(np.mean(np.asarray(_sigma_or_nan(b)) ** 2)) for b in blocks]
        sigma = float(np.nanmean(s)) if np.any(np.isfinite(s)) else float("nan")
    return DesignProblem(robot, q, Jg, W, bnames, bunits, scaling, report, prob, theta,
                         float(sigma), rows_for, kind)


def _nominal_block(robot: Robot, q: Array, kind: str, extra: Array, noise: float,
                   orientation_noise: float, name: str, K: int) -> MeasurementModel:
    """A block at ``q`` whose observations are the nominal robot's predictions."""
    if kind == "position":
        probe = PositionMeasurement(q, np.zeros((len(q), K, 3)) if K > 1
                                    else np.zeros((len(q), 3)), noise, name, K)
        y = probe.predict(robot, extra)
        return PositionMeasurement(q, y if K > 1 else y[:, 0], noise, name, K)
    pose_probe = PoseMeasurement(q, np.tile(np.eye(4), (len(q), 1, 1)), noise,
                                 orientation_noise, name)
    return PoseMeasurement(q, pose_probe.predict(robot, extra), noise, orientation_noise, name)


def design_problem(robot: Robot, q: ArrayLike, instrument: str = "position",
                   noise: float = 1e-5, *, orientation_noise: float = 1e-5,
                   instrument_frame: ArrayLike = DEFAULT_INSTRUMENT,
                   marker: ArrayLike = DEFAULT_MARKER, target_rpy: ArrayLike = (0.0, 0.0, 0.0),
                   name: str = "tracker", scaling: str = "workspace",
                   expected: Mapping[str, float] | None = None,
                   free: Sequence[str] | str | None = None, fixed: Sequence[str] | str = (),
                   tol: float | None = None) -> DesignProblem:
    """The design problem of a laser tracker (``position``) or 6-DOF tracker (``pose``).

    Builds a :class:`~kincal.measure.instruments.position.PositionMeasurement` (or
    ``PoseMeasurement``) with the candidate configurations ``q`` and the nominal
    robot's predicted observations, so the design sees the instrument frame and the
    marker exactly as the calibration will estimate them.

    Args:
        robot: nominal robot.
        q: (N, n) candidate configurations [rad / m].
        instrument: ``"position"`` or ``"pose"``.
        noise: standard deviation of each measured coordinate [m].
        orientation_noise: pose only: of each rotation-vector component [rad].
        instrument_frame: ``(x, y, z, rz, ry, rx)`` of the instrument in the base
            frame [m, rad] (does not change what the poses tell about the robot).
        marker: (3,) or (K, 3) marker(s) in the tool frame [m] (pose: target origin).
        target_rpy: pose only: target orientation (roll, pitch, yaw) [rad].
        name: block name (parameter prefix).
        scaling, expected, free, fixed, tol: see :func:`design_problem_from_blocks`.
    """
    if instrument not in ("position", "pose"):
        raise KincalError(f"instrument {instrument!r}: designs at given configurations "
                          "support 'position' and 'pose'; for other instruments use "
                          "candidates from the instrument's simulator")
    if not (np.isfinite(noise) and noise > 0):
        raise KincalError("the instrument noise must be positive")
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.ndim != 2 or q.shape[1] != robot.n or len(q) == 0:
        raise KincalError(f"candidates must be (N, {robot.n}) configurations, got {q.shape}")
    frame = np.asarray(instrument_frame, dtype=float).reshape(6)
    m = np.asarray(marker, dtype=float).reshape(-1, 3)
    if instrument == "position":
        K = m.shape[0]
        extra = np.concatenate([frame, m.reshape(-1)])
    else:
        K = 1
        extra = np.concatenate([frame, m[0], np.asarray(target_rpy, dtype=float)[::-1]])

    def rows_for(qq: Array) -> Array:
        b = _nominal_block(robot, qq, instrument, extra, noise, orientation_noise, name, K)
        _, Jr, Je = b.evaluate(robot, extra, jacobian=True)
        R = np.concatenate([Jr, Je], axis=1)
        return R.reshape(len(qq), -1, R.shape[1])

    block = _nominal_block(robot, q, instrument, extra, noise, orientation_noise, name, K)
    dp = design_problem_from_blocks(robot, [block], extra, scaling=scaling, expected=expected,
                                    free=free, fixed=fixed, tol=tol, rows_for=rows_for,
                                    kind=instrument, sigma=noise)
    if instrument == "pose":
        dp.sigma_orientation = float(orientation_noise)
    dp.meta.update({"instrument_frame": np.asarray(instrument_frame, dtype=float).tolist(),
                    "marker": m.tolist(), "name": name})
    return dp
