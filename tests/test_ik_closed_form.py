"""Closed-form IK (PUMA 560, spherical RRP, SCARA) checked against forward kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.motion.ik_closed_form import (
    PUMA_BRANCHES,
    closed_form_ik,
    ik_puma560,
    ik_scara,
    ik_spherical_rrp,
)
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import load_serial_robot
from kincal.spatial import pose_error

SQ2 = math.sqrt(2.0)


def _spherical_arm():
    """The spherical arm built independently from its DH table (d2 = 1 m)."""
    return from_dh([DHLink(alpha=-math.pi / 2), DHLink(d=1.0, alpha=math.pi / 2),
                    DHLink(joint="prismatic")], name="spherical_arm")


def test_puma_all_eight_branches_reach_the_pose():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, size=(2000, 6))
    T = robot.fk(q)
    sol = ik_puma560(robot, T)
    assert sol.q.shape == (2000, 8, 6) and sol.branches == PUMA_BRANCHES
    reach = sol.reachable
    assert reach.all()
    e = pose_error(T[:, None], robot.fk(sol.q.reshape(-1, 6)).reshape(-1, 8, 4, 4))
    assert np.abs(e).max() <= 1e-10
    # the eight are distinct for generic poses
    gaps = np.abs(sol.q[:, :, None, :] - sol.q[:, None, :, :]).max(-1)
    gaps[:, np.arange(8), np.arange(8)] = np.inf
    assert gaps.min() > 1e-6


def test_puma_general_geometry_with_base_tool_and_offsets():
    links = [DHLink(d=0.3, alpha=math.pi / 2, theta_offset=0.1),
             DHLink(a=0.45, d=0.05, theta_offset=-0.2),
             DHLink(a=0.03, d=0.1, alpha=-math.pi / 2, theta_offset=0.3),
             DHLink(d=0.42, alpha=math.pi / 2, theta_offset=0.4),
             DHLink(alpha=-math.pi / 2, theta_offset=0.5),
             DHLink(a=0.01, d=0.07, alpha=0.3, theta_offset=0.6)]
    robot = from_dh(links, base=(0.1, 0.2, 0.3, 0.3, 0.2, 0.1),
                    tool=(0.01, 0.02, 0.1, 0.1, 0.2, 0.3))
    q = np.random.default_rng(1).uniform(-3, 3, size=(500, 6))
    T = robot.fk(q)
    sol = ik_puma560(robot, T)
    e = pose_error(T[:, None], robot.fk(sol.q.reshape(-1, 6)).reshape(-1, 8, 4, 4))
    assert np.abs(e).max() <= 1e-10
    # the configuration that made each pose is among the branches
    d = np.abs(np.pi - np.mod(np.pi - (sol.q - q[:, None]), 2 * np.pi)).max(-1).min(-1)
    assert d.max() < 1e-9


def test_puma_wrist_singularity_still_reaches_the_pose():
    robot = load_serial_robot("puma560")
    q = np.array([[0.3, 1.0, -1.2, 0.7, 0.0, -0.4], [0.3, 1.0, -1.2, 0.7, np.pi, -0.4]])
    T = robot.fk(q)
    sol = ik_puma560(robot, T)
    e = pose_error(T[:, None], robot.fk(sol.q.reshape(-1, 6)).reshape(-1, 8, 4, 4))
    assert np.abs(e).max() <= 1e-10


def test_puma_unreachable_and_limits_flags():
    robot = load_serial_robot("puma560")
    T = np.tile(np.eye(4), (2, 1, 1))
    T[0, :3, 3] = [1.5, 0.0, 0.0]
    T[1] = robot.fk(np.radians([10, 30, -40, 20, 50, 60]))
    sol = ik_puma560(robot, T)
    assert not sol.reachable[0].any() and not sol.within_limits[0].any()
    assert np.isnan(sol.q[0]).all()
    assert sol.reachable[1].all() and sol.within_limits[1].any()
    lim = robot.joint_limits
    inside = np.all((sol.q[1] >= lim[:, 0]) & (sol.q[1] <= lim[:, 1]), axis=1)
    np.testing.assert_array_equal(inside, sol.within_limits[1])


def test_spherical_arm_endpoints_by_closed_form():
    robot = _spherical_arm()
    p_i = np.array([SQ2 / 4, 1.0, SQ2 / 4])
    p_f = np.array([-SQ2 / 2, SQ2 / 2, 0.1])
    np.testing.assert_allclose(robot.fk([0, math.pi / 4, 0.5])[:3, 3], p_i, atol=1e-15)
    np.testing.assert_allclose(robot.fk([math.pi / 4, 0, 0.1])[:3, 3], p_f, atol=1e-15)
    sol = ik_spherical_rrp(robot, np.stack([p_i, p_f]))
    # p_i: the 'left/out' branch is q(0) = [0, pi/4, 0.5]
    np.testing.assert_allclose(sol.q[0, 0], [0, math.pi / 4, 0.5], atol=1e-14)
    # p_f is on the cylinder rho = d2: both shoulders coincide, theta2 = 0 (singular)
    np.testing.assert_allclose(sol.q[1, 0], [math.pi / 4, 0, 0.1], atol=1e-7)
    np.testing.assert_allclose(sol.q[1, 2], [math.pi / 4, 0, 0.1], atol=1e-7)


def test_spherical_arm_formula_matches_the_library_robot():
    lib = load_serial_robot("spherical_rrp")
    q = np.random.default_rng(2).uniform(-2, 2, size=(200, 3))
    c1, s1, c2, s2 = np.cos(q[:, 0]), np.sin(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 1])
    d2, d3 = 1.0, q[:, 2]
    p = np.column_stack([c1 * s2 * d3 - d2 * s1, s1 * s2 * d3 + d2 * c1, c2 * d3])
    np.testing.assert_allclose(lib.fk(q)[:, :3, 3], p, atol=1e-14)
    np.testing.assert_allclose(_spherical_arm().fk(q), lib.fk(q), atol=1e-14)


def test_spherical_rrp_branches_and_hole():
    robot = _spherical_arm()
    q = np.random.default_rng(3).uniform(-3, 3, size=(1000, 3))
    p = robot.fk(q)[:, :3, 3]
    sol = ik_spherical_rrp(robot, p)
    pb = robot.fk(sol.q.reshape(-1, 3)).reshape(-1, 4, 4, 4)[..., :3, 3]
    assert np.abs(pb - p[:, None]).max() <= 1e-12
    # 'out' branches have d3 >= 0, 'in' branches d3 <= 0
    assert np.all(sol.q[:, [0, 2], 2] >= 0) and np.all(sol.q[:, [1, 3], 2] <= 0)
    hole = ik_spherical_rrp(robot, np.array([[0.3, 0.2, 0.5]]))
    assert not hole.reachable.any()


def test_scara_branches_reach_the_pose():
    robot = load_serial_robot("scara")
    rng = np.random.default_rng(4)
    q = np.column_stack([rng.uniform(-2.5, 2.5, (1000, 2)), rng.uniform(0, 0.2, 1000),
                         rng.uniform(-3, 3, 1000)])
    T = robot.fk(q)
    sol = ik_scara(robot, T)
    assert sol.reachable.all()
    e = pose_error(T[:, None], robot.fk(sol.q.reshape(-1, 4)).reshape(-1, 2, 4, 4))
    assert np.abs(e).max() <= 1e-10
    # with alpha2 = 0 as well (another SCARA family member)
    other = from_dh([DHLink(a=0.4, d=0.3), DHLink(a=0.3), DHLink(joint="prismatic", d=-0.1),
                     DHLink(d=0.05, theta_offset=0.2)], tool=(0, 0, 0.1, 0.3, 0, 0))
    T2 = other.fk(q)
    e2 = pose_error(T2[:, None], other.fk(ik_scara(other, T2).q.reshape(-1, 4)).reshape(
        -1, 2, 4, 4))
    assert np.abs(e2).max() <= 1e-10


def test_scara_tilted_or_far_poses_are_unreachable():
    robot = load_serial_robot("scara")
    T = robot.fk(np.array([[0.2, 0.3, 0.1, 0.4]] * 2))
    T[0, :3, :3] = T[0, :3, :3] @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    T[1, 0, 3] = 2.0
    assert not ik_scara(robot, T).reachable.any()


def test_dispatch_and_wrong_family():
    assert closed_form_ik(load_serial_robot("puma560"), np.eye(4)).q.shape == (1, 8, 6)
    scara = load_serial_robot("scara")
    assert closed_form_ik(scara, scara.fk(np.zeros(4))).q.shape == (1, 2, 4)
    with pytest.raises(KincalError, match="no closed-form IK"):
        closed_form_ik(load_serial_robot("ur5"), np.eye(4))
    with pytest.raises(KincalError, match="PUMA-560"):
        ik_puma560(load_serial_robot("stanford"), np.eye(4))
