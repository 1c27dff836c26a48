"""URDF front end: loading, compilation, export and errors.

The forward kinematics are checked against an independent evaluation written
here: the URDF is parsed again with ElementTree and the chain is multiplied out as
4x4 matrices (origin: Trans(xyz) Rz Ry Rx built from explicit rotation matrices;
motion: Rodrigues' formula about the normalised axis, or a translation along it).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from kincal.errors import KincalError, RobotFileError
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import load_serial_robot
from kincal.robots.urdf import (
    load_urdf,
    parse_urdf,
    rpy_of,
    urdf_text,
    write_calibrated_urdf,
    write_urdf,
)

HERE = Path(__file__).resolve().parent
FIXTURES = HERE / "data" / "urdf"
ARM = FIXTURES / "arm.urdf"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
TIAGO = SHARED / "tiago_mocap" / "tiago_48_schunk.urdf"
PANDA = SHARED / "panda_two_socket" / "panda.urdf"
TIAGO_JOINTS = ("torso_lift_joint",) + tuple(f"arm_{i}_joint" for i in range(1, 8))


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared data file {path} is absent (the repo is expected next to shared/)")
    return path


# --------------------------------------------------------------------------- reference
def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _vec(elem: ET.Element | None, attr: str, default: str) -> np.ndarray:
    text = default if elem is None or elem.get(attr) is None else elem.get(attr)
    return np.array([float(v) for v in text.split()])


def reference_chain(path: Path, base: str, tip: str) -> list[dict]:
    """The joints from base to tip, parsed independently of kincal."""
    root = ET.parse(path).getroot()
    by_child = {}
    for j in root.findall("joint"):
        origin = j.find("origin")
        by_child[j.find("child").get("link")] = {
            "name": j.get("name"), "type": j.get("type"),
            "parent": j.find("parent").get("link"),
            "xyz": _vec(origin, "xyz", "0 0 0"), "rpy": _vec(origin, "rpy", "0 0 0"),
            "axis": _vec(j.find("axis"), "xyz", "1 0 0")}
    chain, link = [], tip
    while link != base:
        chain.append(by_child[link])
        link = chain[-1]["parent"]
    return chain[::-1]


def reference_fk(chain: list[dict], q: np.ndarray, post: dict | None = None) -> np.ndarray:
    """T = prod_j [Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll) E_j] [motion about/along axis].

    ``post`` maps joint names to a 3x3 rotation ``E_j`` (identity when absent).
    """
    T = np.eye(4)
    i = 0
    for j in chain:
        O = np.eye(4)
        r, p, y = j["rpy"]
        O[:3, :3] = _rz(y) @ _ry(p) @ _rx(r) @ (post or {}).get(j["name"], np.eye(3))
        O[:3, 3] = j["xyz"]
        T = T @ O
        if j["type"] == "fixed":
            continue
        M = np.eye(4)
        if j["type"] == "prismatic":
            M[:3, 3] = q[i] * j["axis"] / np.linalg.norm(j["axis"])
        else:
            M[:3, :3] = _rodrigues(j["axis"], q[i])
        T = T @ M
        i += 1
    return T


def random_q(robot, rng: np.random.Generator, n: int) -> np.ndarray:
    lim = robot.joint_limits.copy()
    lim[~np.isfinite(lim[:, 0]), 0] = -math.pi
    lim[~np.isfinite(lim[:, 1]), 1] = math.pi
    return rng.uniform(lim[:, 0], lim[:, 1], size=(n, robot.n))


def fk_error(robot, chain: list[dict], q: np.ndarray) -> float:
    T = robot.fk(q)
    ref = np.stack([reference_fk(chain, qi) for qi in q])
    return float(np.abs(T - ref).max())


# --------------------------------------------------------------------------- loading
def test_tiago_chain_and_fk():
    path = _need(TIAGO)
    robot = load_urdf(path, tip_link="wrist_ft_tool_link")
    assert robot.meta["base_link"] == "base_footprint"
    assert robot.meta["tip_link"] == "wrist_ft_tool_link"
    assert robot.meta["convention"] == "urdf" and robot.name == "tiago"
    assert robot.joint_names == TIAGO_JOINTS
    assert [j.kind for j in robot.joints] == ["prismatic"] + ["revolute"] * 7
    np.testing.assert_array_equal(robot.joint_limits[0], [0.0, 0.35])
    np.testing.assert_array_equal(robot.joint_limits[1], [0.0, 2.74889357189])
    chain = reference_chain(path, "base_footprint", "wrist_ft_tool_link")
    assert len(chain) == 13  # 8 moving + 5 fixed joints on the path
    # base, tool; xyz per joint; 3 error rotations per fixed (5) or prismatic (1) joint,
    # 2 per revolute joint (the third is its offset); 8 offsets
    assert robot.num_params == 12 + 3 * 13 + 3 * 6 + 2 * 7 + 8
    assert "arm_tool_joint.origin.rx" in robot.param_names  # fixed joints are candidates
    assert "torso_lift_joint.origin.rz" in robot.param_names  # prismatic: all three
    assert "arm_4_joint.origin.rx" in robot.param_names
    assert "arm_4_joint.origin.rz" not in robot.param_names  # axis z: that is the offset
    assert not any(n.endswith((".yaw", ".pitch", ".roll")) for n in robot.param_names)
    assert robot.param_roles[robot.param_index("arm_4_joint.origin.ry")] == "angle"
    assert robot.param_values[robot.param_index("arm_1_joint.origin.x")] == 0.15505
    assert robot.param_units[robot.param_index("torso_lift_joint.offset")] == "m"
    assert robot.param_roles[robot.param_index("arm_3_joint.offset")] == "offset"
    q = random_q(robot, np.random.default_rng(1), 50)
    assert fk_error(robot, chain, q) < 1e-12
    # from base_link instead of the root
    sub = load_urdf(path, base_link="base_link", tip_link="wrist_ft_tool_link")
    assert fk_error(sub, reference_chain(path, "base_link", "wrist_ft_tool_link"), q) < 1e-12


def test_panda_chain_and_fk():
    path = _need(PANDA)
    robot = load_urdf(path, tip_link="ball_link")
    assert robot.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    assert robot.meta["base_link"] == "panda_link0"
    np.testing.assert_array_equal(robot.joint_limits[3], [-3.0718, -0.0698])
    chain = reference_chain(path, "panda_link0", "ball_link")
    q = random_q(robot, np.random.default_rng(2), 50)
    assert fk_error(robot, chain, q) < 1e-12


def test_fixture_axes_and_branches():
    """General, negative and prismatic axes; mimic and floating joints off the chain."""
    robot = load_urdf(ARM, tip_link="tool0")
    assert robot.joint_names == ("j1", "j2", "j3", "j4", "j5")
    assert [j.kind for j in robot.joints] == ["revolute", "revolute", "prismatic",
                                              "revolute", "revolute"]
    assert np.isinf(robot.joint_limits[3]).all()  # continuous
    # the general axes (6) and the non-zero nominal rpy angles are fixed constants
    chain = reference_chain(ARM, "world", "tool0")
    assert sum(et.param < 0 for et in robot.ets) == 6 + sum(
        int(np.count_nonzero(j["rpy"])) for j in chain)
    # revolute joints drop the error rotation closest to the axis: j1 (z), j2 (-y),
    # j4 (1 1 1: the first largest, x), j5 (-x); the prismatic j3 keeps all three
    rot = {n.split(".")[0]: [] for n in robot.param_names if ".origin.r" in n}
    for n in robot.param_names:
        if ".origin.r" in n:
            rot[n.split(".")[0]].append(n.rsplit(".", 1)[1])
    assert rot["j1"] == ["rx", "ry"] and rot["j2"] == ["rx", "rz"]
    assert rot["j3"] == ["rx", "ry", "rz"] and rot["j4"] == ["ry", "rz"]
    assert rot["j5"] == ["ry", "rz"] and rot["tool_joint"] == ["rx", "ry", "rz"]
    q = random_q(robot, np.random.default_rng(3), 100)
    assert fk_error(robot, chain, q) < 1e-12
    # single-configuration call
    assert robot.fk(q[0]).shape == (4, 4)


def test_parse_tree():
    model = parse_urdf(ARM)
    assert model.roots() == ["world"]
    assert sorted(model.leaves_below("world")) == sorted(
        ["tool0", "camera", "finger_left", "finger_right", "object"])
    assert model.joints["j3"].axis == pytest.approx((0.6, 0.0, 0.8), abs=1e-16)
    assert model.joints["j1"].line == 25  # the line of <joint name="j1" ...>


def test_offsets_are_encoder_offsets():
    """A revolute offset c on a +axis joint equals reading q + c."""
    robot = load_urdf(ARM, tip_link="tool0")
    q = random_q(robot, np.random.default_rng(4), 10)
    moved = robot.with_params({"j1.offset": 0.1, "j4.offset": -0.2, "j3.offset": 0.01})
    q2 = q + np.array([0.1, 0, 0.01, -0.2, 0])
    np.testing.assert_allclose(moved.fk(q), robot.fk(q2), atol=1e-13)
    # negative axis (j2: 0 -1 0): the offset turns about +y, i.e. q - c
    moved = robot.with_params({"j2.offset": 0.1})
    np.testing.assert_allclose(moved.fk(q), robot.fk(q - np.array([0, 0.1, 0, 0, 0])),
                               atol=1e-13)


@pytest.mark.parametrize("which", ["fixture", "tiago"])
def test_origin_error_rotations_about_own_axes(which):
    """``<joint>.origin.rx .ry .rz`` turn the frame about its own axes after the nominal
    origin: checked against the independent chain with ``E_j = Rx Ry Rz`` inserted."""
    path, base, tip = {"fixture": (ARM, "world", "tool0"),
                       "tiago": (TIAGO, "base_footprint", "wrist_ft_tool_link")}[which]
    robot = load_urdf(_need(path), base_link=base, tip_link=tip)
    chain = reference_chain(path, base, tip)
    rng = np.random.default_rng(14)
    values, post = {}, {}
    for j in chain:  # large angles: the order Rx Ry Rz matters and is checked
        a = {f: rng.uniform(-0.5, 0.5) for f in ("rx", "ry", "rz")
             if f"{j['name']}.origin.{f}" in robot.param_names}
        values.update({f"{j['name']}.origin.{f}": v for f, v in a.items()})
        post[j["name"]] = _rx(a.get("rx", 0.0)) @ _ry(a.get("ry", 0.0)) @ _rz(a.get("rz", 0.0))
    moved = robot.with_params(values)
    q = random_q(robot, rng, 30)
    ref = np.stack([reference_fk(chain, qi, post) for qi in q])
    assert np.abs(moved.fk(q) - ref).max() < 1e-12


@pytest.mark.parametrize("which", ["fixture", "tiago", "panda"])
def test_origin_rotations_are_well_conditioned(which):
    """At the nominal model the rotation columns of every origin (error rotations and
    the offset of a revolute joint) span all three rotation directions.

    For coordinate axes they are three orthonormal axes (singular values 1); the
    fixture's general axes keep at least ``1/sqrt(3)``.  (With roll-pitch-yaw
    parameters TIAGo's arm_4/5/6 origins, at pitch = -pi/2, had a zero singular value.)
    """
    path, tip = {"fixture": (ARM, "tool0"), "tiago": (TIAGO, "wrist_ft_tool_link"),
                 "panda": (PANDA, "ball_link")}[which]
    robot = load_urdf(_need(path), tip_link=tip)
    q = random_q(robot, np.random.default_rng(15), 5)
    Jw = robot.param_jacobian(q)[:, 3:, :]
    for j in reference_chain(path, robot.meta["base_link"], tip):
        cols = [i for i, n in enumerate(robot.param_names)
                if n.startswith(j["name"] + ".origin.r")
                or (n == j["name"] + ".offset" and j["type"] in ("revolute", "continuous"))]
        assert len(cols) == 3, j["name"]
        s = np.linalg.svd(Jw[:, :, cols], compute_uv=False)    # (N, 3) per configuration
        general = np.count_nonzero(j["axis"]) > 1 and j["type"] != "prismatic"
        if general:
            assert s.min() > 0.3, (j["name"], s)
        else:
            np.testing.assert_allclose(s, 1.0, atol=1e-12, err_msg=j["name"])


def _fd_param_jacobian(robot, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of [p; log(R+ R-^T)] over every parameter."""
    p0 = robot.param_values
    out = np.zeros((q.shape[0], 6, robot.num_params))
    for k in range(robot.num_params):
        dp = np.zeros_like(p0)
        dp[k] = h
        Tp, Tm = robot.with_params(p0 + dp).fk(q), robot.with_params(p0 - dp).fk(q)
        out[:, :3, k] = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
        dR = Tp[:, :3, :3] @ np.swapaxes(Tm[:, :3, :3], 1, 2)
        w = np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0],
                      dR[:, 1, 0] - dR[:, 0, 1]], 1) / 2  # sin(t) axis, t ~ 2h
        out[:, 3:, k] = w / (2 * h)
    return out


