"""Five-bar commands (``fivebar-thesis``, ``fivebar-workspace``, ``fivebar-mobility``,
``fivebar-simulate``) and the helpers the generic ``show``/``fk``/``ik``/``calibrate``
commands call when the robot is a :class:`~kincal.parallel.fivebar.FiveBar`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.errors import KincalError

if TYPE_CHECKING:
    import numpy as np

if TYPE_CHECKING:
    from kincal.parallel.calibration import FiveBarCalibration
    from kincal.parallel.fivebar import FiveBar

_METHODS = {
    "gauss-newton": "gauss-newton",
    "gn": "gauss-newton",
    "ils": "gauss-newton",
    "iterative": "gauss-newton",
    "thesis": "gauss-newton",
    "lm": "lm",
    "levenberg-marquardt": "lm",
}


def _console(json_path: str | None) -> Console:
    """Tables go to stdout unless JSON does (``--json -``), then to stderr."""
    return Console(stderr=json_path == "-")


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
def show_fivebar(robot: FiveBar, console: Console) -> None:
    """Print a five-bar's parameters (SI), default modes, limits, mobility and source."""
    t = Table(title=f"{robot.name}: five-bar, {len(robot.param_names)} parameters (SI)")
    for c in ("parameter", "value", "unit"):
        t.add_column(c, justify="right" if c == "value" else "left")
    for name, value, unit in robot.parameter_table():
        shown = f"{value:.9g}" + (f"  ({math.degrees(value):.6g}°)" if unit == "rad" else "")
        t.add_row(name, shown, unit)
    console.print(t)
    console.print(f"default assembly {robot.assembly:+d} (+1: J3 left of J1->J2), "
                  f"working mode {robot.working_mode} (+: elbow left of B_i->J3)")
    if robot.limits is not None:
        lim = ", ".join(f"q{i + 1} in [{a:.6g}, {b:.6g}] rad"
                        for i, (a, b) in enumerate(robot.limits))
        console.print(f"reading limits: {lim}")
    console.print(f"mobility (Kutzbach, planar five-bar): F = {robot.mobility()}")
    if robot.source:
        console.print(f"source: {escape(robot.source)}")


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


def calibrate_fivebar_file(
    robot: FiveBar,
    data_path: str | Path,
    out_path: str | Path | None,
    json_path: str | None,
    report_path: str | Path | None,
    method: str = "gauss-newton",
    free: list[str] | None = None,
    residual: str = "ik",
    frame_free: bool = False,
    console: Console | None = None,
) -> FiveBarCalibration:
    """Calibrate a five-bar from a measurement CSV (joint readings + measured J3).

    Writes the calibrated robot YAML (``out_path``), the result with its
    iteration history as JSON (``json_path``, ``-`` for stdout) and a Markdown
    report (``report_path``); each is optional.  ``free`` defaults to all ten
    robot parameters (plus the measurement frame when ``frame_free``).
    """
    from kincal.parallel.calibration import ROBOT_FREE, calibrate
    from kincal.parallel.data import read_fivebar_csv
    from kincal.parallel.residuals import FRAME_NAMES

    key = method.lower()
    if key not in _METHODS:
        raise KincalError(f"method must be one of {', '.join(_METHODS)}, not {method!r}")
    data = read_fivebar_csv(data_path)
    names = list(free) if free else list(ROBOT_FREE)
    if frame_free:
        names += [n for n in FRAME_NAMES if n not in names]
    labels = [f"{Path(data_path).name} line {n}" for n in data.lines]
    result = calibrate(robot, data.q, data.x, free=names, residual=residual,
                       method=_METHODS[key], labels=labels)
    console = console or _console(json_path)
    _print_result(console, result)
    if out_path:
        from dataclasses import replace

        from kincal.parallel.files import write_fivebar

        write_fivebar(replace(result.robot, name=f"{robot.name}_calibrated",
                source=f"kincal calibration of {robot.name} from {Path(data_path).name}"
                ), out_path)
    if json_path:
        _write_json(json_path, result.to_dict())
    if report_path:
        from kincal.io import atomic_write_text

        atomic_write_text(report_path, result.report())
    return result


