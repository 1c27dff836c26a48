#!/usr/bin/env bash
# The trust tutorial's real-data part (docs/tutorials/trust.md): a Yaskawa Motoman measured
# by a Leica laser tracker on a small grid of its workspace. The data set is not part of
# kincal: this script needs it in ../shared/data and exits with status 77 (skipped) when
# it is not there.
set -euo pipefail
[ -d "../shared/data/motoman_leica" ] || { echo "skipped: no ../shared/data/motoman_leica" >&2; exit 77; }

# --8<-- [start:grid]
kincal calibrate motoman_right --data ../shared/data/motoman_leica/right_arm_grid_6x6x6.csv \
    -o grid.yaml > grid.txt
sed -n '/^warning: extrapolation/,/^robot:/p' grid.txt | grep -v '^robot:'
# --8<-- [end:grid]
