"""Coincidence: configurations seated in the same socket put the probe tip at one point.

Rows (configurations) are grouped into *sites*: one socket of one artifact placement.
A site ``k`` seated by the rows ``i in I_k`` has one unknown point ``X_k`` [m].  Two
equivalent ways to use it:

* **parameters**: ``X_k`` are block parameters; each row gives the residual
  ``P_i - X_k`` (3 components; ``d/dX_k = -I``);
* **eliminated**: ``X_k`` is replaced by its least-squares estimate, the mean
  ``Xbar_k = mean_{i in I_k} P_i``.  The rows' deviations ``P_i - Xbar_k`` are linearly
  dependent (they sum to zero), so instead of them this module uses the
  *Helmert contrasts*: for the ``j``-th row of a site (``j = 1 .. n_k - 1``, in file
  order)

      h_j = sqrt(j / (j + 1)) (P_j - mean(P_0 .. P_{j-1})),

  ``n_k - 1`` orthonormal combinations with ``sum_j |h_j|^2 = sum_i |P_i - Xbar_k|^2``.
  The least-squares problem is the same as with parameters (variable projection), and
  the residual count ``3 (n_k - 1)`` is the true number of degrees of freedom, so the
  solver's a-posteriori variance factor stays unbiased.

Everything is vectorised: group sums with ``np.add.at``, contrasts with cumulative
sums within groups (after subtracting each group's first row, which keeps the sums
small and exact).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError

Array = NDArray[np.float64]
IntArray = NDArray[np.intp]

SOCKET_MODES = ("eliminate", "parameters")


@dataclass(frozen=True)
class Sites:
    """Rows grouped into sites (one socket of one placement).

    Attributes:
        index: (N,) site of every row.
        count: (S,) rows per site.
        placement: (S,) placement label of every site.
        socket: (S,) socket label of every site.
        placements: the distinct placement labels in order of first appearance.
    """

    index: IntArray
    count: IntArray
    placement: tuple[str, ...]
    socket: tuple[str, ...]
    placements: tuple[str, ...]

    @staticmethod
    def from_labels(placement: Sequence[str], socket: Sequence[str]) -> Sites:
        """Group rows by ``(placement, socket)`` labels, sites in order of first appearance."""
        if len(placement) != len(socket):
            raise KincalError("placement and socket labels differ in length")
        keys: dict[tuple[str, str], int] = {}
        idx = np.empty(len(socket), dtype=np.intp)
        for i, key in enumerate(zip(placement, socket, strict=True)):
            idx[i] = keys.setdefault((str(key[0]), str(key[1])), len(keys))
        pl = tuple(k[0] for k in keys)
        so = tuple(k[1] for k in keys)
        placements = tuple(dict.fromkeys(str(p) for p in placement))
        return Sites(idx, np.bincount(idx, minlength=len(keys)).astype(np.intp), pl, so,
                     placements)

    @property
    def S(self) -> int:
        return len(self.count)

    def find(self, placement: str, socket: str) -> int:
        """Index of a site, or -1 when that socket was not probed in that placement."""
        for k, (p, s) in enumerate(zip(self.placement, self.socket, strict=True)):
            if p == placement and s == socket:
                return k
        return -1

    def site_placement_index(self) -> IntArray:
        """(S,) index into ``placements`` of every site."""
        pos = {p: i for i, p in enumerate(self.placements)}
        return np.array([pos[p] for p in self.placement], dtype=np.intp)


def site_means(values: Array, sites: Sites) -> Array:
    """Mean of ``values`` (N, ...) over the rows of each site: (S, ...)."""
    out = np.zeros((sites.S,) + values.shape[1:])
    np.add.at(out, sites.index, values)
    return out / sites.count.reshape((-1,) + (1,) * (values.ndim - 1))


@dataclass(frozen=True)
class Contrasts:
    """The Helmert contrasts of the rows grouped by site.

    Attributes:
        order: rows sorted by site (stable, so file order within a site).
        start: (N,) position in ``order`` of the first row of each row's site.
        j: (N,) position of each sorted row within its site.
        keep: (N,) True where ``j >= 1`` (rows that give a contrast).
        rows: (K,) original row of each contrast (its owner).
    """

    order: IntArray
    start: IntArray
    j: IntArray
    keep: NDArray[np.bool_]
    rows: IntArray

    @staticmethod
    def build(sites: Sites) -> Contrasts:
        order = np.argsort(sites.index, kind="stable")
        g = sites.index[order]
        first = np.r_[0, np.cumsum(sites.count)[:-1]]
        start = first[g]
        j = np.arange(len(order)) - start
        keep = j >= 1
        return Contrasts(order, start, j, keep, order[keep])

    @property
    def size(self) -> int:
        return int(self.rows.size)

    def apply(self, values: Array) -> Array:
        """Contrasts of ``values`` (N, ...) -> (K, ...): ``sqrt(j/(j+1)) (v_j - mean_{<j} v)``."""
        v = values[self.order]
        v = v - v[self.start]                       # relative to each site's first row
        ex = np.cumsum(v, axis=0) - v               # exclusive cumulative sum
        ex = ex - ex[self.start]                    # ... restricted to the site
        jj = self.j[self.keep].reshape((-1,) + (1,) * (values.ndim - 1)).astype(float)
        prev_mean = ex[self.keep] / jj
        value: Array = np.sqrt(jj / (jj + 1.0)) * (v[self.keep] - prev_mean)
        return value

    def variance(self, var: Array) -> Array:
        """Variance of each contrast component from independent row variances (N,).

        ``var(h_j) = j/(j+1) (s_j^2 + sum_{m<j} s_m^2 / j^2)``.
        """
        s = var[self.order]
        ex = np.cumsum(s) - s
        ex = ex - ex[self.start]
        jj = self.j[self.keep].astype(float)
        value: Array = jj / (jj + 1.0) * (s[self.keep] + ex[self.keep] / jj**2)
        return value


def check_mode(mode: str) -> str:
    if mode not in SOCKET_MODES:
        raise KincalError(f"unknown socket mode {mode!r}; use 'eliminate' (socket points "
                          "are the means of their configurations) or 'parameters'")
    return mode
