"""One frame convention: a frame given as six numbers is ``(x, y, z, rz, ry, rx)`` with
``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` everywhere, and what goes in comes back out
in the same order."""

from __future__ import annotations

import numpy as np

import kincal
from kincal.measure.simulate import random_configurations
from kincal.spatial import (
    FRAME_FIELDS,
    frame_from_matrix,
    matrix_from_frame,
    rotx,
    roty,
    rotz,
)

#: A tracker frame with three distinct, clearly non-zero angles: swapping rz and rx
#: (the old roll-pitch-yaw order of ``instrument=``) would move it far out of tolerance.
TRACKER = (1.6, -0.7, 0.4, 0.9, -0.25, 0.35)


def test_matrix_from_frame_is_the_product_in_field_order():
    rng = np.random.default_rng(11)
    v = np.column_stack([rng.normal(size=(20, 3)), rng.uniform(-3, 3, (20, 3))])
    v[:, 4] = rng.uniform(-1.5, 1.5, 20)                       # ry inside (-pi/2, pi/2)
    for row in v:
        x, y, z, rz, ry, rx = row
        expected = np.eye(4)
        expected[:3, :3] = rotz(rz) @ roty(ry) @ rotx(rx)
        expected[:3, 3] = x, y, z
        np.testing.assert_allclose(matrix_from_frame(row), expected, atol=1e-15)
        np.testing.assert_allclose(frame_from_matrix(expected), row, atol=1e-12)
    # vectorised over leading axes: the same numbers as one frame at a time
    batch = matrix_from_frame(v.reshape(4, 5, 6))
    assert batch.shape == (4, 5, 4, 4)
    np.testing.assert_allclose(batch.reshape(20, 4, 4),
                               np.array([matrix_from_frame(r) for r in v]), atol=1e-15)
    np.testing.assert_allclose(frame_from_matrix(batch).reshape(20, 6), v, atol=1e-12)
    assert FRAME_FIELDS == ("x", "y", "z", "rz", "ry", "rx")


def test_simulated_instrument_frame_comes_back_from_a_calibration_in_the_same_order():
    rng = np.random.default_rng(5)
    nominal = kincal.load_robot("puma560")
    # the robot is the nominal one: every difference is in the tracker's frame (a
    # perturbed base or first-joint offset would be absorbed by it, indistinguishably)
    true = nominal
    q = random_configurations(true, 120, rng)
    block = kincal.simulate_positions(true, q, rng, 1e-5, instrument=TRACKER,
                                      markers=[0.02, -0.01, 0.08], name="tracker")
    result = kincal.calibrate(nominal, [block])
    names = [f"tracker.{f}" for f in FRAME_FIELDS]
    index = {n: k for k, n in enumerate(result.names)}
    estimated = np.array([result.theta[index[n]] for n in names])
    std = np.array([result.std[index[n]] for n in names])
    assert set(names) <= set(result.estimated)
    assert np.all(std > 0)
    np.testing.assert_array_less(np.abs(estimated - np.asarray(TRACKER)), 5 * std + 1e-9)
