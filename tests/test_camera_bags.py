"""ROS bags of board images in: real bags written with rosbags' own writer (ROS 1 with raw
images in four encodings, ROS 2 MCAP with PNG and JPEG CompressedImage and joint
velocities) from a
simulated Panda with a hand camera: standstills with an image each, an image while the
arm moves, one where the joint states have a hole, one after they end.  The imported rows
are checked against the known postures and the board corners' true pixels, the drops
against their causes, and the refusals (damaged bag, wrong topic, unknown encoding)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, matrix_from_frame

pytest.importorskip("rosbags", reason="the 'ros' extra (rosbags) is not installed")
cv2 = pytest.importorskip("cv2")
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from test_camera_fisheye import BOARD, _render  # noqa: E402

W, H = 640, 480
K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
Q0 = np.array([-0.22, -0.19, 0.0, -2.42, 0.28, 2.15, 0.31])
X_HAND = matrix_from_frame([0.040, -0.030, 0.065, 0.80, 0.01, -0.05])
RATE, STILL, MOVE = 50.0, 1.0, 1.0                 # joint states [Hz], [s], [s]
T0 = 1_700_000_000
ENCODINGS = ["mono8", "bgr8", "rgb8", "mono16"]


def _pixels(B: np.ndarray) -> np.ndarray:
    x = BOARD.corner_points(np.arange(BOARD.num_corners)) @ B[:3, :3].T + B[:3, 3]
    return x[:, :2] / x[:, 2:] * K[[0, 1], [0, 1]] + K[:2, 2]


def _rays(dist: np.ndarray | None) -> np.ndarray:
    """Each pixel's ray on z = 1 through the pinhole ``K``, or through ``K`` with the
    radial-tangential ``dist`` (OpenCV's undistortPoints of every pixel)."""
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    uv = np.column_stack([u.ravel(), v.ravel()])
    xy = ((uv - K[:2, 2]) / K[[0, 1], [0, 1]] if dist is None else
          cv2.undistortPoints(uv.reshape(-1, 1, 2), K, dist).reshape(-1, 2))
    return np.column_stack([xy, np.ones(W * H)])


@pytest.fixture(scope="module")
def session():
    """Postures, joint states (t, q, qdot) and the images ``(t, grey, label)``: one in
    each standstill, one mid-move, one in a hole of the joint states, one after them."""
    return _session(None)


def _session(dist: np.ndarray | None, n: int = 5, spread: float = 0.25):
    """:func:`session`, the images rendered through the lens distortion ``dist``; ``n``
    postures within ``spread`` [rad] of ``Q0`` on every joint."""
    robot = load_serial_robot("panda")
    rng = np.random.default_rng(4)
    Z = robot.fk(Q0) @ X_HAND @ matrix_from_frame([-0.085, -0.12, 0.42, 0.2, 0.1, -0.1])

    def view(q: np.ndarray) -> np.ndarray:
        return inverse(X_HAND) @ inverse(robot.fk(q)) @ Z

    postures: list[np.ndarray] = []
    while len(postures) < n:
        q = Q0 + rng.uniform(-spread, spread, 7)
        uv = _pixels(view(q))
        if uv.min() > 40 and uv[:, 0].max() < W - 40 and uv[:, 1].max() < H - 40:
            postures.append(q)
    ts, qs, vs, shots = [], [], [], []
    t = 0.0
    for k, q in enumerate(postures):
        if k:
            for s in np.arange(0.0, MOVE, 1 / RATE):
                a = 0.5 - 0.5 * math.cos(math.pi * s / MOVE)
                ts.append(t + s)
                qs.append(postures[k - 1] + a * (q - postures[k - 1]))
                vs.append(0.5 * math.pi / MOVE * math.sin(math.pi * s / MOVE)
                          * (q - postures[k - 1]))
            shots.append((t + 0.5 * MOVE + 0.003, "moving", k))
            t += MOVE
        for s in np.arange(0.0, STILL, 1 / RATE):
            ts.append(t + s)
            qs.append(q.copy())
            vs.append(np.zeros(7))
        shots.append((t + 0.5 * STILL + 0.0037, "still", k))
        t += STILL
    jt, jq, jv = np.array(ts), np.array(qs), np.array(vs)
    hole = shots[-1][0]                             # no joint states within 60 ms of it
    keep = np.abs(jt - hole) > 0.06
    jt, jq, jv = jt[keep], jq[keep], jv[keep]
    shots[-1] = (hole, "hole", len(postures) - 1)
    shots.append((jt[-1] + 0.5, "after", len(postures) - 1))
    images = []
    rays = _rays(dist)
    for t_img, what, k in shots:
        q = postures[k] if what != "moving" else np.array(
            [np.interp(t_img, jt, jq[:, j]) for j in range(7)])
        images.append((t_img, _render(cv2, view(q), rays, rng).reshape(H, W), what, q))
    truth = {k: (postures[k], _pixels(view(postures[k]))) for k in range(len(postures))}
    return robot, jt, jq, jv, images, truth


def _header(ts, kind: str, t: float):
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=T0 + int(t), nanosec=int(round((t % 1) * 1e9)))
    kw = {"seq": 0} if kind == "ros1" else {}
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id="camera", **kw)


