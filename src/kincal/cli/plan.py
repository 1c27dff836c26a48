"""``kincal plan``: choose calibration poses and predict the accuracy before measuring.

The command builds a candidate set (random configurations within the joint limits,
a CSV of configurations, or the configurations the instrument's simulator can
measure), the design Jacobian of the instrument over the identifiable base set,
selects ``--poses`` of them by an observability criterion
(:mod:`kincal.identify.design`), compares the design with random poses from the
same candidates, predicts the parameter uncertainty and the position error after
calibration over a workspace grid (:mod:`kincal.identify.prediction`), and writes
the poses as a CSV (``{joint}_{unit}`` columns, e.g. ``q1_rad``) that the
measurement-file reader reads back, plus an optional HTML report and JSON.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.camera_plan import (
    BoardOpt,
    BoardPoseOpt,
    CameraOpt,
    CameraPoseOpt,
    CenterOpt,
    DistanceOpt,
    FreeOpt,
    ImageSizeOpt,
    IntrinsicsOpt,
    MaxTiltOpt,
    PixelNoiseOpt,
    SpreadOpt,
)
from kincal.cli.common import (
    RobotArg,
    console,
    err_console,
    point_vector,
    robot_arg,
)
from kincal.cli.options import SeedOpt, SiOpt, console_units, quantity, use_si
from kincal.errors import KincalError

if TYPE_CHECKING:
    from kincal.identify.plan import Plan

#: Random designs in the baseline column (kincal.identify.plan.RANDOM_DESIGNS, not
#: imported here so that `kincal --help` stays free of NumPy).
RANDOM_DESIGNS = 20

__all__ = ["plan", "render_plan_html"]

_MEANING = {
    "O1": "(s1...sL)^(1/L)/sqrt(m), Borm & Menq: D-optimality",
    "O2": "sL/s1, Driels & Pathre: inverse condition number",
    "O3": "sL, Nahvi et al.: minimum singular value",
    "O4": "sL^2/s1, Nahvi & Hollerbach: noise amplification",
    "O5": "1/(1/s1+...+1/sL), Sun & Hollerbach",
    "kappa": "s1/sL: condition number (smaller is better)",
}

_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;
color:#222}h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.88em;margin:.6em 0}th,td{border:1px solid #ddd;
padding:3px 8px;text-align:right}th{background:#f3f3f3}td.l,th.l{text-align:left}
img{max-width:100%}.small{font-size:.85em;color:#555}"""


def _criterion(text: str) -> str:
    from kincal.identify.observability import CRITERIA

    key = text.strip()
    key = "kappa" if key.lower() == "kappa" else key.upper()
    if key not in CRITERIA:
        raise KincalError(f"option --criterion: unknown criterion {text!r}; use one of "
                          f"{', '.join(CRITERIA)}")
    return key


def _seconds(text: str, option: str) -> float:
    """A duration with its unit (``2s``, ``500ms``) in seconds."""
    t = text.strip()
    for unit, f in (("ms", 1e-3), ("s", 1.0)):
        if t.endswith(unit):
            try:
                v = float(t[: -len(unit)])
            except ValueError:
                break
            if v >= 0:
                return v * f
    raise KincalError(f"option {option}: {text!r} is not a duration with its unit (2s, 500ms)")


# --------------------------------------------------------------------------- output
def _fmt_std(value: float, unit: str) -> str:
    """A standard deviation in the console's units (mm and deg; m and rad with --si)."""
    from kincal.cli.options import CONSOLE

    f, u = CONSOLE.scale(unit)
    return f"{value * f:.4g} {u}"


def _indices_table(plan: Plan) -> Table:
    import numpy as np

    from kincal.identify.observability import INDICES

    t = Table(title=f"Observability indices ({plan.problem.scaling} scaling): design vs "
                    f"median of {RANDOM_DESIGNS} random designs")
    for c in ("index", "design", "random", "definition"):
        t.add_column(c, justify="left" if c in ("index", "definition") else "right")
    ind = plan.design.indices.as_dict()
    for k in INDICES:
        med = float(np.median([r[k] for r in plan.random_indices]))
        mark = " *" if k == plan.design.criterion else ""
        t.add_row(k + mark, f"{ind[k]:.4g}", f"{med:.4g}", _MEANING[k])
    return t


