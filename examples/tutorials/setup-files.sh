#!/usr/bin/env bash
# Setup files (docs/tutorials/setup-files.md): a calibration as one reviewable YAML file,
# written by `kincal init` from the data files, run by `kincal calibrate --config`.
set -euo pipefail

# --8<-- [start:data]
kincal simulate puma560 -o tracker.csv --truth truth.yaml -n 60 --noise 0.01mm --seed 1 \
    --holdout holdout.csv --holdout-poses 30
# --8<-- [end:data]

# --8<-- [start:init]
kincal init puma560 --data tracker.csv --validate holdout.csv -o setup.yaml
cat setup.yaml
# --8<-- [end:init]

# --8<-- [start:edit]
# estimate the encoder offsets first, then everything (uncomment one line)
sed -i 's/^  # stages: \[offsets, all\]/  stages: [offsets, all]/' setup.yaml
kincal calibrate --config setup.yaml > calibrate.txt
grep -E "converged|^robot|^report" calibrate.txt
# --8<-- [end:edit]

# --8<-- [start:override]
kincal calibrate --config setup.yaml --cross-validate 5 -o cv.yaml --json cv.json \
    --report cv.html > cv.txt
grep "cross-validation" cv.txt
# --8<-- [end:override]

# --8<-- [start:mistake]
sed 's/^    frames: training/    frame: training/' setup.yaml > broken.yaml
kincal calibrate --config broken.yaml || echo "exit status $?"
# --8<-- [end:mistake]