@pytest.mark.parametrize("which", ["fixture", "tiago"])
def test_param_jacobian_matches_finite_differences(which):
    if which == "tiago":
        robot = load_urdf(_need(TIAGO), tip_link="wrist_ft_tool_link")
    else:
        robot = load_urdf(ARM, tip_link="tool0")
    rng = np.random.default_rng(5)
    robot = robot.with_params(robot.param_values + rng.normal(0, 0.02, robot.num_params))
    q = random_q(robot, rng, 8)
    Jp = robot.param_jacobian(q)
    fd = _fd_param_jacobian(robot, q)
    rel = np.abs(Jp - fd).max() / np.abs(Jp).max()
    assert rel < 1e-6, rel


# --------------------------------------------------------------------------- export
def _dh_robots():
    puma_like = [
        DHLink(a=0.0, d=0.672, alpha=math.pi / 2, theta_offset=0.1, lower=-2.8, upper=2.8),
        DHLink(a=0.4318, d=0.0, alpha=0.0, theta_offset=-0.05, lower=-3.9, upper=0.7),
        DHLink(a=0.0203, d=0.3, alpha=-math.pi / 2, theta_offset=0.3, joint="prismatic",
               lower=0.0, upper=0.4),
        DHLink(a=0.0, d=0.4318, alpha=math.pi / 2, theta_offset=0.02),
        DHLink(a=0.0, d=0.0, alpha=-math.pi / 2, lower=-1.9, upper=1.9),
        DHLink(a=0.0, d=0.0563, alpha=0.0, theta_offset=-0.2, lower=-4.6, upper=4.6),
    ]
    base = (0.2, -0.1, 0.05, 0.8, -0.02, 0.01)                 # x y z rz ry rx
    tool = (0.01, 0.02, 0.15, -0.3, math.pi / 2, 0.1)
    std = from_dh(puma_like, "standard", "puma_like", base, tool)
    mod = from_dh(puma_like, "modified", "puma_like_mdh", base, tool)
    hay = from_dh([*puma_like[:1], DHLink(a=0.43, alpha=0.0, beta=0.01), *puma_like[2:]],
                  "standard", "puma_like_hayati", base, tool)
    return {"standard": std, "modified": mod, "hayati": hay}