def _accuracy_table(plan: Plan) -> Table:
    from kincal.cli.options import CONSOLE

    p, r = plan.prediction, plan.random_prediction
    f, u = CONSOLE.scale("m")
    t = Table(title=f"Predicted position error after calibration over {len(p.q_eval)} "
                    f"grid configurations \\[{u}] (noise {p.noise * f:g} {u})")
    for c in ("poses", "RMS", "95 %", "max"):
        t.add_column(c, justify="left" if c == "poses" else "right")
    t.add_row(f"{plan.design.criterion} design", f"{p.rms * f:.4g}", f"{p.p95 * f:.4g}",
              f"{p.max * f:.4g}")
    t.add_row("random (median)", f"{r.rms * f:.4g}", f"{r.p95 * f:.4g}", f"{r.max * f:.4g}")
    return t


def _param_table(plan: Plan) -> Table:
    p = plan.prediction
    t = Table(title=f"Predicted standard deviation of the {len(p.names)} estimated "
                    "parameters")
    t.add_column("parameter")
    t.add_column("std", justify="right")
    for n, u, s in zip(p.names, p.units, p.std, strict=True):
        t.add_row(n, _fmt_std(float(s), u))
    return t


def render_plan_html(plan: Plan) -> str:
    """A self-contained HTML page: inputs, indices, prediction, figure, the poses."""
    import numpy as np

    from kincal.identify.observability import INDICES
    from kincal.identify.prediction import prediction_figure

    p, d = plan.prediction, plan.design
    esc = html.escape
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>kincal plan: "
             f"{esc(plan.inputs.get('robot', ''))}</title><style>{_CSS}</style></head><body>",
             f"<h1>Calibration plan for {esc(plan.inputs.get('robot', ''))}</h1><table>"]
    parts += [f'<tr><th class="l">{esc(k)}</th><td class="l">{esc(v)}</td></tr>'
              for k, v in plan.inputs.items()]
    parts.append("</table><h2>Observability indices</h2><table><tr><th>index</th><th>design"
                 f"</th><th>random (median of {RANDOM_DESIGNS})</th><th class='l'>definition"
                 "</th></tr>")
    ind = d.indices.as_dict()
    for k in INDICES:
        med = float(np.median([r[k] for r in plan.random_indices]))
        parts.append(f"<tr><td class='l'>{k}</td><td>{ind[k]:.4g}</td><td>{med:.4g}</td>"
                     f"<td class='l'>{esc(_MEANING[k])}</td></tr>")
    parts.append("</table><h2>Predicted accuracy after calibration</h2>"
                 f"<p>Expected RMS position error over the grid: <b>{p.rms * 1e3:.4g} mm</b> "
                 f"(95 %: {p.p95 * 1e3:.4g} mm, max {p.max * 1e3:.4g} mm); random poses: "
                 f"{plan.random_prediction.rms * 1e3:.4g} mm. Noise {p.noise * 1e3:g} mm per "
                 "coordinate; linearised least squares at the nominal parameters "
                 "(Cramér-Rao bound).</p>")
    png = prediction_figure(p, plan.random_prediction,
                            [d.indices.singular_values, plan.random_singular_values],
                            labels=(f"{d.criterion} design", "random"))
    parts.append('<img alt="prediction" src="data:image/png;base64,'
                 + base64.b64encode(png).decode("ascii") + '">')
    parts.append("<h2>Estimated parameters</h2><table><tr><th class='l'>parameter</th>"
                 "<th>predicted std</th></tr>")
    parts += [f"<tr><td class='l'>{esc(n)}</td><td>{_fmt_std(float(s), u)}</td></tr>"
              for n, u, s in zip(p.names, p.units, p.std, strict=True)]
    held = plan.problem.report.not_identifiable
    parts.append("</table>" + (f"<p class='small'>Not identifiable from these candidates "
                               f"(held at nominal): {esc(', '.join(held))}</p>" if held else ""))
    robot = plan.problem.robot
    parts.append("<h2>Poses (deg / mm)</h2><table><tr><th>#</th>" + "".join(
        f"<th>{esc(j.name)}</th>" for j in robot.joints) + "</tr>")
    rev = np.array([j.kind == "revolute" for j in robot.joints])
    for i, q in enumerate(d.q, start=1):
        v = np.where(rev, np.degrees(q), q * 1e3)
        parts.append(f"<tr><td>{i}</td>" + "".join(f"<td>{x:.3f}</td>" for x in v) + "</tr>")
    now = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    parts.append(f"</table><p class='small'>kincal plan, {now}.</p></body></html>")
    return "\n".join(parts)


