"""Monte Carlo: robot parameters from a fixed camera (eye-to-hand) are recovered within
their stated standard errors.

A Panda with joint offsets of 0.4-0.7 deg and 1 mm link errors (a[4], d[5]) carries a
5x7 ChArUco board on its flange; a fixed camera 0.6 m away (640 px focal length,
1280x720) takes ``--images`` images at random poses around a working configuration
(+-0.35 rad per joint) that see the whole board; pixel noise ``--noise`` px.  Every set
is calibrated with ``kincal.identify.hand_eye_lens.calibrate_board_camera`` (mount
fixed, ``free = theta_offset*, a[4], d[5]``, the pinhole intrinsics fitted) and the
ratio ``(estimate - truth) / stated standard error`` is collected per parameter.
An honest standard error gives an RMS ratio of 1 (within ``1 +- 1/sqrt(2 trials)``).

    python benchmarks/camera_fixed_free.py --trials 50
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kincal.identify.hand_eye_lens import calibrate_board_camera, project_lens
from kincal.measure.camera_board import Board
from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
LENS = np.array([640.0, 641.0, 645.0, 355.0, 0.0, 0.0, 0.0, 0.0, 0.0])
SIZE = np.array([1280.0, 720.0])
Q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
TRUTH = {"theta_offset[2]": -0.009, "theta_offset[3]": -0.0126, "theta_offset[4]": -0.0064,
         "theta_offset[5]": 0.0126, "theta_offset[6]": -0.0085, "a[4]": 0.001,
         "d[5]": -0.0012}


def one_set(rng: np.random.Generator, n: int, noise: float) -> dict[str, float]:
    nominal = load_serial_robot("panda")
    true = nominal.with_params(TRUTH)
    board = matrix_from_frame([0.0, 0.0, 0.05, 0.0, 0.0, np.pi])
    camera = true.fk(Q0) @ board @ matrix_from_frame([0.07, 0.1, 0.6, 0.3, np.pi, 0.0])
    pts = BOARD.corner_points(np.arange(BOARD.num_corners))
    q, uv = [], []
    while len(q) < n:
        qi = Q0 + rng.uniform(-0.35, 0.35, 7)
        B = inverse(camera) @ true.fk(qi) @ board
        x = pts @ B[:3, :3].T + B[:3, 3]
        p = project_lens(x, LENS)
        if np.all(x[:, 2] > 0.1) and np.all((p > 5) & (p < SIZE - 5)):
            q.append(qi)
            uv.append(p + rng.normal(0.0, noise, p.shape))
    Q = np.array(q)
    fit = calibrate_board_camera(nominal.fk(Q), [pts] * n, uv, [f"{k:02d}" for k in range(n)],
                                 LENS, "fixed", 0.0, fit_lens=("fx", "fy", "cx", "cy"),
                                 sigma=noise, robot=nominal, q=Q, free=list(TRUTH) + [
                                     "theta_offset[1]", "theta_offset[7]"])
    return {k: (v - TRUTH[k]) / s for k, (v, s) in fit.robot.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--images", type=int, default=16)
    ap.add_argument("--noise", type=float, default=0.3)
    a = ap.parse_args()
    t0 = time.perf_counter()
    z: dict[str, list[float]] = {}
    for k in range(a.trials):
        for n, v in one_set(np.random.default_rng(1000 + k), a.images, a.noise).items():
            z.setdefault(n, []).append(v)
    print(f"{a.trials} sets of {a.images} images, {a.noise} px, "
          f"{(time.perf_counter() - t0) / a.trials:.2f} s per set")
    print("parameter         RMS (error / stated std)   mean")
    for n, v in z.items():
        print(f"{n:17s} {np.sqrt(np.mean(np.square(v))):8.2f} {np.mean(v):22.2f}")
    allz = np.concatenate([np.asarray(v) for v in z.values()])
    print(f"all               {np.sqrt(np.mean(allz ** 2)):8.2f}")


if __name__ == "__main__":
    main()
