"""Calibration commands: ``identifiability``, ``calibrate`` and ``validate``.

The computation lives in :mod:`kincal.workflow.flow`; these commands parse options, print
tables (mm and degrees) and hand the outputs to :func:`kincal.workflow.flow.write_outputs`.
Every command reads all its inputs and runs all its numerics before writing any output,
and every output is written atomically, so a bad file or an unreachable target leaves
nothing behind (the error is one line, exit code 2).  Sibling modules:
:mod:`~kincal.cli.simulate` (``instruments``, ``simulate``),
:mod:`~kincal.cli.compensate`, :mod:`~kincal.cli.demo`, :mod:`~kincal.cli.export`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

import kincal.cli.simulate  # noqa: F401  (registers `instruments`, `simulate` first in --help)
from kincal.cli.app import app
from kincal.cli.calibration_common import (
    DataOpt,
    IgnoreOpt,
    JointModelOpt,
    JointNamesOpt,
    JsonOpt,
    OptionalDataOpt,
    OptionalRobotArg,
    Progress,
    SchedulerOpt,
    UnitsOpt,
    WorkersOpt,
    fold_engine,
    joint_names_option,
    load,
    out_console,
    print_cross_validation,
    print_errors,
    print_heldout,
    print_identifiability,
    print_ignored,
    print_parameters,
    print_selection,
    print_staged_selection,
    print_weak,
    read_blocks,
    serial,
)
from kincal.cli.common import BaseLink, RobotArg, TipLink, is_fivebar
from kincal.cli.options import SiOpt, length_option, use_si
from kincal.cli.setupfile import (
    ConfigOpt,
    HoldOpt,
    InstrumentOpt,
    OptionOpt,
    as_sources,
    held_robot,
    require_robot,
    uses_setup,
)
from kincal.defaults import max_iter_for
from kincal.errors import CheckFailedError, KincalError
from kincal.io import check_outputs

if TYPE_CHECKING:                 # types only: the workflow loads lazily (start-up time)
    from rich.console import Console

    from kincal.workflow.result import FlowResult


@app.command()
def identifiability(
    robot: RobotArg, data: DataOpt, units: UnitsOpt = None, ignore: IgnoreOpt = None,
    free: Annotated[str | None, typer.Option("--free", help="Candidate parameters: names or * "
                                             "patterns, 'role:offset' (default: all).")] = None,
    fix: Annotated[str | None, typer.Option("--fix", help="Parameters to hold fixed.")] = None,
    base_link: BaseLink = None, tip_link: TipLink = None, si: SiOpt = False,
    json_out: JsonOpt = None,
) -> None:
    """Which parameters can these measurements identify? Zero and dependent columns,
    the base parameter set and the condition number, in plain sentences."""
    from kincal.identify.identifiability import analyze
    from kincal.io import write_json
    from kincal.measure.base import stack
    from kincal.workflow.flow import check_options_used, parse_selection

    out = out_console(json_out)
    cu = use_si(si)
    r = serial(load(robot, base_link, tip_link), "identifiability")
    check_options_used(data, units, ignore)
    blocks = read_blocks(data, r, units, ignore, out)
    prob, theta0 = stack(r, blocks)
    _, J = prob.residuals_and_jacobian(theta0)
    free_names, fixed = parse_selection(prob.names, prob.roles, free, fix)
    cand = [i for i, n in enumerate(prob.names)
            if (free_names is None or n in free_names) and n not in fixed]
    rep = analyze(J[:, cand], [prob.names[i] for i in cand],
                  roles=[prob.roles[i] for i in cand])
    n_meas = sum(b.q.shape[0] for b in blocks)
    out.print(f"[bold]{rep.rank} of {len(cand)}[/bold] candidate parameters are identifiable "
              f"from {n_meas} measurements ({len(prob.residuals(theta0))} residuals); "
              f"condition number (scaled columns) {rep.cond_scaled:.4g}.")
    t = Table(title="Parameters")
    for c in ("parameter", "unit", "status"):
        t.add_column(c, overflow="fold")
    ident = set(rep.identifiable)
    for i in cand:
        n = prob.names[i]
        if n in ident:
            status = "[green]identifiable[/green]"
        elif n in rep.unobservable:
            status = "[red]no effect on the measurements[/red]"
        else:
            status = "[yellow]dependent on " + escape(", ".join(rep.dependent.get(n, []))) + \
                "[/yellow]"
        t.add_row(escape(n), cu.scale(prob.units[i])[1], status)
    out.print(t)
    for s in rep.describe():
        out.print(f"- {escape(s)}")
    if json_out:
        write_json(json_out, {**rep.to_dict(), "measurements": n_meas,
                              "candidates": [prob.names[i] for i in cand]})


# ------------------------------------------------------------------ options of `calibrate`
OutputOpt = Annotated[str | None, typer.Option("-o", "--output", help="Calibrated robot file "
                                               "(YAML, SI units).")]
ValidateOpt = Annotated[list[str] | None, typer.Option(
    "--validate", help="Held-out measurement CSV (repeatable): errors before/after.")]
ReportOpt = Annotated[str | None, typer.Option("--report", help="Write a single-file HTML "
                                               "report here (artifact data: also the "
                                               "plots of the artifact's length errors as PNG "
                                               "next to it).")]
UrdfOpt = Annotated[str | None, typer.Option("--urdf", help="Also write the calibrated robot as "
                                             "URDF (URDF robots: the original file with "
                                             "corrected joint origins). Default for URDF "
                                             "robots: next to -o.")]
ProcedureOpt = Annotated[str, typer.Option(
    "--procedure", help="lm: one-stage least squares (--method); staged-selection: the "
    "two-stage procedure for artifact data (angles, then lengths; optional data "
    "selection by the condition number).")]
StagesOpt = Annotated[str | None, typer.Option("--stages", help="Comma-separated stages, e.g. "
                                               "'offsets,all' (encoder offsets first).")]
MethodOpt = Annotated[str, typer.Option("--method", help="lm | gauss-newton (--procedure "
                                        "lm).")]
LossOpt = Annotated[str, typer.Option("--loss", help="linear | huber | cauchy (robust to "
                                      "outliers).")]
LossScaleOpt = Annotated[float, typer.Option("--loss-scale", help="Robust threshold in "
                                              "standard deviations.")]
ConditionGrowthOpt = Annotated[float | None, typer.Option(
    "--condition-growth", metavar="FACTOR", help="--procedure staged-selection: the "
    "data selection: discard a placement if the condition number grows by more "
    "than FACTOR (>= 1; default: keep all).")]
CyclesOpt = Annotated[int | None, typer.Option(
    "--cycles", metavar="N", help="--procedure staged-selection: passes through the two "
    "stages; 1 = a single pass (default: until no point moves).")]
ToleranceOpt = Annotated[str | None, typer.Option(
    "--tolerance", metavar="LENGTH", help="--procedure staged-selection: a stage stops "
    "when no predicted probe point moves more than this, with its unit (default 0.1um).")]
FreeOpt = Annotated[str | None, typer.Option("--free", help="Parameters to estimate: names, * "
                                             "patterns or role:offset (default: every "
                                             "identifiable one).")]
FixOpt = Annotated[str | None, typer.Option("--fix", help="Parameters to hold at their "
                                            "nominal values.")]
MaxIterOpt = Annotated[int | None, typer.Option(
    "--max-iter", min=1, help="Iterations: in all (lm, default 100) or per stage and "
    "cycle (staged-selection, default 20).")]
PriorOpt = Annotated[str | None, typer.Option(
    "--prior", metavar="ENTRIES|none", help="The estimate is maximum a-posteriori: "
    "Gaussian priors centred on the nominal values with the parameters' manufacturing "
    "tolerances (default: length 1mm, angle 0.1deg, encoder offset 0.5deg; base, tool "
    "and instrument parameters none; a robot file's 'tolerances:' section overrides). "
    "Entries override them: roles, names or * patterns with a value and its unit, e.g. "
    "'length=0.5mm,offset=0.05deg,*.origin.r?=0.2deg', 'd[3]=none', 'scale=3' (the "
    "prior is 3x the tolerances). 'none': plain least squares. The tolerances also "
    "bound what is plausible (10x). Does not change which parameters are estimated.")]
CrossValidateOpt = Annotated[int | None, typer.Option(
    "--cross-validate", metavar="K", help="Also run K-fold cross-validation of the same "
    "calibration on the training file (folds drawn with seed 0): the RMS error on "
    "measurements each fold was not fitted to. Compare models (--joint-model, --prior, "
    "markers) by it, not by the validation file.")]
SelectOpt = Annotated[str, typer.Option(
    "--select", metavar="auto|none", help="auto: choose the joint model (geometric, "
    "+hysteresis, +compliance where the robot has link masses) and the prior scale (1x, 3x "
    "the tolerances, least squares) by cross-validation on the training files (folds by "
    "file, placement or workspace region; random rows only when none applies), print "
    "the table and fit the winner: the lowest cross-validated RMS among the fits that "
    "converge with plausible estimates. --joint-model and --prior none/scale= restrict "
    "it. none (default): fit the model as given.")]
FoldsOpt = Annotated[int, typer.Option("--folds", min=2, help="K of --select auto "
                                       "(permutation seed 0).")]
SplitOpt = Annotated[str, typer.Option(
    "--split", metavar="auto|random", help="What each fold of --select auto holds out: "
    "auto (files sharing a name, else artifact placements, else workspace regions; random "
    "folds only when none applies) or random (random folds of rows and placements).")]
SharedMarkerOpt = Annotated[bool, typer.Option(
    "--shared-marker", help="The --data (and --validate) files see one physical tool "
    "point (the same reflector, the same ball): estimate it once, as the robot's tool "
    "origin (tool.x/y/z), instead of one marker or probe per file.")]
CalibrationFramesOpt = Annotated[str, typer.Option(
    "--validation-frames", help="Instrument frames on held-out files: 'training' (same "
    "session: use the training frames and markers, no refit), 'register' (the "
    "instrument moved: refit its frame only), 'auto' (training when the file's name tag "
    "matches a training file's, else register).")]
TruthOpt = Annotated[str | None, typer.Option("--truth", help="Simulations: the true robot "
                                              "file, shown in the report.")]
AllParametersOpt = Annotated[bool, typer.Option("--all", help="List every parameter, not only "
                                                 "the estimated ones.")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Write the calibrated robot even when "
                                        "the calibration cannot be trusted (did not converge, "
                                        "or an estimate more than 10 tolerances from nominal); "
                                        "the exit status is still 1.")]


@app.command("calibrate")
@uses_setup
def calibrate_cmd(
    ctx: typer.Context, robot: OptionalRobotArg = None, data: OptionalDataOpt = None,
    output: OutputOpt = None, validate_files: ValidateOpt = None, report: ReportOpt = None,
    json_out: JsonOpt = None, urdf: UrdfOpt = None, procedure: ProcedureOpt = "lm",
    stages: StagesOpt = None, method: MethodOpt = "lm", loss: LossOpt = "linear",
    loss_scale: LossScaleOpt = 3.0, condition_growth: ConditionGrowthOpt = None,
    cycles: CyclesOpt = None, tolerance_text: ToleranceOpt = None, free: FreeOpt = None,
    fix: FixOpt = None, max_iter: MaxIterOpt = None, prior: PriorOpt = None,
    joint_model: JointModelOpt = None, cross_validate: CrossValidateOpt = None,
    select: SelectOpt = "none", folds: FoldsOpt = 10, split: SplitOpt = "auto",
    shared_marker: SharedMarkerOpt = False, scheduler: SchedulerOpt = None,
    workers: WorkersOpt = None, units: UnitsOpt = None,
    ignore: IgnoreOpt = None, validation_frames: CalibrationFramesOpt = "auto",
    truth: TruthOpt = None, all_parameters: AllParametersOpt = False, force: ForceOpt = False,
    base_link: BaseLink = None, tip_link: TipLink = None, si: SiOpt = False,
    config: ConfigOpt = None, hold: HoldOpt = None, instrument: InstrumentOpt = None,
    option: OptionOpt = None, joint_names: JointNamesOpt = None,
) -> None:
    """Calibrate ROBOT from measurement files: estimate the identifiable parameters, report
    errors before/after (training and held-out), write the calibrated robot, JSON and report.

    --config setup.yaml takes the robot, the files (each with its own reading options),
    the options and the outputs from a setup file (`kincal init` writes one).

    --procedure staged-selection follows the staged-selection procedure: angles (joint offsets,
    twists), then lengths, with an optional condition-number data selection; the JSON and
    report add its record and a comparison with one-stage Levenberg-Marquardt on the same
    data."""
    from kincal.measure.joints.terms import parse_joint_model
    from kincal.workflow import flow as wf
    from kincal.workflow.inputs import calibration_inputs
    from kincal.workflow.session import available_masses, read_session

    out = out_console(json_out)
    use_si(si)
    robot = require_robot(robot, "calibrate")
    if not data:
        raise KincalError("`kincal calibrate` needs --data FILE (or data: in the setup file)")
    r = held_robot(ctx, load(robot, base_link, tip_link), hold)
    if is_fivebar(r):
        from kincal.cli.fivebar import calibrate_fivebar_command

        calibrate_fivebar_command(ctx, r)
        return
    tolerance = length_option(tolerance_text, "--tolerance")
    from kincal.workflow.options import parse_prior_text

    prior_value = parse_prior_text(prior)            # the typed prior of the library
    wf.check_flow_options(procedure=procedure, method=method, loss=loss,
                          stages=wf.parse_stages(stages), validation_frames=validation_frames,
                          condition_growth=condition_growth, cycles=cycles,
                          tolerance=tolerance, prior=prior_value)
    if not (math.isfinite(loss_scale) and loss_scale > 0):
        raise KincalError(f"option --loss-scale: {loss_scale!r} is not a positive finite "
                          "number of standard deviations")
    train_src, held_src = as_sources(data, validate_files, units=units, ignore=ignore,
                                     instrument=instrument,
                                     options=[*(option or []), *joint_names_option(joint_names)])
    urdf = _urdf_output(robot, r, output, urdf)
    check_outputs({"-o": output, "--urdf": urdf, "--json": json_out, "--report": report},
                  {"--data": [s.path for s in train_src],
                   "--validate": [s.path for s in held_src],
                   "ROBOT": [robot] if Path(robot).is_file() else [],
                   "--truth": [truth] if truth else [], "--config": [config] if config else []})
    auto = select == "auto"
    if select not in ("auto", "none"):
        raise KincalError(f"option --select: {select!r} is not auto or none")
    session = read_session(r, train_src, held_src, joint_model=None if auto else joint_model,
                           spec=robot, base_link=base_link, tip_link=tip_link)
    print_ignored(out, session.blocks + session.holdouts)
    terms = session.terms
    masses, models = None, None
    if auto:
        models = [parse_joint_model(joint_model)] if joint_model else None
        masses = available_masses(robot, base_link, tip_link)
    truth_vals = wf.truth_values(truth) if truth else None
    bar_total = max_iter or max_iter_for(procedure)
    with Progress(bar_total, json_out != "-") as bar, fold_engine(scheduler, workers) as eng:
        flow = wf.run_flow(r, session.blocks, session.holdouts, free=free, fix=fix,
                           stages=wf.parse_stages(stages), method=method, loss=loss,
                           loss_scale=loss_scale, max_iter=max_iter,
                           validation_frames=validation_frames, procedure=procedure,
                           condition_growth=condition_growth, cycles=cycles,
                           tolerance=tolerance, prior=prior_value,
                           cross_validate=cross_validate, progress=bar, select=select,
                           folds=folds, masses=masses, joint_models=models,
                           mapper=bar.mapper_on(eng), shared_marker=shared_marker,
                           split=split)
    for n in flow.notes:
        out.print(f"[dim]{escape(n)}[/dim]")
    if flow.selection is not None:
        terms = flow.selection.choice.terms if flow.selection.choice else ()
        print_selection(out, flow.selection)
    inputs = calibration_inputs(
        robot=robot, data=[s.path for s in train_src], validation=[s.path for s in held_src],
        procedure=procedure, staged=procedure == "staged-selection", method=method,
        loss=loss, stages=stages, validation_frames=validation_frames, free=free, fix=fix,
        prior=prior, terms=terms, folds=folds if auto else None,
        condition_growth=condition_growth, cycles=cycles, tolerance=tolerance)
    from kincal.robots.controller import calibration_zero_shifts  # (kincal --help stays light)

    shifts = calibration_zero_shifts(r, flow.result.robot)      # None: no controller declared
    extra: dict[str, Any] = {"seconds": flow.seconds}
    if shifts is not None:
        extra["controller_zero_shifts"] = [z.to_dict() for z in shifts]
    written = wf.write_outputs(flow, output, urdf, json_out, report, inputs, truth_vals,
                               extra, force=force)
    _print_calibration(out, flow, terms, prior, all_parameters)
    for z in shifts or []:
        out.print(escape(z.line()))
    for k, v in written.items():
        out.print(f"{k}: {escape(v)}")
    _refuse_if_not_trusted(flow, written, (output, urdf), force)


def _refuse_if_not_trusted(flow: Any, written: dict[str, str],
                           outputs: tuple[str | None, ...], force: bool) -> None:
    """Exit 1 with the verdict's line when the calibration is not trusted, naming the robot
    files withheld (or written anyway under ``--force``)."""
    if flow.verdict is not None and not flow.trusted:
        withheld = [p for p in outputs if p and p not in written.values()]
        tail = (f"; no calibrated robot written ({', '.join(withheld)}; --force writes it)"
                if withheld else "; written anyway (--force)" if force and outputs[0] else "")
        raise CheckFailedError(flow.verdict.line() + tail)


def _urdf_output(spec: str, robot: Any, output: str | None, urdf: str | None) -> str | None:
    """``--urdf``, by default for URDF robots next to ``-o`` (``NAME_calibrated.urdf``
    where that would overwrite the robot's own file)."""
    if urdf is None and output and robot.meta.get("convention") == "urdf":
        urdf = str(Path(output).with_suffix(".urdf"))
        if Path(spec).is_file() and Path(urdf).resolve() == Path(spec).resolve():
            urdf = str(Path(output).with_name(Path(output).stem + "_calibrated.urdf"))
    return urdf


def _print_calibration(out: Console, flow: FlowResult, terms: Sequence[str],
                       prior: str | None, all_parameters: bool) -> None:
    """The run on the console: convergence, the prior and joint model in a sentence each,
    the parameter, error, held-out, cross-validation and identifiability tables, the
    weak parameters, the staged selection's record, warnings and outliers."""
    res = flow.result
    conv = "[green]converged[/green]" if res.converged else "[red]did not converge[/red]"
    out.print(f"{conv} in {res.iterations_text()} ({flow.seconds:.2f} s), "
              f"{len(res.estimated)} parameters estimated, sigma0 = {res.sigma0:.3g}")
    if res.prior:
        what = escape(prior) if prior else "default tolerances"
        if flow.tolerances is not None and flow.tolerances.scale != 1:
            what += f" x{flow.tolerances.scale:g}"
        noise = (f"; noise scale sigma0 = {res.sigma0:.3g} (residual / stated sigma) estimated "
                 "before the prior was weighed" if res.noise_scale_estimated else "")
        out.print(f"MAP estimate: {len(res.prior)} estimated parameter(s) have a Gaussian "
                  f"prior centred on their nominal value ({what}; column 'prior (1σ)'; "
                  f"--prior none for least squares){noise}.")
    if terms:
        out.print(escape(f"joint model: {', '.join(terms)} (parameters {{block}}.h[joint] "
                         "[rad, m] and {block}.k[joint] [rad/(N m), m/N] in the table and the "
                         "JSON; the robot file holds the geometry only)"))
    print_parameters(out, res, all_parameters)
    print_errors(out, [c for c in flow.comparisons if c.label != "validation"]
                 if flow.heldout else flow.comparisons)
    print_heldout(out, flow.heldout)
    if flow.cross_validation is not None:
        print_cross_validation(out, flow.cross_validation)
    print_identifiability(out, res)
    print_weak(out, flow.weak)
    if res.procedure_record is not None:
        print_staged_selection(out, res.procedure_record)
    for w in flow.warnings:
        out.print(f"[yellow]warning[/yellow]: {escape(w)}")
    if res.outliers:
        out.print(f"[yellow]{len(res.outliers)} outlier measurement(s)[/yellow]: " + ", ".join(
            f"{b} row {i + 1}" for b, i in res.outliers[:10]))


@app.command("validate")
def validate_cmd(
    robot: RobotArg, data: DataOpt,
    result: Annotated[str | None, typer.Option("--result", help="Result JSON of `kincal "
                                               "calibrate`: its instrument frames and markers "
                                               "(same session), the nominal robot's "
                                               "registration and the predicted accuracy."
                                               )] = None,
    nominal: Annotated[str | None, typer.Option("--before", help="The nominal robot, "
                                                "evaluated by the same protocol: the 'before' "
                                                "column.")] = None,
    validation_frames: Annotated[str, typer.Option(
        "--validation-frames", help="'training' (same session: the result's frames and "
        "markers, no refit), 'register' (the instrument moved: frame and marker refitted on "
        "each file, as far as it can identify them), 'auto' (training with --result, else "
        "register).")] = "auto",
    joint_model: JointModelOpt = None,
    iso9283: Annotated[bool, typer.Option("--iso9283", help="Also the ISO 9283 figures per "
                                          "position: pose accuracy AP, repeatability RP, "
                                          "distance accuracy AD (P2-P4). Rows at the same "
                                          "joint values are one position.")] = False,
    units: UnitsOpt = None, ignore: IgnoreOpt = None,
    base_link: BaseLink = None, tip_link: TipLink = None, si: SiOpt = False,
    json_out: JsonOpt = None,
    report: Annotated[str | None, typer.Option("--report", help="Write a single-file HTML "
                                               "report: the held-out rows before and after, "
                                               "the predicted accuracy (with --result) and, "
                                               "with --iso9283, the ISO 9283 figures.")
                      ] = None,
) -> None:
    """Errors of ROBOT on held-out measurements, one row per file and pooled: RMS before
    (the nominal robot, --before) and after, and, with --result, the predicted accuracy
    and the poses outside the calibrated region.

    Without --result each file's instrument parameters (frame and marker) are re-registered
    to each robot: they absorb a little of any robot error."""
    from kincal.io import write_json
    from kincal.measure.joints.terms import parse_joint_model, with_joint_model
    from kincal.workflow.flow import check_options_used
    from kincal.workflow.validation import validate_on_files

    out = out_console(json_out)
    use_si(si)
    check_outputs({"--json": json_out, "--report": report},
                  {"ROBOT": robot, "--data": data, "--result": result, "--before": nominal})
    if validation_frames not in ("auto", "training", "register"):
        raise KincalError(f"option --validation-frames: {validation_frames!r} is not auto, "
                          "training or register")
    if validation_frames == "training" and not result:
        raise KincalError("--validation-frames training needs --result (the frames come from "
                          "the calibration)")
    r = serial(load(robot, base_link, tip_link), "validate")
    before = serial(load(nominal, base_link, tip_link), "validate") if nominal else None
    terms = parse_joint_model(joint_model)
    if terms and not result:
        raise KincalError("--joint-model needs --result: the joint model's coefficients "
                          "come from the calibration")
    from kincal.workflow.session import joint_masses

    masses = joint_masses(robot, base_link, tip_link) if "compliance" in terms else None
    check_options_used(data, units, ignore)
    blocks = with_joint_model(read_blocks(data, r, units, ignore, out), r, terms, masses)
    if not terms:                   # the joint model the calibrated robot file carries
        from kincal.workflow.carried_joint_model import wrap_carried

        blocks = wrap_carried(blocks, r)
    from kincal.measure.data_checks import refuse_joint_data

    refuse_joint_data(r, blocks)                  # exit 1, one line, nothing written
    val = validate_on_files(r, blocks, before, result, validation_frames)
    print_heldout(out, val.files, f"Errors of {r.name} on held-out data")
    for w in val.warnings:
        out.print(f"[bold yellow]warning[/bold yellow]: {escape(w)}")
    if iso9283:
        val = dataclasses.replace(val, iso9283=_iso9283(out, r, before, blocks, val.extras))
    if json_out:
        write_json(json_out, val.to_dict())
    if report:
        _validation_report(report, r, val.files, val.accuracy, val.iso9283, {
            "robot": robot, "data": ", ".join(data), "result": result or "-",
            "before": nominal or "-", "frames": validation_frames})
        out.print(f"report: {escape(report)}")


def _validation_report(path: str, robot: Any, files: Any, accuracy: Any,
                       iso_doc: dict[str, Any] | None, inputs: dict[str, str]) -> None:
    """``kincal validate --report``: the calibration report's family for held-out data."""
    from kincal.io import atomic_write_text
    from kincal.report.html import render_validation_html
    from kincal.report.metrics import ErrorComparison
    from kincal.workflow.report_sections import heldout_section_html, iso9283_section_html

    comps = [ErrorComparison("validation", f.file, f.before, f.after, f.note) for f in files]
    sections = [heldout_section_html(files, accuracy)]
    if iso_doc:
        sections.append(iso9283_section_html(iso_doc))
    atomic_write_text(path, render_validation_html(
        f"kincal validation of {robot.name} on held-out data", comps, inputs, sections))


def _iso9283(out: Any, robot: Any, before: Any, blocks: Any, extras: Any) -> dict[str, Any]:
    """Print and return the ISO 9283 figures of every position block, before and after."""
    import math
    import warnings

    from kincal.cli.calibration_common import scaled
    from kincal.cli.options import console_units
    from kincal.identify.iso9283 import block_figures, group_positions
    from kincal.identify.validation import validate
    from kincal.measure.instruments.position import PositionMeasurement
    from kincal.workflow.carried_joint_model import carried_values, link_side
    from kincal.workflow.flow import block_values, reregister
    from kincal.workflow.heldout import evaluate_file

    doc: dict[str, Any] = {}
    for b in blocks:
        if not isinstance(link_side(b, robot, b.initial_guess(robot))[0],
                          PositionMeasurement):
            continue
        labels = group_positions(b.q)

        def figures(rob: Any, b: Any = b, labels: list[str] = labels) -> Any:
            if extras:
                with warnings.catch_warnings():    # printed once, by validate's own lines
                    warnings.simplefilter("ignore", UserWarning)
                    val = validate(rob, [b], extras=dict(extras))
                e = block_values(val["extras"][b.name], b)
            elif b is not link_side(b, rob, b.initial_guess(rob))[0]:   # a joint model
                known = carried_values(b, robot) if rob is robot else {}
                e = evaluate_file(None, rob, b, "register", known_after=known).values["after"]
            else:
                e = reregister(rob, b, None, None)
            return block_figures(rob, *link_side(b, rob, e), labels)

        after, dist_a = figures(robot)
        bef, dist_b = figures(before) if before is not None else (None, None)
        name = Path(b.source_label).name
        lf, L = console_units().scale("m")
        t = Table(title=f"ISO 9283 on {escape(name)} ({escape(robot.name)}"
                        + (f", before: {escape(before.name)})" if before is not None else ")"))
        cols = ["position", "cycles"] + ([f"AP before [{L}]"] if bef else []) + \
            [f"AP [{L}]", f"RP [{L}]"]
        for c in cols:
            t.add_column(escape(c), justify="left" if c == "position" else "right")
        for k, f in enumerate(after):
            row = [f.name, str(f.n)] + ([scaled(bef[k].AP, lf)] if bef else []) + \
                [scaled(f.AP, lf), scaled(f.RP, lf)]
            t.add_row(*row)
        out.print(t)
        entry: dict[str, Any] = {"after": [f.to_dict() for f in after]}
        if bef:
            entry["before"] = [f.to_dict() for f in bef]
        for label, dist in (("before", dist_b), ("after", dist_a)):
            if dist is not None:
                entry[f"distance_P2_P4_{label}"] = dist
                if label == "after" or dist_a is None:
                    out.print(f"distance P2-P4 ({label}): AD "
                              f"{scaled(dist.get('AD_m', math.nan), lf)} {L}, RD "
                              f"{scaled(dist['RD_m'], lf)} {L}")
        doc[name] = entry
    if not doc:
        raise KincalError("--iso9283 needs position measurements (x, y, z columns)")
    return doc
