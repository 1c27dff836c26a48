"""Shared pieces of the calibration commands: option types, robot loading, progress, tables.

Used by :mod:`kincal.cli.calibration`, :mod:`~kincal.cli.simulate`,
:mod:`~kincal.cli.compensate`, :mod:`~kincal.cli.demo` and :mod:`~kincal.cli.export`.
Tables show mm and degrees; everything computed stays SI (m, rad).
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Iterator, Sequence
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from kincal.cli.common import JsonOut, console, err_console, is_fivebar
from kincal.cli.options import console_quantity, console_units
from kincal.errors import KincalError

JsonOpt = JsonOut

# --------------------------------------------------------------------------- options
DataOpt = Annotated[list[str], typer.Option("--data", "-d", help="Measurement CSV file "
                                            "(repeat for several instruments / sessions; each "
                                            "file is one block with its own instrument frame).")]
OptionalDataOpt = Annotated[list[str] | None, typer.Option(
    "--data", "-d", help="Measurement CSV file, or a folder of per-socket files (repeat for "
    "several instruments / sessions; each file is one block with its own instrument "
    "frame).")]
OptionalRobotArg = Annotated[str | None, typer.Argument(
    metavar="ROBOT", help="Built-in robot name (see `kincal robots`), or a path to a YAML "
    "robot file or a URDF file (or robot: in the --config setup file).", show_default=False)]
UnitsOpt = Annotated[str | None, typer.Option(
    "--units", help="Units of columns whose header has none, e.g. "
    "'x1=m,y1=m,z1=m,arm_1_joint=rad'; keys may use * and ? ('x?=m').")]
IgnoreOpt = Annotated[list[str] | None, typer.Option(
    "--ignore", help="Columns to drop on purpose, comma separated, * and ? allowed "
    "('x2,y2,z2' or '?2,?3'). Columns that look like joints or measurements are never "
    "dropped silently.")]
JointNamesOpt = Annotated[str | None, typer.Option(
    "--joint-names", metavar="MAP", help="Joint columns under other names, FILE_COLUMN=JOINT "
    "comma separated (e.g. 'J1=q1,J2=q2'); 'ros' for the ROS names of a built-in robot "
    "(recognised by themselves: shoulder_pan_joint, panda_joint1, joint_a1, joint_1).")]
JointModelOpt = Annotated[str | None, typer.Option(
    "--joint-model", metavar="TERMS", help="Non-geometric joint model, comma separated: "
    "'hysteresis' (each joint lags its encoder by a play, in the direction it last moved; "
    "needs the rows of every file in the order measured) and/or 'compliance' (each joint "
    "yields under its gravity load; needs link masses: a URDF's <inertial>, a robot file's "
    "masses:, the built-in URs'). Default: "
    "geometric only.")]
LengthUnit = Annotated[str, typer.Option("--length-unit", help="Length unit of written CSV "
                                         "files: m, mm, um.")]
AngleUnit = Annotated[str, typer.Option("--angle-unit", help="Angle unit of written CSV files: "
                                        "rad, deg.")]


SchedulerOpt = Annotated[str | None, typer.Option(
    "--scheduler", metavar="tcp://HOST:PORT", help="Run the cross-validation and --select "
    "auto fits on this Dask cluster (the fleet extra). Worth it for fits of a second or "
    "more: each task costs a few ms.")]
WorkersOpt = Annotated[int | None, typer.Option(
    "--workers", min=1, help="Run the cross-validation and --select auto fits on an "
    "embedded Dask LocalCluster of this many processes (the fleet extra; starting it "
    "costs ~2 s, so it gains above ~10 s of fits).")]


# --------------------------------------------------------------------------- helpers
@contextlib.contextmanager
def fold_engine(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """The Dask engine of ``--scheduler`` / ``--workers`` (None without them), closed
    after the command; Dask is imported only here."""
    if scheduler is None and workers is None:
        yield None
        return
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise KincalError("--scheduler / --workers need Dask: pip install 'kincal[fleet]'")
    from kincal.fleet.engine import DaskEngine

    with DaskEngine(scheduler=scheduler, workers=workers) as engine:
        yield engine


def out_console(json_path: str | None) -> Console:
    """Tables go to stdout unless the JSON does (``--json -``)."""
    return err_console if json_path == "-" else console


def load(spec: str, base_link: str | None = None, tip_link: str | None = None) -> Any:
    """Load ROBOT (library name, YAML or URDF path)."""
    from kincal.workflow.robots import load_any_robot

    return load_any_robot(spec, base_link=base_link, tip_link=tip_link)


def print_cross_validation(out: Any, cv: dict[str, Any]) -> None:
    """One line per error kind of ``run_flow(cross_validate=K)`` (mm / deg / px)."""

    for key, v in cv.items():
        if key.startswith("rms_"):
            name, f, unit = console_quantity(key[4:])
            out.print(f"{cv['folds']}-fold cross-validation on the training file (seed "
                      f"{cv['seed']}, split by {cv['split']}): RMS {escape(name)} "
                      f"{v * f:.4g} {escape(unit)} on held-out folds")


def serial(robot: Any, command: str) -> Any:
    """``robot`` if it is a serial robot, else a one-line error naming ``command``."""
    if is_fivebar(robot):
        raise KincalError(f"`kincal {command}` works on serial robots; for the five-bar use "
                          "`kincal calibrate` or the fivebar-* commands")
    return robot


def check_unit(unit: str, dimension: str, option: str) -> str:
    """``unit`` if it is a ``dimension`` unit of measurement files, else a one-line error."""
    from kincal.units import UNITS

    if unit not in UNITS or UNITS[unit][0] != dimension:
        ok = [u for u, (d, _) in UNITS.items() if d == dimension]
        raise KincalError(f"option {option}: {unit!r} is not a {dimension} unit "
                          f"({', '.join(ok)})")
    return unit


def read_blocks(paths: Sequence[str], robot: Any, units: str | None,
                ignore: Sequence[str] | None, out: Console | None = None) -> list[Any]:
    """:func:`kincal.workflow.flow.read_blocks`, printing the columns each file did not read."""
    from kincal.workflow.flow import read_blocks as read

    blocks = read(paths, robot, units, ignore)
    if out is not None:
        print_ignored(out, blocks)
    return blocks


def joint_names_option(text: str | None) -> list[str]:
    """``--joint-names MAP`` as an ``--option`` item (the ``joint_names`` tag)."""
    return [f"joint_names={text.strip()}"] if text and text.strip() else []


def print_ignored(out: Console, blocks: Sequence[Any]) -> None:
    """One dim line per file: the columns its reader did not read."""
    from kincal.workflow.flow import ignored_columns

    for path, cols in ignored_columns(blocks):
        out.print(f"[dim]{escape(path)}: not read (not joint or measurement "
                  f"columns): {escape(', '.join(cols))}[/dim]")
    for b in blocks:                     # how a file in another spelling was read
        table = b.provenance.table if b.provenance is not None else None
        for note in getattr(table, "notes", None) or []:
            out.print(f"[dim]{escape(b.source_label)}: {escape(note)}[/dim]")


class Progress:
    """A rich progress bar fed by the solver's per-iteration callback (on stderr)."""

    def __init__(self, total: int, enabled: bool = True) -> None:
        from rich.progress import BarColumn, TextColumn, TimeElapsedColumn
        from rich.progress import Progress as RichProgress

        self.total = total
        self.progress = RichProgress(TextColumn("[bold]{task.description}"), BarColumn(),
                                     TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                                     console=err_console, transient=True,
                                     disable=not enabled or not err_console.is_terminal)
        self.task: Any = None
        self.stage: Any = None

    def __enter__(self) -> Progress:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.__exit__(*exc)

    def mapper_on(self, engine: Any) -> Any:
        """:meth:`mapper`, or with a fleet engine (:func:`fold_engine`) the same bar over
        the fold tasks run on Dask, results in input order."""
        if engine is None:
            return self.mapper

        def on_dask(fn: Any, tasks: Any) -> list[Any]:
            tasks = list(tasks)
            task = self.progress.add_task("cross-validation", total=len(tasks),
                                          info=f"{len(tasks)} fits on {engine.describe()}")
            out: list[Any] = [None] * len(tasks)
            for k, (i, result, exc) in enumerate(engine.map_unordered(fn, tasks)):
                if exc is not None:
                    raise exc
                out[i] = result
                self.progress.update(task, completed=k + 1)
            self.progress.remove_task(task)
            return out
        return on_dask

    def mapper(self, fn: Any, tasks: Any) -> Any:
        """A ``map`` for the fold tasks of model selection and cross-validation that
        advances a bar per finished task."""
        tasks = list(tasks)
        task = self.progress.add_task("cross-validation", total=len(tasks),
                                      info=f"{len(tasks)} fits")
        for k, t in enumerate(tasks):
            yield fn(t)
            self.progress.update(task, completed=k + 1, info=f"fit {k + 1} of {len(tasks)}")
        self.progress.remove_task(task)

    def __call__(self, rec: Any) -> None:
        if rec.stage != self.stage:     # one bar, restarted per stage (the procedure has many)
            self.stage = rec.stage
            if self.task is None:
                self.task = self.progress.add_task(f"stage {rec.stage}", total=self.total,
                                                   info="")
            else:
                self.progress.reset(self.task, total=self.total,
                                    description=f"stage {rec.stage}")
        self.progress.update(self.task, completed=min(rec.iteration, self.total),
                             info=f"iteration {rec.iteration}  RMS {rec.rms:.4g} sigma")


