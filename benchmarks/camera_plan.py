"""Monte Carlo of a camera plan: the hand-eye error `kincal plan --camera` predicts is the
error a fit of captures at the planned poses makes, and the plan beats random poses that
also see the board.

A Panda with a camera on the flange (640 px focal length, 1280x720), a 5x7 ChArUco board
facing it (``--mount fixed``: the board on the flange, the camera fixed, fitted with
``calibrate_board_camera``, intrinsics held); ``--poses`` poses planned (O1) among 2000
candidates (+-30 deg around a working configuration) with the joint offsets designed
for.  ``--trials`` capture sets are simulated at the planned poses (exact pixels +
``--noise`` px), each fitted with ``kincal.identify.hand_eye_fit.fit_hand_camera`` (joint
offsets free); the RMS of the
hand-eye's position and rotation errors is compared with the plan's prediction (ratio 1
within about ``1 +- 1/sqrt(6 trials)``).  The same for ``--poses`` random visible poses.

    python benchmarks/camera_plan.py --trials 40 [--mount fixed]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kincal.identify.camera_plan import plan_camera_poses
from kincal.identify.hand_eye_fit import fit_hand_camera
from kincal.identify.hand_eye_lens import calibrate_board_camera
from kincal.measure.camera_board import Board
from kincal.measure.instruments.camera import HandCameraMeasurement
from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
K = (640.0, 641.0, 645.0, 355.0)
Q0 = np.radians([0.0, -17.0, 0.0, -115.0, 0.0, 103.0, 46.0])


def errors(robot, q, X, Z, trials, noise, rng, mount="hand"):
    pts = BOARD.corner_points(np.arange(BOARD.num_corners))
    uv = []
    for T in robot.fk(q):
        B = inverse(T @ X) @ Z if mount == "hand" else inverse(X) @ T @ Z
        x = pts @ B[:3, :3].T + B[:3, 3]
        uv.append(np.column_stack([K[0] * x[:, 0] / x[:, 2] + K[2],
                                   K[1] * x[:, 1] / x[:, 2] + K[3]]))
    uv = np.array(uv)
    labels = np.repeat([f"{k:02d}" for k in range(len(q))], len(pts))
    ep, er = [], []
    for _ in range(trials):
        if mount == "fixed":
            f = calibrate_board_camera(robot.fk(q), [pts] * len(q),
                                       list(uv + rng.normal(0.0, noise, uv.shape)),
                                       [f"{k:02d}" for k in range(len(q))],
                                       np.r_[K, np.zeros(5)], "fixed", 0.0, fit_lens=(),
                                       sigma=noise, min_rotation_deg=0.0, robot=robot, q=q,
                                       free=["theta_offset*"])
            ep.append(np.linalg.norm(f.X[:3, 3] - X[:3, 3]))
            R = f.X[:3, :3] @ X[:3, :3].T
            er.append(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
            continue
        b = HandCameraMeasurement("camera", np.repeat(q, len(pts), axis=0),
                                  np.tile(pts, (len(q), 1)),
                                  (uv + rng.normal(0.0, noise, uv.shape)).reshape(-1, 2),
                                  noise, K)
        f = fit_hand_camera(robot, b, labels, 0.0, ["theta_offset*"], 0.0)
        ep.append(np.linalg.norm(f.X[:3, 3] - X[:3, 3]))
        R = f.X[:3, :3] @ X[:3, :3].T
        er.append(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return np.sqrt(np.mean(np.square(ep))), np.sqrt(np.mean(np.square(er)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--poses", type=int, default=12)
    ap.add_argument("--noise", type=float, default=0.5)
    ap.add_argument("--mount", choices=("hand", "fixed"), default="hand")
    a = ap.parse_args()
    robot = load_serial_robot("panda")
    t0 = time.perf_counter()
    p = plan_camera_poses(robot, BOARD.corner_points(np.arange(BOARD.num_corners)), K,
                          (1280, 720), a.mount, a.poses, ["theta_offset*"], center=Q0,
                          X=matrix_from_frame([0.04, -0.03, 0.06, np.pi / 4, 0.0, 0.0])
                          if a.mount == "hand" else None, sigma=a.noise)
    print(f"plan: {a.poses} of {p.visible} visible candidates in "
          f"{time.perf_counter() - t0:.1f} s")
    rng = np.random.default_rng(7)
    mp, mr = errors(robot, p.q, p.X, p.Z, a.trials, a.noise, rng, a.mount)
    print(f"planned: predicted {p.std_position * 1e3:.3f} mm {np.degrees(p.std_rotation):.4f} "
          f"deg; Monte Carlo ({a.trials} sets) {mp * 1e3:.3f} mm {np.degrees(mr):.4f} deg; "
          f"ratio {mp / p.std_position:.2f} {mr / p.std_rotation:.2f}")
    rnd = rng.choice(p.design.problem.num_candidates, a.poses, replace=False)
    qr = p.design.problem.q[rnd]
    rp, rr = errors(robot, qr, p.X, p.Z, a.trials, a.noise, rng, a.mount)
    print(f"random visible ({a.poses}): Monte Carlo {rp * 1e3:.3f} mm {np.degrees(rr):.4f} deg "
          f"(median predicted over 20 random designs {p.median_random[0] * 1e3:.3f} mm "
          f"{np.degrees(p.median_random[1]):.4f} deg)")


if __name__ == "__main__":
    main()