class _Bar:
    """A rich progress bar fed by ``progress(phase, done, total)``."""

    def __init__(self) -> None:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                                 TextColumn("{task.completed}/{task.total}"),
                                 TimeElapsedColumn(), console=err_console, transient=True,
                                 disable=not err_console.is_terminal)
        self.task: Any = None
        self.phase: str | None = None

    def __enter__(self) -> _Bar:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.__exit__(*exc)

    def __call__(self, phase: str, done: int, total: int) -> None:
        if phase != self.phase:
            if self.task is not None:
                self.progress.update(self.task, visible=False)
            self.phase = phase
            self.task = self.progress.add_task(phase, total=total)
        self.progress.update(self.task, completed=done, total=total)


@app.command()
def plan(
    robot: RobotArg,
    output: Annotated[str, typer.Option("-o", "--output", help="CSV of the selected poses "
                                        "(columns named as the robot's joints with units, "
                                        "e.g. q1_rad).")],
    instrument: Annotated[str, typer.Option("--instrument", "-i", help="Instrument that will "
                                            "measure: position (laser tracker), pose, or any "
                                            "of `kincal instruments` with --reachable.")
                          ] = "position",
    poses: Annotated[int, typer.Option("--poses", "-n", min=1, help="Number of poses to "
                                       "select.")] = 30,
    criterion: Annotated[str, typer.Option("--criterion", "-c", help="O1 (D-optimal, DETMAX), "
                                           "O2, O3, O4, O5 (exchange) or kappa (greedy "
                                           "condition number, the cross-bar procedure's).")] = "O1",
    candidates: Annotated[int, typer.Option("--candidates", min=1, help="Number of random "
                                            "candidate configurations.")] = 2000,
    candidates_file: Annotated[str | None, typer.Option("--candidates-file", help="CSV of "
                                                        "candidate configurations (joint "
                                                        "columns with units) instead of "
                                                        "random ones.")] = None,
    reachable: Annotated[bool, typer.Option("--reachable", help="Candidates from the "
                                            "instrument's simulator (configurations it can "
                                            "measure).")] = False,
    noise: Annotated[str, typer.Option("--noise", help="Instrument noise per coordinate, "
                                       "with its unit.")] = "0.01mm",
    orientation_noise: Annotated[str, typer.Option(
        "--orientation-noise", help="Pose instrument: rotation noise per axis, with its "
        "unit.")] = "0.005deg",
    marker: Annotated[str | None, typer.Option("--marker", help="Marker (or target origin) in "
                                               "the tool frame, x,y,z with its unit; default "
                                               "20,10,50mm.")] = None,
    scaling: Annotated[str, typer.Option("--scaling", help="workspace (default), unit or "
                                         "errors: the Jacobian scaling of the indices.")
                       ] = "workspace",
    min_distance: Annotated[str, typer.Option("--min-distance", help="Minimum joint-space "
                                              "distance between poses, with its unit.")
                            ] = "0deg",
    margin: Annotated[float, typer.Option("--margin", min=0.0, max=0.45, help="Fraction of "
                                          "each joint range kept away from the limits.")
                      ] = 0.05,
    grid: Annotated[int, typer.Option("--grid", min=1, max=12, help="Values per joint of the "
                                      "evaluation grid.")] = 3,
    no_exchange: Annotated[bool, typer.Option("--no-exchange", help="Greedy selection only "
                                              "(no DETMAX / exchange).")] = False,
    seed: SeedOpt = 0,
    program: Annotated[str | None, typer.Option("--program", help="Write the poses as a "
                                                "joint-move program to run on the robot: krl, "
                                                "rapid, urscript or fanuc-ls. -o is then the "
                                                "program; the pose CSV goes beside it "
                                                "(.csv).")] = None,
    dwell: Annotated[str, typer.Option("--dwell", help="With --program: standstill at each "
                                       "pose for the measurement, e.g. 2s.")] = "2s",
    iso9283: Annotated[bool, typer.Option("--iso9283", help="Lay out the ISO 9283 test cube "
                                          "instead: positions P1-P5 on its diagonal plane, "
                                          "visited P1 P5 P4 P3 P2 for --cycles cycles.")] = False,
    cube_center: Annotated[str | None, typer.Option("--cube-center", help="ISO 9283 cube "
                                                    "centre, e.g. 500,0,600mm (default: the "
                                                    "tool at mid-range joints).")] = None,
    cube_size: Annotated[str | None, typer.Option("--cube-size", help="ISO 9283 cube edge, "
                                                  "e.g. 400mm (default: a quarter of the "
                                                  "reach).")] = None,
    cycles: Annotated[int, typer.Option("--cycles", min=2, help="ISO 9283 cycles (the "
                                        "standard: 30).")] = 30,
    report: Annotated[str | None, typer.Option("--report", help="Write an HTML report here.")
                      ] = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Also write the plan as JSON "
                                                 "('-' for stdout).")] = None,
    angle_unit: Annotated[str, typer.Option("--angle-unit", help="Angle unit of the CSV: rad, "
                                            "deg.")] = "rad",
    length_unit: Annotated[str, typer.Option("--length-unit", help="Length unit of the CSV "
                                             "(prismatic joints): m, mm.")] = "m",
    units: Annotated[str | None, typer.Option("--units", help="Units of candidate-file "
                                              "columns without one, e.g. 'q1=deg'.")] = None,
    ignore: Annotated[list[str] | None, typer.Option("--ignore", help="Candidate-file columns "
                                                     "to drop.")] = None,
    base_link: Annotated[str | None, typer.Option("--base-link", help="URDF only: first link.")
                         ] = None,
    tip_link: Annotated[str | None, typer.Option("--tip-link", help="URDF only: last link.")
                        ] = None,
    si: SiOpt = False,
    camera: CameraOpt = None, board: BoardOpt = None, intrinsics: IntrinsicsOpt = None,
    image_size: ImageSizeOpt = None, free: FreeOpt = None, camera_pose: CameraPoseOpt = None,
    board_pose: BoardPoseOpt = None, center: CenterOpt = None, spread: SpreadOpt = "30deg",
    max_tilt: MaxTiltOpt = "45deg", board_distance: DistanceOpt = None,
    pixel_noise: PixelNoiseOpt = "0.5px",
) -> None:
    """Choose calibration poses by an observability criterion (O1-O5, kappa) and predict the
    accuracy after calibration before measuring anything.

    \f
    Why this is long: one parameter per command-line option (the tracker's, the ISO 9283
    cube's and the camera's); the cube and the camera plans branch off at once."""
    if camera is not None:
        from kincal.cli.camera_plan import camera_plan

        extra = [o for o, v in (("--iso9283", iso9283), ("--program", program), ("--report",
                 report), ("--candidates-file", candidates_file), ("--reachable", reachable))
                 if v]
        if extra:
            raise KincalError(f"option {extra[0]}: not with --camera")
        _check_units(angle_unit, length_unit)
        camera_plan(err_console if json_out == "-" else console,
                    robot_arg(robot, base_link, tip_link), output, camera, board, intrinsics,
                    image_size, poses, free, camera_pose, board_pose, center, spread, max_tilt,
                    board_distance, pixel_noise, candidates, _criterion(criterion), seed,
                    angle_unit, json_out)
        return
    if iso9283:
        _iso_plan(robot, output, cube_center, cube_size, cycles, program, dwell, angle_unit,
                  length_unit, base_link, tip_link, json_out, use_si(si))
        return
    crit = _criterion(criterion)
    _check_units(angle_unit, length_unit)
    use_si(si)
    sd = quantity(noise, "length", "--noise", positive=True)
    sd_rot = quantity(orientation_noise, "angle", "--orientation-noise",
                      positive=instrument == "pose", minimum=0.0)
    min_dist = quantity(min_distance, "angle", "--min-distance", minimum=0.0)
    r = _plan_robot(robot, instrument, reachable, candidates_file, base_link, tip_link)
    marker_m = point_vector(marker, "--marker", ["length"] * 3) if marker is not None else None
    out = err_console if json_out == "-" else console
    cands, src, dropped = _candidates(r, candidates, None if reachable else candidates_file,
                                      units, ignore)
    with _Bar() as bar:
        from kincal.identify.plan import plan_poses

        p = plan_poses(r, instrument=instrument, poses=poses, criterion=crit,
                       candidates=cands, reachable=reachable, noise=sd,
                       orientation_noise=sd_rot or 1e-5,
                       marker=marker_m, scaling=scaling,
                       min_distance=min_dist, margin=margin, grid=grid,
                       exchange=not no_exchange, seed=seed, progress=bar,
                       source=src, dropped=dropped)
    poses_csv = _write_plan_files(p, r, output, program, dwell, angle_unit, length_unit, report,
                                  f"{crit} ({p.design.method})", instrument, seed, sd)
    _print_plan(out, p, r, crit, program, output, poses_csv, angle_unit, length_unit, report)
    _envelope_and_json(out, p, r, json_out, output, report)


