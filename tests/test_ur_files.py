"""UR controller calibration files and the ROS kinematics YAML.

The independent check: a "true" UR whose joint origins are perturbed in a URDF-style
chain (so axes 2-4 are only nearly parallel), its exact standard-DH table computed here
from the joint axes (common normals), the difference to the nominal table written as a
``calibration.conf``.  Reading that file must give the true robot's kinematics; nearly
parallel axes put the DH frames hundreds of metres away (the factory files' large
``delta_d``), and the kinematics YAML written back must stay near the nominal numbers and
round-trip the kinematics to 1e-12 m.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from cli_helpers import run

from kincal.errors import RobotFileError
from kincal.robots.files import load_serial_robot
from kincal.robots.ur import (
    joint_frames,
    kinematics_yaml,
    read_calibration_conf,
    read_kinematics_yaml,
)

UR = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e"]


def _axes(robot, q=None):
    """Joint axes at q = 0 in the base frame: (point, direction) per joint, and the flange."""
    F = joint_frames(robot)
    return [(f[:3, 3], f[:3, 2]) for f in F], robot.fk(np.zeros(6))


def dh_from_axes(robot, nominal):
    """The standard-DH table (theta, d, a, alpha per link) of a 6R chain from its axes.

    Frame 0 is the robot's base frame; frame i has z along axis i + 1 and x along the
    common normal of axes i and i + 1 (sign nearest the nominal frame's x); frame 6 is
    the flange.
    """
    axes, E = _axes(robot)
    _, En = _axes(nominal)
    Fn = joint_frames(nominal)
    o, x, z = np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    rows = []
    for i in range(6):
        if i < 5:
            P, zn = axes[i + 1]
            w = np.cross(z, zn)
            # closest points of the lines (o, z) and (P, zn)
            A = np.array([[z @ z, -z @ zn], [z @ zn, -zn @ zn]])
            rhs = np.array([(P - o) @ z, (P - o) @ zn])
            t, s = np.linalg.solve(A, rhs)
            b, c = o + t * z, P + s * zn
            xn = c - b if np.linalg.norm(c - b) > 1e-12 else w
            xn = xn / np.linalg.norm(xn)
            ref = Fn[i + 1][:3, 0]
            if xn @ ref < 0:
                xn = -xn
        else:
            b, c, zn, xn = E[:3, 3], E[:3, 3], E[:3, 2], E[:3, 0]
            t = (b - o) @ z
        theta = math.atan2(np.cross(x, xn) @ z, x @ xn)
        d = (b - o) @ z
        a = (c - b) @ xn
        alpha = math.atan2(np.cross(z, zn) @ xn, z @ zn)
        rows.append((theta, d, a, alpha))
        o, x, z = c, xn, zn
    return np.array(rows)


@pytest.fixture(scope="module")
def true_ur5e(tmp_path_factory):
    """(nominal, truth, path of its calibration.conf)."""
    nom = load_serial_robot("ur5e")
    folder = tmp_path_factory.mktemp("ur")
    kin = folder / "nominal_kinematics.yaml"
    kin.write_text(kinematics_yaml(nom, nom))
    chain = read_kinematics_yaml(kin, nom)
    rng = np.random.default_rng(5)
    values = chain.params()
    for name in values:
        if name.startswith(("base.", "tool.")) or name.startswith("shoulder."):
            continue
        values[name] += rng.normal(0, 3e-4 if name.endswith((".x", ".y", ".z")) else 5e-4)
    truth = chain.with_params(values)
    dh = dh_from_axes(truth, nom)
    dh_nom = np.array([[L.theta_offset, L.d, L.a, L.alpha] for L in
                       __import__("kincal.robots.dh", fromlist=["dh_links"]).dh_links(nom)])
    delta = dh - dh_nom
    delta[:, 0] = (delta[:, 0] + np.pi) % (2 * np.pi) - np.pi
    delta[:, 3] = (delta[:, 3] + np.pi) % (2 * np.pi) - np.pi
    conf = folder / "calibration.conf"
    lines = ["[mounting]"]
    for k, name in enumerate(("theta", "d", "a", "alpha")):
        lines.append(f"delta_{name} = [ " + ", ".join(repr(float(v)) for v in delta[:, k]) + "]")
    lines.append("calibration_status = 2 # 2 == Linearised")
    conf.write_text("\n".join(lines) + "\n")
    return nom, truth, conf, delta


def test_calibration_conf_gives_the_true_kinematics(true_ur5e):
    nom, truth, conf, delta = true_ur5e
    assert np.max(np.abs(delta[1:4, 1])) > 10.0, "nearly parallel axes: DH frames far away"
    cal = read_calibration_conf(conf, nom)
    q = np.random.default_rng(1).uniform(-math.pi, math.pi, (300, 6))
    assert np.abs(cal.fk(q) - truth.fk(q))[:, :3, 3].max() < 1e-10
    assert np.abs(nom.fk(q) - truth.fk(q))[:, :3, 3].max() > 1e-3


def test_kinematics_yaml_round_trips_without_long_links(true_ur5e, tmp_path):
    nom, truth, conf, _ = true_ur5e
    cal = read_calibration_conf(conf, nom)
    text = kinematics_yaml(cal, nom)
    doc = yaml.safe_load(text)["kinematics"]
    nominal_doc = yaml.safe_load(kinematics_yaml(nom, nom))["kinematics"]
    for link in doc:
        if link == "hash":
            continue
        for key in ("x", "y", "z"):
            assert abs(doc[link][key] - nominal_doc[link][key]) < 0.01, (link, key)
    path = tmp_path / "kin.yaml"
    path.write_text(text)
    back = read_kinematics_yaml(path, nom)
    q = np.random.default_rng(2).uniform(-math.pi, math.pi, (300, 6))
    assert np.abs(back.fk(q) - cal.fk(q))[:, :3, 3].max() < 1e-12       # the round trip
    assert np.abs(back.fk(q) - truth.fk(q))[:, :3, 3].max() < 1e-10     # the DH file's digits


@pytest.mark.parametrize("name", UR)
def test_nominal_kinematics_yaml_is_ur_descriptions(name, tmp_path):
    """The nominal YAML has UR's DH numbers where ur_description's default_kinematics has
    them (shoulder z = d1, forearm x = a2, wrist_1 x = a3 and z = d4, wrist_2 y = -d5,
    wrist_3 y = d6) and reproduces the DH model."""
    from kincal.robots.dh import dh_links

    nom = load_serial_robot(name)
    L = dh_links(nom)
    doc = yaml.safe_load(kinematics_yaml(nom, nom))["kinematics"]
    assert doc["shoulder"]["z"] == pytest.approx(L[0].d, abs=1e-15)
    assert doc["forearm"]["x"] == pytest.approx(L[1].a, abs=1e-15)
    assert doc["wrist_1"]["x"] == pytest.approx(L[2].a, abs=1e-15)
    assert doc["wrist_1"]["z"] == pytest.approx(L[3].d, abs=1e-15)
    assert doc["wrist_2"]["y"] == pytest.approx(-L[4].d, abs=1e-15)
    assert doc["wrist_3"]["y"] == pytest.approx(L[5].d, abs=1e-15)
    path = tmp_path / "k.yaml"
    path.write_text(kinematics_yaml(nom, nom))
    q = np.random.default_rng(3).uniform(-math.pi, math.pi, (100, 6))
    assert np.abs(read_kinematics_yaml(path, nom).fk(q) - nom.fk(q)).max() < 1e-14


def test_published_ur_numbers_at_zero():
    """UR's zero posture: the arm stretched along -x; flange at (a2 + a3, -(d4 + d6), d1 - d5)."""
    for name in UR:
        from kincal.robots.dh import dh_links

        L = dh_links(load_serial_robot(name))
        p = load_serial_robot(name).fk(np.zeros(6))[:3, 3]
        assert np.allclose(p, [L[1].a + L[2].a, -(L[3].d + L[5].d), L[0].d - L[4].d],
                           atol=1e-15)


def test_bad_calibration_conf_names_the_line(tmp_path):
    f = tmp_path / "calibration.conf"
    f.write_text("[mounting]\ndelta_theta = [ 0, 0, 0, 0, 0]\n")
    with pytest.raises(RobotFileError, match=r"calibration.conf: line 2: delta_theta needs 6"):
        read_calibration_conf(f, load_serial_robot("ur5"))


def test_import_ur_command(true_ur5e, tmp_path, capsys):
    nom, truth, conf, _ = true_ur5e
    out, kin = tmp_path / "cal.yaml", tmp_path / "kinematics.yaml"
    code, stdout, err = run(capsys, "import", "ur", conf, "--nominal", "ur5e", "-o", out,
                            "--kinematics", kin)
    assert code == 0, err
    assert "round trip" in stdout
    robot = load_serial_robot(str(out))
    q = np.random.default_rng(4).uniform(-3, 3, (50, 6))
    assert np.abs(robot.fk(q) - truth.fk(q))[:, :3, 3].max() < 1e-9
    code, stdout, err = run(capsys, "import", "ur", kin, "--nominal", "ur5e",
                            "-o", tmp_path / "from_yaml.yaml")
    assert code == 0, err
    back = load_serial_robot(str(tmp_path / "from_yaml.yaml"))
    assert np.abs(back.fk(q) - truth.fk(q))[:, :3, 3].max() < 1e-9


def test_import_and_ur_kinematics_refuse_to_write_over_their_input(true_ur5e, tmp_path,
                                                                   capsys):
    """-o / --kinematics / --json on the file being read: exit 2, one line, input intact."""
    _, _, conf, _ = true_ur5e
    before = conf.read_bytes()
    for opt in ("-o", "--kinematics", "--json"):
        args = ["import", "ur", conf, "--nominal", "ur5e", "-o", tmp_path / "cal.yaml"]
        code, _, err = run(capsys, *(args[:-2] + [opt, conf] if opt == "-o" else
                                     args + [opt, conf]))
        assert code == 2 and f"option {opt}:" in err and "also the input of FILE" in err, err
    assert conf.read_bytes() == before
    assert run(capsys, "import", "ur", conf, "--nominal", "ur5e", "-o",
               tmp_path / "cal.yaml")[0] == 0
    robot_before = (tmp_path / "cal.yaml").read_bytes()
    code, _, err = run(capsys, "ur-kinematics", tmp_path / "cal.yaml", "--nominal", "ur5e",
                       "-o", tmp_path / "cal.yaml")
    assert code == 2 and "also the input of ROBOT" in err, err
    assert (tmp_path / "cal.yaml").read_bytes() == robot_before
