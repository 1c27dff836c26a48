"""Timing laws and joint polynomials: how fast a path is travelled.

A *timing law* maps time ``t in [0, T]`` to a path parameter ``s in [0, 1]`` with
``s(0) = 0``, ``s(T) = 1`` and rest at both ends (``s'(0) = s'(T) = 0``):

* cubic:    ``s = 3 tau^2 - 2 tau^3``               (``tau = t / T``)
* quintic:  ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``  (also ``s'' = 0`` at both ends)
* trapezoidal velocity: constant acceleration ``a`` for ``t_a``, cruise at ``v``,
  constant deceleration; from limits on the path's speed and acceleration.

Also here: the cubic / quintic polynomial coefficients meeting given end conditions,
their evaluation (:func:`polyval`) and the sample times of a trajectory
(:func:`sample_times`).  :mod:`kincal.motion.trajectory` re-exports every name.  Units: s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError

Array = NDArray[np.float64]
TimingKind = Literal["cubic", "quintic", "trapezoidal", "linear"]
TIMING_KINDS: tuple[TimingKind, ...] = ("cubic", "quintic", "trapezoidal", "linear")

__all__ = ["TimingKind", "TIMING_KINDS", "timing_kind", "TimingLaw", "cubic", "quintic",
           "trapezoidal", "timing_law", "cubic_coefficients", "quintic_coefficients", "polyval",
           "sample_times"]


def timing_kind(name: str) -> TimingKind:
    """The :data:`TimingKind` called ``name``; a one-line error for another name."""
    for kind in TIMING_KINDS:
        if kind == name:
            return kind
    raise KincalError(f"unknown timing law {name!r}; use cubic, quintic, trapezoidal or linear")


def _check_duration(duration: float) -> None:
    if not (duration > 0 and math.isfinite(duration)):
        raise KincalError(f"a timing law needs a positive duration, got {duration}")


@dataclass(frozen=True)
class TimingLaw:
    """Normalised timing ``s(t)`` from 0 to 1 over ``[0, duration]``.

    Attributes:
        kind: ``"cubic"``, ``"quintic"``, ``"trapezoidal"`` or ``"linear"`` (constant
            speed, not at rest at the ends).
        duration: T [s].
        t_acc: trapezoidal only: acceleration (and deceleration) time [s].
        s_dot_max: trapezoidal only: cruise rate of s [1/s].
    """

    kind: TimingKind
    duration: float
    t_acc: float = 0.0
    s_dot_max: float = 0.0

    def __post_init__(self) -> None:
        _check_duration(self.duration)
        timing_kind(self.kind)

    @classmethod
    def named(cls, kind: str, duration: float) -> TimingLaw:
        """A cubic, quintic or linear law from its kind's name (text of the command line),
        with the constructor's checks in the same order (duration, then kind)."""
        _check_duration(duration)
        return cls(timing_kind(kind), duration)

    def __call__(self, t: ArrayLike) -> tuple[Array, Array, Array]:
        """``(s, s_dot [1/s], s_ddot [1/s^2])`` at times t (clamped to [0, T])."""
        T = self.duration
        tt = np.clip(np.asarray(t, dtype=float), 0.0, T)
        tau = tt / T
        if self.kind == "cubic":
            return (tau**2 * (3 - 2 * tau), 6 * tau * (1 - tau) / T, (6 - 12 * tau) / T**2)
        if self.kind == "quintic":
            return (tau**3 * (10 - 15 * tau + 6 * tau**2), 30 * tau**2 * (1 - tau)**2 / T,
                    60 * tau * (1 - tau) * (1 - 2 * tau) / T**2)
        if self.kind == "linear":
            return tau, np.full_like(tau, 1 / T), np.zeros_like(tau)
        ta, v = self.t_acc, self.s_dot_max
        a = v / ta
        rise, fall = tt < ta, tt > T - ta
        s = np.where(rise, 0.5 * a * tt**2,
                     np.where(fall, 1 - 0.5 * a * (T - tt)**2, v * (tt - 0.5 * ta)))
        sd = np.where(rise, a * tt, np.where(fall, a * (T - tt), v))
        sdd = np.where(rise, a, np.where(fall, -a, 0.0))
        return s, sd, sdd


def cubic(duration: float) -> TimingLaw:
    """Cubic rest-to-rest law ``s = 3 tau^2 - 2 tau^3`` over ``duration`` [s]."""
    return TimingLaw("cubic", float(duration))


def quintic(duration: float) -> TimingLaw:
    """Quintic law ``s = 10 tau^3 - 15 tau^4 + 6 tau^5`` (zero end velocity and acceleration)."""
    return TimingLaw("quintic", float(duration))