def _envelope_and_json(out: Any, p: Plan, r: Any, json_out: str | None, output: str,
                       report: str | None) -> None:
    """A calibrated robot: where the planned poses leave its present calibration's training
    region (one warning); then the JSON document."""
    from kincal.cli.envelope_lines import envelope_report

    trust = envelope_report(out, r, p.q, "planned poses", console_units().scale("m"),
                            quiet=True)
    if json_out:
        from kincal.io import write_json

        doc = p.to_dict(output=output, report=report)
        write_json(json_out, {**doc, "calibration_envelope": trust} if trust else doc)


def _check_units(angle_unit: str, length_unit: str) -> None:
    """``--angle-unit`` an angle unit, ``--length-unit`` a length unit (one-line error)."""
    from kincal.units import UNITS

    for u, dim, opt in ((angle_unit, "angle", "--angle-unit"),
                        (length_unit, "length", "--length-unit")):
        if u not in UNITS or UNITS[u][0] != dim:
            raise KincalError(f"option {opt}: {u!r} is not {'an' if dim == 'angle' else 'a'} "
                              f"{dim} unit")


def _candidates(r: Any, count: int, path: str | None, units: str | None,
                ignore: list[str] | None) -> tuple[Any, str | None, int]:
    """The candidates: ``count`` random ones, or the configurations of the file ``path``
    (with what is said about them and the rows outside the joint limits dropped)."""
    if not path:
        return count, None, 0
    from kincal.identify.design import read_configurations
    from kincal.measure.files import parse_list_option, parse_units_option

    cands, dropped = read_configurations(path, r, parse_units_option(units),
                                         parse_list_option(ignore))
    return cands, f"{len(cands)} configurations from {path}", dropped


