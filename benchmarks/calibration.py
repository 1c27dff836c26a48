"""Calibration benchmark: kincal against the honest peer, against pybotics, and its scaling.

**The honest peer** (``--section peers``, :mod:`calibration_peers`): FIGAROH's recipe written
out for the same problem - a vectorised-NumPy forward kinematics (and, when ``pin`` is
installed, Pinocchio's, looped over the configurations as FIGAROH does) inside
``scipy.optimize.least_squares(method="lm")`` with its finite-difference Jacobian - over
exactly the parameters kincal estimates, from the same start (the nominal robot, kincal's
closed-form tracker frame and markers; the peer's start is computed outside its timing).
Problems: the PUMA 560 of kincal's library with one marker (26 parameters estimated) and
the Franka Panda (7R, modified DH) with three markers (37), each perturbed (1 mm / 0.05 deg
/ 0.1 deg) and measured by a tracker 0.9 m away, turned, with 0.01 mm noise per
coordinate, at N = 1k, 10k, 100k configurations.  Accuracy is the RMS distance between
each tool's predicted and the *true* (noise-free) marker positions on 2 000 held-out
configurations, and ``|dθ|/σ`` the largest difference between kincal's and the NumPy
peer's estimates in kincal's standard errors.  Both tools solve the same plain
least-squares problem.  kincal is timed twice: as a user calls it (``auto``: it also
chooses the identifiable parameters among all 45 / 55 candidates, which the peer is
handed), and given the peer's parameter list (``same P``: ``free=`` the estimated names;
it still computes its own start, checks identifiability and the covariance).  kincal's
command-line default (a MAP fit with the manufacturing tolerances as priors and the
noise scale estimated, ``MAP``) is timed in the same rounds and shown apart.

**pybotics** (``--section pybotics``): the UR10 of pybotics' MDH table, 1 000 poses, its
documented recipe (``OptimizationHandler`` + ``least_squares(optimize_accuracy)``).

**Scaling** (``--section scaling``): kincal alone, PUMA 560, N = 10^3 ... 10^7 position
measurements, one fresh process per N: wall and CPU time, time per measurement, peak
resident memory (``ru_maxrss``: the whole process, the data included).

**Other instruments** (``--section instruments``): range (3 stations), bearing (2),
camera (2), plane (3 unknown planes) and fixture blocks of ``--instrument-poses`` poses on
the PUMA 560, one fresh process each: the CPU time of the calibration and the memory it
adds to the process (the peak resident set during the fit, reset after simulating, minus
the resident set before it: the data are not counted).

Timing: every contender once per round, the order rotated, at least five rounds; the
tables quote medians and the median of the same-round ratios (:mod:`timing`), never
best-of.  In the peer table every call starts with cold CPU caches (128 MiB of other
memory written before it, untimed): one kincal variant right after another would
otherwise find its arrays still cached.  One BLAS thread for everyone.  The machine and
its load are printed.

Run (the peers live in the benchmark environment, ``pip install -e ".[bench]"``)::

    python benchmarks/calibration.py [--section peers,pybotics,scaling,instruments]
        [--rounds 5] [--sizes 1000,10000,100000] [--pin-max 10000]
        [--scaling 1000,...,10000000] [--instrument-poses 100000]
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
sys.path.insert(0, str(Path(__file__).resolve().parent))

from kincal.identify.identifiability import analyze  # noqa: E402
from kincal.identify.solver import calibrate  # noqa: E402
from kincal.measure.base import stack  # noqa: E402
from kincal.measure.instruments.position import PositionMeasurement  # noqa: E402
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
    from kincal.spatial import matrix_from_frame

    return matrix_from_frame(TRACKER)


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


def run_kincal(q: np.ndarray, y: np.ndarray, free: list[str]):
    robot = kincal_robot(UR10_MDH)
    block = PositionMeasurement(q, y, NOISE_MM * 1e-3)
    return calibrate(robot, [block], free=free, method="lm")


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
    handler = OptimizationHandler(robot=robot, kinematic_chain_mask=mask,
                                  tool_mask=[True, True, True, False, False, False],
                                  world_mask=[True] * 6)
    x0 = handler.generate_optimization_vector()
    res = least_squares(optimize_accuracy, x0, args=(handler, q, y_mm))
    handler.apply_optimization_vector(res.x)
    return handler.robot, res


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


#: The honest-peer problems: (library robot, DH convention of its file, markers in the
#: tool frame [m]).  PUMA 560: one marker, 26 parameters; Panda: three markers, 37.
PROBLEMS = {
    "puma560": ("standard", [[0.01, -0.02, 0.03]]),
    "panda": ("modified", [[0.01, -0.02, 0.03], [0.06, 0.0, 0.02], [0.0, 0.07, 0.01]]),
}
#: Tracker pose in the robot's world frame, (x, y, z, roll, pitch, yaw) [m, rad].
INSTRUMENT = [0.8, -0.4, 0.2, math.radians(20), math.radians(5), math.radians(-3)]


def peer_problem(name: str, n: int, holdout: int = 2000, seed: int = 0):
    """(nominal robot, training block, held-out q, true held-out positions (N, K, 3))."""
    from kincal.measure.instruments.position import simulate_positions
    from kincal.measure.simulate import perturb_robot, random_configurations
    from kincal.robots.files import load_serial_robot

    robot = load_serial_robot(name)
    markers = np.array(PROBLEMS[name][1])
    rng = np.random.default_rng(seed)
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, n, rng)
    m = markers[0] if len(markers) == 1 else markers
    block = simulate_positions(true, q, rng, NOISE_MM * 1e-3, INSTRUMENT, m)
    qv = random_configurations(robot, holdout, rng)
    yv = simulate_positions(true, qv, rng, 0.0, INSTRUMENT, m)._y
    return robot, block, qv, yv


def peers(sizes: list[int], rounds: int, pin_max: int, robots: list[str]) -> None:
    """kincal against the NumPy and Pinocchio least_squares peers (interleaved medians)."""
    from timing import load_average, machine

    try:
        import pinocchio  # noqa: F401
        have_pin = True
    except ImportError:
        have_pin = False
        print("pinocchio not installed (pip install pin): its column is left out")
    print(f"\nkincal vs the honest peer (least_squares 'lm', finite differences); "
          f"{rounds} interleaved rounds, medians\n{machine()}")
    print("kincal 'auto': as a user calls it (chooses the parameters among all candidates); "
          "'same P': given the peer's parameter list.\nRatios: peer time / kincal time, "
          "median of the same-round ratios.")
    head = (f"{'robot':<9}{'P':>4}{'N':>8}{'auto [s]':>10}{'same P [s]':>12}"
            f"{'NumPy+lsq [s]':>15}{'ratio':>7}{'same P':>8}"
            f"{'pin+lsq [s]':>13}{'ratio':>7}{'same P':>8}{'it':>4}{'nfev':>6}"
            f"{'RMS vs truth [um]: kincal':>27}{'NumPy':>8}{'pin':>8}{'|dθ|/σ':>8}"
            f"{'MAP [s]':>9}{'MAP RMS':>9}")
    print(head)
    print("-" * len(head))
    for name in robots:
        for n in sizes:
            print(peer_row(name, n, rounds, have_pin and n <= pin_max), flush=True)
    print(f"load average after: {load_average()}")


def peer_row(name: str, n: int, rounds: int, with_pin: bool) -> str:
    """One line of the peer table: ``name`` at ``n`` configurations."""
    from calibration_peers import DHModel, calibrate_peer
    from timing import interleaved

    from kincal.workflow.flow import tolerances_of

    robot, block, qv, yv = peer_problem(name, n)
    prob, theta0 = stack(robot, [block])
    res = calibrate(robot, [block])
    free = [prob.names.index(s) for s in res.estimated]
    model = DHModel(prob.names, robot.n, PROBLEMS[name][0], block.K)
    y, sigma = block._y, NOISE_MM * 1e-3
    # the command line's default fit: MAP with the tolerances as priors, the noise scale
    # estimated (not what the peer solves: timed alongside, not in the ratio)
    prior = tolerances_of(robot, prob).prior()
    fns = {"kincal": lambda: calibrate(robot, [block]),
           "same": lambda: calibrate(robot, [block], free=res.estimated),
           "numpy": lambda: calibrate_peer(model, block.q, y, sigma, theta0, free),
           "map": lambda: calibrate(robot, [block], prior=prior)}
    if with_pin:
        fk = model.pinocchio()
        fns["pin"] = lambda: calibrate_peer(model, block.q, y, sigma, theta0, free, fk)
    t = interleaved(fns, rounds=rounds, warmup=False, cold=True)

    def truth_rms(theta: np.ndarray) -> float:
        pred = model.observe(theta, model.fk_numpy(theta, qv))
        return rms(np.linalg.norm(pred - yv, axis=-1)) * 1e6

    def kincal_rms(r) -> float:
        return rms(np.linalg.norm(_predict_on(block, r.robot, r.theta[prob.slices[0]], qv) - yv,
                                  axis=-1)) * 1e6

    rk = t.results["kincal"]
    rn = t.results["numpy"]
    rs = t.results["same"]
    if rs.estimated != rk.estimated or not np.allclose(rs.theta, rk.theta, rtol=0, atol=1e-12):
        raise SystemExit(f"{name} {n}: kincal given the peer's parameters found another "
                         "solution than its automatic fit")
    cells = [f"{name:<9}{len(free):>4}{n:>8}{t.median('kincal'):>10.3f}"
             f"{t.median('same'):>12.3f}{t.median('numpy'):>15.3f}"
             f"{t.ratio('numpy', 'kincal'):>6.1f}x{t.ratio('numpy', 'same'):>7.1f}x"]
    pin_rms = f"{'-':>8}"
    if with_pin:
        cells.append(f"{t.median('pin'):>13.3f}{t.ratio('pin', 'kincal'):>6.1f}x"
                     f"{t.ratio('pin', 'same'):>7.1f}x")
        pin_rms = f"{truth_rms(t.results['pin'].theta):>8.2f}"
    else:
        cells.append(f"{'-':>13}{'-':>7}{'-':>8}")
    # the two solutions apart, in kincal's standard errors (the largest over parameters)
    est = [prob.names.index(s) for s in rk.estimated]
    apart = float(np.max(np.abs(rk.theta[est] - rn.theta[est]) / rk.std[est]))
    cells.append(f"{rk.iterations:>4}{rn.nfev:>6}{kincal_rms(rk):>27.2f}"
                 f"{truth_rms(rn.theta):>8.2f}{pin_rms}{apart:>8.0e}"
                 f"{t.median('map'):>9.3f}{kincal_rms(t.results['map']):>9.2f}")
    return "".join(cells)


def _predict_on(block: PositionMeasurement, robot, extra: np.ndarray, q: np.ndarray
                ) -> np.ndarray:
    """The block's prediction (N, K, 3) at other configurations ``q``."""
    other = PositionMeasurement(q, np.zeros((len(q), block.K, 3)), block.sigma[0, 0],
                                block.name, block.K)
    return other.predict(robot, extra)


