#!/usr/bin/env bash
# Calibrate with a camera (docs/tutorials/camera.md): print a board, then the real Franka
# eye-in-hand set, a ChArUco board on the table and a RealSense camera on the hand. Needs
# the data in ../shared/data and OpenCV (pip install 'kincal[camera]'); exits with status
# 77 (skipped) without the data.
set -euo pipefail
# Every command runs as printed from the root of a clone with the data sets in ../shared/data.
[ -d ../shared/data/camera/franka_eye_in_hand ] \
    || { echo "skipped: no ../shared/data/camera/franka_eye_in_hand" >&2; exit 77; }

# --8<-- [start:board]
kincal board charuco --columns 5 --rows 7 --square 34mm --marker 28mm -o board.pdf
cat board.yaml
# --8<-- [end:board]

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

# --8<-- [start:lens]
kincal hand-eye panda --images $SET/session_1 \
    --board $SET/config/calibration_board_parameters.yaml --free 'theta_offset*'
# --8<-- [end:lens]

# --8<-- [start:abb]
ABB=../shared/data/camera/abb_eye_to_hand
cat > abb_board.yaml <<'EOF'
type: charuco
squares: [5, 7]
square: 36.195 mm
marker: 18.256 mm
dictionary: DICT_6X6_250
EOF
kincal hand-eye --images $ABB/images --board abb_board.yaml --poses $ABB/poses --mount fixed \
    --intrinsics $ABB/cal_data.yaml --lens none
# --8<-- [end:abb]

# --8<-- [start:abb-lens]
kincal hand-eye --images $ABB/images --board abb_board.yaml --poses $ABB/poses --mount fixed \
    --intrinsics $ABB/cal_data.yaml --leave-one-out
# --8<-- [end:abb-lens]

# --8<-- [start:ros]
kincal hand-eye --images $ABB/images --board abb_board.yaml --poses $ABB/poses --mount fixed \
    --intrinsics $ABB/cal_data.yaml --ros-yaml abb_handeye.yaml --ros-launch camera_tf.launch \
    --urdf-joint camera_joint.urdf --camera-info camera_info.yaml --report abb_report.html \
    | grep -- '->'
# the files hold 17 digits; cut to 6 decimals here, as the last ones vary between machines
cat abb_handeye.yaml camera_tf.launch camera_joint.urdf camera_info.yaml \
    | sed -E 's/([0-9]\.[0-9]{6})[0-9]+/\1/g'
# --8<-- [end:ros]
