"""Hand-eye from a simulated camera on a simulated robot: known truth, no OpenCV.

The truth: a Panda whose joint offsets differ from nominal, a camera at a known pose in
the flange frame (about where the Franka set's camera is), a ChArUco 5 x 7 board (34 mm
squares) 0.4 m in front of it.  Pixels are the exact pinhole projection plus Gaussian
noise; everything is recovered from them.
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import IdentifiabilityError
from kincal.identify.hand_eye import check_rotations, hand_eye
from kincal.identify.hand_eye_fit import fit_hand_camera, split_images
from kincal.measure.camera_board import Board, board_pose
from kincal.measure.instruments.camera import HandCameraMeasurement
from kincal.robots.files import load_serial_robot
from kincal.spatial import exp_so3, inverse, log_so3, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
K = (634.0, 633.0, 642.0, 359.0)
SIZE = (1280, 720)
Q0 = np.array([-0.22, -0.19, 0.0, -2.42, 0.28, 2.15, 0.31])     # the Franka set's pose_01
X_TRUE = matrix_from_frame([0.040, -0.030, 0.065, 0.80, 0.01, -0.05])   # camera in flange


def _project(T_cam: np.ndarray, Z: np.ndarray, pts: np.ndarray) -> np.ndarray:
    x = (inverse(T_cam) @ Z @ np.column_stack([pts, np.ones(len(pts))]).T).T[:, :3]
    return np.column_stack([K[0] * x[:, 0] / x[:, 2] + K[2], K[1] * x[:, 1] / x[:, 2] + K[3],
                            x[:, 2]])


def simulate(robot, n_images: int, noise: float, rng: np.random.Generator,
             spread: float = 0.25, only_joint: int | None = None, joint_error: float = 0.0):
    """Rows of a hand camera: poses around Q0 that see every corner of the board.
    ``joint_error`` [rad]: the image is taken at joint values off the recorded ones by
    that standard deviation per joint and image (an error no robot parameter explains)."""
    pts = BOARD.corner_points(np.arange(BOARD.num_corners))
    cam0 = robot.fk(Q0) @ X_TRUE
    Z = cam0 @ matrix_from_frame([-0.07, -0.10, 0.40, 0.3, 0.1, -0.1])   # board in base
    q, s, uv, labels = [], [], [], []
    while len(labels) < n_images * len(pts):
        dq = rng.uniform(-spread, spread, 7)
        if only_joint is not None:
            dq = np.where(np.arange(7) == only_joint, dq * 3, 0.0)
        qi = Q0 + dq
        p = _project(robot.fk(qi + rng.normal(0.0, joint_error, 7)) @ X_TRUE, Z, pts)
        if np.any(p[:, 2] < 0.1) or np.any(p[:, 0] < 0) or np.any(p[:, 0] > SIZE[0]) \
                or np.any(p[:, 1] < 0) or np.any(p[:, 1] > SIZE[1]):
            continue
        k = len(labels) // len(pts)
        q.append(np.tile(qi, (len(pts), 1)))
        s.append(pts)
        uv.append(p[:, :2] + rng.normal(0.0, noise, (len(pts), 2)))
        labels += [f"img_{k:02d}"] * len(pts)
    block = HandCameraMeasurement("camera", np.vstack(q), np.vstack(s), np.vstack(uv),
                                  max(noise, 0.1), K)
    return block, labels, Z


def _rot_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(log_so3(A[:3, :3] @ B[:3, :3].T))))


def test_board_pose_from_exact_pixels_is_the_truth() -> None:
    pts = BOARD.corner_points(np.arange(24))
    T = matrix_from_frame([-0.05, 0.02, 0.45, 1.2, 0.3, np.pi - 0.4])   # looks down at it
    uv = _project(T, np.eye(4), pts)[:, :2]
    # the camera at T sees the board at the origin: the board in the camera frame is T^-1
    found, rms = board_pose(pts, uv, K)
    assert np.abs(found - inverse(T)).max() < 1e-9 and rms < 1e-8


def test_closed_form_is_exact_without_noise_and_does_not_depend_on_order() -> None:
    rng = np.random.default_rng(3)
    robot = load_serial_robot("panda")
    block, labels, Z = simulate(robot, 10, 0.0, rng)
    lab = np.array(labels)
    names = sorted(set(labels))
    first = [int(np.flatnonzero(lab == n)[0]) for n in names]
    A = robot.fk(block.q[first])
    B = np.array([board_pose(block.s[lab == n], block.obs[lab == n], K)[0] for n in names])
    he = hand_eye(A, B)
    assert np.abs(he.X - X_TRUE).max() < 1e-8 and np.abs(he.Z - Z).max() < 1e-8
    for seed in range(3):
        p = np.random.default_rng(seed).permutation(len(A))
        shuffled = hand_eye(A[p], B[p])
        assert np.abs(shuffled.X - he.X).max() < 1e-9
        assert np.abs(shuffled.Z - he.Z).max() < 1e-9


def test_eye_to_hand_closed_form() -> None:
    rng = np.random.default_rng(5)
    camera = matrix_from_frame([1.5, 0.2, 0.8, 3.0, 0.2, -1.6])      # camera in the base
    board = matrix_from_frame([0.02, -0.05, 0.09, 0.3, 0.0, 0.1])    # board on the flange
    A = np.array([matrix_from_frame(np.r_[rng.uniform(-0.3, 0.3, 3) + [0.6, 0, 0.6],
                                          rng.uniform(-0.6, 0.6, 3)]) for _ in range(8)])
    B = inverse(camera) @ A @ board                                   # board in the camera
    he = hand_eye(A, B, mount="fixed")
    assert np.abs(he.X - camera).max() < 1e-9 and np.abs(he.Z - board).max() < 1e-9
    p = rng.permutation(8)
    assert np.abs(hand_eye(A[p], B[p], mount="fixed").X - he.X).max() < 1e-9


def test_fit_recovers_the_hand_eye_within_its_stated_error() -> None:
    """Monte Carlo over 8 noise draws: the error's mean square matches the stated one."""
    robot = load_serial_robot("panda")
    ratios_p, ratios_r = [], []
    for seed in range(8):
        rng = np.random.default_rng(100 + seed)
        block, labels, _ = simulate(robot, 12, 0.3, rng)
        fit = fit_hand_camera(robot, block, labels, holdout=0.25)
        ratios_p.append(np.linalg.norm(fit.X[:3, 3] - X_TRUE[:3, 3]) / fit.std_position)
        ratios_r.append(np.radians(_rot_deg(fit.X, X_TRUE)) / fit.std_rotation)
        # held-out pixels: the noise, sqrt(2) * 0.3 px per corner, plus a little
        assert 0.3 < fit.held_rms_px < 0.3 * np.sqrt(2) * 1.5
    # E|e|^2 = trace(Cov): the RMS ratio is 1 for an honest covariance (8 draws: +-35 %)
    assert 0.6 < np.sqrt(np.mean(np.square(ratios_p))) < 1.4
    assert 0.6 < np.sqrt(np.mean(np.square(ratios_r))) < 1.4