# --------------------------------------------------------------------------- tables
def scaled(v: float | None, factor: float) -> str:
    """``v * factor`` for a table cell (4 decimals in mm / deg, 7 in SI with ``--si``)."""
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v * factor:.{7 if console_units().si else 4}f}"


def print_errors(out: Console, comparisons: Sequence[Any]) -> None:
    """The before/after table: RMS and max of every measured error kind (mm, deg, px)."""
    from kincal.report.metrics import error_keys, error_metrics

    captions = [escape(c.title) for c in comparisons if " (" in c.title]
    t = Table(title="Errors before -> after calibration", caption="; ".join(captions) or None)
    for c in ("data", "quantity", "n", "RMS before", "RMS after", "max before", "max after"):
        t.add_column(c, justify="left" if c in ("data", "quantity") else "right",
                     overflow="fold", no_wrap=c == "quantity")
    for c in comparisons:
        for k, key in enumerate(error_keys(c.before, c.after)):
            name, f, unit = console_quantity(key)
            b = error_metrics({key: c.before[key]}) if key in c.before else {}
            a = error_metrics({key: c.after[key]}) if key in c.after else {}
            t.add_row(escape(c.title.split(" (")[0]) if k == 0 else "", escape(f"{name} [{unit}]"),
                      str(a.get("n", b.get("n", ""))), scaled(b.get(f"rms_{key}"), f),
                      f"[bold]{scaled(a.get(f'rms_{key}'), f)}[/bold]",
                      scaled(b.get(f"max_{key}"), f), scaled(a.get(f"max_{key}"), f))
    out.print(t)
    for c in comparisons:
        if c.note:
            out.print(f"[dim]{escape(c.title.split(' (')[0])}: {escape(c.note)}[/dim]")


