"""The ``demo`` command: a complete calibration in about ten seconds.

A PUMA 560 with injected geometric errors is measured by a simulated laser tracker,
calibrated (encoder offsets first, then everything identifiable), validated on
held-out poses and checked against the (known) truth; the files and the HTML report
land in one folder.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import Progress, out_console, print_errors, print_identifiability
from kincal.cli.common import JsonOut
from kincal.cli.options import SeedOpt, SiOpt, quantity, use_si


@app.command()
def demo(
    out_dir: Annotated[str, typer.Option("--out-dir", help="Folder for the demo's files.")
                       ] = "kincal-demo",
    seed: SeedOpt = 7,
    poses: Annotated[int, typer.Option("-n", "--poses", min=10, help="Training poses.")] = 80,
    holdout_poses: Annotated[int, typer.Option(min=1, help="Held-out poses.")] = 40,
    noise: Annotated[str, typer.Option("--noise", help="Tracker noise per coordinate, with "
                                       "its unit.")] = "0.01mm",
    si: SiOpt = False,
    json_out: JsonOut = None,
) -> None:
    """A complete calibration in a few seconds: PUMA 560 measured by a simulated laser tracker,
    calibrated, validated on held-out poses; writes the report into ./kincal-demo/."""
    import numpy as np

    from kincal.io import atomic_write_text
    from kincal.measure.base import Provenance
    from kincal.measure.registry import get_instrument, simulate_measurements, write_measurements
    from kincal.measure.simulate import perturb_robot
    from kincal.robots.files import load_serial_robot, robot_yaml_text
    from kincal.workflow.flow import block_values, run_flow, write_outputs

    t0 = time.perf_counter()
    folder = Path(out_dir)
    sd = quantity(noise, "length", "--noise", minimum=0.0) or 0.0
    cu = use_si(si)
    out = out_console(json_out)
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(seed)
    true = perturb_robot(nominal, rng, length_std=5e-4, angle_std=math.radians(0.05),
                         offset_std=math.radians(0.1))
    inst = get_instrument("position")
    train, inst_truth = simulate_measurements(inst, true, rng, poses, sd,
                                              {"name": "tracker"})
    held, _ = simulate_measurements(inst, true, rng, holdout_poses, sd,
                                    {"name": "tracker"}, truth=inst_truth)
    out.print(f"[bold]kincal demo[/bold]: PUMA 560 with injected geometric errors "
                  f"(lengths 0.5 mm, angles 0.05°, encoder offsets 0.1°), measured by a "
                  f"simulated laser tracker (noise {cu.value(sd, 'm', 4)}) at {poses} poses; "
                  f"{holdout_poses} more poses held out.")
    folder.mkdir(parents=True, exist_ok=True)
    files = {"train": folder / "train.csv", "holdout": folder / "holdout.csv",
             "truth": folder / "truth.yaml"}
    units = {"length": "mm", "angle": "deg"}
    write_measurements(inst, train, files["train"], units, nominal)
    write_measurements(inst, held, files["holdout"], units, nominal)
    atomic_write_text(files["truth"], robot_yaml_text(true))
    for b, p in ((train[0], files["train"]), (held[0], files["holdout"])):
        b.provenance = Provenance(str(p))
    with Progress(100, json_out != "-") as bar:
        flow = run_flow(nominal, train, held, stages=["offsets", "all"], progress=bar)
    res = flow.result
    truth_vals = {**true.params(), **inst_truth}
    inputs = {"robot": "puma560 (built-in)", "data": str(files["train"]),
              "validation": str(files["holdout"]), "truth": str(files["truth"]),
              "stages": "offsets, all", "method": "lm"}
    write_outputs(flow, str(folder / "calibrated.yaml"), None, str(folder / "result.json"),
                  str(folder / "report.html"), inputs, truth_vals)
    conv = "converged" if res.converged else "did NOT converge"
    out.print(f"calibration {conv} in {res.iterations_text()} "
              f"({flow.seconds:.2f} s); {len(res.estimated)} parameters estimated.")
    print_errors(out, flow.comparisons)
    # Independent check against the truth: the measured point predicted by the calibrated
    # model vs the true robot on the held-out poses, in the tracker frame.
    q = held[0].q
    yt = held[0].predict(true, block_values(inst_truth, held[0]))
    yc = held[0].predict(res.robot, res.theta[res.problem.block_slice("tracker")])
    dev = np.linalg.norm((yc - yt).reshape(-1, 3), axis=1)
    out.print(f"model vs truth on the {len(q)} held-out poses (noise-free): RMS "
              f"{cu.value(math.sqrt(np.mean(dev**2)), 'm')}, max "
              f"{cu.value(float(np.max(dev)), 'm')}")
    print_identifiability(out, res)
    for w in flow.warnings:
        out.print(f"[yellow]warning[/yellow]: {escape(w)}")
    out.print(f"report: [bold]{escape(str(folder / 'report.html'))}[/bold]  (also "
              f"calibrated.yaml, result.json, train.csv, holdout.csv, truth.yaml in "
              f"{escape(str(folder))}/)   [{time.perf_counter() - t0:.1f} s]")
    if json_out:
        from kincal.io import write_json

        doc = json.loads((folder / "result.json").read_text(encoding="utf-8"))
        doc["model_vs_truth_heldout"] = {"rms_position_m": math.sqrt(np.mean(dev**2)),
                                         "max_position_m": float(np.max(dev))}
        doc["folder"] = str(folder)
        write_json(json_out, doc)
