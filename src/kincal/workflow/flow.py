"""The calibration workflow as plain functions: read data, calibrate, validate, write.

What ``kincal calibrate`` / ``validate`` / ``demo`` do, usable from Python::

    from kincal.robots.files import load_serial_robot
    from kincal.workflow.flow import read_blocks, run_flow, write_outputs

    robot = load_serial_robot("puma560")
    blocks = read_blocks(["train.csv"], robot)
    flow = run_flow(robot, blocks, read_blocks(["held.csv"], robot))
    write_outputs(flow, "calibrated.yaml", json_out="result.json", report="report.html")

* :func:`read_blocks` - measurement files, one block each, clashing names renamed;
* :func:`run_flow` - calibrate (``procedure="lm"``: :func:`~kincal.identify.solver.calibrate`;
  ``"staged-selection"``:
  :func:`~kincal.identify.staged_selection.calibrate_staged_selection`), then the errors
  before/after on the training and held-out data (:class:`~kincal.report.html.ErrorComparison`);
* :func:`validate_blocks` - errors of a robot on held-out files;
* :func:`write_outputs` - calibrated robot (YAML, URDF), result JSON, HTML report and,
  for artifact data, the bar-length figures, each rendered first and then written
  atomically (a failure while rendering writes nothing).

Option text is checked and parsed in :mod:`kincal.workflow.options` and the staged-selection /
artifact figure sections of the report are rendered in :mod:`kincal.workflow.report_sections`;
both are re-exported here.

Units are SI (m, rad) everywhere; the report shows mm and degrees.  Nothing here prints:
progress goes to an optional callback, warnings into :attr:`FlowResult.warnings`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.defaults import STAGE_TOLERANCE_M
from kincal.errors import KincalError
from kincal.identify.identifiability import NON_GEOMETRIC_ROLES
from kincal.identify.noise_floor import fit_with_floor
from kincal.workflow.options import (
    LOSSES,
    METHODS,
    PROCEDURES,
    STAGES,
    Prior,
    check_flow_options,
    check_options_used,
    parse_prior,
    parse_selection,
    parse_stages,
    prior_spec,
)
from kincal.workflow.report_sections import (
    artifact_figures,
    figures_section_html,
    staged_selection_section_html,
    trust_section_html,
)
from kincal.workflow.result import FlowResult

Array = NDArray[np.float64]

__all__ = ["FlowResult", "read_blocks", "ignored_columns", "check_options_used",
           "parse_selection", "parse_stages", "parse_prior", "check_flow_options", "run_flow",
           "validate_blocks", "reregister", "errors_with", "block_values", "truth_values",
           "extras_from_result", "render_outputs", "write_outputs", "staged_selection_section_html",
           "figures_section_html", "PROCEDURES", "METHODS", "LOSSES", "STAGES"]


# --------------------------------------------------------------------------- reading data
def read_blocks(paths: Sequence[str | Path], robot: Any, units: str | None = None,
                ignore: Sequence[str] | None = None) -> list[Any]:
    """Read measurement files (one block each), renaming blocks whose names clash.

    Args:
        paths: measurement CSV files (or folders of per-socket files).
        robot: the robot whose joints the files' joint columns name.
        units: ``--units`` text (``"x1=m,arm_1_joint=rad"``); each entry goes to the
            files whose columns it matches (an entry matching no file is an error).
        ignore: ``--ignore`` patterns, likewise per file.

    Every block's ``provenance`` names its file.  Raises one-line errors for bad files.
    :func:`kincal.workflow.sources.read_sources` reads files with options of their own.
    """
    from kincal.workflow.sources import read_sources, sources_from_options

    return read_sources(sources_from_options([str(p) for p in paths], units, ignore), robot)


def ignored_columns(blocks: Sequence[Any]) -> list[tuple[str, list[str]]]:
    """``(file, [column ...])`` of the columns each block's reader did not read."""
    out = []
    for b in blocks:
        table = b.provenance.table if b.provenance is not None else None
        if table is not None and table.ignored:
            out.append((b.source_label, list(table.ignored)))
    return out


# --------------------------------------------------------------------------- calibration
def errors_with(robot: Any, block: Any, extra: Array) -> dict[str, Array]:
    """Physical errors (``position_m`` ...) of ``block`` under ``robot`` with its parameters."""
    return {k: np.asarray(v, dtype=float) for k, v in block.errors(robot, extra).items()}


def _calibrate(robot: Any, blocks: list[Any], free_names: list[str] | None, fixed: list[str],
               procedure: str, progress: Callable[[Any], Any] | None,
               options: Mapping[str, Any]) -> Any:
    if procedure == "staged-selection":
        from kincal.identify.staged_selection import calibrate_staged_selection

        extra = {"max_iter": options["max_iter"]} if options.get("max_iter") else {}
        return calibrate_staged_selection(robot, blocks, free=free_names, fixed=fixed,
                                condition_growth=options.get("condition_growth"),
                                cycles=options.get("cycles"),
                                tolerance=options.get("tolerance") or STAGE_TOLERANCE_M,
                                progress=progress, compare=True, **extra)
    from kincal.identify.solver import calibrate

    return calibrate(robot, blocks, free=free_names, fixed=fixed, method=options["method"],
                     stages=options.get("stages"), loss=options["loss"],
                     loss_scale=options["loss_scale"], max_iter=options.get("max_iter") or 100,
                     progress=progress, prior=options.get("prior") or None,
                     prefer=options.get("prefer") or ())


