"""The configuration of robots without a closed-form IK (7-axis arms, wrist offsets, ETS
chains): the corrected joints must continue the nominal ones.

:func:`kincal.compensation.configuration.continuation_problems` walks the straight joint
path from the nominal to the corrected joints: the flange must stay near the target and the
Jacobian's signature (det J, or the signed maximal minors of a 7-column J) must keep its
sign.  Independent checks: the null space of J from numpy's SVD, the iiwa's wrist flip
``(A5 + pi, -A6, A7 + pi)`` (same flange pose: Rz Ry Rz Euler angles), finite-difference
Jacobians, and the YuMi's calibrated arm whose exact solution is the nominal joints minus
the zero shifts.
"""

from __future__ import annotations

import math

import numpy as np

from kincal.compensation.configuration import continuation_problems, jacobian_signature
from kincal.compensation.filter import TargetRequest, filter_targets
from kincal.robots.files import load_serial_robot

IIWA_Q = np.array([0.3, 0.8, -0.4, -1.2, -1.5, 0.9, -1.4])
#: YuMi right arm, model order (rax_1, rax_2, eax_a, rax_3 ... rax_6); axis 7 prescribed.
YUMI_FREE = np.array([1, 1, 0, 1, 1, 1, 1], bool)


def test_signature_of_seven_columns_spans_the_null_space():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(5, 6, 7))
    c = jacobian_signature(J)
    for Ji, ci in zip(J, c, strict=True):
        null = np.linalg.svd(Ji)[2][-1]             # numpy's null vector of J
        assert abs(abs(ci @ null) / np.linalg.norm(ci) - 1) < 1e-12
        assert np.linalg.norm(Ji @ ci) < 1e-12 * np.linalg.norm(ci)
    np.testing.assert_allclose(jacobian_signature(J[:, :, :6])[:, 0],
                               np.linalg.det(J[:, :, :6]), rtol=1e-12)


def test_iiwa_wrist_flip_is_another_branch_a_small_step_is_not():
    robot = load_serial_robot("lbr_iiwa7")
    flip = IIWA_Q + np.array([0, 0, 0, 0, math.pi, 0, math.pi])
    flip[5] = -IIWA_Q[5]
    np.testing.assert_allclose(robot.fk(flip), robot.fk(IIWA_Q), atol=1e-12)   # same pose
    words = continuation_problems(robot, IIWA_Q[None], flip[None])[0]
    assert words.startswith("configuration changed: the corrected joints are on another branch")
    # A calibration-sized correction (0.05 deg per joint) continues the branch.
    step = np.radians(0.05) * np.array([1, -1, 1, 1, -1, 1, -1])
    assert continuation_problems(robot, IIWA_Q[None], (IIWA_Q + step)[None]) == [""]


def _fd_det(robot, q: np.ndarray) -> float:
    """det of the finite-difference Jacobian (position; rotation from R(q+h) R(q-h)^T) of
    the free columns."""
    cols = []
    for j in np.flatnonzero(YUMI_FREE):
        h = np.zeros(7)
        h[j] = 1e-6
        Tp, Tm = robot.fk(q + h), robot.fk(q - h)
        W = Tp[:3, :3] @ Tm[:3, :3].T
        w = np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]]) / 2
        cols.append(np.concatenate([(Tp[:3, 3] - Tm[:3, 3]) / 2e-6, w / 2e-6]))
    return float(np.linalg.det(np.array(cols).T))


def test_yumi_correction_across_the_wrist_singularity_is_refused():
    nominal = load_serial_robot("yumi_r")
    # The calibration turns axis 5's zero by 0.6 deg: the exact corrected joints of a target
    # taught at axis 5 = +0.3 deg are at -0.3 deg, across the wrist singularity (axis 5 = 0,
    # where axes 4 and 6 align).
    d = math.radians(0.6)
    cal = nominal.with_params({"rax_5.offset": nominal.params()["rax_5.offset"] + d})
    near = np.radians([10, -100, -110, 20, 30, 0.3, 10])
    far = np.radians([10, -100, -110, 20, 30, 40.0, 10])
    crossed = near - np.array([0, 0, 0, 0, 0, d, 0])
    assert _fd_det(nominal, near) * _fd_det(nominal, crossed) < 0          # independent
    np.testing.assert_allclose(cal.fk(crossed), nominal.fk(near), atol=1e-12)
    fixed = np.where(YUMI_FREE, np.nan, near)
    req = [TargetRequest("pose", flange=nominal.fk(q), seed=q, fixed=fixed, config=None)
           for q in (near, far)]
    res = filter_targets(cal, nominal, req)
    assert not res.ok[0] and not res.changed[0]
    assert res.reason[0].startswith("configuration changed: the corrected joints lie across "
                                    "a singularity")
    np.testing.assert_array_equal(res.flange[0], req[0].flange)            # not rewritten
    # Far from it the same correction is made: the real arm at the nominal controller's
    # joints for the filtered pose reaches the target, axis 7 kept.
    assert res.ok[1] and res.changed[1]
    q = res.joints[1]
    assert q[2] == far[2]
    np.testing.assert_allclose(cal.fk(q), req[1].flange, atol=1e-10)
    np.testing.assert_allclose(q, far - np.array([0, 0, 0, 0, 0, d, 0]), atol=1e-9)


def test_iiwa_correction_through_the_stretched_elbow_is_refused():
    # The iiwa's elbow (A4) at 0.11 deg from stretched; the calibration moves A4's zero by
    # 0.57 deg, so the exact corrected joints have A4 on the other side of the stretched
    # arm, where the 6 x 7 Jacobian (nearly: the URDF's 0.44 mm offsets) loses rank.  The
    # numerical IK (no closed form) follows it; the filter refuses the target.
    robot = load_serial_robot("lbr_iiwa7")
    q = np.array([0.2, 0.5, 0.1, 0.002, 0.3, -0.6, 0.1])
    cal = robot.with_params({"A4.offset": robot.params()["A4.offset"] - 0.01})
    req = TargetRequest("pose", flange=robot.fk(q), seed=q)
    res = filter_targets(cal, robot, [req])
    np.testing.assert_allclose(cal.fk(res.joints[0]), req.flange, atol=1e-9)
    # Independently: the smallest singular value (numpy's SVD) along the joint path dips
    # to nearly zero between the two ends.
    path = q + np.linspace(0, 1, 201)[:, None] * (res.joints[0] - q)
    s6 = np.linalg.svd(robot.jacobian(path), compute_uv=False)[:, 5]
    assert s6.min() < 0.05 * min(s6[0], s6[-1])
    assert not res.ok[0] and not res.changed[0]
    assert res.reason[0].startswith("configuration changed: the corrected joints lie across")
    # 3 deg from stretched the same correction keeps the side and is made.
    q[3] = np.radians(3.0)
    res = filter_targets(cal, robot, [TargetRequest("pose", flange=robot.fk(q), seed=q)])
    assert res.ok[0] and res.changed[0] and res.joints[0][3] > 0