@pytest.mark.parametrize("kind", ["standard", "modified", "hayati"])
def test_write_urdf_from_dh_round_trip(kind, tmp_path):
    robot = _dh_robots()[kind]
    path = tmp_path / "dh.urdf"
    base, tip = write_urdf(robot, path)
    assert (base, tip) == ("base_link", "tool_link")
    back = load_urdf(path)  # single chain: default root and leaf
    assert back.meta["tip_link"] == "tool_link"
    assert back.joint_names == robot.joint_names
    assert [j.kind for j in back.joints] == [j.kind for j in robot.joints]
    np.testing.assert_array_equal(back.joint_limits, robot.joint_limits)
    q = random_q(robot, np.random.default_rng(6), 200)
    err = np.abs(back.fk(q) - robot.fk(q)).max()
    assert err < 1e-12, err
    # ... and the written file agrees with the independent evaluation too
    assert fk_error(back, reference_chain(path, "base_link", "tool_link"), q) < 1e-12
    root = ET.parse(path).getroot()
    types = {j.get("name"): j.get("type") for j in root.findall("joint")}
    assert types["q4"] == "continuous" and types["q3"] == "prismatic"


def test_write_urdf_of_urdf_robot_with_general_axes(tmp_path):
    robot = load_urdf(ARM, tip_link="tool0")
    robot = robot.with_params(robot.param_values
                              + np.random.default_rng(7).normal(0, 0.05, robot.num_params))
    base, tip = write_urdf(robot, tmp_path / "arm_again.urdf", name="copy")
    back = load_urdf(tmp_path / "arm_again.urdf", base, tip)
    assert back.name == "copy"
    q = random_q(robot, np.random.default_rng(8), 100)
    assert np.abs(back.fk(q) - robot.fk(q)).max() < 1e-12


