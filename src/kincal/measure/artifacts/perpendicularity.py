"""Perpendicularity of two probed segments: ``(X_c - X_a) . (X_d - X_b) = 0`` (cross-bar).

The residual is the cosine of the angle between the segments ``u = X_c - X_a`` and
``v = X_d - X_b`` (dimensionless; for a near right angle it equals the deviation from
90 degrees in radians, ``cos(pi/2 - delta) ~ delta``), which is the procedure's
``AC . BD = 0`` divided by ``|AC| |BD|``:

    e = u . v / (|u| |v|)
    de/du = v / (|u| |v|) - e u / |u|^2,      de/dv = u / (|u| |v|) - e v / |v|^2

The deviation from the right angle reported to people is ``asin(e)`` [rad].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def cosines(u: Array, v: Array) -> tuple[Array, Array, Array]:
    """``cos(angle(u, v))`` (K,) and its gradients w.r.t. ``u`` and ``v`` (K, 3)."""
    nu = np.linalg.norm(u, axis=1)
    nv = np.linalg.norm(v, axis=1)
    c = np.einsum("ki,ki->k", u, v) / (nu * nv)
    gu = v / (nu * nv)[:, None] - (c / nu**2)[:, None] * u
    gv = u / (nu * nv)[:, None] - (c / nv**2)[:, None] * v
    return c, gu, gv


def perpendicularity_residuals(Xa: Array, Xc: Array, Xb: Array, Xd: Array,
                               dXa: Array | None = None, dXc: Array | None = None,
                               dXb: Array | None = None, dXd: Array | None = None
                               ) -> tuple[Array, Array | None]:
    """``e = cos(angle(X_c - X_a, X_d - X_b))`` (K,) and ``de/dtheta`` (K, P).

    The ``dX`` are ``dX/dtheta`` (K, 3, P) of the four points.
    """
    c, gu, gv = cosines(Xc - Xa, Xd - Xb)
    if dXa is None or dXb is None or dXc is None or dXd is None:
        return c, None
    J = np.einsum("ki,kip->kp", gu, dXc - dXa) + np.einsum("ki,kip->kp", gv, dXd - dXb)
    return c, J


def perpendicularity_variance(Xa: Array, Xc: Array, Xb: Array, Xd: Array, Ca: Array,
                              Cc: Array, Cb: Array, Cd: Array) -> Array:
    """Variance of the cosine (K,) from independent point covariances (K, 3, 3)."""
    _, gu, gv = cosines(Xc - Xa, Xd - Xb)
    value: Array = (np.einsum("ki,kij,kj->k", gu, Ca + Cc, gu)
                    + np.einsum("ki,kij,kj->k", gv, Cb + Cd, gv))
    return value


def angle_deviation(c: Array) -> Array:
    """Deviation from a right angle [rad] of segments whose cosine is ``c``: ``asin(c)``."""
    return np.arcsin(np.clip(c, -1.0, 1.0))
