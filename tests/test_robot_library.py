"""The industrial robots of the built-in library, checked against what their vendors publish.

* Each robot built from a ROS-Industrial URDF equals that URDF: the joint origins, axes and
  limits were copied by hand into tests/data/robots/ros_industrial_urdfs.yaml (repository,
  path and commit named there) and their forward kinematics is computed here with numpy
  (Rodrigues), not with kincal's URDF loader: 1e-6 mm, since the numbers are the same.
* The controller's conventions, as the vendors document them: KUKA's HOME (A2 = -90, A3 = +90)
  puts $FLANGE at A 0, B 90, C 0; ABB's calibration position puts tool0 at the quaternion
  [0.70711, 0, 0.70711, 0]; FANUC's J = 0 puts the faceplate at W, P, R = 180, -90, 0, and
  FANUC's J2/J3 interaction keeps the forearm's attitude when J2 alone moves.
* The reach in each vendor's model name (KR 10 R1100: 1100 mm, IRB 1200-7/0.7: 0.7 m, ...)
  equals the stretched arm of the URDF's numbers, to the name's rounding; five datasheet
  figures without a found source are marked UNVERIFIED (see REACH_UNVERIFIED).
* A URDF whose tree has ROS-Industrial's extra ``base`` leaf loads without ``--tip-link``.
* The joint map (controller axes <-> model joints): round trips, FANUC's coupling, a zero
  moved by calibration said in controller units.
* ``kincal robots --vendor`` lists each vendor's robots with their sources.
"""

from __future__ import annotations

import json
import math
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import run
from typer.testing import CliRunner

from kincal.cli import app
from kincal.errors import RobotFileError
from kincal.robots.controller import axis_zero_shifts, calibration_zero_shifts, controller_map
from kincal.robots.files import library_dir, library_names, load_serial_robot
from kincal.robots.urdf import load_urdf

DATA = Path(__file__).parent / "data" / "robots"
FIXTURE = yaml.safe_load((DATA / "ros_industrial_urdfs.yaml").read_text(encoding="utf-8"))
NAMES = sorted(FIXTURE)
TOL_M = 1e-9            # 1e-6 mm: same numbers, only a different front end
TOL_R = 1e-9            # rotation matrix entries
# ABB's tool0 is link_6 turned by ry = 90 deg (z out of the flange); the older IRB 2400 URDF
# leaves tool0 = link_6, so the comparison turns it as ABB defines tool0.
TOOL0_ABB = {"irb2400": (0.0, 90.0, 0.0)}


def _rng(name: str) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32(name.encode()))


def _rot(axis, angle) -> np.ndarray:
    """Rodrigues: rotation about the unit ``axis`` by ``angle`` [rad], (N, 3, 3)."""
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _rpy(r, p, y) -> np.ndarray:
    """URDF rpy [rad]: Rz(y) Ry(p) Rx(r)."""
    one = np.ones(1)
    return (_rot((0, 0, 1), y * one) @ _rot((0, 1, 0), p * one) @ _rot((1, 0, 0), r * one))[0]


