#!/usr/bin/env bash
# Calibration with artifacts instead of an instrument (docs/tutorials/artifacts.md):
# a cross-bar (the staged-selection procedure), a ball-bar, and a two-socket artifact, each on a
# simulated PUMA 560 with known errors whose joint readings are the only measurement.
set -euo pipefail

# --8<-- [start:cross-bar]
kincal simulate puma560 -i cross-bar -o cross.csv --holdout cross_check.csv \
    --placements 20 --holdout-poses 10 --bar-length 300mm --probe-length 100mm \
    --encoder-noise 0.001deg --seed 1
head -n 5 cross.csv
# --8<-- [end:cross-bar]

# --8<-- [start:cross-calibrate]
kincal calibrate puma560 --data cross.csv --validate cross_check.csv -o cross_cal.yaml \
    > cross.txt
sed -n '/Errors before/,/^cross_check.csv: artifact: sockets/p' cross.txt
sed -n '/^identifiability/,/more (see/p' cross.txt
# --8<-- [end:cross-calibrate]

# --8<-- [start:staged-selection]
kincal calibrate puma560 --data cross.csv --procedure staged-selection --condition-growth 1.0 \
    -o staged_cal.yaml --json staged.json > staged.txt
sed -n '/staged-selection data selection/,/^robot/p' staged.txt
# --8<-- [end:staged-selection]

# --8<-- [start:ball-bar]
kincal simulate puma560 -i ball-bar -o ballbar.csv --placements 30 --bar-length 200mm \
    --encoder-noise 0.001deg --seed 2 > /dev/null
kincal identifiability puma560 --data ballbar.csv > ballbar.txt
head -n 2 ballbar.txt
grep -E "^- " ballbar.txt | head -n 4
# --8<-- [end:ball-bar]

# --8<-- [start:two-socket]
kincal simulate puma560 -i two-socket -o sockets.csv --placements 8 --bar-length 50mm \
    --option probe=tool --encoder-noise 0.001deg --seed 3 \
    --holdout sockets_check.csv --holdout-poses 4 > /dev/null
head -n 3 sockets.csv
kincal calibrate puma560 --data sockets.csv --validate sockets_check.csv \
    -o sockets_cal.yaml > sockets.txt
sed -n '/Held-out/,/^identifiability/p' sockets.txt
# --8<-- [end:two-socket]
