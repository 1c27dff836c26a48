"""Numerical inverse kinematics, batched over many targets (Levenberg-Marquardt).

For each target pose ``T_t`` find joint values ``q`` that zero the pose error

    e(q) = [p_t - p(q); log(R_t R(q)^T)]      (metres; radians; base frame)

or the rows of it selected by a mask (``"position"`` keeps the first three).  All
unfinished targets take one step together per iteration (no Python loop over
targets):

    (J^T J + lambda I) dq = J^T e,        q <- P(q + dq)

with ``J`` the rows of the geometric Jacobian picked by the mask (to first order
``e(q + dq) = e(q) - J dq``) and ``P`` the projection onto the joint limits (a
revolute joint is first moved by a multiple of 2 pi when that brings it inside).
A step is kept when the cost ``0.5 |e|^2`` drops, and the damping shrinks; otherwise
it is rejected and the damping grows.  The damping is tied to the error,
``lambda = mu * 0.5 |e|^2`` with ``mu`` adapted by the accept/reject rule (Chan &
Lawrence 1988; Sugihara 2011), so the iteration turns into Gauss-Newton, with
quadratic convergence, as the error vanishes.

A target has converged when the error itself is small: ``|e_p| <= tol_position`` [m]
and ``|e_o| <= tol_orientation`` [rad] (norms of the selected position and orientation
rows), not a quadratic form of them.

Restarts.  An attempt is abandoned early when it stalls (steps keep failing, it pushes
against a joint limit, or its cost stops falling).  Restart round ``k`` (1-based) then
gives each unsolved target ``4^(k-1)`` new starts at once: the stored configurations,
drawn at random inside the joint limits, whose poses are nearest to the target (a
nearby pose reached inside the limits is usually close to a solution inside them).
Joint limits often leave a pose a single valid branch of eight (PUMA 560), so
seeding by nearby poses and trying several seeds per round matters more than the
iteration itself.  The starts (mid-range, random) and the projection
onto the limits live in :mod:`kincal.motion.joint_limits`, the seed pool in
:mod:`kincal.motion.ik_starts`.

Failures carry a reason: ``"unreachable: ..."`` when the target is provably out of
reach (farther from the first joint than the sum of the link lengths) or every
attempt stalled at a non-zero error minimum, ``"joint limits: ..."`` when the best
attempt stopped against a limit, ``"no convergence after ..."`` otherwise.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.motion.ik_problem import IKProblem
from kincal.motion.ik_starts import SeedPool
from kincal.motion.joint_limits import default_q0, limit_arrays, project_to_limits, random_q
from kincal.robots.chain import ROTATIONS, Robot
from kincal.spatial import log_so3

Array = NDArray[np.float64]

__all__ = ["IKSolution", "IKSolutions", "MASKS", "parse_mask", "reach_bound", "check_solutions",
           "solve_spd", "solve_ik",
           # re-exported from kincal.motion.joint_limits
           "default_q0", "random_q", "project_to_limits"]

MASKS = {"pose": (True,) * 6, "position": (True, True, True, False, False, False),
         "orientation": (False, False, False, True, True, True)}

_MU0 = 1e-2            # initial damping factor, lambda = mu * cost
_MU_DOWN, _MU_UP = 0.1, 10.0
_MU_MIN = 1e-6
_MU_MAX = 1e12         # steps kept failing past this: stalled
_LAMBDA_FLOOR = 1e-12  # relative to the mean diagonal of J^T J
_CLAMP_ITERS = 3       # iterations in a row pushing against a joint limit: stalled
_PATIENCE = 10         # the cost must drop 1/_PATIENCE_FACTOR-fold every _PATIENCE iterations
_PATIENCE_FACTOR = 1e-2
_SEED_POOL = 4096      # stored configurations that seed the restarts
_GROWTH = 4            # restart round k tries _GROWTH^(k-1) starts per target


@dataclass(frozen=True)
class IKSolution:
    """The inverse-kinematics result for one target.

    Attributes:
        q: joint values (n,) [rad / m]; for a failure, the best found.
        success: the error met both tolerances (and the joint limits when asked).
        iterations: Levenberg-Marquardt iterations, summed over all attempts.
        restarts: restart rounds used (0 when the first attempt converged).
        position_error: norm of the selected position rows of ``e(q)`` [m].
        orientation_error: norm of the selected orientation rows of ``e(q)`` [rad].
        reason: ``""`` on success, otherwise why it failed (one line).
    """

    q: Array
    success: bool
    iterations: int
    restarts: int
    position_error: float
    orientation_error: float
    reason: str = ""


@dataclass(frozen=True)
class IKSolutions:
    """Inverse-kinematics results for N targets (arrays indexed by target).

    Attributes:
        q: (N, n) joint values [rad / m].
        success: (N,) bool.
        iterations: (N,) iterations summed over attempts.
        restarts: (N,) restart rounds used.
        position_error: (N,) [m].
        orientation_error: (N,) [rad].
        reason: N strings, ``""`` for successes.
        mask: the 6 selected rows of the pose error ``[x y z rx ry rz]``.
        tol_position, tol_orientation: the tolerances used [m], [rad].
    """

    q: Array
    success: NDArray[np.bool_]
    iterations: NDArray[np.int64]
    restarts: NDArray[np.int64]
    position_error: Array
    orientation_error: Array
    reason: list[str]
    mask: tuple[bool, ...] = MASKS["pose"]
    tol_position: float = 1e-9
    tol_orientation: float = 1e-9

    def __len__(self) -> int:
        return int(self.q.shape[0])

    def __getitem__(self, i: int) -> IKSolution:
        return IKSolution(self.q[i].copy(), bool(self.success[i]), int(self.iterations[i]),
                          int(self.restarts[i]), float(self.position_error[i]),
                          float(self.orientation_error[i]), self.reason[i])

    def __iter__(self) -> Iterator[IKSolution]:
        return (self[i] for i in range(len(self)))

    @property
    def success_rate(self) -> float:
        """Fraction of targets solved (0..1)."""
        return float(np.mean(self.success)) if len(self) else 1.0

    def failures(self) -> NDArray[np.intp]:
        """Indices of the targets that failed."""
        return np.flatnonzero(~self.success)

    def _repr_html_(self) -> str:
        """Notebook display: the failures with their reasons, and the worst errors."""
        from kincal.io import html_table

        rows = [[int(i), self.reason[i]] for i in self.failures()[:20]]
        more = len(self.failures()) - len(rows)
        return html_table(["target", "why it failed"], rows, repr(self)
                          + (f"; {more} more failures" if more > 0 else ""))

    def __repr__(self) -> str:
        n, ok = len(self), int(np.sum(self.success))
        worst_p = float(np.max(self.position_error[self.success], initial=0.0))
        worst_o = float(np.max(self.orientation_error[self.success], initial=0.0))
        return (f"IKSolutions({ok}/{n} solved, worst error of solved {worst_p:.2e} m / "
                f"{worst_o:.2e} rad, mean iterations {np.mean(self.iterations):.1f}, "
                f"tolerances {self.tol_position:g} m / {self.tol_orientation:g} rad)")


# ---------------------------------------------------------------------------
# set-up helpers


def parse_mask(mask: str | Sequence[bool] | NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The 6 selected rows ``[x y z rx ry rz]`` of the pose error from a name or 6 bools."""
    if isinstance(mask, str):
        if mask not in MASKS:
            raise KincalError(f"unknown IK mask {mask!r}; use one of {', '.join(MASKS)} "
                              "or 6 booleans")
        return np.array(MASKS[mask])
    m = np.asarray(mask, dtype=bool).reshape(-1)
    if m.size != 6 or not m.any():
        raise KincalError("an IK mask needs 6 booleans [x, y, z, rx, ry, rz], at least one true")
    return m


