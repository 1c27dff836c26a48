"""Calibration residuals of the five-bar and their analytic Jacobians.

Parameters ``theta`` (13, SI): the robot's ten (see
:data:`kincal.parallel.kinematics.PARAM_NAMES`) followed by the pose of
the measurement frame in the robot's base frame, ``frame.x, frame.y`` [m],
``frame.theta`` [rad]: a measured point x_m maps to ``x = t + R(theta_f) x_m``.

Joint-space (inverse-kinematics) residual, the thesis's model (eq. 3.5.1-3.6.4):

    dQ = Q_m - IK(X_m, xi)  ~=  Psi(X_m, xi) dxi,   Psi = d IK / d xi.

Psi comes from implicit differentiation of each arm's closure with its passive
joint eliminated,  f_i = |x - B_i - l_i u(beta_i)|^2 - l_{i+2}^2 = 0.  With
``e_i = x - J_i``, ``D_i = u(beta_i) x e_i = l_{i+2} sin(beta_{i+2} - beta_i)``:

    d beta_i/d l_i     = -(e_i . u_i) / (l_i D_i)
    d beta_i/d l_{i+2} = -l_{i+2} / (l_i D_i)
    d beta_i/d B_i     = -e_i / (l_i D_i)
    d beta_i/d x       =  e_i / (l_i D_i)          (then x = t + R x_m)
    d q_i / d offset_i = -1                          (q = beta - offset)

(the thesis's eq. 3.5.28-3.5.30 are this, written with DH Jacobians; its last
vector there should read [dl1, dl3, dl2, dl4]).  Only Type-1 singularities
(D_i = 0) make Psi blow up.

Task-space (forward-kinematics) residual, for comparison:

    dX = X_m - R^T (FK(Q_m, xi) - t)  ~=  G dxi,

    G_robot = R^T dx/dxi,  dx/dxi = -A^{-1} dg/dxi,  A = [e_1^T; e_2^T],

with the closures g_i = (|e_i|^2 - l_{i+2}^2) / 2 (dg_i/dl_i = -e_i . u_i,
dg_i/dl_{i+2} = -l_{i+2}, dg_i/dB_i = -e_i, dg_i/doffset_i = -l_i D_i), and
dX/dt = -R^T, dX/dtheta_f = -perp(R^T (x - t)).  Only Type-2 singularities
(det A = 0) make G blow up.
"""

from __future__ import annotations

import numpy as np

from kincal.parallel import kinematics as kin

FRAME_NAMES: tuple[str, ...] = ("frame.x", "frame.y", "frame.theta")
FRAME_UNITS: tuple[str, ...] = ("m", "m", "rad")
ALL_NAMES: tuple[str, ...] = kin.PARAM_NAMES + FRAME_NAMES
ALL_UNITS: tuple[str, ...] = kin.PARAM_UNITS + FRAME_UNITS
N_ROBOT = len(kin.PARAM_NAMES)


def perp(v: np.ndarray) -> np.ndarray:
    """Rotation by +90 degrees: (x, y) -> (-y, x)."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def rotation(angle: float) -> np.ndarray:
    """2x2 rotation matrix R(angle)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def to_base(theta: np.ndarray, x_m: np.ndarray) -> np.ndarray:
    """Measured points (N,2) in the robot base frame: ``t + R x_m``."""
    return np.asarray(theta[10:12] + x_m @ rotation(theta[12]).T)