def _calibrate_with_floor(robot: Any, blocks: list[Any], notes: list[str],
                          free_names: list[str] | None, fixed: list[str], procedure: str,
                          progress: Callable[[Any], Any] | None,
                          options: Mapping[str, Any]) -> tuple[Any, list[Any], list[str]]:
    """:func:`_calibrate`, then again with the unmodelled floor added to the stated
    variances of the blocks whose stated sigmas vary and leave a residual
    (:mod:`kincal.identify.noise_floor`): the result, the blocks it used, the notes."""
    res, blocks, floors = fit_with_floor(
        lambda bs: _calibrate(robot, bs, free_names, fixed, procedure, progress, options),
        blocks)
    return res, blocks, [*notes, *(f.sentence() for f in floors)]


def run_flow(robot: Any, blocks: list[Any], holdouts: Sequence[Any] = (), *,
             free: str | None = None, fix: str | None = None, stages: list[str] | None = None,
             method: str = "lm", loss: str = "linear", loss_scale: float = 3.0,
             max_iter: int | None = None, validation_frames: str = "auto",
             procedure: str = "lm", condition_growth: float | None = None,
             cycles: int | None = None, tolerance: float | None = None,
             prior: Prior = None, cross_validate: int | None = None,
             progress: Callable[[Any], Any] | None = None, select: str | None = None,
             folds: int = 10, masses: Sequence[Any] | None = None,
             joint_models: Sequence[Sequence[str]] | None = None,
             mapper: Callable[..., Any] = map, shared_marker: bool = False,
             split: str = "auto") -> FlowResult:
    """Calibrate, then compute the errors before/after on the training and held-out data.

    Args:
        robot: the nominal robot.
        blocks, holdouts: training and held-out measurement blocks.
        free, fix: ``--free`` / ``--fix`` patterns (names, ``*``, ``role:offset``).
        stages, method, loss, loss_scale: the one-stage solver's options
            (``procedure="lm"``).
        max_iter: iterations (lm: in all, default 100; staged-selection: per stage, default 20).
        validation_frames: ``auto`` | ``training`` | ``register`` (see below).
        procedure: ``lm`` (the one-stage solver) or ``staged-selection`` (two stages,
            :func:`~kincal.identify.staged_selection.calibrate_staged_selection`, with its
            comparison against one-stage LM).
        condition_growth: staged-selection only: discard a placement when the condition number
            grows by more than this factor (None: keep every placement).
        cycles: staged-selection only: passes through the stages (1 = a single pass;
            None = until converged).
        tolerance: staged-selection only: stop when no predicted point moves more than this [m]
            (default 1e-7 m).
        prior: typed (:data:`~kincal.workflow.options.Prior`; ``--prior`` text becomes
            one by :func:`~kincal.workflow.options.parse_prior_text`): None or
            ``"tolerances"``, ``"none"`` for plain least squares, a mapping ``{role, name or
            pattern: sigma [m / rad]}`` or a ``TolSpec`` whose entries override the
            parameters' manufacturing tolerances (role defaults, then the robot file's
            ``tolerances:``) and may scale them.  By default (``procedure="lm"``) the
            calibration is the maximum a-posteriori estimate with Gaussian priors of
            these standard deviations centred on the nominal values, the noise scale
            estimated first.  The tolerances also bound what is plausible (``FlowResult.verdict``).
        cross_validate: K-fold cross-validation of the same calibration on the training
            data (the fold tasks of :mod:`~kincal.identify.validation`, folds drawn with
            seed 0; one training block, ``procedure="lm"``): how well the chosen model
            predicts measurements it was not fitted to, from the training data alone.
        progress: called with every :class:`~kincal.identify.solver.IterationRecord`.
        select: ``"auto"``: choose the joint model and the prior scale by ``folds``-fold
            cross-validation on the training blocks
            (:func:`~kincal.identify.selection.select_model`), then fit the winner.  The
            blocks (and held-out blocks) must then be plain, without a joint model: each
            candidate wraps them in its own.  ``masses`` (link masses) adds the
            compliance candidates; ``joint_models`` restricts the joint models tried; a
            ``--prior`` with ``none`` or ``scale=K`` pins the prior scale.
        folds, split: K of ``select`` (default 10), what a fold holds out (``auto``, ``random``).
        shared_marker: the training (and held-out) files see one physical tool point:
            it becomes the robot's tool origin, one set of parameters
            (:func:`~kincal.workflow.shared.share_tool_point`).
        mapper: runs the selection's and the cross-validation's fold tasks
            (:func:`~kincal.identify.selection.run_fold`): the builtin ``map``, an
            executor's ``map`` or a Dask client's ``map``.

    *Before* = the nominal robot with the instruments registered to it (only the
    blocks' own parameters fitted: the "registration only" baseline); *after* = the
    calibrated robot with the frames estimated with it.  The training errors use the
    blocks the solver used (``result.problem.blocks``: after the procedure's selection,
    only the kept placements).

    Held-out blocks, for both robots:

    * **same session** (``validation_frames="training"``, or ``"auto"`` when the file's
      tag names a training block, e.g. ``name=tracker`` in both files): every block
      parameter comes from training, nothing is refitted (FIGAROH's protocol);
    * otherwise (``"register"``, or ``"auto"`` for a file without a name tag or with
      another name): the instrument moved, so only its frame (role ``instrument``) is
      fitted on the held-out data; the marker / target comes from the training block
      of the same kind (when there is one), so it cannot absorb robot errors.

    A same-session block whose errors are more than 5x those after re-registering the
    frame raises a warning (the instrument probably moved).
    """
    check_flow_options(procedure=procedure, method=method, loss=loss, stages=stages,
                       validation_frames=validation_frames, condition_growth=condition_growth,
                       cycles=cycles, tolerance=tolerance, prior=prior)
    _check_validation_options(procedure, cross_validate, select, split)
    robot, blocks, holdouts, notes = _share_marker(robot, blocks, holdouts, shared_marker)
    free_names, fixed, tols = _selection_and_tolerances(robot, blocks, free, fix, prior)
    prefer = [f"tool.{c}" for c in "xyz"] if shared_marker else []
    solver_options = {"free": free_names, "fixed": fixed, "method": method, "stages": stages,
                      "loss": loss, "loss_scale": loss_scale, "max_iter": max_iter or 100,
                      "prefer": prefer}
    selection, warnings = None, list[str]()
    if select == "auto":
        selection, blocks, holdouts, tols = _select_model(
            robot, blocks, list(holdouts), tols, prior, folds, masses, joint_models, mapper,
            solver_options, warnings, split)
    prior_s = tols.prior() if procedure == "lm" else {}
    options = {"method": method, "stages": stages, "loss": loss, "loss_scale": loss_scale,
               "max_iter": max_iter, "condition_growth": condition_growth, "cycles": cycles,
               "tolerance": tolerance, "prior": prior_s, "prefer": prefer}
    t0 = time.perf_counter()
    res, blocks, notes = _calibrate_with_floor(robot, blocks, notes, free_names, fixed,
                                               procedure, progress, options)
    seconds = time.perf_counter() - t0
    cv = _cross_validation_summary(robot, blocks, selection, cross_validate, tols.sigma,
                                   {**solver_options, "prior": prior_s or None}, mapper)
    train, before, after, comps = _training_comparison(robot, res)
    accuracy = _accuracy_outside(robot, blocks, res, _accuracy(res, cv, before, tols.sigma)
                                 if procedure == "lm" else None, comps, warnings,
                                 (free_names, fixed, options))
    heldout: list[Any] = []
    if holdouts:
        comp, heldout = _holdout_comparison(robot, res.robot, train, list(holdouts), before,
                                            after, validation_frames, warnings, accuracy)
        comps.append(comp)
    from kincal.identify.weak import weak_parameters

    verdict = _verdict(res, tols, robot, [*blocks, *holdouts], warnings)
    return FlowResult(res, comps, seconds, warnings, robot, train, before, after, cv,
                      tolerances=tols, verdict=verdict,
                      weak=weak_parameters(res), selection=selection, accuracy=accuracy,
                      heldout=heldout, notes=notes)


