#!/usr/bin/env bash
# Non-geometric joint models on the real TIAGo (docs/tutorials/joint-models.md): joint
# hysteresis (backlash) and gravity compliance, compared by cross-validation on the
# training day and checked on another day. Needs the TIAGo data set in
# ../shared/data; exits with status 77 (skipped) without it.
set -euo pipefail
# Every command runs as printed from the root of a clone with the data sets in ../shared/data.
[ -d ../shared/data/tiago_mocap ] || { echo "skipped: no ../shared/data/tiago_mocap" >&2; exit 77; }

# --8<-- [start:fit]
kincal calibrate --config examples/setups/tiago_mocap.yaml --json tiago.json > tiago.txt
grep -E "^converged" tiago.txt
python3 - <<'PY'
import json
for p in json.load(open("tiago.json"))["parameters"]:
    if p["name"].startswith(("mocap.h[arm_", "mocap.k[arm_")) and p["std"]:
        kind = "play [mrad]" if ".h[" in p["name"] else "compliance [mrad/(N m)]"
        print(f"{p['name']:18} {kind:24} {p['estimate'] * 1e3:8.2f} ± {p['std'] * 1e3:.2f}")
PY
sed -n '/Held-out files/,/^ *before/p' tiago.txt
# --8<-- [end:fit]

# --8<-- [start:compare]
sed '/^  joint_model:/d' examples/setups/tiago_mocap.yaml > examples/setups/tiago_geometric.yaml
kincal calibrate --config examples/setups/tiago_geometric.yaml --cross-validate 10 -o g.yaml --json g.json \
    --report g.html --urdf g.urdf | grep -A 1 "cross-validation"
kincal calibrate --config examples/setups/tiago_mocap.yaml --joint-model hysteresis --cross-validate 10 \
    -o h.yaml --json h.json --report h.html --urdf h.urdf | grep -A 1 "cross-validation"
kincal calibrate --config examples/setups/tiago_mocap.yaml --cross-validate 10 \
    -o hc.yaml --json hc.json --report hc.html --urdf hc.urdf | grep -A 1 "cross-validation"
# --8<-- [end:compare]
