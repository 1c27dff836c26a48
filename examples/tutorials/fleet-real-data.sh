#!/usr/bin/env bash
# The fleet tutorial's real robots (docs/tutorials/fleet.md): five Franka Pandas of the
# MUKCa project, each calibrated with a two-socket artifact at several places. The data
# sets are not part of kincal: this script needs them in ../shared/data and exits with
# status 77 (skipped) when they are not there.
set -euo pipefail
for set in mukca_fleet panda_two_socket; do
    [ -d "../shared/data/$set" ] || { echo "skipped: no ../shared/data/$set" >&2; exit 77; }
done

# --8<-- [start:manifest]
sed -n '8,21p' examples/fleets/mukca.yaml
# --8<-- [end:manifest]

# --8<-- [start:calibrate]
kincal fleet calibrate examples/fleets/mukca.yaml --db mukca.db --serial
# --8<-- [end:calibrate]

# --8<-- [start:unchanged]
kincal fleet calibrate examples/fleets/mukca_split.yaml --db split.db --serial > /dev/null
kincal fleet drift --db split.db --reproducibility none || echo "exit status $?"
kincal fleet drift --db split.db --all || echo "exit status $?"
# --8<-- [end:unchanged]

# --8<-- [start:prior]
kincal fleet prior --db mukca.db -o panda_fleet.yaml
# --8<-- [end:prior]
