"""The files ``kincal hand-eye`` writes for ROS and for people: ``--ros-yaml`` (easy_handeye's
calibration YAML), ``--ros-launch`` (a static_transform_publisher launch file; ROS 2 XML
when the name ends in ``.launch.xml``), ``--urdf-joint`` (a fixed joint), ``--camera-info``
(the fitted intrinsics as ROS camera_info YAML) and ``--report`` (the images with the
detected and predicted corners, worst first), with the frame names ``--parent-frame`` /
``--child-frame`` (:mod:`kincal.report.ros_camera`, :mod:`kincal.report.camera_pictures`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from kincal.errors import KincalError

RosYamlOpt = Annotated[str | None, typer.Option(
    "--ros-yaml", help="Write the hand-eye as easy_handeye's calibration YAML.")]
RosLaunchOpt = Annotated[str | None, typer.Option(
    "--ros-launch", help="Write a launch file publishing the hand-eye (tf2_ros "
    "static_transform_publisher; ROS 2 XML when FILE ends in .launch.xml).")]
UrdfJointOpt = Annotated[str | None, typer.Option(
    "--urdf-joint", help="Write the hand-eye as a fixed URDF joint (origin xyz rpy).")]
CameraInfoOpt = Annotated[str | None, typer.Option(
    "--camera-info", help="Write the fitted intrinsics as ROS camera_info YAML (with "
    "--images).")]
ReportOpt = Annotated[str | None, typer.Option(
    "--report", help="Write an HTML page: every image's reprojection error, worst first, "
    "and the worst images with the detected and predicted corners (with --images).")]
ParentFrameOpt = Annotated[str | None, typer.Option(
    "--parent-frame", help="The frame the camera is given in, in the ROS files (default "
    "tool0 with the camera on the hand, base_link with it fixed).")]
ChildFrameOpt = Annotated[str, typer.Option(
    "--child-frame", help="The camera's optical frame in the ROS files (z along the view, "
    "x right, y down).")]

#: How many of the worst images the report draws.
PICTURES = 4


@dataclass
class HandEyeFiles:
    """The output options of ``kincal hand-eye`` besides ``-o`` and ``--json``."""

    ros_yaml: str | None = None
    ros_launch: str | None = None
    urdf_joint: str | None = None
    camera_info: str | None = None
    report: str | None = None
    parent_frame: str | None = None
    child_frame: str = "camera_optical_frame"

    def outputs(self) -> dict[str, str | None]:
        return {"--ros-yaml": self.ros_yaml, "--ros-launch": self.ros_launch,
                "--urdf-joint": self.urdf_joint, "--camera-info": self.camera_info,
                "--report": self.report}

    def parent(self, mount: str) -> str:
        return self.parent_frame or ("tool0" if mount == "hand" else "base_link")

    def check(self, mount: str, images: bool) -> None:
        """Before any work: the frame names, the options that need the images, and a
        folder to write each file into (one line naming the option)."""
        from kincal.report.ros_camera import check_frame_name

        check_frame_name(self.child_frame, "--child-frame")
        if self.parent_frame is not None:
            check_frame_name(self.parent_frame, "--parent-frame")
        if not images:
            for opt, path in (("--camera-info", self.camera_info), ("--report", self.report)):
                if path is not None:
                    raise KincalError(f"option {opt}: needs --images (the image size and "
                                      "the fitted lens come from the images)")
        for opt, path in self.outputs().items():
            if path is not None and not Path(path).resolve().parent.is_dir():
                raise KincalError(f"option {opt}: the folder of {path!r} does not exist")

    def write_transform(self, out: Any, fit: Any, mount: str, source: str) -> None:
        """The hand-eye ``fit.X`` (the camera's optical frame in the parent frame) into the
        ROS YAML, the launch file and the URDF joint that were asked for, each headed by
        where it came from and its expected error."""
        import numpy as np

        from kincal._version import __version__
        from kincal.io import atomic_write_text
        from kincal.report import ros_camera as rc

        parent, child, X = self.parent(mount), self.child_frame, fit.X
        held = (f", held out {fit.held_rms_px:.2f} px" if fit.held_out else "")
        comment = [f"kincal {__version__} hand-eye from {source}: the camera's optical frame "
                   f"{child} (z along the view, x right, y down) in {parent}",
                   f"expected error (1 sigma) {fit.expected_position * 1e3:.2f} mm, "
                   f"{np.degrees(fit.expected_rotation):.3f} deg; reprojection RMS training "
                   f"{fit.train_rms_px:.2f} px{held}"]
        texts: list[tuple[str, str]] = []
        if self.ros_yaml:
            texts.append((self.ros_yaml, rc.easy_handeye_yaml(X, parent, child, mount == "hand",
                                                              comment=comment)))
        if self.ros_launch:
            ros2 = self.ros_launch.endswith(".launch.xml")
            texts.append((self.ros_launch, rc.static_transform_launch(X, parent, child, ros2,
                                                                      comment)))
        if self.urdf_joint:
            texts.append((self.urdf_joint, rc.urdf_joint(X, parent, child, comment)))
        for path, text in texts:
            atomic_write_text(path, text)
            out.print(f"hand-eye {escape(parent)} -> {escape(child)} -> {escape(path)}")

    def write_camera_info(self, out: Any, lens: Any, size: tuple[int, int],
                          model: str = "radtan") -> None:
        """``--camera-info``: ROS ``plumb_bob`` (k1 k2 p1 p2 k3) for the radial-tangential
        lens, ``equidistant`` (k1 k2 k3 k4) for the fisheye one."""
        from kincal.io import atomic_write_text
        from kincal.report.ros_camera import camera_info_yaml

        if self.camera_info is None:
            return
        name = self.child_frame.strip("/").replace("/", "_")
        fx, fy, cx, cy = (float(v) for v in lens[:4])
        fisheye = model == "fisheye"
        dist = [float(v) for v in (lens[4:8] if fisheye else lens[4:9])]
        atomic_write_text(self.camera_info, camera_info_yaml(
            fx, fy, cx, cy, dist, size[0], size[1], name,
            "equidistant" if fisheye else "plumb_bob"))
        out.print(f"intrinsics (camera_info, {size[0]} x {size[1]} px) -> "
                  f"{escape(self.camera_info)}")


def write_lens_report(out: Any, path: str, folder: str, fit: Any, found: Any, A: Any,
                      points: list[Any], mount: str, summary: list[str]) -> None:
    """``--report``: the reprojection of every image under the fit (``A`` the flange poses
    of ``found.detections``, with the fitted robot parameters), the worst
    :data:`PICTURES` drawn."""
    import cv2

    from kincal.io import atomic_write_text
    from kincal.report.camera_pictures import (
        draw_corners,
        hand_eye_page,
        image_errors,
        image_file,
        predicted_pixels,
    )

    names = [d.image for d in found.detections]
    pred = predicted_pixels(A, points, fit.X, fit.Z, fit.lens, mount)
    rows = image_errors(names, [d.uv for d in found.detections], pred, fit.held_out)
    pictures = []
    for r in rows[:PICTURES]:
        img = cv2.imread(str(image_file(folder, r.image)), cv2.IMREAD_COLOR)
        if img is not None:
            pictures.append((r, draw_corners(img, r)))
    atomic_write_text(path, hand_eye_page(f"Hand-eye: {folder}", summary, rows,
                                          pictures))
    out.print(f"report ({len(rows)} images, the {len(pictures)} worst drawn) -> "
              f"{escape(path)}")