def write_image_bag(path: Path, kind: str, session, encodings=None, info=None) -> None:
    """ROS 1: /joint_states without velocities, raw Image in the four encodings in turn
    (or ``encodings``); ROS 2 MCAP: joint velocities, PNG and JPEG CompressedImage.  The joint
    states name one more joint (a gripper finger) than the arm has.  ``info``: a
    ``(K 3x3, D, distortion_model)`` per image, written as CameraInfo on
    /camera/camera_info just before it."""
    robot, jt, jq, jv, images, _ = session
    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    T = ts.types
    js, img_t = "sensor_msgs/msg/JointState", ("sensor_msgs/msg/Image" if kind == "ros1"
                                               else "sensor_msgs/msg/CompressedImage")
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer, ser = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP), ts.serialize_cdr
    names = [*robot.joint_names, "finger_joint"]
    events = sorted([(t, 0, i) for i, t in enumerate(jt)]
                    + [(im[0], 1, i) for i, im in enumerate(images)])
    encodings = encodings or ENCODINGS
    with writer:
        cj = writer.add_connection("/joint_states", js, typestore=ts)
        ci = writer.add_connection("/camera/image", img_t, typestore=ts)
        cc = (writer.add_connection("/camera/camera_info", "sensor_msgs/msg/CameraInfo",
                                    typestore=ts) if info else None)
        for t, which, i in events:
            ns = T0 * 1_000_000_000 + int(round(t * 1e9))
            if which == 0:
                vel = np.r_[jv[i], 0.0] if kind != "ros1" else np.zeros(0)
                msg = T[js](header=_header(ts, kind, t), name=names,
                            position=np.r_[jq[i], 0.02], velocity=vel, effort=np.zeros(0))
                writer.write(cj, ns, ser(msg, js))
                continue
            grey = images[i][1]
            if info:
                writer.write(cc, ns - 1000, ser(_camera_info(ts, kind, t, *info[i]),
                                                "sensor_msgs/msg/CameraInfo"))
            if kind != "ros1":                        # PNG and JPEG (quality 95) in turn
                fmt = ("png", "jpeg")[i % 2]
                data = cv2.imencode(".png" if fmt == "png" else ".jpg", grey,
                                    [] if fmt == "png" else [cv2.IMWRITE_JPEG_QUALITY, 95])[1]
                msg = T[img_t](header=_header(ts, kind, t), format=fmt, data=data.reshape(-1))
            else:
                enc = encodings[i % len(encodings)]
                pix = {"mono8": grey, "mono16": grey.astype(np.uint16) * 257,
                       "bgr8": np.dstack([grey] * 3), "rgb8": np.dstack([grey] * 3)}.get(
                    enc, grey)
                data = np.frombuffer(pix.astype(pix.dtype.newbyteorder("<")).tobytes(),
                                     dtype=np.uint8)
                msg = T[img_t](header=_header(ts, kind, t), height=H, width=W, encoding=enc,
                               is_bigendian=0, step=data.size // H, data=data)
            writer.write(ci, ns, ser(msg, img_t))


def _camera_info(ts, kind: str, t: float, Km: np.ndarray, D: np.ndarray, model: str):
    """A sensor_msgs/CameraInfo (ROS 1 spells its arrays K, D, R, P; ROS 2 k, d, r, p)."""
    T = ts.types
    P = np.hstack([Km, np.zeros((3, 1))])
    arrays = dict(zip("dkrp" if kind != "ros1" else "DKRP",
                      [np.asarray(D, float), Km.ravel(), np.eye(3).ravel(), P.ravel()],
                      strict=True))
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                do_rectify=False)
    return T["sensor_msgs/msg/CameraInfo"](header=_header(ts, kind, t), height=H, width=W,
                                           distortion_model=model, binning_x=0, binning_y=0,
                                           roi=roi, **arrays)