def _verdict(res: Any, tols: Any, robot: Any, blocks: Sequence[Any], warnings: list[str]
             ) -> Any:
    """The trust verdict (:func:`~kincal.identify.checks.judge`) with the files' joint
    data checked; its warnings join ``warnings``."""
    from kincal.identify.checks import judge

    verdict = judge(res, tols.sigma, data=_joint_data(robot, blocks))
    warnings += verdict.warnings()
    return verdict


def _joint_data(robot: Any, blocks: Sequence[Any]) -> list[str]:
    """The one-line problems of the training and held-out files' joint readings
    (:mod:`kincal.measure.data_checks`), for the verdict."""
    from kincal.measure.data_checks import block_joint_problems, joint_data_line

    line = joint_data_line(block_joint_problems(robot, blocks))
    return [line] if line else []


def _share_marker(robot: Any, blocks: list[Any], holdouts: Sequence[Any], shared: bool
                  ) -> tuple[Any, list[Any], list[Any], list[str]]:
    """With ``shared``, the blocks' markers become the robot's tool origin
    (:func:`~kincal.workflow.shared.share_tool_point`); returns the notes to report."""
    if not shared:
        return robot, blocks, list(holdouts), []
    from kincal.workflow.shared import share_tool_point

    robot, blocks, kept, note = share_tool_point(robot, blocks, list(holdouts))
    return robot, blocks, kept, [note]


def _selection_and_tolerances(robot: Any, blocks: Sequence[Any], free: str | None,
                              fix: str | None, prior: Prior
                              ) -> tuple[list[str] | None, list[str], Any]:
    """The free and fixed parameter names of ``--free``/``--fix`` and the tolerances
    (``--prior``) of the stacked problem."""
    from kincal.identify.checks import require_free
    from kincal.measure.base import stack

    prob, _ = stack(robot, blocks)
    free_names, fixed = parse_selection(prob.names, prob.roles, free, fix)
    require_free(prob.names, free_names, fixed, free, fix)
    return free_names, fixed, tolerances_of(robot, prob, prior)


