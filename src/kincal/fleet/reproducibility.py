"""Session-to-session reproducibility: the error a calibration repeats only within a session.

Two calibrations of a robot that did not change still differ by more than their standard
errors say.  Each session samples the workspace its own way (the artifact put at other
places on the table, the tracker elsewhere, other poses), and what the model does not
describe (elasticity, gear errors, temperature) is absorbed into the parameters
differently each time.  The model of a session's estimate is

    theta_hat_s = theta + u_s + e_s,    e_s ~ N(0, C_s),    u_s ~ N(0, T / m_s),

with ``C_s`` the calibration's own covariance (the noise of its measurements) and ``u_s``
the session's share of the unmodelled error: the mean of one effect per placement (per
training file: an artifact placement, a tracker set-up), each ``N(0, T)`` and independent,
over the session's ``m_s`` placements.  ``T`` [m^2 / rad^2, m rad, ...], the
placement-to-placement covariance, is the same for every robot of the model.  The change
between two sessions of an unchanged robot then has

    Cov(delta) = C_a + C_b + w T,    w = 1 / m_a + 1 / m_b.

``T`` is estimated across the fleet by the method of moments: over ``n`` pairs of
sessions of robots of the same model (the previous and latest calibration of each),
``E[delta delta^T] = V + w T`` with ``V = C_a + C_b``, so

    T_ij = sum_r (delta_ri delta_rj - V_r,ij) / sum_r w_r,

over the pairs in which both parameters were estimated in both sessions; ``T`` is then
made positive semi-definite (:func:`_denoise`: negative eigenvalues set to zero).  The
drift test of a robot uses the estimate from the *other* robots' pairs (leave one robot
out), so a robot that did drift neither hides itself nor takes part in its own threshold,
and its statistic is independent of ``T``; with ``nu = n - 1`` pairs behind ``T`` the
thresholds account for its uncertainty (:mod:`kincal.fleet.drift`).  Fewer than
:data:`MIN_PAIRS` other pairs: not estimated.

Two models.  ``T`` is additive: every placement moves a parameter by the same spread,
whatever its conditioning.  What the model lacks reaches a parameter through the fit,
though, and a placement that fixes a parameter weakly lets the same unmodelled error move
it further: the placement effect then grows with the calibration's own variance, like a
design effect in cluster sampling (rows of one placement share their unmodelled error),

    Cov(delta_i) = lambda_i^2 V_ii,    lambda_i^2 = mean_r delta_ri^2 / V_r,ii  (>= 1),

over the other pairs ``r`` (each ``delta_ri / sqrt(V_r,ii)`` is then ``N(0, lambda_i^2)``;
the estimated part ``(lambda_i^2 - 1) V_ii`` gets Satterthwaite degrees of freedom as
``w T_ii`` does).  The MUKCa Pandas show it: ``panda_7``'s single placements leave a
standard error of its ``panda_joint2.origin.y`` change 1.8-17 times the other robots',
and move it 1.53 mm where theirs move it 0.19 mm or less.

Which model holds is asked of the other robots' changes: each pair's change is judged by
both models estimated without it, and the log-likelihood ratios are summed per parameter
(:attr:`Reproducibility.evidence`) and over all parameters at once, correlations
included (:attr:`Reproducibility.joint_evidence`).  The drift test
(:mod:`kincal.fleet.drift`) uses the model the evidence supports, and where it cannot
tell, reports a change only when both models call it one: whichever model is true, the
false-alarm rate is then at most the stated one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from kincal.robots.chain import ROLES

__all__ = ["Reproducibility", "PairTerms", "pair_terms", "estimate_reproducibility",
           "MIN_PAIRS", "ReproducibilityPool", "placements"]

#: Pairs of sessions (other robots of the same model) needed to estimate ``T``.
MIN_PAIRS = 2


@dataclasses.dataclass(frozen=True)
class PairTerms:
    """One robot's previous-to-latest change over the parameters ``names`` estimated in
    both: ``delta`` and ``V = C_a + C_b`` (its covariance from the two calibrations alone,
    SI), and the robot model the pair belongs to."""

    serial: str
    model: str
    names: tuple[str, ...]
    delta: np.ndarray
    V: np.ndarray
    weight: float = 2.0     # 1/m_a + 1/m_b: m placements (data files) in each session


@dataclasses.dataclass(frozen=True)
class Reproducibility:
    """The placement-to-placement covariance ``T`` over ``names`` (SI squared) and the
    number of session pairs ``pairs`` it was estimated from (its degrees of freedom)."""

    names: tuple[str, ...]
    matrix: np.ndarray
    pairs: int
    diagonal: np.ndarray | None = None     # T_ii each clipped at 0 (None: the matrix's)
    #: ``lambda_i^2`` per parameter, at least 1: the second model's variance factor
    #: (module docstring, "Two models"); None: not estimated
    inflation: dict[str, float] | None = None
    #: per parameter, the log-likelihood of the pairs' changes under the additive model
    #: less that under the design effect (positive: additive fits better); None: none
    evidence: dict[str, float] | None = None
    #: the same for all parameters at once (correlations included); None: none
    joint_evidence: float | None = None

    @property
    def variance(self) -> dict[str, float]:
        """``tau_i^2`` per parameter: the moment estimate of each, clipped at zero (not
        the diagonal of the positive semi-definite matrix, biased upwards by clipping)."""
        d = np.diag(self.matrix) if self.diagonal is None else self.diagonal
        return {n: float(d[k]) for k, n in enumerate(self.names)}

    def block(self, names: Sequence[str]) -> np.ndarray:
        """``T`` over ``names`` (zero rows and columns for parameters it does not cover)."""
        at = {n: k for k, n in enumerate(self.names)}
        idx = np.array([at.get(n, -1) for n in names], dtype=int)
        out = np.zeros((len(names), len(names)))
        have = np.flatnonzero(idx >= 0)
        out[np.ix_(have, have)] = self.matrix[np.ix_(idx[have], idx[have])]
        return out

    def std(self, name: str) -> float:
        """``tau_i`` [m or rad] (0 for a parameter without an estimate)."""
        return float(np.sqrt(self.variance.get(name, 0.0)))

    def factor(self, name: str) -> float:
        """``lambda_i^2`` of ``name`` (1 without an estimate)."""
        return 1.0 if self.inflation is None else float(self.inflation.get(name, 1.0))

    def support(self, name: str) -> float:
        """The evidence for the additive model over the design effect for ``name``
        (log-likelihood ratio over the pairs; 0 without an estimate)."""
        return 0.0 if self.evidence is None else float(self.evidence.get(name, 0.0))

    def to_dict(self) -> dict[str, Any]:
        return {"pairs": self.pairs, "std": {k: float(np.sqrt(v))
                                             for k, v in self.variance.items()},
                "inflation": None if self.inflation is None else dict(self.inflation),
                "evidence": None if self.evidence is None else dict(self.evidence),
                "joint_evidence": self.joint_evidence}


def _block(record: Mapping[str, Any]) -> tuple[dict[str, float], np.ndarray, list[str]]:
    est = {p["name"]: float(p["estimate"]) for p in record["parameters"]
           if p["role"] in ROLES and p["estimated"]}
    return est, np.asarray(record["covariance"], dtype=float), list(record["estimated"])


def pair_terms(previous: Mapping[str, Any], latest: Mapping[str, Any]) -> PairTerms:
    """The :class:`PairTerms` of two full records of one robot (``previous`` first)."""
    ea, Ca, na = _block(previous)
    eb, Cb, nb = _block(latest)
    names = tuple(n for n in nb if n in ea and n in eb and n in na)
    ia, ib = [na.index(n) for n in names], [nb.index(n) for n in names]
    return PairTerms(str(latest["serial"]), str(latest.get("robot") or ""), names,
                     np.array([eb[n] - ea[n] for n in names]),
                     Ca[np.ix_(ia, ia)] + Cb[np.ix_(ib, ib)],
                     1.0 / placements(previous) + 1.0 / placements(latest))


def placements(record: Mapping[str, Any]) -> int:
    """The placements of a session: its training files (each file is one set-up of the
    instrument or one placement of the artifact), at least one."""
    return max(1, len(record.get("data") or ()))


class ReproducibilityPool:
    """The sums behind ``T`` for every robot model of a fleet, so that the estimate
    leaving one robot out costs ``O(p^2)`` (a fleet of 100,000 robots is one pass)."""

    def __init__(self, pairs: Sequence[PairTerms]) -> None:
        self.names: dict[str, list[str]] = {}
        self.sums: dict[str, np.ndarray] = {}
        self.counts: dict[str, np.ndarray] = {}
        self.weights: dict[str, np.ndarray] = {}
        self.pairs: dict[str, int] = {}
        self.ratios: dict[str, np.ndarray] = {}       # sum of delta_i^2 / V_ii
        self.ratio_counts: dict[str, np.ndarray] = {}
        for p in pairs:
            names = self.names.setdefault(p.model, [])
            names += [n for n in p.names if n not in names]
        for model, names in self.names.items():
            self.sums[model] = np.zeros((len(names), len(names)))
            self.counts[model] = np.zeros((len(names), len(names)), dtype=int)
            self.weights[model] = np.zeros((len(names), len(names)))
            self.ratios[model] = np.zeros(len(names))
            self.ratio_counts[model] = np.zeros(len(names), dtype=int)
        for p in pairs:
            self.pairs[p.model] = self.pairs.get(p.model, 0) + 1
            idx, S = self._outer(p, p.model)
            self.sums[p.model][np.ix_(idx, idx)] += S
            self.counts[p.model][np.ix_(idx, idx)] += 1
            self.weights[p.model][np.ix_(idx, idx)] += p.weight
            ok, z2 = _squared_z(p)
            self.ratios[p.model][np.asarray(idx)[ok]] += z2[ok]
            self.ratio_counts[p.model][np.asarray(idx)[ok]] += 1
        # which model of placement error the pairs support: each pair's change judged by
        # both models estimated without it (cross-validated, so that the additive model's
        # p(p+1)/2 entries of T do not buy their fit), summed per parameter and jointly
        self.evidence: dict[str, np.ndarray] = {}
        self.joint_evidence: dict[str, float] = {}
        # each pair's own terms, to subtract when it is left out (kept with the pair, so
        # that an id reused by another object cannot match)
        self._own: dict[int, tuple[PairTerms, list[int], np.ndarray, float]] = {}
        for model, names in self.names.items():
            self.evidence[model] = np.zeros(len(names))
            self.joint_evidence[model] = 0.0
        for p in pairs:
            idx, ev, joint = self._evidence(p)
            self._own[id(p)] = (p, idx, ev, joint)
            self.evidence[p.model][idx] += ev
            self.joint_evidence[p.model] += joint

    def _evidence(self, p: PairTerms) -> tuple[list[int], np.ndarray, float]:
        """Indices of ``p``'s parameters; per parameter, the log-likelihood of its change
        under the additive model less that under the design effect, both estimated from
        the pool without ``p``; and the same over all its parameters at once
        (``log N(delta; 0, V + w T) - log N(delta; 0, lambda V lambda)``, correlations
        included).  Positive favours the additive model."""
        idx = [self.names[p.model].index(n) for n in p.names]
        T, lam2 = self._fit_without(p, p.model)
        T = _denoise(T)[np.ix_(idx, idx)]
        lam2 = lam2[idx]
        v = np.diag(p.V)
        ok = v > 0
        s_add = v + p.weight * np.diag(T)
        s_de = lam2 * v
        with np.errstate(divide="ignore", invalid="ignore"):
            ev = -0.5 * (np.log(s_add / s_de) + p.delta**2 / s_add - p.delta**2 / s_de)
        ev = np.where(ok & np.isfinite(ev), ev, 0.0)
        lam = np.sqrt(lam2)
        joint = _log_normal(p.delta, p.V + p.weight * T) - _log_normal(
            p.delta, p.V * np.outer(lam, lam))
        return idx, ev, joint

    def _fit_without(self, pair: PairTerms | None, model: str
                     ) -> tuple[np.ndarray, np.ndarray]:
        """``(T, lambda^2)`` of ``model`` from the sums less ``pair``'s terms (all of them
        for None; ``T`` not yet made positive semi-definite)."""
        S, N = self.sums[model].copy(), self.counts[model].copy()
        Wt = self.weights[model].copy()
        Z, K = self.ratios[model].copy(), self.ratio_counts[model].copy()
        if pair is not None:
            idx, own = self._outer(pair, model)
            S[np.ix_(idx, idx)] -= own
            N[np.ix_(idx, idx)] -= 1
            Wt[np.ix_(idx, idx)] -= pair.weight
            ok, z2 = _squared_z(pair)
            Z[np.asarray(idx)[ok]] -= z2[ok]
            K[np.asarray(idx)[ok]] -= 1
        T = np.where((N >= MIN_PAIRS) & (Wt > 0), S / np.where(Wt > 0, Wt, 1.0), 0.0)
        lam = np.where(K >= MIN_PAIRS, Z / np.maximum(K, 1), 1.0)
        return T, np.maximum(lam, 1.0)

    def _outer(self, p: PairTerms, model: str) -> tuple[list[int], np.ndarray]:
        """Indices of ``p``'s parameters and ``delta delta^T - V`` over them."""
        names = self.names[model]
        return [names.index(n) for n in p.names], np.outer(p.delta, p.delta) - p.V

    def without(self, pair: PairTerms | None, model: str) -> Reproducibility | None:
        """``T`` of ``model`` from every pair but ``pair`` (module docstring); None with
        fewer than :data:`MIN_PAIRS` pairs."""
        n = self.pairs.get(model, 0) - (pair is not None)
        if n < MIN_PAIRS:
            return None
        ev = self.evidence[model].copy()
        joint = self.joint_evidence[model]
        if pair is not None and pair.model == model:
            cached = self._own.get(id(pair))
            own_idx, own_ev, own_joint = (cached[1:] if cached is not None and cached[0] is pair
                                          else self._evidence(pair))
            ev[own_idx] -= own_ev
            joint -= own_joint
        T, lam = self._fit_without(pair, model)
        names = self.names[model]
        return Reproducibility(tuple(names), _denoise(T), n,
                               np.maximum(np.diag(T), 0.0),
                               {nm: float(v) for nm, v in zip(names, lam, strict=True)},
                               {nm: float(v) for nm, v in zip(names, ev, strict=True)},
                               float(joint))


