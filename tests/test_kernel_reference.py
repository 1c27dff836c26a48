"""The tuned chain kernel (:mod:`kincal.robots.chain`) against a ten-line reference.

The reference multiplies one 4x4 matrix per elementary transform, ``T = prod_k
X_k(c_k + s_k q_j(k))``, and differentiates by central finite differences: position rows
``(p(+h) - p(-h)) / 2h``, rotation rows ``vee(R(+h) R(-h)^T - I) / 2h`` (the small rotation
in the base frame).  Random DH, modified-DH, Hayati and URDF robots (general joint axes,
prismatic joints) at random configurations; URDF forward kinematics is also checked
against the file's own formula ``prod Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll) M(axis, q)``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from kincal.robots.chain import Robot, elementary_matrix
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.urdf import load_urdf
from kincal.spatial import exp_so3, log_so3, xyzrpy_to_matrix


def reference_fk(robot: Robot, params: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``prod_k X_k(c_k + s_k q_j)``: one plain 4x4 product per elementary transform."""
    T = np.eye(4)
    for et in robot.ets:
        v = params[et.param] if et.param >= 0 else et.constant
        T = T @ elementary_matrix(et.kind, v + (et.scale * q[et.joint] if et.joint >= 0 else 0))
    return T


def reference_jacobian(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(6, len(x)) central differences of a pose function: ``[dp; vee(dR R^T)]``."""
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        Tp, Tm = f(x + e), f(x - e)
        cols.append(np.concatenate([(Tp[:3, 3] - Tm[:3, 3]) / (2 * h),
                                    log_so3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)]))
    return np.array(cols).T


def random_dh(rng: np.random.Generator, convention: str, hayati: bool = False) -> Robot:
    links = []
    for i in range(int(rng.integers(3, 8))):
        prismatic = convention == "standard" and not hayati and i == 2 and rng.random() < 0.5
        links.append(DHLink(a=rng.uniform(-0.5, 0.5), d=rng.uniform(-0.5, 0.5),
                            alpha=rng.uniform(-math.pi, math.pi),
                            theta_offset=rng.uniform(-math.pi, math.pi),
                            joint="prismatic" if prismatic else "revolute",
                            beta=rng.uniform(-0.1, 0.1) if hayati and i == 1 else None))
    frame = lambda: np.concatenate([rng.uniform(-1, 1, 3), rng.uniform(-1.2, 1.2, 3)])  # noqa: E731
    return from_dh(links, convention, "random", base=frame(), tool=frame())


def random_urdf(rng: np.random.Generator, path) -> tuple[Robot, list[tuple]]:
    """A random serial URDF (principal and general axes, one prismatic joint) and its joints."""
    joints, lines = [], ['<robot name="random">', '<link name="l0"/>']
    for i in range(int(rng.integers(3, 7))):
        xyz, rpy = rng.uniform(-0.4, 0.4, 3), rng.uniform(-1.5, 1.5, 3)
        axis = rng.normal(size=3) if i % 3 == 1 else np.eye(3)[i % 3] * rng.choice([-1, 1])
        axis = axis / np.linalg.norm(axis)
        kind = "prismatic" if i == 2 else "revolute"
        joints.append((xyz, rpy, axis, kind))
        f = lambda v: " ".join(repr(float(x)) for x in v)  # noqa: E731
        lines += [f'<link name="l{i + 1}"/>',
                  f'<joint name="j{i + 1}" type="{kind}"><parent link="l{i}"/>'
                  f'<child link="l{i + 1}"/><origin xyz="{f(xyz)}" rpy="{f(rpy)}"/>'
                  f'<axis xyz="{f(axis)}"/><limit lower="-1" upper="1" effort="1" '
                  f'velocity="1"/></joint>']
    path.write_text("\n".join(lines + ["</robot>"]))
    return load_urdf(path), joints


def urdf_fk(joints: list[tuple], q: np.ndarray) -> np.ndarray:
    """The URDF definition: ``prod Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll) M(axis, q)``."""
    T = np.eye(4)
    for (xyz, rpy, axis, kind), qi in zip(joints, q, strict=True):
        M = np.eye(4)
        if kind == "revolute":
            M[:3, :3] = exp_so3(axis * qi)
        else:
            M[:3, 3] = axis * qi
        T = T @ xyzrpy_to_matrix(np.concatenate([xyz, rpy])) @ M
    return T


def check_against_reference(robot: Robot, rng: np.random.Generator) -> None:
    """FK, geometric Jacobian, parameter Jacobian and tool points of the kernel equal the
    reference at random configurations and random parameter values."""
    robot = robot.with_params(robot.param_values + rng.normal(0, 0.01, robot.num_params))
    theta = np.array(robot.param_values)
    Q = rng.uniform(-1, 1, (5, robot.n))
    T, J, Jp = robot.fk_with_jacobians(Q)
    assert J is not None and Jp is not None
    for i, q in enumerate(Q):
        np.testing.assert_allclose(T[i], reference_fk(robot, theta, q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[i], reference_jacobian(
            lambda x: reference_fk(robot, theta, x), q), rtol=0, atol=1e-7)
        np.testing.assert_allclose(Jp[i], reference_jacobian(
            lambda x, q=q: reference_fk(robot, x, q), theta), rtol=0, atol=1e-7)
    # tool points through a frame in front of the chain, a subset of the columns
    H = xyzrpy_to_matrix(rng.uniform(-1, 1, 6))
    m = rng.uniform(-0.2, 0.2, (2, 3))
    cols = sorted(rng.choice(robot.num_params, size=robot.num_params // 2, replace=False))
    Y, D, Rot = robot.point_jacobian(Q, m, left=H, columns=cols, rotation=True)
    assert Rot is not None
    for i, q in enumerate(Q):
        Tr = H @ reference_fk(robot, theta, q)
        np.testing.assert_allclose(Y[:, :, i], m @ Tr[:3, :3].T + Tr[:3, 3], atol=1e-12)
        np.testing.assert_allclose(Rot[:, :, i], Tr[:3, :3].T, atol=1e-12)
        for j, c in enumerate(cols):
            e = np.zeros_like(theta)
            e[c] = 1e-6
            Tp = H @ reference_fk(robot, theta + e, q)
            Tm = H @ reference_fk(robot, theta - e, q)
            fd = (m @ (Tp - Tm)[:3, :3].T + (Tp - Tm)[:3, 3]) / 2e-6
            np.testing.assert_allclose(D[j, :, :, i], fd, atol=1e-7)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("convention", ["standard", "modified", "hayati"])
def test_dh_kernel_equals_reference(convention, seed):
    rng = np.random.default_rng(100 + seed)
    robot = random_dh(rng, "standard" if convention == "hayati" else convention,
                      hayati=convention == "hayati")
    check_against_reference(robot, rng)


@pytest.mark.parametrize("seed", range(4))
def test_urdf_kernel_equals_reference(seed, tmp_path):
    rng = np.random.default_rng(200 + seed)
    robot, joints = random_urdf(rng, tmp_path / "random.urdf")
    for q in rng.uniform(-1, 1, (5, robot.n)):
        np.testing.assert_allclose(robot.fk(q), urdf_fk(joints, q), rtol=0, atol=1e-12)
    check_against_reference(robot, rng)


def test_reference_catches_a_wrong_kernel():
    """The comparison fails for a robot that differs from the reference by 1e-6."""
    rng = np.random.default_rng(7)
    robot = random_dh(rng, "standard")
    theta = np.array(robot.param_values)
    q = rng.uniform(-1, 1, robot.n)
    moved = robot.with_params(theta + 1e-6 * (np.arange(robot.num_params) == 3))
    assert np.abs(moved.fk(q) - reference_fk(robot, theta, q)).max() > 1e-9
