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
from typing import Any

import numpy as np

from kincal.identify.identifiability import analyze

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

    def to_dict(self) -> dict[str, Any]:
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

    Uses kincal's general :func:`kincal.identify.identifiability.analyze` (unit-norm
    columns, greedy selection in priority order) with the five-bar's priority.  Its
    ``combinations`` (a change of d moves the data as ``c_k`` times changes of the kept
    k) give the absorption coefficients ``n_k = -c_k``.

    Args:
        jacobian: stacked Jacobian (M, len(names)), one column per parameter.
        names: column names.
        requested: the parameters the user wants free.
        rank_tol: smallest admissible singular value of the scaled kept columns.
        priority: order in which parameters are offered a place.
    """
    requested = list(requested)
    cols = [list(names).index(n) for n in requested]
    rank = [priority.index(n) if n in priority else len(priority) for n in requested]
    rep = analyze(np.asarray(jacobian)[:, cols], requested, tol=rank_tol, priority=rank)
    kept = set(rep.identifiable)
    no_effect = tuple(rep.unobservable)
    absorbed = {d: {k: -float(c) for k, c in rep.combinations.get(d, {}).items() if abs(c) > 1e-9}
                for d in requested if d not in kept and d not in no_effect}
    condition = float(rep.cond_scaled) if kept and np.isfinite(rep.cond_scaled) else 1.0
    return Identifiability(
        requested=tuple(requested),
        kept=tuple(n for n in requested if n in kept),
        held=tuple(n for n in requested if n not in kept),
        absorbed=absorbed,
        no_effect=no_effect,
        condition=condition,
    )
