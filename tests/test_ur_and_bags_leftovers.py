"""UR files and ROS bags as users bring them: a kinematics YAML of another UR model or
with a frame turned by pi is refused (exit 1) naming the parameter and the model that fits;
an unchanged round trip keeps the factory hash the UR driver checks; a damaged bag, a topic
of the wrong type and a bag with joint states only each get their own answer."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run

from kincal.robots.files import load_serial_robot
from kincal.robots.ur import kinematics_yaml

FACTORY_HASH = "calib_12788084448423163542"       # the form ur_calibration writes


def _factory_yaml(path, model: str, turn_upper_arm: bool = False) -> None:
    """ur_description's nominal numbers of ``model`` with a factory hash; optionally the
    upper arm's frame turned by pi about x (roll +pi/2 -> -pi/2)."""
    text = kinematics_yaml(load_serial_robot(model), load_serial_robot(model), FACTORY_HASH)
    if turn_upper_arm:
        old = "  upper_arm:\n    x: 0\n    y: 0\n    z: 0\n    roll: 1.5707963267948966\n"
        assert old in text
        text = text.replace(old, old.replace("roll: 1.5", "roll: -1.5"))
    path.write_text(text)


@pytest.mark.parametrize(("model", "read_as", "parameter"),
                         [("ur3e", "ur3", "wrist_2.z"), ("ur10e", "ur10", "upper_arm.z")])
def test_another_model_is_refused_naming_the_model_that_fits(model, read_as, parameter,
                                                             tmp_path, capsys):
    f = tmp_path / f"{model}.yaml"
    _factory_yaml(f, model)
    a, b = load_serial_robot(model), load_serial_robot(read_as)
    q = np.zeros((1, 6))
    gap = np.linalg.norm(a.fk(q)[0, :3, 3] - b.fk(q)[0, :3, 3])
    assert gap > 0.01                                   # the two models differ by cm
    code, out, err = run(capsys, "import", "ur", f, "--nominal", read_as,
                         "-o", tmp_path / "r.yaml")
    assert code == 1, err
    assert len(err.strip().splitlines()) == 1
    assert parameter in err and f"--nominal {model}" in err and f.name in err
    assert not (tmp_path / "r.yaml").exists()
    code, out, err = run(capsys, "import", "ur", f, "--nominal", model, "-o", tmp_path / "r.yaml")
    assert code == 0, err


def test_a_turned_frame_is_refused_unless_forced(tmp_path, capsys):
    f = tmp_path / "turned.yaml"
    _factory_yaml(f, "ur5e", turn_upper_arm=True)
    code, out, err = run(capsys, "import", "ur", f, "--nominal", "ur5e", "-o", tmp_path / "r.yaml")
    assert code == 1 and "upper_arm.roll" in err and "-180.000 deg" in err
    assert "no built-in UR fits" in err and len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "import", "ur", f, "--nominal", "ur5e", "-o", tmp_path / "r.yaml",
                         "--force")
    assert code == 0, err
    assert (tmp_path / "r.yaml").exists()


def test_unchanged_round_trip_keeps_the_factory_hash(tmp_path, capsys):
    f = tmp_path / "factory.yaml"
    _factory_yaml(f, "ur5e")
    kin = tmp_path / "kin.yaml"
    code, out, err = run(capsys, "import", "ur", f, "--nominal", "ur5e", "-o",
                         tmp_path / "r.yaml", "--kinematics", kin)
    assert code == 0, err
    assert f"hash: {FACTORY_HASH}\n" in kin.read_text()
    assert "kept from the input" in out
    # a robot file has no hash: the new YAML gets kincal's, and the output says what the
    # UR driver logs about it
    code, out, err = run(capsys, "ur-kinematics", tmp_path / "r.yaml", "--nominal", "ur5e",
                         "-o", tmp_path / "k2.yaml")
    assert code == 0, err
    assert "hash: calib_kincal_" in (tmp_path / "k2.yaml").read_text()
    assert "logs an ERROR" in " ".join(out.split())


# ---- ROS bags ---------------------------------------------------------------------------

rosbags = pytest.importorskip("rosbags", reason="the 'ros' extra (rosbags) is not installed")
from test_bags import MOVE, STILL, session, write_bag  # noqa: E402


@pytest.fixture(scope="module")
def short_session():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(21)
    postures = rng.uniform(-1.0, 1.0, (6, robot.n))
    return robot, postures, session(robot, postures, rng)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_truncated_bag_is_one_line_exit_2(kind, short_session, tmp_path, capsys):
    robot, postures, (jt, jq, mt, mp) = short_session
    path = tmp_path / ("s.bag" if kind == "ros1" else "s")
    write_bag(path, kind, robot.joint_names, jt, jq, mt, mp)
    data = path if kind == "ros1" else next(path.glob("*.mcap"))
    raw = data.read_bytes()
    data.write_bytes(raw[: len(raw) // 2])          # recording cut off: no index, half a chunk
    code, out, err = run(capsys, "import", "bag", path, "-o", tmp_path / "d.csv", "--point",
                         "/tracker/point")
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and str(path.name) in err
    assert "internal error" not in err
    assert not (tmp_path / "d.csv").exists()


def test_a_topic_of_the_wrong_type_says_its_type(short_session, tmp_path, capsys):
    robot, postures, (jt, jq, mt, mp) = short_session
    path = tmp_path / "s.bag"
    write_bag(path, "ros1", robot.joint_names, jt, jq, mt, mp)
    code, out, err = run(capsys, "import", "bag", path, "-o", tmp_path / "d.csv", "--pose",
                         "/tracker/point")
    assert code == 2
    assert "geometry_msgs/msg/PointStamped" in err and "geometry_msgs/msg/PoseStamped" in err
    assert "no messages" not in err and len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "import", "bag", path, "-o", tmp_path / "d.csv", "--joints",
                         "/tracker/point", "--point", "/tracker/point")
    assert code == 2 and "sensor_msgs/msg/JointState" in err


def test_joint_states_only_give_the_standstills_with_their_times(short_session, tmp_path,
                                                                  capsys):
    robot, postures, (jt, jq, mt, mp) = short_session
    path = tmp_path / "joints"
    write_bag(path, "mcap", robot.joint_names, jt, jq, mt[:0], mp[:0])
    out_csv = tmp_path / "postures.csv"
    code, out, err = run(capsys, "import", "bag", path, "-o", out_csv, "--json",
                         tmp_path / "p.json")
    assert code == 0, err
    assert "6 standstill postures" in out
    doc = json.loads((tmp_path / "p.json").read_text())
    assert len(doc["postures"]) == len(postures)
    t_start = 1700000000.0                          # the bag's clock (write_bag's stamps)
    for k, (p, q) in enumerate(zip(doc["postures"], postures, strict=True)):
        still_from = t_start + k * (MOVE + STILL)   # the recorded standstill, known by design
        assert abs(p["t0_s"] - (still_from + 0.2)) < 0.03            # --settle 0.2 s
        assert still_from + 0.2 < p["t1_s"] <= still_from + STILL + 0.1
        assert np.abs(np.array(p["q"]) - q).max() < 1e-6
    rows = out_csv.read_text().splitlines()
    assert rows[1].split(",")[:2] == ["t0_s", "t1_s"] and len(rows) == 2 + len(postures)
    assert float(rows[2].split(",")[0]) == pytest.approx(doc["postures"][0]["t0_s"], abs=1e-6)