def _log_normal(x: np.ndarray, C: np.ndarray) -> float:
    """``log N(x; 0, C)`` on the range of ``C`` (pseudo-determinant and -inverse)."""
    w, U = np.linalg.eigh((C + C.T) / 2)
    keep = w > (w.max() * 1e-12 if w.size and w.max() > 0 else np.inf)
    y = U[:, keep].T @ x
    return float(-0.5 * (np.sum(np.log(2 * np.pi * w[keep])) + np.sum(y**2 / w[keep])))


def _squared_z(pair: PairTerms) -> tuple[np.ndarray, np.ndarray]:
    """``(ok, delta_i^2 / V_ii)`` of a pair (``ok``: ``V_ii > 0``)."""
    v = np.diag(pair.V)
    ok = v > 0
    return ok, np.where(ok, pair.delta**2 / np.where(ok, v, 1.0), 0.0)


def _denoise(T: np.ndarray) -> np.ndarray:
    """``T`` made positive semi-definite: negative eigenvalues set to zero.  (Clipping
    noise biases ``T`` upwards, by up to ``sqrt(p/n)`` times the calibrations' own
    covariance ``W``: a conservative test, at the price of some power in small fleets;
    lowering the eigenvalues by that edge lost the false-alarm rate when the placement
    effect is correlated between parameters.)"""
    w, V = np.linalg.eigh((T + T.T) / 2)
    out: np.ndarray = (V * np.maximum(w, 0.0)) @ V.T
    return out


def estimate_reproducibility(pairs: Sequence[PairTerms], exclude: str | None = None
                             ) -> Reproducibility | None:
    """``T`` (module docstring) from ``pairs`` of one robot model, leaving out the robot
    ``exclude``; None with fewer than :data:`MIN_PAIRS` pairs."""
    use = [p for p in pairs if p.serial != exclude]
    if not use:
        return None
    return ReproducibilityPool([dataclasses.replace(p, model="") for p in use]).without(
        None, "")
