"""Batched kinematics of the planar five-bar (the parallel part of a dual SCARA).

Pure array functions on a parameter vector ``p`` (SI units) in the order of
:data:`PARAM_NAMES`::

    p = [l1, l2, l3, l4, base1.x, base1.y, base2.x, base2.y, offset1, offset2]

Geometry.  Base joints B1, B2; encoder readings q1, q2 give the motor angles
``beta_i = q_i + offset_i``; elbows ``J_i = B_i + l_i u(beta_i)`` with
``u(a) = (cos a, sin a)``; the end point J3 is at distance l3 from J1 and l4
from J2.  The passive angles beta3, beta4 are the absolute directions of the
distal links: ``J3 = J1 + l3 u(beta3) = J2 + l4 u(beta4)``.

Every angle of a triangle with sides (a, b, c) is taken as

    angle between a and b = atan2(sqrt(P), a^2 + b^2 - c^2),
    P = (a+b+c)(-a+b+c)(a-b+c)(a+b-c) = (4 * area)^2,

which is the law of cosines written without ``arccos`` (accurate near 0 and
pi); ``P < 0`` means the triangle cannot close.

Sign conventions (both +1 or -1):
    assembly sigma = sign((J2 - J1) x (J3 - J1)): +1 puts J3 left of J1->J2.
    working mode s_i = sign((J3 - B_i) x (J_i - B_i)): +1 puts elbow i left of
    B_i->J3 (counter-clockwise from it).  A mode string ``"+-"`` is (s1, s2).
"""

from __future__ import annotations

import numpy as np

PARAM_NAMES: tuple[str, ...] = (
    "l1",
    "l2",
    "l3",
    "l4",
    "base1.x",
    "base1.y",
    "base2.x",
    "base2.y",
    "offset1",
    "offset2",
)
PARAM_UNITS: tuple[str, ...] = ("m",) * 8 + ("rad",) * 2
MODES: tuple[str, ...] = ("++", "+-", "-+", "--")


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z-component of the planar cross product ``a x b`` over the last axis."""
    return np.asarray(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])


def unit(angle: np.ndarray) -> np.ndarray:
    """u(a) = (cos a, sin a), shape ``angle.shape + (2,)``."""
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def wrap(angle: np.ndarray) -> np.ndarray:
    """Angle wrapped to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def triangle_angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angle between sides a and b of the triangle (a, b, c), and its closure mask.

    angle = atan2(sqrt(P), a^2 + b^2 - c^2) in [0, pi]; closes where P >= 0.
    """
    P = (a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c)
    ok = P >= 0.0
    angle = np.arctan2(np.sqrt(np.where(ok, P, 0.0)), a * a + b * b - c * c)
    return angle, ok


def bases(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """B1, B2 as (2,) arrays."""
    return p[4:6], p[6:8]


def elbows(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motor angles beta (N,2) and elbows J1, J2 (N,2): ``J_i = B_i + l_i u(q_i + o_i)``."""
    beta = q + p[8:10]
    b1, b2 = bases(p)
    return beta, b1 + p[0] * unit(beta[:, 0]), b2 + p[1] * unit(beta[:, 1])


