"""ROS bags of board images in: each image matched to the robot's joint states by time.

``kincal import images BAG --image-topic TOPIC --board board.yaml`` reads a ROS 1 ``.bag``
or a ROS 2 bag folder (through ``rosbags``, the ``ros`` extra; the joint states by
:func:`kincal.measure.bags.read_bag_streams`) holding ``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage`` messages and ``sensor_msgs/JointState``.  Each image's
time ``t`` is its header stamp (the bag's log time when the stamp is zero).

**Joint values at the image.**  Linear interpolation between the joint states just before
(``t0 <= t``) and just after (``t1 >= t``) it::

    q(t) = q0 + (t - t0) / (t1 - t0) (q1 - q0)                                  [rad, m]

An image is dropped, with the reason, when either neighbour is more than ``max_gap`` [s]
away (``--max-gap``, default 20 ms; or there is none: the image lies outside the joint
states), or when the robot moves at the image time: the joint speed
``max_j |q1_j - q0_j| / (t1 - t0)`` [rad/s or m/s], or the recorded velocity
interpolated the same way when every joint state carries one, above ``max_speed``
(``--max-speed``, default 0.01 rad/s as for the standstills of a tracker bag).

**Pixels.**  ``Image`` encodings ``mono8``/``8UC1``, ``mono16``/``16UC1`` (scaled to 8
bit by its maximum), ``bgr8``, ``rgb8``, ``bgra8``, ``rgba8`` (converted to grey); any
other encoding is refused in one line naming it.  ``CompressedImage`` (jpeg, png) is
decoded by ``cv2.imdecode``; an image that does not decode is dropped.  The board is then
found as in a folder (:func:`kincal.measure.camera_images.detect_gray`: not found, too
few corners, blurred), and the result is the same :class:`ImageSet` the folder import
makes, written as the same measurement file.  Images are named ``NNNN@STAMP`` (their
order on the topic, and the stamp in s).

**Intrinsics from the bag.**  When the bag holds ``sensor_msgs/CameraInfo`` on
``camera_info_topic`` (default: the image topic's sibling ``camera_info``, e.g.
``/camera/image_raw`` -> ``/camera/camera_info``), its ``K`` (fx, fy, cx, cy [px]) and
``D`` with ``distortion_model`` (plumb_bob, rational_polynomial, equidistant; as a
``camera_info`` YAML is read) become the set's intrinsics.  Messages whose ``K``, ``D``
or model differ are refused in one line naming the topic; an all-zero ``K`` (ROS's
"uncalibrated") is not used.  A topic named explicitly must exist.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.bags import read_bag_streams
from kincal.measure.camera_board import Board
from kincal.measure.camera_images import (
    MIN_SHARPNESS,
    ImageSet,
    Intrinsics,
    add_detection,
    distortion_model_named,
    intrinsics_from,
    require_opencv,
)

Array = NDArray[np.float64]

__all__ = ["ImageBagOptions", "ENCODINGS", "is_bag", "read_image_bag", "joints_at",
           "camera_info_topic"]

#: ``sensor_msgs/Image`` encodings read: (channels, bytes per channel).
ENCODINGS = {"mono8": (1, 1), "8UC1": (1, 1), "mono16": (1, 2), "16UC1": (1, 2),
             "bgr8": (3, 1), "rgb8": (3, 1), "bgra8": (4, 1), "rgba8": (4, 1)}
_IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


@dataclass(frozen=True)
class ImageBagOptions:
    """When an image is kept (module docstring): ``max_gap`` [s] to the joint states on
    either side, ``max_speed`` [rad/s or m/s] of the fastest joint at the image time."""

    max_gap: float = 0.02
    max_speed: float = 0.01


def is_bag(path: str | Path) -> bool:
    """A ROS 1 ``.bag`` file or a ROS 2 bag folder (with ``metadata.yaml``)."""
    p = Path(path)
    return (p.is_file() and p.suffix == ".bag") or (p.is_dir() and
                                                    (p / "metadata.yaml").is_file())


def joints_at(t: float, jt: Array, jq: Array, opt: ImageBagOptions,
              jv: Array | None = None) -> tuple[Array, str | None]:
    """The joint values at time ``t`` [s] interpolated in the joint states ``(jt, jq)``
    (and the speed check, with the recorded velocities ``jv`` if any), or why not: the
    reason the image is dropped (module docstring)."""
    k = int(np.searchsorted(jt, t, side="left"))      # jt[k - 1] < t <= jt[k]
    k0, k1 = (k, k) if k < len(jt) and jt[k] == t else (k - 1, k)
    gaps = [t - jt[k0] if k0 >= 0 else np.inf, jt[k1] - t if k1 < len(jt) else np.inf]
    if max(gaps) > opt.max_gap:
        near = ", ".join(f"{w} {g * 1e3:.0f} ms" if np.isfinite(g) else f"none {w}"
                         for w, g in zip(("before", "after"), gaps, strict=True))
        return np.zeros(0), (f"no joint states within {opt.max_gap * 1e3:g} ms of the image "
                             f"({near})")
    dt = jt[k1] - jt[k0]
    a = (t - jt[k0]) / dt if dt > 0 else 0.0
    q = jq[k0] + a * (jq[k1] - jq[k0])
    lo, hi = (k0, k1) if k1 > k0 else (max(k0 - 1, 0), min(k0 + 1, len(jt) - 1))
    speed = float(np.abs(jq[hi] - jq[lo]).max() / (jt[hi] - jt[lo])) if hi > lo else 0.0
    if jv is not None:
        speed = max(speed, float(np.abs(jv[k0] + a * (jv[k1] - jv[k0])).max()))
    if speed > opt.max_speed:
        return q, (f"robot moving ({speed:.3g} rad/s or m/s at the image time > "
                   f"{opt.max_speed:g}, --max-speed)")
    return q, None


def _gray(cv2: Any, msg: Any, compressed: bool, where: str, path: str) -> Any:
    """The grey 8-bit image of a message (None if a compressed one does not decode); the
    encoding of a raw one is one of :data:`ENCODINGS` (checked by :func:`_images`)."""
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if compressed:
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if img is None:
            return None
    else:
        enc = str(msg.encoding)
        ch, nb = ENCODINGS[enc]
        h, w, step = int(msg.height), int(msg.width), int(msg.step)
        if step < w * ch * nb or data.size < h * step:
            raise MeasurementFileError(f"{where}: {data.size} bytes of data for a {w} x {h} "
                                       f"{enc} image of step {step}", source=path)
        rows = data[:h * step].reshape(h, step)[:, :w * ch * nb]
        if nb == 2:
            img = rows.copy().view(">u2" if msg.is_bigendian else "<u2").reshape(h, w)
        else:
            img = rows.reshape(h, w, ch) if ch > 1 else rows
        if enc.startswith("rgb"):
            img = img[:, :, [2, 1, 0]]
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        top = float(img.max()) or 1.0
        img = np.clip(img.astype(float) * (255.0 / top), 0, 255).astype(np.uint8)
    return img


def _velocities(reader: Any, joint_topic: str, names: Sequence[str]) -> Array | None:
    """The recorded joint velocities (one row per joint state, in stamp order), None
    unless every joint state carries them."""
    from kincal.measure.bags import _stamp

    vel: list[tuple[float, list[float]]] = []
    conns = [c for c in reader.connections if c.topic == joint_topic]
    for conn, t_ns, raw in reader.messages(connections=conns):
        msg: Any = reader.deserialize(raw, conn.msgtype)
        order = {n: i for i, n in enumerate(msg.name)}
        if not all(n in order for n in names):
            continue                                       # a message for other joints
        if len(msg.velocity) != len(msg.name):
            return None
        vel.append((_stamp(msg, t_ns), [float(msg.velocity[order[n]]) for n in names]))
    vel.sort(key=lambda m: m[0])
    return np.array([v for _, v in vel]) if vel else None


def camera_info_topic(image_topic: str) -> str:
    """The image topic's sibling ``camera_info``: ``/camera/image_raw`` ->
    ``/camera/camera_info`` (``image`` -> ``camera_info`` at the top level)."""
    head = image_topic.rsplit("/", 1)[0] if "/" in image_topic else ""
    return f"{head}/camera_info" if head or image_topic.startswith("/") else "camera_info"


def _bag_intrinsics(reader: Any, path: str, topic: str, explicit: bool) -> Intrinsics | None:
    """The intrinsics of the ``CameraInfo`` messages on ``topic`` (module docstring), None
    when the bag has no such topic (refused if ``explicit``) or its ``K`` is all zero."""
    topics = {c.topic: c.msgtype for c in reader.connections}
    if topic not in topics:
        if explicit:
            raise MeasurementFileError(f"--camera-info-topic: no topic {topic!r} (topics: "
                                       f"{', '.join(sorted(topics))})", source=path)
        return None
    if topics[topic].replace("/msg/", "/") != "sensor_msgs/CameraInfo":
        raise MeasurementFileError(f"camera info topic {topic}: its messages are "
                                   f"{topics[topic]}, expected sensor_msgs/msg/CameraInfo",
                                   source=path)
    seen: list[tuple[tuple[float, ...], tuple[float, ...], str]] = []
    conns = [c for c in reader.connections if c.topic == topic]
    for conn, _, raw in reader.messages(connections=conns):
        msg: Any = reader.deserialize(raw, conn.msgtype)
        k = tuple(float(v) for v in getattr(msg, "k", getattr(msg, "K", ())))
        d = tuple(float(v) for v in getattr(msg, "d", getattr(msg, "D", ())))
        seen.append((k, d, str(msg.distortion_model)))
        if seen[-1] != seen[0]:
            i = next(j for j in range(3) if seen[-1][j] != seen[0][j])
            what = ("K", "D", "distortion_model")[i]
            raise MeasurementFileError(
                f"camera info topic {topic}: message {len(seen) - 1} has another {what} than "
                f"message 0 ({_show(seen[-1][i])} against {_show(seen[0][i])}); give the "
                "intrinsics with --intrinsics", source=path)
    if not seen or not any(seen[0][0]):
        return None
    where = f"{path}: camera info topic {topic}"
    k, d, model = seen[0]
    intr = intrinsics_from(k, d, where, distortion_model_named(model, where))
    return replace(intr, source=f"from the bag's {topic} ({len(seen)} messages)")


def _show(v: tuple[float, ...] | str) -> str:
    return repr(v) if isinstance(v, str) else " ".join(f"{x:.6g}" for x in v)


def _images(reader: Any, path: str, image_topic: str, board: Board, s: Any,
            jv: Array | None, opt: ImageBagOptions, min_corners: int,
            min_sharpness: float) -> ImageSet:
    """One image message at a time (none kept in memory): its stamp, the joint values
    there, the grey image and the board's corners, or why it is dropped."""
    from kincal.measure.bags import _stamp

    cv2 = require_opencv()
    topics = {c.topic: c.msgtype for c in reader.connections}
    if image_topic not in topics:
        raise MeasurementFileError(f"--image-topic: no topic {image_topic!r} (topics: "
                                   f"{', '.join(sorted(topics))})", source=path)
    if topics[image_topic].replace("/msg/", "/") not in [t.replace("/msg/", "/")
                                                         for t in _IMAGE_TYPES]:
        raise MeasurementFileError(f"--image-topic {image_topic}: its messages are "
                                   f"{topics[image_topic]}, expected "
                                   f"{' or '.join(_IMAGE_TYPES)}", source=path)
    out = ImageSet([], [], (0, 0))
    conns = [c for c in reader.connections if c.topic == image_topic]
    for k, (conn, t_ns, raw) in enumerate(reader.messages(connections=conns)):
        msg: Any = reader.deserialize(raw, conn.msgtype)
        compressed = "Compressed" in conn.msgtype
        if not compressed and str(msg.encoding) not in ENCODINGS:
            raise MeasurementFileError(f"--image-topic {image_topic}, message {k}: image "
                                       f"encoding {str(msg.encoding)!r} is not read (use "
                                       f"{', '.join(ENCODINGS)})", source=path)
        t = _stamp(msg, t_ns)
        label = f"{k:04d}@{t:.3f}"
        q, why = joints_at(t, s.joint_t, s.joint_q, opt, jv)
        if why is not None:
            out.dropped.append((label, why))
            continue
        gray = _gray(cv2, msg, compressed, f"{image_topic} message {k}", path)
        if gray is None:
            out.dropped.append((label, f"cannot be decoded ({msg.format})"))
            continue
        add_detection(cv2, out, label, gray, q, board, min_corners, min_sharpness)
    if not out.detections and not out.dropped:
        raise MeasurementFileError(f"--image-topic {image_topic}: no images", source=path)
    return out