def _targets(targets: ArrayLike, mask: NDArray[np.bool_]) -> tuple[Array, Array | None]:
    """Target positions (N, 3) and rotations (N, 3, 3) (None for position-only targets)."""
    t = np.asarray(targets, dtype=float)
    if t.ndim >= 2 and t.shape[-2:] == (4, 4):
        t = t.reshape(-1, 4, 4)
        p, R = t[:, :3, 3].copy(), t[:, :3, :3].copy()
    elif t.ndim in (1, 2) and t.shape[-1] == 3:
        if mask[3:].any():
            raise KincalError("position targets (N, 3) need mask='position' (or a mask "
                              "without orientation rows)")
        p, R = t.reshape(-1, 3).copy(), None
    else:
        raise KincalError(f"IK targets must be poses (N, 4, 4) or positions (N, 3); got shape "
                          f"{t.shape}")
    if not np.all(np.isfinite(p)) or (R is not None and not np.all(np.isfinite(R))):
        raise KincalError("IK targets must be finite")
    return p, R


def reach_bound(robot: Robot) -> tuple[Array, float]:
    """A point ``c`` fixed in the base and a radius ``r`` with ``|p(q) - c| <= r`` for all q.

    ``c`` is the origin of the frame where the first joint acts; ``r`` sums the
    magnitudes of every translation after it (for a prismatic joint, the largest
    ``|d + q|`` within its limits) [m].  Infinite when a prismatic joint is unlimited.
    """
    first = min(k for k, et in enumerate(robot.ets) if et.joint >= 0)
    centre = robot.frames(default_q0(robot))[0][:3, 3].copy()
    lo, hi, _ = limit_arrays(robot)
    radius = 0.0
    for et in robot.ets[first:]:
        if et.kind in ROTATIONS:
            continue
        c = robot.param_values[et.param] if et.param >= 0 else et.constant
        if et.joint >= 0:
            radius += float(np.max(np.abs(c + et.scale * np.array([lo[et.joint],
                                                                    hi[et.joint]]))))
        else:
            radius += abs(float(c))
    return centre, radius


