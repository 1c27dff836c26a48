"""Calibration experiment design: choose m poses out of N candidates.

Works on a :class:`~kincal.identify.observability.DesignProblem`: every candidate i
contributes the scaled rows ``A_i`` (r x L) and a design S the information
``M_S = sum_{i in S} A_i^T A_i`` whose eigenvalues are the squared singular values
of the stacked scaled Jacobian, from which the indices O1-O5 and kappa follow
(:mod:`kincal.identify.observability`).  Criteria and algorithms
(:func:`select_poses`):

* ``"kappa"`` - **greedy addition by the condition number** (the
  staged-selection procedure's rule): at every step the candidate whose addition gives the
  smallest ``kappa(M + A_i^T A_i)``; no exchange.
* ``"O1"`` - D-optimality, ``max det M``: greedy addition by the matrix determinant
  lemma ``det(M + A_i^T A_i) = det M det(I_r + A_i M^-1 A_i^T)`` (one Cholesky factor
  per step, an r x r determinant per candidate), then **DETMAX** (Mitchell 1974,
  Technometrics 16(2)): excursions that add the k best candidates and remove the k
  least useful points (``det(M - A_j^T A_j) = det M det(I_r - A_j M^-1 A_j^T)``),
  accepted when ``det M`` grows; k = 1, 2, ... up to ``max_excursion``, back to 1
  after every success.
* ``"O2"``, ``"O3"``, ``"O4"``, ``"O5"`` - greedy addition by the index, then a
  **Fedorov exchange** (V. V. Fedorov, Theory of Optimal Experiments, 1972): each
  selected pose in turn is swapped for the best candidate if the index improves,
  passes repeated until none does (the exchange optimisation of Sun & Hollerbach
  2008).  The indices built on ``s_L`` are not smooth (the smallest singular values
  cluster at the optimum) and one exchange run stops in a local optimum, so the
  exchange runs from two starts - the index's greedy design and the D-optimal greedy
  design - and keeps the better.

The first poses, while ``M`` is still singular (every index but O1 is 0 there), are
chosen by the determinant lemma with a tiny ridge ``M + epsilon I``, epsilon =
1e-9 times the mean diagonal of a candidate's information, which only breaks ties
between directions not yet seen.  The eigenvalue criteria (O2-O5, kappa) of
``M + A_i^T A_i`` are evaluated exactly (a batched symmetric eigen-solve) for a
shortlist of candidates ranked by cheap surrogates.  In the eigenbasis
``M = V diag(lambda) V^T``, with ``B_i = A_i V``: (1) all candidates are screened by
the first-order spectrum ``lambda_j + ||B_i e_j||^2``; (2) the best ``4 K`` by the
compression of the update onto the 6 weakest and the strongest eigen-directions
(``diag(lambda_W) + B_W^T B_W``: exact eigenvalues of a 7 x 7 matrix, first order
elsewhere); (3) the best ``K`` (``shortlist``) exactly.  Only those K pay an L x L
eigen-solve.

Constraints: candidates are configurations inside the joint limits (see the
candidate helpers); ``min_distance`` > 0 keeps every pair of selected configurations
at least that far apart in joint space (Euclidean norm of ``q_a - q_b`` in SI:
rad for revolute, m for prismatic joints).  A pose is never selected twice.

Candidate sets: :func:`random_candidates` (uniform within the joint limits),
:func:`read_configurations` (a user CSV, joint columns with units, rows outside the
limits dropped) and :func:`instrument_candidates` (configurations the instrument's
own simulator can measure, e.g. a camera's field of view).  :func:`write_poses`
writes the selected poses as a CSV the measurement-file reader reads back.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import solve_triangular

from kincal.errors import KincalError
from kincal.identify.observability import (
    CRITERIA,
    DesignProblem,
    ObservabilityIndices,
    criterion_score,
    design_problem,
    design_problem_from_blocks,
)
from kincal.robots.chain import Robot

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], Any]

__all__ = ["PoseDesign", "select_poses", "random_design", "random_candidates",
           "read_configurations", "instrument_candidates", "within_limits", "write_poses",
           "joint_distance"]

#: Relative ridge used while the information matrix is singular.
RIDGE = 1e-9
#: Improvement (on the log-scale score) needed to accept an exchange / excursion.
IMPROVE = 1e-9


# --------------------------------------------------------------------------- result
@dataclass
class PoseDesign:
    """Poses selected from a candidate set.

    Attributes:
        problem: the design problem (candidates, base set, scaling).
        selected: candidate indices of the chosen poses.
        criterion: ``O1`` ... ``O5``, ``kappa`` or ``random``.
        method: the algorithm, e.g. ``"greedy + DETMAX"``.
        indices: O1-O5 and kappa of the design.
        history: the criterion's score (:func:`criterion_score`) after every greedy
            addition and accepted exchange / excursion.
        exchanges: number of accepted exchanges or excursions.
        min_distance: the joint-space distance enforced [rad / m].
    """

    problem: DesignProblem
    selected: NDArray[np.intp]
    criterion: str
    method: str
    indices: ObservabilityIndices
    history: list[float] = field(default_factory=list)
    exchanges: int = 0
    min_distance: float = 0.0

    @property
    def q(self) -> Array:
        """(m, n) the selected configurations [rad / m]."""
        return self.problem.q[self.selected]

    @property
    def poses(self) -> int:
        return int(len(self.selected))

    def __repr__(self) -> str:
        ind = self.indices
        return (f"PoseDesign({self.criterion}, {self.method}, poses={self.poses} of "
                f"{self.problem.num_candidates}, O1={ind.O1:.4g}, kappa={ind.kappa:.4g}, "
                f"O3={ind.O3:.4g})")


# --------------------------------------------------------------------------- constraints
def joint_distance(q: Array, qj: Array) -> Array:
    """Euclidean joint-space distance ``||q_i - q_j||`` of every row of ``q`` to ``qj``."""
    out: Array = np.linalg.norm(q - qj, axis=1)
    return out


class _Pool:
    """Which candidates may still be added (not chosen, far enough from the chosen)."""

    def __init__(self, q: Array, min_distance: float) -> None:
        self.q = q
        self.d = float(min_distance)
        self.chosen = np.zeros(len(q), dtype=bool)
        self.blocked = np.zeros(len(q), dtype=np.intp)

    def near(self, j: int) -> NDArray[np.bool_]:
        return joint_distance(self.q, self.q[j]) < self.d

    def add(self, j: int) -> None:
        self.chosen[j] = True
        if self.d > 0:
            self.blocked += self.near(j)

    def remove(self, j: int) -> None:
        self.chosen[j] = False
        if self.d > 0:
            self.blocked -= self.near(j)

    def reset(self, selected: Sequence[int]) -> None:
        self.chosen[:] = False
        self.blocked[:] = 0
        for j in selected:
            self.add(int(j))

    def available(self, without: int | None = None) -> NDArray[np.intp]:
        """Indices that may be added (to the design minus ``without``)."""
        free = ~self.chosen
        if self.d > 0:
            blocked = self.blocked - (self.near(without) if without is not None else 0)
            free &= blocked == 0
        return np.flatnonzero(free)


# --------------------------------------------------------------------------- linear algebra
def _info(A: Array, idx: Sequence[int] | NDArray[np.intp]) -> Array:
    Ai = A[np.asarray(idx, dtype=np.intp)]
    out: Array = np.einsum("nri,nrj->ij", Ai, Ai)
    return out


def _lemma_terms(A: Array, idx: NDArray[np.intp], M: Array) -> Array:
    """``G_i = A_i M^-1 A_i^T`` (K, r, r) for candidates ``idx`` from one Cholesky factor."""
    c = np.linalg.cholesky(M)
    Ai = A[idx]                                               # (K, r, L)
    K, r, L = Ai.shape
    Y = solve_triangular(c, Ai.reshape(K * r, L).T, lower=True)   # L^-1 A_i^T: (L, K r)
    Y = Y.T.reshape(K, r, L)
    out: Array = np.einsum("kal,kbl->kab", Y, Y)
    return out


def _logdet_psd(G: Array, sign: float) -> Array:
    """``log det(I + sign G)`` for a batch of r x r symmetric ``G`` (-inf if not PD)."""
    r = G.shape[-1]
    s, ld = np.linalg.slogdet(np.eye(r) + sign * G)
    return np.where(s > 0, ld, -np.inf)


def _logdet(M: Array) -> float:
    s, ld = np.linalg.slogdet(M)
    return float(ld) if s > 0 else -np.inf


def _surrogate(lam: Array, B: Array, criterion: str, k: int) -> Array:
    """Approximate score of ``diag(lam) + B^T B`` (eigenbasis) for a batch ``B`` (K, r, L)."""
    L = lam.size
    weak = list(range(min(k, L)))
    if L > len(weak):
        weak.append(L - 1)
    rest = np.setdiff1d(np.arange(L), weak)
    Bw = B[:, :, weak]
    C = np.einsum("kri,krj->kij", Bw, Bw)
    C[:, np.arange(len(weak)), np.arange(len(weak))] += lam[weak]
    spec = [np.linalg.eigvalsh(C)]
    if rest.size:
        spec.append(lam[rest] + np.einsum("kri,kri->ki", B[:, :, rest], B[:, :, rest]))
    return criterion_score(np.concatenate(spec, axis=1), criterion)


def _best_addition(A: Array, M: Array, idx: NDArray[np.intp], criterion: str,
                   shortlist: int, weak: int = 6) -> tuple[int, float]:
    """Candidate of ``idx`` maximising ``criterion(M + A_i^T A_i)``, and its score."""
    if idx.size == 0:
        return -1, -np.inf
    lam, V = np.linalg.eigh(M)
    top = idx
    if top.size > shortlist:
        B = A[top] @ V
        if top.size > 4 * shortlist:                 # first-order screen, no eigen-solve
            diag = lam + np.einsum("kri,kri->ki", B, B)
            keep = np.argsort(-criterion_score(diag, criterion), kind="stable")[:4 * shortlist]
            top, B = top[keep], B[keep]
        sur = _surrogate(lam, B, criterion, weak)
        top = top[np.argsort(-sur, kind="stable")[:shortlist]]
    At = A[top]
    Ms = M + np.einsum("kri,krj->kij", At, At)
    score = criterion_score(np.linalg.eigvalsh(Ms), criterion)
    b = int(np.argmax(score))
    return int(top[b]), float(score[b])


# --------------------------------------------------------------------------- algorithms
def _greedy(A: Array, pool: _Pool, sel: list[int], m: int, criterion: str, shortlist: int,
            ridge: float, history: list[float], progress: Progress | None) -> Array:
    """Add poses one at a time until ``m``; returns the information matrix."""
    L = A.shape[2]
    M = _info(A, sel) if sel else np.zeros((L, L))
    eye = np.eye(L)
    while len(sel) < m:
        idx = pool.available()
        if idx.size == 0:
            raise KincalError(f"only {len(sel)} candidate poses satisfy the minimum distance; "
                              "lower --min-distance or give more candidates")
        lam = np.linalg.eigvalsh(M)
        singular = lam[0] <= 1e-12 * max(lam[-1], 1e-300)
        if criterion == "O1" or singular:
            gain = _logdet_psd(_lemma_terms(A, idx, M + ridge * eye), +1.0)
            j = int(idx[int(np.argmax(gain))])
        else:
            j, _ = _best_addition(A, M, idx, criterion, shortlist)
        sel.append(j)
        pool.add(j)
        M = M + A[j].T @ A[j]
        history.append(float(criterion_score(np.linalg.eigvalsh(M), criterion)))
        if progress is not None:
            progress("greedy", len(sel), m)
    return M


def _detmax(A: Array, pool: _Pool, sel: list[int], M: Array, max_excursion: int,
            max_iter: int, history: list[float], progress: Progress | None
            ) -> tuple[list[int], Array, int]:
    """Mitchell's DETMAX on ``log det M`` with excursions of size 1 .. ``max_excursion``."""
    cur = _logdet(M)
    if not np.isfinite(cur):
        return sel, M, 0
    k, accepted, it = 1, 0, 0
    while k <= max_excursion and it < max_iter:
        it += 1
        trial, Mt = list(sel), M.copy()
        for _ in range(k):                                   # excursion up: add k
            idx = pool.available()
            if idx.size == 0:
                break
            gain = _logdet_psd(_lemma_terms(A, idx, Mt), +1.0)
            j = int(idx[int(np.argmax(gain))])
            trial.append(j)
            pool.add(j)
            Mt = Mt + A[j].T @ A[j]
        for _ in range(len(trial) - len(sel)):               # back down: remove as many
            t = np.array(trial, dtype=np.intp)
            keep = _logdet_psd(_lemma_terms(A, t, Mt), -1.0)
            j = int(t[int(np.argmax(keep))])
            trial.remove(j)
            pool.remove(j)
            Mt = Mt - A[j].T @ A[j]
        new = _logdet(Mt)
        if new > cur + IMPROVE and sorted(trial) != sorted(sel):
            sel, M, cur, k = trial, Mt, new, 1
            accepted += 1
            history.append(cur)
        else:
            pool.reset(sel)
            k += 1
        if progress is not None:
            progress("DETMAX", min(k, max_excursion), max_excursion)
    return sel, M, accepted


