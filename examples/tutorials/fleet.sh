#!/usr/bin/env bash
# Fleet calibration (docs/tutorials/fleet.md): eight simulated PUMA 560s, two sessions
# each, calibrated on the embedded Dask cluster into an SQLite history; a broken file, a
# re-run that skips what is stored, drift alarms, and the export.
set -euo pipefail

# --8<-- [start:simulate]
kincal fleet simulate puma560 -n 8 --out-dir plant --poses 40 --drifted 2 --broken 1 --seed 1
sed -n '1,10p' plant/fleet.yaml
# --8<-- [end:simulate]

# --8<-- [start:calibrate]
kincal fleet calibrate plant --db history.db --workers 2 || echo "exit status $?"
# --8<-- [end:calibrate]

# --8<-- [start:again]
kincal fleet calibrate plant --db history.db --serial || echo "exit status $?"
# --8<-- [end:again]

# --8<-- [start:sqlite]
python3 - <<'PY'
import math
import sqlite3

db = sqlite3.connect("history.db")
print([name for (name,) in db.execute("select name from sqlite_master where type='table'")])
for serial, date, status, estimate, std in db.execute(
        "select c.serial, c.session_date, c.status, p.estimate, p.std"
        " from calibrations c left join parameters p"
        " on p.calibration_id = c.id and p.name = 'alpha[3]'"
        " where c.serial in ('R-00005', 'R-00007') order by c.serial, c.session_date"):
    value = (f"alpha[3] = {math.degrees(estimate):+.4f} ± {math.degrees(std):.4f} deg"
             if estimate is not None else "")
    print(serial, date, f"{status:<6}", value)
PY
# --8<-- [end:sqlite]

# --8<-- [start:drift]
kincal fleet drift --db history.db --report fleet.html || echo "exit status $?"
# --8<-- [end:drift]

# --8<-- [start:drift-own]
kincal fleet drift --db history.db --reproducibility none || echo "exit status $?"
# --8<-- [end:drift-own]

# --8<-- [start:history]
kincal fleet history R-00005 --db history.db
# --8<-- [end:history]

# --8<-- [start:export]
kincal fleet export --db history.db -o history.csv --parameters parameters.csv \
    --out-dir calibrated/
ls calibrated
head -n 3 parameters.csv | cut -d, -f2-    # (not the id column: the order records arrived)
# --8<-- [end:export]
