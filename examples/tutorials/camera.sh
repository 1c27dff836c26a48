#!/usr/bin/env bash
# Calibrate with a camera (docs/tutorials/camera.md): the real Franka eye-in-hand set, a
# ChArUco board on the table and a RealSense camera on the hand. Needs the data in
# ../shared/data and OpenCV (pip install 'kincal[camera]'); exits with status 77
# (skipped) without the data.
set -euo pipefail
# Every command runs as printed from the root of a clone with the data sets in ../shared/data.
[ -d ../shared/data/camera/franka_eye_in_hand ] \
    || { echo "skipped: no ../shared/data/camera/franka_eye_in_hand" >&2; exit 77; }

# --8<-- [start:import]
SET=../shared/data/camera/franka_eye_in_hand
kincal import images $SET/session_1 --board $SET/config/calibration_board_parameters.yaml \
    --robot panda -o franka.csv
sed -n '1,4p' franka.csv | cut -c 1-160
# --8<-- [end:import]

# --8<-- [start:nominal]
kincal hand-eye panda --data franka.csv
# --8<-- [end:nominal]

# --8<-- [start:offsets]
kincal hand-eye panda --data franka.csv --free 'theta_offset*' -o panda_camera.yaml \
    --leave-one-out
# --8<-- [end:offsets]

# --8<-- [start:later]
mkdir -p later && cp -r $SET/session_1/pose_02 $SET/session_1/pose_06 $SET/session_1/pose_10 later/
kincal import images later --board $SET/config/calibration_board_parameters.yaml \
    --robot panda -o later.csv
kincal validate panda_camera.yaml --data later.csv > later.txt
grep -E "^later|image \[px\]" later.txt
# --8<-- [end:later]
