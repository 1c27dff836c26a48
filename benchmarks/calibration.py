"""Calibration benchmark: kincal against pybotics on the same simulated UR10 problem.

Problem (identical for both): the UR10 modified-DH model of pybotics
(``pybotics.predefined_models.ur10``), a "true" robot with Gaussian errors on every
DH parameter (0.5 mm lengths, 0.05 deg angles, 0.1 deg joint offsets) and a tool
point 100 mm off the flange, measured by a tracker 0.9 m away and turned by 20 deg
(its frame unknown to both tools) at N random configurations with 0.01 mm noise per
coordinate.  Both tools start from the nominal model with the tool point at the
flange and estimate the same parameters: the tracker frame (pybotics: its world
frame, started at identity; kincal: its closed-form initial guess), the identifiable
DH parameters (kincal's identifiability analysis of this problem: the tracker frame
takes the place of the first link's constants, the tool point that of the last
link's) and the tool point.  Accuracy is the RMS position error on held-out
configurations, each tool using its own forward kinematics and its training frames.

pybotics: ``OptimizationHandler`` + ``scipy.optimize.least_squares(optimize_accuracy)``
(its documented calibration recipe: finite-difference Jacobian, one residual per
pose = the 3-D error norm).  kincal: ``kincal.identify.solver.calibrate`` with a
``PositionMeasurement`` block (analytic Jacobian, Levenberg-Marquardt).

Then the scaling run: kincal alone for N = 1k, 10k, 100k position measurements,
each in a fresh process to report its wall time (and CPU time: on a shared machine
the steadier number), time per measurement and peak resident memory (``ru_maxrss``:
the whole process, data included).  The problem is
the one above (UR10, its estimated set) or, with ``--scaling-robot puma560``, the
PUMA 560 of kincal's library with a tool point, a perturbed "true" robot and the
automatic parameter selection (``free=None``: 26 identifiable of 45).  The target
(issue 3): time linear in N, 100k measurements in well under 10 s and < 1 GB.

Run (pybotics lives in the benchmark environment)::

    /work/benchvenv/bin/python benchmarks/calibration.py [--poses 1000] [--skip-pybotics]
        [--scaling 1000,10000,100000] [--scaling-robot ur10|puma560] [--skip-comparison]
"""

from __future__ import annotations

import os

# One BLAS thread for both tools: on a shared or loaded machine OpenBLAS's threads
# oversubscribe the cores and slow small dense factorisations by 10-30x.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from kincal.identify.identifiability import analyze  # noqa: E402
from kincal.identify.solver import calibrate  # noqa: E402
from kincal.measure.base import stack  # noqa: E402
from kincal.measure.models import PositionMeasurement  # noqa: E402
from kincal.robots.dh import DHLink, from_dh  # noqa: E402

# pybotics' UR10 MDH table: rows (alpha [rad], a [mm], theta [rad], d [mm])
UR10_MDH = np.array([
    [0, 0, 0, 118],
    [np.pi / 2, 0, np.pi, 0],
    [0, 612.7, 0, 0],
    [0, 571.6, 0, 163.9],
    [-np.pi / 2, 0, 0, 115.7],
    [np.pi / 2, 0, np.pi, 92.2],
])
TOOL_TRUE_MM = np.array([12.0, -8.0, 100.0])
#: True tracker frame in the robot world frame: (x, y, z) [m], rz, ry, rx [rad].
TRACKER = np.array([0.8, -0.4, 0.2, math.radians(20), math.radians(5), math.radians(-3)])
NOISE_MM = 0.01
FRAME = ["tracker.x", "tracker.y", "tracker.z", "tracker.rz", "tracker.ry", "tracker.rx"]
MARKER = ["tracker.marker.x", "tracker.marker.y", "tracker.marker.z"]


def kincal_robot(mdh: np.ndarray):
    """The MDH table (mm) as a kincal robot (m); unlimited joints."""
    links = [DHLink(a=r[1] * 1e-3, d=r[3] * 1e-3, alpha=r[0], theta_offset=r[2])
             for r in mdh]
    return from_dh(links, "modified", "ur10")


def true_table(rng: np.random.Generator) -> np.ndarray:
    t = UR10_MDH.copy()
    t[:, 0] += rng.normal(0, math.radians(0.05), 6)
    t[:, 1] += rng.normal(0, 0.5, 6)
    t[:, 2] += rng.normal(0, math.radians(0.1), 6)
    t[:, 3] += rng.normal(0, 0.5, 6)
    return t


def tracker_matrix() -> np.ndarray:
    from kincal.measure.base import frame_matrix

    return frame_matrix(TRACKER)


