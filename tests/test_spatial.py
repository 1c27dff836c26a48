"""SE(3) / SO(3) helpers against independent computations (scipy's Rotation, explicit
formulas, finite differences)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kincal.errors import KincalError
from kincal.spatial import (
    exp_so3,
    homogeneous,
    inverse,
    log_so3,
    matrix_to_angles,
    matrix_to_rpy,
    matrix_to_xyzrpy,
    matrix_to_zyz,
    pose_error,
    rate_matrix,
    rotx,
    roty,
    rotz,
    rpy_to_matrix,
    skew,
    xyzrpy_to_matrix,
    zyz_to_matrix,
)

RNG = np.random.default_rng(20240611)
TIGHT = 1e-12


def _vee(S: np.ndarray) -> np.ndarray:
    return np.stack([S[..., 2, 1], S[..., 0, 2], S[..., 1, 0]], -1)


# --------------------------------------------------------------------------- rotations
@pytest.mark.parametrize("fn, axis", [(rotx, "x"), (roty, "y"), (rotz, "z")])
def test_elementary_rotations_match_scipy(fn, axis):
    a = RNG.uniform(-4, 4, 50)
    want = Rotation.from_euler(axis, a[:, None]).as_matrix()
    np.testing.assert_allclose(fn(a), want, atol=TIGHT)
    assert fn(0.3).shape == (3, 3)
    np.testing.assert_allclose(fn(0.3), Rotation.from_euler(axis, 0.3).as_matrix(), atol=TIGHT)


def test_rotx_explicit_entries():
    c, s = np.cos(0.7), np.sin(0.7)
    np.testing.assert_allclose(rotx(0.7), [[1, 0, 0], [0, c, -s], [0, s, c]], atol=TIGHT)
    np.testing.assert_allclose(roty(0.7), [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=TIGHT)
    np.testing.assert_allclose(rotz(0.7), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=TIGHT)


def test_homogeneous_inverse_and_skew():
    R = Rotation.random(20, random_state=1).as_matrix()
    p = RNG.normal(size=(20, 3))
    T = homogeneous(R, p)
    assert T.shape == (20, 4, 4)
    np.testing.assert_array_equal(T[:, 3], np.tile([0, 0, 0, 1.0], (20, 1)))
    np.testing.assert_allclose(inverse(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=TIGHT)
    np.testing.assert_allclose(inverse(T), np.linalg.inv(T), atol=TIGHT)
    v, w = RNG.normal(size=(2, 20, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(v), w), np.cross(v, w), atol=TIGHT)
    np.testing.assert_allclose(skew(v), -np.swapaxes(skew(v), 1, 2), atol=0)


# --------------------------------------------------------------------------- RPY / ZYZ
def test_rpy_matches_scipy_intrinsic_zyx():
    rpy = np.column_stack([RNG.uniform(-np.pi, np.pi, 200), RNG.uniform(-1.5, 1.5, 200),
                           RNG.uniform(-np.pi, np.pi, 200)])
    want = Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix()
    np.testing.assert_allclose(rpy_to_matrix(rpy), want, atol=TIGHT)
    np.testing.assert_allclose(matrix_to_rpy(want), rpy, atol=1e-11)


def test_zyz_matches_scipy_intrinsic_zyz():
    zyz = np.column_stack([RNG.uniform(-np.pi, np.pi, 200), RNG.uniform(0.01, np.pi - 0.01, 200),
                           RNG.uniform(-np.pi, np.pi, 200)])
    want = Rotation.from_euler("ZYZ", zyz).as_matrix()
    np.testing.assert_allclose(zyz_to_matrix(zyz), want, atol=TIGHT)
    np.testing.assert_allclose(matrix_to_zyz(want), zyz, atol=1e-11)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 1e-7,
                                   np.pi / 2 - 1e-13, 0.0])
def test_rpy_round_trip_near_gimbal_lock(pitch):
    for roll, yaw in RNG.uniform(-3, 3, (10, 2)):
        R = rpy_to_matrix([roll, pitch, yaw])
        back = matrix_to_rpy(R)
        assert -np.pi / 2 <= back[1] <= np.pi / 2
        # the angles may differ in the lock, the rotation must not
        np.testing.assert_allclose(rpy_to_matrix(back), R, atol=1e-9)


@pytest.mark.parametrize("theta", [0.0, 1e-9, np.pi - 1e-9, 1e-13, 1.0, np.pi, np.pi - 1e-13])
def test_zyz_round_trip_near_singular(theta):
    for phi, psi in RNG.uniform(-3, 3, (10, 2)):
        R = zyz_to_matrix([phi, theta, psi])
        back = matrix_to_zyz(R)
        assert 0.0 <= back[1] <= np.pi
        np.testing.assert_allclose(zyz_to_matrix(back), R, atol=1e-9)


def test_xyzrpy_round_trip():
    v = np.column_stack([RNG.normal(size=(50, 3)), RNG.uniform(-3, 3, 50),
                         RNG.uniform(-1.5, 1.5, 50), RNG.uniform(-3, 3, 50)])
    T = xyzrpy_to_matrix(v)
    np.testing.assert_allclose(T[:, :3, :3], Rotation.from_euler("ZYX", v[:, 5:2:-1]).as_matrix(),
                               atol=TIGHT)
    np.testing.assert_allclose(matrix_to_xyzrpy(T), v, atol=1e-11)


def test_unknown_representation_is_a_kincal_error():
    with pytest.raises(KincalError, match="xyz"):
        matrix_to_angles(np.eye(3), "xyz")
    with pytest.raises(KincalError, match="xyz"):
        rate_matrix(np.zeros(3), "xyz")


# --------------------------------------------------------------------------- exp / log
def test_exp_matches_scipy_rotvec():
    w = RNG.normal(size=(300, 3)) * RNG.uniform(0, 3.1, (300, 1))
    np.testing.assert_allclose(exp_so3(w), Rotation.from_rotvec(w).as_matrix(), atol=TIGHT)
    tiny = np.array([1e-10, -2e-10, 3e-11])
    np.testing.assert_allclose(exp_so3(tiny), np.eye(3) + skew(tiny), atol=1e-18)
    np.testing.assert_array_equal(exp_so3(np.zeros(3)), np.eye(3))


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-3, 0.5, 2.0, 3.0, np.pi - 0.1,
                                   np.pi - 1e-2, np.pi - 2e-3])
def test_log_inverts_exp(angle):
    axes = RNG.normal(size=(50, 3))
    w = axes / np.linalg.norm(axes, axis=1, keepdims=True) * angle
    got = log_so3(Rotation.from_rotvec(w).as_matrix())
    np.testing.assert_allclose(got, w, atol=1e-10)


@pytest.mark.parametrize("delta", [9e-4, 1e-4, 1e-6])
def test_log_near_pi(delta):
    """Within 1e-3 of pi the axis must come from the symmetric part alone."""
    axes = RNG.normal(size=(50, 3))
    w = axes / np.linalg.norm(axes, axis=1, keepdims=True) * (np.pi - delta)
    got = log_so3(Rotation.from_rotvec(w).as_matrix())
    np.testing.assert_allclose(got, w, atol=1e-9)


def test_log_at_exactly_pi_is_a_valid_rotation_vector():
    for axis in [np.eye(3)[0], np.eye(3)[1], np.eye(3)[2], np.array([1.0, 1, 1]) / np.sqrt(3),
                 np.array([0.6, -0.8, 0.0])]:
        R = Rotation.from_rotvec(np.pi * axis).as_matrix()
        w = log_so3(R)
        assert abs(np.linalg.norm(w) - np.pi) < 1e-7
        assert min(np.abs(w - np.pi * axis).max(), np.abs(w + np.pi * axis).max()) < 1e-7
        np.testing.assert_allclose(exp_so3(w), R, atol=1e-7)


def test_log_matches_scipy_on_random_rotations():
    R = Rotation.random(500, random_state=7)
    np.testing.assert_allclose(log_so3(R.as_matrix()), R.as_rotvec(), atol=1e-9)


# --------------------------------------------------------------------------- pose error
def test_pose_error_is_the_twist_between_poses():
    Ta = xyzrpy_to_matrix(np.column_stack([RNG.normal(size=(40, 3)),
                                           RNG.uniform(-3, 3, (40, 3))]))
    dp = RNG.normal(size=(40, 3)) * 1e-2
    dphi = RNG.normal(size=(40, 3)) * 0.3
    Tt = Ta.copy()
    Tt[:, :3, 3] += dp
    Tt[:, :3, :3] = Rotation.from_rotvec(dphi).as_matrix() @ Ta[:, :3, :3]
    e = pose_error(Tt, Ta)
    assert e.shape == (40, 6)
    np.testing.assert_allclose(e[:, :3], dp, atol=TIGHT)
    np.testing.assert_allclose(e[:, 3:], dphi, atol=1e-10)
    np.testing.assert_allclose(pose_error(Ta, Ta), 0.0, atol=1e-15)
    np.testing.assert_allclose(pose_error(Tt[0], Ta[0]), e[0], atol=TIGHT)


# --------------------------------------------------------------------------- rate matrix
@pytest.mark.parametrize("rep", ["rpy", "zyz"])
def test_rate_matrix_matches_finite_differences(rep):
    to_matrix = rpy_to_matrix if rep == "rpy" else zyz_to_matrix
    if rep == "rpy":
        ang = np.column_stack([RNG.uniform(-3, 3, 30), RNG.uniform(-1.4, 1.4, 30),
                               RNG.uniform(-3, 3, 30)])
    else:
        ang = np.column_stack([RNG.uniform(-3, 3, 30), RNG.uniform(0.1, 3.0, 30),
                               RNG.uniform(-3, 3, 30)])
    rate = RNG.normal(size=(30, 3))
    h = 1e-6
    dR = (to_matrix(ang + h * rate) - to_matrix(ang - h * rate)) / (2 * h)
    omega = _vee(dR @ np.swapaxes(to_matrix(ang), 1, 2))
    got = np.einsum("nij,nj->ni", rate_matrix(ang, rep), rate)
    np.testing.assert_allclose(got, omega, rtol=1e-6, atol=1e-8)


def test_rate_matrix_singularities():
    # det E = cos(pitch) for rpy and -sin(theta) for zyz
    a = RNG.uniform(-3, 3, (100, 3))
    np.testing.assert_allclose(np.linalg.det(rate_matrix(a, "rpy")), np.cos(a[:, 1]), atol=TIGHT)
    np.testing.assert_allclose(np.linalg.det(rate_matrix(a, "zyz")), -np.sin(a[:, 1]), atol=TIGHT)
    assert abs(np.linalg.det(rate_matrix([0.3, np.pi / 2, -1.0], "rpy"))) < 1e-15
    assert abs(np.linalg.det(rate_matrix([0.3, 0.0, -1.0], "zyz"))) < 1e-15
