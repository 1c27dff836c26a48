"""``kincal import images BAG --image-topic TOPIC``: the options of a bag of board images
turned into :func:`kincal.measure.camera_bags.read_image_bag`'s arguments."""

from __future__ import annotations

from typing import Any

from kincal.errors import KincalError
from kincal.measure.camera_bags import is_bag
from kincal.measure.camera_board import Board
from kincal.measure.camera_images import ImageSet

__all__ = ["bag_images", "is_bag"]


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