def _hom(R, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def urdf_fk(spec: dict, q: np.ndarray, tool_rpy_deg=None) -> np.ndarray:
    """base -> tool0 of the fixture's URDF at URDF joint values ``q`` [rad], (N, 4, 4)."""
    n = q.shape[0]
    base = spec.get("base") or {"xyz": [0, 0, 0], "rpy": [0, 0, 0]}
    B = _hom(_rpy(*np.radians(base["rpy"])), base["xyz"])
    T = np.broadcast_to(np.linalg.inv(B), (n, 4, 4)).copy()
    rpys = spec.get("rpy") or [(0.0, 0.0, 0.0)] * len(spec["xyz"])
    for i, (xyz, ax) in enumerate(zip(spec["xyz"], spec["axis"], strict=True)):
        A = np.zeros((n, 4, 4))
        A[:, :3, :3] = _rpy(*rpys[i]) @ _rot(ax, q[:, i])
        A[:, :3, 3] = xyz
        A[:, 3, 3] = 1.0
        T = T @ A
    rpy = spec["tool0"]["rpy"] if tool_rpy_deg is None else tool_rpy_deg
    return T @ _hom(_rpy(*np.radians(rpy)), spec["tool0"]["xyz"])


def urdf_limits(spec: dict) -> np.ndarray:
    """(n, 2) [rad]; +-inf for a continuous joint (``limits: null``)."""
    lim = np.array([(-np.inf, np.inf) if v is None else v for v in spec["limits"]], float)
    return np.radians(lim) if spec["limit_unit"] == "deg" else lim


def test_every_fixture_robot_is_built_in():
    assert set(NAMES) <= set(library_names())


@pytest.mark.parametrize("name", NAMES)
def test_library_robot_equals_its_urdf(name):
    spec = FIXTURE[name]
    robot = load_serial_robot(name)
    lim = urdf_limits(spec)
    # Limits: the URDF's own where it writes degrees; its 3-4 decimal radians otherwise.
    tol = 1e-12 if spec["limit_unit"] == "deg" else 6e-4
    np.testing.assert_allclose(robot.joint_limits, lim, rtol=0, atol=tol)
    n = len(lim)
    box = np.where(np.isfinite(lim), lim, [-math.pi, math.pi])
    q = box[:, 0] + (box[:, 1] - box[:, 0]) * _rng(name).random((25, n))
    q = np.vstack([np.zeros(n), q])
    ours = robot.fk(q)
    ref = urdf_fk(spec, q, TOOL0_ABB.get(name))
    # Where the file writes a quarter turn as 1.5708 rad the library has pi/2: each such
    # rounding d turns the rest of the arm by d, moving the end by at most d x the arm's length.
    quarter = math.pi / 2
    rounding = sum(abs(v - round(v / quarter) * quarter) for r in spec.get("rpy") or []
                   for v in r)
    length = sum(np.linalg.norm(x) for x in spec["xyz"]) + np.linalg.norm(spec["tool0"]["xyz"])
    assert np.max(np.abs(ours[:, :3, 3] - ref[:, :3, 3])) <= TOL_M + rounding * length
    assert np.max(np.abs(ours[:, :3, :3] - ref[:, :3, :3])) <= TOL_R + rounding


@pytest.mark.parametrize("name", NAMES)
def test_file_names_its_source(name):
    spec = FIXTURE[name]
    robot = load_serial_robot(name)
    src = robot.meta["source"]
    assert spec["repo"] in src and spec["path"] in src and spec["commit"][:12] in src
    assert robot.meta["vendor"] in ("KUKA", "ABB", "FANUC", "Yaskawa", "UFACTORY", "Kinova")


# --------------------------------------------------------------------------- vendor conventions
def _R(name, axes_deg) -> np.ndarray:
    robot = load_serial_robot(name)
    q = controller_map(robot).to_model(np.asarray(axes_deg, float))
    return robot.fk(q)


KUKA = [n for n in NAMES if n.startswith("kr")]
ABB = [n for n in NAMES if FIXTURE[n]["repo"].startswith("ros-industrial/abb")
       and FIXTURE[n]["coupling"] == "identity"]
YUMI = [n for n in NAMES if FIXTURE[n]["coupling"] == "abb_axis7"]
FANUC = [n for n in NAMES if FIXTURE[n]["coupling"] == "fanuc_j2_j3"]


@pytest.mark.parametrize("name", KUKA)
def test_kuka_home_flange_is_a0_b90_c0(name):
    # KUKA's HOME {A1 0, A2 -90, A3 90, A4 0, A5 0, A6 0}: $FLANGE at A 0, B 90, C 0 (ZYX Euler)
    # = Ry(90): x down, z forward.
    T = _R(name, [0, -90, 90, 0, 0, 0])
    np.testing.assert_allclose(T[:3, :3], _rpy(0, math.pi / 2, 0), atol=1e-12)
    assert T[0, 3] > 0.3 and T[2, 3] > 0.3          # in front of and above $ROBROOT


@pytest.mark.parametrize("name", ABB)
def test_abb_calibration_position_tool0_quaternion(name):
    # ABB: at the calibration position (all axes 0) tool0 has the orientation
    # [q1, q2, q3, q4] = [0.707107, 0, 0.707107, 0] (z forward, x down).
    T = _R(name, np.zeros(6))
    w, x, y, z = math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)


