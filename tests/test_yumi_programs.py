"""RAPID programs of the ABB YuMi (IRB 14000, 7 axes): axis 7 travels in ``eax_a``.

ABB's RAPID carries a 7-axis arm's axis 7 in the first external axis: ``jointtarget
[[rax_1 ... rax_6], [eax_a, 9E9, ...]]`` (the synchronization position is
``[[0, -130, 30, 0, 40, 0], [-135, 9E9, ...]]`` on the right arm) and, as the arm angle
the controller keeps while it solves the pose, ``robtarget [..., [cf1, cf4, cf6, cfx],
[eax_a, 9E9, ...]]``.  The filter keeps a robtarget's ``eax_a`` and solves the six other
axes; an offline jointtarget gets all seven corrected.

Independent check: the program is written here from numpy forward kinematics of the
ROS-Industrial URDF numbers (tests/data/robots/ros_industrial_urdfs.yaml), the calibration
moves joint zeros only (``f_cal(q) = f_nom(q + d)``), and a numpy Newton solve (finite-
difference Jacobian) plays the nominal controller on the filtered numbers.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import run

from kincal.robots.controller import controller_map
from kincal.robots.files import load_serial_robot, write_robot_yaml

FIXTURE = yaml.safe_load((Path(__file__).parent / "data" / "robots" / "ros_industrial_urdfs.yaml")
                         .read_text(encoding="utf-8"))["yumi_r"]
#: The calibration's joint zero shifts [deg], model order (rax_1, rax_2, eax_a, rax_3 ...).
ZERO_SHIFT_DEG = np.array([0.0, 0.05, 0.04, -0.03, 0.0, 0.06, 0.0])
#: Controller axes (rax_1 ... rax_6, eax_a) [deg] of the two robtargets.
PICK = [-20.0, -100.0, 20.0, 30.0, 50.0, 10.0, -110.0]
PLACE = [10.0, -90.0, 10.0, -20.0, 60.0, -30.0, -100.0]


def _rot(axis, a: float) -> np.ndarray:
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * (K @ K)


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    return _rot((0, 0, 1), y) @ _rot((0, 1, 0), p) @ _rot((1, 0, 0), r)


def fk(q_model: np.ndarray) -> np.ndarray:
    """base -> tool0 of the URDF numbers at model joints [rad] (chain order)."""
    T = np.eye(4)
    for xyz, rpy, qi in zip(FIXTURE["xyz"], FIXTURE["rpy"], q_model, strict=True):
        A = np.eye(4)
        A[:3, :3] = _rpy(*rpy) @ _rot((0, 0, 1), qi)
        A[:3, 3] = xyz
        T = T @ A
    t0 = np.eye(4)
    t0[:3, :3] = _rpy(*np.radians(FIXTURE["tool0"]["rpy"]))
    t0[:3, 3] = FIXTURE["tool0"]["xyz"]
    return T @ t0


def model(axes_deg) -> np.ndarray:
    """RAPID's (rax_1 ... rax_6, eax_a) [deg] -> chain order [rad]."""
    a = np.radians(axes_deg)
    return np.array([a[0], a[1], a[6], a[2], a[3], a[4], a[5]])


def quat(R: np.ndarray) -> np.ndarray:
    w = math.sqrt(max(0.0, 1 + np.trace(R))) / 2
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
                     (R[1, 0] - R[0, 1]) / (4 * w)])