def _check_validation_options(procedure: str, cross_validate: int | None,
                              select: str | None, split: str = "auto") -> None:
    """``--cross-validate`` (lm only, at least 2 folds), ``--select`` (auto or none) and
    ``--split`` (auto or random)."""
    from kincal.identify.region_folds import SPLITS

    if split not in SPLITS:
        raise KincalError(f"option --split: {split!r} is not {' or '.join(SPLITS)}")
    if cross_validate is not None:
        if procedure != "lm":
            raise KincalError("--cross-validate works with --procedure lm")
        if cross_validate < 2:
            raise KincalError(f"option --cross-validate: needs at least 2 folds (got "
                              f"{cross_validate})")
    if select not in (None, "none", "auto"):
        raise KincalError(f"option --select: {select!r} is not auto or none")
    if select == "auto" and procedure != "lm":
        raise KincalError("--select auto works with --procedure lm")


def _cross_validation_summary(robot: Any, blocks: Sequence[Any], selection: Any,
                              cross_validate: int | None, sigma: Any,
                              solver_options: Mapping[str, Any],
                              mapper: Callable[..., Any]) -> dict[str, Any] | None:
    """The cross-validated RMS errors of the fitted model: those of the selection's
    winner, or a ``cross_validate``-fold run of the same calibration (folds drawn with
    seed 0), or None when neither was asked."""
    if selection is not None and selection.chosen is not None:
        i = selection.chosen
        from kincal.identify.selection import split_kind

        return {"folds": selection.folds, "seed": selection.seed,
                "split": selection.split_by or split_kind(blocks),
                "model": selection.candidates[i].label,
                **{f"rms_{k}": v for k, v in selection.rms_all[i].items()}}
    if cross_validate is None:
        return None
    from kincal.identify.selection import Candidate, fold_units, gather_folds, split_kind

    parts, _ = fold_units(blocks, cross_validate, 0)
    if all(p is None for p in parts):
        raise KincalError(f"--cross-validate {cross_validate}: no training file has "
                          f"{cross_validate} rows or placements to hold out")
    got = gather_folds(robot, [blocks], [Candidate()], parts, sigma, solver_options, mapper)
    return {"folds": cross_validate, "seed": 0, "split": split_kind(blocks),
            **{f"rms_{k}": v for k, v in got[0].items()}}


def _training_comparison(robot: Any, res: Any) -> tuple[list[Any], dict[str, Array],
                                                        dict[str, Array], list[Any]]:
    """The blocks the solver used, their own parameters before (fitted to the nominal
    robot) and after (estimated with the calibrated robot), and the training errors."""
    from kincal.report.metrics import ErrorComparison, merge_errors

    train = list(res.problem.blocks)    # thinned copies keep their provenance
    before = {b.name: reregister(robot, b, None, None) for b in train}
    after = {b.name: res.theta[res.problem.block_slice(b.name)] for b in train}
    comps = [ErrorComparison(
        "train", "train" + _files(train),
        merge_errors([errors_with(robot, b, before[b.name]) for b in train]),
        merge_errors([errors_with(res.robot, b, after[b.name]) for b in train]),
        "before: nominal robot, instrument frames and markers fitted to it; after: "
        "calibrated robot and frames")]
    return train, before, after, comps


def _accuracy(res: Any, cv: Mapping[str, Any] | None,
              before: Mapping[str, Array] | None = None,
              tolerances: Mapping[str, float] | None = None) -> Any:
    """The calibration's :class:`~kincal.identify.accuracy.AccuracyModel`, with the
    instrument registered to the nominal robot (``before``) and the robot parameters'
    ``tolerances`` (the nominal robot's predicted error); its floor from the
    cross-validated position RMS when cross-validation ran."""
    from kincal.identify.accuracy import accuracy_model, floor_from_cross_validation

    try:
        model = accuracy_model(res)
    except (KincalError, ValueError, IndexError):
        return None
    if tolerances is not None:
        model = dataclasses.replace(model, tolerances={
            n: float(v) for n, v in tolerances.items() if n in res.robot.param_names})
    inst = model.instrument
    if isinstance(inst, dict) and before and inst["block"] in before:
        inst["nominal_values"] = [float(v) for v in np.asarray(before[inst["block"]])[:9]]
    rms = (cv or {}).get("rms_position_m")
    if rms is not None and model.region is not None:
        q = np.vstack([np.asarray(b.q, dtype=float) for b in res.problem.blocks])
        model = model.with_floor(floor_from_cross_validation(model, res.robot, q, rms),
                                 "cross-validation")
    return model


