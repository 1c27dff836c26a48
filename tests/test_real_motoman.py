"""Real data: Yaskawa Motoman dual-arm robot (right arm) measured by a Leica laser tracker.

5-fold cross-validation on the right-arm 6x6x6 grid: each fold is fitted on the other
four folds and evaluated on its own poses with the training frames (no refit).  The
repeatability sets (poses revisited) give the floor no kinematic model can beat.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

from kincal.identify.validation import cross_validate
from kincal.measure.instruments.position import PositionMeasurement
from kincal.robots.dh import DHLink, from_dh

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "motoman_leica"

pytestmark = pytest.mark.skipif(not DATA.is_dir(),
                                reason=f"real Motoman data not found at {DATA}")


def motoman_right():
    """The nominal right arm (E, S, L, U, R, B, T) with the reflector link as tool frame."""
    cfg = yaml.safe_load((DATA / "nominal_dh.yaml").read_text())["right_arm"]
    links = [DHLink(a=a, d=d, alpha=al, theta_offset=th, name=n)
             for (a, d, al, th), n in zip(cfg["links"], cfg["joints"], strict=True)]
    a, d, al, th = cfg["reflector"]          # Rz(th) Tz(d) Tx(a) Rx(al), fixed
    tool = [a * np.cos(th), a * np.sin(th), d, th, 0.0, al]      # x y z rz ry rx
    return from_dh(links, name="motoman_right", tool=tool), cfg["joints"]


def block(name, joints):
    with open(DATA / name, newline="") as f:
        rows = list(csv.DictReader(f))
    q = np.array([[float(r[f"{j}_rad"]) for j in joints] for r in rows])
    y = np.array([[float(r[c]) for c in ("x_m", "y_m", "z_m")] for r in rows])
    s = np.array([float(r["sigma_m"]) for r in rows])
    return PositionMeasurement(q, y, s, name="leica")


def test_motoman_cross_validation():
    robot, joints = motoman_right()
    grid = block("right_arm_grid_6x6x6.csv", joints)
    floors = {}
    for f in ("right_arm_repeatability_table1.csv", "right_arm_repeatability_wall1.csv"):
        y = block(f, joints).positions
        floors[f] = float(np.sqrt(np.mean(np.sum((y - y.mean(0)) ** 2, axis=1))))
    frame = ["leica.x", "leica.y", "leica.z", "leica.rz", "leica.ry", "leica.rx"]
    marker0 = {"leica.marker.x": 0.0, "leica.marker.y": 0.0, "leica.marker.z": 0.0}
    # nominal model (reflector link from the table) + tracker frame registration
    nominal = cross_validate(robot, grid, 5, np.random.default_rng(0), free=frame,
                             initial=marker0)
    # nominal model + registration of the frame and the reflector point (9 parameters)
    registered = cross_validate(robot, grid, 5, np.random.default_rng(0), free=["leica.*"])
    # the reflector point and the tracker frame are only weakly separated by this grid
    # (the hand barely turns): Levenberg-Marquardt needs ~100 iterations along that valley
    calibrated = cross_validate(robot, grid, 5, np.random.default_rng(0), max_iter=400)
    n, g, c = (x["rms_position_m"] * 1e3 for x in (nominal, registered, calibrated))
    est = calibrated["results"][0]
    msg = (f"Motoman right arm, 5-fold CV RMS: nominal + tracker registration {n:.4f} mm, "
           f"nominal + tracker and reflector registration {g:.4f} mm, calibrated "
           f"({len(est.estimated)} parameters) {c:.4f} mm; gain {n / c:.1f}x / {g / c:.1f}x; "
           "repeatability floor " + ", ".join(f"{k.split('_')[-1][:-4]} {v * 1e3:.4f} mm"
                                              for k, v in floors.items()))
    print("\n" + msg)
    assert all(r.converged for r in calibrated["results"]), msg
    assert n >= 4 * c, msg
    assert g >= 3 * c, msg
    assert c > min(floors.values()), msg        # nothing beats repeatability
