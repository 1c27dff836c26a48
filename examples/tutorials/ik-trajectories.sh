#!/usr/bin/env bash
# Kinematics, inverse kinematics, trajectories and closed-loop IK
# (docs/tutorials/ik-trajectories.md).
set -euo pipefail

# --8<-- [start:fk]
kincal fk puma560 --q 0,45,-30,0,60,0 --deg
kincal jacobian puma560 --q 0,45,-30,0,60,0 --deg --frame tool
# --8<-- [end:fk]

# --8<-- [start:ik]
kincal ik puma560 --pose 400,100,200mm,0,90,0deg --deg
# --8<-- [end:ik]

# --8<-- [start:branches]
kincal ik puma560 --pose 400,100,200mm,0,90,0deg --deg --all-branches
# --8<-- [end:branches]

# --8<-- [start:unreachable]
kincal ik puma560 --position 2000,0,0mm || echo "exit status $?"
# --8<-- [end:unreachable]

# --8<-- [start:trajectory]
kincal trajectory puma560 --start 0,45,-30,0,60,0 --end 60,30,-60,20,45,90 --deg \
    --timing trapezoidal --v-max 1.5 --a-max 3 --out-dir joint
kincal trajectory puma560 --start 0,45,-30,0,60,0 --deg --space line \
    --end-pose 350,-150,550mm,0,-75,0deg --timing quintic --duration 2s --out-dir line
head -n 3 line/trajectory.csv | cut -c 1-96
# --8<-- [end:trajectory]

# --8<-- [start:clik]
for method in inverse dls; do
    kincal clik spherical_rrp --start 0,45deg,0.5m --end-position=-707.107,707.107,100mm \
        --method "$method" --out-dir "clik_$method"
done
# --8<-- [end:clik]