def trapezoidal(length: float, v_max: float, a_max: float,
                duration: float | None = None) -> TimingLaw:
    """Trapezoidal velocity law for a path of ``length`` (m or rad) within limits.

    Minimum time: if ``length >= v_max^2 / a_max``, ``t_a = v_max / a_max`` and
    ``T = length / v_max + t_a``; otherwise the profile is a triangle with
    ``t_a = sqrt(length / a_max)``, ``T = 2 t_a``.  With a longer ``duration`` the cruise
    speed drops to ``v = (a T - sqrt(a^2 T^2 - 4 a L)) / 2`` at the same acceleration.

    Raises:
        KincalError: non-positive limits or length, or a duration shorter than the
            minimum time.
    """
    L, v, a = float(length), float(v_max), float(a_max)
    if not (L > 0 and v > 0 and a > 0):
        raise KincalError("a trapezoidal law needs a positive length, v_max and a_max")
    if L >= v * v / a:
        ta, T = v / a, L / v + v / a
    else:
        ta = math.sqrt(L / a)
        T, v = 2 * ta, a * ta
    if duration is not None:
        if duration < T * (1 - 1e-12):
            raise KincalError(f"a trapezoidal move of {L:g} needs at least {T:.6g} s with "
                              f"v_max = {v_max:g}, a_max = {a_max:g}; {duration:g} s asked")
        T = float(duration)
        v = (a * T - math.sqrt(max(a * a * T * T - 4 * a * L, 0.0))) / 2
        ta = v / a
    return TimingLaw("trapezoidal", T, t_acc=ta, s_dot_max=v / L)


def timing_law(kind: str, duration: float | None = None, length: float = 1.0,
               v_max: float | None = None, a_max: float | None = None) -> TimingLaw:
    """A timing law by name (for the CLI): cubic, quintic, linear need ``duration``;
    trapezoidal needs ``v_max`` and ``a_max`` (and uses ``duration`` when given)."""
    if kind == "trapezoidal":
        if v_max is None or a_max is None:
            raise KincalError("the trapezoidal law needs --v-max and --a-max")
        return trapezoidal(length, v_max, a_max, duration)
    if duration is None:
        raise KincalError(f"the {kind} law needs a duration")
    return TimingLaw.named(kind, float(duration))


def cubic_coefficients(q0: ArrayLike, q1: ArrayLike, v0: ArrayLike, v1: ArrayLike,
                       T: float) -> Array:
    """Coefficients ``c (4, n)`` of ``q(t) = sum_k c_k t^k`` with given end positions/velocities.

    ``c0 = q0, c1 = v0, c2 = (3 dq - (2 v0 + v1) T) / T^2, c3 = (-2 dq + (v0 + v1) T) / T^3``.
    """
    q0, q1, v0, v1 = (np.asarray(x, dtype=float) for x in (q0, q1, v0, v1))
    dq = q1 - q0
    return np.stack([q0, v0, (3 * dq - (2 * v0 + v1) * T) / T**2,
                     (-2 * dq + (v0 + v1) * T) / T**3])


def quintic_coefficients(q0: ArrayLike, q1: ArrayLike, v0: ArrayLike, v1: ArrayLike,
                         a0: ArrayLike, a1: ArrayLike, T: float) -> Array:
    """Coefficients ``c (6, n)`` of the quintic meeting end positions, velocities, accelerations.

    Solves the 6 boundary equations in closed form:
    ``c3 = (20 dq - (8 v1 + 12 v0) T - (3 a0 - a1) T^2) / (2 T^3)``,
    ``c4 = (-30 dq + (14 v1 + 16 v0) T + (3 a0 - 2 a1) T^2) / (2 T^4)``,
    ``c5 = (12 dq - 6 (v1 + v0) T + (a1 - a0) T^2) / (2 T^5)``.
    """
    q0, q1, v0, v1, a0, a1 = (np.asarray(x, dtype=float) for x in (q0, q1, v0, v1, a0, a1))
    dq = q1 - q0
    return np.stack([q0, v0, a0 / 2,
                     (20 * dq - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T**2) / (2 * T**3),
                     (-30 * dq + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T**2)
                     / (2 * T**4),
                     (12 * dq - 6 * (v1 + v0) * T + (a1 - a0) * T**2) / (2 * T**5)])


def polyval(c: Array, t: ArrayLike) -> tuple[Array, Array, Array]:
    """Position, velocity and acceleration (N, n) of polynomial coefficients ``c (K, n)``."""
    t = np.asarray(t, dtype=float)[:, None]
    k = np.arange(c.shape[0])
    pw = t[..., None] ** k                                   # (N, 1, K)
    p = np.einsum("nok,kj->nj", pw, c)
    v = np.einsum("nok,kj->nj", pw[..., :-1], c[1:] * k[1:, None])
    a = np.einsum("nok,kj->nj", pw[..., :-2], c[2:] * (k[2:] * (k[2:] - 1))[:, None])
    return p, v, a


#: Most samples of one trajectory (10 million: 1 h at 1 kHz, a few hundred MB).
MAX_SAMPLES = 10_000_000


def sample_times(duration: float, dt: float) -> Array:
    """``0, dt, 2 dt, ...`` up to and including ``duration`` [s]."""
    if not (dt > 0):
        raise KincalError(f"the time step must be positive, got {dt}")
    if not math.isfinite(duration) or duration < 0:
        raise KincalError(f"the duration must be finite and >= 0, got {duration}")
    if duration / dt > MAX_SAMPLES:
        raise KincalError(f"{duration:g} s at {dt:g} s steps are {duration / dt:.3g} samples, "
                          f"more than {MAX_SAMPLES:,}: take a longer time step")
    n = int(math.floor(duration / dt + 1e-9))
    t = np.arange(n + 1) * dt
    if duration - t[-1] > 1e-9 * max(dt, 1.0):
        t = np.append(t, duration)
    return np.asarray(t, dtype=np.float64)                # already float64: no copy
