"""Real data: PAL TIAGo measured by Qualisys motion capture (FIGAROH's held-out protocol).

Protocol (data README): calibrate on the training session only; the motion-capture
frame (6) and the marker point in ``wrist_ft_tool_link`` (3) are estimated with the
robot parameters; RMS of the 3-D position error norm on the training file and on the
validation file, the latter with the frames and parameters from training (no refit).
FIGAROH publishes (mm, train / validation): registration only 3.37 / 4.87; joint
offsets 2.88 / 4.23; full joint placements 1.64 / 3.07.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from kincal.identify.solver import calibrate
from kincal.identify.validation import validate
from kincal.measure.models import PositionMeasurement

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "tiago_mocap"

pytestmark = pytest.mark.skipif(not DATA.is_dir(),
                                reason=f"real TIAGo data not found at {DATA}")


def tiago():
    from kincal.robots.urdf import load_urdf

    return load_urdf(DATA / "tiago_48_schunk.urdf", tip_link="wrist_ft_tool_link")


def session(robot, name):
    """Marker 1 (x1, y1, z1 [m]) and the joint readings (torso [m], arm [rad])."""
    with open(DATA / name, newline="") as f:
        rows = list(csv.DictReader(f))
    q = np.array([[float(r[j]) for j in robot.joint_names] for r in rows])
    y = np.array([[float(r[c]) for c in ("x1", "y1", "z1")] for r in rows])
    return PositionMeasurement(q, y, sigma=1e-3, name="mocap")


@pytest.fixture(scope="module")
def data():
    robot = tiago()
    return (robot, session(robot, "train_2021-11-30.csv"),
            session(robot, "validation_2021-11-26.csv"))


def rms_mm(result, block):
    train = np.sqrt(np.mean(result.errors()["mocap"]["position_m"] ** 2)) * 1e3
    val = validate(result.robot, [block], extras=result.extras())
    return train, val["overall"]["rms_position_m"] * 1e3


def test_registration_only_reproduces_figaroh(data):
    robot, train, val = data
    res = calibrate(robot, [train], free=["mocap.*"])        # no user guess anywhere
    assert res.converged and len(res.estimated) == 9
    t, v = rms_mm(res, val)
    print(f"\nTIAGo registration only (9): train {t:.3f} mm, validation {v:.3f} mm "
          "(FIGAROH 3.37 / 4.87)")
    assert t == pytest.approx(3.37, abs=0.02), f"train RMS {t:.4f} mm vs FIGAROH 3.37"
    assert v == pytest.approx(4.87, abs=0.02), f"validation RMS {v:.4f} mm vs FIGAROH 4.87"


def test_joint_offsets_reproduce_figaroh(data):
    robot, train, val = data
    res = calibrate(robot, [train], free=["*.offset", "mocap.*"])
    t, v = rms_mm(res, val)
    print(f"\nTIAGo joint offsets ({len(res.estimated)}): train {t:.3f} mm, validation "
          f"{v:.3f} mm (FIGAROH 14: 2.88 / 4.23)")
    assert len(res.estimated) == 14
    # the torso and arm_1 offsets cannot be told from the mocap frame, arm_7's from the marker
    dep = res.identifiability.dependent
    assert {"torso_lift_joint.offset", "arm_1_joint.offset", "arm_7_joint.offset"} <= set(dep)
    assert t == pytest.approx(2.88, abs=0.02) and v == pytest.approx(4.23, abs=0.02)


def test_full_automatic_calibration(data):
    robot, train, val = data
    reg = calibrate(robot, [train], free=["mocap.*"])
    res = calibrate(robot, [train])                        # automatic parameter selection
    t, v = rms_mm(res, val)
    t0, v0 = rms_mm(reg, val)
    msg = (f"TIAGo full automatic ({len(res.estimated)} of {len(res.names)} parameters): "
           f"train {t:.3f} mm, validation {v:.3f} mm (FIGAROH full 31: 1.64 / 3.07); "
           f"registration only {t0:.3f} / {v0:.3f} mm")
    print("\n" + msg)
    assert res.converged, res.message
    assert np.all(np.isfinite(res.std))
    assert t < 0.55 * t0, msg             # the geometric model explains half the error
    assert v < v0, msg                    # and generalises to another day
    if v >= 3.07:
        pytest.xfail("validation RMS above FIGAROH's 3.07 mm: " + msg + ". The converged "
                     "least-squares optimum of the full geometric model over-fits the 37 "
                     "training postures (the URDF rpy origins at pitch = -pi/2 also hide two "
                     "directions); see the issue report")
