"""Filtering a 10 000-target robot program: KRL (branches from S/T) and URScript (no branches).

    python benchmarks/filter.py                  # 10 000 targets, 5 interleaved repeats
    python benchmarks/filter.py -n 2000 --repeats 7

The programs are written here: N Cartesian targets drawn from configurations uniformly
inside the joint limits (away from the wrist singularity), as a KUKA KR 6 ``.dat`` with
``E6POS`` points (and their S/T) used by ``LIN`` motions, and as a UR5 URScript with
``movel(p[...])`` calls.  The calibrated robot has 1 mm / 0.05 deg / 0.1 deg errors.
Each repeat runs the whole of :func:`kincal.compensation.programs.driver.filter_program`
(read, closed-form or numerical nominal IK, calibrated IK, FK, write back), the two
programs interleaved (A B A B ...); the table gives the median and the spread of the
repeats, and the number of targets filtered (the rest lie where the calibrated
robot cannot reach them on the asked branch: the workspace boundary).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from timing import interleaved

from kincal.compensation.configuration import Configurator
from kincal.compensation.programs.driver import filter_program
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.controller import controller_map
from kincal.robots.files import load_serial_robot
from kincal.spatial import log_so3, matrix_to_rpy


def _configs(robot, n: int, rng: np.random.Generator) -> np.ndarray:
    """Configurations inside the limits (3 deg from them) where the Jacobian's condition
    number is below 30: away from every singularity and the workspace boundary, where a
    calibrated robot may not reach a nominal target on the same branch."""
    q = random_configurations(robot, 4 * n, rng)
    lim = robot.joint_limits
    ok = np.all((q > lim[:, 0] + 0.05) & (q < lim[:, 1] - 0.05), axis=1)
    ok &= np.linalg.cond(robot.jacobian(q)) < 30
    return q[ok][:n]


def krl_program(folder: Path, n: int, rng: np.random.Generator) -> Path:
    nom = load_serial_robot("kr6")
    conf = Configurator.of(nom, controller_map(nom))
    q = _configs(nom, n, rng)
    T = nom.fk(q)
    s = conf.signs(q)
    S = (s[:, 0] < 0) * 1 + (s[:, 1] > 0) * 2 + (s[:, 2] < 0) * 4
    Tb = sum(((np.degrees(q[:, k]) < 0) * 1) << k for k in range(6))
    rpy = np.degrees(matrix_to_rpy(T[:, :3, :3]))
    dat = ["DEFDAT bench"]
    src = ["DEF bench( )"]
    for i in range(n):
        x, y, z = T[i, :3, 3] * 1e3
        dat.append(f"DECL E6POS XP{i}={{X {x:.3f},Y {y:.3f},Z {z:.3f},A {rpy[i, 2]:.3f},"
                   f"B {rpy[i, 1]:.3f},C {rpy[i, 0]:.3f},S {S[i]},T {Tb[i]},E1 0.0}}")
        src.append(f"LIN XP{i} C_DIS")
    dat.append("ENDDAT")
    src.append("END")
    (folder / "bench.dat").write_bytes(("\r\n".join(dat) + "\r\n").encode("latin-1"))
    (folder / "bench.src").write_bytes(("\r\n".join(src) + "\r\n").encode("latin-1"))
    return folder / "bench.src"


def ur_program(folder: Path, n: int, rng: np.random.Generator) -> Path:
    nom = load_serial_robot("ur5")
    q = _configs(nom, n, rng)
    T = nom.fk(q)
    lines = ["def bench():"]
    for i in range(n):
        r = log_so3(T[i, :3, :3])
        p = T[i, :3, 3]
        lines.append(f"  movej([{', '.join(f'{v:.6f}' for v in q[i])}])")
        lines.append(f"  movel(p[{p[0]:.6f}, {p[1]:.6f}, {p[2]:.6f}, {r[0]:.6f}, {r[1]:.6f}, "
                     f"{r[2]:.6f}])")
    lines.append("end")
    (folder / "bench.script").write_text("\n".join(lines) + "\n")
    return folder / "bench.script"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", "--targets", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        runs = {"KRL, KR 6 (S/T, closed form)": ("kr6", krl_program(folder, args.targets, rng)),
                "URScript, UR5 (numerical IK)": ("ur5", ur_program(folder, args.targets, rng))}
        robots = {}
        for name, (robot, _) in runs.items():
            nom = load_serial_robot(robot)
            robots[name] = (nom, perturb_robot(nom, np.random.default_rng(1)))
        t = interleaved({name: lambda path=path, name=name: filter_program(
            str(path), robots[name][1], robots[name][0]) for name, (_, path) in runs.items()},
            rounds=args.repeats, warmup=False)
        filtered: dict[str, int] = {}
        for name in runs:
            poses = [r for r in t.results[name].reports if r.kind == "pose"]
            filtered[name] = sum(r.status == "filtered" for r in poses)
            if filtered[name] < 0.99 * len(poses):
                sys.exit(f"{name}: only {filtered[name]} of {len(poses)} targets filtered")
        print(f"filtering a program with {args.targets} Cartesian targets "
              f"({args.repeats} interleaved repeats)")
        print("| program | median | min - max | targets/s | filtered |")
        print("|---|---|---|---|---|")
        for name, ts in t.wall.items():
            med = t.median(name)
            print(f"| {name} | {med:.2f} s | {min(ts):.2f} - {max(ts):.2f} s | "
                  f"{args.targets / med:,.0f} | {filtered[name]} |")


if __name__ == "__main__":
    main()
