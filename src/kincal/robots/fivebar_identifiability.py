"""Which five-bar parameters the data can identify, named.

The columns of the stacked Jacobian W (2N x p) are scaled to unit norm (so
metres and radians compare), then parameters are taken in a priority order and
kept only if they raise the numerical rank (smallest singular value of the
kept, scaled columns above ``rank_tol`` times the largest).  The others are
*dependent*: held at their nominal values.  For each dependent parameter d the
null space of W, put in the form where d moves by 1 and the other dependents by
0, says how its error is absorbed: the estimate of each kept parameter k is
``k_true + n_k (d_nominal - d_true)``.

The priority order puts the measurement frame first, then lengths, offsets, the
second base and last the first base: with a free measurement frame the held
parameters are then base1.x, base1.y and base2.y, which is the usual convention
that fixes the robot's base frame at B1 with B2 on its x axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

PRIORITY: tuple[str, ...] = (
    "frame.x",
    "frame.y",
    "frame.theta",
    "l1",
    "l2",
    "l3",
    "l4",
    "offset1",
    "offset2",
    "base2.x",
    "base2.y",
    "base1.x",
    "base1.y",
)


@dataclass(frozen=True)
class Identifiability:
    """Identifiable (kept) and dependent (held) parameters with the null directions.

    ``absorbed[d]`` maps each held parameter d to ``{name: n_k}``, the kept
    parameters whose estimates absorb its error (coefficients in SI units).
    ``condition``: condition number of the scaled Jacobian of the kept ones.
    """

    requested: tuple[str, ...]
    kept: tuple[str, ...]
    held: tuple[str, ...]
    absorbed: dict[str, dict[str, float]] = field(default_factory=dict)
    no_effect: tuple[str, ...] = ()
    condition: float = 1.0

    @property
    def full_rank(self) -> bool:
        """True when every requested parameter is identifiable."""
        return not self.held

    def describe(self) -> list[str]:
        """One line per held parameter, naming what absorbs it."""
        lines = []
        for name in self.held:
            if name in self.no_effect:
                lines.append(f"{name}: has no effect on the residuals; held at nominal")
                continue
            parts = " ".join(f"{c:+.4g} {k}" for k, c in self.absorbed.get(name, {}).items())
            lines.append(
                f"{name}: not identifiable with the others; held at nominal, its error "
                f"(nominal - true) shifts the estimates by [{parts}] x that error"
            )
        return lines

    def to_dict(self) -> dict:
        """Plain mapping for JSON."""
        return {
            "requested": list(self.requested),
            "identifiable": list(self.kept),
            "held_at_nominal": list(self.held),
            "absorbed_by": self.absorbed,
            "no_effect": list(self.no_effect),
            "condition_number": self.condition,
            "messages": self.describe(),
        }


def analyse(
    jacobian: np.ndarray,
    names: Sequence[str],
    requested: Sequence[str],
    rank_tol: float = 1e-8,
    priority: Sequence[str] = PRIORITY,
) -> Identifiability:
    """Split the requested parameters into identifiable and dependent ones.

    Args:
        jacobian: stacked Jacobian (M, len(names)), one column per parameter.
        names: column names.
        requested: the parameters the user wants free.
        rank_tol: relative singular-value threshold on the unit-norm columns.
        priority: order in which parameters are offered a place.
    """
    order = [n for n in priority if n in requested] + [n for n in requested if n not in priority]
    cols = {n: jacobian[:, list(names).index(n)] for n in order}
    norms = {n: float(np.linalg.norm(c)) for n, c in cols.items()}
    scale_ref = max(norms.values(), default=0.0)
    no_effect = tuple(n for n in order if norms[n] <= 1e-14 * max(scale_ref, 1e-300))
    kept: list[str] = []
    for n in order:
        if n in no_effect:
            continue
        trial = np.column_stack([cols[k] / norms[k] for k in [*kept, n]])
        s = np.linalg.svd(trial, compute_uv=False)
        if s[-1] > rank_tol * s[0]:
            kept.append(n)
    held = tuple(n for n in order if n not in kept)
    absorbed = _absorbed(cols, norms, kept, [n for n in held if n not in no_effect])
    condition = 1.0
    if kept:
        s = np.linalg.svd(np.column_stack([cols[k] / norms[k] for k in kept]), compute_uv=False)
        condition = float(s[0] / s[-1])
    return Identifiability(
        requested=tuple(requested),
        kept=tuple(n for n in requested if n in kept),
        held=tuple(n for n in requested if n in held),
        absorbed=absorbed,
        no_effect=no_effect,
        condition=condition,
    )


def _absorbed(
    cols: dict[str, np.ndarray], norms: dict[str, float], kept: list[str], dependent: list[str]
) -> dict[str, dict[str, float]]:
    """Null directions with each dependent parameter moving by 1 and the others by 0.

    For dependent d: solve  W_kept n = -w_d  (least squares; exact when d depends
    on the kept columns), so that the direction e_d + n leaves W unchanged.
    """
    out: dict[str, dict[str, float]] = {}
    if not dependent:
        return out
    wk = np.column_stack([cols[k] / norms[k] for k in kept]) if kept else None
    for d in dependent:
        if wk is None:
            out[d] = {}
            continue
        n_scaled, *_ = np.linalg.lstsq(wk, -cols[d], rcond=None)
        coeff = n_scaled / np.array([norms[k] for k in kept])
        out[d] = {k: float(c) for k, c in zip(kept, coeff, strict=True) if abs(c) > 1e-9}
    return out