@pytest.mark.parametrize("name", FANUC)
def test_fanuc_zero_pose_and_j2_j3_interaction(name):
    # FANUC: at J = 0 the faceplate has W, P, R = 180, -90, 0 (x up, z forward) ...
    wpr = _rpy(math.pi, -math.pi / 2, 0)
    T0 = _R(name, np.zeros(6))
    np.testing.assert_allclose(T0[:3, :3], wpr, atol=1e-12)
    # ... and J3 is the forearm's angle to the horizontal: moving J2 alone tilts the upper arm
    # but keeps the forearm (and, with J4 = J5 = J6 = 0, the faceplate) in the same attitude,
    # so the faceplate moves by the upper arm's chord only.
    spec = FIXTURE[name]
    upper = spec["xyz"][2][2]
    for j2 in (-30.0, 20.0, 45.0):
        T = _R(name, [0, j2, 0, 0, 0, 0])
        np.testing.assert_allclose(T[:3, :3], wpr, atol=1e-12)
        t = math.radians(j2)
        np.testing.assert_allclose(T[:3, 3] - T0[:3, 3],
                                   [upper * math.sin(t), 0, upper * (math.cos(t) - 1)],
                                   atol=1e-12)


# Maximum reach (to the wrist centre, arm stretched) [m] and the rounding it is given to.
# This checks the fixture's numbers against the vendor; test_library_robot_equals_its_urdf ties
# the library robots to the fixture.
#
# 1. The vendor's model designation states the reach (KUKA "R1100" = 1100 mm, ABB "-7/0.7" =
#    0.7 m), to the designation's own rounding (10 mm for KUKA's R numbers, 0.01 m for ABB's):
REACH_IN_NAME = {"kr10r1100sixx": (1.100, 0.005),    # KR 10 R1100 sixx
                 "kr16r1610_2": (1.610, 0.005),      # KR 16 R1610-2
                 "kr210r2700": (2.700, 0.005),       # KR 210 R2700 extra
                 "irb1200_7_70": (0.70, 0.005),      # IRB 1200-7/0.7
                 "irb1200_5_90": (0.90, 0.005),      # IRB 1200-5/0.9
                 "irb4600": (2.05, 0.005),           # IRB 4600-60/2.05
                 "irb6700": (2.60, 0.005)}           # IRB 6700-200/2.60
# 2. UNVERIFIED: datasheet figures whose vendor document (product specification / data sheet)
#    was searched for and not found; they are the figures the vendors' brochures are commonly
#    quoted with and agree with the URDFs to 1 mm, but no source is cited.  Replace each by
#    the data sheet's figure with its document name and edition when it is at hand.
REACH_UNVERIFIED = {"kr16_2": (1.611, 0.001),        # KR 16-2 (no reach in its name)
                    "lrmate200id": (0.717, 0.001),   # LR Mate 200iD
                    "m20ia": (1.811, 0.001),         # M-20iA
                    "gp7": (0.927, 0.001),           # Motoman GP7
                    "gp25": (1.730, 0.001)}          # Motoman GP25
REACH = {**REACH_IN_NAME, **REACH_UNVERIFIED}


def _stretched_reach(spec: dict) -> float:
    x = np.asarray(spec["xyz"], float)
    shoulder = math.hypot(x[1][0], x[1][1])                 # J1 axis -> J2 axis
    upper = np.linalg.norm(x[2])                            # J2 -> J3
    forearm = np.linalg.norm(x[3] + x[4])                   # J3 -> wrist centre (J5)
    return float(shoulder + upper + forearm)


@pytest.mark.parametrize("name", sorted(REACH))
def test_datasheet_reach(name):
    want, rounding = REACH[name]
    assert abs(_stretched_reach(FIXTURE[name]) - want) <= rounding + 1e-9