def check_solutions(robot: Robot, targets: ArrayLike, q: ArrayLike,
                    mask: str | Sequence[bool] | NDArray[np.bool_] = "pose") -> tuple[Array, Array]:
    """Position [m] and orientation [rad] error norms of ``FK(q)`` against the targets.

    An independent check of any IK result: ``e = [p_t - p(q); log(R_t R(q)^T)]`` on
    the selected rows (orientation error 0 for position targets).
    """
    m = parse_mask(mask)
    p_t, R_t = _targets(targets, m)
    T = robot.fk(np.atleast_2d(np.asarray(q, dtype=float)))
    ep = np.linalg.norm((p_t - T[:, :3, 3])[:, m[:3]], axis=1)
    if R_t is None:
        return ep, np.zeros_like(ep)
    w = log_so3(R_t @ np.swapaxes(T[:, :3, :3], 1, 2))
    return ep, np.linalg.norm(w[:, m[3:]], axis=1)


# ---------------------------------------------------------------------------
# the batched iteration


@dataclass
class _Attempt:
    """Outcome of one batched attempt, one row per start."""

    q: Array
    converged: NDArray[np.bool_]
    stalled: NDArray[np.bool_]
    iterations: NDArray[np.int64]
    cost: Array
    ep: Array
    eo: Array


