#!/usr/bin/env bash
# Results on real robots (docs/tutorials/real-robots.md): PAL TIAGo with motion capture,
# Yaskawa Motoman with a Leica laser tracker, Franka Panda with a two-socket artifact.
# The data sets are not part of kincal: this script needs them in ../shared/data
# and exits with status 77 (skipped) when they are not there.
set -euo pipefail
# Every command runs as printed from the root of a clone with the data sets in ../shared/data.
for set in tiago_mocap motoman_leica panda_two_socket; do
    [ -d "../shared/data/$set" ] || { echo "skipped: no ../shared/data/$set" >&2; exit 77; }
done

# --8<-- [start:tiago-offsets]
kincal calibrate --config examples/setups/tiago_offsets.yaml > tiago_offsets.txt
sed -n '/Errors before/,/^train:/p; /Held-out files/,/^ *before/p' tiago_offsets.txt
sed -n '/^warning/,/^robot:/p' tiago_offsets.txt | grep -v '^robot:'      # the warnings, whole
# --8<-- [end:tiago-offsets]

# --8<-- [start:tiago-select]
kincal calibrate ../shared/data/tiago_mocap/tiago_48_schunk.urdf --tip-link wrist_ft_tool_link \
    --data ../shared/data/tiago_mocap/train_2021-11-30.csv \
    --validate ../shared/data/tiago_mocap/validation_2021-11-26.csv --validation-frames training \
    --units 'x1=m,y1=m,z1=m' --ignore '?2,?3,?4' --select auto -o tiago.yaml > tiago.txt
sed -n '/Model selection/,/^converged/p' tiago.txt | grep -v '^converged'
sed -n '/Errors before/,/^train:/p; /Held-out files/,/^identifiability/p' tiago.txt \
    | grep -v '^identifiability'
sed -n '/^warning/,/^robot:/p' tiago.txt | grep -v '^robot:'      # the warnings, whole
# --8<-- [end:tiago-select]

# --8<-- [start:tiago-least-squares]
kincal calibrate ../shared/data/tiago_mocap/tiago_48_schunk.urdf --tip-link wrist_ft_tool_link \
    --data ../shared/data/tiago_mocap/train_2021-11-30.csv --units 'x1=m,y1=m,z1=m' \
    --ignore '?2,?3,?4' --prior none -o tiago_ls.yaml > tiago_ls.txt 2>&1 \
    || echo "exit status $?"
tail -n 1 tiago_ls.txt
# --8<-- [end:tiago-least-squares]

# --8<-- [start:motoman]
kincal calibrate --config examples/setups/motoman_right.yaml > motoman.txt
grep -E -A1 "^converged|cross-validation" motoman.txt
sed -n '/Errors before/,/^train:/p' motoman.txt
sed -n '/^warning/,/^robot:/p' motoman.txt | grep -v '^robot:'      # the warnings, whole
# --8<-- [end:motoman]

# --8<-- [start:motoman-iso]
for set in table1 wall1; do
    kincal validate motoman_right --data "../shared/data/motoman_leica/right_arm_repeatability_$set.csv" \
        --iso9283 > "iso_$set.txt"
    sed -n '/ISO 9283/,$p' "iso_$set.txt"
done
# --8<-- [end:motoman-iso]

# --8<-- [start:panda]
kincal calibrate --config examples/setups/panda_two_socket.yaml > panda.txt
grep -E "^converged" panda.txt
sed -n '/artifact metrics/,/^identifiability/p' panda.txt | grep -v '^identifiability'
sed -n '/^warning/,/^robot:/p' panda.txt | grep -v '^robot:'      # the warnings, whole
# --8<-- [end:panda]
