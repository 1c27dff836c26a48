"""``kincal plan ROBOT --camera hand|fixed --board B --intrinsics I -o poses.csv``: robot
poses for a camera calibration that see the whole board and excite the hand-eye and the
robot parameters asked for (:mod:`kincal.identify.camera_plan`), written as the joints CSV
``kincal import images --joints`` reads back, with the predicted hand-eye error."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from kincal.errors import KincalError

__all__ = ["camera_plan", "image_size"]

# the options of `kincal plan --camera` (declared here to keep `plan` readable)
CameraOpt = Annotated[str | None, typer.Option(
    "--camera", help="Plan a camera calibration instead: hand (camera on the flange) or "
    "fixed (board on the flange); poses that see the whole board, written as the CSV of "
    "`kincal import images --joints`.")]
BoardOpt = Annotated[str | None, typer.Option("--board", help="--camera: the board YAML.")]
IntrinsicsOpt = Annotated[str | None, typer.Option(
    "--intrinsics", help="--camera: ROS camera_info or OpenCV YAML.")]
ImageSizeOpt = Annotated[str | None, typer.Option(
    "--image-size", help="--camera: WIDTHxHEIGHT px (default: the camera_info's).")]
FreeOpt = Annotated[list[str] | None, typer.Option(
    "--free", help="--camera: robot parameters to design for with the hand-eye, e.g. "
    "'theta_offset*'.")]
CameraPoseOpt = Annotated[str | None, typer.Option(
    "--camera-pose", help="--camera: camera in the tool (hand) or base (fixed) frame, "
    "x,y,z,rz,ry,rx (m and deg unless given).")]
BoardPoseOpt = Annotated[str | None, typer.Option(
    "--board-pose", help="--camera: board in the base (hand) or tool (fixed) frame "
    "(default: facing the camera at the centre configuration).")]
CenterOpt = Annotated[str | None, typer.Option(
    "--center", help="--camera: configuration the candidates spread around, one angle per "
    "joint (deg unless given; default mid-range).")]
SpreadOpt = Annotated[str, typer.Option(
    "--spread", help="--camera: candidates spread per joint around --center.")]
MaxTiltOpt = Annotated[str, typer.Option(
    "--max-tilt", help="--camera: largest angle between the board's normal and the ray to "
    "the camera.")]
DistanceOpt = Annotated[str | None, typer.Option(
    "--board-distance", help="--camera: board to camera at the centre configuration "
    "(default: the board fills half the image).")]
PixelNoiseOpt = Annotated[str, typer.Option(
    "--pixel-noise", help="--camera: corner noise per coordinate.")]


def image_size(text: str | None, intrinsics: str) -> tuple[int, int]:
    """``--image-size 1280x720``, else the intrinsics file's ``image_width`` and
    ``image_height`` (ROS camera_info)."""
    import yaml

    if text:
        parts = text.lower().replace(",", "x").split("x")
        try:
            w, h = (int(p) for p in parts)
        except ValueError:
            raise KincalError(f"option --image-size: {text!r}: use WIDTHxHEIGHT in pixels, "
                              "e.g. 1280x720") from None
        if w <= 0 or h <= 0:
            raise KincalError(f"option --image-size: {text!r}: sizes must be positive")
        return w, h
    try:
        data = yaml.safe_load(Path(intrinsics).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):
        data = None
    if isinstance(data, dict) and isinstance(data.get("image_width"), int) \
            and isinstance(data.get("image_height"), int):
        return int(data["image_width"]), int(data["image_height"])
    raise KincalError("no image_width / image_height in the intrinsics file: give "
                      "--image-size WIDTHxHEIGHT", source=intrinsics)


def camera_plan(out: Any, r: Any, output: str, mount: str, board: str | None,
                intrinsics: str | None, size: str | None, poses: int, free: list[str] | None,
                camera_pose: str | None, board_pose: str | None, center: str | None,
                spread: str, max_tilt: str, distance: str | None, pixel_noise: str,
                candidates: int, criterion: str, seed: int, angle_unit: str,
                json_out: str | None) -> None:
    """Plan, print, write the CSV (and the JSON); every input is checked first."""
    import numpy as np

    from kincal.cli.common import point_vector
    from kincal.identify.camera_plan import plan_camera_poses, write_camera_poses
    from kincal.io import check_outputs, write_json
    from kincal.measure.camera_board import read_board
    from kincal.measure.camera_images import read_intrinsics
    from kincal.spatial import frame_from_matrix, matrix_from_frame
    from kincal.units import parse_quantity

    if mount not in ("hand", "fixed"):
        raise KincalError(f"option --camera: {mount!r}: use hand or fixed")
    if board is None or intrinsics is None:
        raise KincalError("--camera needs --board (the board YAML) and --intrinsics (ROS "
                          "camera_info or OpenCV YAML)")
    check_outputs({"-o": output, "--json": json_out}, {"--board": [board],
                                                       "--intrinsics": [intrinsics]})
    b = read_board(board)
    intr = read_intrinsics(intrinsics)
    wh = image_size(size, intrinsics)
    frame = ["length"] * 3 + ["angle"] * 3
    X = matrix_from_frame(point_vector(camera_pose, "--camera-pose", frame, deg=True)) \
        if camera_pose else None
    Z = matrix_from_frame(point_vector(board_pose, "--board-pose", frame, deg=True)) \
        if board_pose else None
    qc = point_vector(center, "--center", ["angle"] * r.n, deg=True) if center else None
    p = plan_camera_poses(
        r, b.corner_points(np.arange(b.num_corners)), intr.pinhole, wh, mount, poses,
        free or (), qc, parse_quantity(spread, "angle", "--spread", positive=True),
        candidates, X, Z,
        parse_quantity(distance, "length", "--board-distance", positive=True)
        if distance else None, parse_quantity(pixel_noise, "pixel", "--pixel-noise",
                                              positive=True),
        max_tilt_deg=float(np.degrees(parse_quantity(max_tilt, "angle", "--max-tilt",
                                                     positive=True))),
        criterion=criterion, seed=seed)
    rp, rr = p.median_random
    he = ("camera in the tool frame" if mount == "hand" else "camera in the base frame")
    bz = ("board in the base frame" if mount == "hand" else "board in the flange frame")
    fx, fz = frame_from_matrix(p.X), frame_from_matrix(p.Z)
    comments = [f"kincal plan --camera {mount}: robot={r.name}; {poses} poses; criterion="
                f"{criterion}; seed={seed}",
                f"{he} (x y z mm, rz ry rx deg): " + _frame_text(fx),
                f"{bz}: " + _frame_text(fz),
                f"predicted hand-eye error (1 sigma, {p.inputs['noise']} per corner "
                f"coordinate): {p.std_position * 1e3:.3g} mm, "
                f"{np.degrees(p.std_rotation):.3g} deg"]
    names = write_camera_poses(output, r, p.q, angle_unit, comments=comments)
    out.print(f"{escape(r.name)}, camera {'on the hand' if mount == 'hand' else 'fixed'}: "
              f"{p.visible} of {p.candidates} candidate poses see the whole board ("
              f"{escape(p.inputs['visibility'])})")
    out.print(f"{he} (x y z mm, rz ry rx deg): {_frame_text(fx)}; {bz}: {_frame_text(fz)} "
              f"({escape(p.inputs['board distance'])})")
    robot_names = [n for n in p.std if not n.startswith(("tool.", "camera."))]
    out.print("designed for: the hand-eye, the board" + (", " + ", ".join(robot_names)
                                                          if robot_names else ""))
    for n, why in p.not_identifiable.items():
        out.print(f"not identifiable from these poses: {escape(n)} ({escape(why)})")
    out.print(f"selected {len(p.q)} poses by {criterion} ({p.design.method}); tilt "
              f"{p.view.tilt_deg.min():.0f}-{p.view.tilt_deg.max():.0f} deg, board "
              f"{p.view.size.min():.2f}-{p.view.size.max():.2f} of the image diagonal")
    out.print(f"predicted hand-eye error (1 sigma, {p.inputs['noise']} per corner "
              f"coordinate, intrinsics known): {p.std_position * 1e3:.3g} mm, "
              f"{np.degrees(p.std_rotation):.3g} deg; median of 20 random visible designs: "
              f"{rp * 1e3:.3g} mm, {np.degrees(rr):.3g} deg")
    out.print(f"wrote {len(p.q)} poses -> {escape(output)} (image names {names[0]} ..., "
              f"then the joints in {angle_unit}): take one image per pose and import them "
              "with --joints")
    if json_out:
        write_json(json_out, {
            "robot": r.name, "mount": mount, "poses": p.q.tolist(), "images": names,
            "joint_names": list(r.joint_names), "camera": p.X.tolist(), "board": p.Z.tolist(),
            "predicted_hand_eye": {"position_m": p.std_position,
                                   "rotation_rad": p.std_rotation},
            "random_median_hand_eye": {"position_m": rp, "rotation_rad": rr},
            "predicted_std": p.std, "not_identifiable": p.not_identifiable,
            "tilt_deg": p.view.tilt_deg.tolist(), "board_size": p.view.size.tolist(),
            "inputs": p.inputs, "output": output})


def _frame_text(f: Any) -> str:
    import numpy as np

    a = np.asarray(f, dtype=float)
    v = np.round(np.concatenate([a[:3] * 1e3, np.degrees(a[3:])]), 1) + 0.0   # no -0.0
    return " ".join(f"{x:.1f}" for x in v[:3]) + ", " + " ".join(f"{x:.1f}" for x in v[3:])
