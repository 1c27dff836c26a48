"""What ``--select auto`` costs: one default calibration against the model selection.

The selection fits every candidate (joint models x prior scales) once on all the
training data and once per fold: ``candidates x (K + 1)`` fits.  Timed on the real data
of ``../shared/data`` through :func:`kincal.workflow.flow.run_flow` (what ``kincal
calibrate`` runs, without reading the files or printing):

* TIAGo, 37 postures, point 1: 12 candidates (hysteresis, compliance from the URDF's
  masses), 10 folds;
* Motoman right arm, 212 grid poses: 6 candidates (no masses), 10 folds.

Timing: interleaved rounds, medians and the median of same-round ratios (:mod:`timing`).
One BLAS thread.

    python benchmarks/selection.py [--rounds 5]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

from timing import interleaved, machine  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def problems() -> dict[str, tuple]:
    from kincal.robots.files import load_serial_robot
    from kincal.robots.urdf import load_urdf, load_urdf_inertials
    from kincal.workflow.flow import read_blocks

    urdf = DATA / "tiago_mocap" / "tiago_48_schunk.urdf"
    tiago = load_urdf(urdf, tip_link="wrist_ft_tool_link")
    t_blocks = read_blocks([DATA / "tiago_mocap" / "train_2021-11-30.csv"], tiago,
                           "x1=m,y1=m,z1=m", ["?2,?3,?4"])
    masses = load_urdf_inertials(urdf, tip_link="wrist_ft_tool_link")
    moto = load_serial_robot("motoman_right")
    m_blocks = read_blocks([DATA / "motoman_leica" / "right_arm_grid_6x6x6.csv"], moto)
    return {"TIAGo (37 postures)": (tiago, t_blocks, masses),
            "Motoman (212 poses)": (moto, m_blocks, None)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    from kincal.workflow.flow import run_flow

    print(machine())
    print(f"{'problem':22s} {'default fit':>12s} {'--select auto':>14s} {'ratio':>7s}  choice")
    for name, (robot, blocks, masses) in problems().items():
        t = interleaved({
            "default": lambda r=robot, b=blocks: run_flow(r, b, max_iter=400),
            "auto": lambda r=robot, b=blocks, m=masses: run_flow(r, b, max_iter=400,
                                                                 select="auto", masses=m),
        }, rounds=args.rounds)
        choice = t.results["auto"].selection.choice
        print(f"{name:22s} {t.median('default'):10.2f} s {t.median('auto'):12.2f} s "
              f"{t.ratio('auto', 'default'):6.1f}x  {choice.label if choice else '-'}")


if __name__ == "__main__":
    main()
