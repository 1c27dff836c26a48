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

# --8<-- [start:camera]
cat > board.yaml <<'YAML'
type: charuco
squares: [5, 7]
square: 34mm
marker: 28mm
dictionary: DICT_6X6_250
YAML
cat > camera.yaml <<'YAML'
image_width: 1280
image_height: 720
camera_matrix: {rows: 3, cols: 3, data: [640, 0, 645, 0, 641, 355, 0, 0, 1]}
distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}
YAML
kincal plan panda --camera hand --board board.yaml --intrinsics camera.yaml \
    --camera-pose 40,-30,60mm,45,0,0deg --center 0,-17,0,-115,0,103,46 \
    --free 'theta_offset*' -n 12 --angle-unit deg -o camera-poses.csv
head -n 7 camera-poses.csv
# --8<-- [end:camera]