def test_write_urdf_name_clash():
    """A joint named like a generated link does not produce duplicate names."""
    robot = from_dh([DHLink(a=0.1, name="tool"), DHLink(a=0.2, name="base")], name="clash")
    text, base, tip = urdf_text(robot)
    root = ET.fromstring(text)
    names = [e.get("name") for e in root.findall("link")]
    assert len(names) == len(set(names)) and tip == "tool_link_1" and base == "base_link"


def _perturbed(robot, seed: int):
    rng = np.random.default_rng(seed)
    return robot.with_params(robot.param_values + rng.normal(0, 0.03, robot.num_params))


@pytest.mark.parametrize("which", ["fixture", "tiago", "panda"])
def test_write_calibrated_urdf_round_trip(which, tmp_path):
    src, tip_link = {"fixture": (ARM, "tool0"), "tiago": (TIAGO, "wrist_ft_tool_link"),
                     "panda": (PANDA, "ball_link")}[which]
    src = _need(src) if which != "fixture" else src
    nominal = load_urdf(src, tip_link=tip_link)
    calibrated = _perturbed(nominal, 9)  # every parameter: origins, offsets, base, tool
    out = tmp_path / "calibrated.urdf"
    base, tip = write_calibrated_urdf(src, calibrated, out)
    assert (base, tip) == ("calibrated_base", "calibrated_tool")
    back = load_urdf(out, base_link=base, tip_link=tip)
    assert back.joint_names == nominal.joint_names
    q = random_q(nominal, np.random.default_rng(10), 100)
    err = np.abs(back.fk(q) - calibrated.fk(q)).max()
    assert err < 1e-12, err
    # the rest of the file is kept: every original link and joint is still there
    before, after = parse_urdf(src), parse_urdf(out)
    assert set(before.links) <= set(after.links) and set(before.joints) <= set(after.joints)
    assert len(after.joints) == len(before.joints) + 2
    off_chain = [n for n in before.joints
                 if n not in {j.split(".")[0] for j in nominal.param_names}]
    for n in off_chain:
        assert after.joints[n].xyz == before.joints[n].xyz
        assert after.joints[n].rpy == before.joints[n].rpy
    if which == "panda":  # the xacro banner before <robot> is kept
        assert "autogenerated by xacro" in out.read_text()


