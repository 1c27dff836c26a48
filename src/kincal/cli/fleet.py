"""``kincal fleet``: calibrate many robots on Dask, keep their history, watch for drift.

Commands: ``calibrate`` (every session of a manifest, on an embedded LocalCluster or
``--scheduler``), ``simulate`` (a simulated fleet), ``drift`` (latest vs previous
calibration of every robot; ``--report`` writes the fleet page), ``history`` (one
robot's or every robot's records) and ``export`` (CSV / JSON).  The work lives in
:mod:`kincal.fleet`; Dask and SQLAlchemy are imported inside the commands only, so the
command line starts fast and works without the ``fleet`` extra until a fleet command
runs.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.calibration_common import JsonOpt, out_console
from kincal.cli.common import err_console
from kincal.cli.options import SeedOpt
from kincal.errors import KincalError
from kincal.units import display_scale

fleet_app = typer.Typer(
    name="fleet", no_args_is_help=True, add_completion=False, rich_markup_mode=None,
    help="Calibrate many robots on Dask distributed, keep every calibration in a database "
    "(SQLite file or any SQLAlchemy URL) and flag robots whose parameters drifted.")
app.add_typer(fleet_app, name="fleet")

DbOpt = Annotated[str, typer.Option(
    "--db", metavar="FILE|URL", help="The calibration history: an SQLite file (created "
    "when missing) or an SQLAlchemy URL, e.g. postgresql+psycopg://user@host/kincal.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", help="No progress bar.")]
DEFAULT_DB = "history.db"


def _need_fleet_extra() -> None:
    """A one-line error when the ``fleet`` extra is missing."""
    import importlib.util

    missing = [m for m in ("distributed", "sqlalchemy") if importlib.util.find_spec(m) is None]
    if missing:
        raise KincalError(f"kincal fleet needs {', '.join(missing)}: pip install "
                          "'kincal[fleet]'")


def _store(db: str, lock_timeout: float = 30.0, create: bool = True) -> Any:
    _need_fleet_extra()
    from kincal.fleet.store import HistoryStore

    return HistoryStore(db, lock_timeout=lock_timeout, create=create)


def _mm(v: float | None) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v * 1e3:.4f}"


# --------------------------------------------------------------------------- calibrate
@fleet_app.command("calibrate")
def calibrate_cmd(
    fleet: Annotated[str, typer.Argument(
        metavar="MANIFEST", help="A fleet manifest (YAML: robots, sessions, files, options; "
        "docs/conventions.md), a folder holding fleet.yaml, or a folder "
        "<serial>/<date>/*.csv (then --robot or --config).")],
    db: DbOpt = DEFAULT_DB,
    robot: Annotated[str | None, typer.Option(
        "--robot", help="Robot of every session whose manifest names none (built-in name, "
        "YAML or URDF).")] = None,
    config: Annotated[str | None, typer.Option(
        "--config", help="A setup file (no data) whose keys are the fleet's defaults.")
    ] = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", metavar="tcp://HOST:PORT", help="Run on an existing Dask cluster "
        "(started with `dask scheduler` and `dask worker`) instead of an embedded one.")
    ] = None,
    workers: Annotated[int | None, typer.Option(
        "--workers", min=1, help="Worker processes of the embedded LocalCluster (default: "
        "one per core).")] = None,
    serial_run: Annotated[bool, typer.Option(
        "--serial", help="Run in this process, no cluster (small fleets, debugging).")
    ] = False,
    force: Annotated[bool, typer.Option(
        "--force", help="Recompute sessions already in the history with the same inputs.")
    ] = False,
    lock_timeout: Annotated[str, typer.Option(
        "--lock-timeout", help="How long to wait for an SQLite file another process is "
        "writing, with its unit.")] = "30s",
    json_out: JsonOpt = None, quiet: QuietOpt = False,
) -> None:
    """Calibrate every robot session of MANIFEST, one Dask task per session, and store each
    result in the history (--db) as it arrives.

    Sessions whose inputs (files, robot, options) are already stored are skipped, so an
    interrupted run continues where it stopped. One robot's bad file fails that robot
    only; its reason is stored and listed. Exit status 1 when any session failed, did not
    converge or cannot be trusted (the checks of `kincal calibrate`)."""
    from kincal.units import parse_quantity

    _need_fleet_extra()
    from kincal.fleet.engine import make_engine
    from kincal.fleet.manifest import load_fleet, setup_defaults
    from kincal.fleet.run import calibrate_fleet

    out = out_console(json_out)
    wait = parse_quantity(lock_timeout, "time", "--lock-timeout", minimum=0.0)
    tasks = load_fleet(fleet, setup_defaults(config, robot))
    store = _store(db, wait)
    store.check_writable()
    bar = _Bar(not quiet and json_out != "-")
    with store, make_engine(scheduler, workers, serial_run) as engine:
        out.print(f"{len(tasks)} session(s) of {len({t.serial for t in tasks})} robot(s); "
                  f"engine: {escape(engine.describe())}; history: {escape(store.display)}")
        with bar:
            summary = calibrate_fleet(tasks, store, engine, force=force, on_start=bar.start,
                                      on_record=bar.advance)
    _print_summary(out, summary)
    if json_out:
        from kincal.io import write_json

        write_json(json_out, {"db": store.display, **summary.to_dict()})
    if summary.failed:
        err_console.print(f"error: {len(summary.failed)} session(s) failed; their reasons "
                          "are listed above and stored in the history")
        raise typer.Exit(1)


class _Bar:
    """A rich progress bar over sessions (stderr)."""

    def __init__(self, enabled: bool) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(TextColumn("[bold]calibrating"), BarColumn(),
                                 MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                                 TimeElapsedColumn(), TimeRemainingColumn(),
                                 console=err_console, transient=True,
                                 disable=not enabled or not err_console.is_terminal)
        self.task: Any = None
        self.failed = 0

    def __enter__(self) -> _Bar:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.__exit__(*exc)

    def start(self, total: int) -> None:
        self.task = self.progress.add_task("calibrating", total=total, info="")

    def advance(self, record: Any) -> None:
        self.failed += record["status"] != "ok"
        self.progress.update(self.task, advance=1, info=f"{record['serial']} "
                             f"{record['status']}" + (f", {self.failed} failed"
                                                      if self.failed else ""))


def _print_summary(out: Any, s: Any) -> None:
    out.print(f"[bold]{s.calibrated}[/bold] session(s) calibrated, {s.skipped} already in the "
              f"history (skipped), [{'red' if s.failed else 'green'}]{len(s.failed)} failed"
              f"[/{'red' if s.failed else 'green'}]; {s.crosschecks} previous calibration(s) "
              f"checked on newer data; {s.seconds:.1f} s")
    if s.failed:
        t = Table(title="Failed sessions")
        for c in ("robot", "date", "status", "reason"):
            t.add_column(c, overflow="fold")
        for serial, date, status, reason in s.failed:
            t.add_row(escape(serial), date, f"[red]{escape(status)}[/red]", escape(reason))
        out.print(t)


# --------------------------------------------------------------------------- simulate
@fleet_app.command("simulate")
def simulate_cmd(
    robot: Annotated[str, typer.Argument(help="The robot model (built-in name, YAML or "
                                         "URDF).")],
    out_dir: Annotated[str, typer.Option("--out-dir", help="Folder to write the fleet in "
                                         "(<serial>/<date>/tracker.csv, fleet.yaml, "
                                         "truth.json).")],
    robots: Annotated[int, typer.Option("-n", "--robots", min=1, help="Robots.")] = 20,
    sessions: Annotated[int, typer.Option("--sessions", min=1, help="Calibration sessions "
                                          "per robot.")] = 2,
    poses: Annotated[int, typer.Option("--poses", min=1, help="Measured poses per "
                                       "session.")] = 50,
    noise: Annotated[str, typer.Option("--noise", help="Tracker noise per coordinate "
                                       "(standard deviation) with its unit.")] = "0.01mm",
    drifted: Annotated[int, typer.Option("--drifted", min=0, help="Robots with one joint "
                                         "parameter drifted between their last two "
                                         "sessions.")] = 2,
    drift_sigma: Annotated[float, typer.Option(
        "--drift-sigma", min=0.0, help="Size of each drift in predicted combined standard "
        "errors of that parameter.")] = 10.0,
    broken: Annotated[int, typer.Option("--broken", min=0, help="Robots whose last session "
                                        "file is unreadable.")] = 1,
    start: Annotated[str, typer.Option("--start", help="Date of the first session, "
                                       "YYYY-MM-DD.")] = "2026-01-05",
    interval: Annotated[int, typer.Option("--interval", min=1, help="Days between "
                                          "sessions.")] = 91,
    seed: SeedOpt = 0,
    json_out: JsonOpt = None,
) -> None:
    """Write a simulated fleet of ROBOT: each robot with its own errors, measured by a
    tracker at every session, a few drifted between their last two sessions and a few
    with a broken file; fleet.yaml lists the sessions, truth.json what was injected."""
    from kincal.fleet.simulate import simulate_fleet
    from kincal.units import parse_quantity

    out = out_console(json_out)
    sd = parse_quantity(noise, "length", "--noise", minimum=0.0)
    got = simulate_fleet(out_dir, robot=robot, robots=robots, sessions=sessions,
                         poses=poses, noise=sd, drifted=drifted, broken=broken,
                         drift_sigma=drift_sigma, seed=seed, start=start,
                         interval_days=interval)
    out.print(f"simulated {robots} robot(s) x {sessions} session(s) x {poses} poses of "
              f"{escape(robot)} (tracker noise {sd * 1e3:g} mm) -> {escape(str(got.root))}/")
    for r in got.robots:
        if r["drift"]:
            d = r["drift"]
            f, u = display_scale(d["unit"])
            out.print(f"  {r['serial']}: {d['parameter']} {d['change'] * f:+.4g} {u} between "
                      f"{d['from']} and {d['to']} ({d['sigmas']:g} predicted σ)")
        if r["broken"]:
            out.print(f"  {r['serial']}: {escape(r['broken']['file'])} line "
                      f"{r['broken']['line']} made unreadable")
    out.print(f"manifest: {escape(str(got.manifest))}; truth: {escape(str(got.truth))}")
    if json_out:
        from kincal.io import write_json

        write_json(json_out, got.to_dict())


# --------------------------------------------------------------------------- drift
@fleet_app.command("drift")
def drift_cmd(
    db: DbOpt = DEFAULT_DB,
    false_alarm: Annotated[float, typer.Option(
        "--false-alarm", help="Probability that a robot that did not change is flagged "
        "anyway (per robot, both tests together).")] = 1e-3,
    report: Annotated[str | None, typer.Option("--report", help="Write the fleet page "
                                               "(HTML) here.")] = None,
    all_robots: Annotated[bool, typer.Option("--all", help="List every robot, not only the "
                                             "flagged ones.")] = False,
    reproducibility: Annotated[str, typer.Option(
        "--reproducibility", help="fleet: allow for the session-to-session (placement-to-"
        "placement) error estimated from the other robots of the model, added to each "
        "change's covariance or grown with the calibrations' own (the model their changes "
        "support); none: the calibrations' own standard errors alone.")] = "fleet",
    json_out: JsonOpt = None,
) -> None:
    """Compare each robot's latest calibration with its previous one: per-parameter change
    in combined standard errors, a chi-square test on the identifiable set, and the
    previous model's error on the new data. Exit status 1 when a robot is flagged."""
    from kincal.fleet.drift import fleet_drift

    out = out_console(json_out)
    if report:
        from kincal.io import check_outputs

        check_outputs({"--report": report, "--json": json_out}, {})
    with _store(db, create=False) as store:
        if reproducibility not in ("fleet", "none"):
            raise KincalError(f"option --reproducibility: {reproducibility!r} is not fleet "
                              "or none")
        check = fleet_drift(store, false_alarm, reproducibility=reproducibility == "fleet")
        drifts, flagged = check.robots, check.flagged
        if report:
            from kincal.fleet.page import fleet_page
            from kincal.io import atomic_write_text

            summaries = store.summaries()
            ids: dict[str, list[int]] = {}
            for s in summaries:
                if s["status"] == "ok":
                    ids.setdefault(s["serial"], []).append(s["id"])
            histories: dict[str, list[Any]] = {}
            for d in flagged[:30]:
                histories[d.serial] = store.records(ids[d.serial])
            atomic_write_text(report, fleet_page(summaries, drifts, histories,
                                                 false_alarm=false_alarm))
    t = Table(title=f"Drift between the last two calibrations ({len(flagged)} of "
              f"{len(drifts)} robots flagged)")
    for c in ("robot", "latest", "max |z|", "χ²/dof", "p", "RMS [mm]", "prev. model [mm]"):
        t.add_column(escape(c), justify="left" if c in ("robot", "latest") else "right")
    shown = [d for d in drifts if d.flagged or all_robots]
    for d in shown:
        red = d.flagged
        t.add_row(f"[red]{escape(d.serial)}[/red]" if red else escape(d.serial), d.latest[1],
                  f"{d.z_max:.1f}", f"{d.chi2:.1f}/{d.dof}", f"{d.p_value:.2g}",
                  _mm(d.rms_latest_m), _mm(d.rms_previous_model_m))
    if shown:
        out.print(t)
    for d in flagged:
        for note in d.notes():
            out.print(f"[red]{escape(d.serial)}[/red]: {escape(note)}")
    if not drifts:
        out.print("no robot has two calibrated sessions yet: nothing to compare")
    else:
        z = drifts[0].z_crit
        out.print(f"{len(flagged)} of {len(drifts)} robot(s) flagged (per-parameter threshold "
                  f"|z| > {z:.2f} for {len(drifts[0].changes)} parameters, or the chi-square "
                  f"test; false-alarm probability {false_alarm:g} per robot)")
        out.print(check.reproducibility_line())
    if report:
        out.print(f"fleet page: {escape(report)}")
    if json_out:
        from kincal.io import write_json

        write_json(json_out, check.to_dict())
    if flagged:
        err_console.print(f"error: {len(flagged)} robot(s) drifted: "
                          + ", ".join(d.serial for d in flagged[:10])
                          + (" ..." if len(flagged) > 10 else ""))
        raise typer.Exit(1)