def ik_model(
    theta: np.ndarray, q_m: np.ndarray, x_m: np.ndarray, modes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint-space residual dQ (N,2) [rad], Jacobian Psi (N,2,13), reach mask (N,).

    dQ = wrap(Q_m - IK(t + R x_m, xi)); rows out of reach are NaN.
    """
    p = theta[:N_ROBOT]
    x = to_base(theta, x_m)
    q_model, ok = kin.ik(p, x, modes)
    beta, j1, j2 = kin.elbows(p, np.where(ok[:, None], q_model, 0.0))
    u = kin.unit(beta)  # (N, arm, 2)
    e = x[:, None, :] - np.stack([j1, j2], axis=1)  # (N, arm, 2)
    lp, ld = p[0:2], p[2:4]
    lD = lp * kin.cross2(u, e)  # (N, arm)
    n = x.shape[0]
    psi = np.zeros((n, 2, len(ALL_NAMES)))
    arm = np.arange(2)
    psi[:, arm, arm] = -np.sum(e * u, axis=2) / lD
    psi[:, arm, 2 + arm] = -ld / lD
    dbdx = e / lD[..., None]  # (N, arm, 2)
    for i in range(2):
        psi[:, i, 4 + 2 * i : 6 + 2 * i] = -dbdx[:, i]
        psi[:, i, 8 + i] = -1.0
    psi[:, :, 10:12] = dbdx
    psi[:, :, 12] = np.sum(dbdx * perp(x_m @ rotation(theta[12]).T)[:, None, :], axis=2)
    dq = kin.wrap(q_m - q_model)
    return dq, psi, ok


def fk_model(
    theta: np.ndarray, q_m: np.ndarray, x_m: np.ndarray, sigma: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Task-space residual dX (N,2) [m], Jacobian G (N,2,13), closure mask (N,).

    dX = X_m - R^T (FK(Q_m, xi) - t); rows where the loop cannot close are NaN.
    """
    p = theta[:N_ROBOT]
    x, ok = kin.fk(p, q_m, sigma)
    beta, j1, j2 = kin.elbows(p, q_m)
    u = kin.unit(beta)
    e = x[:, None, :] - np.stack([j1, j2], axis=1)  # (N, arm, 2)
    n = x.shape[0]
    dg = np.zeros((n, 2, N_ROBOT))
    arm = np.arange(2)
    dg[:, arm, arm] = -np.sum(e * u, axis=2)
    dg[:, arm, 2 + arm] = -p[2:4]
    for i in range(2):
        dg[:, i, 4 + 2 * i : 6 + 2 * i] = -e[:, i]
        dg[:, i, 8 + i] = -p[i] * kin.cross2(u[:, i], e[:, i])
    a = np.where(ok[:, None, None], e, np.eye(2))  # keep solve finite on failed rows
    dxdp = -np.linalg.solve(a, dg)  # (N, 2, 10)
    rt = rotation(theta[12]).T
    x_model = (x - theta[10:12]) @ rt.T
    g = np.zeros((n, 2, len(ALL_NAMES)))
    g[:, :, :N_ROBOT] = np.einsum("ab,nbk->nak", rt, dxdp)
    g[:, :, 10:12] = -rt
    g[:, :, 12] = -perp(x_model)
    return x_m - x_model, g, ok


def ik_modes_nearest(theta: np.ndarray, q_m: np.ndarray, x_m: np.ndarray) -> np.ndarray:
    """Working modes (N,2) whose IK of x_m is nearest the readings q_m, per arm.

    Each arm's angle depends only on its own elbow sign, so the choice is made
    arm by arm; rows out of reach keep +1.
    """
    x = to_base(theta, x_m)
    p = theta[:N_ROBOT]
    q_plus, _ = kin.ik(p, x, np.ones_like(q_m))
    q_minus, _ = kin.ik(p, x, -np.ones_like(q_m))
    d_plus = np.abs(kin.wrap(q_m - q_plus))
    d_minus = np.abs(kin.wrap(q_m - q_minus))
    return np.where(d_minus < d_plus, -1, 1)


def fk_assembly_nearest(theta: np.ndarray, q_m: np.ndarray, x_m: np.ndarray) -> np.ndarray:
    """Assembly modes (N,) whose FK of q_m is nearest the measured points x_m."""
    x = to_base(theta, x_m)
    x_plus, x_minus, _ = kin.fk_both(theta[:N_ROBOT], q_m)
    d_plus = np.linalg.norm(x - x_plus, axis=1)
    d_minus = np.linalg.norm(x - x_minus, axis=1)
    return np.where(d_minus < d_plus, -1, 1)