@pytest.mark.parametrize("name, reach", [("lbr_iiwa7", 0.800), ("lbr_iiwa14", 0.820)])
def test_lbr_iiwa_reach_is_its_model_name(name, reach):
    # LBR iiwa 7 R800 / 14 R820: A2 -> A4 -> A6 (shoulder to wrist centre) is 800 / 820 mm; the
    # library robot, stretched upright at q = 0, has its flange that far above A2 plus the
    # 126 mm flange.
    spec = FIXTURE[name]
    x = np.asarray(spec["xyz"], float)
    assert abs(x[3][2] + x[5][2] - reach) <= 1e-12
    T = load_serial_robot(name).fk(np.zeros(7))
    assert abs(T[2, 3] - (x[1][2] + reach + 0.126)) <= 1e-12
    assert abs(T[0, 3]) <= 1e-12 and abs(T[1, 3]) <= 1e-12


def test_xarm6_zero_position():
    # UFACTORY (xArm Studio, SDK get_position without a TCP offset): at the zero position the
    # xArm 6 flange is at X 207, Y 0, Z 112 mm with roll 180, pitch 0, yaw 0 deg.
    T = load_serial_robot("xarm6").fk(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [0.207, 0, 0.112], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], _rpy(math.pi, 0, 0), atol=1e-12)


# ABB YuMi: the synchronization position of each arm (RAPID jointtarget [[0, -130, 30, 0, 40, 0],
# [eax_a, 9E9, ...]] with eax_a = -135 right, +135 left) and the tool0 pose the controller
# reports there (robtarget in wobj0, as read through Robot Web Services from a YuMi controller
# and written in users' public YuMi programs: [[-9.578368507, -+182.609892723, 198.627808149],
# [0.066010726, -+0.842420918, -0.111214912, -+0.523068661], [0, 0, 0, 4], [-+135, ...]]).
YUMI_SYNC = {"yumi_r": (-135.0, -1.0), "yumi_l": (135.0, 1.0)}