@pytest.mark.parametrize("free", [(), ("theta_offset*",)])
def test_expected_error_covers_an_unmodelled_joint_error(free) -> None:
    """Monte Carlo, 16 sets of 12 images: every image taken 0.1 deg per joint away from
    the joint values recorded (no parameter explains it).  The covariance, which takes
    the 24 corners of an image as 24 independent looks, is 4.7-5.4 times too optimistic;
    the stated expected error (covariance plus the unmodelled floor from the images'
    disagreement) matches the true error's RMS (measured 1.00-1.09 in position, 1.05 in
    rotation; 16 draws scatter by about +-25 %, so 1/1.5 to 1.5)."""
    robot = load_serial_robot("panda")
    e_p, e_r, cov_p, exp_p, exp_r = [], [], [], [], []
    for seed in range(16):
        block, labels, _ = simulate(robot, 12, 0.3, np.random.default_rng(500 + seed),
                                    joint_error=np.radians(0.1))
        fit = fit_hand_camera(robot, block, labels, holdout=0.0, free=free)
        e_p.append(np.linalg.norm(fit.X[:3, 3] - X_TRUE[:3, 3]))
        e_r.append(np.radians(_rot_deg(fit.X, X_TRUE)))
        cov_p.append(fit.std_position)
        exp_p.append(fit.expected_position)
        exp_r.append(fit.expected_rotation)
        assert fit.floor_position > fit.std_position        # the images say so
    def rms_ratio(e: list, s: list) -> float:
        return float(np.sqrt(np.mean(np.square(np.array(e) / np.array(s)))))
    assert rms_ratio(e_p, cov_p) > 3.0
    assert 1 / 1.5 < rms_ratio(e_p, exp_p) < 1.5
    assert 1 / 1.5 < rms_ratio(e_r, exp_r) < 1.5


