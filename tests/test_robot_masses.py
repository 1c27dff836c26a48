"""Link masses stated in robot files (UR's published table in the built-in URs): the
gravity load they give equals ``-dV/dq`` of the potential energy computed independently
from the DH table (centres of mass placed by plain DH matrices, derivative by central
differences), so ``--joint-model compliance`` works on a built-in UR without a URDF."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kincal.errors import KincalError, RobotFileError
from kincal.robots.files import load_serial_robot
from kincal.robots.gravity import gravity_torques
from kincal.robots.masses import stated_masses
from kincal.workflow.session import joint_masses

#: UR10 (CB3) rows of UR's table: a, d, alpha of each DH row; mass, centre of mass in
#: the row's DH frame (written out here, not read from the library file).
UR10 = {"a": [0, -0.612, -0.5723, 0, 0, 0], "d": [0.1273, 0, 0, 0.163941, 0.1157, 0.0922],
        "alpha": [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0],
        "m": [7.1, 12.7, 4.27, 2.0, 2.0, 0.365],
        "c": [[0.021, 0, 0.027], [0.38, 0, 0.158], [0.24, 0, 0.068], [0, 0.007, 0.018],
              [0, 0.007, 0.018], [0, 0, -0.026]]}


def _potential(q: np.ndarray) -> float:
    """``V = -sum m g . c`` [J] with ``g = (0, 0, -9.81)``, frames by standard DH."""
    T, V = np.eye(4), 0.0
    for i in range(6):
        ct, st = np.cos(q[i]), np.sin(q[i])
        ca, sa = np.cos(UR10["alpha"][i]), np.sin(UR10["alpha"][i])
        A = np.array([[ct, -st * ca, st * sa, UR10["a"][i] * ct],
                      [st, ct * ca, -ct * sa, UR10["a"][i] * st],
                      [0, sa, ca, UR10["d"][i]], [0, 0, 0, 1]])
        T = T @ A
        c = T @ np.array([*UR10["c"][i], 1.0])
        V += UR10["m"][i] * 9.81 * c[2]
    return V


def test_ur10_masses_give_the_gravity_load_of_the_dh_table():
    robot = load_serial_robot("ur10")
    masses = stated_masses(robot)
    assert masses is not None and [m.mass for m in masses] == UR10["m"]
    rng = np.random.default_rng(2)
    q = rng.uniform(-np.pi, np.pi, (4, 6))
    tau = gravity_torques(robot, q, masses)
    h = 1e-6
    for k in range(len(q)):
        want = [-(_potential(q[k] + h * e) - _potential(q[k] - h * e)) / (2 * h)
                for e in np.eye(6)]
        np.testing.assert_allclose(tau[k], want, atol=1e-6)
    assert np.abs(tau[:, 1]).max() > 50.0                  # the shoulder carries ~ 100 N m


#: Universal_Robots_ROS2_Description, config/ur16e/physical_parameters.yaml: masses and
#: centres of mass in its URDF link frames, with the rule beside each that maps UR's DH
#: table ("model") into them; written out here, not read from the library file.
UR16E_URDF = {"m": [7.369, 10.450, 4.321, 2.180, 2.033, 0.907],
              "c": [[0.0, -0.030, -0.016], [-0.1764, 0.0, 0.16], [-0.166, 0.0, 0.065],
                    [0.0, -0.011, -0.009], [0.0, 0.012, -0.018], [0.0, 0.0, -0.044]]}


def _urdf_frame(i: int, c: list[float], a: list[float]) -> list[float]:
    """The description's rules: shoulder and wrist 1 ``(x, -z, y)``, upper arm and
    forearm ``(x - link length, y, z)``, wrist 2 ``(x, z, -y)``, wrist 3 as is."""
    x, y, z = c
    if i in (0, 3):
        return [x, -z, y]
    if i in (1, 2):
        return [x + a[i], y, z]          # a[i] is minus the link length
    if i == 4:
        return [x, z, -y]
    return [x, y, z]


def test_ur16e_masses_are_the_ros_description_s_in_the_dh_frames():
    robot = load_serial_robot("ur16e")
    masses = robot.meta["masses"]["links"]
    a = [robot.params()[f"a[{i + 1}]"] for i in range(6)]
    assert [row["mass"] for row in masses] == UR16E_URDF["m"]
    for i, row in enumerate(masses):
        np.testing.assert_allclose(_urdf_frame(i, row["com"], a), UR16E_URDF["c"][i],
                                   atol=1e-12)


@pytest.mark.parametrize("name", ["ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e",
                                  "ur20"])
def test_built_in_urs_state_their_masses(name):
    masses = joint_masses(name)
    assert len(masses) == 6 and all(m.mass > 0 for m in masses)


def test_bad_masses_are_one_line_errors(tmp_path):
    robot = load_serial_robot("ur10")
    bad = dict(robot.meta["masses"])
    bad["links"] = [{"joint": "elbow", "mass": -1.0, "com": [0, 0, 0]}]
    with pytest.raises(RobotFileError, match=r"masses\.links\[0\]: mass must be >= 0"):
        stated_masses(dataclasses.replace(robot, meta={**robot.meta, "masses": bad}))
    with pytest.raises(KincalError, match="states none"):
        joint_masses("puma560")
