"""Distance between two probed points equals a known length (cross-bar arms, ball-bar).

For sockets ``a`` and ``b`` of one placement, seated at the points ``X_a``, ``X_b``
[m] (probe tips, or socket means / parameters, see :mod:`.coincidence`):

    e = |X_b - X_a| - L                        [m]
    de = u . (dX_b - dX_a),   u = (X_b - X_a) / |X_b - X_a|

Distances are invariant under any rigid motion of all the points: the robot's base
frame (six parameters) and, for a ``length`` probe, rotations of the tool about the
probe axis never change them; the identifiability analysis finds these zero columns
by itself.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def distances(Xa: Array, Xb: Array) -> tuple[Array, Array]:
    """Distances ``|X_b - X_a|`` (K,) [m] and unit vectors ``u`` (K, 3) from a to b."""
    d = Xb - Xa
    n = np.linalg.norm(d, axis=1)
    u = d / np.where(n > 0, n, 1.0)[:, None]
    return n, u


def distance_residuals(Xa: Array, Xb: Array, length: Array, dXa: Array | None = None,
                       dXb: Array | None = None) -> tuple[Array, Array | None]:
    """``e = |X_b - X_a| - L`` (K,) [m] and ``de/dtheta`` (K, P) from ``dX/dtheta`` (K, 3, P)."""
    n, u = distances(Xa, Xb)
    e = n - length
    if dXa is None or dXb is None:
        return e, None
    return e, np.einsum("ki,kip->kp", u, dXb - dXa)


def distance_variance(Xa: Array, Xb: Array, Ca: Array, Cb: Array) -> Array:
    """Variance of ``|X_b - X_a|`` (K,) [m^2] from independent point covariances (K, 3, 3)."""
    _, u = distances(Xa, Xb)
    value: Array = np.einsum("ki,kij,kj->k", u, Ca + Cb, u)
    return value
