#!/usr/bin/env bash
# The five-bar (dual SCARA) parallel robot (docs/tutorials/fivebar.md): mobility,
# workspace, and the inverse-kinematics calibration of the thesis experiment.
set -euo pipefail

# --8<-- [start:robot]
kincal show fivebar
# --8<-- [end:robot]

# --8<-- [start:mobility]
kincal fivebar-mobility
# --8<-- [end:mobility]

# --8<-- [start:workspace]
kincal fivebar-workspace fivebar -o workspace.png --resolution 150
# --8<-- [end:workspace]

# --8<-- [start:ik]
kincal ik fivebar --position 0,250mm
# --8<-- [end:ik]

# --8<-- [start:demo]
kincal fivebar-demo --out-dir lengths --json thesis.json
ls lengths
# --8<-- [end:demo]

# --8<-- [start:files]
kincal fivebar-simulate fivebar -o readings.csv -n 40 --noise 0.01deg --seed 2 \
    --set l1=150.8mm --set l2=149.5mm --set l3=250.6mm --set offset1=0.2deg
head -n 4 readings.csv
kincal calibrate fivebar --data readings.csv -o fivebar_cal.yaml > calibrate.txt
sed -n '/Estimated parameters/,/^└/p' calibrate.txt
# --8<-- [end:files]