def _plan_robot(robot: str, instrument: str, reachable: bool, candidates_file: str | None,
                base_link: str | None, tip_link: str | None) -> Any:
    """The serial robot to plan for, after the instrument and candidate options agree."""
    if candidates_file and reachable:
        raise KincalError("use either --candidates-file or --reachable, not both")
    from kincal.measure.registry import get_instrument

    get_instrument(instrument)                       # unknown names: one line listing them
    if instrument not in ("position", "pose") and not reachable:
        raise KincalError(f"instrument {instrument!r}: its poses cannot be placed at arbitrary "
                          "configurations; add --reachable to take the candidates from its "
                          "simulator")
    r = robot_arg(robot, base_link, tip_link)
    if not hasattr(r, "param_jacobian"):
        raise KincalError(f"robot {getattr(r, 'name', robot)!r}: `kincal plan` works on serial "
                          "robots")
    return r


def _write_plan_files(p: Plan, r: Any, output: str, program: str | None, dwell: str,
                      angle_unit: str, length_unit: str, report: str | None, how: str,
                      instrument: str, seed: int, sd: float) -> str:
    """Write the pose CSV (beside ``output`` when ``output`` is a program), the program and
    the report; returns the pose CSV's path.  Everything is computed before writing."""
    from kincal.identify.design import write_poses
    from kincal.io import atomic_write_bytes, atomic_write_text

    d, pred = p.design, p.prediction
    html_text = render_plan_html(p) if report else None
    comments = [f"kincal plan: robot={r.name}; instrument={instrument}; criterion={how}; "
                f"poses={d.poses}; seed={seed}",
                f"predicted RMS position error after calibration: {pred.rms * 1e3:.4g} mm "
                f"(noise {sd * 1e3:g} mm); O1={d.indices.O1:.4g} kappa={d.indices.kappa:.4g}"]
    poses_csv = output
    prog_text = None
    if program:
        from kincal.compensation.programs.writers import joint_program

        prog_text = joint_program(program, r, d.q, name=Path(output).stem,
                                  dwell=_seconds(dwell, "--dwell"))
        poses_csv = str(Path(output).with_suffix(".csv"))
        if Path(poses_csv).resolve() == Path(output).resolve():
            raise KincalError(f"option -o: a program cannot be named {output!r} (.csv is the "
                              "pose file)")
    write_poses(poses_csv, r, d.q, angle_unit=angle_unit, length_unit=length_unit,
                comments=comments)
    if prog_text is not None:
        atomic_write_bytes(output, prog_text.encode("latin-1"))
    if html_text is not None and report is not None:
        atomic_write_text(report, html_text)
    return poses_csv