def pybotics_section(poses: int, holdout: int, rounds: int) -> None:
    """kincal against pybotics on its UR10 (interleaved medians)."""
    from timing import interleaved, load_average, machine

    try:
        import pybotics  # noqa: F401
    except ImportError:
        print("pybotics not installed in this environment: pip install -e '.[bench]'")
        return
    rng = np.random.default_rng(2024)
    table = true_table(rng)
    q = rng.uniform(-np.pi, np.pi, (poses, 6))
    y = measure(table, q, rng)
    qv = rng.uniform(-np.pi, np.pi, (holdout, 6))
    yv = measure(table, qv, rng)
    free = estimated_set(q, y)
    print(f"\nUR10 (pybotics MDH), {poses} poses, noise {NOISE_MM} mm, {len(free)} parameters "
          f"estimated; {rounds} interleaved rounds, medians\n{machine()}")
    print(f"model check: max |kincal FK - pybotics FK| = {check_models_agree(q, table):.2e} m")
    t = interleaved({"kincal": lambda: run_kincal(q, y, free),
                     "pybotics": lambda: run_pybotics(q, y * 1e3, free)}, rounds=rounds)
    res = t.results["kincal"]
    pb_robot, pb_res = t.results["pybotics"]
    ek, ep = kincal_errors(res, qv, yv), pybotics_errors(pb_robot, qv, yv * 1e3)
    nom = np.linalg.norm(measure(UR10_MDH, qv, None) - yv, axis=1)
    head = f"{'tool':<38}{'time [s]':>10}{'iter/nfev':>10}{'valid RMS':>11}{'valid max':>11}"
    print(head + "   (errors in mm)")
    print("-" * len(head))
    print(f"{'nominal model (no calibration)':<38}{'-':>10}{'-':>10}"
          f"{rms(nom) * 1e3:>11.4f}{np.max(nom) * 1e3:>11.4f}")
    for label, key, it, e in (("kincal (LM, analytic J)", "kincal", res.iterations, ek),
                              ("pybotics (least_squares, FD J)", "pybotics", pb_res.nfev, ep)):
        print(f"{label:<38}{t.median(key):>10.3f}{it:>10}{rms(e) * 1e3:>11.4f}"
              f"{np.max(e) * 1e3:>11.4f}")
    print(f"kincal is {t.ratio('pybotics', 'kincal'):.0f}x faster (median of same-round "
          f"ratios); load average after: {load_average()}")


