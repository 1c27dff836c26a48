"""Which parameters can the measurements identify?  Zero columns, dependent columns, base set.

Given the whitened identification Jacobian ``J`` (M, P) of a calibration problem
(``dr / dtheta``, columns named), :func:`analyze` answers, by name:

* **unobservable**: columns that are zero: changing the parameter does not change
  any measurement (``||J_j|| <= zero_tol * max_k ||J_k||``, ``zero_tol = 1e-9``);
* **identifiable**: a *base set*, a largest set of columns that are numerically
  independent, chosen greedily in a stable priority order;
* **dependent**: every other column, with the base parameters whose combination it
  duplicates: ``J_j ~= sum_b c_jb J_b``, i.e. a change of ``theta_j`` moves the
  measurements exactly as the change ``c_jb`` of each ``theta_b``.  The data cannot
  tell them apart; the solver holds the dependent ones at their initial value and
  the base parameters absorb their effect.

Algorithm.  A tall ``J`` is first compressed to the triangle ``R`` of ``J = Q R``
(tiled QR, :func:`kincal.measure.base.r_factor`; ``O(M P^2)`` time, ``O(P^2)`` memory).
Every quantity below (column norms, projections of one column on others, singular
values) depends on ``J`` only through ``J^T J = R^T R``, so the analysis then runs on
the (P, P) triangle and costs nothing in M; passing the triangle itself (e.g. ``R`` of
:meth:`kincal.measure.base.StackedProblem.compressed`) gives the same report.

Columns are scaled to unit norm (``scale=True``; otherwise divided by the largest
column norm), which makes the test independent of units (m vs rad) and of
the noise level.  Candidates are visited in priority order; a column joins the base
set when the smallest singular value of the selected scaled columns stays above
``tol`` (default ``1e-8``; a parameter whose best-separated direction is weaker than
that is, for every practical noise level, not identifiable: its standard error would
be ``> 1e8`` times that of a unit column).  Because each accepted column keeps
``sigma_min >= tol``, the scaled condition number of the base set is at most
``sqrt(rank) / tol``.

Priority (lower first; ties keep the given order):

0. measurement-block parameters: instrument frames, markers, targets, artifact
   geometry (roles other than the robot's);
1. robot joint-chain parameters (roles ``offset``, ``length``, ``angle``) in chain order;
2. the robot's ``base.*`` frame;
3. the robot's ``tool.*`` frame;
4. non-geometric terms (roles ``compliance``, ``hysteresis``, ``deflection``): an
   effect the geometry can explain is given to the geometry (a joint always
   approached from the same side has a hysteresis that is its offset).

So an unknown tracker frame takes the place of the robot's base frame and of the
first joint's offset (the absolute zero of joint 1 cannot be seen from a tracker
placed at an unknown angle), a marker takes the place of the tool frame and of the
last link's constants (a calibration never moves the user's flange/TCP definition
to the marker), and in the middle of the chain the earlier link keeps the parameter
(``d[2]`` over ``d[3]`` for parallel axes 2-3).  Pass ``priority`` to override.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.measure.base import r_factor, singular_values

Array = NDArray[np.float64]

#: Default tolerance on the smallest singular value of the scaled base set.
DEFAULT_TOL = 1e-8
#: A column whose norm is below this fraction of the largest is "unobservable".
ZERO_TOL = 1e-9
#: Coefficients below this (relative to the largest) are not listed as dependencies.
COEF_TOL = 1e-6

ROBOT_CHAIN_ROLES = ("offset", "length", "angle")
#: Roles of non-geometric block parameters (joint deflection models): kept last.
NON_GEOMETRIC_ROLES = ("compliance", "hysteresis", "deflection")


@dataclass
class IdentifiabilityReport:
    """What the data can and cannot identify, by parameter name.

    Attributes:
        names: all candidate names, in the order of ``J``'s columns.
        identifiable: the base set (names), in priority order.
        unobservable: names whose column is zero.
        dependent: name -> base parameters it cannot be told apart from.
        combinations: name -> {base name: c}: a change ``d theta_name`` moves the
            measurements as the changes ``c * d theta_name`` of those base parameters
            (in the parameters' own units).
        residual: name -> how far (sin of the angle, 0..1) its column is from the
            span of the base set (0 for an exact duplicate).
        rank: number of identifiable parameters.
        cond_unscaled: condition number of the base set's columns of ``J``.
        cond_scaled: the same with unit-norm columns (the meaningful one).
        singular_values: singular values of the full scaled ``J`` (descending).
        column_scale: norm of each column of ``J`` (units: whitened residual per m or rad).
        tol: the tolerance used.
    """

    names: tuple[str, ...]
    identifiable: list[str]
    unobservable: list[str]
    dependent: dict[str, list[str]]
    combinations: dict[str, dict[str, float]]
    residual: dict[str, float]
    rank: int
    cond_unscaled: float
    cond_scaled: float
    singular_values: Array
    column_scale: Array
    tol: float
    weak: dict[str, float] = field(default_factory=dict)

    @property
    def not_identifiable(self) -> list[str]:
        """Unobservable and dependent names, in column order."""
        ident = set(self.identifiable)
        return [n for n in self.names if n not in ident]

    def describe(self) -> list[str]:
        """One sentence per non-identifiable parameter, naming the others involved."""
        out = []
        for n in self.names:
            if n in self.unobservable:
                out.append(f"{n} does not affect these measurements (its column is zero); "
                           "it is held at its initial value.")
            elif n in self.dependent:
                comb = self.combinations.get(n, {})
                parts = [f"{c:+.4g}*{b}" for b, c in comb.items()]
                rel = self.residual.get(n, 0.0)
                how = ("cannot be told apart from" if rel < 1e-6
                       else f"is nearly indistinguishable (residual {rel:.1e}) from")
                if parts:
                    out.append(f"{n} {how} {', '.join(self.dependent[n])}: changing it moves "
                               f"the measurements like {' '.join(parts)}; it is held at its "
                               "initial value.")
                else:
                    out.append(f"{n} is not identifiable from these measurements; it is held "
                               "at its initial value.")
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {
            "rank": int(self.rank),
            "identifiable": list(self.identifiable),
            "unobservable": list(self.unobservable),
            "dependent": {k: list(v) for k, v in self.dependent.items()},
            "combinations": {k: {b: float(c) for b, c in v.items()}
                             for k, v in self.combinations.items()},
            "cond_unscaled": _finite(self.cond_unscaled),
            "cond_scaled": _finite(self.cond_scaled),
            "singular_values": [float(s) for s in self.singular_values],
            "tol": float(self.tol),
            "sentences": self.describe(),
        }

    def __repr__(self) -> str:
        return (f"IdentifiabilityReport(rank={self.rank} of {len(self.names)}, "
                f"unobservable={len(self.unobservable)}, dependent={len(self.dependent)}, "
                f"cond_scaled={self.cond_scaled:.3g})")


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def default_priority(names: Sequence[str], roles: Sequence[str] | None = None) -> Array:
    """Priority class per name (lower is kept first); see the module docstring.

    Without ``roles``, names starting with ``base.`` / ``tool.`` get classes 2 / 3 and
    every other name class 1.
    """
    pri = np.ones(len(names))
    for i, n in enumerate(names):
        role = roles[i] if roles is not None else None
        if role == "base" or (role is None and n.startswith("base.")):
            pri[i] = 2
        elif role == "tool" or (role is None and n.startswith("tool.")):
            pri[i] = 3
        elif role in NON_GEOMETRIC_ROLES:
            pri[i] = 4
        elif role is not None and role not in ROBOT_CHAIN_ROLES:
            pri[i] = 0
    return pri


def _sigma_min(R: Array) -> float:
    return float(np.linalg.svd(R, compute_uv=False)[-1]) if R.size else np.inf


def _greedy_base(Js: Array, zero: NDArray[np.bool_], order: Sequence[int], tol: float
                 ) -> tuple[list[int], Array, Array]:
    """The columns of ``Js`` kept in ``order``: each one whose distance from the span of
    those kept before it exceeds ``tol`` while the kept set's smallest singular value
    stays above ``tol``.  Returns ``(chosen, Q, Rf)`` with ``Js[:, chosen] = Q Rf``
    (``Q`` orthonormal columns, ``Rf`` upper triangular).

    An incrementally updated QR factor of the selected columns (rows of ``Qt``: the
    orthonormal basis so far; ``Rf`` its triangle).  ``sigma_min(Rf) >= 1 / ||Rf^-1||_F``:
    while that bound (kept up to date with the inverse of the growing triangle) is well
    above ``tol``, no SVD is needed to accept a column.
    """
    m, P = Js.shape
    chosen: list[int] = []
    Qt = np.zeros((P, m))
    Rfull = np.zeros((P, P))
    Ifull = np.zeros((P, P))                    # Rf^-1
    inv_f2 = 0.0                                # ||Rf^-1||_F^2
    bound = 0.25 / tol**2
    for i in order:
        if zero[i]:
            continue
        k = len(chosen)
        c = Js[:, i]
        Q = Qt[:k]
        proj = Q @ c
        res = c - proj @ Q
        proj2 = Q @ res                         # re-orthogonalise once
        res -= proj2 @ Q
        proj += proj2
        rho = math.sqrt(float(res @ res))
        if rho <= tol:
            continue
        # [[Rf, proj], [0, rho]]^-1 = [[Rf^-1, -Rf^-1 proj / rho], [0, 1 / rho]]
        u = Ifull[:k, :k] @ proj / rho
        f2 = inv_f2 + float(u @ u) + 1.0 / rho**2
        Rfull[:k, k] = proj
        Rfull[k, k] = rho
        if not f2 < bound and _sigma_min(Rfull[:k + 1, :k + 1]) <= tol:
            Rfull[:k + 1, k] = 0.0
            continue
        chosen.append(i)
        Qt[k] = res / rho
        Ifull[:k, k] = -u
        Ifull[k, k] = 1.0 / rho
        inv_f2 = f2
    r = len(chosen)
    return chosen, Qt[:r].T, Rfull[:r, :r]


def _dependencies(Js: Array, names: Sequence[str], chosen: list[int], others: list[int],
                  Q: Array, Rinv: Array, col: Array
                  ) -> tuple[dict[str, list[str]], dict[str, dict[str, float]],
                             dict[str, float]]:
    """``(dependent, combinations, residual)`` of the columns ``others`` on the base
    columns ``chosen`` (``Js[:, chosen] = Q Rf``, ``Rinv = Rf^-1``).

    Least squares ``B x ~ c`` (``B = Js[:, chosen]``) by ``x = Rf^-1 Q^T c`` for every
    other column ``c`` at once; the coefficients in parameter units are
    ``d theta_i ~ sum_b x_b col_i / col_b d theta_b`` (``col``: the divisor of each
    column of ``Js``), those below ``COEF_TOL`` of the largest are left out; the residual
    is ``|c - B x| / |c|``.
    """
    dependent: dict[str, list[str]] = {}
    combinations: dict[str, dict[str, float]] = {}
    residual: dict[str, float] = {}
    if not chosen:
        for i in others:
            dependent[names[i]], combinations[names[i]], residual[names[i]] = [], {}, 1.0
        return dependent, combinations, residual
    if not others:
        return dependent, combinations, residual
    C = Js[:, others]
    X = Rinv @ (Q.T @ C)
    rels = np.linalg.norm(C - Js[:, chosen] @ X, axis=0) / np.maximum(
        np.linalg.norm(C, axis=0), 1e-300)
    absX = np.abs(X)
    kept = (absX > COEF_TOL * np.maximum(absX.max(axis=0), 1e-300)).T.tolist()
    coef = (X * col[others] / col[chosen][:, None]).T.tolist()
    base_names = [names[j] for j in chosen]
    for n_i, i in enumerate(others):
        comb = {b: c for b, c, k in zip(base_names, coef[n_i], kept[n_i], strict=True) if k}
        dependent[names[i]] = list(comb)
        combinations[names[i]] = comb
        residual[names[i]] = float(rels[n_i])
    return dependent, combinations, residual


def analyze(J: ArrayLike, names: Sequence[str], tol: float | None = None, scale: bool = True,
            priority: ArrayLike | None = None, roles: Sequence[str] | None = None
            ) -> IdentifiabilityReport:
    """Identifiability of the parameters ``names`` from the Jacobian ``J`` (M, P).

    Args:
        J: whitened identification Jacobian (rows: measurements; columns: ``names``),
            or any matrix with the same ``J^T J`` such as its QR triangle ``R``.
        names: one name per column.
        tol: smallest admissible singular value of the scaled base set (default 1e-8).
        scale: scale columns to unit norm first (recommended; otherwise all columns
            are divided by the largest norm).
        priority: optional class per column (lower kept first); default from
            ``roles`` / names (:func:`default_priority`).
        roles: parameter roles (``offset`` ... or block roles) for the default priority.

    Returns:
        An :class:`IdentifiabilityReport`.
    """
    J = np.asarray(J, dtype=float)
    names = tuple(names)
    if J.ndim != 2 or J.shape[1] != len(names):
        raise ValueError(f"J has shape {J.shape} but {len(names)} names were given")
    tol = DEFAULT_TOL if tol is None else float(tol)
    P = len(names)
    if J.shape[0] > P:
        J = r_factor(J)                         # same J^T J, (P, P)
    norms = np.linalg.norm(J, axis=0)
    big = float(norms.max()) if P else 0.0
    zero = norms <= ZERO_TOL * big if big > 0 else np.ones(P, dtype=bool)
    # the divisor of each column: its norm, or (unscaled) the largest norm for all
    col = norms if scale else np.full(P, big if big > 0 else 1.0)
    Js = J / np.where(zero, 1.0, col) if scale else J / col
    Js[:, zero] = 0.0
    sv = singular_values(Js) if P and J.shape[0] else np.zeros(0)
    pri = default_priority(names, roles) if priority is None else np.asarray(priority, float)
    order = sorted(range(P), key=lambda i: (pri[i], i))
    chosen, Q, Rf = _greedy_base(Js, zero, order, tol)
    r = len(chosen)
    chosen_set = set(chosen)
    Rinv = (np.asarray(np.linalg.solve(Rf, np.eye(r)), dtype=np.float64) if chosen
            else np.zeros((0, 0)))
    others = [i for i in range(P) if not zero[i] and i not in chosen_set]
    dependent, combinations, residual = _dependencies(Js, names, chosen, others, Q, Rinv, col)
    if chosen:
        # Js[:, chosen] = Q Rf (Q orthonormal): Rf has the singular values of the scaled
        # base columns, and Rf diag(column divisors) those of the unscaled ones
        sB = sv if r == P else np.linalg.svd(Rf, compute_uv=False)
        sU = np.linalg.svd(Rf * col[chosen], compute_uv=False)
        cond_s = float(sB[0] / sB[-1]) if sB[-1] > 0 else np.inf
        cond_u = float(sU[0] / sU[-1]) if sU[-1] > 0 else np.inf
        # variance inflation of each base parameter (scaled): diag((B^T B)^-1)
        vif = np.sum(Rinv**2, axis=1)
        weak = {names[chosen[j]]: float(vif[j]) for j in range(len(chosen)) if vif[j] > 1e6}
    else:
        cond_s = cond_u = np.inf
        weak = {}
    identifiable = [names[i] for i in chosen]
    unobservable = [names[i] for i in range(P) if zero[i]]
    return IdentifiabilityReport(names, identifiable, unobservable, dependent, combinations,
                                 residual, r, cond_u, cond_s, sv, norms, tol, weak)
