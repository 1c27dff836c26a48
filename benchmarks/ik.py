"""Inverse kinematics throughput and success: kincal's batched IK vs the Robotics Toolbox.

Run it in the benchmark environment (the peers are never dependencies of kincal)::

    python -m venv /work/benchvenv
    /work/benchvenv/bin/pip install -e '/work/main[bench]'
    /work/benchvenv/bin/python benchmarks/ik.py   # 10 000 targets; RTB on 2 000 and 200

Every solver runs once per round, in turn, for at least five rounds; the table quotes
the medians (never best-of) and throughputs per target.

The task: N = 10 000 PUMA 560 poses, FK of configurations drawn uniformly inside the
joint limits (so every target is reachable inside the limits), solved to the same strict
tolerance by every solver: position error <= 1e-9 m and orientation error <= 1e-9 rad.

* kincal ``solve_ik(robot, T)`` - one batched call for all N, defaults (start at the
  mid-range of the limits, 5 restart rounds seeded by nearby stored poses).
* RTB ``ETS.ik_LM`` - C++ Levenberg-Marquardt (Chan damping), one call per target (RTB
  has no batched IK), defaults (random start, up to 100 searches of 30 iterations,
  joint limits enforced) with ``tol = 5e-19`` on ``E = 0.5 e^T e`` (so that
  ``|e_p|, |e_o| <= 1e-9``).
* RTB ``DHRobot.ikine_LM`` - the Python solver, same settings, one call per target.
* kincal ``ik_puma560`` (closed form, all 8 branches) for reference.

The RTB robot is built from kincal's DH table and limits (RTB's own Puma560 has
d1 = 0.6718 m); the two models are checked to agree first.  Every returned solution is
checked here by kincal's FK against the target and the joint limits: "verified" counts
only those.  Throughput is targets per wall-clock second on this machine (other work on
it slows every solver alike).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

try:
    from kincal.motion.ik import check_solutions, solve_ik
    from kincal.motion.ik_closed_form import ik_puma560
    from kincal.robots.dh import dh_links
    from kincal.robots.files import load_serial_robot
except ImportError:  # pragma: no cover - a message instead of a traceback
    sys.exit("kincal is not installed in this environment: pip install -e /path/to/kincal")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from timing import interleaved, load_average, machine  # noqa: E402

TOL = 1e-9
RTB_TOL = 0.5 * TOL**2          # E = 0.5 (|e_p|^2 + |e_o|^2) <= 5e-19 => both <= 1e-9


def verify(robot, T, q, claimed) -> dict:
    """Check solutions by FK: within both tolerances and inside the joint limits."""
    q = np.asarray(q, dtype=float)
    good = np.all(np.isfinite(q), axis=1)
    ep = np.full(len(T), np.inf)
    eo = np.full(len(T), np.inf)
    if good.any():
        ep[good], eo[good] = check_solutions(robot, T[good], q[good])
    lim = robot.joint_limits
    inside = np.all((q >= lim[:, 0] - 1e-12) & (q <= lim[:, 1] + 1e-12), axis=1)
    ok = good & (ep <= TOL) & (eo <= TOL) & inside
    return {"claimed": float(np.mean(claimed)), "verified": float(np.mean(ok)),
            "claimed_but_wrong": int(np.sum(np.asarray(claimed, bool) & ~ok)),
            "worst_position_error_m": float(np.max(ep[ok], initial=0.0)),
            "worst_orientation_error_rad": float(np.max(eo[ok], initial=0.0))}


def run_kincal(robot, T):
    t0, c0 = time.perf_counter(), time.process_time()
    sol = solve_ik(robot, T)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row = {"solver": "kincal solve_ik (batched, NumPy)", "n": len(T), "wall_s": wall,
           "cpu_s": cpu, "mean_iterations": float(np.mean(sol.iterations))}
    row.update(verify(robot, T, sol.q, sol.success))
    return row


def run_closed_form(robot, T):
    t0, c0 = time.perf_counter(), time.process_time()
    cf = ik_puma560(robot, T)
    first = np.argmax(cf.within_limits, axis=1)
    q = cf.q[np.arange(len(T)), first]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row = {"solver": "kincal ik_puma560 (closed form, 8 branches)", "n": len(T),
           "wall_s": wall, "cpu_s": cpu, "mean_iterations": 0.0}
    row.update(verify(robot, T, q, cf.within_limits.any(axis=1)))
    return row


def rtb_robot(rtb, robot):
    links = [rtb.RevoluteDH(a=L.a, d=L.d, alpha=L.alpha, offset=L.theta_offset,
                            qlim=[L.lower, L.upper]) for L in dh_links(robot)]
    return rtb.DHRobot(links, name="puma560_kincal")


def run_rtb(kind, rr, robot, T, n):
    ets = rr.ets()
    Q = np.full((n, robot.n), np.nan)
    ok = np.zeros(n, bool)
    iters = np.zeros(n)
    np.random.seed(0)                       # RTB draws its random starts from np.random
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(n):                      # RTB solves one pose per call
        sol = ets.ik_LM(T[i], tol=RTB_TOL) if kind == "ik_LM" else rr.ikine_LM(T[i], tol=RTB_TOL)
        if sol.q is not None:
            Q[i] = sol.q
        ok[i] = bool(sol.success)
        iters[i] = sol.iterations
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    name = ("RTB ETS.ik_LM (C++, one call per target)" if kind == "ik_LM"
            else "RTB DHRobot.ikine_LM (Python, one call per target)")
    row = {"solver": name, "n": n, "wall_s": wall, "cpu_s": cpu,
           "mean_iterations": float(np.mean(iters))}
    row.update(verify(robot, T[:n], Q, ok))
    return row


def table(rows, ref):
    lines = ["| solver | targets | wall time [s] | CPU time [s] | throughput [targets/s] | "
             "kincal / this | success claimed | success verified by FK | mean iterations |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        thr = r["n"] / r["wall_s"]
        cpu = "-" if r["cpu_s"] != r["cpu_s"] else f"{r['cpu_s']:.3f}"
        lines.append(f"| {r['solver']} | {r['n']} | {r['wall_s']:.3f} | {cpu} | {thr:,.0f} | "
                     f"{ref / thr:.2f}x | {100 * r['claimed']:.2f} % | "
                     f"{100 * r['verified']:.2f} % | {r['mean_iterations']:.1f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="targets (default 10 000)")
    ap.add_argument("--rtb-n", type=int, default=2_000,
                    help="targets for RTB's one-call-per-target ik_LM (default 2 000)")
    ap.add_argument("--ikine-n", type=int, default=200,
                    help="targets for the slow Python ikine_LM (default 200)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (>= 5)")
    ap.add_argument("--seed", type=int, default=20240601)
    ap.add_argument("--json", default=None, help="write the results as JSON here")
    args = ap.parse_args()

    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(args.seed)
    lim = robot.joint_limits
    T = robot.fk(rng.uniform(lim[:, 0], lim[:, 1], size=(args.n, robot.n)))
    print(f"# IK benchmark: {args.n} PUMA 560 targets, tolerance {TOL:g} m / {TOL:g} rad")
    print(machine())

    fns = {"kincal": lambda: run_kincal(robot, T),
           "closed": lambda: run_closed_form(robot, T)}
    try:
        import roboticstoolbox as rtb
    except Exception as exc:                # a message instead of a traceback
        print(f"roboticstoolbox-python unavailable ({type(exc).__name__}: {exc})")
        rtb = None
    if rtb is not None:
        rr = rtb_robot(rtb, robot)
        q_chk = rng.uniform(lim[:, 0], lim[:, 1], size=(50, robot.n))
        diff = max(np.abs(np.asarray(rr.ets().eval(q)) - robot.fk(q)).max() for q in q_chk)
        if diff > 1e-12:
            sys.exit(f"RTB and kincal PUMA models differ by {diff:g}")
        print(f"RTB {rtb.__version__}: models agree to {diff:.1e} m")
        fns["ik_LM"] = lambda: run_rtb("ik_LM", rr, robot, T, min(args.rtb_n, args.n))
        fns["ikine_LM"] = lambda: run_rtb("ikine_LM", rr, robot, T, min(args.ikine_n, args.n))
    # every solver once per round, the order rotated, medians (timing.interleaved)
    t = interleaved(fns, rounds=args.rounds, warmup=False)
    rows = []
    for k in fns:
        row = dict(t.results[k])
        row["wall_s"], row["cpu_s"] = t.median(k), t.median(k, cpu=True)
        rows.append(row)
    ref = rows[0]["n"] / rows[0]["wall_s"]
    print()
    print(table(rows, ref))
    print(f"\n'kincal / this' = kincal solve_ik throughput / this solver's throughput (wall "
          f"clock, targets per second); times are medians of {args.rounds} interleaved rounds "
          f"(the RTB solvers on the first --rtb-n / --ikine-n targets). Load after: "
          f"{load_average()}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"tolerance": TOL, "n": args.n, "rows": rows}, f, indent=2)


if __name__ == "__main__":
    main()