def scaling_problem(n: int):
    """PUMA 560 measured at ``n`` configurations, simulated in pieces (O(piece) memory
    beyond the data): (nominal robot, block)."""
    from kincal.measure.instruments.position import simulate_positions
    from kincal.measure.simulate import perturb_robot, random_configurations
    from kincal.robots.files import load_serial_robot

    robot = load_serial_robot("puma560")
    true = perturb_robot(robot, np.random.default_rng(0))
    rng = np.random.default_rng(n)
    q = random_configurations(robot, n, rng)
    block = simulate_positions(true, q, rng, NOISE_MM * 1e-3, INSTRUMENT, PROBLEMS["puma560"][1][0])
    return robot, block


def child(n: int) -> None:
    """One scaling point in a fresh process: print time and peak RSS as JSON."""
    robot, block = scaling_problem(n)
    calibrate(*scaling_problem(50))                      # warm-up (lazy imports)
    c0, t0 = time.process_time(), time.perf_counter()
    res = calibrate(robot, [block], method="lm")
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    # position error RMS from the whitened residuals (no (N, 3) array after the fit):
    # |e_i| = sigma |r_i|, so RMS = sigma sqrt(3 r.r / M)
    r = res.residuals
    rms_mm = NOISE_MM * float(np.sqrt(3.0 * (r @ r) / r.size))
    print(json.dumps({"n": n, "seconds": seconds, "cpu_seconds": cpu, "peak_mb": peak,
                      "iterations": res.iterations, "params": len(res.estimated),
                      "rms_mm": rms_mm}))


