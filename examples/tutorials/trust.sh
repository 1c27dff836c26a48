#!/usr/bin/env bash
# When not to trust a calibration (docs/tutorials/trust.md): a PUMA 560 whose fifth
# joint moved by 1 degree only while it was measured; what plain least squares does with
# that, what the default does, where the calibrated model may be used, and how the model
# is chosen.
set -euo pipefail

# --8<-- [start:robot]
puma() {  # the PUMA 560 as a robot file, q5 limited to [$1, $2] degrees
cat <<YAML
name: puma560
units: {length: mm, angle: deg}
convention: standard_dh
joints:
  - {name: q1, type: revolute, a: 0,     d: 0,      alpha: 90,  theta_offset: 0, limits: [-160, 160]}
  - {name: q2, type: revolute, a: 431.8, d: 0,      alpha: 0,   theta_offset: 0, limits: [-45, 225]}
  - {name: q3, type: revolute, a: 20.3,  d: 150.05, alpha: -90, theta_offset: 0, limits: [-225, 45]}
  - {name: q4, type: revolute, a: 0,     d: 431.8,  alpha: 90,  theta_offset: 0, limits: [-110, 170]}
  - {name: q5, type: revolute, a: 0,     d: 0,      alpha: -90, theta_offset: 0, limits: [$1, $2]}
  - {name: q6, type: revolute, a: 0,     d: 0,      alpha: 0,   theta_offset: 0, limits: [-266, 266]}
YAML
}
puma 30 31 > narrow.yaml
puma -100 100 > full.yaml
# the same seed draws the same robot errors and tracker placement for both files
kincal simulate narrow.yaml -o narrow.csv -n 40 --noise 0.01mm --seed 8
kincal simulate full.yaml -o everywhere.csv -n 40 --noise 0.01mm --seed 8
# --8<-- [end:robot]

# --8<-- [start:refusals]
# the same 40 poses in degrees under the _rad headers; one q2 reading set to 300 deg; one row
awk -F, 'BEGIN{OFS=","} /^#/ || /^q1_/ {print; next}
    {for (i = 1; i <= 6; i++) $i = $i * 180 / 3.141592653589793; print}' everywhere.csv \
    > deg_as_rad.csv
awk -F, 'BEGIN{OFS=","} /^#/ || /^q1_/ {print; next}
    {if (++n == 4) $2 = 300 * 3.141592653589793 / 180; print}' everywhere.csv > beyond.csv
awk '/^#/ || /^q1_/ || ++n == 1' everywhere.csv > one.csv
for f in deg_as_rad beyond one; do
    kincal calibrate puma560 --data $f.csv -o cal_$f.yaml > /dev/null 2> $f.err \
        || echo "$f.csv: exit status $?"
    fold -s -w 100 $f.err          # (one line each, folded for the page)
done
kincal fk puma560 --q 10,20,30,40,50,60 > /dev/null 2> fk.err || echo "fk: exit status $?"
fold -s -w 100 fk.err
# --8<-- [end:refusals]

# --8<-- [start:least-squares]
kincal calibrate puma560 --data narrow.csv --prior none -o ls.yaml || echo "exit status $?"
ls ls.yaml 2>&1 || true
# --8<-- [end:least-squares]

# --8<-- [start:default]
kincal calibrate puma560 --data narrow.csv -o calibrated.yaml --json result.json
# --8<-- [end:default]

# --8<-- [start:extrapolation]
kincal validate calibrated.yaml --data everywhere.csv --result result.json --before puma560
# --8<-- [end:extrapolation]

# --8<-- [start:compensate]
cat > targets.csv <<'CSV'
x_mm,y_mm,z_mm
450,150,300
500,-100,250
420,0,420
300,300,100
CSV
kincal compensate calibrated.yaml --targets targets.csv --nominal puma560 --result result.json \
    -o joints.csv --filtered filtered.csv --fallback nominal
# --8<-- [end:compensate]

# --8<-- [start:select]
kincal simulate puma560 -o train.csv -n 60 --noise 0.01mm --seed 4
kincal calibrate puma560 --data train.csv --select auto --folds 5 > selection.txt
sed -n '/Model selection/,/^converged/p' selection.txt
# --8<-- [end:select]

# --8<-- [start:envelope]
# the calibrated robot file carries its envelope: no --result needed
kincal validate calibrated.yaml --data everywhere.csv --before puma560
kincal fk calibrated.yaml --q 0,45,-60,10,80,0 --deg | tail -4
# --8<-- [end:envelope]
