"""Motion commands: ``ik``, ``trajectory``, ``clik`` (registered on the shared typer app).

Positions and poses on the command line carry their units (``--position 400,0,300mm``,
``--pose 0.4,0,0.3m,0,90,0deg``; bare lengths are m, bare angles rad, or deg with
``--deg``); joint values are rad / m (deg with ``--deg``) or carry their unit.  The
console shows lengths in mm and angles in degrees (``--si``: m, rad); joint values as
they are read.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.common import (
    JsonOut,
    RobotArg,
    console,
    err_console,
    is_fivebar,
    joint_vector,
    parse_vector,
    point_vector,
    robot_arg,
)
from kincal.cli.options import DegOpt, SeedOpt, SiOpt, Units, quantity
from kincal.errors import KincalError, UnreachableError
from kincal.io import write_json

if TYPE_CHECKING:
    import numpy as np

POSE = ["length"] * 3 + ["angle"] * 3


def _refuse_beyond_limits(robot: Any, q: Any, option: str, deg: bool) -> None:
    """Exit 1 with one line, before anything is computed or written, when joint values
    given by ``option`` lie beyond the robot's limits (a motion from or to a configuration
    the robot cannot take is no answer)."""
    from kincal.errors import CheckFailedError
    from kincal.measure.data_checks import command_line_joints

    line = command_line_joints(robot, q, option, deg)
    if line:
        raise CheckFailedError(line)


def _pose_from_option(text: str, deg: bool, option: str = "--pose") -> np.ndarray:
    from kincal.spatial import xyzrpy_to_matrix

    return xyzrpy_to_matrix(point_vector(text, option, POSE, deg))


# ---------------------------------------------------------------------------
# ik


@app.command()
def ik(robot: RobotArg,
       pose: Annotated[str | None, typer.Option(help="Target pose x,y,z,rx,ry,rz with units "
                                                "(0.4,0,0.3m,0,90,0deg; roll-pitch-yaw, R = "
                                                "Rz Ry Rx); bare: m and rad (deg with --deg).")]
       = None,
       position: Annotated[str | None, typer.Option(help="Target position x,y,z with its unit "
                                                    "(400,0,300mm; bare: m); position-only "
                                                    "IK. A five-bar takes x,y.")] = None,
       deg: DegOpt = False,
       q0: Annotated[str | None, typer.Option("--q0", help="Initial guess, comma separated "
                                              "(default: mid-range of the joint limits).")]
       = None,
       mask: Annotated[str | None, typer.Option(help="Rows of the pose error to solve: pose, "
                                                "position, orientation, or 6 flags like "
                                                "1,1,1,0,0,1 (x y z rx ry rz).")] = None,
       tol_position: Annotated[str, typer.Option(help="Tolerance on the position error, "
                                                 "with its unit.")] = "1e-6mm",
       tol_orientation: Annotated[str, typer.Option(help="Tolerance on the orientation "
                                                    "error, with its unit.")] = "1e-9rad",
       restarts: Annotated[int, typer.Option(help="Restart rounds for a failed attempt.")] = 5,
       seed: SeedOpt = 0,
       no_limits: Annotated[bool, typer.Option("--no-limits", help="Ignore the joint "
                                               "limits.")] = False,
       all_branches: Annotated[bool, typer.Option("--all-branches", help="Also list every "
                                                  "closed-form branch (PUMA-560, spherical "
                                                  "RRP and SCARA geometries).")] = False,
       mode: Annotated[str | None, typer.Option(help="Five-bar only: working mode ++, +-, -+, "
                                                "-- or all (default: the robot's).")] = None,
       si: SiOpt = False, json_out: JsonOut = None) -> None:
    """Inverse kinematics: joint values that put the tool at a pose or position.

    Solves with batched Levenberg-Marquardt to the stated tolerances on the pose error
    itself (metres, radians), checks the answer by forward kinematics, and exits with
    code 2 and a one-line reason when the target cannot be reached.
    """
    import numpy as np

    r = robot_arg(robot)
    if is_fivebar(r):
        if position is None:
            raise KincalError("a five-bar takes --position x,y")
        from kincal.cli.fivebar import ik_fivebar

        ik_fivebar(r, point_vector(position, "--position", ["length"] * 2), mode, json_out)
        return
    if mode is not None:
        raise KincalError("--mode is for five-bar robots; serial arms take --q0 to pick a "
                          "branch")
    if (pose is None) == (position is None):
        raise KincalError("give exactly one of --pose x,y,z,rx,ry,rz or --position x,y,z")
    from kincal.motion.ik import check_solutions, solve_ik

    tol_p = quantity(tol_position, "length", "--tol-position", positive=True)
    tol_o = quantity(tol_orientation, "angle", "--tol-orientation", positive=True)
    if pose is not None:
        target: np.ndarray = _pose_from_option(pose, deg)
        m_spec: Any = mask or "pose"
    else:
        target = point_vector(position or "", "--position", ["length"] * 3)
        m_spec = mask or "position"
    if mask is not None and mask not in ("pose", "position", "orientation"):
        m_spec = [bool(float(v)) for v in parse_vector(mask, "--mask", 6)]
    guess = None if q0 is None else joint_vector(r, q0, deg, "--q0")
    if guess is not None and not no_limits:
        _refuse_beyond_limits(r, guess, "--q0", deg)
    sol = solve_ik(r, target[None], q0=guess, mask=m_spec, tol_position=tol_p,
                   tol_orientation=tol_o, restarts=restarts,
                   rng=np.random.default_rng(seed), respect_limits=not no_limits)
    one = sol[0]
    ep, eo = check_solutions(r, target[None], sol.q, m_spec)
    data: dict[str, Any] = {
        "robot": r.name, "success": one.success, "reason": one.reason,
        "q": one.q.tolist(), "joint_names": list(r.joint_names),
        "joint_units": [j.unit for j in r.joints],
        "position_error_m": one.position_error, "orientation_error_rad": one.orientation_error,
        "fk_check": {"position_error_m": float(ep[0]), "orientation_error_rad": float(eo[0])},
        "iterations": one.iterations, "restarts": one.restarts,
        "tolerances": {"position_m": tol_p, "orientation_rad": tol_o},
        "mask": list(sol.mask)}
    if all_branches:
        data["branches"] = _branches(r, target, pose is not None)
    if json_out != "-":
        _print_ik(r, one, data, Units(si, deg))
    if one.success:
        from kincal.cli.envelope_lines import envelope_report

        trust = envelope_report(err_console if json_out == "-" else console, r, one.q,
                                "solutions", Units(si, deg).scale("m"), quiet=json_out == "-")
        if trust:
            data["calibration_envelope"] = trust
    if json_out:
        write_json(json_out, data)
    if not one.success:
        raise UnreachableError(f"{r.name}: {one.reason}")


def _branches(r: Any, target: np.ndarray, is_pose: bool) -> list[dict[str, Any]]:
    from kincal.motion.ik_closed_form import closed_form_ik

    if not is_pose:
        try:
            cf = closed_form_ik(r, target[None])
        except KincalError:
            raise KincalError(f"--all-branches: the closed form of {r.name} solves full "
                              "poses; give --pose x,y,z,rx,ry,rz instead of --position") \
                from None
    else:
        cf = closed_form_ik(r, target[None])
    return [{"branch": name, "q": None if not cf.reachable[0, b] else cf.q[0, b].tolist(),
             "reachable": bool(cf.reachable[0, b]),
             "within_limits": bool(cf.within_limits[0, b])}
            for b, name in enumerate(cf.branches)]


def _print_ik(r: Any, one: Any, data: dict[str, Any], units: Units) -> None:
    chk = data["fk_check"]
    errors = (f"position error {units.value(one.position_error, 'm', 6)}, orientation error "
              f"{units.value(one.orientation_error, 'rad', 6)} (FK check "
              f"{units.value(chk['position_error_m'], 'm', 6)}, "
              f"{units.value(chk['orientation_error_rad'], 'rad', 6)}); {one.iterations} "
              f"iterations, {one.restarts} restart rounds")
    if one.success:
        t = Table(title=f"{escape(r.name)}: inverse kinematics (solved)")
        t.add_column("joint")
        t.add_column("value", justify="right")
        for j, v in zip(r.joints, one.q, strict=True):
            t.add_row(escape(j.name), units.joint(float(v), j.kind))
        console.print(t)
        console.print(errors)
    else:
        console.print(f"[red]no solution within the tolerances[/red]: {escape(one.reason)}")
        if one.iterations > 0:          # else the solver never started: q is the guess
            console.print("closest configuration found (not a solution): " + ", ".join(
                f"{escape(j.name)} = {units.joint(float(v), j.kind)}"
                for j, v in zip(r.joints, one.q, strict=True)) + f"; {errors}")
    for b in data.get("branches", []):
        if b["q"] is None:
            console.print(f"  branch {b['branch']}: unreachable")
            continue
        vals = ", ".join(units.joint(v, j.kind) for v, j in zip(b["q"], r.joints, strict=True))
        flag = "" if b["within_limits"] else "  (outside the joint limits)"
        console.print(f"  branch {b['branch']}: {vals}{flag}")


# ---------------------------------------------------------------------------
# trajectory


@app.command()
def trajectory(robot: RobotArg,
               start: Annotated[str, typer.Option(help="Start joint values, comma separated "
                                                  "(rad / m, deg with --deg, or with units).")],
               end: Annotated[str | None, typer.Option(help="End joint values.")] = None,
               end_pose: Annotated[str | None, typer.Option(help="End pose x,y,z,rx,ry,rz with "
                                                            "units, for line and arc paths.")]
               = None,
               space: Annotated[str, typer.Option(help="joint: interpolate joint values; "
                                                  "line: straight tool path; arc: circular "
                                                  "tool path through --via-position.")]
               = "joint",
               via: Annotated[list[str] | None, typer.Option(help="Joint via point (repeat "
                                                             "for several); joint space "
                                                             "only.")] = None,
               via_position: Annotated[str | None, typer.Option(help="A point x,y,z on the arc, "
                                                                "with its unit.")] = None,
               timing: Annotated[str, typer.Option(help="cubic, quintic, trapezoidal or "
                                                   "linear.")] = "quintic",
               duration: Annotated[str | None, typer.Option(
                   help="Duration with its unit, e.g. 2s (needed except for trapezoidal).")]
               = None,
               v_max: Annotated[str | None, typer.Option(help="Trapezoidal: speed limit, "
                                                         "per joint (rad/s | m/s) or of the "
                                                         "tool path [m/s].")] = None,
               a_max: Annotated[str | None, typer.Option(help="Trapezoidal: acceleration "
                                                         "limit, per joint or of the tool "
                                                         "path (SI).")] = None,
               dt: Annotated[str, typer.Option(help="Sample time with its unit.")] = "10ms",
               deg: DegOpt = False, si: SiOpt = False,
               out_dir: Annotated[Path, typer.Option("--out-dir", help="Folder for "
                                                     "trajectory.csv and trajectory.png.")]
               = Path("."),
               json_out: JsonOut = None) -> None:
    """Plan a trajectory and write it as CSV (units in the header) and a PNG plot.

    Joint space: straight interpolation with a timing law (trapezoidal synchronised to
    the slowest joint), or a C2 spline through --via points.  Cartesian: a straight
    line or a circular arc with slerp orientation, joints from batched IK.
    """
    import numpy as np

    from kincal.motion import trajectory as tj

    out = out_dir
    step = quantity(dt, "time", "--dt", positive=True)
    total = quantity(duration, "time", "--duration", positive=True)
    r = robot_arg(robot)
    q_start = joint_vector(r, start, deg, "--start")
    q_end = None if end is None else joint_vector(r, end, deg, "--end")
    _refuse_beyond_limits(r, q_start, "--start", deg)
    if q_end is not None:
        _refuse_beyond_limits(r, q_end, "--end", deg)
    for v in via or []:
        _refuse_beyond_limits(r, joint_vector(r, v, deg, "--via"), "--via", deg)
    if space == "joint":
        if q_end is None:
            raise KincalError("a joint-space trajectory needs --end")
        if via:
            if total is None:
                raise KincalError("a trajectory through via points needs --duration")
            pts = np.vstack([q_start] + [joint_vector(r, v, deg, "--via") for v in via] + [q_end])
            traj = tj.via_trajectory(pts, np.linspace(0.0, total, len(pts)), step, "spline", r)
        elif timing == "trapezoidal":
            if v_max is None or a_max is None:
                raise KincalError("the trapezoidal law needs --v-max and --a-max")
            law = tj.synchronized_trapezoidal(q_start, q_end, parse_vector(v_max, "--v-max"),
                                              parse_vector(a_max, "--a-max"))
            traj = tj.joint_trajectory(q_start, q_end, law, step, r)
        else:
            traj = tj.joint_trajectory(q_start, q_end, tj.timing_law(timing, total), step, r)
    elif space in ("line", "arc"):
        T0 = r.fk(q_start)
        if end_pose is not None:
            T1 = _pose_from_option(end_pose, deg, "--end-pose")
        elif q_end is not None:
            T1 = r.fk(q_end)
        else:
            raise KincalError(f"a {space} path needs --end or --end-pose")
        vm = None if v_max is None else float(parse_vector(v_max, "--v-max", 1)[0])
        am = None if a_max is None else float(parse_vector(a_max, "--a-max", 1)[0])
        if space == "line":
            path: Any = tj.LinePath(T0, T1)
        else:
            if via_position is None:
                raise KincalError("an arc needs --via-position x,y,z")
            path = tj.arc_through(T0, point_vector(via_position, "--via-position",
                                                   ["length"] * 3), T1)
        law = tj.timing_law(timing, total, path.length, vm, am)
        mask = "pose" if r.n >= 6 else "position"
        traj = tj.cartesian_trajectory(r, tj.CartesianMotion(path, law), q_start, step,
                                       mask=mask, kind=space)
    else:
        raise KincalError(f"unknown --space {space!r}; use joint, line or arc")
    out.mkdir(parents=True, exist_ok=True)
    traj.to_csv(out / "trajectory.csv")
    traj.plot(out / "trajectory.png", title=f"{r.name}: {space} trajectory ({timing})")
    summary = {"robot": r.name, "space": space, "samples": len(traj),
               "duration_s": traj.duration, "csv": str(out / "trajectory.csv"),
               "plot": str(out / "trajectory.png"),
               "max_abs_qd": np.abs(traj.qd).max(axis=0).tolist(),
               "max_abs_qdd": np.abs(traj.qdd).max(axis=0).tolist(),
               "joint_units": list(traj.joint_units)}
    if json_out != "-":
        units = Units(si, deg)
        t = Table(title=f"{r.name}: {space} trajectory, {len(traj)} samples over "
                  f"{traj.duration:.4g} s")
        for c in ("joint", "start", "end", "max |velocity|", "max |acceleration|"):
            t.add_column(c, justify="left" if c == "joint" else "right")
        for j, joint in enumerate(r.joints):
            rev = joint.kind == "revolute"
            f, u = (180.0 / math.pi, "deg") if rev and deg else (1.0, "rad" if rev else "m")
            t.add_row(escape(joint.name), units.joint(traj.q[0, j], joint.kind),
                      units.joint(traj.q[-1, j], joint.kind),
                      f"{summary['max_abs_qd'][j] * f:.6g} {u}/s",
                      f"{summary['max_abs_qdd'][j] * f:.6g} {u}/s²")
        console.print(t)
        console.print(f"wrote {escape(summary['csv'])} and {escape(summary['plot'])}")
    if json_out:
        write_json(json_out, summary)


# ---------------------------------------------------------------------------
# clik


@app.command("clik")
def clik_command(
        robot: RobotArg,
        start: Annotated[str, typer.Option(help="Initial joint values (rad / m, deg with "
                                           "--deg, or with units); the line starts at their "
                                           "tool position.")],
        end_position: Annotated[str, typer.Option(help="End of the straight line x,y,z with "
                                                  "its unit, e.g. -707.1,707.1,100mm.")],
        method: Annotated[list[str] | None, typer.Option(
            help="Inversion: inverse (J^-1), transpose, pinv, dls (constant damping), "
                 "adaptive (damping near singularities); repeat to compare "
                 "(default: inverse and dls).")] = None,
        damping: Annotated[str, typer.Option(help="k of dls, k_max of adaptive, with its "
                                             "unit.")] = "0.1m",
        threshold: Annotated[str, typer.Option(help="adaptive: damping starts when the "
                                               "smallest singular value is below this.")]
        = "0.1m",
        gain: Annotated[str, typer.Option(help="K [1/s]: one value or x,y,z diagonal.")]
        = "50",
        dt: Annotated[str, typer.Option(help="Integration step with its unit.")] = "2ms",
        duration: Annotated[str, typer.Option(help="Duration of the line with its unit.")]
        = "4s",
        timing: Annotated[str, typer.Option(help="Timing law on the line: quintic, cubic, "
                                            "linear.")] = "quintic",
        integrator: Annotated[str, typer.Option(help="euler or rk4.")] = "euler",
        deg: DegOpt = False, si: SiOpt = False,
        out_dir: Annotated[Path, typer.Option("--out-dir", help="Folder for the CSV files and "
                                              "the plot.")] = Path("clik"),
        json_out: JsonOut = None) -> None:
    """Closed-loop inverse kinematics along a straight line: q_dot = J#(q)(p_dot_d + K e).

    The tool position follows the line from FK(--start) to --end-position with the timing
    law, by the 3 x n position Jacobian inverted by each --method; near a singularity
    J^-1 blows up and damped least squares trades path accuracy for bounded speeds.  The
    spherical arm example: kincal clik spherical_rrp --start 0,45deg,0.5m
    --end-position=-707.107,707.107,100mm (d2 = 1 m: the line enters the unreachable
    cylinder around the first axis).
    """

    from kincal.motion.clik import INTEGRATORS, METHODS, Method, clik, plot_clik
    from kincal.motion.trajectory import CartesianMotion, LinePath, TimingLaw

    out = out_dir
    step = quantity(dt, "time", "--dt", positive=True)
    total = quantity(duration, "time", "--duration", positive=True)
    k = quantity(damping, "length", "--damping", minimum=0.0)
    eps = quantity(threshold, "length", "--threshold", minimum=0.0)
    methods: list[Method] = []
    for name in method or ["inverse", "dls"]:
        known = next((m for m in METHODS if m == name), None)
        if known is None:
            raise KincalError(f"unknown --method {name!r}; use one of {', '.join(METHODS)}")
        methods.append(known)
    scheme = next((i for i in INTEGRATORS if i == integrator), None)
    if scheme is None:
        raise KincalError(f"option --integrator: {integrator!r} is not euler or rk4")
    g = parse_vector(gain, "--gain")
    if g.size not in (1, 3):
        raise KincalError("option --gain: give 1 or 3 values")
    r = robot_arg(robot)
    if is_fivebar(r):
        raise KincalError("`kincal clik` works on serial robots")
    q0 = joint_vector(r, start, deg, "--start")
    _refuse_beyond_limits(r, q0, "--start", deg)
    p_end = point_vector(end_position, "--end-position", ["length"] * 3)
    T0 = r.fk(q0)
    T1 = T0.copy()
    T1[:3, 3] = p_end
    motion = CartesianMotion(LinePath(T0, T1), TimingLaw.named(timing, total))
    out.mkdir(parents=True, exist_ok=True)
    results = []
    quiet = json_out == "-"
    with Progress(TextColumn("{task.description}"), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(),
                  console=err_console, disable=quiet or not err_console.is_terminal,
                  transient=True) as bar:
        for m in methods:
            task = bar.add_task(f"CLIK {m}", total=1.0)

            def advance(i: int, n: int, task: TaskID = task) -> None:
                bar.update(task, completed=i / n)

            res = clik(r, motion, q0, step, g if g.size == 3 else float(g[0]), m,
                       k, eps, task="position", integrator=scheme, progress=advance)
            res.meta["segment"] = (T0[:3, 3].tolist(), p_end.tolist())
            res.meta["damping_k"] = k
            res.to_csv(out / f"clik_{m}.csv")
            results.append(res)
    plot_clik(results, out / "clik_compare.png",
              title=f"{r.name}: CLIK along a straight line (one column per method)")
    summary = _clik_summary(r, results, out, T0[:3, 3], p_end)
    if not quiet:
        _print_clik(summary, Units(si, deg))
    if json_out:
        write_json(json_out, summary)


#: Tracking error [m] above which a CLIK run is said to leave the path.
_OFF_PATH = 1e-3


def _clik_summary(robot: Any, results: list[Any], out: Path, p0: np.ndarray,
                  p1: np.ndarray) -> dict[str, Any]:
    """Per method: final error, path deviation, peak joint speeds (and when), worst
    manipulability; the ratio of each method's peak joint speed to the first method's."""
    import numpy as np

    runs = []
    for r in results:
        s = r.summary()
        peaks = np.abs(r.qd).max(axis=0)
        j = int(np.argmax(peaks / np.maximum(np.abs(results[0].qd).max(axis=0), 1e-300)))
        k = int(np.argmax(np.abs(r.qd[:, j])))
        err = np.linalg.norm(r.error[:, :3], axis=1)
        off = np.flatnonzero(err > _OFF_PATH)
        s.update(peak_joint=robot.joint_names[j], peak_time_s=float(r.t[k]),
                 max_abs_qd=peaks.tolist(), final_q=r.q[-1].tolist(),
                 off_path_time_s=float(r.t[off[0]]) if off.size else None,
                 csv=str(out / f"clik_{r.method}.csv"))
        runs.append(s)
    ref = np.abs(results[0].qd).max(axis=0)
    for s, r in zip(runs, results, strict=True):
        s["peak_speed_ratio_first_over_this"] = (ref / np.maximum(
            np.abs(r.qd).max(axis=0), 1e-300)).tolist()
        # when the first method's joint speeds first exceed this method's peaks: a time
        # that does not depend on the step, unlike the peak itself past a singularity
        j = int(np.argmax(s["peak_speed_ratio_first_over_this"]))
        peak = float(np.abs(r.qd[:, j]).max())
        over = np.flatnonzero(np.abs(results[0].qd[:, j]) > peak)
        s["first_exceeds_this_peak"] = {
            "joint": robot.joint_names[j], "peak": peak,
            "time_s": float(results[0].t[over[0]]) if over.size else None}
    return {"robot": robot.name, "start_position_m": p0.tolist(), "end_position_m": p1.tolist(),
            "joint_names": list(robot.joint_names),
            "joint_units": [j.unit for j in robot.joints],
            "compare_plot": str(out / "clik_compare.png"), "runs": runs}


def _joint_speed_unit(units: Units, unit: str) -> tuple[float, str]:
    """(factor from SI, unit) of a joint speed: deg/s by default and with --deg, rad/s
    with --si alone; prismatic joints in m/s."""
    if unit != "rad":
        return 1.0, "m"
    return (180 / math.pi, "deg") if units.deg or not units.si else (1.0, "rad")


def _print_clik(summary: dict[str, Any], units: Units) -> None:
    L = units.length_unit
    names, kinds = summary["joint_names"], summary["joint_units"]
    t = Table(title=f"{escape(summary['robot'])}: CLIK along the line "
              f"{', '.join(units.length(v, 1) for v in summary['start_position_m'])} -> "
              f"{', '.join(units.length(v, 1) for v in summary['end_position_m'])} {L}")
    cols = ["method", f"final |e| \\[{L}]", f"max dist. from line \\[{L}]"]
    for n, u in zip(names, kinds, strict=True):
        cols.append(escape(f"max |{n}'| [{_joint_speed_unit(units, u)[1]}/s]"))
    cols += ["peak at \\[s]", "min manipulability"]
    for c in cols:
        t.add_column(c, justify="left" if c == "method" else "right")
    for s in summary["runs"]:
        speeds = [f"{v * _joint_speed_unit(units, u)[0]:.4g}"
                  for v, u in zip(s["max_abs_qd"], kinds, strict=True)]
        t.add_row(s["method"], units.length(s["final_position_error_m"], 6),
                  units.length(s["max_path_deviation_m"], 3), *speeds,
                  f"{s['peak_time_s']:.3f}", f"{s['min_manipulability']:.3g}")
    console.print(t)
    runs = summary["runs"]
    for s in runs:
        t_off = s["off_path_time_s"]
        console.print(f"{s['method']}: " + (
            f"tracking error above {units.length(_OFF_PATH, 3)} {L} from t = {t_off:.3f} s"
            if t_off is not None else f"tracking error within {units.length(_OFF_PATH, 3)} {L}"
            " all along"))
    for s in runs[1:]:
        ex = s["first_exceeds_this_peak"]
        if ex["time_s"] is not None:
            f, su = _joint_speed_unit(units, kinds[names.index(ex["joint"])])
            console.print(escape(
                f"{runs[0]['method']}: {ex['joint']}' passes {s['method']}'s peak "
                f"({ex['peak'] * f:.4g} {su}/s) at t = {ex['time_s']:.3f} s; past a "
                "singularity its own peak depends on the step (--dt)"))
    console.print(f"plots and CSV in {escape(str(Path(summary['compare_plot']).parent))}")