def test_write_calibrated_urdf_without_base_tool_keeps_links(tmp_path):
    nominal = load_urdf(ARM, tip_link="tool0")
    v = nominal.param_values.copy()
    moving = [i for i, n in enumerate(nominal.param_names) if not n.startswith(("base.", "tool."))]
    v[moving] += np.random.default_rng(11).normal(0, 0.05, len(moving))
    calibrated = nominal.with_params(v)
    out = tmp_path / "cal.urdf"
    assert write_calibrated_urdf(None, calibrated, out) == ("world", "tool0")  # meta urdf_file
    back = load_urdf(out, tip_link="tool0")
    q = random_q(nominal, np.random.default_rng(12), 50)
    assert np.abs(back.fk(q) - calibrated.fk(q)).max() < 1e-12
    assert np.all(back.param_values[[back.param_index(f"j{i}.offset") for i in range(1, 6)]]
                  == 0.0)
    # a minimal diff: only the <origin> lines of the chain's joints change
    import difflib

    changed = [ln for ln in difflib.unified_diff(ARM.read_text().splitlines(),
                                                 out.read_text().splitlines(), n=0, lineterm="")
               if ln[:1] in "+-" and not ln.startswith(("+++", "---"))]
    assert changed and all("<origin" in ln for ln in changed), changed
    # nominal values written back reproduce the nominal file's kinematics
    write_calibrated_urdf(ARM, nominal, out)
    again = load_urdf(out, tip_link="tool0")
    assert np.abs(again.fk(q) - nominal.fk(q)).max() < 1e-15