def _files(tmp_path: Path) -> tuple[Path, Path]:
    board = tmp_path / "board.yaml"
    board.write_text("type: charuco\nsquares: [5, 7]\nsquare: 34 mm\nmarker: 28 mm\n"
                     "dictionary: DICT_6X6_250\n")
    cam = tmp_path / "camera_info.yaml"
    cam.write_text("camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, "
                   "1]}\ndistortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, "
                   "cols: 5, data: [0, 0, 0, 0, 0]}\n")
    return board, cam


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_image_bag_rows_are_the_known_postures_and_corners(kind, tmp_path, capsys,
                                                           session) -> None:
    robot, jt, jq, jv, images, truth = session
    bag = tmp_path / ("cal.bag" if kind == "ros1" else "cal")
    write_image_bag(bag, kind, session)
    board, cam = _files(tmp_path)
    code, out, err = run(capsys, "import", "images", bag, "--board", board, "--image-topic",
                         "/camera/image", "--intrinsics", cam, "--robot", "panda",
                         "-o", tmp_path / "m.csv", "--json", tmp_path / "m.json")
    assert code == 0, err
    doc = json.loads((tmp_path / "m.json").read_text())
    why = {d["image"].split("@")[0]: d["reason"] for d in doc["dropped"]}
    kinds = [im[2] for im in images]
    for k, what in enumerate(kinds):
        label = f"{k:04d}"
        if what == "still":
            assert label not in why, why
        else:
            expect = {"moving": "robot moving", "hole": "no joint states within 20 ms",
                      "after": "none after"}[what]
            assert expect in why[label], (what, why[label])
    assert len(doc["images"]) == kinds.count("still") == 4
    rows = [r for r in csv.DictReader(line for line in (tmp_path / "m.csv").read_text()
                                      .splitlines() if not line.startswith("#"))]
    names = [n for n in rows[0] if n.endswith("_rad")]
    assert len(names) == 7                                 # the finger joint left out
    still = [im for im in images if im[2] == "still"]
    for (t_img, _, _, q), label in zip(still, sorted({r["image"] for r in rows}), strict=True):
        mine = [r for r in rows if r["image"] == label]
        assert abs(float(label.split("@")[1]) - (T0 + t_img)) < 1e-3
        assert np.abs(np.array([float(mine[0][n]) for n in names]) - q).max() < 1e-12
        k = [j for j, (p, _) in truth.items() if np.array_equal(p, q)][0]
        uv = np.array([[float(r["u_px"]), float(r["v_px"])] for r in mine])
        ids = np.array([int(r["corner"]) for r in mine])
        err_px = np.linalg.norm(uv - truth[k][1][ids], axis=1)
        assert len(ids) >= 16 and np.sqrt(np.mean(err_px**2)) < 0.15 and err_px.max() < 0.3