def _exchange(A: Array, pool: _Pool, sel: list[int], M: Array, criterion: str,
              shortlist: int, max_passes: int, history: list[float],
              progress: Progress | None) -> tuple[list[int], Array, int]:
    """Fedorov exchange: swap each selected pose for the best candidate while it helps."""
    cur = float(criterion_score(np.linalg.eigvalsh(M), criterion))
    accepted = 0
    for p in range(max_passes):
        improved = False
        for pos in range(len(sel)):
            j = sel[pos]
            Mj = M - A[j].T @ A[j]
            i, s = _best_addition(A, Mj, pool.available(without=j), criterion, shortlist)
            if i >= 0 and s > cur + IMPROVE:
                pool.remove(j)
                pool.add(i)
                sel[pos] = i
                M = Mj + A[i].T @ A[i]
                cur = s
                accepted += 1
                improved = True
                history.append(cur)
            if progress is not None:
                progress(f"exchange pass {p + 1}", pos + 1, len(sel))
        if not improved:
            break
    return sel, M, accepted


def _check_size(problem: DesignProblem, poses: int) -> None:
    N, r, L = problem.J.shape
    if poses < 1:
        raise KincalError("the number of poses must be at least 1")
    if poses > N:
        raise KincalError(f"{poses} poses requested but only {N} candidates")
    if poses * r < L:
        raise KincalError(f"{poses} poses give {poses * r} equations for {L} identifiable "
                          f"parameters; ask for at least {-(-L // r)} poses")


