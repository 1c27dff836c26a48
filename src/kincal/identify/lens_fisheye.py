"""The fisheye lens: OpenCV's equidistant (Kannala-Brandt) model, its Jacobian and inverse.

A camera-frame point ``x = (x1, x2, x3)`` [m] makes the angle ``theta`` [rad] with the
optical axis; the lens maps it to the distorted angle ``theta_d`` and the pixel::

    rho = sqrt(x1^2 + x2^2),   theta = atan2(rho, x3)
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    s = theta_d / rho,   u = fx s x1 + cx,   v = fy s x2 + cy                     [px]

(``lens = fx fy cx cy k1 k2 k3 k4``; OpenCV's ``cv2.fisheye`` with zero skew, whose
``theta = atan(rho / x3)`` is the same in front of the camera.  ``atan2`` keeps points
beyond 90 deg of the axis valid.)  Plain NumPy: the pixels, their analytic Jacobian
(:func:`fisheye_jacobian`) and the pinhole pixels of the same rays
(:func:`undistort_fisheye`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

FISHEYE = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

__all__ = ["FISHEYE", "project_fisheye", "fisheye_jacobian", "undistort_fisheye"]

#: Below this ``rho / x3`` the ray is taken on the axis (the limit ``s -> (1 + ...)/x3``).
_AXIS = 1e-12


def _lens(lens: ArrayLike) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(lens, dtype=float).reshape(8))


def _angles(x: Array) -> tuple[Array, Array]:
    rho = np.hypot(x[:, 0], x[:, 1])
    return rho, np.arctan2(rho, x[:, 2])


def project_fisheye(x: Array, lens: ArrayLike) -> Array:
    """Raw pixels (n, 2) [px] of camera-frame points ``x`` (n, 3) [m] (module docstring)."""
    fx, fy, cx, cy, k1, k2, k3, k4 = _lens(lens)
    rho, th = _angles(x)
    t2 = th * th
    thd = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    on_axis = rho <= _AXIS * np.abs(x[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(on_axis, 1.0 / x[:, 2], thd / np.where(on_axis, 1.0, rho))
    return np.column_stack([fx * s * x[:, 0] + cx, fy * s * x[:, 1] + cy])


def fisheye_jacobian(x: Array, lens: ArrayLike) -> tuple[Array, Array]:
    """``d uv / d x`` (n, 2, 3) [px/m] and ``d uv / d lens`` (n, 2, 8) of
    :func:`project_fisheye`, analytic::

        d theta / d x = (x3 x1, x3 x2, -rho^2) / (rho (rho^2 + x3^2))
        d theta_d / d theta = 1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8
        d s / d x = (theta_d' d theta / d x - s d rho / d x) / rho,  d rho / d x = (x1, x2, 0) / rho
        d u / d x = fx (s e1 + x1 d s / d x),   d v / d x = fy (s e2 + x2 d s / d x)
        d u / d (fx, cx, k_j) = (s x1, 1, x1 theta^(2j+1) / rho),  likewise v with fy, cy, x2

    Points on the optical axis (``rho = 0``) are not differentiable in this form; a
    board corner exactly on the axis is moved off it by ``1e-12 x3``."""
    fx, fy, cx, cy, k1, k2, k3, k4 = _lens(lens)
    x = np.array(x, dtype=float)
    rho, th = _angles(x)
    tiny = rho < _AXIS * np.abs(x[:, 2])
    x[tiny, 0] += _AXIS * np.abs(x[tiny, 2])
    rho, th = _angles(x)
    t2 = th * th
    thd = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    dthd = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    s = thd / rho
    r2z2 = rho**2 + x[:, 2] ** 2
    dth = np.column_stack([x[:, 2] * x[:, 0], x[:, 2] * x[:, 1], -rho**2]) / (rho * r2z2)[:, None]
    drho = np.column_stack([x[:, 0], x[:, 1], np.zeros(len(x))]) / rho[:, None]
    ds = (dthd[:, None] * dth - s[:, None] * drho) / rho[:, None]
    jx = np.zeros((len(x), 2, 3))
    jx[:, 0] = fx * (x[:, 0, None] * ds)
    jx[:, 1] = fy * (x[:, 1, None] * ds)
    jx[:, 0, 0] += fx * s
    jx[:, 1, 1] += fy * s
    jl = np.zeros((len(x), 2, 8))
    jl[:, 0, 0] = s * x[:, 0]
    jl[:, 1, 1] = s * x[:, 1]
    jl[:, 0, 2] = 1.0
    jl[:, 1, 3] = 1.0
    for j in range(4):
        p = th ** (2 * j + 3) / rho
        jl[:, 0, 4 + j] = fx * x[:, 0] * p
        jl[:, 1, 4 + j] = fy * x[:, 1] * p
    return jx, jl


def undistort_fisheye(uv: Array, lens: ArrayLike, iterations: int = 30) -> Array:
    """The pinhole pixels ``(fx tan(theta) cos(phi) + cx, fy tan(theta) sin(phi) + cy)``
    (n, 2) [px] of raw pixels ``uv``: ``theta_d`` is the length of
    ``((u - cx) / fx, (v - cy) / fy)``, ``theta`` solves ``theta_d(theta) = theta_d`` by
    Newton's method from ``theta = theta_d`` (converged to 1e-14 rad or ``iterations``).
    A ray 90 deg or more off the axis has no pinhole image: NaN."""
    fx, fy, cx, cy, k1, k2, k3, k4 = _lens(lens)
    a, b = (uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy
    thd = np.hypot(a, b)
    th = thd.copy()
    for _ in range(iterations):
        t2 = th * th
        f = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - thd
        df = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        step = f / df
        th = th - step
        if float(np.abs(step).max(initial=0.0)) < 1e-14:
            break
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(thd > 0, np.tan(th) / np.where(thd > 0, thd, 1.0), 1.0)
    scale[(th >= 0.5 * np.pi) | (th < 0)] = np.nan
    return np.column_stack([fx * a * scale + cx, fy * b * scale + cy])
