"""Five-bar commands (``fivebar-demo``, ``fivebar-workspace``, ``fivebar-mobility``,
``fivebar-simulate``) and the helpers the generic ``show``/``fk``/``ik``/``calibrate``
commands call when the robot is a :class:`~kincal.parallel.fivebar.FiveBar`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.common import KincalConsole
from kincal.cli.options import OutputOpt, SeedOpt, Units, quantity
from kincal.errors import KincalError

if TYPE_CHECKING:
    import numpy as np

    from kincal.parallel.calibration import FiveBarCalibration
    from kincal.parallel.fivebar import FiveBar

def _console(json_path: str | None) -> Console:
    """Tables go to stdout unless JSON does (``--json -``), then to stderr."""
    return KincalConsole(stderr=json_path == "-")


def _load(spec: str) -> FiveBar:
    from kincal.parallel.fivebar import FiveBar
    from kincal.workflow.robots import load_any_robot

    robot = load_any_robot(spec)
    if not isinstance(robot, FiveBar):
        raise KincalError(f"robot {spec!r} is not a five-bar (kind: fivebar)")
    return robot


def _write_json(path: str, data: Any) -> None:
    from kincal.io import write_json

    write_json(path, data)


def _config_json(robot: FiveBar, q: np.ndarray, x: np.ndarray) -> dict[str, Any]:
    import numpy as np
    sigma, mode = robot.configuration_signs(q, x)
    meas = robot.singularity_measures(q, x)
    j1, j2 = robot.elbows(q)
    return {
        "q": np.asarray(q).tolist(),
        "x": np.asarray(x).tolist(),
        "assembly": int(sigma),
        "working_mode": str(mode),
        "passive": robot.passive_angles(q, x).tolist(),
        "elbows": {"J1": j1.tolist(), "J2": j2.tolist()},
        "singularity": {"type1": meas["type1"].tolist(), "type2": float(meas["type2"])},
        "units": {"q": "rad", "x": "m", "passive": "rad", "elbows": "m"},
    }


def _print_config(console: Console, title: str, c: dict[str, Any]) -> None:
    t = Table(title=title)
    t.add_column("quantity")
    t.add_column("value", justify="right")
    q, x, b = c["q"], c["x"], c["passive"]
    t.add_row("readings q1, q2", f"{q[0]:.9f}, {q[1]:.9f} rad  "
              f"({math.degrees(q[0]):.6f}°, {math.degrees(q[1]):.6f}°)")
    t.add_row("end point J3 x, y", f"{x[0]:.9f}, {x[1]:.9f} m")
    t.add_row("passive beta3, beta4 (absolute)", f"{b[0]:.9f}, {b[1]:.9f} rad")
    t.add_row("elbow J1", ", ".join(f"{v:.6f}" for v in c["elbows"]["J1"]) + " m")
    t.add_row("elbow J2", ", ".join(f"{v:.6f}" for v in c["elbows"]["J2"]) + " m")
    t.add_row("assembly / working mode", f"{c['assembly']:+d} / {c['working_mode']}")
    s = c["singularity"]
    t.add_row("Type-1 measure (arms)", f"{s['type1'][0]:.4f}, {s['type1'][1]:.4f}")
    t.add_row("Type-2 measure", f"{s['type2']:.4f}")
    console.print(t)


# ----------------------------------------------------------------- helpers for the lead
def show_fivebar(robot: FiveBar, console: Console, units: Units | None = None,
                 json_out: str | None = None) -> None:
    """Print a five-bar's parameters (mm and degrees; SI with ``--si``), default modes,
    limits, mobility and source; ``json_out`` also writes them (SI)."""
    units = units or Units()
    t = Table(title=f"{robot.name}: five-bar, {len(robot.param_names)} parameters")
    for c in ("parameter", "value", "unit"):
        t.add_column(c, justify="right" if c == "value" else "left")
    for name, value, unit in robot.parameter_table():
        f, u = units.scale(unit)
        t.add_row(name, f"{value * f:.{4 if not units.si else 9}f}", u)
    if json_out != "-":
        console.print(t)
        console.print(f"default assembly {robot.assembly:+d} (+1: J3 left of J1->J2), "
                      f"working mode {robot.working_mode} (+: elbow left of B_i->J3)")
        if robot.limits is not None:
            lim = ", ".join(f"q{i + 1} in [{units.value(a, 'rad', 2)}, {units.value(b, 'rad', 2)}]"
                            for i, (a, b) in enumerate(robot.limits))
            console.print(f"reading limits: {lim}")
        console.print(f"mobility (Kutzbach, planar five-bar): F = {robot.mobility()}")
        if robot.source:
            console.print(f"source: {escape(robot.source)}")
    if json_out:
        _write_json(json_out, {"name": robot.name, "kind": "fivebar", "parameters": [
            {"name": n, "value": float(v), "unit": u} for n, v, u in robot.parameter_table()],
            "assembly": robot.assembly, "working_mode": robot.working_mode,
            "limits": None if robot.limits is None else [list(x) for x in robot.limits],
            "mobility": robot.mobility(), "units": {"length": "m", "angle": "rad"}})


def fk_fivebar(robot: FiveBar, q: np.ndarray, json_path: str | None) -> None:
    """Direct kinematics of one reading pair q [rad] (default assembly); print and/or JSON."""
    import numpy as np

    q = np.asarray(q, dtype=float)
    if q.shape != (2,):
        raise KincalError(f"option --q: a five-bar needs 2 readings, got {q.size}")
    x = robot.fk(q)
    c = _config_json(robot, q, x)
    other = robot.fk(q, assembly=-robot.assembly)
    c["other_assembly_x"] = other.tolist()
    if json_path != "-":
        console = _console(json_path)
        _print_config(console, f"{robot.name}: direct kinematics", c)
        console.print(f"other assembly ({-robot.assembly:+d}): J3 = "
                      f"{other[0]:.9f}, {other[1]:.9f} m")
    if json_path:
        _write_json(json_path, c)


def ik_fivebar(
    robot: FiveBar, position: np.ndarray, mode: str | None, json_path: str | None
) -> None:
    """Inverse kinematics of J3 = position [m] in a working mode (``all``: the four)."""
    import numpy as np

    x = np.asarray(position, dtype=float)
    if x.shape != (2,):
        raise KincalError(f"option --position: a five-bar needs x,y, got {x.size} values")
    modes = ["++", "+-", "-+", "--"] if mode == "all" else [mode or robot.working_mode]
    results = {}
    for m in modes:  # at most four modes; each call is batched
        q = robot.ik(x, m)
        results[m] = _config_json(robot, q, x)
    if json_path != "-":
        console = _console(json_path)
        for m, c in results.items():
            _print_config(console, f"{robot.name}: inverse kinematics, working mode {m}", c)
    if json_path:
        _write_json(json_path, results if mode == "all" else results[modes[0]])


#: Options of ``kincal calibrate`` a five-bar calibration takes (the rest are refused).
FIVEBAR_CALIBRATE_OPTIONS = ("robot", "data", "output", "validate_files", "report", "json_out",
                             "method", "free", "fix", "max_iter", "all_parameters", "force",
                             "truth", "si")


def _flag(ctx: typer.Context, name: str) -> str:
    """The long spelling of parameter ``name`` of the running command (``--validate``)."""
    for p in ctx.command.params:
        if p.name == name:
            longs = [o for o in p.opts if o.startswith("--")]
            return (longs or list(p.opts) or [name])[0]
    return name


def refuse_unused_options(ctx: typer.Context, used: tuple[str, ...], what: str) -> None:
    """One-line error (exit 2) naming the first option given that ``what`` cannot use."""
    for p in ctx.command.params:
        if p.name is None or p.name in used:
            continue
        source = getattr(ctx.get_parameter_source(p.name), "name", "DEFAULT")
        if source not in ("DEFAULT", "DEFAULT_MAP"):  # typer's click or click: by name
            usable = ", ".join(_flag(ctx, n) for n in used if n != "robot")
            raise KincalError(f"option {_flag(ctx, p.name)} does not apply to {what} "
                              f"(it takes {usable})")


def _names(text: str | None) -> list[str] | None:
    return [t.strip() for t in text.split(",") if t.strip()] if text else None


def calibrate_fivebar_command(ctx: typer.Context, robot: FiveBar) -> None:
    """``kincal calibrate FIVEBAR``: refuse the options a five-bar cannot use, calibrate
    (:func:`kincal.parallel.file_calibration.calibrate_fivebar_file`), print the tables,
    write the outputs; exit status 1 when the result cannot be trusted."""
    from kincal.defaults import FIVEBAR_MAX_ITER
    from kincal.errors import CheckFailedError
    from kincal.io import check_outputs
    from kincal.parallel.file_calibration import (
        calibrate_fivebar_file,
        fivebar_method,
        select_fivebar_parameters,
        write_fivebar_outputs,
    )

    refuse_unused_options(ctx, FIVEBAR_CALIBRATE_OPTIONS, "a five-bar")
    opt = ctx.params
    data = list(opt.get("data") or [])
    if len(data) != 1:
        raise KincalError("five-bar calibration takes one --data file")
    held = list(opt.get("validate_files") or [])
    output, json_out, report = opt.get("output"), opt.get("json_out"), opt.get("report")
    truth = _load(opt["truth"]) if opt.get("truth") else None
    check_outputs({"-o": output, "--json": json_out, "--report": report},
                  {"--data": data, "--validate": held})
    free = select_fivebar_parameters(_names(opt.get("free")), _names(opt.get("fix")),
                                     where=("option --free", "option --fix"))
    result = calibrate_fivebar_file(
        robot, data[0], validate=held, free=free,
        method=fivebar_method(opt["method"], "option --method"),
        max_iter=opt.get("max_iter") or FIVEBAR_MAX_ITER)
    console = _console(json_out)
    _print_result(console, result.calibration, list(result.comparisons),
                  bool(opt.get("all_parameters")))
    force = bool(opt.get("force"))
    written = write_fivebar_outputs(result, output, json_out, report, force, truth)
    if not result.trusted:
        tail = ("; written anyway (--force)" if force and output else
                f"; no calibrated robot written ({output}; --force writes it)"
                if output and "calibrated robot" not in written else "")
        raise CheckFailedError(result.verdict.line() + tail)


def _print_result(console: Console, result: FiveBarCalibration,
                  comparisons: list[Any] | None = None, all_parameters: bool = False) -> None:
    """Like every serial robot: parameters in mm / deg with standard errors, the
    before/after table of the end-point error, what is not identifiable."""
    from kincal.cli.calibration_common import print_errors, scaled
    from kincal.cli.options import CONSOLE
    from kincal.parallel.residuals import ALL_NAMES, ALL_UNITS

    units = dict(zip(ALL_NAMES, ALL_UNITS, strict=True))
    conv = "[green]converged[/green]" if result.converged else "[red]did not converge[/red]"
    console.print(f"five-bar calibration ({result.residual} residual, {result.method}): "
                  f"{conv} in {result.iterations} iterations, {len(result.free)} parameters "
                  "estimated")
    t = Table(title=f"Estimated parameters ({CONSOLE.length_unit}, {CONSOLE.angle_unit})")
    for c in ("parameter", "nominal", "estimate", "change", "std (1σ)"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    start = dict(zip(result.names, result.start.tolist(), strict=True))
    for n in result.names if all_parameters else result.free:
        f, _ = CONSOLE.scale(units[n])
        t.add_row(escape(n), scaled(start[n], f), scaled(result.params[n], f),
                  scaled(result.params[n] - start[n], f), scaled(result.std_errors.get(n), f))
    console.print(t)
    if comparisons:
        print_errors(console, comparisons)
    for line in result.identifiability.describe():
        console.print(f"[yellow]{escape(line)}[/yellow]")


# ----------------------------------------------------------------- commands
@app.command("fivebar-demo")
def fivebar_demo(
    n: Annotated[int, typer.Option("-n", "--configurations", help="Number of measured "
                                   "configurations.")] = 50,
    seed: SeedOpt = 0,
    method: Annotated[str, typer.Option(help="gauss-newton (iterative linearised least "
                                        "squares) or lm.")] = "gauss-newton",
    residual: Annotated[str, typer.Option(help="ik (joint-space residuals) or fk "
                                          "(end-point residuals).")] = "ik",
    noise: Annotated[str | None, typer.Option(
        "--noise", metavar="ANGLE", help="Joint-reading noise (standard deviation) with its "
        "unit, e.g. 0.01deg (default: none).")] = None,
    out_dir: Annotated[str | None, typer.Option(
        "--out-dir", help="Folder for the four plots of the lengths against the iteration "
        "(fivebar_demo_l1..l4.png).")] = "fivebar-demo",
    json_out: Annotated[str | None, typer.Option(
        "--json", help="Write the result with its iteration history as JSON ('-': stdout).")
    ] = None,
) -> None:
    """A simulated five-bar calibration: from nominal lengths [2, 2, 3, 3] m the true
    [1.86, 2.2, 2.8, 3.3] m are recovered from joint readings at measured end points.

    Bases B1 = (1, 0) m, B2 = (-1, 0) m; the end point from the direct kinematics with
    beta1 in (0, pi/2), beta2 in (pi/2, pi); well-conditioned configurations only; stop
    at 1e-10 m.  (The experiment of Pittr's dual SCARA thesis.)  Exit status 1 when the
    result cannot be trusted (a length more than 0.5 m from nominal, a standard error
    above 1 m, no convergence).
    """
    from kincal.errors import CheckFailedError
    from kincal.parallel.file_calibration import fivebar_method
    from kincal.parallel.reference_experiment import (
        EXPERIMENT_TRUE_LENGTHS,
        plot_reference_experiment,
        reference_experiment,
    )

    noise_rad = quantity(noise, "angle", "--noise", minimum=0.0) or 0.0
    if n < 3:
        raise KincalError("option -n: at least 3 configurations are needed for 4 lengths")
    key = fivebar_method(method, "option --method")
    run = reference_experiment(n=n, seed=seed, method=key, residual=residual, noise=noise_rad)
    result = run.calibration
    console = _console(json_out)
    names = list(EXPERIMENT_TRUE_LENGTHS)
    t = Table(title=f"five-bar calibration: {n} configurations, seed {seed}, {key}, "
              f"{residual} residual (B1 = (1, 0) m, B2 = (-1, 0) m; lengths in mm, step and "
              "residual in SI)")
    for c in ["iteration", *names, "max step", "rms residual"]:
        t.add_column(c, justify="right")
    for h in result.history:
        t.add_row(str(h["iteration"]), *[f"{h['params'][k] * 1e3:.3f}" for k in names],
                  f"{h['step']:.3g}", f"{h['rms']:.3g}")
    t.add_row("true", *[f"{EXPERIMENT_TRUE_LENGTHS[k] * 1e3:.3f}" for k in names], "", "")
    console.print(t)
    console.print(f"converged: {result.converged} after {result.iterations} iterations; "
                  f"largest length error {run.largest_length_error * 1e3:.3g} mm")
    if out_dir:
        paths = plot_reference_experiment(result, run.true, out_dir)
        console.print("plots: " + ", ".join(str(p) for p in paths))
    if json_out:
        _write_json(json_out, run.to_dict())
    if not run.verdict.trusted:
        raise CheckFailedError(run.verdict.line())


@app.command("fivebar-workspace")
def fivebar_workspace(
    robot: Annotated[str, typer.Argument(help="Five-bar robot: built-in name or YAML file.")],
    output: Annotated[str | None, typer.Option("-o", "--output", help="Image file to write "
                                               "(PNG, SVG, PDF).")] = None,
    mode: Annotated[str | None, typer.Option(help="Working mode ++, +-, -+, -- "
                                             "(default: the robot's).")] = None,
    assembly: Annotated[int | None, typer.Option(help="Keep only points reached in this "
                                                 "assembly mode (+1 / -1).")] = None,
    margin: Annotated[float, typer.Option(help="Keep only points whose singularity measures "
                                          "are at least this (0..1).")] = 0.0,
    resolution: Annotated[int, typer.Option(help="Grid points per axis.")] = 250,
    json_out: Annotated[str | None, typer.Option("--json", help="Also write the area and the "
                                                 "mode as JSON ('-' for stdout).")] = None,
) -> None:
    """Plot the reachable region of a working mode, with the Type-2 singular curves."""
    from kincal.parallel.workspace import plot_workspace, workspace

    if output is None:
        raise KincalError("`kincal fivebar-workspace` needs -o FILE.png")
    r = _load(robot)
    if mode is not None and mode not in ("++", "+-", "-+", "--"):
        raise KincalError(f"option --mode: one of ++, +-, -+, --, not {mode!r}")
    if assembly not in (None, 1, -1):
        raise KincalError("option --assembly: +1 or -1")
    if resolution < 10:
        raise KincalError("option --resolution: at least 10")
    path = plot_workspace(r, output, mode, resolution, assembly, margin)
    ws = workspace(r, mode, resolution, assembly=assembly, margin=margin)
    if json_out != "-":
        KincalConsole().print(f"workspace of {r.name}, working mode {ws.mode}: area {ws.area:.6g} "
                               f"m² -> {path}")
    if json_out:
        _write_json(json_out, ws.to_dict(r.name, str(path)))


@app.command("fivebar-mobility")
def fivebar_mobility() -> None:
    """Kutzbach/Grübler mobility of the dual SCARA (4) and of the planar five-bar (2)."""
    from kincal.parallel.mobility import dual_scara_thesis, planar_five_bar

    t = Table(title="mobility F = lam (n - j - 1) + sum f_i  (Grübler: sum f_i - lam L)")
    for c in ("mechanism", "lam", "links n", "joints j", "sum f_i", "loops L", "Kutzbach",
              "Grübler"):
        t.add_column(c, justify="left" if c == "mechanism" else "right")
    for label, m in (("dual SCARA (Pittr 2012, 3.1)", dual_scara_thesis()),
                     ("planar five-bar", planar_five_bar())):
        t.add_row(label, str(m.dimension), str(len(m.links)), str(len(m.joints)),
                  str(sum(j.freedom for j in m.joints)), str(m.loops()), str(m.kutzbach()),
                  str(m.grubler()))
    KincalConsole().print(t)


@app.command("fivebar-simulate")
def fivebar_simulate(
    robot: Annotated[str, typer.Argument(help="Nominal five-bar: built-in name or YAML file.")],
    output: OutputOpt = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="True parameter with its "
                                                   "unit, e.g. l1=1.86m; repeatable.")] = None,
    n: Annotated[int, typer.Option("-n", "--configurations", help="Number of "
                                   "configurations.")] = 50,
    seed: SeedOpt = 0,
    noise: Annotated[str | None, typer.Option("--noise", metavar="ANGLE", help="Reading noise "
                                              "(standard deviation) with its unit, e.g. "
                                              "0.01deg.")] = None,
    q1_range: Annotated[str | None, typer.Option(help="min,max of beta1 with units, e.g. "
                                                 "0,90deg (default: the robot's limits or the "
                                                 "full turn).")] = None,
    q2_range: Annotated[str | None, typer.Option(help="min,max of beta2, e.g. 90,180deg.")
                        ] = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Also write what was "
                                                 "simulated as JSON ('-' for stdout).")
                        ] = None,
) -> None:
    """Simulate a five-bar measurement file (readings in deg, points in mm) from a true robot."""
    from kincal.parallel.data import write_fivebar_csv
    from kincal.parallel.reference_experiment import simulate_fivebar
    from kincal.units import parse_quantities

    if output is None:
        raise KincalError("`kincal fivebar-simulate` needs -o FILE.csv")
    noise_rad = quantity(noise, "angle", "--noise", minimum=0.0) or 0.0
    nominal = _load(robot)
    changes = {}
    for item in set_ or []:
        name, eq, value = item.partition("=")
        if not eq:
            raise KincalError(f"option --set: {item!r} is not NAME=VALUE (e.g. l1=1.86m)")
        changes[name.strip()] = float(quantity(value, ("length", "angle"), "--set") or 0.0) \
            if any(c.isalpha() for c in value) else _bare_si(value, "--set")
    nominal.with_params(changes)                    # unknown names: one line, before drawing
    ranges = []
    for k, text in enumerate((q1_range, q2_range)):
        if text is not None:
            lo, hi = parse_quantities(text, "angle", f"--q{k + 1}-range", count=2, bare="deg")
        elif nominal.limits is not None:
            lo, hi = nominal.limits[k]
        else:
            lo, hi = -math.pi, math.pi
        ranges.append((lo, hi))
    sim = simulate_fivebar(nominal, changes, n, seed, ranges, noise_rad)
    write_fivebar_csv(output, sim.q, sim.x, comment=sim.comment())
    if json_out != "-":
        KincalConsole().print(f"{sim.q.shape[0]} measurements -> {output}")
    if json_out:
        _write_json(json_out, sim.to_dict(output))


def _bare_si(text: str, option: str) -> float:
    """A bare number in SI (m, rad), the old spelling of ``--set``."""
    try:
        return float(text)
    except ValueError:
        raise KincalError(f"option {option}: {text!r} is not a number with its unit") \
            from None
