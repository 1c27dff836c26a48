#!/usr/bin/env bash
# Experiment design (docs/tutorials/experiment-design.md): choose the poses to measure a
# PUMA 560 at before measuring anything, read the figures `kincal plan` prints, choose how
# many poses, and hand the poses to the robot as a program.
set -euo pipefail

# --8<-- [start:plan]
kincal plan puma560 -n 15 -o poses.csv --report plan.html
# --8<-- [end:plan]

# --8<-- [start:file]
head -n 4 poses.csv
# --8<-- [end:file]

# --8<-- [start:criteria]
for criterion in O1 O4 kappa; do
    kincal plan puma560 -n 15 -c "$criterion" -o "poses-$criterion.csv" \
        | grep -E "^│ ($criterion design|random)"
done
# --8<-- [end:criteria]

# --8<-- [start:how-many]
for n in 10 15 30 60; do
    echo "$n poses (predicted error after calibration: RMS, 95 %, max [mm]):"
    kincal plan puma560 -n "$n" -o "poses-$n.csv" | grep -E "^│ (O1 design|random)"
done
kincal plan puma560 -n 8 -o too-few.csv || echo "exit status $?"
# --8<-- [end:how-many]

# --8<-- [start:program]
kincal plan puma560 -n 15 --program urscript --dwell 2s -o poses.script | tail -n 2
head -n 12 poses.script
# --8<-- [end:program]