def test_without_unmodelled_error_the_floor_is_small() -> None:
    """The model right (corner noise only): the expected error stays the covariance's to
    within the scatter of the image-clustered figure (measured: expected / covariance
    1.0-1.25 over 8 draws)."""
    robot = load_serial_robot("panda")
    ratios = []
    for seed in range(8):
        block, labels, _ = simulate(robot, 12, 0.3, np.random.default_rng(100 + seed))
        fit = fit_hand_camera(robot, block, labels, holdout=0.0)
        ratios.append(fit.expected_position / fit.std_position)
    assert 1.0 <= min(ratios) and np.sqrt(np.mean(np.square(ratios))) < 1.5


def test_fit_with_joint_offsets_recovers_robot_and_hand_eye() -> None:
    nominal = load_serial_robot("panda")
    offsets = {f"theta_offset[{k}]": v for k, v in
               zip(range(2, 7), [-0.009, -0.0126, -0.0064, 0.0126, -0.0085], strict=True)}
    true = nominal.with_params(offsets)
    rng = np.random.default_rng(11)
    block, labels, _ = simulate(true, 16, 0.3, rng, spread=0.35)
    plain = fit_hand_camera(nominal, block, labels, holdout=0.25)
    fit = fit_hand_camera(nominal, block, labels, holdout=0.25, free=["theta_offset*"])
    res = fit.result
    for name, value in offsets.items():
        k = res.names.index(name)
        assert abs(res.theta[k] - value) < 4 * res.std[k], name
    assert np.linalg.norm(fit.X[:3, 3] - X_TRUE[:3, 3]) < 4 * fit.std_position
    assert plain.held_rms_px > 3 * fit.held_rms_px      # the nominal robot cannot fit


def test_shuffled_rows_give_the_same_fit() -> None:
    robot = load_serial_robot("panda")
    block, labels, _ = simulate(robot, 10, 0.3, np.random.default_rng(7))
    p = np.random.default_rng(1).permutation(len(labels))
    shuffled = HandCameraMeasurement("camera", block.q[p], block.s[p], block.obs[p],
                                     block.sigma[p], K)
    a = fit_hand_camera(robot, block, labels)
    b = fit_hand_camera(robot, shuffled, [labels[i] for i in p])
    assert a.held_out == b.held_out
    assert np.abs(a.start.X - b.start.X).max() < 1e-9
    assert np.abs(a.X - b.X).max() < 1e-7          # the same iterations, rows reordered