@pytest.mark.parametrize("name", YUMI)
def test_yumi_axis7_is_eax_a_and_sync_position_is_the_controllers(name):
    robot = load_serial_robot(name)
    cmap = controller_map(robot)
    assert cmap.vendor == "abb" and cmap.axes[-1] == "eax_a" and robot.n == 7
    eax_a, side = YUMI_SYNC[name]
    axes = np.array([0, -130, 30, 0, 40, 0, eax_a])
    q = cmap.to_model(axes)
    # The chain's third joint is axis 7 (the URDF's yumi_joint_7 between joints 2 and 3).
    np.testing.assert_allclose(np.degrees(q), [0, -130, eax_a, 30, 0, 40, 0], atol=1e-12)
    T = robot.fk(q)
    np.testing.assert_allclose(T, urdf_fk(FIXTURE[name], np.radians(
        [[0, -130, eax_a, 30, 0, 40, 0]]))[0], atol=1e-12)
    p = np.array([-9.578368507, side * 182.609892723, 198.627808149]) * 1e-3
    w, x, y, z = 0.066010726, side * 0.842420918, -0.111214912, side * 0.523068661
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    # The URDF is not ABB's calibrated geometry (its shoulder mount has 4-decimal angles):
    # it agrees with the controller to 1.6 mm (right) / 1.4 mm (left) and 0.16 deg there.
    # Without its 7 mm flange or its half turn about z the miss would be 7 mm / 180 deg.
    assert np.linalg.norm(T[:3, 3] - p) < 2e-3
    angle = math.degrees(math.acos(np.clip((np.trace(R.T @ T[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 0.2


# --------------------------------------------------------------------------- URDF leaf rule
def _urdf(tmp_path, joints: list[tuple[str, str, str, str]]) -> Path:
    """A URDF of (name, type, parent, child) joints, each 0.1 m along x, turning about z."""
    links = sorted({p for _, _, p, _ in joints} | {c for _, _, _, c in joints})
    rows = [f'<link name="{n}"/>' for n in links]
    for name, kind, parent, child in joints:
        lim = '<limit lower="-3" upper="3" effort="0" velocity="1"/>' if kind != "fixed" else ""
        rows.append(f'<joint name="{name}" type="{kind}"><origin xyz="0.1 0 0" rpy="0 0 0"/>'
                    f'<parent link="{parent}"/><child link="{child}"/><axis xyz="0 0 1"/>'
                    f'{lim}</joint>')
    path = tmp_path / "r.urdf"
    path.write_text('<robot name="r">' + "".join(rows) + "</robot>", encoding="utf-8")
    return path


ARM = [("j1", "revolute", "base_link", "link_1"), ("j2", "revolute", "link_1", "link_2"),
       ("t0", "fixed", "link_2", "tool0")]


def test_ros_industrial_base_leaf_is_not_the_tip(tmp_path):
    # ROS-Industrial: base_link -> base (fixed) beside the arm: two leaves, one static.
    path = _urdf(tmp_path, ARM + [("b", "fixed", "base_link", "base")])
    robot = load_urdf(path)
    assert robot.meta["tip_link"] == "tool0" and robot.n == 2
    # Three links in the frame: 0.1 (j1) + 0.1 (j2) + 0.1 (tool0) along x at q = 0.
    np.testing.assert_allclose(robot.fk(np.zeros(2))[:3, 3], [0.3, 0, 0], atol=1e-15)


def test_static_leaves_below_the_root_through_fixed_chains(tmp_path):
    # A fixed chain of two links off the root (a pedestal marker) is still static.
    path = _urdf(tmp_path, ARM + [("b", "fixed", "base_link", "base"),
                                  ("m", "fixed", "base", "marker")])
    assert load_urdf(path).meta["tip_link"] == "tool0"


def test_two_moving_leaves_still_ask_for_the_tip(tmp_path):
    path = _urdf(tmp_path, ARM + [("b", "fixed", "base_link", "base"),
                                  ("g", "prismatic", "link_2", "finger")])
    with pytest.raises(RobotFileError, match="choose the tip with --tip-link"):
        load_urdf(path)
    assert load_urdf(path, tip_link="tool0").n == 2


def test_a_tree_of_fixed_joints_only_is_refused(tmp_path):
    path = _urdf(tmp_path, [("a", "fixed", "base_link", "x"), ("b", "fixed", "base_link", "y")])
    with pytest.raises(RobotFileError, match="leaf links"):
        load_urdf(path)


# --------------------------------------------------------------------------- kincal robots
def test_cli_robots_by_vendor_lists_sources(tmp_path):
    out = tmp_path / "kuka.json"
    res = CliRunner().invoke(app, ["robots", "--vendor", "KuKa", "--json", str(out)])
    assert res.exit_code == 0, res.output
    rows = json.loads(out.read_text())["robots"]
    assert {r["name"] for r in rows} == {"kr6", "kr10r1100sixx", "kr16_2", "kr16r1610_2",
                                         "kr210r2700", "lbr_iiwa7", "lbr_iiwa14"}
    assert all(r["vendor"] == "KUKA" and r["source"] for r in rows)
    assert any("kuka_kr16_support/urdf/kr16_2_macro.xacro" in r["source"] for r in rows)


def test_cli_robots_search_term(tmp_path):
    out = tmp_path / "r.json"
    res = CliRunner().invoke(app, ["robots", "--search", "collaborative", "--vendor", "abb",
                                   "--json", str(out)])
    assert res.exit_code == 0, res.output
    assert [r["name"] for r in json.loads(out.read_text())["robots"]] == ["gofa5", "yumi_l",
                                                                        "yumi_r"]


def test_cli_robots_unknown_vendor_is_one_line_exit_2(capsys):
    code, out, err = run(capsys, "robots", "--vendor", "kawasaki")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "no built-in robot matches vendor 'kawasaki'" in err
    assert "KUKA" in err


# --------------------------------------------------------------------------- the joint map
WITH_MAP = [n for n in library_names()
            if isinstance(yaml.safe_load((library_dir() / f"{n}.yaml").read_text(
                encoding="utf-8")).get("controller"), dict)]


@pytest.mark.parametrize("name", WITH_MAP)
def test_joint_map_round_trip(name):
    robot = load_serial_robot(name)
    cmap = controller_map(robot)
    rng = _rng(name + " map")
    q = rng.uniform(-2.5, 2.5, (20, robot.n))
    np.testing.assert_allclose(cmap.to_model(cmap.to_axes(q)), q, rtol=0, atol=1e-12)
    a = q / cmap.scale
    np.testing.assert_allclose(cmap.to_axes(cmap.to_model(a)), a, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", FANUC + ["m10ia"])
def test_fanuc_map_is_the_documented_coupling(name):
    # ROS-Industrial's fanuc driver: joint_3 = J2 + J3, every other joint its axis (the
    # m10ia DH model turns J3, J4, J5, J6 the other way: q3 = -(J2 + J3)).
    cmap = controller_map(load_serial_robot(name))
    J = np.array([10.0, 20.0, -35.0, 40.0, -50.0, 60.0])
    q = np.degrees(cmap.to_model(J))
    sign = -1.0 if name == "m10ia" else 1.0
    np.testing.assert_allclose(q, [10, 20, sign * (20 - 35), sign * 40, sign * -50, sign * 60],
                               atol=1e-12)


def _mapped_robot(tmp_path, controller: dict, key: str = "controller") -> Path:
    doc = {"name": "servo_arm", "units": {"length": "m", "angle": "deg"},
           "convention": "standard_dh",
           "joints": [{"name": "shoulder", "type": "revolute", "a": 0.1, "d": 0, "alpha": 0},
                      {"name": "elbow", "type": "revolute", "a": 0.1, "d": 0, "alpha": 0}],
           key: controller}
    path = tmp_path / "servo_arm.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def test_counts_sign_offset_and_gear_ratio(tmp_path):
    # A hobby-servo arm read as encoder counts (4096 a turn): the shoulder servo turns the
    # other way and reads 2048 at the model's zero; the elbow is driven through a 2:1 belt.
    path = _mapped_robot(tmp_path, {"axes": ["m1", "m2"], "unit": "counts",
                                    "counts_per_turn": 4096,
                                    "joints": {"shoulder": {"m1": -1}, "elbow": {"m2": 0.5}},
                                    "offsets": {"shoulder": 2048}}, key="joint_map")
    cmap = controller_map(load_serial_robot(path))
    q = cmap.to_model(np.array([[2048, 0], [3072, 1024], [1024, -2048]]))
    np.testing.assert_allclose(q, [[0, 0], [-math.pi / 2, math.pi / 4],
                                   [math.pi / 2, -math.pi / 2]], atol=1e-15)
    np.testing.assert_allclose(cmap.to_axes(q), [[2048, 0], [3072, 1024], [1024, -2048]],
                               atol=1e-9)


@pytest.mark.parametrize("bad, words", [
    ({"axes": ["m1", "m2"], "unit": "counts"}, "controller.counts_per_turn"),
    ({"axes": ["m1", "m2"], "unit": "counts", "counts_per_turn": 0}, "positive"),
    ({"axes": ["m1", "m2"], "unit": "deg", "counts_per_turn": 4096}, "only allowed"),
    ({"axes": ["m1", "m2"], "unit": "grad"}, "deg, rad or counts"),
])
def test_bad_joint_map_is_one_line(tmp_path, bad, words):
    with pytest.raises(RobotFileError, match=words) as info:
        controller_map(load_serial_robot(_mapped_robot(tmp_path, bad)))
    assert "\n" not in str(info.value)


def test_controller_and_joint_map_together_are_refused(tmp_path):
    path = _mapped_robot(tmp_path, {"axes": ["m1", "m2"]})
    doc = yaml.safe_load(path.read_text())
    doc["joint_map"] = doc["controller"]
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(RobotFileError, match="joint_map"):
        load_serial_robot(path)


@pytest.mark.parametrize("name, moved", [("lrmate200id", {"joint_2.offset": 0.01}),
                                         ("lrmate200id", {"joint_3.offset": -0.02}),
                                         ("kr10r1100sixx", {"A1.offset": 0.003}),
                                         ("m10ia", {"theta_offset[3]": 0.004})])
def test_zero_shift_in_controller_units(name, moved):
    nominal = load_serial_robot(name)
    names = [n for n in nominal.param_names if "offset" in n]
    assert set(moved) <= set(names), names
    cal = nominal.with_params({k: nominal.params()[k] + v for k, v in moved.items()})
    shifts = axis_zero_shifts(nominal, cal)
    cmap = controller_map(nominal)
    da = np.zeros(nominal.n)
    for z in shifts:
        da[list(cmap.axes).index(z.axis)] = z.shift
        assert z.unit == "deg" and "in controller units" in z.line()
    # The calibrated arm at controller values a is where the nominal model is at a + da.
    a = _rng(name).uniform(-40, 40, (10, nominal.n))
    np.testing.assert_allclose(cal.fk(cmap.to_model(a)), nominal.fk(cmap.to_model(a + da)),
                               atol=1e-12)
    if moved == {"joint_2.offset": 0.01}:
        # FANUC: J2's zero moved by +0.573 deg; J3 (against the horizontal) by the opposite.
        assert [(z.axis, round(z.shift, 3)) for z in shifts] == [("J2", 0.573), ("J3", -0.573)]
        assert shifts[0].line() == "J2 zero: +0.573 deg in controller units"
    if name == "kr10r1100sixx":     # A1 turns about -z: its zero moves the other way
        assert [(z.axis, round(z.shift, 4)) for z in shifts] == [("A1", -0.1719)]
    if name == "m10ia":             # q3 = -(J2 + J3): J3 alone, the other way
        assert [(z.axis, round(z.shift, 4)) for z in shifts] == [("J3", -0.2292)]


def test_calibrate_says_zero_shifts_in_controller_units(tmp_path, capsys):
    train, truth, cal, res = (tmp_path / f for f in ("t.csv", "truth.yaml", "cal.yaml", "r.json"))
    code, _, err = run(capsys, "simulate", "lrmate200id", "-o", train, "--truth", truth,
                       "--poses", "60", "--noise", "0.01mm", "--seed", "5")
    assert code == 0, err
    code, out, err = run(capsys, "calibrate", "lrmate200id", "--data", train, "-o", cal,
                         "--json", res, "--stages", "offsets,all")
    assert code == 0, err
    shifts = json.loads(res.read_text())["controller_zero_shifts"]
    # Independently of the joint map code: the offsets in the two files, joint_3 turning
    # about -y (scale -1), J3 = joint_3 - J2.
    nom = load_serial_robot("lrmate200id").params()
    new = load_serial_robot(cal).params()
    d2 = math.degrees(new["joint_2.offset"] - nom["joint_2.offset"])
    d3 = -math.degrees(new["joint_3.offset"] - nom["joint_3.offset"])
    got = {s["axis"]: s["shift"] for s in shifts}
    assert abs(d2) > 1e-3 and got["J2"] == pytest.approx(d2, abs=1e-9)
    assert got["J3"] == pytest.approx(d3 - d2, abs=1e-9)
    assert f"J3 zero: {got['J3']:+.3f} deg in controller units" in out


# --------------------------------------------------------------------------- UR20 / UR30
# UniversalRobots/Universal_Robots_ROS2_Description config/ur30/default_kinematics.yaml
# (commit 67272756de58): per joint x, y, z [m], roll, pitch, yaw [rad] of the joint frame in
# its parent; each joint turns about its own z.  The chain ends at wrist_3_link = UR's tool0.
UR30_KINEMATICS = [
    (0, 0, 0.23630000000000001, -0.0, 0, -0.0),
    (0, 0, 0, 1.570796327, 0, -0.0),
    (-0.637, 0, 0, -0.0, 0, -0.0),
    (-0.5037, 0, 0.20100000000000001, -0.0, 0, -0.0),
    (0, -0.1593, 0, 1.570796327, 0, -0.0),
    (0, 0.15429999999999999, -3.1647459019915597e-11, 1.5707963265897931, 3.1415926535897931,
     3.1415926535897931),
]


def rpy_chain_fk(rows, q: np.ndarray) -> np.ndarray:
    """Joint frames given as (x, y, z, roll, pitch, yaw) in the parent, each joint turning
    about its own z; extra rows beyond q's columns are fixed.  (N, 4, 4)."""
    T = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    for i, (x, y, z, r, p, w) in enumerate(rows):
        A = np.zeros((len(q), 4, 4))
        turn = q[:, i] if i < q.shape[1] else np.zeros(len(q))
        A[:, :3, :3] = _rpy(r, p, w) @ _rot((0, 0, 1), turn)
        A[:, :3, 3] = (x, y, z)
        A[:, 3, 3] = 1.0
        T = T @ A
    return T


def test_ur30_equals_urs_default_kinematics():
    robot = load_serial_robot("ur30")
    q = np.vstack([np.zeros(6), _rng("ur30").uniform(-math.pi, math.pi, (25, 6))])
    T = rpy_chain_fk(UR30_KINEMATICS, q)
    ours = robot.fk(q)
    # The file's roll 1.570796327 is pi/2 to 9 decimals: 3e-10 rad, < 1e-9 m at 1.5 m reach.
    assert np.max(np.abs(ours[:, :3, 3] - T[:, :3, 3])) <= 1e-9
    assert np.max(np.abs(ours[:, :3, :3] - T[:, :3, :3])) <= 1e-9



# --------------------------------------------------------------------------- Franka FR3
# franka_description robots/fr3/kinematics.yaml, joint1 ... joint8 (x, y, z, roll, pitch, yaw;
# read in Swiss-Battery-Technology-Center/franka_description, commit 3c55fbf8cbd2); joint8 is
# the fixed flange.  Limits: frankaemika/franka_description robots/fr3/joint_limits.yaml
# (commit 1ddff9ba71ab).
H = 1.570796326794897
FR3_KINEMATICS = [(0, 0, 0.333, 0, 0, 0), (0, 0, 0, -H, 0, 0), (0, -0.316, 0, H, 0, 0),
                  (0.0825, 0, 0, H, 0, 0), (-0.0825, 0.384, 0, -H, 0, 0), (0, 0, 0, H, 0, 0),
                  (0.088, 0, 0, H, 0, 0), (0, 0, 0.107, 0, 0, 0)]
FR3_LIMITS = [(-2.7437, 2.7437), (-1.7837, 1.7837), (-2.9007, 2.9007), (-3.0421, -0.1518),
              (-2.8065, 2.8065), (0.5445, 4.5169), (-3.0159, 3.0159)]


def test_fr3_equals_frankas_kinematics_and_limits():
    robot = load_serial_robot("fr3")
    lim = np.asarray(FR3_LIMITS)
    np.testing.assert_array_equal(robot.joint_limits, lim)
    q = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * _rng("fr3").random((25, 7))
    q = np.vstack([np.zeros(7), q])
    ours, ref = robot.fk(q), rpy_chain_fk(FR3_KINEMATICS, q)
    assert np.max(np.abs(ours - ref)) <= 1e-12
    # Franka: at q = 0 the flange is at (0.088, 0, 0.926) m, facing down.
    np.testing.assert_allclose(ours[0, :3, 3], [0.088, 0, 0.926], atol=1e-15)


def test_zero_shift_of_a_linear_axis_is_in_metres():
    # SCARA (RRPR): the prismatic joint's zero (d[3]) moved by 2 mm, the last joint's by 0.1 deg.
    nominal = load_serial_robot("scara")
    p = nominal.params()
    names = [n for n in nominal.param_names if n in ("d[3]", "theta_offset[4]")]
    assert names == ["d[3]", "theta_offset[4]"]
    cal = nominal.with_params({"d[3]": p["d[3]"] + 0.002,
                               "theta_offset[4]": p["theta_offset[4]"] + math.radians(0.1)})
    shifts = {z.axis: (round(z.shift, 9), z.unit) for z in axis_zero_shifts(nominal, cal)}
    axes = controller_map(nominal).axes
    assert shifts == {axes[2]: (0.002, "m"), axes[3]: (0.1, "deg")}


def test_no_zero_shifts_without_a_declared_controller():
    # puma560 declares no controller: its "controller units" are unknown, nothing is said.
    nominal = load_serial_robot("puma560")
    assert "controller" not in nominal.meta
    cal = nominal.with_params({"theta_offset[2]": nominal.params()["theta_offset[2]"] + 0.01})
    assert calibration_zero_shifts(nominal, cal) is None
    kr6 = load_serial_robot("kr6")
    moved = kr6.with_params({"theta_offset[2]": kr6.params()["theta_offset[2]"] + 0.01})
    assert [z.axis for z in calibration_zero_shifts(kr6, moved)] == ["A2"]