def select_poses(problem: DesignProblem, poses: int, criterion: str = "O1", *,
                 min_distance: float = 0.0, exchange: bool = True, shortlist: int = 32,
                 max_passes: int = 10, max_excursion: int = 4,
                 initial: Sequence[int] | None = None,
                 progress: Progress | None = None) -> PoseDesign:
    """Select ``poses`` candidates maximising an observability criterion.

    Args:
        problem: the candidates and their scaled rows (:func:`design_problem`).
        poses: m, the number of poses to select.
        criterion: ``O1`` (greedy + DETMAX), ``O2`` ... ``O5`` (greedy + exchange) or
            ``kappa`` (greedy by the condition number only); see the module docstring.
        min_distance: smallest joint-space distance between selected poses [rad / m].
        exchange: refine the greedy design (DETMAX / exchange); ignored for kappa.
        shortlist: candidates evaluated exactly per step for O2-O5 / kappa.
        max_passes: exchange passes (O2-O5).
        max_excursion: largest DETMAX excursion (O1).
        initial: candidate indices that must be in the design (kept by the greedy
            phase; the refinement may swap them out).
        progress: ``progress(phase, done, total)`` callback.

    Returns:
        A :class:`PoseDesign`.
    """
    if criterion not in CRITERIA:
        raise KincalError(f"unknown criterion {criterion!r}; use one of {', '.join(CRITERIA)}")
    if not (np.isfinite(min_distance) and min_distance >= 0):
        raise KincalError("the minimum distance must be >= 0")
    _check_size(problem, poses)
    A = problem.A
    N, r, L = A.shape
    pool = _Pool(problem.q, min_distance)
    sel: list[int] = []
    for j in initial or ():
        j = int(j)
        if not 0 <= j < N:
            raise KincalError(f"initial pose {j} is not a candidate index (0..{N - 1})")
        if j in sel:
            continue
        if j not in pool.available():
            raise KincalError(f"initial pose {j} is closer than the minimum distance to "
                              "another initial pose")
        sel.append(j)
        pool.add(j)
    mean_diag = float(np.einsum("nrj,nrj->", A, A)) / (N * L)
    ridge = RIDGE * mean_diag
    start = list(sel)
    history: list[float] = []
    M = _greedy(A, pool, sel, poses, criterion, shortlist, ridge, history, progress)
    accepted, method = 0, "greedy"
    if exchange and criterion == "O1":
        sel, M, accepted = _detmax(A, pool, sel, M, max_excursion, 50 * poses, history,
                                   progress)
        method = "greedy + DETMAX"
    elif exchange and criterion != "kappa":
        sel, M, accepted = _exchange(A, pool, sel, M, criterion, shortlist, max_passes,
                                     history, progress)
        method = "greedy + exchange"
        # second start: the D-optimal greedy design (the eigenvalue criteria are not
        # smooth and the exchange stops in local optima; two starts find better ones)
        pool2 = _Pool(problem.q, min_distance)
        pool2.reset(start)
        sel2, hist2 = list(start), list[float]()
        M2 = _greedy(A, pool2, sel2, poses, "O1", shortlist, ridge, hist2, progress)
        sel2, M2, acc2 = _exchange(A, pool2, sel2, M2, criterion, shortlist, max_passes,
                                   hist2, progress)
        score = criterion_score(np.linalg.eigvalsh(np.stack([M, M2])), criterion)
        method = "greedy + exchange, best of 2 starts"
        if score[1] > score[0]:
            sel, accepted, history = sel2, acc2, hist2
    s = np.array(sel, dtype=np.intp)
    return PoseDesign(problem, s, criterion, method, problem.indices(s), history, accepted,
                      float(min_distance))