def test_write_calibrated_urdf_adds_missing_origin_and_guards_base(tmp_path):
    """A chain joint without <origin> gets one; a base frame below a parent joint is refused."""
    src = FIXTURES / "bad_floating.urdf"  # valid from 'base' (below the floating joint)
    robot = load_urdf(src, base_link="base")
    cal = robot.with_params({"j1.offset": 0.3, "j1.origin.x": 0.1, "tool.x": 0.05})
    out = tmp_path / "cal.urdf"
    assert write_calibrated_urdf(None, cal, out) == ("base", "calibrated_tool")
    back = load_urdf(out, "base", "calibrated_tool")
    q = np.array([[0.0], [1.0], [-2.0]])
    assert np.abs(back.fk(q) - cal.fk(q)).max() < 1e-15
    assert parse_urdf(out).joints["j1"].rpy == (0.0, 0.0, 0.3)
    with pytest.raises(RobotFileError, match="base link 'base' has parent joint 'mobile_base'"):
        write_calibrated_urdf(None, cal.with_params({"base.z": 0.1}), tmp_path / "no.urdf")
    assert not (tmp_path / "no.urdf").exists()


def test_write_calibrated_urdf_rejects_other_robots(tmp_path):
    out = tmp_path / "never.urdf"
    with pytest.raises(KincalError, match="not loaded from a URDF"):
        write_calibrated_urdf(ARM, _dh_robots()["standard"], out)
    # the same links, but j5 is fixed in this file: the parameters differ
    edited = tmp_path / "edited.urdf"
    edited.write_text(ARM.read_text().replace('name="j5" type="revolute"',
                                              'name="j5" type="fixed"'))
    robot = load_urdf(ARM, tip_link="tool0")
    with pytest.raises(RobotFileError, match="does not match the chain world -> tool0"):
        write_calibrated_urdf(edited, robot, out)
    # the same parameters, but another nominal rotation of j4's origin
    edited.write_text(ARM.read_text().replace('rpy="-0.3 0.2 -0.1"', 'rpy="-0.3 0.2 -0.2"'))
    with pytest.raises(RobotFileError, match="different nominal origins"):
        write_calibrated_urdf(edited, robot, out)
    assert not out.exists()