def _in_fresh_process(*args: str) -> dict:
    """Run this script with ``args`` in a fresh Python process; its last line, as JSON."""
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def scaling(sizes: list[int]) -> None:
    """The scaling table: one fresh process per N."""
    from timing import load_average, machine

    print(f"\nscaling (kincal, PUMA 560, position measurements, fresh process per N)\n"
          f"{machine()}")
    head = (f"{'N':>9}{'time [s]':>10}{'CPU [s]':>9}{'time/N [us]':>13}{'peak RSS [MiB]':>15}"
            f"{'iterations':>12}{'params':>8}{'RMS [mm]':>10}")
    print(head)
    print("-" * len(head))
    for n in sizes:
        d = _in_fresh_process("--child", str(n))
        print(f"{d['n']:>9}{d['seconds']:>10.3f}{d['cpu_seconds']:>9.3f}"
              f"{d['seconds'] / n * 1e6:>13.2f}"
              f"{d['peak_mb']:>15.0f}{d['iterations']:>12}{d['params']:>8}"
              f"{d['rms_mm']:>10.4f}", flush=True)
    print(f"load average after: {load_average()}")


#: ``--section instruments``: instrument -> simulator options.
INSTRUMENTS = {"range": {"stations": 3}, "bearing": {"stations": 2}, "camera": {"cameras": 2},
               "plane": {"planes": 3}, "fixture": {}}