def test_image_bag_refusals(tmp_path, capsys, session) -> None:
    """One line, exit 2: a damaged bag, a topic it does not have, a topic of another type,
    an encoding kincal does not read; without --image-topic the bag is named."""
    board, cam = _files(tmp_path)
    bag = tmp_path / "cal.bag"
    write_image_bag(bag, "ros1", session, encodings=["mono8", "bayer_rggb8"])
    base = ["import", "images", bag, "--board", board, "--intrinsics", cam, "-o",
            tmp_path / "m.csv"]
    for extra, match in [(["--image-topic", "/camera/nope"], "no topic '/camera/nope'"),
                         (["--image-topic", "/joint_states"], "expected sensor_msgs/msg/Image"),
                         (["--image-topic", "/camera/image"], "encoding 'bayer_rggb8'"),
                         ([], "give the images' topic with --image-topic")]:
        code, out, err = run(capsys, *base, *extra)
        assert code == 2 and err.count("\n") == 1 and match in err, err
        assert str(bag) in err or "--image-topic" in err
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 2])
    code, out, err = run(capsys, *base, "--image-topic", "/camera/image")
    assert code == 2 and err.count("\n") == 1 and "ROS bag" in err, err
    assert not (tmp_path / "m.csv").exists()


def test_joints_at_interpolates_and_checks_gap_and_speed() -> None:
    """Linear interpolation between the neighbours; an exact stamp takes its sample; a
    recorded velocity alone (positions still) marks the robot moving."""
    from kincal.measure.camera_bags import ImageBagOptions, joints_at

    jt = np.array([0.0, 0.01, 0.02, 0.05])
    jq = np.array([[0.0, 1.0], [0.0, 1.0], [0.0002, 1.0], [0.0002, 1.0]])
    opt = ImageBagOptions(max_gap=0.02, max_speed=0.01)
    q, why = joints_at(0.015, jt, jq, opt)
    assert why is not None and "robot moving (0.02 " in why     # 2e-4 rad in 10 ms
    q, why = joints_at(0.015, jt, jq, ImageBagOptions(0.02, 0.05))
    assert why is None and np.allclose(q, [0.0001, 1.0])
    q, why = joints_at(0.01, jt, jq, ImageBagOptions(0.02, 0.05))
    assert why is None and np.array_equal(q, jq[1])
    q, why = joints_at(0.045, jt, jq, opt)
    assert why is not None and "before 25 ms, after 5 ms" in why
    q, why = joints_at(0.06, jt, jq, opt)
    assert why is not None and "none after" in why
    jv = np.zeros((4, 2))
    jv[:, 1] = 0.5
    q, why = joints_at(0.035, jt, jq, ImageBagOptions(0.02, 0.01), jv)
    assert why is not None and "robot moving (0.5 " in why


#: A radial-tangential lens (k1 k2 p1 p2 k3) the distorted images are rendered through.
DIST = np.array([-0.12, 0.09, 0.0012, -0.0008, -0.02])


@pytest.fixture(scope="module")
def distorted():
    return _session(DIST)


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_image_bag_camera_info_gives_the_intrinsics(kind, tmp_path, capsys, distorted) -> None:
    """Images rendered through a distorting lens, its K and D in the bag's CameraInfo (no
    --intrinsics): the file carries them, and the corners undistorted with them are the
    pinhole projections of the board (as in the undistorted bag above)."""
    images, truth = distorted[4], distorted[5]
    bag = tmp_path / ("cal.bag" if kind == "ros1" else "cal")
    write_image_bag(bag, kind, distorted, info=[(K, DIST, "plumb_bob")] * len(images))
    board, _ = _files(tmp_path)
    code, out, err = run(capsys, "import", "images", bag, "--board", board, "--image-topic",
                         "/camera/image", "-o", tmp_path / "m.csv", "--json", tmp_path / "m.json")
    assert code == 0, err
    assert f"intrinsics from the bag's /camera/camera_info ({len(images)} messages)" in out
    doc = json.loads((tmp_path / "m.json").read_text())["intrinsics"]
    assert [doc[k] for k in ("fx", "fy", "cx", "cy")] == [500.0, 500.0, 320.0, 240.0]
    assert doc["dist"] == DIST.tolist() and doc["distortion_model"] == "plumb_bob"
    rows = [r for r in csv.DictReader(line for line in (tmp_path / "m.csv").read_text()
                                      .splitlines() if not line.startswith("#"))]
    assert {float(r["fx_px"]) for r in rows} == {500.0}
    still = [im for im in images if im[2] == "still"]
    for (_, _, _, q), label in zip(still, sorted({r["image"] for r in rows}), strict=True):
        mine = [r for r in rows if r["image"] == label]
        k = [j for j, (p, _) in truth.items() if np.array_equal(p, q)][0]
        uv = np.array([[float(r["u_px"]), float(r["v_px"])] for r in mine])
        err_px = np.linalg.norm(uv - truth[k][1][[int(r["corner"]) for r in mine]], axis=1)
        assert np.sqrt(np.mean(err_px**2)) < 0.15 and err_px.max() < 0.3, err_px


