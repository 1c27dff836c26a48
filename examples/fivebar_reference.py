"""The dual SCARA calibration experiment of Pittr (2012), chapter 4, with kincal.

True lengths [1.86, 2.2, 2.8, 3.3] m, nominal [2, 2, 3, 3] m, bases B1 = (1, 0) m
and B2 = (-1, 0) m (kincal's choice; the thesis gives none), end points from the
direct kinematics with beta1 in (0, pi/2), beta2 in (pi/2, pi), stop threshold
1e-10.  Prints the lengths at each iteration, writes one plot per length (like
the thesis's figures 4.1-4.4) and the result with its history as JSON, then
repeats the run with the task-space residual and with noisy readings.

    python examples/fivebar_reference.py [output folder]

The same from the command line: ``kincal fivebar-demo --out-dir DIR --json FILE``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from kincal.parallel.reference_experiment import (
    EXPERIMENT_TRUE_LENGTHS,
    plot_reference_experiment,
    run_reference_experiment,
)


def main(out: Path) -> None:
    result, true = run_reference_experiment(n=50, seed=0, method="gauss-newton", residual="ik")
    print(
        f"bases: B1 = ({true.base1_x}, {true.base1_y}) m, B2 = ({true.base2_x}, {true.base2_y}) m"
    )
    print("iteration " + " ".join(f"{k:>16s}" for k in EXPERIMENT_TRUE_LENGTHS) + "     max step")
    for h in result.history:
        values = " ".join(f"{h['params'][k]:16.12f}" for k in EXPERIMENT_TRUE_LENGTHS)
        print(f"{h['iteration']:9d} {values} {h['step']:12.3g}")
    print("true      " + " ".join(f"{v:16.12f}" for v in EXPERIMENT_TRUE_LENGTHS.values()))
    for path in plot_reference_experiment(result, true, out):
        print("wrote", path)
    print("wrote", result.to_json(out / "fivebar_reference.json"))

    fk_result, _ = run_reference_experiment(residual="fk")
    err = max(abs(fk_result.params[k] - v) for k, v in EXPERIMENT_TRUE_LENGTHS.items())
    print(f"task-space residual: {fk_result.iterations} iterations, largest error {err:.2g} m")

    noisy, _ = run_reference_experiment(noise=math.radians(0.05), seed=1)
    print("with 0.05 deg reading noise: estimate +- standard error")
    for k, v in EXPERIMENT_TRUE_LENGTHS.items():
        print(f"  {k}: {noisy.params[k]:.6f} +- {noisy.std_errors[k]:.6f} m (true {v})")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("fivebar-thesis"))