def _attempt(pb: IKProblem, idx: NDArray[np.intp], q_init: Array, max_iter: int) -> _Attempt:
    """Run Levenberg-Marquardt for targets ``idx`` (M,) from starts ``q_init`` (M, n).

    A row leaves the batch when it converges (inside the limits when they apply) or when
    it stalls: its steps keep being rejected (``mu > _MU_MAX``), it pushes against a joint
    limit ``_CLAMP_ITERS`` iterations in a row, or its cost falls less than
    ``1 / _PATIENCE_FACTOR``-fold over ``_PATIENCE`` iterations.  Every start of a round
    runs to its end, so that the caller can keep the solution nearest to ``q0``.
    """
    M, n = q_init.shape
    out = _Attempt(q_init.copy(), np.zeros(M, bool), np.zeros(M, bool), np.zeros(M, np.int64),
                   np.zeros(M), np.zeros(M), np.zeros(M))
    pos = np.arange(M)
    q = pb.project(q_init.copy())
    e, J, ep, eo = pb.evaluate(q, idx)
    cost = 0.5 * np.einsum("ij,ij->i", e, e)
    mu = np.full(M, _MU0)
    clamp = np.zeros(M, np.int64)
    ref = cost.copy()
    for it in range(max_iter + 1):
        done = (ep <= pb.tol_p) & (eo <= pb.tol_o) & pb.inside(q)
        stall = (mu > _MU_MAX) | (clamp >= _CLAMP_ITERS)
        if it and it % _PATIENCE == 0:
            stall |= cost > _PATIENCE_FACTOR * ref
            ref = cost.copy()
        finish = done | stall | (it == max_iter)
        if np.any(finish):
            f = pos[finish]
            out.q[f], out.cost[f] = q[finish], cost[finish]
            out.ep[f], out.eo[f] = ep[finish], eo[finish]
            out.converged[f] = done[finish]
            out.stalled[f] = stall[finish] & ~done[finish]
            out.iterations[f] = it
            keep = ~finish
            if not np.any(keep):
                break
            alive: tuple[Any, ...] = (pos, q, e, J, ep, eo, cost, mu, clamp, ref)
            pos, q, e, J, ep, eo, cost, mu, clamp, ref = (a[keep] for a in alive)
        # normal equations in "structure of arrays" layout (row, column, target): every
        # operation below is a vector operation over all M targets at once
        Js = np.transpose(J, (1, 2, 0))
        H = np.einsum("kim,kjm->ijm", Js, Js)
        g = np.einsum("kim,km->im", Js, np.ascontiguousarray(e.T))
        lam = mu * cost + _LAMBDA_FLOOR * (1.0 + np.einsum("iim->m", H) / n)
        for i in range(n):
            H[i, i] += lam
        q_try = q + solve_spd(H, g).T
        q_new = pb.project(q_try)
        clamp = np.where(np.any(q_new != q_try, axis=1), clamp + 1, 0)
        e_new, J_new, ep_new, eo_new = pb.evaluate(q_new, idx[pos])
        cost_new = 0.5 * np.einsum("ij,ij->i", e_new, e_new)
        ok = cost_new < cost
        if ok.all():
            q, e, J, ep, eo, cost = q_new, e_new, J_new, ep_new, eo_new, cost_new
        else:
            q[ok], e[ok], J[ok] = q_new[ok], e_new[ok], J_new[ok]
            ep[ok], eo[ok], cost[ok] = ep_new[ok], eo_new[ok], cost_new[ok]
        mu = np.where(ok, np.maximum(mu * _MU_DOWN, _MU_MIN), mu * _MU_UP)
    return out


def solve_spd(H: Array, g: Array) -> Array:
    """Solve ``H x = g`` for symmetric positive-definite H, batched in the last axis.

    ``H`` is (n, n, M) and ``g`` (n, M), one system per column m; Cholesky
    ``H = L L^T``, then forward and back substitution, each step a vector operation over
    the M systems (the Python loops run over the n <= ~7 matrix indices only).  A pivot
    that round-off makes non-positive is clamped to 1e-300 (the step is then huge and
    the Levenberg-Marquardt test rejects it).
    """
    n = H.shape[0]
    L: list[list[Array]] = [[H[0, 0]] * n for _ in range(n)]
    for j in range(n):
        s = H[j, j].copy()
        for k in range(j):
            s -= L[j][k] * L[j][k]
        d = np.sqrt(np.maximum(s, 1e-300))
        L[j][j] = d
        inv = 1.0 / d
        for i in range(j + 1, n):
            s = H[i, j].copy()
            for k in range(j):
                s -= L[i][k] * L[j][k]
            L[i][j] = s * inv
    y: list[Array] = []
    for i in range(n):
        s = g[i].copy()
        for k in range(i):
            s -= L[i][k] * y[k]
        y.append(s / L[i][i])
    x: list[Array] = [y[0]] * n
    for i in reversed(range(n)):
        s = y[i].copy()
        for k in range(i + 1, n):
            s -= L[k][i] * x[k]
        x[i] = s / L[i][i]
    return np.stack(x)


