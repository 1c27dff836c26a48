"""ISO 9283 acceptance figures before and after calibration (docs/tutorials/iso9283.md).

A KR 6 with known errors is calibrated on simulated tracker data; the ISO 9283 test
cycles are planned, "run" on the true robot (its repeatability and the tracker's noise
added), and the figures computed for the nominal and the calibrated model.
"""

from __future__ import annotations

import csv
import subprocess

import numpy as np

import kincal


def sh(command: str) -> None:
    """Run a shell command (a kincal command line) and stop on failure."""
    subprocess.run(command, shell=True, check=True)


# --8<-- [start:calibrate]
sh("kincal simulate kr6 -o train.csv --truth truth.yaml -n 60 --noise 0.01mm --seed 1")
sh("kincal calibrate kr6 --data train.csv -o calibrated.yaml > calibrate.txt")
# --8<-- [end:calibrate]

# --8<-- [start:plan]
sh("kincal plan kr6 --iso9283 --cycles 30 --cube-size 300mm -o iso.csv")
# --8<-- [end:plan]

# --8<-- [start:measure]
# the robot runs the 150 moves; the tracker measures the flange at each stop
robot = kincal.load_robot("kr6")
rows = [r for r in csv.reader(open("iso.csv")) if r and not r[0].startswith("#")]
header, values = rows[0], np.array(rows[1:], dtype=float)
q = np.radians(values) if header[0].endswith("_deg") else values
truth = kincal.load_robot("truth.yaml")
rng = np.random.default_rng(2)
repeatability = rng.normal(0, 0.01, (len(q), 3))          # the arm's own scatter [mm]
p = truth.fk(q)[:, :3, 3] * 1e3 + repeatability + rng.normal(0, 0.01, (len(q), 3))
with open("cycles.csv", "w", newline="") as f:
    f.write("# kincal measurements: instrument=position; name=tracker; sigma_mm=0.01\n")
    out = csv.writer(f)
    out.writerow([f"{j}_rad" for j in robot.joint_names] + ["x_mm", "y_mm", "z_mm"])
    out.writerows([*qi, *pi] for qi, pi in zip(q, p, strict=True))
print(f"{len(q)} stops measured -> cycles.csv")
# --8<-- [end:measure]

# --8<-- [start:figures]
sh("kincal validate calibrated.yaml --data cycles.csv --before kr6 --iso9283")
# --8<-- [end:figures]
