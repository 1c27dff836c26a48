#!/usr/bin/env bash
# Getting started: the README's first command, a complete calibration on a built-in
# example (docs/index.md shows this script and what it prints).
set -euo pipefail

# --8<-- [start:demo]
kincal demo
# --8<-- [end:demo]

# --8<-- [start:files]
ls kincal-demo
head -n 4 kincal-demo/train.csv
# --8<-- [end:files]
