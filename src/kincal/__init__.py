"""kincal: kinematic calibration of robot manipulators.

The names a notebook needs, importable from ``kincal`` (each is loaded on first use,
so ``import kincal`` stays cheap)::

    import kincal

    robot = kincal.load_robot("puma560")
    blocks = kincal.read_measurements("tracker.csv", robot)
    result = kincal.calibrate(robot, blocks, prior="tolerances")
    result                                   # a table in a notebook

Robots
    :func:`load_robot` (built-in name, YAML or URDF file; serial or five-bar),
    :func:`write_robot` (YAML), :func:`write_urdf`, :class:`Robot`, :class:`FiveBar`.
Measurements
    :func:`read_measurements` (any kincal CSV), :class:`PositionMeasurement`,
    :class:`PoseMeasurement`; simulated experiments: :func:`perturb_robot`,
    :func:`random_configurations`, :func:`simulate_positions`, :func:`simulate_poses`.
Calibration
    :func:`calibrate` / :class:`Calibration` -> :class:`CalibrationResult`;
    :func:`validate` and :func:`cross_validate` on held-out data;
    :func:`accuracy_model` and :func:`predict_accuracy`: the predicted error of the
    calibrated model where it is used, and where it is extrapolating (after
    calibrating; before measuring it is :func:`predict_plan_accuracy`);
    :func:`envelope_of` / :func:`predict_with_envelope`: the training region and
    accuracy model a calibrated robot file carries; :func:`validate_on_files`: what
    ``kincal validate`` does, warning outside the training region.
Putting it to use
    :func:`compensate` -> :class:`Compensation` (joint commands, filtered targets),
    :func:`solve_ik` -> :class:`IKSolutions`.
Planning
    :func:`plan_poses` -> :class:`Plan`: choose calibration poses and predict the
    accuracy before measuring; :func:`predict_plan_accuracy` -> the accuracy a pose
    design will give, from the design alone.
Set-ups
    :func:`load_setup`: a calibration set-up file (the same one ``kincal calibrate
    --config`` reads).
Errors
    :class:`KincalError`: every problem with the user's input, as one line.

Units are SI (m, rad) everywhere in the Python API; files and the command line say
their units.
"""

from __future__ import annotations

import importlib
from typing import Any

from kincal._version import __version__

#: public name -> (module, attribute)
_API: dict[str, tuple[str, str]] = {
    # robots
    "load_robot": ("kincal.workflow.robots", "load_any_robot"),
    "write_robot": ("kincal.robots.files", "write_robot_yaml"),
    "write_urdf": ("kincal.robots.urdf", "write_urdf"),
    "Robot": ("kincal.robots.chain", "Robot"),
    "FiveBar": ("kincal.parallel.fivebar", "FiveBar"),
    # measurements
    "read_measurements": ("kincal.measure.registry", "read_measurements"),
    "PositionMeasurement": ("kincal.measure.instruments.position", "PositionMeasurement"),
    "PoseMeasurement": ("kincal.measure.instruments.pose", "PoseMeasurement"),
    "perturb_robot": ("kincal.measure.simulate", "perturb_robot"),
    "random_configurations": ("kincal.measure.simulate", "random_configurations"),
    "simulate_positions": ("kincal.measure.instruments.position", "simulate_positions"),
    "simulate_poses": ("kincal.measure.instruments.pose", "simulate_poses"),
    # calibration
    "calibrate": ("kincal.identify.solver", "calibrate"),
    "Calibration": ("kincal.identify.solver", "Calibration"),
    "CalibrationResult": ("kincal.identify.solver", "CalibrationResult"),
    "validate": ("kincal.identify.validation", "validate"),
    "Validation": ("kincal.identify.validation", "Validation"),
    "cross_validate": ("kincal.identify.validation", "cross_validate"),
    "accuracy_model": ("kincal.identify.accuracy", "accuracy_model"),
    "predict_accuracy": ("kincal.identify.accuracy", "predict"),
    "envelope_of": ("kincal.identify.envelope", "envelope_of"),
    "predict_with_envelope": ("kincal.identify.envelope", "predict_with_envelope"),
    "validate_on_files": ("kincal.workflow.validation", "validate_on_files"),
    # using the calibration
    "compensate": ("kincal.compensation.compensate", "compensate"),
    "Compensation": ("kincal.compensation.compensate", "Compensation"),
    "solve_ik": ("kincal.motion.ik", "solve_ik"),
    "IKSolutions": ("kincal.motion.ik", "IKSolutions"),
    # planning
    "plan_poses": ("kincal.identify.plan", "plan_poses"),
    "predict_plan_accuracy": ("kincal.identify.prediction", "predict_accuracy"),
    "Plan": ("kincal.identify.plan", "Plan"),
    # set-ups
    "load_setup": ("kincal.workflow.config", "load_setup"),
    # errors
    "KincalError": ("kincal.errors", "KincalError"),
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    """Load a public name on first use (PEP 562) and keep it in the module."""
    try:
        module, attr = _API[name]
    except KeyError:
        raise AttributeError(f"module 'kincal' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))