def test_rpy_of_is_accurate_at_gimbal_lock():
    rng = np.random.default_rng(13)
    worst = 0.0
    for _ in range(500):
        pitch = math.copysign(math.pi / 2 - 10 ** rng.uniform(-16, -4), rng.normal())
        R = _rz(rng.uniform(-3, 3)) @ _ry(pitch) @ _rx(rng.uniform(-3, 3)) @ _rx(1e-3)
        r, p, y = rpy_of(R)
        worst = max(worst, np.abs(_rz(y) @ _ry(p) @ _rx(r) - R).max())
    assert worst < 1e-15, worst


def test_yaml_pointing_to_urdf(tmp_path):
    (tmp_path / "arm.yaml").write_text(
        f"name: my_arm\nconvention: urdf\nfile: {ARM}\ntip_link: tool0\n"
        "source: test fixture\n")
    robot = load_serial_robot(tmp_path / "arm.yaml")
    assert robot.name == "my_arm" and robot.meta["tip_link"] == "tool0"
    assert robot.n == 5
    assert load_serial_robot(ARM, tip_link="tool0").num_params == robot.num_params


# --------------------------------------------------------------------------- errors
BAD = [
    ("bad_mimic.urdf", {}, ["line 12", "joint 'coupled_joint'", "mimic"]),
    ("bad_loop.urdf", {}, ["line 22", "joint 'j_top_right'", "link 'top'", "two parent"]),
    ("bad_missing_link.urdf", {}, ["line 10", "joint 'j2'", "'link_two'", "not declared"]),
    ("bad_joint_type.urdf", {}, ["line 5", "joint 'wrist_ball'", "'spherical'"]),
    ("bad_number.urdf", {}, ["line 6", "joint 'elbow'", "<origin xyz=", "'${arm_length}'",
                             "not a number"]),
    ("bad_nan.urdf", {}, ["line 6", "joint 'shoulder'", "<origin rpy=", "'nan'",
                          "not a finite number"]),
    ("bad_malformed.urdf", {}, ["line 9 column", "malformed XML"]),
    ("bad_floating.urdf", {}, ["joint 'mobile_base'", "floating"]),
    ("arm.urdf", {}, ["link 'world'", "5 leaf links", "tool0", "camera", "--tip-link"]),
    ("arm.urdf", {"tip_link": "tool9"}, ["tip link 'tool9'", "did you mean tool0"]),
    ("arm.urdf", {"base_link": "flange_link"}, ["base link 'flange_link'", "flange"]),
    ("arm.urdf", {"base_link": "link3", "tip_link": "camera"},
     ["tip link 'camera' is not below base link 'link3'"]),
]
BAD_IDS = [f"{f.removesuffix('.urdf')}-{'-'.join(kw.values()) or 'default'}" for f, kw, _ in BAD]


@pytest.mark.parametrize(("name", "kw", "words"), BAD, ids=BAD_IDS)
def test_bad_urdf_raises_one_line(name, kw, words):
    with pytest.raises(RobotFileError) as info:
        load_urdf(FIXTURES / name, **kw)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(str(FIXTURES / name) + ": ")
    for w in words:
        assert w in msg, (w, msg)


