"""Forward kinematics and geometric Jacobian throughput: kincal vs RTB and pybotics.

Run it in the benchmark environment (the peers are never dependencies of kincal)::

    python -m venv /work/benchvenv
    /work/benchvenv/bin/pip install -e '/work/main[bench]'
    /work/benchvenv/bin/python benchmarks/kinematics.py            # N = 1k, 10k, 100k
    /work/benchvenv/bin/python benchmarks/kinematics.py --loop-cap 0  # looped peers on all N

What is timed, for the same PUMA 560 (all three models are checked to agree first):

* kincal: ``Robot.fk(Q)`` and ``Robot.jacobian(Q)``, one batched NumPy call for all N.
* Robotics Toolbox for Python (RTB): ``ETS.eval(Q)`` on ``rtb.models.DH.Puma560().ets()``,
  its fastest documented batched FK (an (N, n) trajectory goes to the C++ extension in
  one call); ``ETS.jacob0(q)``, C++ but one configuration per call (RTB has no batched
  Jacobian), so it is looped in Python; ``DHRobot.fkine(Q)``, documented for (N, n) but
  a Python loop over links and rows that builds ``SE3`` objects.
* pybotics: ``Robot.fk(q)`` and ``Robot.jacobian_world(q)``, one configuration per call
  (no batched API), looped in Python.

Times are medians of at least five interleaved rounds (every contender once per round, the
order rotated: a busy moment slows all alike; :mod:`timing`), never best-of; the slow
Python-looped peers are timed on at most ``--loop-cap`` configurations (extrapolated).  ``ratio`` is
kincal throughput / peer throughput.  Targets (issue 2): kincal FK >= 3x RTB
``ETS.eval`` and Jacobian >= 10x RTB ``ETS.jacob0`` at N = 100 000.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from timing import interleaved, machine  # noqa: E402

try:
    from kincal.robots.dh import dh_links, standard_to_modified
    from kincal.robots.files import load_serial_robot
    from kincal.spatial import matrix_from_frame
except ImportError:  # pragma: no cover - a message instead of a traceback
    sys.exit("kincal is not installed in this environment: pip install -e /path/to/kincal")

SIZES = (1_000, 10_000, 100_000)
FK_TARGET, JAC_TARGET = 3.0, 10.0


# --------------------------------------------------------------------------- peers
def _import_rtb():
    try:
        import roboticstoolbox as rtb
    except Exception as exc:  # ImportError, or a peer broken by its own dependencies
        return None, f"roboticstoolbox-python unavailable ({type(exc).__name__}: {exc})"
    return rtb, None


def _import_pybotics():
    try:
        import pybotics
        from pybotics.kinematic_chain import MDHKinematicChain
        from pybotics.robot import Robot
        from pybotics.tool import Tool
    except Exception as exc:
        return None, f"pybotics unavailable ({type(exc).__name__}: {exc})"
    return (pybotics, MDHKinematicChain, Robot, Tool), None


def _version(module_name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(module_name)
    except PackageNotFoundError:
        return "?"


# --------------------------------------------------------------------------- models
def kincal_puma(rtb_robot=None):
    """kincal's library PUMA 560; with RTB present, its DH values set to RTB's model
    (RTB puts the shoulder height d1 = 0.67183 m into the table, kincal's file has d1 = 0)."""
    robot = load_serial_robot("puma560")
    if rtb_robot is None:
        return robot
    values = {}
    for i, link in enumerate(rtb_robot.links, start=1):
        values.update({f"a[{i}]": link.a, f"d[{i}]": link.d, f"alpha[{i}]": link.alpha,
                       f"theta_offset[{i}]": link.offset})
    return robot.with_params(values)


def pybotics_puma(robot, peer):
    """The same robot for pybotics, which speaks modified DH: converted exactly by kincal."""
    _, MDHKinematicChain, PRobot, Tool = peer
    mod = standard_to_modified(robot)
    rows = np.array([[L.alpha, L.a, L.theta_offset, L.d] for L in dh_links(mod)])
    return PRobot(MDHKinematicChain(rows), tool=Tool(matrix=matrix_from_frame(
        mod.frame_parameters("tool"))), world_frame=matrix_from_frame(mod.frame_parameters("base")))


# --------------------------------------------------------------------------- timing
@dataclass
class Row:
    op: str
    n: int
    library: str
    call: str
    batched: bool
    seconds: tuple[float, float]          # (wall, CPU) for timed_on configurations
    timed_on: int

    @property
    def per_config(self) -> float:
        return self.seconds[0] / self.timed_on

    @property
    def cpu_per_config(self) -> float:
        return self.seconds[1] / self.timed_on


def medians(fns: dict[str, Callable[[], object]], rounds: int
            ) -> dict[str, tuple[float, float]]:
    """Median wall and CPU time of each function over ``rounds`` interleaved rounds
    (:func:`timing.interleaved`: the order rotated each round; never best-of)."""
    t = interleaved(fns, rounds=rounds)
    return {k: (t.median(k), t.median(k, cpu=True)) for k in fns}


def loop(fn: Callable[[np.ndarray], object], Q: np.ndarray) -> Callable[[], list]:
    return lambda: [fn(q) for q in Q]


# --------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES),
                    help="batch sizes N (default: 1000 10000 100000)")
    ap.add_argument("--loop-cap", type=int, default=10_000,
                    help="time Python-looped peers on at most this many configurations "
                         "(their time per batch is then extrapolated, marked *; 0 = all)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (>= 5)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    rtb, rtb_msg = _import_rtb()
    pyb, pyb_msg = _import_pybotics()
    for msg in (rtb_msg, pyb_msg):
        if msg:
            print(f"note: {msg}; its rows are skipped "
                  "(pip install roboticstoolbox-python pybotics)", file=sys.stderr)

    rtb_robot = rtb.models.DH.Puma560() if rtb else None
    robot = kincal_puma(rtb_robot)
    ets = rtb_robot.ets() if rtb else None
    prob = pybotics_puma(robot, pyb) if pyb else None

    rng = np.random.default_rng(args.seed)
    lim = robot.joint_limits

    # ---- the same computation? (1000 random configurations)
    Qc = rng.uniform(lim[:, 0], lim[:, 1], (1000, robot.n))
    Tk, Jk = robot.fk(Qc), robot.jacobian(Qc)
    agree = []
    if rtb:
        agree.append(("RTB ETS.eval", np.abs(Tk - ets.eval(Qc)).max()))
        fkine = np.array([T.A for T in rtb_robot.fkine(Qc[:200])])
        agree.append(("RTB DHRobot.fkine", np.abs(Tk[:200] - fkine).max()))
        agree.append(("RTB ETS.jacob0", max(np.abs(Jk[i] - ets.jacob0(q)).max()
                                            for i, q in enumerate(Qc))))
    if pyb:
        agree.append(("pybotics Robot.fk", max(np.abs(Tk[i] - prob.fk(q)).max()
                                               for i, q in enumerate(Qc))))
        agree.append(("pybotics jacobian_world", max(np.abs(Jk[i] - prob.jacobian_world(q)).max()
                                                     for i, q in enumerate(Qc))))

    rows: list[Row] = []
    loop_cap = args.loop_cap or None
    for N in args.sizes:
        Q = rng.uniform(lim[:, 0], lim[:, 1], (N, robot.n))
        M = min(N, loop_cap) if loop_cap else N
        Qm = Q[:M]
        # every contender in the same interleaved rounds, so that the ratios compare
        # times taken under the same load
        fns = {"kincal fk": lambda Q=Q: robot.fk(Q), "kincal J": lambda Q=Q: robot.jacobian(Q)}
        if rtb:
            fns["rtb eval"] = lambda Q=Q: ets.eval(Q)
            fns["rtb fkine"] = lambda Qm=Qm: rtb_robot.fkine(Qm)
            fns["rtb jacob0"] = loop(ets.jacob0, Qm)
        if pyb:
            fns["pyb fk"] = loop(prob.fk, Qm)
            fns["pyb J"] = loop(prob.jacobian_world, Qm)
        t = medians(fns, args.rounds)
        rows.append(Row("FK", N, "kincal", "Robot.fk(Q)", True, t["kincal fk"], N))
        rows.append(Row("Jacobian", N, "kincal", "Robot.jacobian(Q)", True, t["kincal J"], N))
        if rtb:
            rows.append(Row("FK", N, "RTB", "ETS.eval(Q)", True, t["rtb eval"], N))
            rows.append(Row("FK", N, "RTB", "DHRobot.fkine(Q)", False, t["rtb fkine"], M))
            rows.append(Row("Jacobian", N, "RTB", "ETS.jacob0(q)", False, t["rtb jacob0"], M))
        if pyb:
            rows.append(Row("FK", N, "pybotics", "Robot.fk(q)", False, t["pyb fk"], M))
            rows.append(Row("Jacobian", N, "pybotics", "Robot.jacobian_world(q)", False,
                            t["pyb J"], M))

    report(rows, agree, rtb is not None, pyb is not None)
    return 0


def report(rows: list[Row], agree: list[tuple[str, float]], have_rtb: bool,
           have_pyb: bool) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(width=170)
    rtb_v = _version("roboticstoolbox-python") if have_rtb else "-"
    pyb_v = _version("pybotics") if have_pyb else "-"
    console.print(f"[bold]PUMA 560 kinematics throughput[/bold]: kincal "
                  f"{_version('kincal')}, roboticstoolbox-python {rtb_v}, pybotics {pyb_v}; "
                  f"{machine()}")
    if agree:
        t = Table(title="Same computation? max |kincal - peer| over 1000 random configurations "
                  "(DHRobot.fkine: 200)")
        t.add_column("peer call")
        t.add_column("max abs difference", justify="right")
        for name, d in agree:
            t.add_row(name, f"{d:.2e}")
        console.print(t)

    t = Table(title="Time per batch (median of interleaved rounds), throughput, kincal/peer "
              "ratio (= peer time / kincal time)")
    cols = ("op", "N", "library", "call", "batched", "wall per batch", "configs/s",
            "kincal/peer", "CPU per batch", "kincal/peer CPU")
    for c in cols:
        t.add_column(c, justify="left" if c in ("op", "library", "call", "batched") else "right")
    ref = {(r.op, r.n): r for r in rows if r.library == "kincal"}
    for r in rows:
        k = ref[(r.op, r.n)]
        ratio = cpu_ratio = ""
        if r.library != "kincal":
            ratio = f"{r.per_config / k.per_config:,.1f}x"
            cpu_ratio = f"{r.cpu_per_config / k.cpu_per_config:,.1f}x"
        star = "*" if r.timed_on < r.n else ""
        batched = "1 call" if r.batched else "Python loop"
        t.add_row(r.op, f"{r.n:,}", r.library, r.call, batched,
                  f"{r.per_config * r.n * 1e3:,.2f} ms{star}", f"{1 / r.per_config:,.0f}", ratio,
                  f"{r.cpu_per_config * r.n * 1e3:,.2f} ms{star}", cpu_ratio)
    console.print(t)
    if any(r.timed_on < r.n for r in rows):
        cap = min(r.timed_on for r in rows if r.timed_on < r.n)
        console.print(f"* looped peer timed on the first {cap:,} configurations, time scaled to N")
    console.print("Wall time is what a user waits; CPU time (process time) leaves out the time "
                  "the process was descheduled, which matters on a busy machine.")

    if have_rtb:
        n_max = max(r.n for r in rows)
        per = {(r.op, r.call): r for r in rows if r.n == n_max}
        for what, op, peer, mine, want in (
                ("FK vs RTB ETS.eval", "FK", "ETS.eval(Q)", "Robot.fk(Q)", FK_TARGET),
                ("Jacobian vs RTB ETS.jacob0", "Jacobian", "ETS.jacob0(q)",
                 "Robot.jacobian(Q)", JAC_TARGET)):
            p, k = per[(op, peer)], per[(op, mine)]
            wall, cpu = p.per_config / k.per_config, p.cpu_per_config / k.cpu_per_config
            verdict = "[green]met[/green]" if min(wall, cpu) >= want else "[red]MISSED[/red]"
            console.print(f"target at N = {n_max:,}: {what} >= {want:g}x: {wall:.1f}x wall, "
                          f"{cpu:.1f}x CPU: {verdict}")


if __name__ == "__main__":
    sys.exit(main())