def test_image_bag_camera_info_refusals(tmp_path, capsys, distorted) -> None:
    """CameraInfo messages that disagree (another K in one of them), a --camera-info-topic
    the bag does not have: one line naming the topic, exit 2, no file written."""
    board, cam = _files(tmp_path)
    n = len(distorted[4])
    K2 = K.copy()
    K2[0, 0] = 510.0
    bag = tmp_path / "cal.bag"
    write_image_bag(bag, "ros1", distorted, info=[(K, DIST, "plumb_bob")] * (n - 1)
                    + [(K2, DIST, "plumb_bob")])
    base = ["import", "images", bag, "--board", board, "--image-topic", "/camera/image",
            "-o", tmp_path / "m.csv"]
    for extra, match in [([], f"camera info topic /camera/camera_info: message {n - 1} has "
                              "another K than message 0 (510 0 320"),
                         (["--camera-info-topic", "/cam/info"], "no topic '/cam/info'")]:
        code, out, err = run(capsys, *base, *extra)
        assert code == 2 and err.count("\n") == 1 and match in err and str(bag) in err, err
        assert not (tmp_path / "m.csv").exists()
    code, out, err = run(capsys, *base, "--intrinsics", cam)         # given: the topic unread
    assert code == 0 and "distortion 0 0 0 0 0 removed" in out, err


@pytest.fixture(scope="module")
def wide():
    """12 postures turning the flange up to 0.45 rad per joint: a hand-eye can be seen."""
    return _session(None, 12, 0.45)


def test_hand_eye_straight_from_a_bag(tmp_path, capsys, wide) -> None:
    """``hand-eye panda --images BAG``: the joint values and the intrinsics (CameraInfo)
    from the bag, the images taken at a standstill; the hand-eye within 3 stated expected
    errors of the simulated one; --joints with a bag refused in one line."""
    images = wide[4]
    bag = tmp_path / "cal"
    write_image_bag(bag, "ros2", wide, info=[(K, np.zeros(5), "plumb_bob")] * len(images))
    board, _ = _files(tmp_path)
    base = ["hand-eye", "panda", "--images", bag, "--board", board, "--image-topic",
            "/camera/image"]
    code, out, err = run(capsys, *base, "--lens", "none", "--json", tmp_path / "h.json")
    assert code == 0, err
    assert "intrinsics from the bag's /camera/camera_info" in out, out
    assert f"{[im[2] for im in images].count('still')} images with the board" in out, out
    fit = json.loads((tmp_path / "h.json").read_text())
    X = np.array(fit["camera"]["matrix"])
    e = fit["expected_error"]
    assert np.linalg.norm(X[:3, 3] - X_HAND[:3, 3]) < 3 * e["position_m"], (X, e)
    R = X[:3, :3].T @ X_HAND[:3, :3]
    assert math.acos(min(1.0, (np.trace(R) - 1) / 2)) < 3 * e["rotation_rad"], e
    (tmp_path / "j.csv").write_text("image,q1_rad\n")
    code, out, err = run(capsys, *base, "--joints", tmp_path / "j.csv")
    assert code == 2 and err.count("\n") == 1 and "joint values come from the bag" in err, err