def _accuracy_outside(robot: Any, blocks: list[Any], res: Any, accuracy: Any,
                      comps: Sequence[Any], warnings: list[str],
                      fit_options: tuple[Any, list[str], Mapping[str, Any]]) -> Any:
    """The accuracy model with the floor's growth outside the training region, measured
    by the region test on the training data (same fit options), and the extrapolation
    warning before use (appended to ``warnings``;
    :mod:`~kincal.identify.extrapolation`)."""
    if accuracy is None:
        return None
    from kincal.identify.extrapolation import extrapolation_warning, region_test

    free_names, fixed, options = fit_options
    test = region_test(robot, blocks, lambda bl: _calibrate(
        robot, bl, free_names, fixed, "lm", None, options))
    accuracy = accuracy.with_floor_growth(test.floor_growth_m if test else None)
    e0 = comps[0].before.get("position_m", comps[0].before.get("coincidence_m"))
    nominal = 0.0 if e0 is None else float(np.sqrt(np.mean(np.square(e0))))
    warning = extrapolation_warning(accuracy, res.robot, test, nominal)
    if warning:
        warnings.append(warning)
    return accuracy


def _select_model(robot: Any, blocks: list[Any], holdouts: list[Any], tols: Any,
                  prior: Prior, folds: int, masses: Sequence[Any] | None,
                  joint_models: Sequence[Sequence[str]] | None, mapper: Callable[..., Any],
                  options: Mapping[str, Any], warnings: list[str], split: str = "auto"
                  ) -> tuple[Any, list[Any], list[Any], Any]:
    """``--select auto``: the selection, the blocks inside the chosen joint model, and the
    tolerances with the chosen prior scale (appends to ``warnings``)."""
    from kincal.identify.selection import JOINT_MODELS, PRIOR_SCALES, candidates, select_model
    from kincal.measure.joints.deflection import JointDeflection
    from kincal.measure.joints.terms import with_joint_model

    if any(isinstance(b, JointDeflection) for b in [*blocks, *holdouts]):
        raise KincalError("--select auto chooses the joint model itself: give the blocks "
                          "without one (joint_models= restricts the models it tries)")
    spec = prior_spec(prior)
    scales: Sequence[float | None] = PRIOR_SCALES
    if not spec.use_prior:
        scales = [None]
    elif spec.scale_given:
        scales = [spec.scale]
    models = [tuple(m) for m in joint_models] if joint_models else list(JOINT_MODELS)
    cands = candidates(bool(masses), scales, models)
    if not cands:
        raise KincalError("--select auto: no candidate model (compliance needs link masses)")
    sel = select_model(robot, blocks, tols.sigma, cands, masses=masses, folds=folds,
                       mapper=mapper, split=split, **dict(options))
    choice = sel.choice
    if choice is None:
        choice = cands[0]
        warnings.append("--select auto: " + "; ".join(sel.notes) + f"; fitting {choice.label}")
    terms = choice.terms
    if terms:
        blocks = with_joint_model(blocks, robot, terms, masses)
        holdouts = with_joint_model(holdouts, robot, terms, masses)
    return sel, blocks, holdouts, tols.with_scale(choice.scale)


def tolerances_of(robot: Any, prob: Any, prior: Prior = None) -> Any:
    """The manufacturing tolerances of a calibration problem's parameters: role defaults,
    the robot file's ``tolerances:`` section, then the entries of ``prior``
    (:func:`~kincal.identify.tolerances.resolve_tolerances`)."""
    from kincal.identify.tolerances import resolve_tolerances

    meta = getattr(robot, "meta", {}) or {}
    return resolve_tolerances(prob.names, prob.units, prob.roles, meta.get("tolerances"),
                              prior_spec(prior), robot_source=str(meta.get("file", robot.name)))


def _holdout_comparison(nominal: Any, calibrated: Any, train: list[Any], holdouts: list[Any],
                        before: dict[str, Array], after: dict[str, Array], frames: str,
                        warnings: list[str], accuracy: Any = None) -> tuple[Any, list[Any]]:
    """The pooled ``validation`` comparison of :func:`run_flow` and one
    :class:`~kincal.workflow.heldout.HeldOutFile` per held-out block (appends to
    ``warnings``)."""
    from kincal.report.metrics import ErrorComparison, merge_errors
    from kincal.workflow.heldout import before_lines, evaluate_file, map_values

    files = []
    default = frames
    for h in holdouts:
        source = h.provenance.source if h.provenance is not None else None
        frames = (source.frames if source is not None else None) or default
        twin = _training_twin(h, train)
        if frames == "training" and twin is None:
            raise KincalError(f"held-out block {h.name!r} has no training block of its "
                              "kind to take frames from")
        same = twin is not None and (frames == "training" or (
            frames == "auto" and twin.name == h.name and _explicit_name(h)))
        tb = before.get(twin.name) if twin is not None else None
        ta = after.get(twin.name) if twin is not None else None
        got = evaluate_file(nominal, calibrated, h, "training" if same else "register",
                            known_before=map_values(h, twin, tb),
                            known_after=map_values(h, twin, ta), accuracy=accuracy)
        if got.warning:
            warnings.append(got.warning)
        files.append(got)
    notes = "; ".join(f"{f.file}: {f.note}" for f in files)
    comp = ErrorComparison("validation", "held-out" + _files(holdouts),
                           merge_errors([f.before for f in files]),
                           merge_errors([f.after for f in files]),
                           "\n".join([notes, *before_lines(f.protocol for f in files)]))
    return comp, files