# --------------------------------------------------------------------------- history
@fleet_app.command("history")
def history_cmd(
    serial: Annotated[str | None, typer.Argument(help="One robot's serial number (default: "
                                                 "every robot).")] = None,
    db: DbOpt = DEFAULT_DB, json_out: JsonOpt = None,
) -> None:
    """List the calibrations stored in the history: date, status, RMS, reason."""
    out = out_console(json_out)
    with _store(db, create=False) as store:
        rows = store.summaries([serial] if serial else None)
    if serial and not rows:
        raise KincalError(f"no calibration of robot {serial!r} in the history",
                          source=store.display)
    t = Table(title=escape(f"Calibration history ({len(rows)} records; position RMS [mm])"),
              caption=escape("iter.: solver iterations; train / held-out / CV: position RMS "
                             "on the training data, held-out files, cross-validation [mm]"))
    for c in ("robot", "date", "status", "iter.", "train", "held-out", "CV", "kincal"):
        t.add_column(c, justify="right" if c in ("iter.", "train", "held-out", "CV")
                     else "left", no_wrap=c in ("robot", "date"))
    for r in rows:
        st = r["status"]
        t.add_row(escape(r["serial"]), r["date"], st if st == "ok" else f"[red]{st}[/red]",
                  "-" if r["iterations"] is None else str(r["iterations"]),
                  _mm(r["rms_train_m"]), _mm(r["rms_validation_m"]), _mm(r["rms_cv_m"]),
                  r["kincal_version"])
    out.print(t)
    for r in rows:
        if r["reason"]:
            out.print(f"[red]{escape(r['serial'])} {r['date']}[/red]: {escape(r['reason'])}")
    if json_out:
        from kincal.io import write_json

        write_json(json_out, {"records": rows})