def test_refuses_rotations_about_one_axis_naming_it() -> None:
    robot = load_serial_robot("panda")
    block, labels, _ = simulate(robot, 8, 0.3, np.random.default_rng(2), only_joint=6)
    with pytest.raises(IdentifiabilityError, match=r"about the flange's z axis.*need 5 deg"):
        fit_hand_camera(robot, block, labels, holdout=0.0)
    A = robot.fk(np.tile(Q0, (5, 1)) + np.r_[0, 0, 0, 0, 0, 0, 1.0] * np.linspace(
        0, 1, 5)[:, None])
    with pytest.raises(IdentifiabilityError, match="rotations too small"):
        check_rotations(A)


def test_split_images_depends_on_names_only() -> None:
    names = [f"p{k:02d}" for k in range(12)]
    train, held = split_images(names[::-1] * 3, 0.25)
    assert held == ["p02", "p06", "p10"] and len(train) == 9
    assert split_images(names, 0.0) == (names, [])


def test_exp_log_helpers_used_by_the_truth() -> None:
    # the truth's rotation is what matrix_from_frame says (guards the simulation itself)
    R = exp_so3(np.array([0.1, -0.2, 0.3]))
    assert np.allclose(log_so3(R), [0.1, -0.2, 0.3])


def _write(path, block, labels) -> None:
    from kincal.measure.camera_images import (
        Detection,
        ImageSet,
        Intrinsics,
        write_image_measurements,
    )

    lab = np.array(labels)
    dets = [Detection(n, np.arange(BOARD.num_corners), block.obs[lab == n],
                      block.q[np.flatnonzero(lab == n)[0]]) for n in sorted(set(labels))]
    write_image_measurements(path, ImageSet(dets, [], SIZE), BOARD, Intrinsics(*K), 0.3)


def test_cli_refuses_in_one_line_and_writes_the_robot(tmp_path, capsys) -> None:
    from cli_helpers import run

    robot = load_serial_robot("panda")
    block, labels, _ = simulate(robot, 8, 0.3, np.random.default_rng(2), only_joint=6)
    _write(tmp_path / "bad.csv", block, labels)
    code, out, err = run(capsys, "hand-eye", "panda", "--data", tmp_path / "bad.csv")
    assert code == 2 and err.count("\n") == 1 and "rotations too small" in err
    assert "flange's z axis" in err
    block, labels, _ = simulate(robot, 12, 0.3, np.random.default_rng(4))
    _write(tmp_path / "good.csv", block, labels)
    code, out, err = run(capsys, "hand-eye", "panda", "--data", tmp_path / "good.csv", "-o",
                         tmp_path / "cam.yaml")
    assert code == 0, err
    assert "expected error of the hand-eye" in out and "held out" in out
    tool = load_serial_robot(str(tmp_path / "cam.yaml")).frame_parameters("tool")
    flange = matrix_from_frame(robot.frame_parameters("tool"))
    assert np.linalg.norm((flange @ X_TRUE)[:3, 3] - matrix_from_frame(tool)[:3, 3]) < 2e-3


def test_eye_to_hand_leave_one_out_from_pixels() -> None:
    """A fixed camera watching a board on the flange: exact pixels give a zero held-out
    error and the true camera; 0.3 px noise gives held-out errors of that order."""
    from kincal.identify.hand_eye_fit import closed_form_leave_one_out

    rng = np.random.default_rng(8)
    camera = matrix_from_frame([0.0, 1.27, 0.28, -1.6, 0.1, -2.0])      # camera in the base
    board = matrix_from_frame([0.06, 0.12, 0.21, 0.5, 0.2, 0.3])        # board in the flange
    pts = BOARD.corner_points(np.arange(24))
    A, uv = [], []
    while len(A) < 9:
        face = camera @ matrix_from_frame(np.r_[rng.uniform(-0.1, 0.1, 2), 0.7,
                                                rng.uniform(-0.4, 0.4, 2), np.pi
                                                + rng.uniform(-0.4, 0.4)])  # board pose seen
        T = face @ inverse(board)                                         # the flange
        p = _project(camera, T @ board, pts)
        A.append(T)
        uv.append(p[:, :2])
    A = np.array(A)
    he, loo = closed_form_leave_one_out(A, [pts] * 9, uv, K, mount="fixed")
    assert np.abs(he.X - camera).max() < 1e-8 and loo.max() < 1e-6
    noisy = [u + rng.normal(0, 0.3, u.shape) for u in uv]
    he, loo = closed_form_leave_one_out(A, [pts] * 9, noisy, K, mount="fixed")
    assert 0.2 < np.sqrt(np.mean(loo**2)) < 3.0