def rot_of(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def controller_ik(T: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """The nominal controller: Newton on the six axes other than axis 7 (chain index 2),
    finite-difference Jacobian of :func:`fk`, from ``q0`` [rad]."""
    free = [0, 1, 3, 4, 5, 6]
    q = q0.copy()
    for _ in range(30):
        C = fk(q)
        e = np.concatenate([T[:3, 3] - C[:3, 3], 0.5 * _vee(C[:3, :3].T @ T[:3, :3], C)])
        if np.linalg.norm(e) < 1e-13:
            break
        J = np.zeros((6, 6))
        for c, j in enumerate(free):
            h = np.zeros(7)
            h[j] = 1e-7
            Cp, Cm = fk(q + h), fk(q - h)
            J[:3, c] = (Cp[:3, 3] - Cm[:3, 3]) / 2e-7
            J[3:, c] = 0.5 * _vee(Cm[:3, :3].T @ Cp[:3, :3], C) / 2e-7
        q[free] += np.linalg.solve(J, e)
    return q


def _vee(R_rel: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Rotation vector of a small relative rotation in the tool frame, expressed in the base."""
    w = np.array([R_rel[2, 1] - R_rel[1, 2], R_rel[0, 2] - R_rel[2, 0], R_rel[1, 0] - R_rel[0, 1]])
    return C[:3, :3] @ w


def _robtarget(axes) -> str:
    T = fk(model(axes))
    p, q = T[:3, 3] * 1e3, quat(T[:3, :3])
    cf = [math.floor(axes[k] / 90) for k in (0, 3, 5)]
    return (f"[[{p[0]:.3f},{p[1]:.3f},{p[2]:.3f}],[{q[0]:.6f},{q[1]:.6f},{q[2]:.6f},"
            f"{q[3]:.6f}],[{cf[0]},{cf[1]},{cf[2]},4],[{axes[6]:g},9E+09,9E+09,9E+09,9E+09,"
            "9E+09]]")


PROGRAM = f"""MODULE YumiRight
    CONST jointtarget jSync:=[[0,-130,30,0,40,0],[-135,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST jointtarget jAbove:=[[-20.0000,-100.0000,20.0000,30.0000,50.0000,10.0000],
                               [-110.0000,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pPick:={_robtarget(PICK)};
    CONST robtarget pPlace:={_robtarget(PLACE)};

    PROC main()
        MoveAbsJ jSync\\NoEOffs, v200, fine, tool0;
        MoveAbsJ jAbove\\NoEOffs, v200, fine, tool0;
        MoveJ pPick, v200, fine, tool0;
        MoveL pPlace, v200, fine, tool0;
    ENDPROC
ENDMODULE
"""


def _numbers(text: str, name: str) -> list[float]:
    m = re.search(rf"{name}:=(\[.*?\]\]);", text, re.DOTALL)
    assert m is not None, name
    return [float(v) for v in re.findall(r"[-+]?\d+(?:\.\d*)?(?:E[-+]?\d+)?", m.group(1))]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory) -> str:
    nom = load_serial_robot("yumi_r")
    names = [f"{j}.offset" for j in nom.joint_names]
    p = nom.params()
    cal = nom.with_params({n: p[n] + math.radians(d) for n, d in
                           zip(names, ZERO_SHIFT_DEG, strict=True)}).with_name("yumi_r_cal")
    path = tmp_path_factory.mktemp("yumi") / "yumi_r_cal.yaml"
    write_robot_yaml(cal, path)
    # The calibration is the zero shifts: the calibrated arm at q is the URDF's at q + d.
    q = model(PICK)
    np.testing.assert_allclose(load_serial_robot(str(path)).fk(q),
                               fk(q + np.radians(ZERO_SHIFT_DEG)), atol=1e-12)
    return str(path)


def test_controller_map_reads_eax_a_as_axis_7():
    cmap = controller_map(load_serial_robot("yumi_r"))
    np.testing.assert_allclose(cmap.to_model(np.array(PICK)), model(PICK), atol=1e-15)
    np.testing.assert_allclose(cmap.to_axes(model(PICK)[None])[0], PICK, atol=1e-12)


def test_yumi_program_filtered_keeps_arm_angle_and_reaches_targets(calibrated, tmp_path,
                                                                   capsys):
    src = tmp_path / "YumiRight.mod"
    src.write_text(PROGRAM, encoding="utf-8")
    out = tmp_path / "out" / "YumiRight.mod"
    code, stdout, err = run(capsys, "filter", src, "--robot", calibrated, "--nominal", "yumi_r",
                            "-o", out)
    assert code == 0, stdout + err
    text = out.read_text(encoding="utf-8")
    assert _numbers(text, "jSync") == _numbers(PROGRAM, "jSync")     # taught: kept
    d = np.radians(ZERO_SHIFT_DEG)
    for name, axes in (("pPick", PICK), ("pPlace", PLACE)):
        old, new = _numbers(PROGRAM, name), _numbers(text, name)
        assert new[11:] == old[11:]                   # confdata quadrants, eax_a: the same
        assert new[11] == axes[6]
        # The nominal controller solves the filtered pose with axis 7 = eax_a ...
        T_new = np.eye(4)
        T_new[:3, :3], T_new[:3, 3] = rot_of(new[3:7]), np.array(new[:3]) * 1e-3
        q = controller_ik(T_new, model(axes))
        assert abs(q[2] - math.radians(axes[6])) < 1e-15
        # ... and the real (calibrated) robot there reaches the written target: to the
        # program's 3 decimals in mm and 6 of the quaternion.
        real = fk(q + d)
        T_old = np.eye(4)
        T_old[:3, :3], T_old[:3, 3] = rot_of(old[3:7]), np.array(old[:3]) * 1e-3
        assert np.linalg.norm(real[:3, 3] - T_old[:3, 3]) < 2e-6
        cos = (np.trace(real[:3, :3].T @ T_old[:3, :3]) - 1) / 2
        assert math.acos(min(1.0, cos)) < 5e-6
        assert np.linalg.norm(T_new[:3, 3] - T_old[:3, 3]) > 1e-4    # it was corrected


def test_offline_jointtarget_gets_all_seven_axes(calibrated, tmp_path, capsys):
    src = tmp_path / "YumiRight.mod"
    src.write_text(PROGRAM, encoding="utf-8")
    out = tmp_path / "out" / "YumiRight.mod"
    code, stdout, err = run(capsys, "filter", src, "--robot", calibrated, "--nominal", "yumi_r",
                            "-o", out, "--joint-targets", "offline")
    assert code == 0, stdout + err
    new = np.array(_numbers(out.read_text(encoding="utf-8"), "jAbove")[:7])
    old = np.array(PICK)
    # All seven axes written (eax_a too), a nearby solution of f_cal(q') = f_nom(q), with
    # f_cal(q) = f_nom(q + d); to the program's 4 decimals (5e-5 deg x 7 axes x 0.6 m).
    assert new[6] != old[6] and np.max(np.abs(new - old)) < 0.2
    np.testing.assert_allclose(fk(model(new) + np.radians(ZERO_SHIFT_DEG)), fk(model(old)),
                               atol=4e-6)


def test_jointtarget_without_axis_7_is_listed_not_filtered(calibrated, tmp_path, capsys):
    src = tmp_path / "YumiRight.mod"
    src.write_text(PROGRAM.replace("[-110.0000,9E+09", "[9E+09,9E+09"), encoding="utf-8")
    out = tmp_path / "out" / "YumiRight.mod"
    code, stdout, err = run(capsys, "filter", src, "--robot", calibrated, "--nominal", "yumi_r",
                            "-o", out, "--joint-targets", "offline")
    assert code == 1 and "Traceback" not in err
    assert "jAbove" in err and "without axis 7" in err and err.count("\n") == 1
