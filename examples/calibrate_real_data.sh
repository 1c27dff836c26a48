#!/usr/bin/env sh
# kincal's command line on two real data sets (see ../shared/data/*/README.md).
#
# 1. PAL TIAGo (torso + 7-DOF arm, URDF), Qualisys motion capture, FIGAROH's protocol:
#    calibrate on the training day, validate on another day with the training frames.
#    The files have bare column names: units come from --units (markers in m) and from
#    the URDF (joints in rad / m); markers 2-4 are dropped on purpose with --ignore.
#    Published RMS (FIGAROH, train / validation): offsets 2.88 / 4.23 mm.
# 2. Yaskawa Motoman (standard DH), Leica laser tracker: the file is unit-suffixed
#    (S_rad, x_m, sigma_m) and reads as it is; pose_id is reported as not read.
set -e
DATA=${DATA:-../shared/data}
OUT=${OUT:-real_data_out}
mkdir -p "$OUT"

T=$DATA/tiago_mocap
kincal identifiability "$T/tiago_48_schunk.urdf" --tip-link wrist_ft_tool_link \
    --data "$T/train_2021-11-30.csv" --units 'x?=m,y?=m,z?=m' --ignore '?2,?3,?4' \
    --free 'role:offset,tracker.*'
kincal calibrate "$T/tiago_48_schunk.urdf" --tip-link wrist_ft_tool_link \
    --data "$T/train_2021-11-30.csv" --validate "$T/validation_2021-11-26.csv" \
    --units 'x?=m,y?=m,z?=m' --ignore '?2,?3,?4' --validation-frames training \
    --free 'role:offset,tracker.*' \
    -o "$OUT/tiago_offsets.yaml" --json "$OUT/tiago_offsets.json" --report "$OUT/tiago.html"

M=$DATA/motoman_leica
kincal calibrate motoman_right --data "$M/right_arm_grid_6x6x6.csv" --stages offsets,all \
    -o "$OUT/motoman_right.yaml" --json "$OUT/motoman_right.json" \
    --report "$OUT/motoman_right.html"
