"""The stopping rules of the least-squares solver, each a pure function of numbers.

Costs are ``1/2 sum w r^2`` (squared units of the weighted residuals), steps are
scaled: ``max_j |dx_j| / (1 + |x_j|)`` (dimensionless).  The solver
(:mod:`kincal.identify.solver`) asks these in turn and maps the first true one to a
:class:`~kincal.identify.status.StageStatus`.
"""

from __future__ import annotations

__all__ = ["cost_change_below", "no_further_decrease", "step_below",
           "step_within_standard_errors"]


def step_within_standard_errors(z_norm2: float, cost: float, dof: int, tol_std: float) -> bool:
    """Whether the full Gauss-Newton step is within ``tol_std`` standard errors.

    The full step moves ``|R dx| = |z|``; with ``s0^2 = min(2 cost / dof, 1)`` (never
    looser than the stated sigmas) the rule is ``|z|^2 <= tol_std^2 s0^2``.
    ``z_norm2`` is ``|z|^2``; false without redundancy (``dof <= 0``).
    """
    return dof > 0 and z_norm2 <= tol_std**2 * min(2.0 * cost / dof, 1.0)


def step_below(step: float, tol_step: float) -> bool:
    """Whether the scaled step ``max |dx| / (1 + |x|)`` is at most ``tol_step``."""
    return step <= tol_step


def cost_change_below(cost: float, new_cost: float, tol_cost: float,
                      absolute: bool = True) -> bool:
    """Whether the cost changed by at most ``tol_cost`` relative to ``cost``:
    ``|cost - new_cost| <= tol_cost max(cost, 1e-300)`` (``absolute``), else the signed
    decrease ``cost - new_cost`` is compared (a rise counts as below)."""
    change = abs(cost - new_cost) if absolute else cost - new_cost
    return change <= tol_cost * max(cost, 1e-300)


def no_further_decrease(predicted: float, cost: float, lam: float) -> bool:
    """Whether a damped step can no longer decrease the cost: the predicted decrease is
    below ``1e-30`` of the cost (machine precision) or the damping ``lam`` passed 1e30."""
    return predicted <= 1e-30 * max(cost, 1e-300) or lam > 1e30
