#!/usr/bin/env bash
# A UR controller's calibration in ROS and in kincal, and calibrated URDFs that review
# cleanly (docs/tutorials/ur-calibration.md).
set -euo pipefail

# --8<-- [start:import]
cp "examples/tutorials/files/calibration.conf" .
kincal import ur calibration.conf --nominal ur5e -o ur5e_cal.yaml --kinematics ur5e_kinematics.yaml
# --8<-- [end:import]

# --8<-- [start:yaml]
head -n 16 ur5e_kinematics.yaml
# --8<-- [end:yaml]

# --8<-- [start:refine]
kincal simulate ur5e_cal.yaml -o tracker.csv -n 50 --noise 0.01mm --seed 3 > /dev/null
kincal calibrate ur5e_cal.yaml --data tracker.csv -o refined.yaml > calibrate.txt
tail -n 1 calibrate.txt
kincal ur-kinematics refined.yaml --nominal ur5e -o kinematics.yaml
# --8<-- [end:refine]

# --8<-- [start:urdf]
cp "examples/tutorials/files/arm.urdf" .
kincal simulate arm.urdf --tip-link tool0 -o arm.csv -n 60 --noise 0.01mm --seed 2 > /dev/null
kincal calibrate arm.urdf --tip-link tool0 --data arm.csv -o arm_cal.yaml \
    --urdf arm_calibrated.urdf > calibrate.txt
tail -n 2 calibrate.txt
diff arm.urdf arm_calibrated.urdf || true
# --8<-- [end:urdf]

# --8<-- [start:refuse]
kincal ur-kinematics ur3e --nominal ur3e -o ur3e.yaml > /dev/null
kincal import ur ur3e.yaml --nominal ur3 -o ur3_cal.yaml || echo "exit status $?"
# the upper arm's frame turned by pi about x
sed '/upper_arm:/,/roll:/ s/roll: 1.57085[0-9]*/roll: -1.5707414736/' ur5e_kinematics.yaml > turned.yaml
kincal import ur turned.yaml --nominal ur5e -o turned_cal.yaml || echo "exit status $?"
# --8<-- [end:refuse]
