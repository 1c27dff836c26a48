#!/usr/bin/env sh
# kincal's command line on the real data sets (see ../shared/data/*/README.md).
# Each calibration is one setup file in examples/setups/ (robot, files with their own
# reading options, calibration options, outputs); tests/test_examples.py runs them all.
#
# 1. PAL TIAGo, Qualisys motion capture, FIGAROH's protocol (train one day, validate
#    another with the training frames): joint offsets, then the full model with joint
#    hysteresis and gravity compliance.
# 2. Yaskawa Motoman (standard DH), Leica laser tracker: 5-fold cross-validation.
# 3. Franka Panda, two-socket artifact (MUKCa socket folders): train front, validate left.
# Outputs land in examples/setups/out/.
set -e
HERE=$(dirname "$0")
kincal identifiability "$HERE/../../shared/data/tiago_mocap/tiago_48_schunk.urdf" \
    --tip-link wrist_ft_tool_link --data "$HERE/../../shared/data/tiago_mocap/train_2021-11-30.csv" \
    --units 'x?=m,y?=m,z?=m' --ignore '?2,?3,?4' --free 'role:offset,instrument.*'
for setup in tiago_offsets tiago_mocap motoman_right panda_two_socket; do
    kincal calibrate --config "$HERE/setups/$setup.yaml"
done
