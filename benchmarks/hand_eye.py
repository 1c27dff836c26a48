"""Hand-eye benchmark: kincal against OpenCV's ``calibrateHandEye`` (every method) and
``calibrateRobotWorldHandEye``, on the same simulated detections.

**The problem** (eye-in-hand): a camera (1280 x 720 px, fx = fy = 900 px, no distortion,
the intrinsics known to everyone) on the flange at ``X`` (40, -30, 65 mm, rotated 46 deg),
a 9 x 6 corner board (30 mm) fixed on the table at ``Z``.  Each of ``--images`` views puts
the camera 0.35-0.6 m from the board centre, within 35 deg of the board's normal, rolled
up to +-90 deg, the whole board in the image; the flange pose is then ``A = Z B^-1 X^-1``
(``B`` the board in the camera).  The corners are projected and get Gaussian noise
(``--pixel-noise``, px per coordinate); the flange pose each tool is given is the true one
times a small random motion (``--robot-noise``: mm per axis, and the same figure x 0.1
in deg: the robot's own error, which OpenCV's users meet as "the answer depends on the
order of my samples").

**The contenders**, each handed exactly what its API takes:

* OpenCV's ``calibrateHandEye`` with TSAI, PARK, HORAUD, ANDREFF, DANIILIDIS: the flange
  poses and the board poses from ``cv2.solvePnP`` (iterative) on the noisy corners;
* OpenCV's ``calibrateRobotWorldHandEye`` (SHAH, LI) on the same poses (world = board,
  ``base2gripper = A^-1``, its ``gripper2cam`` is ``X^-1``);
* kincal's order-free closed forms on the same poses: ``hand_eye`` (all pairs, quaternion
  eigenvector) and ``robot_world`` (all samples, no pairs);
* kincal's joint fit (``calibrate_board_camera``, intrinsics held, no held-out images):
  the reprojection errors of the noisy corners themselves over ``X`` and ``Z``, from its
  own closed-form start (its time includes its own board poses and that start).

**Measured**, over ``--rounds`` rounds (each a fresh data set; within a round every
contender runs once, the order rotated, :mod:`timing`'s rule): the rotation error
``|log(R_est R_true^T)|`` [deg] and the translation error ``|t_est - t_true|`` [mm] of
``X``, the wall time [ms], and the **shuffle change**: the same data with the samples in a
random order, ``|t - t_shuffled|`` [mm] and the angle between the two rotations [deg].
The table quotes medians over the rounds (the shuffle change also its largest).

OpenCV 5.0's wheel has no ``calibrateHandEye``: run this in an environment with OpenCV
4.x, e.g.::

    python -m venv /tmp/cv4 && /tmp/cv4/bin/pip install 'opencv-python-headless<5' \\
        numpy scipy pyyaml
    PYTHONPATH=src /tmp/cv4/bin/python benchmarks/hand_eye.py [--rounds 20] [--images 15]
        [--pixel-noise 0.5] [--robot-noise 0.2] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from timing import machine

from kincal.identify.hand_eye import hand_eye, robot_world
from kincal.identify.hand_eye_lens import calibrate_board_camera
from kincal.spatial import exp_so3, inverse, log_so3, matrix_from_frame

SIZE = (1280, 720)
K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]])
X_TRUE = matrix_from_frame([0.040, -0.030, 0.065, 0.80, 0.01, -0.05])
Z_TRUE = matrix_from_frame([0.55, 0.05, 0.02, 0.3, 0.0, np.pi])     # board face up
GRID = np.array([[c * 0.03, r * 0.03, 0.0] for r in range(6) for c in range(9)])
CENTRE = GRID.mean(axis=0)

Data = tuple[np.ndarray, np.ndarray, list[np.ndarray]]      # A (stated), B (solvePnP), uv


def _view(rng: np.random.Generator) -> np.ndarray:
    """A camera pose in the board frame looking at the board centre from its front."""
    tilt, az = np.radians(rng.uniform(0, 35)), rng.uniform(-np.pi, np.pi)
    ray = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
    pos = CENTRE - rng.uniform(0.35, 0.6) * ray            # z axis of the camera = ray
    x = np.cross([0.0, 1.0, 0.0], ray)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(ray, x), ray]) @ exp_so3([0, 0, rng.uniform(-1.57, 1.57)])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, pos
    return T


def simulate(rng: np.random.Generator, n: int, pixel_noise: float, robot_noise_mm: float,
             cv2: object) -> Data:
    """``n`` images: stated flange poses, solvePnP board poses and the noisy corners."""
    A, B, uv = [], [], []
    while len(A) < n:
        Bt = inverse(_view(rng))                            # the board in the camera
        x = GRID @ Bt[:3, :3].T + Bt[:3, 3]
        p = x[:, :2] / x[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
        if p.min() < 10 or p[:, 0].max() > SIZE[0] - 10 or p[:, 1].max() > SIZE[1] - 10:
            continue
        p = p + rng.normal(0.0, pixel_noise, p.shape)
        err = np.eye(4)
        err[:3, :3] = exp_so3(rng.normal(0.0, np.radians(0.1 * robot_noise_mm), 3))
        err[:3, 3] = rng.normal(0.0, robot_noise_mm * 1e-3, 3)
        A.append(Z_TRUE @ inverse(Bt) @ inverse(X_TRUE) @ err)
        ok, rvec, tvec = cv2.solvePnP(GRID, p.reshape(-1, 1, 2), K, None)   # type: ignore
        Bp = np.eye(4)
        Bp[:3, :3], Bp[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()       # type: ignore
        B.append(Bp)
        uv.append(p)
    return np.array(A), np.array(B), uv


def _T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.ravel(t)
    return T


def contenders(cv2: object) -> dict[str, Callable[[Data], np.ndarray]]:
    """``{name: data -> X}``."""
    c: object = cv2

    def opencv(method: int) -> Callable[[Data], np.ndarray]:
        def run(d: Data) -> np.ndarray:
            A, B, _ = d
            R, t = c.calibrateHandEye(list(A[:, :3, :3]), list(A[:, :3, 3]),   # type: ignore
                                      list(B[:, :3, :3]), list(B[:, :3, 3]), method=method)
            return _T(R, t)
        return run

    def opencv_rw(method: int) -> Callable[[Data], np.ndarray]:
        def run(d: Data) -> np.ndarray:
            A, B, _ = d
            Ai = inverse(A)
            out = c.calibrateRobotWorldHandEye(                                 # type: ignore
                list(B[:, :3, :3]), list(B[:, :3, 3]), list(Ai[:, :3, :3]),
                list(Ai[:, :3, 3]), method=method)
            return inverse(_T(out[2], out[3]))
        return run

    def joint(d: Data) -> np.ndarray:
        A, _, uv = d
        lens = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.zeros(5)]
        return calibrate_board_camera(A, [GRID] * len(A), uv, [f"{k:03d}" for k in
                                                               range(len(A))], lens, "hand",
                                      0.0, (), 0.5, 0.0).X

    out: dict[str, Callable[[Data], np.ndarray]] = {
        f"OpenCV calibrateHandEye {m}": opencv(getattr(c, f"CALIB_HAND_EYE_{m}"))
        for m in ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS")}
    out.update({f"OpenCV calibrateRobotWorldHandEye {m}":
                opencv_rw(getattr(c, f"CALIB_ROBOT_WORLD_HAND_EYE_{m}"))
                for m in ("SHAH", "LI")})
    out["kincal closed form (pairs)"] = lambda d: hand_eye(d[0], d[1], "hand").X
    out["kincal closed form (robot-world)"] = lambda d: robot_world(d[0], d[1], "hand").X
    out["kincal joint fit (reprojection)"] = joint
    return out


def _diff(S: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """(angle [deg], distance [mm]) between two poses."""
    return (float(np.degrees(np.linalg.norm(log_so3(S[:3, :3] @ T[:3, :3].T)))),
            float(np.linalg.norm(S[:3, 3] - T[:3, 3]) * 1e3))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--images", type=int, default=15)
    ap.add_argument("--pixel-noise", type=float, default=0.5, help="px")
    ap.add_argument("--robot-noise", type=float, default=0.2, help="mm (x 0.1 in deg)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.rounds < 5:
        ap.error("--rounds: at least 5 for a quoted median")
    import cv2

    if not hasattr(cv2, "calibrateHandEye"):
        raise SystemExit(f"OpenCV {cv2.__version__} has no calibrateHandEye: run this with "
                         "opencv-python-headless<5 (module docstring)")
    rng = np.random.default_rng(args.seed)
    fns = contenders(cv2)
    names = list(fns)
    rec: dict[str, list[tuple[float, ...]]] = {k: [] for k in names}
    for d in (simulate(rng, args.images, 0, 0, cv2),):         # noise-free: all exact
        for k in names:
            ang, mm = _diff(fns[k](d), X_TRUE)
            assert ang < 1e-4 and mm < 1e-3, (k, ang, mm)
    for i in range(args.rounds):
        d = simulate(rng, args.images, args.pixel_noise, args.robot_noise, cv2)
        perm = rng.permutation(args.images)
        shuffled = (d[0][perm], d[1][perm], [d[2][k] for k in perm])
        for k in names[i % len(names):] + names[:i % len(names)]:
            t0 = time.perf_counter()
            X = fns[k](d)
            dt = time.perf_counter() - t0
            Xs = fns[k](shuffled)
            rec[k].append((*_diff(X, X_TRUE), dt * 1e3, *_diff(X, Xs)))
    print(f"# {args.rounds} rounds, {args.images} images each, corner noise "
          f"{args.pixel_noise} px, robot pose noise {args.robot_noise} mm / "
          f"{0.1 * args.robot_noise:g} deg per axis; OpenCV {cv2.__version__}")
    print(f"# {machine()}")
    print("| method | rotation error [deg] | translation error [mm] | time [ms] | "
          "shuffle change, median (max) [mm] | shuffle change, median (max) [deg] |")
    print("|---|---:|---:|---:|---:|---:|")
    for k in names:
        r = np.array(rec[k])
        med = np.median(r, axis=0)
        mx = r.max(axis=0)
        print(f"| {k} | {med[0]:.3f} | {med[1]:.2f} | {med[2]:.2f} | {med[4]:.2g} "
              f"({mx[4]:.2g}) | {med[3]:.2g} ({mx[3]:.2g}) |")


if __name__ == "__main__":
    main()
