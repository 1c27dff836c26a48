"""ROS bags in: real bags (ROS 1 .bag, ROS 2 MCAP) written with rosbags' own writer from a
simulated session - motion between postures, standstills, a tracker that also reports
while the robot moves - imported, checked against the recorded postures, and calibrated
back to the truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_helpers import run

from kincal.measure.bags import StillOptions, find_postures, read_bag_streams
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot

rosbags = pytest.importorskip("rosbags", reason="the 'ros' extra (rosbags) is not installed")
from rosbags.typesys import Stores, get_typestore  # noqa: E402

JOINT_RATE, TRACKER_RATE = 100.0, 40.0
MOVE, STILL = 1.5, 2.5                   # s
TRACKER_NOISE = 2e-5                     # m


def session(truth, postures: np.ndarray, rng, lost: int | None = None):
    """Time-stamped joint states and tracker points of a session: smooth joint moves of
    MOVE seconds between the postures, STILL seconds at each; the tracker measures the
    tool origin all the time (also while moving), except during posture ``lost``."""
    times, qs = [], []
    t = 0.0
    spans = []
    for k, q in enumerate(postures):
        if k:
            q_prev = postures[k - 1]
            for s in np.arange(0.0, MOVE, 1 / JOINT_RATE):
                a = 0.5 - 0.5 * math.cos(math.pi * s / MOVE)
                times.append(t + s)
                qs.append(q_prev + a * (q - q_prev))
            t += MOVE
        spans.append((t, t + STILL))
        for s in np.arange(0.0, STILL, 1 / JOINT_RATE):
            times.append(t + s)
            qs.append(q.copy())
        t += STILL
    jt = np.array(times)
    jq = np.array(qs) + rng.normal(0, 1e-7, (len(qs), postures.shape[1]))   # encoder noise
    mt = np.arange(0.0, t, 1 / TRACKER_RATE) + 0.0037
    q_at = np.array([np.interp(mt, jt, jq[:, j]) for j in range(jq.shape[1])]).T
    mp = truth.fk(q_at)[:, :3, 3] + rng.normal(0, TRACKER_NOISE, (len(mt), 3))
    if lost is not None:
        a, b = spans[lost]
        keep = (mt < a) | (mt > b)
        mt, mp = mt[keep], mp[keep]
    return jt, jq, mt, mp


def _stamp(ts, t):
    sec = int(t)
    return ts.types["builtin_interfaces/msg/Time"](sec=1700000000 + sec,
                                                  nanosec=int(round((t - sec) * 1e9)))


def write_bag(path, kind: str, names, jt, jq, mt, mp, as_tf: bool = False):
    """A ROS 1 (``kind="ros1"``) or ROS 2 MCAP (``"mcap"``) bag with /joint_states and
    /tracker/point (or /tf with mocap -> marker)."""
    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:     # ROS 1's store lacks it: its definition
        from rosbags.typesys import get_types_from_msg

        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                       "tf2_msgs/msg/TFMessage"))
    T = ts.types
    header_kw = (lambda t: {"seq": 0, "stamp": _stamp(ts, t), "frame_id": "base"}) \
        if kind == "ros1" else (lambda t: {"stamp": _stamp(ts, t), "frame_id": "base"})
    Header = T["std_msgs/msg/Header"]
    js_type, pt_type = "sensor_msgs/msg/JointState", "geometry_msgs/msg/PointStamped"
    tf_type = "tf2_msgs/msg/TFMessage"
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        ser = ts.serialize_cdr
    events = [(t, 0, i) for i, t in enumerate(jt)] + [(t, 1, i) for i, t in enumerate(mt)]
    events.sort()
    with writer:
        cj = writer.add_connection("/joint_states", js_type, typestore=ts)
        cm = (writer.add_connection("/tf", tf_type, typestore=ts) if as_tf else
              writer.add_connection("/tracker/point", pt_type, typestore=ts))
        for t, which, i in events:
            ns = 1700000000_000000000 + int(round(t * 1e9))
            if which == 0:
                msg = T[js_type](header=Header(**header_kw(t)), name=list(names),
                                 position=jq[i].astype(np.float64),
                                 velocity=np.zeros(0), effort=np.zeros(0))
                writer.write(cj, ns, ser(msg, js_type))
            elif as_tf:
                v = T["geometry_msgs/msg/Vector3"](x=mp[i, 0], y=mp[i, 1], z=mp[i, 2])
                r = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
                tr = T["geometry_msgs/msg/TransformStamped"](
                    header=Header(**{**header_kw(t), "frame_id": "mocap"}),
                    child_frame_id="marker",
                    transform=T["geometry_msgs/msg/Transform"](translation=v, rotation=r))
                writer.write(cm, ns, ser(T[tf_type](transforms=[tr]), tf_type))
            else:
                p = T["geometry_msgs/msg/Point"](x=mp[i, 0], y=mp[i, 1], z=mp[i, 2])
                writer.write(cm, ns, ser(T[pt_type](header=Header(**header_kw(t)), point=p),
                                         pt_type))


@pytest.fixture(scope="module")
def puma_session():
    nominal = load_serial_robot("puma560")
    truth = perturb_robot(nominal, np.random.default_rng(11))
    rng = np.random.default_rng(12)
    postures = random_configurations(nominal, 40, rng)
    return nominal, truth, postures, session(truth, postures, rng, lost=7)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_bag_import_recovers_the_recorded_postures(kind, tmp_path, puma_session):
    nominal, truth, postures, (jt, jq, mt, mp) = puma_session
    path = tmp_path / ("session.bag" if kind == "ros1" else "session")
    write_bag(path, kind, nominal.joint_names, jt, jq, mt, mp)
    s = read_bag_streams(str(path), "/joint_states", point="/tracker/point")
    assert s.joint_names == list(nominal.joint_names)
    found, dropped = find_postures(s, StillOptions())
    assert len(found) == len(postures) - 1                     # posture 7: tracker lost
    assert len(dropped) == 1 and "0 instrument samples" in dropped[0]
    expected = np.delete(postures, 7, axis=0)
    for ps, q in zip(found, expected, strict=True):
        assert np.abs(ps.q - q).max() < 1e-6
        n = ps.n
        assert np.linalg.norm(ps.p - truth.fk(q)[:3, 3]) < 5 * TRACKER_NOISE / math.sqrt(n)
        assert ps.sigma == pytest.approx(TRACKER_NOISE / math.sqrt(n), rel=0.6)


def test_bag_import_command_and_calibration_recovers_the_truth(tmp_path, puma_session, capsys):
    nominal, truth, postures, (jt, jq, mt, mp) = puma_session
    path = tmp_path / "session"
    write_bag(path, "mcap", nominal.joint_names, jt, jq, mt, mp)
    data = tmp_path / "data.csv"
    code, out, err = run(capsys, "import", "bag", path, "-o", data, "--point", "/tracker/point",
                         "--json", tmp_path / "import.json")
    assert code == 0, err
    assert "39 static postures" in out and "dropped" in out
    doc = json.loads((tmp_path / "import.json").read_text())
    assert len(doc["postures"]) == 39 and len(doc["dropped"]) == 1
    # a calibration on the imported file recovers the truth on held-out configurations
    rng = np.random.default_rng(13)
    q_h = random_configurations(nominal, 30, rng)
    hold = tmp_path / "holdout.csv"
    y = truth.fk(q_h)[:, :3, 3]
    lines = ["# kincal measurements: instrument=position; name=bag",
             ",".join([f"{j}_rad" for j in nominal.joint_names] + ["x_mm", "y_mm", "z_mm"])]
    lines += [",".join([repr(float(v)) for v in q] + [f"{v * 1e3:.6f}" for v in p])
              for q, p in zip(q_h, y, strict=True)]
    hold.write_text("\n".join(lines) + "\n")
    code, out, err = run(capsys, "calibrate", "puma560", "--data", data, "--validate", hold,
                         "-o", tmp_path / "cal.yaml", "--json", tmp_path / "r.json")
    assert code == 0, err
    metrics = json.loads((tmp_path / "r.json").read_text())["metrics"]["validation"]
    rms = metrics["after"]["rms_position_m"] if "after" in metrics else metrics["rms_position_m"]
    before = metrics["before"]["rms_position_m"] if "before" in metrics else None
    assert rms < 0.05e-3, metrics
    if before is not None:
        assert before > 20 * rms


def test_tf_transforms_and_ros1(tmp_path, puma_session, capsys):
    nominal, truth, postures, (jt, jq, mt, mp) = puma_session
    path = tmp_path / "mocap.bag"
    write_bag(path, "ros1", nominal.joint_names, jt, jq, mt, mp, as_tf=True)
    code, out, err = run(capsys, "import", "bag", path, "-o", tmp_path / "d.csv", "--tf",
                         "mocap:marker")
    assert code == 0, err
    assert "39 static postures" in out


def test_bag_errors_are_one_line(tmp_path, puma_session, capsys):
    nominal, truth, postures, (jt, jq, mt, mp) = puma_session
    path = tmp_path / "s.bag"
    write_bag(path, "ros1", nominal.joint_names, jt, jq, mt, mp)
    code, out, err = run(capsys, "import", "bag", path, "-o", tmp_path / "d.csv", "--point",
                         "/nope")
    assert code == 2 and "no topic '/nope'" in err and len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "import", "bag", path, "-o", tmp_path / "d.csv", "--point",
                         "/tracker/point", "--still-speed", "0.01")
    assert code == 2 and "--still-speed" in err
    assert not (tmp_path / "d.csv").exists()