# --------------------------------------------------------------------------- export
@fleet_app.command("export")
def export_cmd(
    output: Annotated[str, typer.Option("-o", "--output", help="File to write: .csv (one row "
                                        "per calibration, estimates in mm / deg) or .json "
                                        "(every record in full, SI).")],
    db: DbOpt = DEFAULT_DB,
    parameters_out: Annotated[str | None, typer.Option(
        "--parameters", help="Also write one CSV row per calibration and parameter "
        "(estimate, standard error; SI).")] = None,
    robots_dir: Annotated[str | None, typer.Option(
        "--out-dir", metavar="DIR", help="Also write each robot's latest calibrated robot "
        "file, DIR/<serial>.yaml (SI; what `kincal calibrate -o` writes).")] = None,
) -> None:
    """Write the calibration history as CSV or JSON (and the calibrated robot files)."""
    from kincal.fleet.export import history_csv, history_json, parameters_csv
    from kincal.io import atomic_write_text, check_outputs

    suffix = Path(output).suffix.lower()
    if suffix not in (".csv", ".json"):
        raise KincalError(f"option -o: {output!r}: give a .csv or .json file name")
    if parameters_out and Path(parameters_out).suffix.lower() != ".csv":
        raise KincalError(f"option --parameters: {parameters_out!r}: give a .csv file name")
    check_outputs({"-o": output, "--parameters": parameters_out}, {})
    with _store(db, create=False) as store:
        records = store.records([r["id"] for r in store.summaries()])
    text = history_csv(records) if suffix == ".csv" else history_json(records)
    params = parameters_csv(records) if parameters_out else None
    robot_files = _robot_files(records) if robots_dir else {}
    atomic_write_text(output, text)
    if params is not None and parameters_out:
        atomic_write_text(parameters_out, params)
    for serial, yaml_text in robot_files.items():
        atomic_write_text(Path(robots_dir or ".") / f"{serial}.yaml", yaml_text)
    out_console(None).print(f"{len(records)} calibration record(s) -> {escape(output)}"
                            + (f"; parameters -> {escape(parameters_out)}"
                               if parameters_out else "")
                            + (f"; {len(robot_files)} calibrated robot file(s) -> "
                               f"{escape(str(robots_dir).rstrip('/'))}/" if robots_dir else ""))


