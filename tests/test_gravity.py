"""Gravity torques and URDF masses against an independent computation.

The truth here is the gravitational potential energy ``V(q) = -sum_i m_i g . c_i(q)``
computed without kincal's chain engine: the URDF is parsed again with ElementTree and
the whole link tree is multiplied out as 4x4 matrices (Rodrigues for the joint
motions), or a DH table is multiplied out from its textbook link matrices.  The load
on joint j is ``tau_j = -dV/dq_j``, taken by central differences.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from kincal.errors import KincalError, RobotFileError
from kincal.robots.chain import ChainBuilder
from kincal.robots.files import load_serial_robot
from kincal.robots.gravity import PointMass, gravity_torques
from kincal.robots.urdf import load_urdf, load_urdf_inertials, parse_urdf_inertials

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
TIAGO = SHARED / "tiago_mocap" / "tiago_48_schunk.urdf"
TIP = "wrist_ft_tool_link"


# --------------------------------------------------------------------------- reference
def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    return (_rot(np.array([0, 0, 1.0]), y) @ _rot(np.array([0, 1.0, 0]), p)
            @ _rot(np.array([1.0, 0, 0]), r))


def _nums(elem, attr, default):
    text = default if elem is None or elem.get(attr) is None else elem.get(attr)
    return np.array([float(v) for v in text.split()])


def urdf_potential(path: Path, root_link: str, q: dict[str, float], g: np.ndarray) -> float:
    """``V = -sum m g . c`` over every link below ``root_link``, joints at ``q`` (0 if
    absent), written from the URDF text alone."""
    root = ET.parse(path).getroot()
    kids: dict[str, list[ET.Element]] = {}
    for j in root.findall("joint"):
        kids.setdefault(j.find("parent").get("link"), []).append(j)
    masses = {}
    for link in root.findall("link"):
        inert = link.find("inertial")
        if inert is not None:
            masses[link.get("name")] = (float(inert.find("mass").get("value")),
                                        _nums(inert.find("origin"), "xyz", "0 0 0"))
    V = 0.0
    stack = [(root_link, np.eye(4))]
    while stack:
        name, T = stack.pop()
        if name in masses:
            m, c = masses[name]
            V -= m * g @ (T[:3, :3] @ c + T[:3, 3])
        for j in kids.get(name, []):
            o = j.find("origin")
            A = np.eye(4)
            A[:3, :3] = _rpy(*_nums(o, "rpy", "0 0 0"))
            A[:3, 3] = _nums(o, "xyz", "0 0 0")
            M = np.eye(4)
            v = q.get(j.get("name"), 0.0)
            if j.get("type") in ("revolute", "continuous"):
                M[:3, :3] = _rot(_nums(j.find("axis"), "xyz", "1 0 0"), v)
            elif j.get("type") == "prismatic":
                a = _nums(j.find("axis"), "xyz", "1 0 0")
                M[:3, 3] = v * a / np.linalg.norm(a)
            stack.append((j.find("child").get("link"), T @ A @ M))
    return V


def minus_gradient(V, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    out = np.zeros(q.size)
    for j in range(q.size):
        e = np.zeros(q.size)
        e[j] = h
        out[j] = -(V(q + e) - V(q - e)) / (2 * h)
    return out


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared data file {path} is absent")
    return path


# --------------------------------------------------------------------------- URDF
def test_tiago_torques_are_minus_the_gradient_of_the_potential():
    path = _need(TIAGO)
    robot = load_urdf(path, tip_link=TIP)
    masses = load_urdf_inertials(path, tip_link=TIP)
    rng = np.random.default_rng(3)
    lim = robot.joint_limits
    q = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((6, robot.n))
    g = np.array([0.0, 0.0, -9.81])
    tau = gravity_torques(robot, q, masses, g)
    assert tau.shape == (6, robot.n)
    for qi, ti in zip(q, tau, strict=True):
        def V(x):
            return urdf_potential(path, "base_footprint", dict(zip(robot.joint_names, x,
                                                                   strict=True)), g)
        ref = minus_gradient(V, qi)
        np.testing.assert_allclose(ti, ref, rtol=1e-7, atol=1e-7)
    # everything above the torso slide weighs on it; arm_1 turns about the vertical
    above = sum(m.mass for m in masses if m.joint >= 0)
    np.testing.assert_allclose(tau[:, 0], -9.81 * above, rtol=1e-12)
    assert np.all(tau[:, 1] == 0.0)
    # a single configuration gives (n,)
    np.testing.assert_allclose(gravity_torques(robot, q[0], masses, g), tau[0], rtol=1e-13)


def test_tiago_masses_ride_on_the_right_joints():
    path = _need(TIAGO)
    masses = load_urdf_inertials(path, tip_link=TIP)
    robot = load_urdf(path, tip_link=TIP)
    rider = {m.name: m.joint for m in masses}
    j = {n: i for i, n in enumerate(robot.joint_names)}
    assert rider["base_link"] == -1 and rider["torso_fixed_link"] == -1
    assert rider["wheel_left_link"] == -1                   # a side branch before the chain
    assert rider["torso_lift_link"] == j["torso_lift_joint"]
    assert rider["head_2_link"] == j["torso_lift_joint"]    # the head rides on the torso
    for i in range(1, 8):
        assert rider[f"arm_{i}_link"] == j[f"arm_{i}_joint"]
    for name in ("arm_tool_link", "wrist_ft_tool_link", "gripper_link",
                 "gripper_left_finger_link"):             # below the chain's tip, too
        assert rider[name] == j["arm_7_joint"]
    # links of other subtrees of the root are not on the chain: none is missing or extra
    inert = parse_urdf_inertials(path)
    assert {m.name for m in masses} == {n for n, i in inert.items() if i.mass > 0}
    assert inert["arm_3_link"].mass == pytest.approx(2.343502)
    assert inert["arm_3_link"].xyz == (0.007418, -0.004361, -0.134194)
    # a URDF link frame is the frame just after its joint's motion (axis +z)
    c = dict((m.name, m.com) for m in masses)["arm_3_link"]
    np.testing.assert_allclose(c, inert["arm_3_link"].xyz, atol=0)


GENERAL = """<?xml version="1.0"?>
<robot name="general">
  <link name="world"/>
  <link name="base"><inertial><mass value="5"/><origin xyz="0.1 0 0.2"/></inertial></link>
  <link name="l1"><inertial><origin xyz="0.2 0.05 -0.1" rpy="0.3 0.2 0.1"/>
    <mass value="1.5"/></inertial></link>
  <link name="l2"><inertial><mass value="2.0"/><origin xyz="0.0 0.3 0.1"/></inertial></link>
  <link name="plate"><inertial><mass value="0.7"/><origin xyz="0.05 0 0"/></inertial></link>
  <link name="l3"><inertial><mass value="1.1"/><origin xyz="0.1 -0.2 0.05"/></inertial></link>
  <link name="finger"><inertial><mass value="0.3"/><origin xyz="0 0 0.04"/></inertial></link>
  <link name="tip"><inertial><mass value="0.4"/><origin xyz="0.02 0.01 0.03"/></inertial></link>
  <link name="nomass"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="0 0 0.5" rpy="0 0.1 0"/></joint>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0.1 0.2 0.3" rpy="0.4 -0.2 0.7"/><axis xyz="1 2 2"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.3 0 0.1" rpy="0 1.5707963267948966 0"/><axis xyz="0 -1 0"/>
    <limit lower="0" upper="0.4" effort="1" velocity="1"/></joint>
  <joint name="plate_fix" type="fixed"><parent link="l2"/><child link="plate"/>
    <origin xyz="0.1 0.1 0" rpy="0.5 0 0"/></joint>
  <joint name="j3" type="continuous"><parent link="plate"/><child link="l3"/>
    <origin xyz="0.2 0 0.05" rpy="0 0 0.3"/><axis xyz="0 1 -1"/></joint>
  <joint name="grip" type="revolute"><parent link="l3"/><child link="finger"/>
    <origin xyz="0 0.1 0" rpy="0 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="tipj" type="fixed"><parent link="l3"/><child link="tip"/>
    <origin xyz="0.15 0 0" rpy="0 0.4 0"/></joint>
  <joint name="empty" type="fixed"><parent link="l3"/><child link="nomass"/></joint>