def random_design(problem: DesignProblem, poses: int, rng: np.random.Generator, *,
                  min_distance: float = 0.0) -> PoseDesign:
    """``poses`` candidates drawn at random (respecting ``min_distance``): the baseline."""
    _check_size(problem, poses)
    pool = _Pool(problem.q, min_distance)
    sel: list[int] = []
    for _ in range(poses):
        idx = pool.available()
        if idx.size == 0:
            raise KincalError(f"only {len(sel)} candidate poses satisfy the minimum distance")
        j = int(rng.choice(idx))
        sel.append(j)
        pool.add(j)
    s = np.array(sel, dtype=np.intp)
    return PoseDesign(problem, s, "random", "random", problem.indices(s), [], 0,
                      float(min_distance))


# --------------------------------------------------------------------------- candidates
def within_limits(robot: Robot, q: ArrayLike) -> NDArray[np.bool_]:
    """Rows of ``q`` (N, n) inside the joint limits (bounds included)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    lim = robot.joint_limits
    out: NDArray[np.bool_] = np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), axis=1)
    return out


def random_candidates(robot: Robot, n: int, rng: np.random.Generator,
                      margin: float = 0.05) -> Array:
    """``n`` configurations uniform within the joint limits shrunk by ``margin`` of the range."""
    from kincal.measure.simulate import random_configurations

    if n < 1:
        raise KincalError("the number of candidates must be at least 1")
    return random_configurations(robot, int(n), rng, margin)


def read_configurations(path: str | Path, robot: Robot, units: Mapping[str, str] | None = None,
                        ignore: Sequence[str] = ()) -> tuple[Array, int]:
    """Configurations from a CSV with one column per joint (``q1_deg``, ``q2_rad`` ...).

    Read with :func:`kincal.measure.files.read_table` (units at the border, one-line
    errors).  Rows outside the joint limits are dropped.

    Returns:
        ``(q, dropped)``: (N, n) configurations [rad / m] and the number of rows dropped.
    """
    from kincal.measure.files import read_table

    t = read_table(path, robot, (), dict(units or {}), tuple(ignore))
    ok = within_limits(robot, t.q)
    if not ok.any():
        raise KincalError(f"none of the {len(ok)} configurations is inside the joint limits",
                          source=str(path))
    return t.q[ok], int(np.count_nonzero(~ok))


def instrument_candidates(robot: Robot, instrument: str, n: int, rng: np.random.Generator,
                          options: Mapping[str, Any] | None = None,
                          **design_options: Any) -> DesignProblem:
    """A design problem over configurations the instrument's simulator can measure.

    The registered instrument (``kincal.measure.registry``) simulates ``n`` poses on
    the *nominal* robot without noise; its configurations (and, for instruments other
    than ``position`` / ``pose``, its blocks of exact nominal observations) make the
    candidate set, so whatever reach or visibility model the instrument has (a
    camera's field of view, plane or fixture contacts) is respected.

    ``design_options`` go to :func:`design_problem` (position / pose) or to
    :func:`design_problem_from_blocks`.
    """
    from kincal.measure.registry import get_instrument, simulate_measurements

    inst = get_instrument(instrument)
    blocks, truth = simulate_measurements(inst, robot, rng, n, 0.0, dict(options or {}))
    if inst.name in ("position", "pose"):
        q = np.unique(np.concatenate([b.q for b in blocks]), axis=0)
        return design_problem(robot, q, inst.name, **design_options)
    extras = np.concatenate([[truth[k] for k in b.parameters().names] for b in blocks])
    return design_problem_from_blocks(robot, blocks, extras, **design_options)


def write_poses(path: str | Path, robot: Robot, q: ArrayLike, angle_unit: str = "rad",
                length_unit: str = "m", comments: Sequence[str] = ()) -> None:
    """Write configurations as a CSV the measurement reader reads back (atomically).

    Header: one column per joint named ``{joint name}_{unit}`` (``q1_rad`` or, with
    ``angle_unit="deg"``, ``q1_deg``; prismatic joints in ``length_unit``), preceded
    by ``#`` comment lines; no instrument tag (the file holds poses to measure, not
    measurements).  ``path == "-"`` writes to stdout.
    """
    from kincal.measure.files import write_table

    write_table(path, np.atleast_2d(np.asarray(q, dtype=float)), [], robot, None,
                angle_unit=angle_unit, length_unit=length_unit, comments=list(comments))