def fk_both(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both circle intersections J3 for readings q (N,2).

    With d = J2 - J1, r = |d|, gamma1 the triangle angle at J1 (sides l3, r, l4):
    ``J3(sigma) = J1 + l3 u(atan2(d) + sigma gamma1)``.

    Returns:
        x_plus, x_minus (N,2) for sigma = +1, -1 (NaN where the loop cannot
        close) and the mask ``ok`` (N,) of closing configurations.
    """
    _, j1, j2 = elbows(p, q)
    d = j2 - j1
    r = np.hypot(d[:, 0], d[:, 1])
    gamma1, ok = triangle_angle(np.full_like(r, p[2]), r, np.full_like(r, p[3]))
    ok &= r > 0.0
    phi = np.arctan2(d[:, 1], d[:, 0])
    nan = np.where(ok, 0.0, np.nan)[:, None]
    x_plus = j1 + p[2] * unit(phi + gamma1) + nan
    x_minus = j1 + p[2] * unit(phi - gamma1) + nan
    return x_plus, x_minus, ok


def continuous_assembly(x_plus: np.ndarray, x_minus: np.ndarray, start: int) -> np.ndarray:
    """Assembly signs (N,) that follow a path of configurations by continuity.

    Row 0 takes ``start``; row 1 the branch nearest row 0's J3; every later row
    the branch nearest the linear extrapolation ``2 x_{k-1} - x_{k-2}`` of the
    two previous points, so a path that passes through a Type-2 singularity
    (where the branches meet) carries on smoothly across it.  Rows that do not
    close keep the previous branch.

    The choice is a finite automaton whose state is (branch at k, branch at
    k-1); each row is a map of the 4 states, and the states along the path are
    the prefix compositions of these maps, computed by a log2(N)-step parallel
    scan, with no loop over the rows.
    """
    n = x_plus.shape[0]
    br = np.stack([x_plus, x_minus], axis=1)  # (N, branch 0 = +1 / 1 = -1, 2)
    states = np.arange(4)
    cur, prev = states // 2, states % 2  # state = 2 * (branch at k) + (branch at k-1)
    first = 0 if start > 0 else 1
    maps = np.empty((n, 4), dtype=int)
    maps[0] = 3 * first  # constant map to (start, start)
    if n > 1:
        last = br[:-1][:, cur]  # (N-1, 4, 2): x_{k-1} on the state's branch
        older = np.concatenate([last[:1], br[:-2][:, prev]])  # x_{k-2}; row k = 1 unused
        first_row = (np.arange(n - 1) == 0)[:, None, None]
        ref = np.where(first_row, last, 2.0 * last - older)
        d = np.linalg.norm(br[1:][:, None, :, :] - ref[:, :, None, :], axis=3)  # (N-1, 4, 2)
        keep = ~(d[:, states, 1 - cur] < d[:, states, cur])  # NaN compares False: keep
        maps[1:] = 2 * np.where(keep, cur, 1 - cur) + cur
    prefix = maps.copy()
    offset = 1
    while offset < n:
        prefix[offset:] = np.take_along_axis(prefix[offset:], prefix[:-offset], axis=1)
        offset *= 2
    return np.where(prefix[:, 0] // 2 == 0, 1, -1)


def fk(p: np.ndarray, q: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J3 (N,2) for readings q (N,2) and assembly signs sigma (N,); and the mask ``ok``."""
    x_plus, x_minus, ok = fk_both(p, q)
    return np.where((sigma > 0)[:, None], x_plus, x_minus), ok


def ik(p: np.ndarray, x: np.ndarray, modes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Readings q (N,2) that put J3 at x (N,2) in working modes ``modes`` (N,2) of +-1.

    With rho_i = |x - B_i|, phi_i = atan2(x - B_i) and alpha_i the triangle
    angle at B_i (sides l_i, rho_i, l_{i+2}):
    ``beta_i = phi_i + s_i alpha_i``, ``q_i = wrap(beta_i - offset_i)``.

    Returns:
        q (NaN where x is out of reach of an arm) and the mask ``ok`` (N,).
    """
    b = np.stack(bases(p))  # (2 arms, 2)
    e = x[:, None, :] - b[None]  # (N, arm, 2)
    rho = np.hypot(e[..., 0], e[..., 1])
    prox = np.broadcast_to(p[0:2], rho.shape)
    dist = np.broadcast_to(p[2:4], rho.shape)
    alpha, ok = triangle_angle(prox, rho, dist)
    ok = np.all(ok & (rho > 0.0), axis=1)
    beta = np.arctan2(e[..., 1], e[..., 0]) + modes * alpha
    q = wrap(beta - p[8:10])
    return np.where(ok[:, None], q, np.nan), ok


def passive(p: np.ndarray, q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Absolute passive angles (N,2): beta3 = atan2(J3 - J1), beta4 = atan2(J3 - J2)."""
    _, j1, j2 = elbows(p, q)
    e1, e2 = x - j1, x - j2
    return np.stack([np.arctan2(e1[:, 1], e1[:, 0]), np.arctan2(e2[:, 1], e2[:, 0])], axis=1)


def signs(p: np.ndarray, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Assembly sigma (N,) and working modes s (N,2) of the configuration (q, x)."""
    _, j1, j2 = elbows(p, q)
    sigma = np.where(cross2(j2 - j1, x - j1) >= 0.0, 1, -1)
    b1, b2 = bases(p)
    s = np.stack([cross2(x - b1, j1 - b1), cross2(x - b2, j2 - b2)], axis=1)
    return sigma, np.where(s >= 0.0, 1, -1)


def singularity_measures(
    p: np.ndarray, q: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Normalised distances to the two kinds of singularity, in [0, 1].

    Type 1 (inverse / serial, arm i stretched or folded; det dF/dq = 0):
        t1_i = |u(beta_i) x (J3 - J_i)| / l_{i+2} = |sin(beta_{i+2} - beta_i)|, (N,2).
    Type 2 (direct / parallel, distal links aligned; det dF/dx = 0):
        t2 = |(J3 - J1) x (J3 - J2)| / (l3 l4) = |sin(beta4 - beta3)|, (N,).
    """
    beta, j1, j2 = elbows(p, q)
    e1, e2 = x - j1, x - j2
    u = unit(beta)
    t1 = np.stack([np.abs(cross2(u[:, 0], e1)) / p[2], np.abs(cross2(u[:, 1], e2)) / p[3]], axis=1)
    t2 = np.abs(cross2(e1, e2)) / (p[2] * p[3])
    return t1, t2


def mode_signs(mode: str) -> np.ndarray:
    """'+-' -> array([1, -1])."""
    return np.array([1 if c == "+" else -1 for c in mode])
