#!/usr/bin/env bash
# More real robots (docs/tutorials/real-robots.md, docs/results.md): a UR10 measured by a
# laser tracker with a 6-D probe (Fraunhofer IPA), Franka Pandas of the MUKCa fleet against
# MUKCa's own calibrated URDFs, and the ROS-Industrial two-axis positioner.
# The data sets are not part of kincal: this script needs them in ../shared/data
# and exits with status 77 (skipped) when they are not there.
set -euo pipefail
# Every command runs as printed from the root of a clone with the data sets in ../shared/data.
for set in ipa_ur10 mukca_fleet rosi_positioner; do
    [ -d "../shared/data/$set" ] || { echo "skipped: no ../shared/data/$set" >&2; exit 77; }
done

# --8<-- [start:ur10]
kincal calibrate --config examples/setups/ipa_ur10.yaml > ur10.txt
sed -n '/the stated sigmas vary/,/components)/p' ur10.txt
grep -E "^converged" ur10.txt
sed -n '/Errors before/,/^train:/p' ur10.txt | grep -v '^train:'
sed -n '/Held-out files: errors before/,/before (same session)/p' ur10.txt \
    | grep -v 'before (same session)'
sed -n '/^warning: measurements_random_poses/,/(frames: register)/p' ur10.txt
# --8<-- [end:ur10]

# --8<-- [start:ur10-compliance]
kincal calibrate --config examples/setups/ipa_ur10.yaml --joint-model compliance \
    -o ur10_compliance.yaml > ur10_compliance.txt
grep -E "┃ parameter|^│ tmac\.k\[" ur10_compliance.txt
sed -n '/Held-out files: errors before/,/before (same session)/p' \
    ur10_compliance.txt | grep -v 'before (same session)'
# --8<-- [end:ur10-compliance]

# --8<-- [start:mukca]
mukca=../shared/data/mukca_fleet
for held in panda_2:front_left:high panda_7:front:right; do
    IFS=: read -r robot train placement <<< "$held"
    echo "== $robot, placement $placement: kincal (examples/setups/mukca_$robot.yaml)"
    kincal calibrate --config "examples/setups/mukca_$robot.yaml" > "kincal_$robot.txt"
    sed -n "/^ *$placement: artifact metrics/,/^└/p" "kincal_$robot.txt"
    echo "== $robot, placement $placement: MUKCa's calibrated URDF as it is (only the unused"
    echo "   orientations of the $train sockets are fitted)"
    kincal calibrate "$mukca/calibrated_urdf/$robot/panda_calibrated.urdf" \
        --base-link panda_link0 --tip-link ball_link -i two-socket \
        --option length=50mm --option length_std=0.1mm --option point_std=0.05mm \
        --data "$mukca/$robot/$train" --validate "$mukca/$robot/$placement" \
        --free 'role:artifact' -o "mukca_$robot.yaml" > "mukca_$robot.txt"
    sed -n "/^ *$placement: artifact metrics/,/^└/p" "mukca_$robot.txt"
done
# --8<-- [end:mukca]

# --8<-- [start:positioner]
kincal calibrate --config examples/setups/rosi_positioner.yaml --json positioner.json \
    > positioner.txt
sed -n '/Errors before/,/^train:/p' positioner.txt | grep -v '^train:'
grep -E "cross-validation" -A1 positioner.txt | grep -v '^--'
grep -o '"mean_position_m": [0-9.e-]*' positioner.json | head -n 2   # after, then before
# --8<-- [end:positioner]

# --8<-- [start:positioner-heldout]
# Every other step of the second axis (22.5 deg grid) held out: orientations never fitted
awk -v even=positioner_even.yaml -v odd=positioner_odd.yaml '
    function flush() { if (rec != "") { print rec > (k % 2 ? odd : even) }; rec = ""; n = 0 }
    /^[^ ]/ { flush() }
    { rec = rec (rec == "" ? "" : "\n") $0 }
    /^  - / { n++; if (n == 2) k = int($2 / 0.39269908 + 0.5) }
    END { flush() }' ../shared/data/rosi_positioner/measurements.yaml
kincal calibrate examples/robots/rosi_positioner.yaml --data positioner_even.yaml \
    --validate positioner_odd.yaml --validation-frames training > positioner_split.txt
sed -n '/Errors before/,/^train:/p' positioner_split.txt | grep -v '^train:'
sed -n '/Held-out files: errors before/,/before (same session)/p' \
    positioner_split.txt | grep -v 'before (same session)'
# --8<-- [end:positioner-heldout]
