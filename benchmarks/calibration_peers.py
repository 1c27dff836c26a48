"""The honest peers of a kincal calibration: what a user would write without kincal.

FIGAROH's recipe, written out for the same problem: a forward-kinematics function of
the parameter vector, the whitened position residuals, and
``scipy.optimize.least_squares(..., method="lm")`` (MINPACK's Levenberg-Marquardt with a
forward-difference Jacobian), over exactly the parameters kincal estimates, from the same
starting values (the nominal robot, kincal's closed-form tracker frame and markers).

Two forward kinematics:

* ``numpy``: vectorised over all configurations: per link an (N, 4, 4) stack of
  Denavit-Hartenberg matrices from ``cos``/``sin`` of the joint column, multiplied with
  ``np.matmul`` down the chain (standard DH ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``, or
  Craig's modified DH ``Rx(alpha) Tx(a) Rz(theta) Tz(d)``), base and tool frames
  ``Trans Rz Ry Rx`` at the ends;
* ``pinocchio``: FIGAROH's own kinematics library.  The joint placements are set from the
  DH parameters at every evaluation, then ``pin.forwardKinematics`` per configuration
  (Pinocchio has no batched forward kinematics; FIGAROH loops over samples the same way).

Neither uses anything of kincal's kinematics: the residual model is written here from
the formulas, ``y = R_I^T (p_e + R_e m_k - t_I)`` with the tracker frame
``T_I = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares


def _rot(axis: int, a: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about x/y/z: (..., 3, 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., j, i] = s
    R[..., i, j] = -s
    return R


def frame(x: float, y: float, z: float, rz: float, ry: float, rx: float) -> np.ndarray:
    """``Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` as a 4x4 matrix."""
    T = np.eye(4)
    T[:3, :3] = _rot(2, rz) @ _rot(1, ry) @ _rot(0, rx)
    T[:3, 3] = (x, y, z)
    return T


@dataclass
class DHModel:
    """A DH robot with base/tool frames, K markers and a tracker frame, by parameter name.

    ``names``/``theta0`` are the parameter names and starting values of kincal's stacked
    problem (the same names: ``theta_offset[i] d[i] a[i] alpha[i] base.* tool.*`` then
    ``tracker.x ... tracker.marker.x ...``); the model reads its numbers by name.
    """

    names: Sequence[str]
    n: int
    convention: str                  # "standard" or "modified"
    markers: int
    block: str = "tracker"

    def __post_init__(self) -> None:
        ix = {nm: i for i, nm in enumerate(self.names)}
        self.dh = np.array([[ix[f"{p}[{i}]"] for p in ("theta_offset", "d", "a", "alpha")]
                            for i in range(1, self.n + 1)])
        fields = ("x", "y", "z", "rz", "ry", "rx")
        self.base = [ix[f"base.{f}"] for f in fields]
        self.tool = [ix[f"tool.{f}"] for f in fields]
        self.inst = [ix[f"{self.block}.{f}"] for f in fields]
        pre = ([f"{self.block}.marker"] if self.markers == 1 else
               [f"{self.block}.marker{k + 1}" for k in range(self.markers)])
        self.mark = np.array([[ix[f"{p}.{c}"] for c in "xyz"] for p in pre])

    def link(self, theta: np.ndarray, i: int, qi: np.ndarray) -> np.ndarray:
        """(N, 4, 4) transform of link ``i`` at joint values ``qi``."""
        to, d, a, al = theta[self.dh[i]]
        th = qi + to
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.cos(al), np.sin(al)
        T = np.zeros((qi.size, 4, 4))
        T[:, 3, 3] = 1.0
        if self.convention == "standard":      # Rz(th) Tz(d) Tx(a) Rx(al)
            T[:, 0, 0], T[:, 0, 1], T[:, 0, 2], T[:, 0, 3] = ct, -st * ca, st * sa, a * ct
            T[:, 1, 0], T[:, 1, 1], T[:, 1, 2], T[:, 1, 3] = st, ct * ca, -ct * sa, a * st
            T[:, 2, 1], T[:, 2, 2], T[:, 2, 3] = sa, ca, d
        else:                                  # Rx(al) Tx(a) Rz(th) Tz(d)
            T[:, 0, 0], T[:, 0, 1], T[:, 0, 3] = ct, -st, a
            T[:, 1, 0], T[:, 1, 1], T[:, 1, 2], T[:, 1, 3] = st * ca, ct * ca, -sa, -sa * d
            T[:, 2, 0], T[:, 2, 1], T[:, 2, 2], T[:, 2, 3] = st * sa, ct * sa, ca, ca * d
        return T

    def fk_numpy(self, theta: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Tool frames (N, 4, 4), vectorised over the configurations."""
        T = frame(*theta[self.base]) @ self.link(theta, 0, q[:, 0])
        for i in range(1, self.n):
            T = T @ self.link(theta, i, q[:, i])
        return T @ frame(*theta[self.tool])

    def observe(self, theta: np.ndarray, T: np.ndarray) -> np.ndarray:
        """Predicted marker positions in the tracker frame (N, K, 3) from tool frames."""
        TI = frame(*theta[self.inst])
        m = theta[self.mark]                                        # (K, 3)
        p = T[:, None, :3, 3] + np.einsum("nij,kj->nki", T[:, :3, :3], m)
        return (p - TI[:3, 3]) @ TI[:3, :3]

    # -------------------------------------------------------------- pinocchio
    def pinocchio(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """A tool-frame function ``(theta, q) -> (N, 4, 4)`` running Pinocchio's FK.

        The model is a chain of revolute-z joints; joint ``i``'s placement (in its
        parent) carries the constant part of the DH transforms around it, set from
        ``theta`` before the configurations are looped over.
        """
        import pinocchio as pin

        model = pin.Model()
        parent = 0
        for i in range(self.n):
            parent = model.addJoint(parent, pin.JointModelRZ(), pin.SE3.Identity(), f"q{i + 1}")
        data = model.createData()
        n = self.n

        def const_after(theta: np.ndarray, i: int) -> np.ndarray:
            """The constant transform following joint ``i``'s rotation (standard DH)
            or preceding it (modified DH)."""
            to, d, a, al = theta[self.dh[i]]
            if self.convention == "standard":      # Rz(to) [Rz(q)] Tz(d) Tx(a) Rx(al)
                return frame(a, 0, d, 0, 0, al)    # Tz(d) Tx(a) = Trans(a, 0, d)
            return frame(0, 0, d, 0, 0, 0)        # modified: [Rz(q)] Tz(d)

        def const_before(theta: np.ndarray, i: int) -> np.ndarray:
            to, d, a, al = theta[self.dh[i]]
            if self.convention == "standard":
                return frame(0, 0, 0, to, 0, 0)
            return frame(a, 0, 0, 0, 0, al) @ frame(0, 0, 0, to, 0, 0)  # Rx Tx = Tx Rx

        def fk(theta: np.ndarray, q: np.ndarray) -> np.ndarray:
            prev = frame(*theta[self.base])
            for i in range(n):
                M = prev @ const_before(theta, i)
                model.jointPlacements[i + 1] = pin.SE3(M[:3, :3].copy(), M[:3, 3].copy())
                prev = const_after(theta, i)
            end = prev @ frame(*theta[self.tool])
            out = np.empty((len(q), 4, 4))
            for k, qk in enumerate(q):
                pin.forwardKinematics(model, data, qk)
                out[k] = data.oMi[n].homogeneous
            return out @ end

        return fk


@dataclass
class PeerResult:
    theta: np.ndarray
    nfev: int
    status: int


def calibrate_peer(model: DHModel, q: np.ndarray, y: np.ndarray, sigma: float,
                   theta0: np.ndarray, free: Sequence[int],
                   fk: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                   ) -> PeerResult:
    """``least_squares(method="lm")`` over ``free`` from ``theta0`` (FIGAROH's recipe).

    ``y`` (N, K, 3) observed positions [m]; residuals ``(y_pred - y) / sigma``.
    """
    fk = fk or model.fk_numpy
    theta = np.array(theta0, dtype=float)
    free = np.asarray(free)

    def residuals(x: np.ndarray) -> np.ndarray:
        theta[free] = x
        return ((model.observe(theta, fk(theta, q)) - y) / sigma).ravel()

    res = least_squares(residuals, theta[free], method="lm")
    theta[free] = res.x
    return PeerResult(theta, int(res.nfev), int(res.status))
