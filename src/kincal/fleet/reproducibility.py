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

    @property
    def variance(self) -> dict[str, float]:
        """``tau_i^2`` per parameter: the moment estimate of each, clipped at zero (not
        the diagonal of the positive semi-definite matrix, biased upwards by clipping)."""
        d = np.diag(self.matrix) if self.diagonal is None else self.diagonal
        return {n: float(d[k]) for k, n in enumerate(self.names)}

    def block(self, names: Sequence[str]) -> np.ndarray:
        """``T`` over ``names`` (zero rows and columns for parameters it does not cover)."""
        at = {n: k for k, n in enumerate(self.names)}
        idx = [at.get(n, -1) for n in names]
        out = np.zeros((len(names), len(names)))
        for a, i in enumerate(idx):
            for b, j in enumerate(idx):
                if i >= 0 and j >= 0:
                    out[a, b] = self.matrix[i, j]
        return out

    def std(self, name: str) -> float:
        """``tau_i`` [m or rad] (0 for a parameter without an estimate)."""
        return float(np.sqrt(self.variance.get(name, 0.0)))

    def to_dict(self) -> dict[str, Any]:
        return {"pairs": self.pairs, "std": {k: float(np.sqrt(v))
                                             for k, v in self.variance.items()}}


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
        self.noise: dict[str, np.ndarray] = {}
        for p in pairs:
            names = self.names.setdefault(p.model, [])
            names += [n for n in p.names if n not in names]
        for model, names in self.names.items():
            self.sums[model] = np.zeros((len(names), len(names)))
            self.counts[model] = np.zeros((len(names), len(names)), dtype=int)
            self.weights[model] = np.zeros((len(names), len(names)))
            self.noise[model] = np.zeros((len(names), len(names)))
        for p in pairs:
            self.pairs[p.model] = self.pairs.get(p.model, 0) + 1
            idx, S = self._outer(p, p.model)
            self.sums[p.model][np.ix_(idx, idx)] += S
            self.counts[p.model][np.ix_(idx, idx)] += 1
            self.weights[p.model][np.ix_(idx, idx)] += p.weight
            self.noise[p.model][np.ix_(idx, idx)] += p.V

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
        S, N = self.sums[model].copy(), self.counts[model].copy()
        Wt = self.weights[model].copy()
        if pair is not None:
            idx, own = self._outer(pair, model)
            S[np.ix_(idx, idx)] -= own
            N[np.ix_(idx, idx)] -= 1
            Wt[np.ix_(idx, idx)] -= pair.weight
        T = np.where((N >= MIN_PAIRS) & (Wt > 0), S / np.where(Wt > 0, Wt, 1.0), 0.0)
        W = self.noise[model] / np.maximum(self.counts[model], 1)
        return Reproducibility(tuple(self.names[model]), _denoise(T, W, n), n,
                               np.maximum(np.diag(T), 0.0))


def _denoise(T: np.ndarray, W: np.ndarray, n: int) -> np.ndarray:
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
