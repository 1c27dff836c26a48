#!/usr/bin/env bash
# A KUKA program through the calibrated model (docs/tutorials/robot-programs.md): a KR 6
# with known errors is calibrated on simulated tracker data, then its weld program is
# filtered so that a controller with the nominal model puts the real robot on target.
set -euo pipefail

# --8<-- [start:calibrate]
kincal simulate kr6 -o train.csv --truth truth.yaml -n 60 --noise 0.01mm --seed 1
kincal calibrate kr6 --data train.csv -o kr6_cal.yaml --json result.json > calibrate.txt
tail -n 1 calibrate.txt
# --8<-- [end:calibrate]

# --8<-- [start:filter]
cp examples/tutorials/files/weld_seam.src examples/tutorials/files/weld_seam.dat \
    examples/tutorials/files/krl_frames.yaml .
kincal filter weld_seam.src --robot kr6_cal.yaml --nominal kr6 --frames krl_frames.yaml \
    --result result.json -o filtered/weld_seam.src --csv targets.csv
# --8<-- [end:filter]

# --8<-- [start:diff]
diff weld_seam.dat filtered/weld_seam.dat | grep XP1 || true
diff weld_seam.src filtered/weld_seam.src || true
# --8<-- [end:diff]

# --8<-- [start:plan]
kincal plan kr6 -n 12 --program krl --dwell 2s -o poses.src > plan.txt
tail -n 2 plan.txt
ls poses.*
grep -m 3 "PTP" poses.src
# --8<-- [end:plan]

# --8<-- [start:spline]
cp examples/tutorials/files/spline_cell.src examples/tutorials/files/spline_cell.dat \
    examples/tutorials/files/spline_frames.yaml .
grep -m 1 "^SLIN XP2" spline_cell.src | cut -c 1-98
kincal filter spline_cell.src --robot kr6_cal.yaml --nominal kr6 --frames spline_frames.yaml \
    -o filtered/spline_cell.src
# --8<-- [end:spline]

# --8<-- [start:polyscope]
kincal simulate ur5 -o ur_train.csv --truth ur_truth.yaml -n 60 --noise 0.01mm --seed 2
kincal calibrate ur5 --data ur_train.csv -o ur5_cal.yaml > ur_calibrate.txt
cp examples/tutorials/files/polyscope_export.script .
kincal filter polyscope_export.script --robot ur5_cal.yaml --nominal ur5 \
    -o filtered/polyscope_export.script
diff polyscope_export.script filtered/polyscope_export.script || true
# --8<-- [end:polyscope]

# --8<-- [start:rapid]
kincal simulate irb120 -o irb_train.csv --truth irb_truth.yaml -n 60 --noise 0.01mm --seed 2
kincal calibrate irb120 --data irb_train.csv -o irb120_cal.yaml > irb_calibrate.txt
cp -r examples/tutorials/files/cell7_backup .
kincal filter cell7_backup --robot irb120_cal.yaml --nominal irb120 -o cell7_filtered
diff -r cell7_backup/RAPID/TASK1 cell7_filtered || true
# --8<-- [end:rapid]

# --8<-- [start:fanuc]
kincal simulate m10ia -o m10_train.csv --truth m10_truth.yaml -n 60 --noise 0.01mm --seed 3
kincal calibrate m10ia --data m10_train.csv -o m10ia_cal.yaml > m10_calibrate.txt
cp examples/tutorials/files/zelle3.ls examples/tutorials/files/fanuc_frames.yaml .
kincal filter zelle3.ls --robot m10ia_cal.yaml --nominal m10ia --frames fanuc_frames.yaml \
    -o filtered/zelle3.ls || echo "exit status $?"
diff zelle3.ls filtered/zelle3.ls || true
# --8<-- [end:fanuc]

# --8<-- [start:yumi]
cp examples/tutorials/files/YumiRight.mod examples/tutorials/files/yumi_r_cal.yaml .
kincal filter YumiRight.mod --robot yumi_r_cal.yaml --nominal yumi_r \
    -o filtered/YumiRight.mod || echo "exit status $?"
diff YumiRight.mod filtered/YumiRight.mod || true
# --8<-- [end:yumi]
