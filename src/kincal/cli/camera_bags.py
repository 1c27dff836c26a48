"""``kincal import images BAG --image-topic TOPIC``: the options of a bag of board images
turned into :func:`kincal.measure.camera_bags.read_image_bag`'s arguments."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from kincal.errors import KincalError
from kincal.measure.camera_bags import is_bag
from kincal.measure.camera_board import Board
from kincal.measure.camera_images import ImageSet

__all__ = ["BagTopics", "bag_images", "hand_eye_bag", "is_bag"]


@dataclass(frozen=True)
class BagTopics:
    """``kincal hand-eye --images BAG``'s topics: images, joint states, camera info."""

    image: str | None = None
    joint: str = "/joint_states"
    camera_info: str | None = None

    def wanted(self, images: str) -> bool:
        """Whether ``--images`` is read as a ROS bag."""
        return self.image is not None or is_bag(images)


def bag_images(bag: str, board: Board, image_topic: str | None, joint_topic: str,
               max_gap: str, max_speed: str, robot: Any, joints: str | None,
               min_corners: int, min_sharpness: float,
               info_topic: str | None = None) -> ImageSet:
    """``kincal import images BAG --image-topic T``: :mod:`kincal.measure.camera_bags`."""
    from kincal.cli.importers import _speed
    from kincal.measure.camera_bags import ImageBagOptions, read_image_bag
    from kincal.units import parse_quantity

    if image_topic is None:
        raise KincalError("a ROS bag: give the images' topic with --image-topic TOPIC",
                          source=bag)
    if joints is not None:
        raise KincalError("--joints: a bag's joint values come from --joint-topic")
    opt = ImageBagOptions(parse_quantity(max_gap, "time", "--max-gap", positive=True),
                          _speed(max_speed, "--max-speed"))
    return read_image_bag(bag, board, image_topic, joint_topic, opt,
                          list(robot.joint_names) if robot is not None else None,
                          min_corners, min_sharpness, info_topic)


def hand_eye_bag(images: str, board: Board, topics: BagTopics, robot: str | None,
                 joints: str | None, poses: str | None, intrinsics: str | None) -> ImageSet:
    """``kincal hand-eye ROBOT --images BAG --image-topic T``: the bag's detections with
    their joint values (default --max-gap and --max-speed), the intrinsics from its
    CameraInfo unless ``--intrinsics`` is given."""
    from kincal.cli.calibration_common import load, serial
    from kincal.measure.camera_images import MIN_SHARPNESS

    if joints is not None:
        raise KincalError("--joints: with a ROS bag the joint values come from the bag "
                          "(--joint-topic)")
    if poses is not None:
        raise KincalError("--poses: with a ROS bag the flange poses come from ROBOT and the "
                          "bag's joint states")
    if robot is None:
        raise KincalError("ROBOT: the robot whose joint states the bag holds is missing")
    if intrinsics and topics.camera_info:
        raise KincalError("--intrinsics and --camera-info-topic: give one of them")
    r = serial(load(robot), "hand-eye")
    return bag_images(images, board, topics.image, topics.joint, "20ms", "0.01rad/s", r, None,
                      6, MIN_SHARPNESS, "" if intrinsics else topics.camera_info)