def _explicit_name(block: Any) -> bool:
    """True when the block's name came from its file's tag (not a default)."""
    table = block.provenance.table if block.provenance is not None else None
    return table is None or "name" in table.tags


def _training_twin(h: Any, blocks: Sequence[Any]) -> Any:
    """The training block measured like ``h``: same name, else the only one of its kind."""
    for b in blocks:
        if b.name == h.name and type(b) is type(h):
            return b
    kind = [b for b in blocks if type(b) is type(h)]
    return kind[0] if len(kind) == 1 else None


def reregister(robot: Any, h: Any, twin: Any, twin_values: Array | None) -> Array:
    """Fit ``h``'s instrument frame to ``robot`` (held fixed); other block parameters from
    the training twin when it has them (matched by name after the block prefix).  Without
    a twin every block parameter is fitted (the "registration only" fit) except the
    non-geometric joint model's (compliance, hysteresis), held at 0."""
    from kincal.identify.solver import calibrate

    spec = h.parameters()
    known: dict[str, float] = {}
    if twin is not None and twin_values is not None:
        tspec = twin.parameters()
        known = {n[len(twin.name) + 1:]: float(v)
                 for n, v, r in zip(tspec.names, twin_values, tspec.roles, strict=True)
                 if r != "instrument"}
    init, free = {}, []
    for n, role in zip(spec.names, spec.roles, strict=True):
        suffix = n[len(h.name) + 1:]
        if role != "instrument" and suffix in known:
            init[n] = known[suffix]
        elif role in NON_GEOMETRIC_ROLES:
            init[n] = 0.0           # no calibrated joint model: the encoders as they read
        else:
            free.append(n)
    if not free:
        return np.array([init[n] for n in spec.names], dtype=float)
    res = calibrate(robot, [h], free=free, initial=init or None, tol_step=1e-12, max_iter=200)
    return res.theta[res.problem.slices[0]]


def block_values(values: Mapping[str, float], block: Any) -> Array:
    """A block's parameter vector from ``{name: value}`` (in the block's order)."""
    return np.array([values[n] for n in block.parameters().names])


def _files(blocks: Sequence[Any]) -> str:
    names = [Path(b.provenance.path).name if b.provenance is not None else ""
             for b in blocks]
    names = [n for n in names if n]
    return f" ({', '.join(names)})" if names else ""


# --------------------------------------------------------------------------- validation


def validate_blocks(robot: Any, blocks: Sequence[Any], before: Any = None,
                    extras: Mapping[str, float] | None = None,
                    protocol: str | None = None,
                    before_extras: Mapping[str, float] | None = None,
                    accuracy: Any = None) -> list[Any]:
    """Errors of ``robot`` (and of the nominal robot ``before``) on held-out blocks, one
    :class:`~kincal.workflow.heldout.HeldOutFile` each (``.before``, ``.after``, ``.note``).

    The same protocols and the same "before" as ``calibrate --validate``
    (:mod:`kincal.workflow.heldout`): with ``extras`` (``{parameter: value}`` from a
    result JSON) the same session, every block parameter as estimated (``protocol``
    ``"register"`` refits frame and marker from them instead); the nominal robot then
    gets the frames of ``before_extras`` (the JSON's ``before_parameters``; refitted
    on the file when absent).  Without ``extras``, each block's frame and marker are
    re-registered to each robot on the file.  ``accuracy``: the calibration's
    :class:`~kincal.identify.accuracy.AccuracyModel`, for the predicted accuracy.
    """
    from kincal.workflow.carried_joint_model import carried_values
    from kincal.workflow.heldout import evaluate_file, known_by_name

    if protocol is None or protocol == "auto":
        protocol = "training" if extras is not None else "register"
    out = []
    for b in blocks:
        after = known_by_name(b, extras)
        proto = protocol if after or protocol != "training" else "register"
        after = {**carried_values(b, robot), **after}    # the file's joint model, if any
        got = evaluate_file(before, robot, b, proto, known_before=known_by_name(
            b, before_extras), known_after=after, accuracy=accuracy)
        if protocol == "training" and not before_extras and before is not None and \
                got.protocol == "training":
            got.note += ("; the result has no nominal registration: the nominal robot's "
                         "frames were fitted on this file")
        out.append(got)
    return out


def truth_values(path: str | Path) -> dict[str, float]:
    """True parameter values from a robot file (and instrument truth from its notes)."""
    from kincal.robots.files import load_serial_robot

    t = load_serial_robot(path)
    vals = {n: float(v) for n, v in zip(t.param_names, t.param_values, strict=True)}
    note = str(getattr(t, "meta", {}).get("notes", ""))
    if "instrument truth:" in note:
        for part in note.split("instrument truth:", 1)[1].split(","):
            if "=" in part:
                k, v = part.split("=", 1)
                try:
                    vals[k.strip()] = float(v)
                except ValueError:
                    pass
    return vals