def _print_result(console: Console, result: FiveBarCalibration) -> None:
    unit = "rad" if result.residual == "ik" else "m"
    t = Table(title=f"five-bar calibration ({result.residual} residual, {result.method}): "
              f"{result.iterations} iterations, converged {result.converged}, "
              f"rms {result.rms:.3g} {unit}")
    for c in ("parameter", "start", "estimate", "std error"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    start = dict(zip(result.names, result.start.tolist(), strict=True))
    for n in result.free:
        t.add_row(n, f"{start[n]:.9g}", f"{result.params[n]:.12g}", f"{result.std_errors[n]:.3g}")
    console.print(t)
    for line in result.identifiability.describe():
        console.print(f"[yellow]{escape(line)}[/yellow]")


# ----------------------------------------------------------------- commands
@app.command("fivebar-thesis")
def fivebar_thesis(
    n: Annotated[int, typer.Option(help="Number of measured configurations.")] = 50,
    seed: Annotated[int, typer.Option(help="Seed of the numpy Generator.")] = 0,
    method: Annotated[str, typer.Option(help="gauss-newton (the thesis's) or lm.")] = (
        "gauss-newton"
    ),
    residual: Annotated[str, typer.Option(help="ik (joint space, the thesis's) or fk.")] = "ik",
    noise_deg: Annotated[float, typer.Option("--noise-deg", help="Std of joint-reading "
                                             "noise [deg].")] = 0.0,
    out: Annotated[str | None, typer.Option(help="Folder for the four plots "
                                            "fivebar_thesis_l1..l4.png.")] = "fivebar-thesis",
    json_out: Annotated[str | None, typer.Option(
        "--json", help="Write the result with its iteration history as JSON ('-': stdout).")
    ] = None,
) -> None:
    """The thesis's experiment: true lengths [1.86, 2.2, 2.8, 3.3] m from nominal [2, 2, 3, 3] m.

    Bases B1 = (1, 0) m, B2 = (-1, 0) m; J3 from the direct kinematics with beta1 in
    (0, pi/2), beta2 in (pi/2, pi); well-conditioned configurations only; stop at 1e-10.
    """
    from kincal.parallel.thesis import THESIS_TRUE, plot_thesis, run_thesis

    if n < 3:
        raise KincalError("option --n: at least 3 configurations are needed for 4 lengths")
    key = _METHODS.get(method.lower())
    if key is None:
        raise KincalError(f"option --method: one of {', '.join(_METHODS)}, not {method!r}")
    result, true = run_thesis(n=n, seed=seed, method=key, residual=residual,
                              noise=math.radians(noise_deg))
    console = _console(json_out)
    names = list(THESIS_TRUE)
    t = Table(title=f"thesis experiment: {n} configurations, seed {seed}, {key}, {residual} "
              f"residual (B1 = (1, 0) m, B2 = (-1, 0) m)")
    for c in ["iteration", *[f"{k} [m]" for k in names], "max step", "rms residual"]:
        t.add_column(c, justify="right")
    for h in result.history:
        t.add_row(str(h["iteration"]), *[f"{h['params'][k]:.10f}" for k in names],
                  f"{h['step']:.3g}", f"{h['rms']:.3g}")
    t.add_row("true", *[f"{THESIS_TRUE[k]:.10f}" for k in names], "", "")
    console.print(t)
    err = max(abs(result.params[k] - THESIS_TRUE[k]) for k in names)
    console.print(f"converged: {result.converged} after {result.iterations} iterations; "
                  f"largest length error {err:.3g} m")
    if out:
        paths = plot_thesis(result, true, out)
        console.print("plots: " + ", ".join(str(p) for p in paths))
    if json_out:
        data = result.to_dict()
        data["experiment"] = {"true": THESIS_TRUE, "n": n, "seed": seed,
                              "noise_rad": math.radians(noise_deg),
                              "bases_m": {"base1": [true.base1_x, true.base1_y],
                                          "base2": [true.base2_x, true.base2_y]}}
        _write_json(json_out, data)


@app.command("fivebar-workspace")
def fivebar_workspace(
    robot: Annotated[str, typer.Argument(help="Five-bar robot: built-in name or YAML file.")],
    out: Annotated[str, typer.Option(help="Image file to write (PNG, SVG, PDF).")],
    mode: Annotated[str | None, typer.Option(help="Working mode ++, +-, -+, -- "
                                             "(default: the robot's).")] = None,
    assembly: Annotated[int | None, typer.Option(help="Keep only points reached in this "
                                                 "assembly mode (+1 / -1).")] = None,
    margin: Annotated[float, typer.Option(help="Keep only points whose singularity measures "
                                          "are at least this (0..1).")] = 0.0,
    resolution: Annotated[int, typer.Option(help="Grid points per axis.")] = 250,
) -> None:
    """Plot the reachable region of a working mode, with the Type-2 singular curves."""
    from kincal.parallel.workspace import plot_workspace, workspace

    r = _load(robot)
    if mode is not None and mode not in ("++", "+-", "-+", "--"):
        raise KincalError(f"option --mode: one of ++, +-, -+, --, not {mode!r}")
    if assembly not in (None, 1, -1):
        raise KincalError("option --assembly: +1 or -1")
    if resolution < 10:
        raise KincalError("option --resolution: at least 10")
    path = plot_workspace(r, out, mode, resolution, assembly, margin)
    ws = workspace(r, mode, resolution, assembly=assembly, margin=margin)
    Console().print(f"workspace of {r.name}, working mode {ws.mode}: area {ws.area:.6g} m^2 "
                    f"-> {path}")


@app.command("fivebar-mobility")
def fivebar_mobility() -> None:
    """Kutzbach/Grübler mobility of the thesis's dual SCARA (4) and of the planar five-bar (2)."""
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
    Console().print(t)


@app.command("fivebar-simulate")
def fivebar_simulate(
    robot: Annotated[str, typer.Argument(help="Nominal five-bar: built-in name or YAML file.")],
    out: Annotated[str, typer.Option(help="Measurement CSV to write.")],
    set_: Annotated[list[str] | None, typer.Option("--set", help="True parameter, e.g. "
                                                   "l1=1.86 (SI: m, rad); repeatable.")] = None,
    n: Annotated[int, typer.Option(help="Number of configurations.")] = 50,
    seed: Annotated[int, typer.Option(help="Seed of the numpy Generator.")] = 0,
    noise_deg: Annotated[float, typer.Option("--noise-deg", help="Reading noise std [deg].")] = 0.0,
    q1_range: Annotated[str | None, typer.Option(help="min,max of beta1 [deg] (default: the "
                                                 "robot's limits or the full turn).")] = None,
    q2_range: Annotated[str | None, typer.Option(help="min,max of beta2 [deg].")] = None,
) -> None:
    """Simulate a five-bar measurement file (readings in deg, points in mm) from a true robot."""
    import numpy as np

    from kincal.parallel.data import write_fivebar_csv
    from kincal.parallel.thesis import simulate

    nominal = _load(robot)
    changes = {}
    for item in set_ or []:
        name, _, value = item.partition("=")
        try:
            changes[name.strip()] = float(value)
        except ValueError:
            raise KincalError(f"option --set: {item!r} is not name=number") from None
    true = nominal.with_params(changes)
    ranges = []
    for k, text in enumerate((q1_range, q2_range)):
        if text is not None:
            parts = text.split(",")
            try:
                lo, hi = (math.radians(float(v)) for v in parts)
            except ValueError:
                raise KincalError(f"option --q{k + 1}-range: expected min,max in deg") from None
        elif nominal.limits is not None:
            lo, hi = nominal.limits[k]
        else:
            lo, hi = -math.pi, math.pi
        ranges.append((lo, hi))
    q, x = simulate(true, nominal, n, np.random.default_rng(seed), tuple(ranges),
                    noise=math.radians(noise_deg))
    comment = (f"simulated by kincal fivebar-simulate from {nominal.name}, seed {seed}, "
               f"noise {noise_deg} deg\ntrue parameters (SI): "
               + ", ".join(f"{k}={v:.12g}" for k, v, _ in true.parameter_table()))
    write_fivebar_csv(out, q, x, comment=comment)
    Console().print(f"{q.shape[0]} measurements -> {out}")