def _status_kib(field: str) -> float:
    """A ``/proc/self/status`` field (VmRSS, VmHWM) [KiB]."""
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith(field + ":"):
                return float(line.split()[1])
    return float("nan")


def instrument_child(name: str, poses: int) -> None:
    """One instrument in a fresh process: CPU seconds and the fit's added memory (JSON)."""
    import gc

    from kincal.measure.registry import instruments, simulate_measurements
    from kincal.measure.simulate import perturb_robot
    from kincal.robots.files import load_serial_robot

    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(1)
    noise = {"m": 1e-5, "rad": 1e-5, "px": 0.1}[instruments()[name].noise_unit]
    blocks, _ = simulate_measurements(name, perturb_robot(nominal, rng), rng, poses, noise,
                                      INSTRUMENTS[name])
    small, _ = simulate_measurements(name, perturb_robot(nominal, rng), rng, 30, noise,
                                     INSTRUMENTS[name])
    calibrate(nominal, small)                             # warm-up (lazy imports)
    gc.collect()
    with open("/proc/self/clear_refs", "w", encoding="ascii") as f:
        f.write("5")                                      # peak RSS := current RSS
    before = _status_kib("VmRSS")
    c0 = time.process_time()
    res = calibrate(nominal, blocks)
    cpu = time.process_time() - c0
    rows = sum(b.num_residuals() for b in blocks)
    print(json.dumps({"instrument": name, "poses": poses, "residuals": rows, "cpu": cpu,
                      "data_mb": before / 1024, "added_mb": (_status_kib("VmHWM") - before) / 1024,
                      "params": len(res.estimated), "converged": res.converged}))


def instruments_section(poses: int) -> None:
    """The point instruments' table: one fresh process per instrument."""
    from timing import load_average, machine

    print(f"\npoint instruments (kincal, PUMA 560, {poses} poses, fresh process each)\n"
          f"{machine()}")
    head = (f"{'instrument':<12}{'residuals':>11}{'params':>8}{'CPU [s]':>9}"
            f"{'process before fit [MB]':>25}{'added by the fit [MB]':>23}")
    print(head)
    print("-" * len(head))
    for name in INSTRUMENTS:
        d = _in_fresh_process("--instrument-child", name, "--instrument-poses", str(poses))
        print(f"{name:<12}{d['residuals']:>11}{d['params']:>8}{d['cpu']:>9.2f}"
              f"{d['data_mb']:>25.0f}{d['added_mb']:>23.0f}", flush=True)
    print(f"load average after: {load_average()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--section", default="peers,pybotics,scaling",
                    help="comma-separated: peers, pybotics, scaling, instruments")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (>= 5)")
    ap.add_argument("--sizes", default="1000,10000,100000", help="N of the peer comparison")
    ap.add_argument("--robots", default="puma560,panda", help="peer-comparison problems")
    ap.add_argument("--pin-max", type=int, default=10000,
                    help="largest N for the Pinocchio peer (it loops over configurations)")
    ap.add_argument("--poses", type=int, default=1000, help="pybotics comparison poses")
    ap.add_argument("--holdout", type=int, default=200)
    ap.add_argument("--scaling", default="10000,100000,1000000",
                    help="comma-separated N of the scaling run")
    ap.add_argument("--instrument-poses", type=int, default=100000,
                    help="poses per instrument in the instruments section")
    ap.add_argument("--child", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--instrument-child", default="", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.child)
        return
    if a.instrument_child:
        instrument_child(a.instrument_child, a.instrument_poses)
        return
    sections = set(a.section.split(","))
    if "peers" in sections:
        peers([int(s) for s in a.sizes.split(",") if s], a.rounds, a.pin_max,
              a.robots.split(","))
    if "pybotics" in sections:
        pybotics_section(a.poses, a.holdout, a.rounds)
    if "scaling" in sections:
        scaling([int(s) for s in a.scaling.split(",") if s])
    if "instruments" in sections:
        instruments_section(a.instrument_poses)


if __name__ == "__main__":
    main()
