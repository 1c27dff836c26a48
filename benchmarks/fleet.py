"""Fleet calibration throughput: the in-process loop vs Dask LocalCluster (1 and 2 workers).

For each fleet size (simulated PUMA 560 robots, one session of ``--poses`` tracker poses
each, written as CSV files), every engine calibrates the whole fleet into a fresh SQLite
history with ``kincal.fleet.run.calibrate_fleet`` (the code ``kincal fleet calibrate``
runs: files read, calibrated, one transaction per record).  Each measurement runs in its
own process so that its peak memory is its own; engines are interleaved (A B C A B C ...)
and the table gives medians over the repeats.

Columns: robots/s over the calibration itself (cluster start-up apart, in its own
column); the scheduler overhead per task, measured by running as many no-op tasks
through the same engine (wall time per task; for the loop, the cost of a Python call);
peak resident memory of the client process and of the largest worker.

    python benchmarks/fleet.py --sizes 1000 --repeats 5
    python benchmarks/fleet.py --sizes 100,1000,10000 --repeats 1 --engines serial,2
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def _noop(x: int) -> dict:
    return {"i": x}


def _worker_peak_kb() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def measure(fleet: str, engine_name: str) -> dict:
    """One run (in a fresh process): calibrate the fleet, then as many no-op tasks."""
    from kincal.fleet.engine import DaskEngine, SerialEngine
    from kincal.fleet.manifest import load_fleet
    from kincal.fleet.run import calibrate_fleet
    from kincal.fleet.store import HistoryStore

    tasks = load_fleet(fleet)
    out: dict = {"engine": engine_name, "robots": len(tasks), "load": os.getloadavg()[0]}
    t0 = time.perf_counter()
    engine = SerialEngine() if engine_name == "serial" else DaskEngine(workers=int(engine_name))
    if engine_name != "serial":
        engine.start()
    out["startup_s"] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as d, HistoryStore(str(Path(d) / "h.db")) as store:
        t1 = time.perf_counter()
        summary = calibrate_fleet(tasks, store, engine, crosscheck=False)
        out["calibrate_s"] = time.perf_counter() - t1
        out["failed"] = len(summary.failed)
    t2 = time.perf_counter()
    n = sum(1 for _ in engine.map_unordered(_noop, range(len(tasks))))
    out["overhead_s_per_task"] = (time.perf_counter() - t2) / n
    out["worker_peak_mb"] = (max(engine.client.run(_worker_peak_kb).values()) / 1024
                             if engine_name != "serial" else None)
    engine.close()
    out["client_peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def _fmt(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="1000", help="fleet sizes, comma separated")
    ap.add_argument("--poses", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--engines", default="serial,1,2", help="serial and/or worker counts")
    ap.add_argument("--root", default=None, help="where to write the fleets (default: tmp)")
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(measure(*args.child)))
        return
    from kincal.fleet.simulate import simulate_fleet

    root = Path(args.root or tempfile.mkdtemp(prefix="kincal-fleet-bench-"))
    engines = args.engines.split(",")
    rows, loads = [], []
    for size in map(int, args.sizes.split(",")):
        fleet = root / f"fleet-{size}"
        if not (fleet / "fleet.yaml").is_file():
            t = time.perf_counter()
            simulate_fleet(fleet, robots=size, sessions=1, poses=args.poses, drifted=0,
                           broken=0, seed=1)
            print(f"# simulated {size} robots x {args.poses} poses in "
                  f"{time.perf_counter() - t:.0f} s", file=sys.stderr)
        runs: dict[str, list[dict]] = {e: [] for e in engines}
        for rep in range(args.repeats):                     # interleaved: A B C A B C
            for e in engines:
                got = subprocess.run([sys.executable, __file__, "--child", str(fleet), e],
                                     capture_output=True, text=True, check=True)
                runs[e].append(json.loads(got.stdout.strip().splitlines()[-1]))
                r = runs[e][-1]
                loads.append(r["load"])
                print(f"# {size} robots, {e}: {r['calibrate_s']:.1f} s (+{r['startup_s']:.1f}"
                      f" s start-up), repeat {rep + 1}", file=sys.stderr)
        for e in engines:
            med = {k: statistics.median(r[k] for r in runs[e]) for k in
                   ("startup_s", "calibrate_s", "overhead_s_per_task", "client_peak_mb")}
            wp = [r["worker_peak_mb"] for r in runs[e] if r["worker_peak_mb"] is not None]
            rows.append((size, e, med, statistics.median(wp) if wp else None,
                         runs[e][0]["failed"]))
    base = {size: med["calibrate_s"] for size, e, med, _, _ in rows if e == "serial"}
    print(f"\nfleet calibration, {args.poses} poses per robot, median of {args.repeats} "
          f"interleaved repeat(s), {os.cpu_count()} cores, 1-minute load average at the "
          f"start of each run {min(loads):.1f}-{max(loads):.1f}")
    print("| robots | engine | start-up [s] | calibration [s] | robots/s | vs loop | "
          "overhead per task [ms] | client peak [MB] | worker peak [MB] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size, e, med, wp, failed in rows:
        name = "in-process loop" if e == "serial" else f"LocalCluster, {e} worker(s)"
        speed = base.get(size, float("nan")) / med["calibrate_s"]
        print(f"| {size:,} | {name} | {med['startup_s']:.2f} | {med['calibrate_s']:.1f} | "
              f"{size / med['calibrate_s']:.1f} | {speed:.2f}x | "
              f"{med['overhead_s_per_task'] * 1e3:.3f} | {med['client_peak_mb']:.0f} | "
              f"{_fmt(wp, '.0f')} |" + (f" {failed} failed" if failed else ""))


if __name__ == "__main__":
    main()
