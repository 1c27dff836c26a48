#!/usr/bin/env bash
# The conventions page's examples (docs/conventions.md): a robot file with a bad field, the
# built-in robots of one vendor, and a controller's zero shifts after a calibration.
set -euo pipefail

# --8<-- [start:bad-robot-file]
cat > broken.yaml <<'YAML'
name: broken
units: {length: mm, angle: deg}
convention: standard_dh
joints:
  - {type: revolute, a: 0, d: 400, alpha: -90}
  - {type: revolute, a: 300, d: 0, alpha: 0}
  - {type: revolute, a: 0, d: 0, alpha: ninety}
YAML
kincal show broken.yaml || echo "exit status $?"
# --8<-- [end:bad-robot-file]

# --8<-- [start:vendor]
kincal robots --vendor yaskawa
kincal robots --vendor kawasaki || echo "exit status $?"
# --8<-- [end:vendor]

# --8<-- [start:zero-shifts]
kincal simulate lrmate200id -o train.csv -n 60 --offset-error 0.3deg --seed 4 > /dev/null
kincal calibrate lrmate200id --data train.csv -o cal.yaml --json res.json \
    --stages offsets,all > calibrate.txt
grep 'zero:' calibrate.txt
# --8<-- [end:zero-shifts]