def read_image_bag(path: str | Path, board: Board, image_topic: str,
                   joint_topic: str = "/joint_states", opt: ImageBagOptions = ImageBagOptions(),
                   joint_names: Sequence[str] | None = None, min_corners: int = 6,
                   min_sharpness: float = MIN_SHARPNESS,
                   info_topic: str | None = None) -> ImageSet:
    """Detect ``board`` in every image of ``image_topic`` and give each the joint values
    at its time (module docstring); errors name the bag and the topic or encoding.  The
    joint positions come from :func:`~kincal.measure.bags.read_bag_streams`; the bag is
    then read twice more, for the joint velocities and for the images one at a time; the
    intrinsics come from ``info_topic`` (default :func:`camera_info_topic`) if the bag
    has it (``""``: not read)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from kincal.measure.bags import _short

    src = str(path)
    require_opencv()
    s = read_bag_streams(src, joint_topic, joint_names=joint_names)
    try:
        reader = AnyReader([Path(src)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:                            # noqa: BLE001 - rosbags' own errors
        raise MeasurementFileError(f"not a readable ROS bag ({_short(exc)})",
                                   source=src) from None
    try:
        jv = _velocities(reader, joint_topic, s.joint_names)
        if jv is not None and len(jv) != len(s.joint_t):
            jv = None
        out = _images(reader, src, image_topic, board, s, jv, opt, min_corners,
                      min_sharpness)
        if info_topic != "":
            out.intrinsics = _bag_intrinsics(reader, src, info_topic or
                                             camera_info_topic(image_topic),
                                             info_topic is not None)
    except KincalError:
        raise
    except Exception as exc:                            # noqa: BLE001 - a damaged chunk
        raise MeasurementFileError(f"damaged ROS bag: reading its images failed "
                                   f"({_short(exc)})", source=src) from None
    finally:
        reader.close()
    out.notes.append(f"{len(out.detections) + len(out.dropped)} images on {image_topic}, "
                     f"joint states on {joint_topic} ({', '.join(s.joint_names)})")
    return out
