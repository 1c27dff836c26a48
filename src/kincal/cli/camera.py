"""Camera commands: board images in, a hand-eye with its quality out.

* ``kincal import images FOLDER --board board.yaml [--joints joints.csv] -o data.csv``:
  detect the board in every image, write the hand-camera measurement file
  (:mod:`kincal.measure.camera_images`; needs ``kincal[camera]``);
* ``kincal hand-eye ROBOT --data DATA``: closed-form start, joint fit, expected error,
  held-out images (:mod:`kincal.identify.hand_eye_fit`; plain NumPy).
* ``kincal hand-eye [ROBOT] --images FOLDER --board board.yaml [--joints J | --poses DIR]
  [--mount hand|fixed]``: the same from the images, the intrinsics and distortion in the
  fit (:mod:`kincal.identify.hand_eye_lens`; needs ``kincal[camera]``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import JsonOpt, load, out_console, serial
from kincal.cli.camera_outputs import (
    CameraInfoOpt,
    ChildFrameOpt,
    HandEyeFiles,
    ParentFrameOpt,
    ReportOpt,
    RosLaunchOpt,
    RosYamlOpt,
    UrdfJointOpt,
)
from kincal.cli.importers import import_app
from kincal.errors import KincalError

if TYPE_CHECKING:
    from kincal.cli.camera_bags import BagTopics


#: A ROS bag's sensor_msgs/JointState topic (import images, hand-eye).
JointTopicOpt = Annotated[str, typer.Option("--joint-topic", help="ROS bag: the "
                                            "sensor_msgs/JointState topic.")]
#: A ROS bag's sensor_msgs/CameraInfo topic (import images, hand-eye).
CameraInfoTopicOpt = Annotated[str | None, typer.Option(
    "--camera-info-topic", help="ROS bag: the sensor_msgs/CameraInfo topic (default: the "
    "image topic's sibling camera_info).")]


def _quality(fit: Any) -> dict[str, Any]:
    """The quality part of a hand-eye JSON, the same for every mount: expected error
    (covariance and unmodelled floor, m / rad) and reprojection RMS (px, and m at the
    board)."""
    return {"expected_error": {"position_m": fit.expected_position,
                               "rotation_rad": fit.expected_rotation,
                               "covariance_position_m": fit.std_position,
                               "covariance_rotation_rad": fit.std_rotation,
                               "floor_position_m": fit.floor_position,
                               "floor_rotation_rad": fit.floor_rotation},
            "reprojection_rms_px": {"training": fit.train_rms_px,
                                    "held_out": fit.held_rms_px},
            "held_out_3d_rms_m": fit.held_rms_3d, "held_out_per_image_px": fit.held_per_image}


@import_app.command("images")
def import_images(
    folder: Annotated[str, typer.Argument(help="Folder of board images, or of pose folders "
                                          "each with image.png and data.json, or a ROS bag "
                                          "(with --image-topic).")],
    board: Annotated[str, typer.Option("--board", help="Board description YAML (type, "
                                       "squares, square, marker, dictionary).")],
    output: Annotated[str, typer.Option("-o", "--output", help="kincal measurement CSV to "
                                        "write.")],
    joints: Annotated[str | None, typer.Option("--joints", help="CSV: image, then joint "
                                               "columns with units (q1_rad ...).")] = None,
    intrinsics: Annotated[str | None, typer.Option("--intrinsics", help="ROS camera_info "
                                                   "or OpenCV YAML (default: the pose "
                                                   "folders' data.json, else estimated).")
                          ] = None,
    min_corners: Annotated[int, typer.Option("--min-corners", min=4, help="Drop an image "
                                             "with fewer corners.")] = 6,
    sigma: Annotated[str, typer.Option("--sigma", help="Stated corner standard deviation "
                                       "(e.g. 0.5px).")] = "0.5px",
    robot: Annotated[str | None, typer.Option("--robot", help="Robot whose joint names head "
                                              "the joint columns.")] = None,
    min_sharpness: Annotated[float, typer.Option("--min-sharpness", min=0.0, help="Drop an "
                                                 "image whose board is less sharp (variance "
                                                 "of the Laplacian x corner spacing / "
                                                 "contrast^2, px^-3).")] = 0.15,
    max_tilt: Annotated[str, typer.Option("--max-tilt", help="Drop an image whose board is "
                                          "tilted more from the viewing ray.")] = "60deg",
    image_topic: Annotated[str | None, typer.Option("--image-topic", help="ROS bag: the "
                                                    "sensor_msgs/Image or CompressedImage "
                                                    "topic.")] = None,
    joint_topic: JointTopicOpt = "/joint_states",
    max_gap: Annotated[str, typer.Option("--max-gap", help="ROS bag: drop an image without "
                                         "joint states this near on both sides.")] = "20ms",
    max_speed: Annotated[str, typer.Option("--max-speed", help="ROS bag: drop an image taken "
                                           "while a joint moves faster.")] = "0.01rad/s",
    camera_info_topic: CameraInfoTopicOpt = None,
    json_out: JsonOpt = None,
) -> None:
    """Detect a calibration board in every image and write a camera measurement file
    (undistorted pixels, joint values, corner ids, the image of every corner)."""
    import numpy as np

    from kincal.cli.camera_bags import bag_images, is_bag
    from kincal.io import check_outputs, write_json
    from kincal.measure.camera_board import read_board
    from kincal.measure.camera_images import (
        detect_images,
        drop_oblique,
        estimate_intrinsics,
        read_intrinsics,
        read_joints_csv,
        require_opencv,
        write_image_measurements,
    )
    from kincal.units import parse_quantity

    out = out_console(json_out)
    check_outputs({"-o": output, "--json": json_out},
                  {"--board": [board], "--joints": joints, "--intrinsics": intrinsics})
    require_opencv()
    b = read_board(board)
    r = serial(load(robot), "import images") if robot else None
    table = read_joints_csv(joints) if joints else None
    given = read_intrinsics(intrinsics) if intrinsics else None
    tilt = float(np.degrees(parse_quantity(max_tilt, "angle", "--max-tilt", minimum=0.0)))
    if intrinsics and camera_info_topic:
        raise KincalError("--intrinsics and --camera-info-topic: give one of them")
    if image_topic is not None or (joints is None and is_bag(folder)):
        images = bag_images(folder, b, image_topic, joint_topic, max_gap, max_speed, r,
                            joints, min_corners, min_sharpness,
                            "" if intrinsics else camera_info_topic)
    else:
        images = detect_images(folder, b, table, min_corners, min_sharpness=min_sharpness)
    intr = given or images.intrinsics or estimate_intrinsics(images, b)
    images = drop_oblique(images, b, intr, tilt)
    block = write_image_measurements(output, images, b, intr,
                                     parse_quantity(sigma, "pixel", "--sigma", positive=True),
                                     r)
    out.print(f"{escape(Path(folder).name)}: {len(images.detections)} images with the "
              f"board, {block.q.shape[0]} corners; {len(images.dropped)} dropped")
    for name, reason in images.dropped:
        out.print(f"[yellow]dropped[/yellow] {escape(name)}: {escape(reason)}")
    out.print(f"intrinsics {escape(intr.source)}: fx {intr.fx:.1f} fy {intr.fy:.1f} cx "
              f"{intr.cx:.1f} cy {intr.cy:.1f} px; distortion "
              f"{' '.join(f'{v:.4g}' for v in intr.dist)} removed")
    out.print(f"measurements -> {escape(output)}")
    if json_out:
        write_json(json_out, {
            "folder": folder, "output": output, "board": b.__dict__,
            "intrinsics": {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy,
                           "dist": list(intr.dist), "source": intr.source,
                           "distortion_model": intr.model},
            "images": [{"image": d.image, "corners": len(d.ids)} for d in images.detections],
            "dropped": [{"image": i, "reason": why} for i, why in images.dropped]})


def _fit_json(fit: Any, data: str) -> dict[str, Any]:
    import numpy as np

    from kincal.spatial import frame_from_matrix

    return {"data": data, "training": fit.training, "held_out": fit.held_out,
            "camera_in_tool_frame": {"matrix": fit.X.tolist(),
                                     "frame_m_rad": frame_from_matrix(fit.X).tolist()},
            "closed_form_start": fit.start.X.tolist(), "board_in_base": fit.board.tolist(),
            **_quality(fit),
            "flange_rotation_deg": np.asarray(fit.rotation_deg).tolist(),
            "sigma0": fit.result.sigma0, "estimated": fit.result.estimated}


@app.command("hand-eye")
def hand_eye_command(
    robot: Annotated[str | None, typer.Argument(help="The nominal robot (built-in name or "
                                                "robot file); its tool frame is the "
                                                "camera's flange. Not with --poses.")] = None,
    data: Annotated[str | None, typer.Option("--data", "-d", help="Camera measurement CSV "
                                             "from `kincal import images` (mount=hand).")
                    ] = None,
    images: Annotated[str | None, typer.Option("--images", help="Folder of board images "
                                               "(or pose folders): hand-eye and intrinsics "
                                               "in one fit from the raw pixels.")] = None,
    board: Annotated[str | None, typer.Option("--board", help="Board YAML (with --images)."
                                              )] = None,
    joints: Annotated[str | None, typer.Option("--joints", help="Joint values per image "
                                               "(with --images and ROBOT).")] = None,
    poses: Annotated[str | None, typer.Option("--poses", help="Folder of flange poses "
                                              "NAME.yaml (x y z m, qx qy qz qw) matching the "
                                              "images: no robot needed.")] = None,
    intrinsics: Annotated[str | None, typer.Option("--intrinsics", help="Start intrinsics "
                                                   "(default: the pose folders', else "
                                                   "OpenCV's calibrateCamera).")] = None,
    mount: Annotated[str, typer.Option("--mount", help="hand: camera on the flange; fixed: "
                                       "camera fixed, board on the flange (with --images)."
                                       )] = "hand",
    lens: Annotated[str, typer.Option("--lens", help="Intrinsics fitted with --images: all "
                                      "(fx fy cx cy k1 k2 p1 p2 k3), pinhole (fx fy cx cy), "
                                      "none, fisheye (fx fy cx cy k1 k2 k3 k4).")] = "all",
    holdout: Annotated[float, typer.Option("--holdout", help="Fraction of the images kept "
                                           "aside to check the fit.")] = 0.25,
    free: Annotated[list[str] | None, typer.Option("--free", help="Robot parameters (names "
                                                   "or patterns) fitted with the hand-eye.")
                    ] = None,
    min_rotation: Annotated[str, typer.Option("--min-rotation", help="Refuse when the "
                                              "flange turns less about two axes.")] = "5deg",
    output: Annotated[str | None, typer.Option("-o", "--output", help="Write the calibrated "
                                               "robot, the camera as its tool frame.")] = None,
    loo: Annotated[bool, typer.Option("--leave-one-out", help="Also fit once per image with "
                                      "that image held out: its error, and the spread of the "
                                      "hand-eye (jackknife).")] = False,
    ros_yaml: RosYamlOpt = None, ros_launch: RosLaunchOpt = None,
    urdf_joint: UrdfJointOpt = None, camera_info: CameraInfoOpt = None,
    report: ReportOpt = None, parent_frame: ParentFrameOpt = None,
    child_frame: ChildFrameOpt = "camera_optical_frame",
    image_topic: Annotated[str | None, typer.Option("--image-topic", help="--images is a ROS "
                                                    "bag: its Image or CompressedImage "
                                                    "topic (joint values from the bag).")
                           ] = None,
    joint_topic: JointTopicOpt = "/joint_states",
    camera_info_topic: CameraInfoTopicOpt = None,
    json_out: JsonOpt = None,
) -> None:
    """Hand-eye of a camera on the flange (--data), or from the images (--images, camera on
    the flange or fixed): order-free closed-form start, joint fit of the reprojection
    errors (with the intrinsics and distortion from --images), expected error with the
    unmodelled floor, held-out images; the hand-eye for ROS (--ros-yaml, --ros-launch,
    --urdf-joint), the intrinsics as camera_info and a page of pictures (--report)."""
    import numpy as np

    from kincal.identify.hand_eye_fit import fit_hand_camera
    from kincal.io import atomic_write_text, check_outputs, write_json
    from kincal.measure.camera_images import read_image_labels
    from kincal.measure.instruments.camera import HandCameraMeasurement, read_camera
    from kincal.robots.files import robot_yaml_text
    from kincal.units import parse_quantity

    out = out_console(json_out)
    files = HandEyeFiles(ros_yaml, ros_launch, urdf_joint, camera_info, report, parent_frame,
                         child_frame)
    if images is not None or data is None:
        from kincal.cli.camera_bags import BagTopics

        _hand_eye_images(out, robot, images, board, joints, poses, intrinsics, mount, lens,
                         holdout, free, min_rotation, loo, output, json_out, data, files,
                         BagTopics(image_topic, joint_topic, camera_info_topic))
        return
    if image_topic is not None:
        raise KincalError("--image-topic: the bag is given with --images BAG, not --data")
    if mount != "hand":
        raise KincalError("--mount fixed: give the images (--images FOLDER --board ...); "
                          "the measurement file is for a camera on the hand")
    if robot is None:
        raise KincalError("ROBOT: the robot the camera is on is missing")
    files.check("hand", images=False)
    check_outputs({"-o": output, "--json": json_out, **files.outputs()},
                  {"--data": [data], "ROBOT": [robot]})
    r = serial(load(robot), "hand-eye")
    blocks = read_camera(data, r)
    if not isinstance(blocks[0], HandCameraMeasurement):
        raise KincalError("not a hand-camera file (mount=hand); `kincal import images` "
                          "writes one", source=data)
    min_deg = float(np.degrees(parse_quantity(min_rotation, "angle", "--min-rotation",
                                              minimum=0.0)))
    fit = fit_hand_camera(r, blocks[0], read_image_labels(data), holdout, free or (), min_deg)
    _print_hand_fit(out, fit)
    doc = _fit_json(fit, data)
    if loo:
        from kincal.identify.hand_eye_fit import leave_one_out

        lo = leave_one_out(r, blocks[0], read_image_labels(data), free or (), min_deg)
        doc["leave_one_out"] = _print_loo(out, lo)
    if output:
        atomic_write_text(output, robot_yaml_text(fit.result.robot))
        out.print(f"robot (camera as tool frame) -> {escape(output)}")
    files.write_transform(out, fit, "hand", data)
    if json_out:
        write_json(json_out, doc)


def _print_hand_fit(out: Any, fit: Any) -> None:
    """The console lines of ``kincal hand-eye ROBOT --data``: the images, the closed-form
    start, the camera, its expected error, the robot parameters and the reprojection."""
    import numpy as np

    from kincal.spatial import frame_from_matrix

    rot = ", ".join(f"{v:.1f}" for v in fit.rotation_deg)
    out.print(f"{len(fit.training)} training images, {len(fit.held_out)} held out"
              + (f" ({', '.join(fit.held_out)})" if fit.held_out else "")
              + f"; the flange turned {rot} deg RMS about its principal axes")
    s = frame_from_matrix(fit.start.X)
    out.print(f"closed-form start: camera at {s[0] * 1e3:.2f} {s[1] * 1e3:.2f} "
              f"{s[2] * 1e3:.2f} mm in the tool frame; pair residuals "
              f"{fit.start.rotation_rms_deg:.3f} deg, {fit.start.translation_rms * 1e3:.2f} mm "
              "RMS")
    f = frame_from_matrix(fit.X)
    std = {n: fit.result.std[fit.result.names.index(n)] for n in fit.result.estimated}
    out.print("camera in the tool frame (x y z mm, rz ry rx deg): "
              + " ".join(f"{v * 1e3:.2f}" for v in f[:3]) + ", "
              + " ".join(f"{np.degrees(v):.3f}" for v in f[3:]))
    out.print(f"expected error of the hand-eye (1 sigma): {fit.expected_position * 1e3:.2f} "
              f"mm, {np.degrees(fit.expected_rotation):.3f} deg: covariance "
              f"{fit.std_position * 1e3:.2f} mm, {np.degrees(fit.std_rotation):.3f} deg "
              f"(sigma0 {fit.result.sigma0:.2f}) with the unmodelled floor "
              f"{fit.floor_position * 1e3:.2f} mm, {np.degrees(fit.floor_rotation):.3f} deg "
              "(images disagreeing beyond their corner noise)")
    extra = [n for n in fit.result.estimated if not n.startswith(("tool.", "camera."))]
    if extra:
        out.print("robot parameters fitted: " + ", ".join(
            f"{n} {fit.result.params[n]:.6g} ± {std[n]:.2g}" for n in extra))
    held = (f"held out {fit.held_rms_px:.2f} px = {fit.held_rms_3d * 1e3:.2f} mm at the board"
            " (" + ", ".join(f"{k} {v:.2f}" for k, v in fit.held_per_image.items()) + ")"
            if fit.held_out else "no held-out images")
    out.print(f"reprojection RMS: training {fit.train_rms_px:.2f} px; {held}")


def _hand_eye_images(out: Any, robot: str | None, images: str | None, board: str | None,
                     joints: str | None, poses: str | None, intrinsics: str | None,
                     mount: str, lens: str, holdout: float, free: list[str] | None,
                     min_rotation: str, loo: bool, output: str | None, json_out: str | None,
                     data: str | None, files: HandEyeFiles,
                     bag: BagTopics) -> None:
    """``kincal hand-eye --images``: detect, closed-form start, one fit of the hand-eye,
    the board and the intrinsics on the raw pixels (:mod:`kincal.identify.hand_eye_lens`)."""
    import numpy as np

    from kincal.cli.camera_bags import hand_eye_bag
    from kincal.identify.hand_eye_lens import calibrate_board_camera, lens_leave_one_out, lens_start
    from kincal.io import check_outputs, write_json
    from kincal.measure.camera_board import read_board
    from kincal.measure.camera_images import (
        detect_images,
        drop_oblique,
        estimate_intrinsics,
        read_flange_poses,
        read_intrinsics,
        read_joints_csv,
    )
    from kincal.units import parse_quantity

    if images is None:
        raise KincalError("--data (a camera measurement file) or --images FOLDER is needed")
    if data is not None:
        raise KincalError("--data and --images: give one of them")
    if board is None:
        raise KincalError("--images needs --board (the board YAML)")
    if mount not in ("hand", "fixed"):
        raise KincalError(f"--mount {mount}: use hand or fixed")
    if lens not in ("all", "pinhole", "none", "fisheye"):
        raise KincalError(f"--lens {lens}: use all, pinhole, none or fisheye")
    if free and poses is not None:
        raise KincalError("--free: robot parameters are fitted from the robot's joint "
                          "values (ROBOT and --joints), not with --poses")
    if output and (mount != "hand" or poses is not None):
        raise KincalError("-o writes the robot with the camera as its tool frame: a camera "
                          "on the hand and joint values (use --json)")
    if poses is not None and (robot is not None or joints is not None):
        raise KincalError("--poses gives the flange poses: no ROBOT and no --joints with it")
    files.check(mount, images=True)
    check_outputs({"--json": json_out, "-o": output, **files.outputs()},
                  {"--images": [images], "--board": [board], "--joints": joints,
                   "--poses": poses, "--intrinsics": intrinsics})
    b = read_board(board)
    table = read_joints_csv(joints) if joints else None
    found = (hand_eye_bag(images, b, bag, robot, joints, poses, intrinsics)
             if bag.wanted(images) else detect_images(images, b, table,
                                                      require_joints=poses is None))
    if len(found.detections) < 3:
        raise KincalError(f"the board was found in {len(found.detections)} images; a "
                          "hand-eye needs 3 at least (better 10 or more)", source=images)
    intr = (read_intrinsics(intrinsics) if intrinsics else found.intrinsics
            or estimate_intrinsics(found, b, "equidistant" if lens == "fisheye" else "plumb_bob"))
    found = drop_oblique(found, b, intr)
    if len(found.detections) < 3:
        raise KincalError(f"{len(found.detections)} images left after dropping the too "
                          "oblique ones; a hand-eye needs 3 at least", source=images)
    r: Any = None
    if poses is not None:
        given = read_flange_poses(poses)
        missing = [d.image for d in found.detections if Path(d.image).stem not in given]
        if missing:
            raise KincalError(f"no pose file for image {missing[0]} ({Path(missing[0]).stem}"
                              ".yaml)", source=poses)
        A = np.array([given[Path(d.image).stem] for d in found.detections])
        frame = "the base frame" if mount == "fixed" else "the flange frame"
    else:
        if robot is None:
            raise KincalError("ROBOT: the robot is missing (or give --poses)")
        r = serial(load(robot), "hand-eye")
        A = r.fk(np.array([d.q for d in found.detections]))
        frame = "the base frame" if mount == "fixed" else "the tool frame"
    model, lens0, fitted = lens_start(intr, lens)
    names = [d.image for d in found.detections]
    pts = [b.corner_points(d.ids) for d in found.detections]
    uv = [d.uv for d in found.detections]
    min_deg = float(np.degrees(parse_quantity(min_rotation, "angle", "--min-rotation",
                                              minimum=0.0)))
    q = np.array([d.q for d in found.detections]) if r is not None else None
    fit = calibrate_board_camera(A, pts, uv, names, lens0, mount, holdout, fitted,
                                 0.5, min_deg, robot=r, q=q, free=free or (), model=model)
    _print_lens_fit(out, fit, found, intr, frame, mount)
    doc = _lens_json(fit, images, mount)
    if loo:
        lo = lens_leave_one_out(A, pts, uv, names, lens0, mount, fitted, 0.5, min_deg, r, q,
                                free or (), model)
        doc["leave_one_out"] = _print_loo(out, lo)
    if output:
        from kincal.io import atomic_write_text
        from kincal.robots.files import robot_yaml_text
        from kincal.spatial import frame_from_matrix, matrix_from_frame

        tool = frame_from_matrix(matrix_from_frame(r.frame_parameters("tool")) @ fit.X)
        values = {n: v for n, (v, _) in fit.robot.items()}
        values.update(zip((f"tool.{c}" for c in ("x", "y", "z", "rz", "ry", "rx")),
                          tool.tolist(), strict=True))
        atomic_write_text(output, robot_yaml_text(r.with_params(values)))
        out.print(f"robot (camera as tool frame) -> {escape(output)}")
    _lens_files(out, files, fit, found, images, A, pts, mount, r, q)
    if json_out:
        write_json(json_out, doc)


def _lens_files(out: Any, files: HandEyeFiles, fit: Any, found: Any, images: str, A: Any,
                pts: list[Any], mount: str, r: Any, q: Any) -> None:
    """The ROS files, the camera_info and the report of ``kincal hand-eye --images``."""
    import numpy as np

    from kincal.cli.camera_outputs import write_lens_report

    files.write_transform(out, fit, mount, images)
    files.write_camera_info(out, fit.lens, found.size, fit.model)
    if files.report:
        if fit.robot:                      # the flange poses of the fitted robot
            A = r.with_params({n: v for n, (v, _) in fit.robot.items()}).fk(q)
        held = (f", held out {fit.held_rms_px:.3f} px" if fit.held_out else "")
        summary = [f"{len(fit.training)} training images, {len(fit.held_out)} held out; "
                   f"reprojection RMS training {fit.train_rms_px:.3f} px{held}.",
                   f"Camera in the {'base' if mount == 'fixed' else 'flange (tool)'} frame"
                   " (x y z mm): " + " ".join(f"{v * 1e3:.2f}" for v in fit.X[:3, 3])
                   + f"; expected error (1 sigma) {fit.expected_position * 1e3:.2f} mm, "
                   f"{np.degrees(fit.expected_rotation):.3f} deg."]
        write_lens_report(out, files.report, images, fit, found, A, pts, mount, summary)


def _print_loo(out: Any, lo: Any) -> dict[str, Any]:
    """Print the leave-one-out line; return its JSON part."""
    import numpy as np

    out.print(f"leave-one-out ({len(lo.images)} fits): held-out RMS "
              f"{np.sqrt(np.mean(lo.rms_px ** 2)):.2f} px = "
              f"{np.sqrt(np.mean(lo.rms_3d ** 2)) * 1e3:.2f} mm at the board, worst "
              f"{escape(lo.images[int(np.argmax(lo.rms_px))])} {lo.rms_px.max():.2f} px; "
              f"hand-eye spread (jackknife) {lo.position_spread * 1e3:.2f} mm, "
              f"{np.degrees(lo.rotation_spread):.3f} deg")
    return {"images": lo.images, "rms_px": lo.rms_px.tolist(), "rms_3d_m": lo.rms_3d.tolist(),
            "position_spread_m": lo.position_spread, "rotation_spread_rad": lo.rotation_spread}


def _print_lens_fit(out: Any, fit: Any, found: Any, intr: Any, frame: str, mount: str) -> None:
    import numpy as np

    from kincal.spatial import frame_from_matrix

    out.print(f"{len(found.detections)} images with the board, {len(found.dropped)} dropped"
              + "".join(f"; dropped {escape(i)}: {escape(why)}" for i, why in found.dropped))
    rot = ", ".join(f"{v:.1f}" for v in fit.rotation_deg)
    out.print(f"{len(fit.training)} training images, {len(fit.held_out)} held out"
              + (f" ({', '.join(fit.held_out)})" if fit.held_out else "")
              + f"; the flange turned {rot} deg RMS about its principal axes")
    out.print(f"start: intrinsics {escape(intr.source)}; closed-form camera at "
              + " ".join(f"{v * 1e3:.2f}" for v in fit.start.X[:3, 3])
              + f" mm in {frame}; pair residuals {fit.start.rotation_rms_deg:.3f} deg, "
              f"{fit.start.translation_rms * 1e3:.2f} mm RMS")
    f = frame_from_matrix(fit.X)
    out.print(f"camera in {frame} (x y z mm, rz ry rx deg): "
              + " ".join(f"{v * 1e3:.2f}" for v in f[:3]) + ", "
              + " ".join(f"{np.degrees(v):.3f}" for v in f[3:]))
    z = frame_from_matrix(fit.Z)
    where = "the flange frame" if mount == "fixed" else "the base frame"
    out.print(f"board in {where} (x y z mm, rz ry rx deg): "
              + " ".join(f"{v * 1e3:.2f}" for v in z[:3]) + ", "
              + " ".join(f"{np.degrees(v):.3f}" for v in z[3:]))
    fitted = [n for n in fit.names if n in fit.lens_names]
    kind = " (fisheye, equidistant)" if fit.model == "fisheye" else ""
    out.print(f"intrinsics{kind}: " + ", ".join(
        f"{n} {fit.lens[k]:.5g}" + (f" ± {fit.lens_std[k]:.2g}" if n in fitted else " (held)")
        for k, n in enumerate(fit.lens_names)))
    if fit.robot:
        out.print("robot parameters fitted: " + ", ".join(
            f"{n} {v:.6g} ± {s:.2g}" for n, (v, s) in fit.robot.items()))
    for n, why in fit.held.items():
        out.print(f"held at nominal: {escape(n)}: {escape(why)}")
    out.print(f"expected error of the hand-eye (1 sigma): {fit.expected_position * 1e3:.2f} "
              f"mm, {np.degrees(fit.expected_rotation):.3f} deg: covariance "
              f"{fit.std_position * 1e3:.2f} mm, {np.degrees(fit.std_rotation):.3f} deg "
              f"(sigma0 {fit.sigma0:.2f}) with the unmodelled floor "
              f"{fit.floor_position * 1e3:.2f} mm, {np.degrees(fit.floor_rotation):.3f} deg")
    held = (f"held out {fit.held_rms_px:.2f} px = {fit.held_rms_3d * 1e3:.2f} mm at the board"
            " (" + ", ".join(f"{k} {v:.2f}" for k, v in fit.held_per_image.items()) + ")"
            if fit.held_out else "no held-out images")
    out.print(f"reprojection RMS: training {fit.train_rms_px:.2f} px; {held}")


def _lens_json(fit: Any, images: str, mount: str) -> dict[str, Any]:
    from kincal.spatial import frame_from_matrix

    return {"images": images, "mount": mount, "training": fit.training,
            "held_out": fit.held_out,
            "camera": {"matrix": fit.X.tolist(),
                       "frame_m_rad": frame_from_matrix(fit.X).tolist()},
            "board": {"matrix": fit.Z.tolist(),
                      "frame_m_rad": frame_from_matrix(fit.Z).tolist()},
            "closed_form_start": fit.start.X.tolist(),
            "lens_model": fit.model,
            "intrinsics": dict(zip(fit.lens_names, fit.lens.tolist(), strict=True)),
            "intrinsics_std": dict(zip(fit.lens_names, fit.lens_std.tolist(), strict=True)),
            "robot_parameters": {n: {"value": v, "std": s} for n, (v, s) in fit.robot.items()},
            "robot_parameters_held": fit.held,
            **_quality(fit),
            "flange_rotation_deg": fit.rotation_deg.tolist(), "sigma0": fit.sigma0}