def test_leave_one_out_spread_agrees_with_the_stated_error() -> None:
    """With the model right, the jackknife spread of the hand-eye over the leave-one-out
    fits estimates the same standard error as the covariance (12 images: the jackknife
    itself scatters by tens of percent; 0.9-2.2 times over four seeds)."""
    from kincal.identify.hand_eye_fit import leave_one_out

    robot = load_serial_robot("panda")
    block, labels, _ = simulate(robot, 12, 0.3, np.random.default_rng(200))
    lo = leave_one_out(robot, block, labels)
    fit = fit_hand_camera(robot, block, labels, holdout=0.0)
    assert 0.4 < lo.position_spread / fit.std_position < 3.0
    assert 0.4 < lo.rotation_spread / fit.std_rotation < 3.0
    assert len(lo.images) == 12 and 0.3 < np.sqrt(np.mean(lo.rms_px**2)) < 0.6


def test_robot_world_closed_form_exact_order_free_and_near_the_pairs() -> None:
    """``A X = Z B^-1`` solved for both at once (no pairs): exact without noise, eye-in-hand
    and eye-to-hand; a shuffle gives the same to 1e-9; with 0.3 px the two closed forms
    agree within a few millimetres."""
    from kincal.identify.hand_eye import robot_world

    rng = np.random.default_rng(3)
    robot = load_serial_robot("panda")
    block, labels, Z = simulate(robot, 10, 0.0, rng)
    lab = np.array(labels)
    names = sorted(set(labels))
    first = [int(np.flatnonzero(lab == n)[0]) for n in names]
    A = robot.fk(block.q[first])
    B = np.array([board_pose(block.s[lab == n], block.obs[lab == n], K)[0] for n in names])
    rw = robot_world(A, B)
    assert np.abs(rw.X - X_TRUE).max() < 1e-8 and np.abs(rw.Z - Z).max() < 1e-8
    p = rng.permutation(len(A))
    again = robot_world(A[p], B[p])
    assert np.abs(again.X - rw.X).max() < 1e-9 and np.abs(again.Z - rw.Z).max() < 1e-9
    camera = matrix_from_frame([1.5, 0.2, 0.8, 3.0, 0.2, -1.6])
    board = matrix_from_frame([0.02, -0.05, 0.09, 0.3, 0.0, 0.1])
    Af = np.array([matrix_from_frame(np.r_[rng.uniform(-0.3, 0.3, 3) + [0.6, 0, 0.6],
                                           rng.uniform(-0.6, 0.6, 3)]) for _ in range(8)])
    fixed = robot_world(Af, inverse(camera) @ Af @ board, mount="fixed")
    assert np.abs(fixed.X - camera).max() < 1e-9 and np.abs(fixed.Z - board).max() < 1e-9
    block, labels, _ = simulate(robot, 12, 0.3, np.random.default_rng(9))
    lab = np.array(labels)
    first = [int(np.flatnonzero(lab == n)[0]) for n in sorted(set(labels))]
    A = robot.fk(block.q[first])
    B = np.array([board_pose(block.s[lab == n], block.obs[lab == n], K)[0]
                  for n in sorted(set(labels))])
    assert np.linalg.norm(robot_world(A, B).X[:3, 3] - hand_eye(A, B).X[:3, 3]) < 5e-3