def print_heldout(out: Console, files: Sequence[Any], title: str = "Held-out files") -> None:
    """One row per held-out file and error kind, then the pooled row: RMS before and
    after, max after, and for measured points the predicted RMS and how many poses lie
    outside the training region; then each file's protocol, extrapolation warnings and,
    for artifacts, the per-socket spread and the signed distance errors."""
    from kincal.report.metrics import error_keys, error_metrics, merge_errors
    from kincal.workflow.heldout import before_lines

    if not files:
        return
    t = Table(title=f"{title}: errors before -> after, one row per file",
              caption="\n".join(before_lines(f.protocol for f in files if f.before)
                                 or ["before: not evaluated (--before NOMINAL gives it)"]))
    for c in ("file", "quantity", "n", "RMS before", "RMS after", "max after",
              "predicted RMS", "outside region"):
        t.add_column(c, justify="left" if c in ("file", "quantity") else "right",
                     overflow="fold")
    rows = [(f.file, f.before, f.after, f.prediction_metrics()) for f in files]
    if len(files) > 1:
        rows.append(("pooled", merge_errors([f.before for f in files]),
                     merge_errors([f.after for f in files]), None))
    for label, before, after, pm in rows:
        for k, key in enumerate(error_keys(before, after)):
            name, f, unit = console_quantity(key)
            b = error_metrics({key: before[key]}) if key in before else {}
            a = error_metrics({key: after[key]}) if key in after else {}
            pred = out_n = ""
            if pm is not None and key == "position_m":
                pred = scaled(pm["predicted_rms_m"], f)
                out_n = f"{pm['outside_n']} of {pm['n']}"
            t.add_row(escape(label) if k == 0 else "", escape(f"{name} [{unit}]"),
                      str(a.get("n", b.get("n", ""))), scaled(b.get(f"rms_{key}"), f),
                      f"[bold]{scaled(a.get(f'rms_{key}'), f)}[/bold]",
                      scaled(a.get(f"max_{key}"), f), pred, out_n)
    out.print(t)
    for f in files:
        out.print(f"[dim]{escape(f.file)}: {escape(f.note)}[/dim]")
        if f.prediction is not None:
            pm = f.prediction_metrics()
            for sentence in f.prediction.summary(unit=console_units().scale("m")):
                out.print(f"  {escape(sentence)}")
            if pm is not None:
                lf, L = console_units().scale("m")
                parts = [f"{where} {scaled(pm[f'measured_rms_{where}_m'], lf)} {L} (predicted "
                         f"{scaled(pm[f'predicted_rms_{where}_m'], lf)})"
                         for where in ("inside", "outside") if pm[f"{where}_n"]]
                out.print("  measured RMS " + ", ".join(parts))
        if f.artifact is not None:
            _print_artifact(out, f)


