"""A calibrated camera in the files ROS reads: the hand-eye as a static transform and a
URDF joint, the intrinsics as ``camera_info``.

The hand-eye ``T`` (4x4) is the camera's optical frame (OpenCV's: z along the viewing
ray, x to the right of the image, y down) in the parent frame (the tool flange for a
camera on the hand, the robot's base for a fixed camera): ``p_parent = R p_camera + t``
[m].  Each writer returns text; the command writes it atomically.

* :func:`easy_handeye_yaml`: easy_handeye's calibration file (``parameters`` with
  ``eye_on_hand``, the robot and tracking frames, and ``transformation: {x, y, z, qx, qy,
  qz, qw}``), what its ``publish.launch`` loads and broadcasts (parent = the effector
  frame on the hand, the base frame otherwise; child = ``tracking_base_frame``);
* :func:`static_transform_launch`: a launch file with one ``tf2_ros``
  ``static_transform_publisher`` node (``args="x y z qx qy qz qw parent child"``): ROS 1
  XML, or ROS 2 XML (``exec=`` and the named ``--x ... --child-frame-id`` arguments);
* :func:`urdf_joint`: a fixed joint (``<origin xyz rpy>``, ``R = Rz(yaw) Ry(pitch)
  Rx(roll)``) and the camera's link inside ``<robot>``, to paste or ``xacro:include``;
* :func:`camera_info_yaml`: ``image_width``, ``image_height``, ``camera_name``,
  ``camera_matrix`` (K), ``distortion_model`` (``plumb_bob``: k1 k2 p1 p2 k3),
  ``distortion_coefficients``, ``rectification_matrix`` (identity: one camera) and
  ``projection_matrix`` ``P = [K | 0]`` (the rectified image keeps K).

Numbers are written with 17 significant digits, so a file read back gives the fitted
matrix to the last bits (tests: 1e-12).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.identify.hand_eye import quaternion
from kincal.spatial import matrix_to_rpy

Array = NDArray[np.float64]

__all__ = ["check_frame_name", "translation_quaternion", "easy_handeye_yaml",
           "static_transform_launch", "urdf_joint", "camera_info_yaml"]

_FRAME = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_/]*$")


def _g(v: float) -> str:
    """A float that reads back to the same bits."""
    return repr(float(v))


def check_frame_name(name: str, option: str) -> str:
    """``name`` if it is a ROS frame (tf) name: a letter or ``_`` first, then letters,
    digits, ``_`` and ``/``; otherwise one line naming ``option``."""
    if not _FRAME.match(name):
        raise KincalError(f"option {option}: {name!r} is not a ROS frame name (letters, "
                          "digits, _ and /, not starting with a digit)")
    return name


def translation_quaternion(T: ArrayLike) -> tuple[Array, Array]:
    """``(t, q)`` of a 4x4 transform: ``t`` [m] and the unit quaternion ``q = (qx, qy, qz,
    qw)`` (ROS's order), ``qw >= 0``, with ``R = I + 2 qw [v]x + 2 [v]x^2``, ``v = (qx,
    qy, qz)``."""
    M = np.asarray(T, dtype=float)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise KincalError("a transform is a finite 4x4 matrix")
    w, x, y, z = quaternion(M[:3, :3])
    return M[:3, 3].copy(), np.array([x, y, z, w])


def easy_handeye_yaml(T: ArrayLike, parent: str, child: str, eye_on_hand: bool,
                      base_frame: str = "base_link", effector_frame: str = "tool0",
                      marker_frame: str = "board", comment: Sequence[str] = ()) -> str:
    """easy_handeye's calibration YAML (module docstring); ``parent`` replaces the
    effector frame (``eye_on_hand``) or the base frame; ``comment`` lines head the file."""
    t, q = translation_quaternion(T)
    if eye_on_hand:
        effector_frame = parent
    else:
        base_frame = parent
    name = "kincal_eye_on_hand" if eye_on_hand else "kincal_eye_on_base"
    lines = [f"# {c}" for c in comment]
    lines += ["parameters:", f"  eye_on_hand: {'true' if eye_on_hand else 'false'}",
              "  move_group: manipulator", "  move_group_namespace: /",
              f"  namespace: /{name}/", f"  robot_base_frame: {base_frame}",
              f"  robot_effector_frame: {effector_frame}", f"  tracking_base_frame: {child}",
              f"  tracking_marker_frame: {marker_frame}", "transformation:"]
    lines += [f"  {k}: {_g(v)}" for k, v in zip(("x", "y", "z"), t, strict=True)]
    lines += [f"  {k}: {_g(v)}" for k, v in zip(("qx", "qy", "qz", "qw"), q, strict=True)]
    return "\n".join(lines) + "\n"


def static_transform_launch(T: ArrayLike, parent: str, child: str, ros2: bool = False,
                            comment: Sequence[str] = ()) -> str:
    """A launch file publishing ``T`` from ``parent`` to ``child`` with ``tf2_ros``'s
    ``static_transform_publisher`` (ROS 1 XML, or ROS 2 XML with ``ros2``)."""
    t, q = translation_quaternion(T)
    node = re.sub(r"[^A-Za-z0-9_]", "_", f"{child}_static_tf").lstrip("_")
    if ros2:
        keys = ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")
        args = " ".join(f"{k} {_g(v)}" for k, v in zip(keys, np.r_[t, q], strict=True))
        args += f" --frame-id {parent} --child-frame-id {child}"
        body = (f'  <node pkg="tf2_ros" exec="static_transform_publisher" name={quoteattr(node)}'
                f"\n        args={quoteattr(args)}/>")
    else:
        args = " ".join(_g(v) for v in np.r_[t, q]) + f" {parent} {child}"
        body = (f'  <node pkg="tf2_ros" type="static_transform_publisher" name={quoteattr(node)}'
                f"\n        args={quoteattr(args)}/>")
    notes = "".join(f"<!-- {c.replace('--', '- -')} -->\n" for c in comment)
    return f'<?xml version="1.0"?>\n{notes}<launch>\n{body}\n</launch>\n'


def urdf_joint(T: ArrayLike, parent: str, child: str, comment: Sequence[str] = ()) -> str:
    """A fixed URDF joint ``{child}_joint`` from ``parent`` to the link ``child`` at ``T``
    (``<origin xyz="x y z" rpy="roll pitch yaw"/>``, ``R = Rz(yaw) Ry(pitch) Rx(roll)``),
    with the link, inside ``<robot>``."""
    M = np.asarray(T, dtype=float)
    t, _ = translation_quaternion(M)
    rpy = matrix_to_rpy(M[:3, :3])
    notes = "".join(f"  <!-- {c.replace('--', '- -')} -->\n" for c in comment)
    return ('<?xml version="1.0"?>\n<robot name="kincal_camera_mount">\n' + notes
            + f"  <link name={quoteattr(child)}/>\n"
            f"  <joint name={quoteattr(child + '_joint')} type=\"fixed\">\n"
            f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(child)}/>\n"
            f"    <origin xyz=\"{' '.join(_g(v) for v in t)}\" "
            f"rpy=\"{' '.join(_g(v) for v in rpy)}\"/>\n  </joint>\n</robot>\n")


def camera_info_yaml(fx: float, fy: float, cx: float, cy: float, dist: Sequence[float],
                     width: int, height: int, camera_name: str = "camera",
                     distortion_model: str = "plumb_bob") -> str:
    """ROS ``camera_info`` YAML (camera_calibration_parsers' form, module docstring):
    ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px], the distortion coefficients as
    given, ``R = I``, ``P = [K | 0]``."""
    K = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    P = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    if width <= 0 or height <= 0:
        raise KincalError(f"image size {width} x {height}: the camera_info needs the image "
                          "size in pixels")

    def mat(key: str, rows: int, cols: int, data: Sequence[float]) -> list[str]:
        return [f"{key}:", f"  rows: {rows}", f"  cols: {cols}",
                "  data: [" + ", ".join(_g(v) for v in data) + "]"]

    lines = [f"image_width: {int(width)}", f"image_height: {int(height)}",
             f"camera_name: {camera_name}", *mat("camera_matrix", 3, 3, K),
             f"distortion_model: {distortion_model}",
             *mat("distortion_coefficients", 1, len(dist), dist),
             *mat("rectification_matrix", 3, 3, np.eye(3).reshape(-1).tolist()),
             *mat("projection_matrix", 3, 4, P)]
    return "\n".join(lines) + "\n"