def test_more_bad_inputs(tmp_path):
    def fails(text: str, *words: str) -> None:
        p = tmp_path / "x.urdf"
        p.write_text(text)
        with pytest.raises(RobotFileError) as info:
            load_urdf(p)
        for w in words:
            assert w in str(info.value), (w, str(info.value))

    head = '<robot name="r"><link name="a"/><link name="b"/>'
    fails("", "line 1", "malformed XML")
    fails('<model name="r"/>', "<model>", "must be <robot>")
    fails(head + '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
          '<axis xyz="0 0 0"/></joint></robot>', "joint 'j'", "zero")
    fails(head + '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
          '<limit lower="1" upper="-1"/></joint></robot>', "joint 'j'", "lower > upper")
    fails(head + '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
          '<origin xyz="1 2"/></joint></robot>', "needs 3 numbers")
    fails(head + '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
          '<limit lower="-inf" upper="1"/></joint></robot>', "<limit lower=", "finite")
    fails(head + '<joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>'
          '</robot>', "no moving joint")
    fails(head + '<joint name="j" type="revolute"><parent link="a"/></joint></robot>',
          "joint 'j'", "<child link=")
    fails(head + '<joint name="j" type="revolute"><parent link="a"/><child link="b"/></joint>'
          '<joint name="k" type="revolute"><parent link="b"/><child link="a"/></joint></robot>',
          "closed loop")
    fails('<robot name="r"><link name="a"/><link name="a"/></robot>', "link 'a'", "twice")
    with pytest.raises(RobotFileError, match="no such URDF file"):
        load_urdf(tmp_path / "missing.urdf")


# --------------------------------------------------------------------------- CLI
CLI = "from kincal.cli import main; main()"


def _cli(*args: str) -> subprocess.Popen:
    env = dict(os.environ, COLUMNS="200", NO_COLOR="1")
    return subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


# Runs `main()` once per argument list inside ONE interpreter (spawning a process per
# case costs ~0.5 s of imports each); the exit code is SystemExit.code, which is what
# the process would return.  test_cli_process_exit_code checks a real process too.
DRIVER = """
import contextlib, io, json, sys
from kincal.cli import main
results = []
for args in json.loads(sys.argv[1]):
    sys.argv = ["kincal", *args]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code
    results.append([code, out.getvalue(), err.getvalue()])
print(json.dumps(results))
"""


def _bad_args(name: str, kw: dict) -> list[str]:
    opts = [str(FIXTURES / name)]
    for key, val in kw.items():
        opts += [f"--{key.replace('_', '-')}", val]
    return opts


def test_cli_bad_urdf_exit_code_2_one_line():
    """Every bad case through `kincal show`: exit code 2, one line on stderr, no traceback."""
    cases = [["show", *_bad_args(name, kw)] for name, kw, _ in BAD]
    proc = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(cases)],
                          capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, COLUMNS="200", NO_COLOR="1"))
    assert proc.returncode == 0, proc.stderr
    results = json.loads(proc.stdout)
    for (code, out, err), (_, _, words) in zip(results, BAD, strict=True):
        assert code == 2, (words, err)
        assert "Traceback" not in err and out == ""
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith("error: ") and all(w in lines[0] for w in words), err


def test_cli_process_exit_code():
    proc = _cli("show", str(FIXTURES / "bad_nan.urdf"))
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and out == "" and "Traceback" not in err
    assert err.count("\n") == 1 and "bad_nan.urdf: line 6: joint 'shoulder'" in err


def test_cli_show_and_fk():
    tiago = _need(TIAGO)
    show = _cli("show", str(tiago), "--tip-link", "wrist_ft_tool_link")
    fk = _cli("fk", str(ARM), "--tip-link", "tool0", "--q", "0.1,-0.2,0.05,0.3,0.4",
              "--json", "-")
    out, err = show.communicate(timeout=60)
    assert show.returncode == 0, err
    assert "tiago: 8 joints (urdf)" in out and "91 parameters" in out
    for name in TIAGO_JOINTS:
        assert name in out
    assert "arm_7_joint.offset" in out
    out, err = fk.communicate(timeout=60)
    assert fk.returncode == 0, err
    T = np.array(json.loads(out)["T"])
    robot = load_urdf(ARM, tip_link="tool0")
    np.testing.assert_allclose(T, robot.fk([0.1, -0.2, 0.05, 0.3, 0.4]), atol=1e-15)
