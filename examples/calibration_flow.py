"""The calibration flow of the lecture slides with the library API, on a simulated PUMA 560.

1. make a "real" robot: the nominal PUMA 560 plus geometric errors (the lecture's
   tolerances and encoder zero offsets);
2. measure it with a simulated laser tracker (a reflector on the flange, 0.01 mm
   noise) at 80 training and 40 held-out configurations, and write / read the
   measurement files (CSV with units in every header);
3. calibrate in two stages, as the lecture advises: the encoder offsets first, then
   every identifiable parameter (iterative linearised least squares /
   Levenberg-Marquardt); print what the data cannot identify;
4. validate on the held-out file with the training frames (no refit);
5. compensate: joint commands that put the real robot on target poses, and the
   filtered targets for a controller that only knows the nominal model;
6. write the calibrated robot (YAML), the result JSON and the HTML report.

Run:  python examples/calibration_flow.py [--out calibration_flow_out] [--seed 3]
The same flow on the command line: `kincal demo`, or `kincal simulate` ->
`kincal calibrate` -> `kincal validate` -> `kincal compensate`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import kincal
from kincal.compensation.compensate import compensate
from kincal.identify.solver import calibrate
from kincal.identify.validation import validate
from kincal.io import write_json
from kincal.measure.registry import read_measurements, simulate_measurements, write_measurements
from kincal.measure.simulate import perturb_robot
from kincal.report.html import write_html_report
from kincal.report.metrics import ErrorComparison, error_metrics, result_json
from kincal.robots.files import write_robot_yaml


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="calibration_flow_out")
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(a.seed)

    # 1. the nominal model and the "real" robot
    nominal = kincal.load_robot("puma560")
    real = perturb_robot(nominal, rng, length_std=5e-4)

    # 2. a simulated laser tracker; the held-out data reuse the same placement (truth=)
    train, placement = simulate_measurements("position", real, rng, 80, 1e-5)
    held, _ = simulate_measurements("position", real, rng, 40, 1e-5, truth=placement)
    units = {"length": "mm", "angle": "deg"}
    write_measurements("position", train, out / "train.csv", units, nominal)
    write_measurements("position", held, out / "holdout.csv", units, nominal)
    train = read_measurements(out / "train.csv", nominal)     # what a user would do
    held = read_measurements(out / "holdout.csv", nominal)

    # 3. calibrate: offsets first, then everything identifiable
    res = calibrate(nominal, train, stages=["offsets", "all"])
    print(res.summary())

    # 4. validation with the training frames (the tracker did not move)
    before = validate(nominal, held, register=True)
    after = validate(res.robot, held, extras=res.extras())
    print(f"\nheld-out RMS: nominal {before['overall']['rms_position_m'] * 1e3:.4f} mm -> "
          f"calibrated {after['overall']['rms_position_m'] * 1e3:.4f} mm")

    # 5. compensation: targets the nominal model reaches at well-conditioned configurations
    q = held[0].q[:10]
    targets = nominal.fk(q)
    comp = compensate(res.robot, targets, nominal=nominal)
    print(f"compensation: {int(comp.success.sum())}/{len(comp)} targets, calibrated FK error "
          f"{comp.position_error.max():.1e} m, filtered targets move by up to "
          f"{comp.correction.max() * 1e3:.3f} mm")

    # 6. outputs
    b, h = train[0], held[0]
    x_nom = np.array([before["extras"][h.name][n] for n in h.parameters().names])
    comparisons = [
        ErrorComparison("train", "training data",
                        b.errors(nominal, b.initial_guess(nominal)),
                        b.errors(res.robot, res.theta[res.problem.block_slice(b.name)])),
        ErrorComparison("validation", "held-out data", h.errors(nominal, x_nom),
                        h.errors(res.robot, res.theta[res.problem.block_slice(h.name)]),
                        "frames from training")]
    write_robot_yaml(res.robot, out / "calibrated.yaml")
    write_json(out / "result.json", result_json(res, comparisons))
    write_html_report(out / "report.html", res, comparisons,
                      truth={**real.params(), **placement})
    print({c.label: round(error_metrics(c.after)["rms_position_m"] * 1e3, 4)
           for c in comparisons}, "mm;", f"files in {out}/")


if __name__ == "__main__":
    main()
