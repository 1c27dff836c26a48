"""Calibration of the five-bar: the thesis's iteration and Levenberg-Marquardt.

Model (joint space, the thesis's):  dQ = Q_m - IK(X_m, xi) = Psi dxi + V, stacked
over the m measurements (W = [Psi^1; ...; Psi^m]).  Task-space alternative:
dX = X_m - FK(Q_m, xi) = G dxi + V.  Both Jacobians are analytic
(:mod:`kincal.parallel.residuals`).

Gauss-Newton, the thesis's iteration (section 3.6):
    xi_0 = xi_N;  dxi_k = (W_k^T W_k)^-1 W_k^T dQ_k;  xi_{k+1} = xi_k + dxi_k;
    stop when max |dxi_k| < tol  (solved by least squares on unit-norm columns).
    One safeguard the thesis lacks: a step after which some measured point is
    out of the model's reach (IK) or some loop cannot close (FK) is halved until
    every point works; ``history[k]["halvings"]`` counts the halvings.
Levenberg-Marquardt: (W^T W + lambda diag(W^T W)) dxi = W^T dQ, lambda divided
by 10 after a step that lowers the cost and multiplied by 10 otherwise.

Parameters the data cannot separate are held at nominal and named
(:mod:`kincal.parallel.identifiability`).  Covariance of the estimate:
``s^2 (W^T W)^-1`` with s the residual standard deviation, given (``sigma``)
or estimated as ``sqrt(|V|^2 / (2m - p))``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kincal.defaults import FIVEBAR_MAX_ITER, FIVEBAR_TOL
from kincal.errors import IdentifiabilityError, KincalError, UnreachableError
from kincal.parallel import residuals as res
from kincal.parallel.fivebar import FiveBar
from kincal.parallel.identifiability import Identifiability, analyse

LENGTHS_FREE: tuple[str, ...] = ("l1", "l2", "l3", "l4")
ROBOT_FREE: tuple[str, ...] = res.ALL_NAMES[: res.N_ROBOT]


@dataclass
class FiveBarCalibration:
    """Result of a five-bar calibration (looks like scipy's OptimizeResult).

    Attributes:
        robot: calibrated robot; ``nominal``: the starting one.
        start: all 13 starting values (nominal robot + starting frame).
        frame: estimated measurement-frame pose (x [m], y [m], theta [rad]).
        names, values: all 13 parameters (robot + frame) after calibration.
        free: estimated parameters; ``identifiability``: what was held and why.
        std_errors: standard error of each estimated parameter (SI).
        covariance: covariance of the estimated parameters, order of ``free``.
        residuals: final residuals (N,2) [rad for 'ik', m for 'fk'].
        history: one entry per iteration (0 = nominal): parameters, step, rms.
    """

    robot: FiveBar
    nominal: FiveBar
    start: np.ndarray
    frame: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray
    free: tuple[str, ...]
    identifiability: Identifiability
    std_errors: dict[str, float]
    covariance: np.ndarray
    residuals: np.ndarray
    residual: str
    method: str
    sigma: float
    converged: bool
    iterations: int
    history: list[dict[str, Any]] = field(default_factory=list)

    @property
    def params(self) -> dict[str, float]:
        """All parameter values by name (SI)."""
        return dict(zip(self.names, self.values.tolist(), strict=True))

    @property
    def rms(self) -> float:
        """Root mean square of the final residual components."""
        return float(np.sqrt(np.mean(self.residuals**2)))

    def trajectory(self, name: str) -> np.ndarray:
        """Value of parameter ``name`` at iterations 0, 1, ... (the thesis's figures)."""
        return np.array([h["params"][name] for h in self.history])

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping for JSON (SI units, named)."""
        units = dict(zip(res.ALL_NAMES, res.ALL_UNITS, strict=True))
        return {
            "robot": self.robot.name,
            "residual": self.residual,
            "method": self.method,
            "converged": self.converged,
            "iterations": self.iterations,
            "units": {n: units[n] for n in self.names},
            "params": self.params,
            "start": dict(zip(res.ALL_NAMES, self.start.tolist(), strict=True)),
            "free": list(self.free),
            "std_errors": self.std_errors,
            "covariance": self.covariance.tolist(),
            "sigma": self.sigma,
            "rms": self.rms,
            "identifiability": self.identifiability.to_dict(),
            "history": self.history,
        }

    def to_json(self, path: str | Path) -> Path:
        """Write :meth:`to_dict` as JSON (temporary file, then rename)."""
        from kincal.parallel.files import write_text_atomic

        return write_text_atomic(path, json.dumps(self.to_dict(), indent=2) + "\n")

    def report(self) -> str:
        """Markdown summary: parameter table, identifiability, convergence."""
        unit = dict(zip(res.ALL_NAMES, res.ALL_UNITS, strict=True))
        nominal = dict(zip(res.ALL_NAMES, self.start.tolist(), strict=True))
        space = "joint space" if self.residual == "ik" else "task space"
        lines = [
            f"# Five-bar calibration: {self.robot.name}",
            "",
            f"- residual: {self.residual} ({space})"
            f", method: {self.method}, iterations: {self.iterations}, converged: {self.converged}",
            f"- residual rms: {self.rms:.4g} {'rad' if self.residual == 'ik' else 'm'}, "
            f"sigma used: {self.sigma:.4g}",
            f"- condition number (scaled): {self.identifiability.condition:.4g}",
            "",
            "| parameter | nominal | calibrated | std error | unit |",
            "|---|---|---|---|---|",
        ]
        for n in self.names:
            se = self.std_errors.get(n)
            if n not in self.free and n not in self.identifiability.held:
                continue
            f, shown = _DISPLAY[unit[n]]
            se_text = f"{se * f:.3g}" if se is not None else "held"
            lines.append(f"| {n} | {nominal[n] * f:.4f} | {self.params[n] * f:.4f} | {se_text} "
                         f"| {shown} |")
        messages = self.identifiability.describe()
        if messages:
            lines += ["", "## Not identifiable", ""] + [f"- {m}" for m in messages]
        return "\n".join(lines) + "\n"

    def __repr__(self) -> str:
        unit = dict(zip(res.ALL_NAMES, res.ALL_UNITS, strict=True))
        est = ", ".join(f"{n}={self.params[n] * _DISPLAY[unit[n]][0]:.4f} "
                        f"{_DISPLAY[unit[n]][1]}" for n in self.free)
        return (
            f"FiveBarCalibration({self.residual}/{self.method}, converged={self.converged}, "
            f"iterations={self.iterations}, rms={self.rms:.3g}, {est})"
        )


#: Shown units of the SI parameters: (factor from SI, unit): lengths in mm, angles in deg.
_DISPLAY = {"m": (1e3, "mm"), "rad": (180 / np.pi, "deg")}


def _check_inputs(q: Any, x: Any) -> tuple[np.ndarray, np.ndarray]:
    q, x = np.asarray(q, dtype=float), np.asarray(x, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2 or x.shape != q.shape:
        raise KincalError(f"readings and points must both be (N, 2), got {q.shape} and {x.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(x))):
        raise KincalError("readings and measured points must be finite numbers")
    return q, x


class _Problem:
    """Residual and Jacobian at theta for the chosen residual type, modes fixed at start."""

    def __init__(
        self,
        kind: str,
        theta0: np.ndarray,
        q: np.ndarray,
        x: np.ndarray,
        labels: Sequence[str] | None = None,
    ) -> None:
        if kind not in ("ik", "fk"):
            raise KincalError(
                f"residual must be 'ik' (joint space) or 'fk' (task space), not {kind!r}"
            )
        self.kind, self.q, self.x = kind, q, x
        self.labels = labels
        if kind == "ik":
            self.branch = res.ik_modes_nearest(theta0, q, x)
        else:
            self.branch = res.fk_assembly_nearest(theta0, q, x)

    def unreachable(self, ok: np.ndarray, when: str) -> UnreachableError:
        """Error naming the first measurement the model cannot match."""
        bad = np.flatnonzero(~ok)
        what = (
            "the measured point is out of reach" if self.kind == "ik" else "the loop cannot close"
        )
        label = self.labels[bad[0]] if self.labels is not None else f"measurement {bad[0]}"
        return UnreachableError(
            f"{when}: {label}: {what} ({bad.size} of {ok.size} measurements); the model is "
            "too far from the data (try method='lm', the other residual, or a better start)"
        )

    def __call__(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        model = res.ik_model if self.kind == "ik" else res.fk_model
        r, jac, ok = model(theta, self.q, self.x, self.branch)
        return r.reshape(-1), jac.reshape(-1, jac.shape[-1]), ok


def calibrate(
    robot: FiveBar,
    q: Any,
    x: Any,
    free: Sequence[str] = ROBOT_FREE,
    residual: str = "ik",
    method: str = "gauss-newton",
    frame: Sequence[float] = (0.0, 0.0, 0.0),
    sigma: float | None = None,
    tol: float = FIVEBAR_TOL,
    max_iter: int = FIVEBAR_MAX_ITER,
    rank_tol: float = 1e-8,
    labels: Sequence[str] | None = None,
) -> FiveBarCalibration:
    """Calibrate a five-bar from joint readings and measured end points.

    Args:
        robot: nominal robot (the start xi_N).
        q: encoder readings (N,2) [rad].
        x: measured J3 (N,2) [m] in the measurement frame.
        free: parameter names to estimate (robot names, ``frame.x``, ``frame.y``,
            ``frame.theta``); the thesis uses l1..l4.
        residual: ``"ik"`` (joint space, the thesis's) or ``"fk"`` (task space).
        method: ``"gauss-newton"`` (the thesis's iteration) or ``"lm"``.
        frame: starting pose of the measurement frame in the base frame.
        sigma: known standard deviation of a residual component; None estimates it.
        tol: stop when the largest parameter step is below tol (SI units).
        max_iter: iteration limit.
        rank_tol: relative singular-value threshold for dependent parameters.
        labels: names of the measurements for error messages (e.g. "data.csv line 7").
    """
    q, x = _check_inputs(q, x)
    unknown = [n for n in free if n not in res.ALL_NAMES]
    if unknown:
        raise KincalError(
            f"unknown five-bar parameter {unknown[0]!r}; known: {', '.join(res.ALL_NAMES)}"
        )
    if method not in ("gauss-newton", "lm"):
        raise KincalError(f"method must be 'gauss-newton' or 'lm', not {method!r}")
    theta = np.r_[robot.param_values, np.asarray(frame, dtype=float)]
    start = theta.copy()
    problem = _Problem(residual, theta, q, x, labels)
    r, jac, ok = problem(theta)
    if not np.all(ok):
        raise problem.unreachable(ok, "at the nominal parameters")
    ident = analyse(jac, res.ALL_NAMES, list(free), rank_tol)
    idx = np.array([res.ALL_NAMES.index(n) for n in ident.kept], dtype=int)
    if idx.size == 0:
        raise IdentifiabilityError(
            f"none of the requested parameters ({', '.join(free)}) affects the residuals"
        )
    if 2 * q.shape[0] <= idx.size:
        raise KincalError(f"{q.shape[0]} measurements are too few for {idx.size} parameters")
    history = [_entry(0, theta, r, 0.0)]
    solve = _gauss_newton if method == "gauss-newton" else _levenberg_marquardt
    theta, converged, history = solve(problem, theta, idx, tol, max_iter, history)
    r, jac, _ = problem(theta)
    cov, s = _covariance(jac[:, idx], r, sigma)
    robot_out = robot.with_params(theta[: res.N_ROBOT])
    return FiveBarCalibration(
        robot=robot_out,
        nominal=robot,
        start=start,
        frame=theta[res.N_ROBOT :].copy(),
        names=res.ALL_NAMES,
        values=theta,
        free=ident.kept,
        identifiability=ident,
        std_errors={n: float(np.sqrt(cov[k, k])) for k, n in enumerate(ident.kept)},
        covariance=cov,
        residuals=r.reshape(-1, 2),
        residual=residual,
        method=method,
        sigma=s,
        converged=converged,
        iterations=len(history) - 1,
        history=history,
    )


History = list[dict[str, Any]]


def _entry(k: int, theta: np.ndarray, r: np.ndarray, step: float, **extra: float
           ) -> dict[str, Any]:
    return {
        "iteration": k,
        "params": dict(zip(res.ALL_NAMES, theta.tolist(), strict=True)),
        "step": step,
        "rms": float(np.sqrt(np.mean(r**2))),
        **extra,
    }


def _scaled_step(jac: np.ndarray, r: np.ndarray, idx: np.ndarray, damping: float = 0.0
                 ) -> np.ndarray:
    """Least-squares step on unit-norm columns: min |W_s d - r|^2 + damping |d|^2."""
    w = jac[:, idx]
    norms = np.linalg.norm(w, axis=0)
    ws = w / norms
    if damping > 0.0:
        ws = np.vstack([ws, np.sqrt(damping) * np.eye(idx.size)])
        r = np.r_[r, np.zeros(idx.size)]
    d, *_ = np.linalg.lstsq(ws, r, rcond=None)
    return np.asarray(d / norms)


def _gauss_newton(problem: _Problem, theta: np.ndarray, idx: np.ndarray, tol: float,
                  max_iter: int, history: History) -> tuple[np.ndarray, bool, History]:
    """The thesis's iteration; a step after which the model cannot reach every
    measured point is halved until it can (recorded as ``halvings``)."""
    converged = False
    r, jac, _ = problem(theta)
    for k in range(1, max_iter + 1):
        step = _scaled_step(jac, r, idx)
        halvings = 0
        while True:
            trial = theta.copy()
            trial[idx] += step
            r_new, jac_new, ok = problem(trial)
            if np.all(ok):
                break
            halvings += 1
            if halvings > 30:
                raise problem.unreachable(ok, f"Gauss-Newton iteration {k}")
            step = step / 2.0
        theta, r, jac = trial, r_new, jac_new
        size = float(np.max(np.abs(step)))
        history.append(_entry(k, theta, r, size, halvings=halvings))
        if size < tol:
            converged = True
            break
    return theta, converged, history


def _levenberg_marquardt(problem: _Problem, theta: np.ndarray, idx: np.ndarray, tol: float,
                         max_iter: int, history: History) -> tuple[np.ndarray, bool, History]:
    """Levenberg-Marquardt on unit-norm columns (damping lambda I = lambda diag(W^T W))."""
    converged = False
    lam = 1e-3
    r, jac, _ = problem(theta)
    cost = float(r @ r)
    k = 0
    while k < max_iter and lam < 1e16:
        step = _scaled_step(jac, r, idx, lam)
        trial = theta.copy()
        trial[idx] += step
        r_new, jac_new, ok = problem(trial)
        cost_new = float(r_new @ r_new) if np.all(ok) else np.inf
        size = float(np.max(np.abs(step)))
        if cost_new <= cost or (size < tol and np.isfinite(cost_new)):
            k += 1
            theta, r, jac, cost = trial, r_new, jac_new, cost_new
            history.append(_entry(k, theta, r, size, damping=lam))
            lam = max(lam / 10.0, 1e-12)
            if size < tol:
                converged = True
                break
        else:
            lam *= 10.0
    return theta, converged, history


def _covariance(w: np.ndarray, r: np.ndarray, sigma: float | None) -> tuple[np.ndarray, float]:
    """s^2 (W^T W)^-1 computed on unit-norm columns; s given or sqrt(|r|^2 / (M - p))."""
    m, p = w.shape
    s = float(sigma) if sigma is not None else float(np.sqrt(r @ r / max(m - p, 1)))
    norms = np.linalg.norm(w, axis=0)
    _, sv, vt = np.linalg.svd(w / norms, full_matrices=False)
    inv = (vt.T / sv**2) @ vt
    return s**2 * inv / np.outer(norms, norms), s