def result_document(path: str | Path) -> dict[str, Any]:
    """A result JSON written by ``kincal calibrate`` (one-line errors)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise KincalError("no such result file", source=str(path)) from None
    except ValueError as exc:
        raise KincalError(f"not a kincal result JSON ({exc})", source=str(path)) from None
    if not isinstance(doc, dict):
        raise KincalError("not a kincal result JSON", source=str(path))
    return doc


def accuracy_from_result(path: str | Path, robot: Any) -> Any:
    """The :class:`~kincal.identify.accuracy.AccuracyModel` of a result JSON written by
    ``kincal calibrate --json`` (its ``accuracy_model``; older files holding only the
    robot parameters' covariance and the training joint ranges read too), checked
    against the calibrated ``robot``: one-line errors naming the file."""
    from kincal.identify.accuracy import AccuracyModel

    doc = result_document(path)
    if not isinstance(doc.get("accuracy_model"), dict):
        raise KincalError("has no accuracy_model (written by `kincal calibrate --json`)",
                          source=str(path))
    model = AccuracyModel.from_dict(doc["accuracy_model"], str(path))
    missing = [n for n in model.parameters if n not in robot.param_names]
    if missing:
        raise KincalError(f"its accuracy model is for another robot (no parameter "
                          f"{missing[0]!r} in {robot.name!r})", source=str(path))
    region = model.region
    if region is not None and tuple(region.joint_names) != tuple(robot.joint_names):
        raise KincalError(f"its accuracy model is for another robot (joints "
                          f"{', '.join(region.joint_names)}, not those of {robot.name!r})",
                          source=str(path))
    return model


def extras_from_result(path: str | Path, which: str = "estimate") -> dict[str, float]:
    """``{parameter: value}`` of a result JSON written by ``kincal calibrate``.

    ``which="estimate"``: every parameter's estimate (the calibrated robot and its
    instrument frames); ``"before"``: the instrument parameters fitted with the nominal
    robot on the training data (``before_parameters``; ``{}`` in older files).
    """
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        if which == "before":
            return {str(k): float(v) for k, v in dict(doc.get("before_parameters") or {}
                                                      ).items()}
        return {p["name"]: float(p["estimate"]) for p in doc["parameters"]}
    except FileNotFoundError:
        raise KincalError("no such result file", source=str(path)) from None
    except IsADirectoryError:
        raise KincalError("is a folder, not a result JSON", source=str(path)) from None
    except UnicodeDecodeError:
        raise KincalError("not a kincal result JSON (not UTF-8 text)", source=str(path)) \
            from None
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise KincalError(f"not a kincal result JSON ({exc.__class__.__name__}: "
                          f"{str(exc).splitlines()[0] if str(exc) else ''})",
                          source=str(path)) from None


# --------------------------------------------------------------------------- outputs
def _render_report(result: Any, comparisons: Sequence[Any], inputs: Mapping[str, str],
                   truth: Mapping[str, float] | None, sections: Sequence[str],
                   notice: str = "") -> str:
    """:func:`kincal.report.html.render_html` with extra sections before the footer."""
    from kincal.report.html import render_html

    return render_html(result, comparisons, inputs=inputs, truth=truth,
                       extra_sections=list(sections), notice=notice)


def _untrusted_notice(flow: FlowResult, force: bool, planned: Mapping[str, str]) -> str:
    """The sentence outputs carry when the calibration cannot be trusted ("" otherwise)."""
    if flow.trusted:
        return ""
    files = [planned[k] for k in ("robot", "urdf") if planned.get(k)]
    what = ""
    if files:
        what = (f"; written anyway (--force): {', '.join(files)}" if force else
                f"; no calibrated robot written ({', '.join(files)}; --force writes it)")
    assert flow.verdict is not None           # not trusted: there is a verdict
    return flow.verdict.line() + what


def carrying_envelope(flow: FlowResult) -> tuple[Any, dict[str, Any] | None]:
    """The calibrated robot carrying its envelope (:mod:`kincal.identify.envelope`: the
    accuracy model with the training region, the training files' hashes, date, version)
    and that envelope's document; without an accuracy model the robot carries none (not
    even the one its nominal file may have had)."""
    from kincal.identify.envelope import make_envelope, with_envelope
    from kincal.workflow.carried_joint_model import (
        joint_model_document,
        with_joint_model_document,
    )

    robot = flow.result.robot
    jm = joint_model_document(flow.train, flow.after, flow.nominal, robot)   # beside it
    if flow.accuracy is None:
        return with_joint_model_document(with_envelope(robot, None), jm), None
    paths: dict[str, int] = {}
    for b in flow.train:
        prov = getattr(b, "provenance", None)
        if prov is not None and prov.path:
            path = str(prov.path)
            paths[path] = paths.get(path, 0) + len(np.atleast_1d(getattr(b, "q", [])))
    env = make_envelope(flow.accuracy, robot, list(paths), list(paths.values()))
    return with_joint_model_document(with_envelope(robot, env), jm), env.to_dict()


def render_outputs(flow: FlowResult, output: str | None = None, urdf: str | None = None,
                   json_out: str | None = None, report: str | None = None,
                   inputs: Mapping[str, str] | None = None,
                   truth: Mapping[str, float] | None = None,
                   extra: Mapping[str, Any] | None = None, force: bool = False
                   ) -> tuple[dict[str, str], dict[str, str | bytes]]:
    """Render every output of a calibration in memory.

    Returns ``(planned, contents)``: ``planned`` maps ``robot``, ``urdf``, ``report``,
    ``json`` and each figure key to its path; ``contents`` maps the same keys to the
    text (or PNG bytes) to write.  A URDF robot's ``urdf`` entry is None: it is
    written by :func:`~kincal.robots.urdf.write_calibrated_urdf` from the original file.

    A calibration that cannot be trusted (``flow.verdict``) plans no calibrated robot
    (YAML, URDF) unless ``force``; its JSON and report say so (``verdict``,
    ``not_written``, a notice under the report's title).
    """
    from kincal.io import _jsonable
    from kincal.report.metrics import result_json
    from kincal.robots.files import robot_yaml_text

    res = flow.result
    calibrated, envelope = carrying_envelope(flow)
    inputs = dict(inputs or {})
    planned = {k: v for k, v in (("robot", output), ("urdf", urdf), ("report", report)) if v}
    notice = _untrusted_notice(flow, force, planned)
    withheld = {}
    if not flow.trusted and not force:
        withheld = {k: planned.pop(k) for k in ("robot", "urdf") if k in planned}
        output = urdf = None
    contents: dict[str, str | bytes] = {}
    info = res.procedure_record
    figures = artifact_figures(flow, report) if report else {}
    for key, (path, png) in figures.items():
        planned[key] = path
        contents[key] = png
    if report:
        units = dict(zip(res.names, res.problem.units, strict=True))
        sections = ([staged_selection_section_html(info, figures, units)] if info is not None else
                    [figures_section_html(figures)] if figures else [])
        sections = [trust_section_html(flow), *sections]
        contents["report"] = _render_report(res, flow.comparisons, inputs, truth, sections,
                                            notice)
    if output:
        contents["robot"] = robot_yaml_text(calibrated)
    if urdf and res.robot.meta.get("convention") != "urdf":
        from kincal.robots.urdf import urdf_text

        contents["urdf"] = urdf_text(calibrated)[0]
    if json_out:
        more = dict(extra or {})
        if info is not None:
            more["staged_selection"] = info.to_dict()
        doc = result_json(res, flow.comparisons, {"inputs": inputs, **more})
        if flow.cross_validation is not None:
            doc["metrics"]["cross_validation"] = dict(flow.cross_validation)
        if flow.verdict is not None:
            doc["verdict"] = {**flow.verdict.to_dict(), "notice": notice}
        if flow.tolerances is not None:
            doc["tolerances"] = flow.tolerances.to_dict()
        doc["held_by_prior"] = [w.to_dict() for w in flow.weak]
        doc["warnings"] = list(flow.warnings)
        if flow.accuracy is not None:
            doc["accuracy_model"] = flow.accuracy.to_dict()
        if envelope is not None:
            doc["envelope"] = envelope
        if flow.heldout:
            from kincal.workflow.heldout import BEFORE_DEFINITION

            doc["metrics"]["validation_files"] = [f.metrics() for f in flow.heldout]
            doc["metrics"]["validation"]["before_definition"] = BEFORE_DEFINITION
            doc["metrics"]["validation"]["files"] = len(flow.heldout)
        if flow.selection is not None:
            doc["selection"] = flow.selection.to_dict()
        doc["before_parameters"] = {
            n: float(v) for b in flow.train if b.name in flow.before
            for n, v in zip(b.parameters().names, flow.before[b.name], strict=True)}
        doc["outputs"] = dict(planned)
        if withheld:
            doc["not_written"] = withheld
        contents["json"] = json.dumps(doc, indent=2, default=_jsonable) + "\n"
        planned["json"] = json_out
    return planned, contents


def write_outputs(flow: FlowResult, output: str | None = None, urdf: str | None = None,
                  json_out: str | None = None, report: str | None = None,
                  inputs: Mapping[str, str] | None = None,
                  truth: Mapping[str, float] | None = None,
                  extra: Mapping[str, Any] | None = None, force: bool = False
                  ) -> dict[str, str]:
    """Render everything (:func:`render_outputs`), then write each file atomically, the
    JSON last, so a failure while rendering leaves no output behind.

    A calibration that cannot be trusted writes no calibrated robot (YAML, URDF) unless
    ``force``.  Returns ``{what: path}`` of the files written (``robot``, ``urdf``,
    ``report``, figure keys).
    """
    from kincal.io import atomic_write_bytes, atomic_write_text

    planned, contents = render_outputs(flow, output, urdf, json_out, report, inputs, truth,
                                       extra, force)
    if not flow.trusted and not force:
        urdf = None
    for key, path in planned.items():
        if key == "json" or key not in contents:
            continue
        data = contents[key]
        if isinstance(data, bytes):
            atomic_write_bytes(path, data)
        else:
            atomic_write_text(path, data)
    calibrated = carrying_envelope(flow)[0]
    if urdf and "urdf" not in contents:
        from kincal.robots.urdf import write_calibrated_urdf

        write_calibrated_urdf(None, calibrated, urdf)
    if urdf:
        from kincal.robots.files import write_envelope_sidecar

        write_envelope_sidecar(calibrated, urdf)
    if json_out:
        atomic_write_text(json_out, str(contents["json"]))
    return {k: v for k, v in planned.items() if k != "json"}