def _print_plan(out: Any, p: Plan, r: Any, crit: str, program: str | None, output: str,
                poses_csv: str, angle_unit: str, length_unit: str, report: str | None) -> None:
    """The plan's summary lines and its three tables."""
    d = p.design
    n_all = len(p.problem.problem.names)
    out.print(f"{escape(r.name)}: {p.problem.num_params} of {n_all} parameters identifiable "
              f"from {escape(p.inputs['candidates'])}"
              + (f" ({p.dropped} row{'s' if p.dropped > 1 else ''} outside the joint limits "
                 "dropped)" if p.dropped else ""))
    out.print(f"selected {d.poses} poses by {crit} ({d.method}, {d.exchanges} exchanges)")
    out.print(_indices_table(p))
    out.print(_accuracy_table(p))
    out.print(_param_table(p))
    cols = ", ".join(f"{j.name}_{angle_unit if j.kind == 'revolute' else length_unit}"
                     for j in r.joints)
    if program:
        out.print(f"wrote the {program} program -> {escape(output)}")
    out.print(f"wrote {d.poses} poses -> {escape(poses_csv)} (columns {cols})"
              + (f"; report -> {escape(report)}" if report else ""))


def _iso_plan(robot: str, output: str, cube_center: str | None, cube_size: str | None,
              cycles: int, program: str | None, dwell: str, angle_unit: str, length_unit: str,
              base_link: str | None, tip_link: str | None, json_out: str | None,
              cu: Any) -> None:
    """``kincal plan ROBOT --iso9283``: the test cube, its positions and the cycles
    (:func:`kincal.identify.iso9283_plan.plan_iso9283_cube`; the console in ``cu``'s
    units: mm and deg, m and rad with --si)."""
    from rich.table import Table as _Table

    from kincal.identify.design import write_poses
    from kincal.identify.iso9283 import CYCLE
    from kincal.identify.iso9283_plan import plan_iso9283_cube
    from kincal.io import atomic_write_bytes, write_json
    from kincal.units import parse_quantities, parse_quantity

    r = robot_arg(robot, base_link, tip_link)
    out = err_console if json_out == "-" else console
    center = parse_quantities(cube_center, "length", "--cube-center", count=3) \
        if cube_center else None
    size = parse_quantity(cube_size, "length", "--cube-size", positive=True) \
        if cube_size else None
    iso = plan_iso9283_cube(r, center, size, cycles)
    rows = iso.rows
    poses_csv = output
    text = None
    if program:
        from kincal.compensation.programs.writers import joint_program

        text = joint_program(program, r, rows, name=Path(output).stem,
                             dwell=_seconds(dwell, "--dwell"))
        poses_csv = str(Path(output).with_suffix(".csv"))
    write_poses(poses_csv, r, rows, angle_unit=angle_unit, length_unit=length_unit,
                comments=iso.comments())
    if text is not None:
        atomic_write_bytes(output, text.encode("latin-1"))
    lf, L = cu.scale("m")
    digits = 4 if cu.si else 1
    t = _Table(title=f"ISO 9283 test cube for {escape(r.name)}: edge "
                     f"{iso.size * lf:.{digits}f} {L}")
    jf = [cu.scale("rad" if j.kind == "revolute" else "m") for j in r.joints]
    for c in ("position", f"x [{L}]", f"y [{L}]", f"z [{L}]") + tuple(
            f"{j.name} [{u}]" for j, (_, u) in zip(r.joints, jf, strict=True)):
        t.add_column(escape(c), justify="left" if c == "position" else "right")
    for n in iso.names:
        t.add_row(n, *(f"{v * lf:.{digits}f}" for v in iso.positions[n]),
                  *(f"{v * f:.{digits + 1}f}" for v, (f, _) in zip(iso.joints[n], jf,
                                                                   strict=True)))
    out.print(t)
    out.print(f"cycle: {' -> '.join(CYCLE)} -> P1, {cycles} times ({len(rows)} moves)")
    if program:
        out.print(f"wrote the {program} program -> {escape(output)}")
    out.print(f"wrote {len(rows)} poses -> {escape(poses_csv)}")
    if json_out:
        write_json(json_out, iso.to_dict(output))