def measure(table: np.ndarray, q: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
    """Positions [m] of the true tool point in the tracker frame (+ noise), kincal's FK."""
    T = kincal_robot(table).fk(q)
    p = T[:, :3, 3] + T[:, :3, :3] @ (TOOL_TRUE_MM * 1e-3)
    TI = tracker_matrix()
    y = (p - TI[:3, 3]) @ TI[:3, :3]
    return y if rng is None else y + rng.normal(0, NOISE_MM * 1e-3, y.shape)


def estimated_set(q: np.ndarray, y: np.ndarray) -> list[str]:
    """The identifiable DH parameters, tracker frame and tool point of this problem."""
    robot = kincal_robot(UR10_MDH)
    block = PositionMeasurement(q, y, NOISE_MM * 1e-3)
    prob, theta = stack(robot, [block])
    _, J = prob.residuals_and_jacobian(theta)
    cand = [i for i, n in enumerate(prob.names) if not n.startswith(("base.", "tool."))]
    rep = analyze(J[:, cand], [prob.names[i] for i in cand],
                  roles=[prob.roles[i] for i in cand])
    return list(rep.identifiable)


def run_kincal(q: np.ndarray, y: np.ndarray, free: list[str]) -> tuple[float, object]:
    robot = kincal_robot(UR10_MDH)
    t0 = time.perf_counter()
    block = PositionMeasurement(q, y, NOISE_MM * 1e-3)
    res = calibrate(robot, [block], free=free, method="lm")
    return time.perf_counter() - t0, res


def kincal_errors(res, q: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Held-out errors with the training tracker frame and tool point (no refit)."""
    block = PositionMeasurement(q, y, NOISE_MM * 1e-3)
    extra = np.array([res.params[n] for n in FRAME + MARKER])
    return np.ravel(block.errors(res.robot, extra)["position_m"])


def run_pybotics(q: np.ndarray, y_mm: np.ndarray, free: list[str]):
    from pybotics.optimization import OptimizationHandler, optimize_accuracy
    from pybotics.robot import Robot
    from scipy.optimize import least_squares

    names = [f"{p}[{i}]" for i in range(1, 7) for p in ("alpha", "a", "theta_offset", "d")]
    mask = [n in free for n in names]
    robot = Robot.from_parameters(UR10_MDH.copy())
    t0 = time.perf_counter()
    handler = OptimizationHandler(robot=robot, kinematic_chain_mask=mask,
                                  tool_mask=[True, True, True, False, False, False],
                                  world_mask=[True] * 6)
    x0 = handler.generate_optimization_vector()
    res = least_squares(optimize_accuracy, x0, args=(handler, q, y_mm))
    seconds = time.perf_counter() - t0
    handler.apply_optimization_vector(res.x)
    return seconds, handler.robot, res


def pybotics_errors(robot, q: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    from pybotics.optimization import compute_absolute_errors

    return np.asarray(compute_absolute_errors(q, y_mm, robot)) * 1e-3


def check_models_agree(q: np.ndarray, table: np.ndarray) -> float:
    """Max |kincal FK - pybotics FK| of the same MDH table + tool [m] (independent check)."""
    from pybotics.robot import Robot

    pb = Robot.from_parameters(table.copy())
    pb.tool.position = TOOL_TRUE_MM
    W = np.linalg.inv(tracker_matrix())
    W[:3, 3] *= 1e3
    pb.world_frame = W
    P = np.array([pb.fk(qi)[:3, 3] for qi in q[:50]]) * 1e-3
    return float(np.max(np.abs(P - measure(table, q[:50], None))))


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def puma_problem(n: int) -> tuple[object, object]:
    """PUMA 560 (library) with a tool point, measured by a tracker: (robot, block)."""
    from kincal.measure.simulate import perturb_robot, random_configurations, simulate_positions
    from kincal.robots.dh import dh_links
    from kincal.robots.files import load_robot

    robot = from_dh(dh_links(load_robot("puma560")), name="puma560",
                    tool=[0.05, 0.03, 0.1, 0, 0, 0])
    rng = np.random.default_rng(n)
    true = perturb_robot(robot, np.random.default_rng(0))
    q = random_configurations(robot, n, rng)
    block = simulate_positions(true, q, rng, NOISE_MM * 1e-3,
                               [0.8, -0.4, 0.2, math.radians(-3), math.radians(5),
                                math.radians(20)], [0.01, -0.02, 0.03])
    return robot, block


def child(n: int, robot_name: str) -> None:
    """One scaling point in a fresh process: print time and peak RSS as JSON."""
    if robot_name == "puma560":
        robot, block = puma_problem(n)
        calibrate(*puma_problem(50))                      # warm-up (lazy imports)
        c0, t0 = time.process_time(), time.perf_counter()
        res = calibrate(robot, [block], method="lm")
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        rms_mm = float(np.sqrt(np.mean(res.errors()[block.name]["position_m"] ** 2))) * 1e3
    else:
        rng = np.random.default_rng(n)
        table = true_table(np.random.default_rng(0))
        q = rng.uniform(-np.pi, np.pi, (n, 6))
        y = measure(table, q, rng)
        free = estimated_set(q[:300], y[:300])
        run_kincal(q[:50], y[:50], free)                  # warm-up (lazy imports)
        c0 = time.process_time()
        seconds, res = run_kincal(q, y, free)
        cpu = time.process_time() - c0
        rms_mm = rms(kincal_errors(res, q, y)) * 1e3
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"n": n, "seconds": seconds, "cpu_seconds": cpu, "peak_mb": peak,
                      "iterations": res.iterations, "params": len(res.estimated),
                      "rms_mm": rms_mm}))


def scaling(sizes: list[int], robot_name: str) -> None:
    """The scaling table: one fresh process per N."""
    print(f"\nscaling (kincal, {robot_name}, position measurements, fresh process per N):")
    head = (f"{'N':>8}{'time [s]':>10}{'CPU [s]':>9}{'time/N [us]':>13}{'peak RSS [MB]':>15}"
            f"{'iterations':>12}{'params':>8}{'RMS [mm]':>10}")
    print(head)
    print("-" * len(head))
    for n in sizes:
        out = subprocess.run([sys.executable, __file__, "--child", str(n), "--scaling-robot",
                              robot_name], capture_output=True, text=True, check=True).stdout
        d = json.loads(out.strip().splitlines()[-1])
        print(f"{d['n']:>8}{d['seconds']:>10.3f}{d['cpu_seconds']:>9.3f}"
              f"{d['seconds'] / n * 1e6:>13.2f}"
              f"{d['peak_mb']:>15.0f}{d['iterations']:>12}{d['params']:>8}"
              f"{d['rms_mm']:>10.4f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--holdout", type=int, default=200)
    ap.add_argument("--skip-pybotics", action="store_true")
    ap.add_argument("--scaling", default="1000,10000,100000",
                    help="comma-separated N of the scaling run (empty: skip it)")
    ap.add_argument("--scaling-robot", choices=("ur10", "puma560"), default="ur10")
    ap.add_argument("--skip-comparison", action="store_true",
                    help="only the scaling run")
    ap.add_argument("--child", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.child, a.scaling_robot)
        return
    sizes = [int(s) for s in a.scaling.split(",") if s]
    if a.skip_comparison:
        scaling(sizes, a.scaling_robot)
        return
    rng = np.random.default_rng(2024)
    table = true_table(rng)
    q = rng.uniform(-np.pi, np.pi, (a.poses, 6))
    y = measure(table, q, rng)
    qv = rng.uniform(-np.pi, np.pi, (a.holdout, 6))
    yv = measure(table, qv, rng)
    free = estimated_set(q, y)
    print(f"UR10 (pybotics MDH), {a.poses} poses, noise {NOISE_MM} mm, {len(free)} parameters "
          f"estimated: {', '.join(free)}")
    rows = []
    run_kincal(q[:50], y[:50], free)                      # warm-up (lazy imports)
    tk, res = min((run_kincal(q, y, free) for _ in range(3)), key=lambda r: r[0])
    ek = kincal_errors(res, qv, yv)
    rows.append(("kincal (LM, analytic J)", tk, res.iterations, rms(kincal_errors(res, q, y)),
                 rms(ek), float(np.max(ek))))
    # nominal for reference
    nom_err = np.linalg.norm(measure(UR10_MDH, qv, None) - yv, axis=1)
    if not a.skip_pybotics:
        try:
            import pybotics  # noqa: F401
        except ImportError:
            print("pybotics not installed in this environment: run with the benchmark venv")
            a.skip_pybotics = True
    if not a.skip_pybotics:
        print(f"model check: max |kincal FK - pybotics FK| = "
              f"{check_models_agree(q, table):.2e} m")
        tp, robot, r = run_pybotics(q, y * 1e3, free)
        ep = pybotics_errors(robot, qv, yv * 1e3)
        rows.append(("pybotics (scipy least_squares, FD J)", tp, r.nfev,
                     rms(pybotics_errors(robot, q, y * 1e3)), rms(ep), float(np.max(ep))))
    print()
    head = f"{'tool':<38}{'time [s]':>10}{'iter/nfev':>10}{'train RMS':>11}{'valid RMS':>11}" \
           f"{'valid max':>11}"
    print(head + "   (errors in mm)")
    print("-" * len(head))
    print(f"{'nominal model (no calibration)':<38}{'-':>10}{'-':>10}{'-':>11}"
          f"{rms(nom_err) * 1e3:>11.4f}{np.max(nom_err) * 1e3:>11.4f}")
    for name, t, it, tr, va, mx in rows:
        print(f"{name:<38}{t:>10.3f}{it:>10}{tr * 1e3:>11.4f}{va * 1e3:>11.4f}{mx * 1e3:>11.4f}")
    if len(rows) == 2:
        print(f"\nspeed-up kincal vs pybotics: {rows[1][1] / rows[0][1]:.0f}x; validation RMS "
              f"ratio {rows[0][4] / rows[1][4]:.3f}")
    if sizes:
        scaling(sizes, a.scaling_robot)


if __name__ == "__main__":
    main()