</robot>
"""


def test_general_axes_prismatic_fixed_and_side_branches(tmp_path):
    """General and negative axes, a prismatic joint, a fixed joint on the chain, a side
    branch with its own (held) joint, a tilted gravity vector."""
    path = tmp_path / "general.urdf"
    path.write_text(GENERAL)
    robot = load_urdf(path, "world", "tip")
    masses = load_urdf_inertials(path, "world", "tip")
    assert [m.name for m in masses] == ["base", "l1", "l2", "plate", "l3", "finger", "tip"]
    assert [m.joint for m in masses] == [-1, 0, 1, 1, 2, 2, 2]
    assert [j.kind for j in robot.joints] == ["revolute", "prismatic", "revolute"]
    g = np.array([0.8, -1.1, -9.7])
    rng = np.random.default_rng(5)
    q = np.column_stack([rng.uniform(-2, 2, 5), rng.uniform(0, 0.4, 5), rng.uniform(-3, 3, 5)])
    tau = gravity_torques(robot, q, masses, g)
    for qi, ti in zip(q, tau, strict=True):
        def V(x):
            return urdf_potential(path, "world", dict(zip(robot.joint_names, x, strict=True)), g)
        np.testing.assert_allclose(ti, minus_gradient(V, qi), rtol=1e-7, atol=1e-8)
    # the robot's current parameters place the axes: a moved base moves the loads
    moved = robot.with_params({"base.ry": 0.3, "base.x": 0.2})
    R = _rot(np.array([0, 1.0, 0]), 0.3)
    np.testing.assert_allclose(gravity_torques(moved, q, masses, g),
                               gravity_torques(robot, q, masses, R.T @ g), rtol=1e-10,
                               atol=1e-12)


def test_urdf_inertial_errors(tmp_path):
    bad = GENERAL.replace('<mass value="2.0"/>', '<mass value="-2.0"/>')
    p = tmp_path / "neg.urdf"
    p.write_text(bad)
    with pytest.raises(RobotFileError, match=r"line 7: link 'l2' <inertial>.*negative"):
        load_urdf_inertials(p, "world", "tip")
    p.write_text(GENERAL.replace('<mass value="0.7"/>', ''))
    with pytest.raises(RobotFileError, match=r"line 8: link 'plate' <inertial>.*no <mass"):
        parse_urdf_inertials(p)
    p.write_text(GENERAL.replace('<mass value="0.7"/>', '<mass value="heavy"/>'))
    with pytest.raises(RobotFileError, match="'heavy' is not a number"):
        load_urdf_inertials(p, "world", "tip")
    # the kinematics alone do not read the masses
    assert load_urdf(p, "world", "tip").n == 3


# --------------------------------------------------------------------------- DH
def _dh(theta, d, a, alpha):
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                     [0, sa, ca, d], [0, 0, 0, 1]])


PUMA_TABLE = [(0, 0, np.pi / 2), (0, 0.4318, 0), (0.15005, 0.0203, -np.pi / 2),
              (0.4318, 0, np.pi / 2), (0, 0, -np.pi / 2), (0, 0, 0)]       # d, a, alpha


def test_puma_torques_against_textbook_dh():
    """Synthetic masses on the PUMA 560 (com in the frame just after each joint's
    rotation ``Rz(theta + q)``), a tilted base and gravity along -z of the world."""
    robot = load_serial_robot("puma560").with_params({"base.z": 0.672, "base.rx": 0.2,
                                               "base.ry": -0.1})
    masses = [PointMass(0, 13.0, (0.0, 0.0, 0.3)), PointMass(1, 17.4, (0.2, 0.0, 0.1)),
              PointMass(2, 4.8, (0.02, 0.01, 0.2)), PointMass(3, 0.8, (0.0, 0.05, 0.4)),
              PointMass(4, 0.34, (0.0, 0.03, 0.0)), PointMass(5, 0.09, (0.01, 0.0, 0.03))]
    base = np.eye(4)
    base[:3, :3] = _rpy(0.2, -0.1, 0.0)
    base[2, 3] = 0.672
    g = np.array([0.0, 0.0, -9.81])

    def V(x):
        T, out = base.copy(), 0.0
        for j, (d, a, alpha) in enumerate(PUMA_TABLE):
            Rq = np.eye(4)
            Rq[:3, :3] = _rot(np.array([0, 0, 1.0]), x[j])
            for m in masses:
                if m.joint == j:
                    out -= m.mass * g @ (T @ Rq @ np.append(m.com, 1.0))[:3]
            T = T @ _dh(x[j], d, a, alpha)
        return out

    rng = np.random.default_rng(11)
    q = rng.uniform(-2.5, 2.5, (5, 6))
    tau = gravity_torques(robot, q, masses, g)
    for qi, ti in zip(q, tau, strict=True):
        np.testing.assert_allclose(ti, minus_gradient(V, qi), rtol=1e-7, atol=1e-7)


def test_sign_convention_pendulum_and_slide():
    """The load torque is gravity's, positive along +q: a horizontal pendulum arm is
    pulled towards -q; the drive must supply ``-tau`` to hold it."""
    b = ChainBuilder("pendulum")
    j = b.joint("swing", "revolute")
    b.transform("Rz", "swing.offset", 0.0, role="offset", joint=j)
    k = b.joint("slide", "prismatic")
    b.transform("Tx", "slide.offset", 0.0, role="offset", joint=k)
    robot = b.build()
    g = (0.0, -9.81, 0.0)                       # the swing axis z is horizontal
    m = [PointMass(0, 2.0, (0.5, 0.0, 0.0)), PointMass(1, 3.0, (0.0, 0.0, 0.0))]
    tau = gravity_torques(robot, [[0.0, 0.0], [np.pi / 2, 0.0], [0.0, 0.4]], m, g)
    # q = 0: both masses on +x; torque (0.5 * 2 + 0 * 3) * -9.81 about +z
    np.testing.assert_allclose(tau[0], [-9.81 * 1.0, 0.0], atol=1e-12)
    # q = pi/2: arm vertical, no torque; the slide (along +y) carries 3 kg: -29.43 N
    np.testing.assert_allclose(tau[1], [0.0, -3.0 * 9.81], atol=1e-12)
    # the slide's mass at x = 0.4 adds its moment
    np.testing.assert_allclose(tau[2], [-9.81 * (1.0 + 3.0 * 0.4), 0.0], atol=1e-12)


def test_bad_masses_and_gravity():
    robot = load_serial_robot("puma560")
    q = np.zeros((2, 6))
    with pytest.raises(KincalError, match="joint 6 is not a joint"):
        gravity_torques(robot, q, [PointMass(6, 1.0, (0, 0, 0))])
    with pytest.raises(KincalError, match="mass -1.0 must be finite and >= 0"):
        gravity_torques(robot, q, [(1, -1.0, (0, 0, 0))])
    with pytest.raises(KincalError, match="three finite numbers"):
        gravity_torques(robot, q, [(1, 1.0, (0, 0))])
    with pytest.raises(KincalError, match="finite 3-vector"):
        gravity_torques(robot, q, [], g=(0, 9.81))
    # no mass, no load; masses before the first joint load nothing
    assert np.all(gravity_torques(robot, q, [(-1, 50.0, (1.0, 2.0, 3.0))]) == 0.0)