def _print_artifact(out: Console, f: Any) -> None:
    a = f.artifact
    lf, L = console_units().scale("m")
    d = 3 + 3 * console_units().si                     # um resolution in mm or m
    t = Table(title=f"{f.file}: artifact metrics (before = the plain nominal robot)")
    for c in ("socket / distance", f"before [{L}]", f"after [{L}]"):
        t.add_column(c, justify="left" if c.startswith("socket") else "right")
    for site, v in a["after"]["spread_m"].items():
        t.add_row(escape(f"spread {site}"), f"{a['before']['spread_m'][site] * lf:.{d}f}",
                  f"{v * lf:.{d}f}")
    for db, da in zip(a["before"]["distances"], a["after"]["distances"], strict=True):
        t.add_row(escape(f"distance error {da['placement']} {da['label']}"),
                  f"{db['error_m'] * lf:+.{d}f}", f"{da['error_m'] * lf:+.{d}f}")
    out.print(t)


def print_parameters(out: Console, res: Any, everything: bool = False) -> None:
    """Estimated parameters: nominal, estimate, change, std (mm / deg); with a prior
    (MAP estimate), its standard deviation ``prior (1σ)`` per parameter."""
    d = res.to_dict()
    with_prior = any(p.get("prior_std") is not None for p in d["parameters"])
    u = console_units()
    shown = [p for p in d["parameters"] if everything or p["estimated"]]
    statuses = {p["status"] for p in shown}
    one_status = len(statuses) == 1          # the same for all: said once, in the caption
    t = Table(title=f"Estimated parameters ({d['estimated_count']} of {len(d['parameters'])}; "
              f"lengths {u.length_unit}, angles {u.angle_unit})",
              caption=f"status: all {escape(next(iter(statuses)))}" if one_status else None)
    cols = ["parameter", "nominal", "estimate", "change", "std (1σ)"]
    cols += ["prior (1σ)"] * with_prior + ["status"] * (not one_status)
    for c in cols:
        t.add_column(c, justify="left" if c in ("parameter", "status") else "right",
                     overflow="fold")
    for p in shown:
        factor, _ = u.scale(p["unit"])
        f = functools.partial(scaled, factor=factor) if p["unit"] in ("m", "rad") else \
            "{:g}".format
        cells = [escape(p["name"]), f(p["nominal"]), f(p["estimate"]),
                 f(p["estimate"] - p["nominal"]), f(p["std"]) if p["std"] is not None else "-"]
        if with_prior:
            cells.append(f(p["prior_std"]) if p.get("prior_std") is not None else "-")
        t.add_row(*cells, *[escape(p["status"])] * (not one_status))
    out.print(t)


def print_identifiability(out: Console, res: Any, limit: int = 8) -> None:
    """What the data could not identify, grouped by what absorbs it."""
    from kincal.report.html import identifiability_groups

    rep = res.identifiability
    held = rep.not_identifiable
    out.print(f"identifiability: [bold]{len(rep.identifiable)}[/bold] of {len(rep.names)} "
              f"candidate parameters identifiable (condition number {rep.cond_scaled:.3g}); "
              f"{len(held)} held at their initial values:")
    groups = identifiability_groups(rep, res.problem.names, res.problem.roles)
    for g in groups[:limit]:
        out.print(f"  - {escape(g)}")
    if len(groups) > limit:
        out.print(f"  ... and {len(groups) - limit} more (see the report / JSON).")


