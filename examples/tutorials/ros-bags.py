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


def write(bag: Writer, connection: object, seconds: float, kind: str, frame: str,
          **fields: object) -> None:
    """One message of type ``kind``, stamped ``seconds`` into the session."""
    header = T["std_msgs/msg/Header"](stamp=stamp(seconds), frame_id=frame)
    bag.write(connection, int((1_700_000_000 + seconds) * 1e9),
              store.serialize_cdr(T[kind](header=header, **fields), kind))


events = sorted([(s, 0, i) for i, s in enumerate(t_joint)]
                + [(s, 1, i) for i, s in enumerate(t_track)])
with Writer("session", version=9, storage_plugin=StoragePlugin.MCAP) as bag:
    joints = bag.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
    point = bag.add_connection("/tracker/point", "geometry_msgs/msg/PointStamped",
                               typestore=store)
    for s, topic, i in events:
        if topic == 0:
            write(bag, joints, s, "sensor_msgs/msg/JointState", "tracker",
                  name=list(nominal.joint_names), position=q_joint[i],
                  velocity=np.zeros(0), effort=np.zeros(0))
        else:
            x, y, z = p_track[i]
            write(bag, point, s, "geometry_msgs/msg/PointStamped", "tracker",
                  point=T["geometry_msgs/msg/Point"](x=x, y=y, z=z))
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

# --8<-- [start:images-record]
# A Panda with a hand camera (640 x 480, fx = fy = 500 px) stops at 6 postures and the
# camera publishes one image at each (sensor_msgs/Image, mono8), plus one while the arm
# moves; the images are the ChArUco board rendered by a perspective warp.
import cv2  # noqa: E402

panda = kincal.load_robot("panda")
with open("board.yaml", "w") as f:
    f.write("type: charuco\nsquares: [5, 7]\nsquare: 34 mm\nmarker: 28 mm\n"
            "dictionary: DICT_6X6_250\n")
with open("camera_info.yaml", "w") as f:        # as ROS's camera_calibration writes it
    f.write("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: "
            "[500, 0, 320, 0, 500, 240, 0, 0, 1]}\ndistortion_model: plumb_bob\n"
            "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n")
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
flat = np.pad(cv2.aruco.CharucoBoard((5, 7), 0.034, 0.028, cv2.aruco.getPredefinedDictionary(
    cv2.aruco.DICT_6X6_250)).generateImage((500, 700)), 20, constant_values=255)
to_flat = np.array([[100 / 0.034, 0, 19.5], [0, 100 / 0.034, 19.5], [0, 0, 1]])
home = np.array([-0.22, -0.19, 0.0, -2.42, 0.28, 2.15, 0.31])
camera = np.eye(4)
camera[:3, 3] = [0.04, -0.03, 0.065]                  # the camera on the flange
board = panda.fk(home) @ camera                       # the board 0.42 m before the camera
board[:3, 3] += board[:3, :3] @ [-0.085, -0.12, 0.42]
stops = home + np.random.default_rng(4).uniform(-0.15, 0.15, (6, 7))


def picture(q: np.ndarray) -> np.ndarray:
    seen = np.linalg.inv(panda.fk(q) @ camera) @ board          # the board in the camera
    H = K @ seen[:3][:, [0, 1, 3]] @ np.linalg.inv(to_flat)
    return cv2.warpPerspective(flat, H, (640, 480), borderValue=255)


t_joint, q_joint, shots, t = [], [], [], 0.0
for k, q in enumerate(stops):                       # 1 s moves, 1 s stops, 50 Hz
    start = stops[k - 1] if k else q
    for s in np.arange(0.0, 2.0 if k else 1.0, 0.02):
        blend = 0.5 - 0.5 * np.cos(np.pi * min(s, 1.0)) if k else 1.0
        t_joint.append(t + s)
        q_joint.append(start + blend * (q - start))
    shots.append((t + (1.5 if k else 0.5), q))       # mid-stop
    if k == 3:
        shots.append((t + 0.5, start + 0.5 * (q - start)))        # mid-move
    t += 2.0 if k else 1.0
events = sorted([(s, 0, i) for i, s in enumerate(t_joint)]
                + [(s, 1, i) for i, (s, _) in enumerate(shots)])
with Writer("images_session", version=9, storage_plugin=StoragePlugin.MCAP) as bag:
    joints = bag.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
    image = bag.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=store)
    for s, topic, i in events:
        if topic == 0:
            write(bag, joints, s, "sensor_msgs/msg/JointState", "camera",
                  name=list(panda.joint_names), position=q_joint[i],
                  velocity=np.zeros(0), effort=np.zeros(0))
        else:
            write(bag, image, s, "sensor_msgs/msg/Image", "camera", height=480, width=640,
                  encoding="mono8", is_bigendian=0, step=640,
                  data=picture(shots[i][1]).reshape(-1))
print(f"images_session: {len(t_joint)} joint states, {len(shots)} images, {t:.0f} s")
# --8<-- [end:images-record]

# --8<-- [start:images-import]
sh("kincal import images images_session --board board.yaml --image-topic /camera/image_raw "
   "--intrinsics camera_info.yaml --robot panda -o camera.csv")
sh("grep -v '^#' camera.csv | head -n 2 | cut -c 1-100")
# --8<-- [end:images-import]
