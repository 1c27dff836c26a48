"""A recorded ROS session to a calibration (docs/tutorials/ros-bags.md).

Step 1 records a session as a ROS 2 bag (MCAP storage) with rosbags' writer: a PUMA 560
with known errors visits 40 postures, stopping 2.5 s at each, while /joint_states runs at
100 Hz and a laser tracker publishes the reflector on /tracker/point at 40 Hz, also while
the arm moves, and loses the reflector at one posture. Steps 2 and 3 are what you run
on a real recording: ``kincal import bag`` and ``kincal calibrate``.
"""

from __future__ import annotations

import subprocess

import numpy as np

import kincal


def sh(command: str) -> None:
    """Run a shell command (a kincal command line) and stop on failure."""
    subprocess.run(command, shell=True, check=True)


# --8<-- [start:record]
from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

nominal = kincal.load_robot("puma560")
truth = kincal.perturb_robot(nominal, np.random.default_rng(11))
rng = np.random.default_rng(12)
postures = kincal.random_configurations(nominal, 40, rng)
kincal.write_robot(truth, "truth.yaml")

# the joints move for 1.5 s (cosine blend) and rest 2.5 s at each posture
t_joint, q_joint, t = [], [], 0.0
for k, q in enumerate(postures):
    start = postures[k - 1] if k else q
    for s in np.arange(0.0, 4.0 if k else 2.5, 0.01):
        blend = 0.5 - 0.5 * np.cos(np.pi * min(s / 1.5, 1.0)) if k else 1.0
        t_joint.append(t + s)
        q_joint.append(start + blend * (q - start))
    t += 4.0 if k else 2.5
t_joint, q_joint = np.array(t_joint), np.array(q_joint)
t_track = np.arange(0.0, t, 1 / 40)
q_track = np.array([np.interp(t_track, t_joint, q_joint[:, j]) for j in range(6)]).T
p_track = truth.fk(q_track)[:, :3, 3] + rng.normal(0, 2e-5, (len(t_track), 3))
lost = (t_track > 8.0) & (t_track < 10.5)           # the reflector is lost at posture 3
t_track, p_track = t_track[~lost], p_track[~lost]

store = get_typestore(Stores.ROS2_HUMBLE)
T = store.types


def stamp(seconds: float) -> object:
    return T["builtin_interfaces/msg/Time"](sec=1_700_000_000 + int(seconds),
                                            nanosec=int(seconds % 1 * 1e9))


events = sorted([(s, 0, i) for i, s in enumerate(t_joint)]
                + [(s, 1, i) for i, s in enumerate(t_track)])
with Writer("session", version=9, storage_plugin=StoragePlugin.MCAP) as bag:
    joints = bag.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
    point = bag.add_connection("/tracker/point", "geometry_msgs/msg/PointStamped",
                               typestore=store)
    for s, topic, i in events:
        header = T["std_msgs/msg/Header"](stamp=stamp(s), frame_id="tracker")
        if topic == 0:
            msg = T["sensor_msgs/msg/JointState"](
                header=header, name=list(nominal.joint_names), position=q_joint[i],
                velocity=np.zeros(0), effort=np.zeros(0))
            bag.write(joints, int((1_700_000_000 + s) * 1e9),
                      store.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
        else:
            x, y, z = p_track[i]
            msg = T["geometry_msgs/msg/PointStamped"](
                header=header, point=T["geometry_msgs/msg/Point"](x=x, y=y, z=z))
            bag.write(point, int((1_700_000_000 + s) * 1e9),
                      store.serialize_cdr(msg, "geometry_msgs/msg/PointStamped"))
print(f"session: {len(t_joint)} joint states, {len(t_track)} tracker points, {t:.0f} s")
# --8<-- [end:record]

# --8<-- [start:import]
sh("kincal import bag session -o data.csv --point /tracker/point")
sh("head -n 4 data.csv")
# --8<-- [end:import]

# --8<-- [start:joints]
sh("kincal import bag session -o postures.csv")
sh("head -n 3 postures.csv | cut -c 1-100")
# --8<-- [end:joints]

# --8<-- [start:calibrate]
# the first 29 postures calibrate, the last 10 (never seen by the fit) validate
sh("(head -n 3 data.csv; sed -n '4,32p' data.csv) > train.csv")
sh("(head -n 3 data.csv; tail -n +33 data.csv) > holdout.csv")
sh("kincal calibrate puma560 --data train.csv --validate holdout.csv -o calibrated.yaml "
   "> calibrate.txt")
sh("grep -A 5 'Errors before' calibrate.txt; grep -A 7 'Held-out files' calibrate.txt")
# --8<-- [end:calibrate]
