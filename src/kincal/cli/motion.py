"""Motion commands: ``ik``, ``trajectory``, ``clik`` (registered on the shared typer app)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.common import JsonOut, RobotArg, console, joint_vector, parse_vector, robot_arg
from kincal.errors import KincalError, UnreachableError
from kincal.io import write_json

if TYPE_CHECKING:
    import numpy as np

DegOpt = Annotated[bool, typer.Option("--deg", help="Angles on the command line and in the "
                                      "printout are in degrees (lengths stay in metres).")]


def _fmt_joint(value: float, unit: str, deg: bool) -> str:
    if unit == "rad":
        return f"{math.degrees(value):.6f}°" if deg else f"{value:.9f} rad"
    return f"{value:.9f} m"


def _pose_from_option(text: str, deg: bool) -> np.ndarray:
    import numpy as np

    from kincal.spatial import xyzrpy_to_matrix

    v = parse_vector(text, "--pose", 6)
    if deg:
        v[3:] = np.radians(v[3:])
    return xyzrpy_to_matrix(v)


# ---------------------------------------------------------------------------
# ik


@app.command()
def ik(robot: RobotArg,
       pose: Annotated[str | None, typer.Option(help="Target pose x,y,z,rx,ry,rz: metres and "
                                                "roll-pitch-yaw (R = Rz Ry Rx), rad or --deg.")]
       = None,
       position: Annotated[str | None, typer.Option(help="Target position x,y,z [m] "
                                                    "(position-only IK; a five-bar takes x,y).")]
       = None,
       deg: DegOpt = False,
       q0: Annotated[str | None, typer.Option("--q0", help="Initial guess, comma separated "
                                              "(default: mid-range of the joint limits).")]
       = None,
       mask: Annotated[str | None, typer.Option(help="Rows of the pose error to solve: pose, "
                                                "position, orientation, or 6 flags like "
                                                "1,1,1,0,0,1 (x y z rx ry rz).")] = None,
       tol_position: Annotated[float, typer.Option(help="Tolerance on the position error "
                                                   "[m].")] = 1e-9,
       tol_orientation: Annotated[float, typer.Option(help="Tolerance on the orientation "
                                                      "error [rad].")] = 1e-9,
       restarts: Annotated[int, typer.Option(help="Restart rounds for a failed attempt.")] = 5,
       seed: Annotated[int, typer.Option(help="Seed of the random restart configurations.")]
       = 0,
       no_limits: Annotated[bool, typer.Option("--no-limits", help="Ignore the joint "
                                               "limits.")] = False,
       all_branches: Annotated[bool, typer.Option("--all-branches", help="Also list every "
                                                  "closed-form branch (PUMA-560, spherical "
                                                  "RRP and SCARA geometries).")] = False,
       mode: Annotated[str | None, typer.Option(help="Five-bar only: working mode ++, +-, -+, "
                                                "-- or all (default: the robot's).")] = None,
       json_out: JsonOut = None) -> None:
    """Inverse kinematics: joint values that put the tool at a pose or position.

    Solves with batched Levenberg-Marquardt to the stated tolerances on the pose error
    itself (metres, radians), checks the answer by forward kinematics, and exits with
    code 2 and a one-line reason when the target cannot be reached.
    """
    import numpy as np

    r = robot_arg(robot)
    if type(r).__name__ == "FiveBar":
        if position is None:
            raise KincalError("a five-bar takes --position x,y")
        from kincal.cli.fivebar import ik_fivebar

        ik_fivebar(r, parse_vector(position, "--position", 2), mode, json_out)
        return
    if mode is not None:
        raise KincalError("--mode is for five-bar robots; serial arms take --q0 to pick a "
                          "branch")
    if (pose is None) == (position is None):
        raise KincalError("give exactly one of --pose x,y,z,rx,ry,rz or --position x,y,z")
    from kincal.motion.ik import check_solutions, solve_ik

    if pose is not None:
        target: np.ndarray = _pose_from_option(pose, deg)
        m_spec: Any = mask or "pose"
    else:
        target = parse_vector(position or "", "--position", 3)
        m_spec = mask or "position"
    if mask is not None and mask not in ("pose", "position", "orientation"):
        m_spec = [bool(float(v)) for v in parse_vector(mask, "--mask", 6)]
    guess = None if q0 is None else joint_vector(r, q0, deg, "--q0")
    sol = solve_ik(r, target[None], q0=guess, mask=m_spec, tol_position=tol_position,
                   tol_orientation=tol_orientation, restarts=restarts,
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
        "tolerances": {"position_m": tol_position, "orientation_rad": tol_orientation},
        "mask": list(sol.mask)}
    if all_branches:
        data["branches"] = _branches(r, target, pose is not None)
    if json_out != "-":
        _print_ik(r, one, data, deg)
    if json_out:
        write_json(json_out, data)
    if not one.success:
        raise UnreachableError(f"{r.name}: {one.reason}")


def _branches(r: Any, target: np.ndarray, is_pose: bool) -> list[dict[str, Any]]:
    from kincal.motion.ik_closed_form import closed_form_ik

    cf = closed_form_ik(r, target[None] if is_pose else target[None])
    return [{"branch": name, "q": None if not cf.reachable[0, b] else cf.q[0, b].tolist(),
             "reachable": bool(cf.reachable[0, b]),
             "within_limits": bool(cf.within_limits[0, b])}
            for b, name in enumerate(cf.branches)]


def _print_ik(r: Any, one: Any, data: dict[str, Any], deg: bool) -> None:
    t = Table(title=f"{r.name}: inverse kinematics "
              f"({'solved' if one.success else 'FAILED'})")
    t.add_column("joint")
    t.add_column("value", justify="right")
    for j, v in zip(r.joints, one.q, strict=True):
        t.add_row(j.name, _fmt_joint(float(v), j.unit, deg))
    console.print(t)
    chk = data["fk_check"]
    console.print(f"position error {one.position_error:.3e} m, orientation error "
                  f"{one.orientation_error:.3e} rad (FK check {chk['position_error_m']:.3e} m, "
                  f"{chk['orientation_error_rad']:.3e} rad); {one.iterations} iterations, "
                  f"{one.restarts} restart rounds")
    for b in data.get("branches", []):
        if b["q"] is None:
            console.print(f"  branch {b['branch']}: unreachable")
            continue
        vals = ", ".join(_fmt_joint(v, j.unit, deg) for v, j in zip(b["q"], r.joints,
                                                                    strict=True))
        flag = "" if b["within_limits"] else "  (outside the joint limits)"
        console.print(f"  branch {b['branch']}: {vals}{flag}")
    if not one.success:
        console.print(f"[red]{one.reason}[/red]")


# ---------------------------------------------------------------------------
# trajectory


@app.command()
def trajectory(robot: RobotArg,
               start: Annotated[str, typer.Option(help="Start joint values (comma separated; "
                                                  "see --deg).")],
               end: Annotated[str | None, typer.Option(help="End joint values.")] = None,
               end_pose: Annotated[str | None, typer.Option(help="End pose x,y,z,rx,ry,rz "
                                                            "for line and arc paths.")] = None,
               space: Annotated[str, typer.Option(help="joint: interpolate joint values; "
                                                  "line: straight tool path; arc: circular "
                                                  "tool path through --via-position.")]
               = "joint",
               via: Annotated[list[str] | None, typer.Option(help="Joint via point (repeat "
                                                             "for several); joint space "
                                                             "only.")] = None,
               via_position: Annotated[str | None, typer.Option(help="A point x,y,z [m] on "
                                                                "the arc.")] = None,
               timing: Annotated[str, typer.Option(help="cubic, quintic, trapezoidal or "
                                                   "linear.")] = "quintic",
               duration: Annotated[float | None, typer.Option(help="Duration [s] (needed "
                                                              "except for trapezoidal).")]
               = None,
               v_max: Annotated[str | None, typer.Option(help="Trapezoidal: speed limit, "
                                                         "per joint (rad/s | m/s) or of the "
                                                         "tool path [m/s].")] = None,
               a_max: Annotated[str | None, typer.Option(help="Trapezoidal: acceleration "
                                                         "limit, per joint or of the tool "
                                                         "path.")] = None,
               dt: Annotated[float, typer.Option(help="Sample time [s].")] = 0.01,
               deg: DegOpt = False,
               out: Annotated[Path, typer.Option(help="Folder for trajectory.csv and "
                                                 "trajectory.png.")] = Path("."),
               json_out: JsonOut = None) -> None:
    """Plan a trajectory and write it as CSV (units in the header) and a PNG plot.

    Joint space: straight interpolation with a timing law (trapezoidal synchronised to
    the slowest joint), or a C2 spline through --via points.  Cartesian: a straight
    line or a circular arc with slerp orientation, joints from batched IK.
    """
    import numpy as np

    from kincal.motion import trajectory as tj

    r = robot_arg(robot)
    q_start = joint_vector(r, start, deg, "--start")
    q_end = None if end is None else joint_vector(r, end, deg, "--end")
    if space == "joint":
        if q_end is None:
            raise KincalError("a joint-space trajectory needs --end")
        if via:
            if duration is None:
                raise KincalError("a trajectory through via points needs --duration")
            pts = np.vstack([q_start] + [joint_vector(r, v, deg, "--via") for v in via] + [q_end])
            traj = tj.via_trajectory(pts, np.linspace(0.0, duration, len(pts)), dt, "spline", r)
        elif timing == "trapezoidal":
            if v_max is None or a_max is None:
                raise KincalError("the trapezoidal law needs --v-max and --a-max")
            law = tj.synchronized_trapezoidal(q_start, q_end, parse_vector(v_max, "--v-max"),
                                              parse_vector(a_max, "--a-max"))
            traj = tj.joint_trajectory(q_start, q_end, law, dt, r)
        else:
            traj = tj.joint_trajectory(q_start, q_end, tj.timing_law(timing, duration), dt, r)
    elif space in ("line", "arc"):
        T0 = r.fk(q_start)
        if end_pose is not None:
            T1 = _pose_from_option(end_pose, deg)
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
            path = tj.arc_through(T0, parse_vector(via_position, "--via-position", 3), T1)
        law = tj.timing_law(timing, duration, path.length, vm, am)
        mask = "pose" if r.n >= 6 else "position"
        traj = tj.cartesian_trajectory(r, tj.CartesianMotion(path, law), q_start, dt,
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
        t = Table(title=f"{r.name}: {space} trajectory, {len(traj)} samples over "
                  f"{traj.duration:.4g} s")
        for c in ("joint", "start", "end", "max |velocity|", "max |acceleration|"):
            t.add_column(c, justify="left" if c == "joint" else "right")
        for j, (n, u) in enumerate(zip(traj.joint_names, traj.joint_units, strict=True)):
            t.add_row(n, f"{traj.q[0, j]:.6g} {u}", f"{traj.q[-1, j]:.6g} {u}",
                      f"{summary['max_abs_qd'][j]:.6g} {u}/s",
                      f"{summary['max_abs_qdd'][j]:.6g} {u}/s²")
        console.print(t)
        console.print(f"wrote {summary['csv']} and {summary['plot']}")
    if json_out:
        write_json(json_out, summary)


# ---------------------------------------------------------------------------
# clik


@app.command("clik")
def clik_command(
        method: Annotated[list[str] | None, typer.Option(
            help="Inversion: inverse (J^-1), transpose, pinv, dls (constant damping), "
                 "adaptive (damping near singularities); repeat to compare "
                 "(default: inverse and dls).")] = None,
        damping: Annotated[float, typer.Option(help="k of dls, k_max of adaptive [m].")] = 0.1,
        threshold: Annotated[float, typer.Option(help="adaptive: damping starts when the "
                                                 "smallest singular value is below this "
                                                 "[m].")] = 0.1,
        gain: Annotated[str, typer.Option(help="K [1/s]: one value or x,y,z diagonal.")]
        = "50",
        dt: Annotated[float, typer.Option(help="Integration step [s].")] = 0.002,
        tf: Annotated[float, typer.Option("--tf", help="Duration of the line [s].")] = 4.0,
        timing: Annotated[str, typer.Option(help="Timing law on the line: quintic, cubic, "
                                            "linear.")] = "quintic",
        integrator: Annotated[str, typer.Option(help="euler or rk4.")] = "euler",
        out: Annotated[Path, typer.Option(help="Folder for the CSV files and plots.")]
        = Path("clik_seed003"),
        json_out: JsonOut = None) -> None:
    """Seed 003: closed-loop IK of the spherical RRP arm (d2 = 1 m) along a straight line.

    From p_i = (sqrt(2)/4, 1, sqrt(2)/4) m, q0 = (0, pi/4, 0.5), to
    p_f = (-sqrt(2)/2, sqrt(2)/2, 0.1) m in --tf seconds, q_dot = J#(q)(p_dot_d + K e)
    with the 3x3 position Jacobian.  The line enters the cylinder rho < d2 that the arm
    cannot reach (theta2 = 0 on its wall): J^-1 blows up there, damped least squares
    slides along the wall and rejoins the line at p_f.
    """
    from kincal.motion.clik import METHODS, plot_clik, run_seed003

    methods = method or ["inverse", "dls"]
    for m in methods:
        if m not in METHODS:
            raise KincalError(f"unknown --method {m!r}; use one of {', '.join(METHODS)}")
    g = parse_vector(gain, "--gain")
    if g.size not in (1, 3):
        raise KincalError("option --gain: give 1 or 3 values")
    out.mkdir(parents=True, exist_ok=True)
    results = []
    quiet = json_out == "-"
    with Progress(TextColumn("{task.description}"), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(), console=console,
                  disable=quiet) as bar:
        for m in methods:
            task = bar.add_task(f"CLIK {m}", total=1.0)
            res = run_seed003(m, gain=g if g.size == 3 else float(g[0]),  # type: ignore[arg-type]
                              damping=damping, threshold=threshold, dt=dt, timing=timing,
                              integrator=integrator, duration=tf,  # type: ignore[arg-type]
                              progress=lambda k, n, task=task: bar.update(task,
                                                                            completed=k / n))
            res.to_csv(out / f"clik_{m}.csv")
            results.append(res)
    plot_clik(results, out / "clik_compare.png",
              title="seed 003: spherical RRP arm along p_i -> p_f (one column per method)")
    summary = _clik_summary(results, out)
    if not quiet:
        _print_clik(summary)
    if json_out:
        write_json(json_out, summary)


def _clik_summary(results: list[Any], out: Path) -> dict[str, Any]:
    import numpy as np

    from kincal.motion.clik import SEED003_P_F, SEED003_P_I, SEED003_QF, seed003_robot

    robot = seed003_robot()
    runs = []
    for r in results:
        k = int(np.argmax(np.abs(r.qd[:, 1])))
        s = r.summary()
        s.update(peak_theta2_dot_time_s=float(r.t[k]), theta2_at_peak_rad=float(r.q[k, 1]),
                 final_q=r.q[-1].tolist(), csv=str(out / f"clik_{r.method}.csv"))
        runs.append(s)
    ref = runs[0]["max_abs_theta2_dot_rad_s"]
    for s in runs:
        s["theta2_dot_peak_ratio_first_over_this"] = float(ref / s["max_abs_theta2_dot_rad_s"])
    a, b = SEED003_P_I, SEED003_P_F
    d = b - a
    # depth of the line inside the cylinder rho < d2 the arm cannot reach
    ss = np.linspace(0, 1, 100001)
    rho = np.hypot(a[0] + ss * d[0], a[1] + ss * d[1])
    inside = rho < 1.0
    return {"robot": robot.name, "p_i": a.tolist(), "p_f": b.tolist(),
            "fk_q0": robot.fk([0, math.pi / 4, 0.5])[:3, 3].tolist(),
            "fk_qf": robot.fk(SEED003_QF)[:3, 3].tolist(),
            "line_inside_unreachable_cylinder_s": ([float(ss[inside][0]), float(ss[inside][-1])]
                                                   if inside.any() else None),
            "least_possible_path_deviation_m": float(max(0.0, 1.0 - rho.min())),
            "compare_plot": str(out / "clik_compare.png"), "runs": runs}


def _print_clik(summary: dict[str, Any]) -> None:
    t = Table(title="seed 003: CLIK of the spherical RRP arm along p_i -> p_f")
    cols = ("method", "final |e| \\[m]", "max dist. from line \\[m]", "max |θ1'| \\[rad/s]",
            "max |θ2'| \\[rad/s]", "max |d3'| \\[m/s]", "θ2' peak at \\[s]", "min manipulability")
    for c in cols:
        t.add_column(c, justify="left" if c == "method" else "right")
    for s in summary["runs"]:
        t.add_row(s["method"], f"{s['final_position_error_m']:.3e}",
                  f"{s['max_path_deviation_m']:.4g}", f"{s['max_abs_theta1_dot_rad_s']:.4g}",
                  f"{s['max_abs_theta2_dot_rad_s']:.4g}", f"{s['max_abs_d3_dot_m_s']:.4g}",
                  f"{s['peak_theta2_dot_time_s']:.3f}", f"{s['min_manipulability']:.3g}")
    console.print(t)
    span = summary["line_inside_unreachable_cylinder_s"]
    if span:
        console.print(f"The line runs inside the unreachable cylinder rho < d2 = 1 m for s in "
                      f"[{span[0]:.4f}, {span[1]:.4f}]; no method can stay closer to it than "
                      f"{summary['least_possible_path_deviation_m']:.4f} m.")
    runs = summary["runs"]
    for s in runs[1:]:
        console.print(f"peak |θ2'|: {runs[0]['method']} / {s['method']} = "
                      f"{s['theta2_dot_peak_ratio_first_over_this']:.3g}")
    console.print(f"plots and CSV in {Path(summary['compare_plot']).parent}")