def print_selection(out: Console, sel: Any) -> None:
    """The ``--select auto`` table: every candidate's cross-validated RMS, the choice."""
    from kincal.identify.selection import RULE

    name, f, unit = console_quantity(sel.kind) if sel.kind else ("error", 1.0, "")
    t = Table(title=f"Model selection: {sel.folds}-fold cross-validation on the training "
              "files", caption=f"rule: {RULE}")
    for c in ("joint model", "prior", f"CV RMS {name} [{unit}]", "not eligible because"):
        t.add_column(escape(c), justify="right" if c.startswith("CV") else "left",
                     overflow="fold")
    for i, c in enumerate(sel.candidates):
        model = "geometric" + "".join(f" + {x}" for x in c.terms)
        prior = "least squares" if c.scale is None else f"{c.scale:g}x tolerances"
        cells = [escape(model), prior, scaled(sel.rms[i], f), escape(sel.reasons[i])]
        if i == sel.chosen:
            cells = [f"[bold green]{x}[/bold green]" for x in cells[:3]] + ["<- chosen"]
        t.add_row(*cells)
    out.print(t)
    if getattr(sel, "split", ""):
        out.print(escape(sel.split))
    for n in sel.notes:
        out.print(f"[yellow]note[/yellow]: {escape(n)}")


def print_weak(out: Console, weak: Sequence[Any]) -> None:
    """The parameters the prior holds (:func:`kincal.identify.weak.weak_parameters`): a
    table with the data-only standard error, the tolerance and what would identify them."""
    if not weak:
        return
    t = Table(title=f"Held by the prior (weakly identifiable): {len(weak)} parameter(s) the "
              "data alone fix worse than their tolerance")
    for c in ("parameter", "data alone", "prior (1σ)", "what would identify it"):
        t.add_column(c, justify="right" if c in ("data alone", "prior (1σ)") else "left",
                     overflow="fold")

    def show(v: float, unit: str) -> str:
        f, u = console_units().scale(unit)
        return f"{v * f:.3g} {u}" if math.isfinite(v) else "-"

    for w in weak:
        if w.joint is not None and w.joint_range is not None:
            have, full = w.joint_range
            f, u = console_units().scale("rad" if w.joint_kind == "revolute" else "m")
            how = (f"{w.joint} over its range (moves {have * f:.3g} of {full * f:.3g} {u}): "
                   f"{show(w.with_joint or math.nan, w.unit)}")
        elif w.partner is not None:
            how = f"poses that separate it from {w.partner} (correlation {w.correlation:+.2f})"
        else:
            how = "-"
        t.add_row(escape(w.name), show(w.data_std, w.unit), show(w.prior_std, w.unit),
                  escape(how))
    out.print(t)


def print_staged_selection(out: Console, info: Any) -> None:
    """The staged-selection procedure's record (angles, then lengths): data selection,
    cycles, comparison with one-stage LM."""

    d = info.to_dict()
    n_all = len(d["kept"]) + len(d["discarded"])
    if d["condition_growth"] is not None:
        dropped = ", ".join(f"{x['placement']}" for x in d["discarded"]) or "none"
        out.print("staged-selection data selection (condition growth <= "
                  f"{d['condition_growth']:g}): "
                  f"kept [bold]{len(d['kept'])} of {n_all}[/bold] placements; discarded: "
                  f"{escape(dropped)}")
    u = console_units()
    moved = d["cycle_corrections_m"][-1] if d["cycle_corrections_m"] else float("nan")
    out.print(f"staged-selection procedure: {d['cycles']} cycle(s) of {len(d['stages'])} stages, "
              + ("converged" if d["converged"] else "[red]NOT converged[/red]")
              + f" (last cycle moved the points by {u.value(moved, 'm', 4)}; tolerance "
              f"{u.value(d['tolerance_m'], 'm', 4)})")
    comp = d.get("comparison")
    if not comp:
        return
    runs = [("staged selection", comp["staged_selection"]),
            ("one-stage LM, same parameters", comp["one_stage"]),
            ("one-stage LM, automatic", comp["automatic"])]
    keys = sorted({k for _, s in runs for k in s if k.startswith("rms_")})
    t = Table(title="Staged selection vs one-stage Levenberg-Marquardt (same data)")
    t.add_column("solver")
    for c in ("estimated", "sigma0"):
        t.add_column(c, justify="right")
    for k in keys:
        name, _, unit = console_quantity(k[4:])
        t.add_column(f"RMS {name} \\[{unit}]", justify="right")
    for label, s in runs:
        t.add_row(label, str(s["estimated"]), f"{s['sigma0']:.4g}",
                  *(scaled(s.get(k), console_quantity(k[4:])[1]) for k in keys))
    out.print(t)
    same = comp["same_parameters"]
    out.print(f"same parameters: largest difference {same['max_sigmas']:.3g} standard errors"
              + (f" ({escape(same['worst'])})" if same["worst"] else ""))