def _robot_files(records: list[Any]) -> dict[str, str]:
    """``{serial: robot file text}`` of each robot's latest ``ok`` calibration."""
    import re

    from kincal.fleet.tasks import calibrated_robot
    from kincal.robots.files import robot_yaml_text

    latest: dict[str, Any] = {}
    for r in records:
        if r["status"] == "ok" and (r["serial"] not in latest or (r["date"], r["id"]) >
                                    (latest[r["serial"]]["date"], latest[r["serial"]]["id"])):
            latest[r["serial"]] = r
    out = {}
    for serial, r in sorted(latest.items()):
        if not re.fullmatch(r"[A-Za-z0-9._-]+", serial):
            raise KincalError(f"option --out-dir: serial {serial!r} cannot be a file name")
        out[serial] = robot_yaml_text(calibrated_robot(r))
    return out


# --------------------------------------------------------------------------- prior
@fleet_app.command("prior")
def prior_cmd(
    output: Annotated[str, typer.Option("-o", "--output", help="Robot file to write (YAML): "
                                        "the model with the fleet means as values and the "
                                        "fleet spread as its tolerances.")],
    db: DbOpt = DEFAULT_DB,
    serials: Annotated[list[str] | None, typer.Option(
        "--serial", help="Use only these robots (repeat the option); default: every "
        "robot of the history.")] = None,
    json_out: JsonOpt = None,
) -> None:
    """Estimate the fleet prior of a robot model from the latest calibration of each robot
    (mean and between-robot spread of every parameter the data fixed, each robot's own
    standard error removed) and write it as a robot file: `kincal calibrate FILE -d DATA`
    (or `robot: FILE` in a setup file) then calibrates a new robot of the model with it."""
    from kincal.fleet.prior import fleet_prior, write_fleet_prior
    from kincal.io import check_outputs

    out = out_console(json_out)
    check_outputs({"--output": output, "--json": json_out}, {})
    with _store(db, create=False) as store:
        latest: dict[str, Any] = {}
        for s in store.summaries(serials):
            if s["status"] == "ok":
                latest[s["serial"]] = s
        records = store.records([s["id"] for s in latest.values()])
    prior = fleet_prior(records)
    write_fleet_prior(prior, output)
    t = Table(title=f"Fleet prior from {len(prior.serials)} robot(s)")
    for c in ("parameter", "unit", "nominal", "fleet mean", "between robots", "prior (1σ)"):
        t.add_column(c, justify="left" if c in ("parameter", "unit") else "right")
    for p in prior.parameters:
        f, u = display_scale(p.unit)
        t.add_row(escape(p.name), u, f"{p.nominal * f:.4f}", f"{p.mean * f:.4f}",
                  f"{p.spread * f:.4f}", f"{p.std * f:.4f}")
    out.print(t)
    out.print(f"fleet prior of {len(prior.parameters)} parameter(s) -> {escape(output)} "
              f"(use it as the robot: kincal calibrate {escape(output)} -d DATA ..., or "
              f"robot: {escape(output)} in a setup file)")
    if json_out:
        from kincal.io import write_json

        write_json(json_out, {"robot": prior.robot, "serials": list(prior.serials),
                              "parameters": [dict(vars(p), std=p.std)
                                             for p in prior.parameters]})
