"""Fleet prior vs the per-robot default prior on the MUKCa Pandas, leave one robot out.

For each Panda of ``examples/fleets/mukca.yaml`` (five robots, one campaign each):

1. the fleet prior (:mod:`kincal.fleet.prior`) is estimated from the full-campaign
   calibrations of the *other* four robots;
2. the robot is calibrated from ``n`` seatings per socket of its first placement (evenly
   spaced rows of ``hole_0.csv`` / ``hole_1.csv``), once with kincal's default (nominal
   model, default tolerances, automatic parameter selection) and once with the fleet
   prior (the fleet-mean robot with the fleet spread as its tolerances, every parameter
   of the prior free);
3. both are measured on the robot's other placements (held out, neither fit saw them):
   the RMS spread of the predicted ball positions in each socket, and the RMS error of
   the 50 mm socket distance.

Run from the root of a clone (the data in ../shared/data)::

    python benchmarks/fleet_prior.py            # prints the table (a few minutes)
    python benchmarks/fleet_prior.py --plot docs/img/fleet_prior.png
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from kincal.fleet.manifest import load_manifest
from kincal.fleet.prior import fleet_prior, fleet_prior_robot
from kincal.fleet.tasks import _robot_of, calibrate_session, source_of
from kincal.report.metrics import result_json
from kincal.workflow.flow import run_flow
from kincal.workflow.session import read_session

MANIFEST = Path(__file__).resolve().parent.parent / "examples" / "fleets" / "mukca.yaml"
POSES = (4, 8, 15, 0)              # seatings per socket of the one training placement (0: all)


def _subset(folder: str, n: int, out: Path) -> str:
    """A copy of a MUKCa placement folder with ``n`` evenly spaced seatings per socket."""
    out.mkdir(parents=True, exist_ok=True)
    for hole in ("hole_0.csv", "hole_1.csv"):
        rows = Path(folder, hole).read_text().splitlines()
        rows = [r for r in rows if r.strip()]
        keep = rows if n <= 0 or n >= len(rows) else [
            rows[int(i)] for i in np.linspace(0, len(rows) - 1, n).round()]
        (out / hole).write_text("\n".join(keep) + "\n")
    return str(out)


def _held_out(robot: Any, train: list[Any], held: list[Any], spec: str,
              free: str | None) -> dict[str, float]:
    session = read_session(robot, train, held, spec=spec)
    flow = run_flow(session.robot, session.blocks, session.holdouts, free=free)
    val = result_json(flow.result, flow.comparisons)["metrics"]["validation"]
    return {"spread": float(val["rms_coincidence_m"]),
            "distance": float(val["rms_distance_m"]), "trusted": bool(flow.trusted)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(MANIFEST))
    ap.add_argument("--plot", help="write the curve as a PNG here")
    args = ap.parse_args(argv)
    tasks = load_manifest(args.manifest)
    full = {t.serial: calibrate_session(t) for t in tasks}
    bad = [s for s, r in full.items() if r["status"] != "ok"]
    if bad:
        print(f"full-campaign calibration failed for {bad}", file=sys.stderr)
        return 1
    rows: dict[tuple[str, int], dict[str, dict[str, float]]] = {}
    sizes: dict[tuple[str, int], int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for task in tasks:
            others = [full[s] for s in full if s != task.serial]
            prior = fleet_prior(others)
            prior_robot = fleet_prior_robot(prior)
            free = ",".join([p.name for p in prior.parameters] + ["ball.*"])
            nominal = _robot_of(task)
            first, *rest = [source_of(f) for f in task.data]
            held = rest
            for n in POSES:
                sub = _subset(first.path, n, Path(tmp, task.serial, f"n{n}", "front"))
                train = [dataclasses.replace(first, path=sub)]
                sizes[task.serial, n] = sum(
                    1 for h in ("hole_0.csv", "hole_1.csv")
                    for r in Path(sub, h).read_text().splitlines() if r.strip())
                rows[task.serial, n] = {
                    "default": _held_out(nominal, train, held, task.robot, None),
                    "fleet": _held_out(prior_robot, train, held, task.robot, free)}
                r = rows[task.serial, n]
                print(f"{task.serial} n={n or 'all'}: default {r['default']['spread'] * 1e3:.3f}"
                      f" mm, fleet prior {r['fleet']['spread'] * 1e3:.3f} mm", file=sys.stderr)
    serials = [t.serial for t in tasks]
    print("Held-out error of a new Panda (leave one robot out; RMS over its held-out "
          "placements, mm)")
    print()
    print("| seatings per socket (poses) | ball spread, default | ball spread, fleet prior "
          "| socket distance, default | socket distance, fleet prior |")
    print("|---|---|---|---|---|")
    curve = []
    for n in POSES:
        d = [rows[s, n]["default"] for s in serials]
        f = [rows[s, n]["fleet"] for s in serials]
        poses = int(round(np.mean([sizes[s, n] for s in serials])))

        def rms(xs: list[dict[str, float]], k: str) -> float:
            return math.sqrt(float(np.mean([x[k] ** 2 for x in xs]))) * 1e3

        curve.append((poses, rms(d, "spread"), rms(f, "spread")))
        print(f"| {n or 'all'} ({poses}) | {rms(d, 'spread'):.3f} | {rms(f, 'spread'):.3f} | "
              f"{rms(d, 'distance'):.3f} | {rms(f, 'distance'):.3f} |")
    print()
    print("Per robot, ball spread default / fleet prior [mm]:")
    for s in serials:
        print(f"  {s}: " + ", ".join(
            f"n={n or 'all'} {rows[s, n]['default']['spread'] * 1e3:.3f} / "
            f"{rows[s, n]['fleet']['spread'] * 1e3:.3f}" for n in POSES))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5.5, 3.6))
        x = [c[0] for c in curve]
        ax.plot(x, [c[1] for c in curve], "o-", label="default prior (per robot)")
        ax.plot(x, [c[2] for c in curve], "s-", label="fleet prior (other 4 robots)")
        ax.set_xlabel("training poses (one placement)")
        ax.set_ylabel("held-out ball spread RMS [mm]")
        ax.set_title("New MUKCa Panda, leave one robot out")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
