"""One calibration session read from files: the robot, its training and held-out blocks.

``kincal calibrate`` and every robot session of ``kincal fleet calibrate`` read their
inputs through :func:`read_session`, so both calibrate exactly the same problem:

1. the robot (:func:`~kincal.workflow.robots.load_any_robot`);
2. the ``--units`` / ``--ignore`` check (:func:`~kincal.workflow.options.check_options_used`);
3. the measurement files (:func:`~kincal.workflow.flow.read_blocks`), training and held-out;
4. the non-geometric joint model around every block
   (:func:`~kincal.measure.joints.terms.with_joint_model`), with the link masses of a URDF
   for ``compliance`` (:func:`joint_masses`).

Then :func:`~kincal.workflow.flow.run_flow` calibrates.  Nothing here prints.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

from kincal.errors import KincalError

__all__ = ["Session", "read_session", "joint_masses", "available_masses"]


@dataclasses.dataclass
class Session:
    """The inputs of one calibration, read and checked.

    Attributes:
        robot: the nominal robot (serial :class:`~kincal.robots.chain.Robot`).
        blocks, holdouts: training and held-out measurement blocks (inside the joint
            model when ``terms`` is not empty).
        terms: the joint-model terms (``("hysteresis", "compliance")`` or fewer).
    """

    robot: Any
    blocks: list[Any]
    holdouts: list[Any]
    terms: tuple[str, ...]


def joint_masses(spec: str, base_link: str | None = None, tip_link: str | None = None
                 ) -> list[Any]:
    """Link masses of ROBOT for ``--joint-model compliance``: a URDF's ``<inertial>``
    elements on the chain ``base_link -> tip_link``, or the ``masses:`` section of a
    robot file or built-in robot (:mod:`kincal.robots.masses`); a one-line error
    otherwise."""
    from kincal.robots.urdf import load_urdf_inertials

    if not str(spec).lower().endswith(".urdf"):
        from kincal.robots.files import load_serial_robot
        from kincal.robots.masses import stated_masses

        stated = stated_masses(load_serial_robot(spec)) if spec else None
        if not stated:
            raise KincalError(f"--joint-model compliance needs the link masses: {spec!r} "
                              "states none (give a URDF with <inertial> elements or a robot "
                              "file with a masses: section)")
        return stated
    masses = load_urdf_inertials(spec, base_link=base_link, tip_link=tip_link)
    if not masses:
        raise KincalError(f"--joint-model compliance: {spec!r} has no <inertial> mass on the "
                          "chain", source=str(spec))
    return masses


def available_masses(spec: str | None, base_link: str | None = None,
                     tip_link: str | None = None) -> list[Any] | None:
    """The link masses of ROBOT when it states them (a URDF's ``<inertial>`` masses on
    the chain, a robot file's ``masses:``), else None (``--select auto`` then tries no
    compliance model)."""
    if not spec:
        return None
    try:
        return joint_masses(spec, base_link, tip_link)
    except KincalError:
        return None


def read_session(robot: str | Any, data: Sequence[Any], validate: Sequence[Any] = (), *,
                 units: str | None = None, ignore: Sequence[str] | None = None,
                 joint_model: str | None = None, spec: str | None = None,
                 base_link: str | None = None, tip_link: str | None = None) -> Session:
    """Load the robot and read the training and held-out files of one calibration.

    Args:
        robot: a built-in name, a YAML or URDF path, or an already loaded serial robot.
        spec: the loaded robot's name or path (for ``compliance``, the URDF's masses).
        data, validate: training and held-out measurement files (paths, or
            :class:`~kincal.workflow.sources.DataSource` with reading options of their
            own, e.g. from a setup file).
        units, ignore: ``--units`` / ``--ignore`` (each entry applies to the files whose
            columns it matches; one matching no file is an error).
        joint_model: ``--joint-model`` text (``"hysteresis,compliance"``).
        base_link, tip_link: URDF chain ends.

    Raises one-line :class:`~kincal.errors.KincalError` for any bad input.
    """
    from kincal.measure.joints.terms import parse_joint_model, with_joint_model
    from kincal.workflow.robots import load_any_robot
    from kincal.workflow.sources import DataSource, read_sources, sources_from_options

    if isinstance(robot, str):
        spec = robot
        robot = load_any_robot(robot, base_link=base_link, tip_link=tip_link)
    r = robot
    terms = parse_joint_model(joint_model)
    if "compliance" in terms and spec is None:
        raise KincalError("--joint-model compliance needs the robot's URDF file for the masses")
    masses = joint_masses(spec or "", base_link, tip_link) if "compliance" in terms else None
    paths = [str(f) for f in list(data) + list(validate) if not isinstance(f, DataSource)]
    converted = iter(sources_from_options(paths, units, ignore) if paths else [])

    def sources(files: Sequence[Any]) -> list[DataSource]:
        return [f if isinstance(f, DataSource) else next(converted) for f in files]

    train, held = sources(data), sources(validate)
    blocks = with_joint_model(read_sources(train, r), r, terms, masses)
    holdouts = with_joint_model(read_sources(held, r), r, terms, masses)
    return Session(r, blocks, holdouts, terms)