# ---------------------------------------------------------------------------
# public entry point


def solve_ik(robot: Robot, targets: ArrayLike, q0: ArrayLike | None = None,
             mask: str | Sequence[bool] | NDArray[np.bool_] = "pose", tol_position: float = 1e-9,
             tol_orientation: float = 1e-9, max_iter: int = 100, restarts: int = 5,
             rng: np.random.Generator | int | None = None,
             respect_limits: bool = True) -> IKSolutions:
    """Solve the inverse kinematics of many targets at once.

    Args:
        robot: the serial robot.
        targets: poses (N, 4, 4) or (4, 4) in the base frame [m]; or positions (N, 3)
            with ``mask="position"``.
        q0: initial guesses (N, n) or (n,) [rad / m]; default: mid-range of the limits.
        mask: ``"pose"``, ``"position"``, ``"orientation"`` or 6 booleans selecting rows
            of the pose error ``[x y z rx ry rz]`` (base-frame axes).
        tol_position: bound on ``|e_p|``, the norm of the selected position rows [m].
        tol_orientation: bound on ``|e_o|``, the norm of the selected rows of the
            rotation vector ``log(R_t R^T)`` [rad].
        max_iter: iterations per attempt.
        restarts: restart rounds for unsolved targets; round k tries ``4^(k-1)`` starts
            per target (341 in 5 rounds), from stored random configurations inside the
            limits whose poses are nearest to the target.
        rng: a ``numpy.random.Generator`` or a seed for those configurations (default:
            seed 0, so results repeat).
        respect_limits: keep every iterate inside the joint limits, so solutions are
            inside them.  When False the limits are ignored.

    Returns:
        :class:`IKSolutions`; ``solutions[i]`` is the :class:`IKSolution` of target i.
        When several starts of a round succeed, the solution nearest to ``q0`` is kept.
    """
    m = parse_mask(mask)
    p_t, R_t = _targets(targets, m)
    N, n = p_t.shape[0], robot.n
    if not (tol_position > 0 and tol_orientation > 0):
        raise KincalError("IK tolerances must be positive")
    if max_iter < 1 or restarts < 0:
        raise KincalError("IK needs max_iter >= 1 and restarts >= 0")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(
        0 if rng is None else rng)
    lo, hi, rev = limit_arrays(robot)
    if q0 is None:
        q_start = np.tile(default_q0(robot), (N, 1))
    else:
        q_start = np.asarray(q0, dtype=float)
        q_start = np.tile(q_start, (N, 1)) if q_start.ndim == 1 else q_start.copy()
        if q_start.shape != (N, n):
            raise KincalError(f"q0 must have shape ({n},) or ({N}, {n}); got {np.shape(q0)}")
    pb = IKProblem(robot, p_t, R_t, m, lo, hi, rev, respect_limits, float(tol_position),
                  float(tol_orientation))

    q = pb.project(q_start)
    success = np.zeros(N, bool)
    iters = np.zeros(N, np.int64)
    rounds = np.zeros(N, np.int64)
    best = np.full(N, np.inf)
    ep_best, eo_best = np.full(N, np.inf), np.full(N, np.inf)
    stalled_all = np.ones(N, bool)

    # Targets provably beyond reach are not attempted.
    centre, radius = reach_bound(robot)
    excess = np.linalg.norm(p_t - centre, axis=1) - radius if m[:3].all() else np.zeros(N)
    beyond = excess > tol_position
    todo = np.flatnonzero(~beyond)
    pool: SeedPool | None = None
    for rnd in range(restarts + 1):
        if todo.size == 0:
            break
        if rnd == 0:
            idx, starts = todo, q_start[todo]
        else:
            if pool is None:
                pool = SeedPool(pb, _SEED_POOL, gen, radius if np.isfinite(radius) else 1.0)
            used = (_GROWTH ** (rnd - 1) - 1) // (_GROWTH - 1)   # starts of earlier rounds
            ranks = pool.nearest(todo, used, _GROWTH ** (rnd - 1))
            idx = np.repeat(todo, ranks.shape[1])
            starts = pool.q[ranks.reshape(-1)]
        res = _attempt(pb, idx, starts, max_iter)
        _merge(res, idx, q_start, q, success, iters, best, ep_best, eo_best, stalled_all)
        rounds[todo] = rnd
        todo = todo[~success[todo]]

    reason = [""] * N
    for i in np.flatnonzero(~success):
        if beyond[i]:
            _, _, ep_b, eo_b = pb.evaluate(q[i:i + 1], np.array([i]))
            ep_best[i], eo_best[i] = ep_b[0], eo_b[0]
        reason[i] = _reason(robot, pb, q[i], bool(beyond[i]), float(excess[i]),
                            bool(stalled_all[i]), float(ep_best[i]), float(eo_best[i]),
                            max_iter, restarts)
    return IKSolutions(q, success, iters, rounds, ep_best, eo_best, reason,
                       tuple(bool(b) for b in m), float(tol_position), float(tol_orientation))


