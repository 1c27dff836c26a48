#!/usr/bin/env bash
# Laser tracker calibration step by step (docs/tutorials/laser-tracker.md): a PUMA 560
# with injected errors, measured by a simulated tracker, identified, calibrated,
# validated on poses the fit never saw, and compensated.
set -euo pipefail

# --8<-- [start:simulate]
kincal simulate puma560 -o train.csv --truth truth.yaml -n 80 --noise 0.01mm --seed 1 \
    --holdout holdout.csv --holdout-poses 40
head -n 3 train.csv
# --8<-- [end:simulate]

# --8<-- [start:identifiability]
kincal identifiability puma560 --data train.csv
# --8<-- [end:identifiability]

# --8<-- [start:calibrate]
kincal calibrate puma560 --data train.csv --validate holdout.csv --stages offsets,all \
    -o calibrated.yaml --json result.json --report report.html
# --8<-- [end:calibrate]

# --8<-- [start:validate]
kincal validate calibrated.yaml --data holdout.csv --result result.json --before puma560
# --8<-- [end:validate]

# --8<-- [start:compensate]
cat > targets.csv <<'CSV'
x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg
450,150,300,0,90,0
500,-100,250,0,90,0
420,0,420,0,90,0
CSV
kincal compensate calibrated.yaml --targets targets.csv --nominal puma560 \
    --result result.json -o joints.csv --filtered filtered.csv
cat joints.csv
# --8<-- [end:compensate]

# --8<-- [start:report]
ls -l --block-size=K report.html calibrated.yaml result.json | awk '{print $5, $9}'
# --8<-- [end:report]