def _merge(res: _Attempt, idx: NDArray[np.intp], q_start: Array, q: Array,
           success: NDArray[np.bool_], iters: NDArray[np.int64], best: Array, ep_best: Array,
           eo_best: Array, stalled_all: NDArray[np.bool_]) -> None:
    """Fold one round (possibly several starts per target) into the per-target results.

    Per target: a converged start wins (the one nearest to its ``q0``); otherwise the
    lowest cost is kept.  Iterations add up over all starts.
    """
    np.add.at(iters, idx, res.iterations)
    stall_t = np.ones(q.shape[0], bool)
    np.logical_and.at(stall_t, idx, res.stalled)
    stalled_all &= stall_t
    # per target: converged rows first (nearest to q0 first), then the lowest cost
    metric = np.where(res.converged, np.linalg.norm(res.q - q_start[idx], axis=1), res.cost)
    order = np.lexsort((metric, ~res.converged, idx))
    first = np.ones(idx.size, bool)
    first[1:] = idx[order][1:] != idx[order][:-1]
    win = order[first]
    t = idx[win]
    conv = res.converged[win]
    better = conv | (res.cost[win] < best[t])
    t, win = t[better], win[better]
    q[t], best[t], ep_best[t], eo_best[t] = res.q[win], res.cost[win], res.ep[win], res.eo[win]
    success[t] |= res.converged[win]


def _reason(robot: Robot, pb: IKProblem, q: Array, beyond: bool, excess: float, stalled: bool,
            ep: float, eo: float, max_iter: int, restarts: int) -> str:
    """One line saying why a target failed."""
    if beyond:
        return f"unreachable: {excess:.3g} m beyond reach"
    err = f"best error {ep:.3g} m, {eo:.3g} rad"
    if pb.limits:
        names = ([f"{robot.joints[j].name} at its lower limit"
                  for j in np.flatnonzero(np.abs(q - pb.lo) <= 1e-9)]
                 + [f"{robot.joints[j].name} at its upper limit"
                    for j in np.flatnonzero(np.abs(q - pb.hi) <= 1e-9)])
        if names:
            return f"joint limits: {', '.join(names)} ({err})"
    if stalled:
        return (f"unreachable: every start stalled at a non-zero error minimum ({err}, "
                f"{restarts} restart rounds)")
    return f"no convergence after {max_iter} iterations and {restarts} restarts ({err})"
