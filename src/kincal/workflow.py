"""The calibration workflow as plain functions: read data, calibrate, validate, write.

What ``kincal calibrate`` / ``validate`` / ``demo`` do, usable from Python::

    from kincal.robots.files import load_robot
    from kincal.workflow import read_blocks, run_flow, write_outputs

    robot = load_robot("puma560")
    blocks = read_blocks(["train.csv"], robot)
    flow = run_flow(robot, blocks, read_blocks(["held.csv"], robot))
    write_outputs(flow, "calibrated.yaml", json_out="result.json", report="report.html")

* :func:`read_blocks` - measurement files, one block each, clashing names renamed;
* :func:`run_flow` - calibrate (``procedure="lm"``: :func:`~kincal.identify.solver.calibrate`;
  ``"patent"``: :func:`~kincal.identify.patent.calibrate_patent`), then the errors
  before/after on the training and held-out data (:class:`~kincal.report.ErrorComparison`);
* :func:`validate_blocks` - errors of a robot on held-out files;
* :func:`write_outputs` - calibrated robot (YAML, URDF), result JSON, HTML report and,
  for artifact data, the patent's figures 4 and 5, each rendered first and then written
  atomically (a failure while rendering writes nothing).

Units are SI (m, rad) everywhere; the report shows mm and degrees.  Nothing here prints:
progress goes to an optional callback, warnings into :attr:`FlowResult.warnings`.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import json
import math
import re
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError

Array = NDArray[np.float64]

__all__ = ["FlowResult", "read_blocks", "ignored_columns", "check_options_used",
           "parse_selection", "parse_stages", "parse_prior", "check_flow_options", "run_flow",
           "validate_blocks", "reregister", "errors_with", "block_values", "truth_values",
           "extras_from_result", "render_outputs", "write_outputs", "patent_section_html",
           "figures_section_html", "PROCEDURES", "METHODS", "LOSSES"]

PROCEDURES = ("lm", "patent")
METHODS = ("lm", "gauss-newton")
LOSSES = ("linear", "huber", "cauchy")
STAGES = ("offsets", "all", "registration")


# --------------------------------------------------------------------------- reading data
def read_blocks(paths: Sequence[str | Path], robot: Any, units: str | None = None,
                ignore: Sequence[str] | None = None) -> list[Any]:
    """Read measurement files (one block each), renaming blocks whose names clash.

    Args:
        paths: measurement CSV files.
        robot: the robot whose joints the files' joint columns name.
        units: ``--units`` text (``"x1=m,arm_1_joint=rad"``); entries matching no column
            of a file are not passed to it (they may belong to another file).
        ignore: ``--ignore`` patterns, likewise per file.

    Every block gets ``source_path`` (its file).  Raises one-line errors for bad files.
    """
    from kincal.measure.files import parse_list_option, parse_units_option
    from kincal.measure.registry import read_measurements

    umap = parse_units_option(units)
    drop = parse_list_option(ignore)
    blocks: list[Any] = []
    taken: set[str] = set()
    for path in map(str, paths):
        if not Path(path).is_file():
            raise MeasurementFileError("no such measurement file", source=path)
        got = read_measurements(path, robot, _matching(path, umap), _matching_list(path, drop))
        for b in got:
            if b.name in taken:
                k = 2
                while f"{b.name}{k}" in taken:
                    k += 1
                b = read_measurements(path, robot, _matching(path, umap),
                                      _matching_list(path, drop), name=f"{b.name}{k}")[0]
            taken.add(b.name)
            b.source_path = path
            blocks.append(b)
    return blocks


def ignored_columns(blocks: Sequence[Any]) -> list[tuple[str, list[str]]]:
    """``(file, [column ...])`` of the columns each block's reader did not read."""
    out = []
    for b in blocks:
        table = getattr(b, "table", None)
        if table is not None and table.ignored:
            out.append((str(getattr(b, "source_path", b.name)), list(table.ignored)))
    return out


def _header(path: str) -> list[str]:
    from kincal.measure.files import read_header

    return read_header(path)[1]


def _matching(path: str, umap: dict[str, str]) -> dict[str, str]:
    from kincal.measure.files import glob_regex

    if not umap:
        return {}
    names = _header(path)
    return {k: v for k, v in umap.items() if any(glob_regex(k).match(n) for n in names)}


def _matching_list(path: str, patterns: list[str]) -> list[str]:
    from kincal.measure.files import glob_regex

    if not patterns:
        return []
    names = _header(path)
    return [p for p in patterns if any(glob_regex(p).match(n) for n in names)]


def check_options_used(paths: Sequence[str | Path], units: str | None,
                       ignore: Sequence[str] | None) -> None:
    """Every ``--units`` / ``--ignore`` entry must match a column of some file (typo guard)."""
    from kincal.measure.files import glob_regex, parse_list_option, parse_units_option

    for p in paths:
        if not Path(p).is_file():
            raise MeasurementFileError("no such measurement file", source=str(p))
    names = [n for p in paths for n in _header(str(p))]
    for key in list(parse_units_option(units)) + parse_list_option(ignore):
        if not any(glob_regex(key).match(n) for n in names):
            raise MeasurementFileError(f"--units/--ignore entry {key!r} matches no column of "
                                       f"{', '.join(map(str, paths))}")


# --------------------------------------------------------------------------- options
def parse_selection(names: Sequence[str], roles: Sequence[str], free: str | None,
                    fix: str | None) -> tuple[list[str] | None, list[str]]:
    """``--free`` / ``--fix`` patterns (comma separated; ``role:offset`` selects a role).

    Returns ``(free names or None for automatic, fixed names)``.
    """
    from kincal.identify.solver import match_names

    def expand(text: str | None) -> list[str] | None:
        if not text:
            return None
        out: list[str] = []
        for p in (s.strip() for s in text.split(",")):
            if not p:
                continue
            if p.startswith("role:"):
                role = p[5:]
                hit = [n for n, r in zip(names, roles, strict=True) if r == role]
                if not hit:
                    raise KincalError(f"no parameter has role {role!r} (roles: "
                                      f"{', '.join(sorted(set(roles)))})")
                out += hit
            else:
                out += [names[i] for i in match_names(names, [p])]
        return list(dict.fromkeys(out))

    return expand(free), expand(fix) or []


_PRIOR_VALUE = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z]+)?\s*\Z")


def parse_prior(text: str | None, names: Sequence[str], units: Sequence[str]
                ) -> dict[str, float]:
    """``--prior`` text -> prior standard deviations ``{parameter name: s}`` [m / rad].

    ``text`` is ``PATTERN=SIGMA_WITH_UNIT`` entries, comma separated, e.g.
    ``"*.origin.*=1mm,*.origin.*=0.1deg"``: names or ``*`` / ``?`` patterns
    (:func:`~kincal.identify.solver.match_names`), each with a value and its unit (any
    unit of measurement files: ``mm``, ``um``, ``m``, ``deg``, ``mrad``, ``arcsec`` ...;
    required, so that ``1`` is never read as 1 m).  An entry applies to the parameters
    its pattern matches *whose unit is of the entry's dimension* (a length to lengths,
    an angle to angles), so one pattern can take both; a later entry overrides an
    earlier one for the names both give a value.  The value becomes SI,
    ``s = value * unit factor`` (``1mm -> 0.001``, ``0.1deg -> 0.001745``).

    Raises one-line :class:`~kincal.errors.KincalError` for an entry that is not
    ``PATTERN=VALUE UNIT``, a missing or unknown unit, a value that is not positive, or
    a pattern that matches no parameter of the unit's dimension.
    """
    from kincal.identify.solver import match_names
    from kincal.measure.files import UNITS

    out: dict[str, float] = {}
    if not text:
        return out
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        pattern, eq, value = (x.strip() for x in part.partition("="))
        m = _PRIOR_VALUE.match(value) if eq and pattern else None
        if m is None:
            raise KincalError(f"option --prior: {part!r} is not PATTERN=SIGMA with a unit "
                              "(e.g. '*.origin.*=1mm,*.origin.r?=0.1deg')")
        number, unit = float(m.group(1)), m.group(2)
        if unit is None:
            raise KincalError(f"option --prior: {part!r} needs a unit (e.g. {pattern}="
                              f"{m.group(1)}mm or {pattern}={m.group(1)}deg)")
        if unit not in UNITS:
            raise KincalError(f"option --prior: unknown unit {unit!r} in {part!r} (known: "
                              f"{', '.join(UNITS)})")
        if not (math.isfinite(number) and number > 0):
            raise KincalError(f"option --prior: the standard deviation in {part!r} must be "
                              "positive")
        dim, factor = UNITS[unit]
        try:
            matched = match_names(names, pattern)
        except KincalError as exc:
            raise KincalError(f"option --prior: {exc}") from None
        hit = [i for i in matched if units[i] in UNITS and UNITS[units[i]][0] == dim]
        if not hit:
            article = "an" if dim[0] in "aeiou" else "a"
            raise KincalError(f"option --prior: {pattern!r} matches no {dim} parameter "
                              f"(the unit of {part!r} is {article} {dim})")
        for i in hit:
            out[names[i]] = number * factor
    return out


def parse_stages(text: str | None) -> list[str] | None:
    """``"offsets,all"`` -> ``["offsets", "all"]`` (the one-stage solver's stages)."""
    if not text:
        return None
    st = [s.strip() for s in text.split(",") if s.strip()]
    for s in st:
        if s not in STAGES:
            raise KincalError(f"option --stages: unknown stage {s!r} (use offsets, all, "
                              "registration, comma separated)")
    return st


def _choice(value: str, option: str, allowed: Sequence[str]) -> str:
    if value not in allowed:
        raise KincalError(f"option {option}: {value!r} is not "
                          f"{', '.join(allowed[:-1])} or {allowed[-1]}")
    return value


# --------------------------------------------------------------------------- calibration
@dataclasses.dataclass
class FlowResult:
    """Everything one calibration run produced.

    Attributes:
        result: the :class:`~kincal.identify.solver.CalibrationResult` (``result.patent``
            for the patent procedure).
        comparisons: errors before/after, ``train`` then ``validation``.
        seconds: wall time of the calibration itself [s].
        warnings: sentences for people (e.g. an instrument that probably moved).
        nominal: the robot the calibration started from.
        train: the training blocks used (the patent's selection keeps only some
            placements); ``before`` / ``after``: their block parameters fitted to the
            nominal robot / estimated with the calibrated one, by block name.
    """

    result: Any
    comparisons: list[Any]
    seconds: float
    warnings: list[str] = dataclasses.field(default_factory=list)
    nominal: Any = None
    train: list[Any] = dataclasses.field(default_factory=list)
    before: dict[str, Array] = dataclasses.field(default_factory=dict)
    after: dict[str, Array] = dataclasses.field(default_factory=dict)


def errors_with(robot: Any, block: Any, extra: Array) -> dict[str, Array]:
    """Physical errors (``position_m`` ...) of ``block`` under ``robot`` with its parameters."""
    return {k: np.asarray(v, dtype=float) for k, v in block.errors(robot, extra).items()}


def _calibrate(robot: Any, blocks: list[Any], free_names: list[str] | None, fixed: list[str],
               procedure: str, progress: Callable[[Any], Any] | None,
               options: Mapping[str, Any]) -> Any:
    if procedure == "patent":
        from kincal.identify.patent import calibrate_patent

        extra = {"max_iter": options["max_iter"]} if options.get("max_iter") else {}
        return calibrate_patent(robot, blocks, free=free_names, fixed=fixed,
                                condition_growth=options.get("condition_growth"),
                                cycles=options.get("cycles"),
                                tolerance=options.get("tolerance") or 1e-7,
                                progress=progress, compare=True, **extra)
    from kincal.identify.solver import calibrate

    return calibrate(robot, blocks, free=free_names, fixed=fixed, method=options["method"],
                     stages=options.get("stages"), loss=options["loss"],
                     loss_scale=options["loss_scale"], max_iter=options.get("max_iter") or 100,
                     progress=progress, prior=options.get("prior") or None)


def _with_origin(kept: Sequence[Any], original: Sequence[Any]) -> list[Any]:
    """The solver's blocks with ``source_path`` / ``table`` of the blocks they came from
    (the patent's selection copies the blocks it thins out)."""
    by_name = {b.name: b for b in original}
    for b in kept:
        src = by_name.get(b.name)
        if src is not None and b is not src:
            for attr in ("source_path", "table"):
                if hasattr(src, attr) and not hasattr(b, attr):
                    setattr(b, attr, getattr(src, attr))
    return list(kept)


def check_flow_options(*, procedure: str = "lm", method: str = "lm", loss: str = "linear",
                       stages: Sequence[str] | None = None, validation_frames: str = "auto",
                       condition_growth: float | None = None, cycles: int | None = None,
                       tolerance: float | None = None, prior: str | None = None) -> None:
    """One-line errors for options of :func:`run_flow` that do not fit together (checked
    before any file is read; ``tolerance`` in m, reported in mm as ``--tolerance-mm``)."""
    _choice(procedure, "--procedure", PROCEDURES)
    _choice(method, "--method", METHODS)
    _choice(loss, "--loss", LOSSES)
    _choice(validation_frames, "--validation-frames", ("auto", "training", "register"))
    if procedure == "patent":
        if method != "lm" or loss != "linear" or stages or prior:
            raise KincalError("--method, --loss, --stages and --prior choose the one-stage "
                              "solver (--procedure lm); the patent has its own two stages")
    elif condition_growth is not None or cycles is not None or tolerance is not None:
        raise KincalError("--condition-growth, --cycles and --tolerance-mm need "
                          "--procedure patent")
    if condition_growth is not None and not condition_growth >= 1.0:
        raise KincalError(f"option --condition-growth: must be >= 1 (got {condition_growth:g})")
    if cycles is not None and cycles < 1:
        raise KincalError(f"option --cycles: must be >= 1 (got {cycles})")
    if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
        raise KincalError(f"option --tolerance-mm: must be > 0 (got {tolerance * 1e3:g})")


def run_flow(robot: Any, blocks: list[Any], holdouts: Sequence[Any] = (), *,
             free: str | None = None, fix: str | None = None, stages: list[str] | None = None,
             method: str = "lm", loss: str = "linear", loss_scale: float = 3.0,
             max_iter: int | None = None, validation_frames: str = "auto",
             procedure: str = "lm", condition_growth: float | None = None,
             cycles: int | None = None, tolerance: float | None = None,
             prior: str | None = None,
             progress: Callable[[Any], Any] | None = None) -> FlowResult:
    """Calibrate, then compute the errors before/after on the training and held-out data.

    Args:
        robot: the nominal robot.
        blocks, holdouts: training and held-out measurement blocks.
        free, fix: ``--free`` / ``--fix`` patterns (names, ``*``, ``role:offset``).
        stages, method, loss, loss_scale: the one-stage solver's options
            (``procedure="lm"``).
        max_iter: iterations (lm: in all, default 100; patent: per stage, default 20).
        validation_frames: ``auto`` | ``training`` | ``register`` (see below).
        procedure: ``lm`` (the one-stage solver) or ``patent`` (the cross-bar patent's
            two stages, :func:`~kincal.identify.patent.calibrate_patent`, with its
            comparison against one-stage LM).
        condition_growth: patent only: discard a placement when the condition number
            grows by more than this factor (None: keep every placement).
        cycles: patent only: passes through the stages (1 = the patent literally;
            None = until converged).
        tolerance: patent only: stop when no predicted point moves more than this [m]
            (default 1e-7 m).
        prior: ``--prior`` text (:func:`parse_prior`, e.g. ``"*.origin.*=1mm"``): a
            maximum a-posteriori estimate with Gaussian priors centred on the nominal
            values (``procedure="lm"``).
        progress: called with every :class:`~kincal.identify.solver.IterationRecord`.

    *Before* = the nominal robot with the instruments registered to it (only the
    blocks' own parameters fitted: the "registration only" baseline); *after* = the
    calibrated robot with the frames estimated with it.  The training errors use the
    blocks the solver used (``result.problem.blocks``: after the patent's selection,
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
    from kincal.measure.base import stack
    from kincal.report import ErrorComparison, merge_errors

    check_flow_options(procedure=procedure, method=method, loss=loss, stages=stages,
                       validation_frames=validation_frames, condition_growth=condition_growth,
                       cycles=cycles, tolerance=tolerance, prior=prior)
    prob, _ = stack(robot, blocks)
    free_names, fixed = parse_selection(prob.names, prob.roles, free, fix)
    prior_s = parse_prior(prior, prob.names, prob.units)
    t0 = time.perf_counter()
    res = _calibrate(robot, blocks, free_names, fixed, procedure, progress,
                     {"method": method, "stages": stages, "loss": loss,
                      "loss_scale": loss_scale, "max_iter": max_iter,
                      "condition_growth": condition_growth, "cycles": cycles,
                      "tolerance": tolerance, "prior": prior_s})
    seconds = time.perf_counter() - t0
    train = _with_origin(res.problem.blocks, blocks)
    before = {b.name: reregister(robot, b, None, None) for b in train}
    after = {b.name: res.theta[res.problem.block_slice(b.name)] for b in train}
    comps = [ErrorComparison(
        "train", "train" + _files(train),
        merge_errors([errors_with(robot, b, before[b.name]) for b in train]),
        merge_errors([errors_with(res.robot, b, after[b.name]) for b in train]),
        "before: nominal robot, instrument frames and markers fitted to it; after: "
        "calibrated robot and frames")]
    warnings: list[str] = []
    if holdouts:
        comps.append(_holdout_comparison(robot, res.robot, train, list(holdouts), before,
                                         after, validation_frames, warnings))
    return FlowResult(res, comps, seconds, warnings, robot, train, before, after)


def _holdout_comparison(nominal: Any, calibrated: Any, train: list[Any], holdouts: list[Any],
                        before: dict[str, Array], after: dict[str, Array], frames: str,
                        warnings: list[str]) -> Any:
    """The ``validation`` comparison of :func:`run_flow` (appends to ``warnings``)."""
    from kincal.report import ErrorComparison, error_keys, error_metrics, merge_errors, quantity

    eb, ea, notes = [], [], []
    for h in holdouts:
        twin = _training_twin(h, train)
        if frames == "training" and twin is None:
            raise KincalError(f"held-out block {h.name!r} has no training block of its "
                              "kind to take frames from")
        same = twin is not None and (frames == "training" or (
            frames == "auto" and twin.name == h.name and _explicit_name(h)))
        if same:
            xb, xa = before[twin.name], after[twin.name]
            notes.append(f"{h.name}: same session, frames and markers from training "
                         "(no refit)")
            check = reregister(calibrated, h, twin, after[twin.name])
            e1, e2 = errors_with(calibrated, h, xa), errors_with(calibrated, h, check)
            key = error_keys(e1)[0]
            reused = error_metrics(e1)[f"rms_{key}"]
            fresh = error_metrics(e2)[f"rms_{key}"]
            if reused > 5 * fresh and reused > 1e-4:
                _, f, unit = quantity(key)
                warnings.append(
                    f"{Path(getattr(h, 'source_path', h.name)).name}: with the training "
                    f"frames the held-out RMS is {reused * f:.3g} {unit}, after "
                    f"re-registering the instrument frame {fresh * f:.3g} {unit}: the "
                    "instrument probably moved; use --validation-frames register")
        else:
            xb = reregister(nominal, h, twin, before[twin.name] if twin else None)
            xa = reregister(calibrated, h, twin, after[twin.name] if twin else None)
            what = f"marker/target from training block {twin.name!r}" if twin else \
                "all its parameters"
            notes.append(f"{h.name}: instrument frame re-registered on the held-out "
                         f"data ({what})")
        eb.append(errors_with(nominal, h, xb))
        ea.append(errors_with(calibrated, h, xa))
    return ErrorComparison("validation", "held-out" + _files(holdouts), merge_errors(eb),
                           merge_errors(ea), "; ".join(notes))


def _explicit_name(block: Any) -> bool:
    """True when the block's name came from its file's tag (not a default)."""
    table = getattr(block, "table", None)
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
    a twin every block parameter is fitted (the "registration only" fit)."""
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
    names = [Path(getattr(b, "source_path", "")).name for b in blocks]
    names = [n for n in names if n]
    return f" ({', '.join(names)})" if names else ""


# --------------------------------------------------------------------------- validation
def validate_blocks(robot: Any, blocks: Sequence[Any], before: Any = None,
                    extras: Mapping[str, float] | None = None,
                    protocol: str | None = None) -> list[Any]:
    """Errors of ``robot`` (and of ``before``) on held-out blocks, one comparison each.

    With ``extras`` (``{parameter: value}`` from a result JSON) every block parameter
    is taken as it is (same session, no refit); without, each block's instrument
    parameters are re-registered to the robot evaluated.  Returns
    :class:`~kincal.report.ErrorComparison` (``before`` = ``after`` without ``before``).
    """
    from kincal.identify.validation import validate
    from kincal.report import ErrorComparison

    how = protocol or ("frames from the result file" if extras is not None
                       else "instrument re-registered on this file")

    def frames(r: Any, b: Any) -> Array:
        if extras is not None:
            return block_values(validate(r, [b], extras=dict(extras))["extras"][b.name], b)
        return reregister(r, b, None, None)

    comps = []
    for b in blocks:
        ea = errors_with(robot, b, frames(robot, b))
        eb = errors_with(before, b, frames(before, b)) if before is not None else ea
        comps.append(ErrorComparison("validation", Path(getattr(b, "source_path", b.name)
                                                         ).name, eb, ea, how))
    return comps


def truth_values(path: str | Path) -> dict[str, float]:
    """True parameter values from a robot file (and instrument truth from its notes)."""
    from kincal.robots.files import load_robot

    t = load_robot(path)
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


def extras_from_result(path: str | Path) -> dict[str, float]:
    """``{parameter: estimate}`` of a result JSON written by ``kincal calibrate``."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        return {p["name"]: float(p["estimate"]) for p in doc["parameters"]}
    except FileNotFoundError:
        raise KincalError("no such result file", source=str(path)) from None
    except (ValueError, KeyError, TypeError) as exc:
        raise KincalError(f"not a kincal result JSON ({exc.__class__.__name__}: {exc})",
                          source=str(path)) from None


# --------------------------------------------------------------------------- outputs
def _artifact_figures(flow: FlowResult, report: str) -> dict[str, tuple[str, bytes]]:
    """The patent's figures 4 and 5 of every training artifact block, rendered in memory:
    ``{key: (path next to the report, PNG bytes)}``."""
    from kincal.measure.artifacts.model import ArtifactMeasurement

    blocks = [b for b in flow.train if isinstance(b, ArtifactMeasurement)]
    if not blocks or flow.nominal is None:
        return {}
    from kincal.artifact_plots import save_patent_figures

    folder, stem = Path(report).parent, Path(report).stem
    out: dict[str, tuple[str, bytes]] = {}
    with tempfile.TemporaryDirectory(prefix="kincal-figures-") as tmp:
        for b in blocks:
            prefix = f"{stem}_figure" if len(blocks) == 1 else f"{stem}_{b.name}_figure"
            made = save_patent_figures(b, flow.nominal, flow.result.robot, tmp,
                                       flow.before.get(b.name), flow.after.get(b.name),
                                       prefix=prefix)
            for key, p in made.items():
                tag = key if len(blocks) == 1 else f"{b.name}.{key}"
                out[tag] = (str(folder / Path(p).name), Path(p).read_bytes())
    return out


def _fmt_cond(v: float | None) -> str:
    """A condition number; None / inf (JSON null) is a rank-deficient matrix."""
    return "inf" if v is None or not math.isfinite(v) else f"{v:.4g}"


def _rms_cells(summary: Mapping[str, Any], keys: Sequence[str]) -> str:
    from kincal.report import quantity

    cells = []
    for k in keys:
        v = summary.get(k)
        _, f, _ = quantity(k[4:])
        cells.append(f"<td>{'-' if v is None else f'{v * f:.4f}'}</td>")
    return "".join(cells)


def patent_section_html(info: Any, figures: Mapping[str, tuple[str, bytes]] | None = None,
                        units: Mapping[str, str] | None = None) -> str:
    """The report's patent section: the procedure, kept and discarded placements with
    their condition numbers, the comparison with one-stage LM and figures 4 and 5.

    Args:
        info: :class:`~kincal.identify.patent.PatentInfo` (or its ``to_dict()``).
        figures: ``{key: (file, PNG bytes)}`` embedded at the end.
        units: ``{parameter: "m" | "rad"}`` to show lengths in mm and angles in deg.
    """
    d = info.to_dict() if hasattr(info, "to_dict") else dict(info)
    e = html.escape
    parts = ["<h2>The patent's procedure</h2>"]
    how = "one pass" if d["cycles"] == 1 else f"{d['cycles']} cycles"
    parts.append(f"<p>{how} through {len(d['stages'])} stage(s) (one pass = the patent "
                 "literally; more: repeated until no point moves): "
                 + "; then ".join(e(f"{s['stage']} ({len(s['candidates'])} candidates)")
                                  for s in d["stages"])
                 + f". Point-correction tolerance {d['tolerance_m'] * 1e3:g} mm; "
                 + ("converged" if d["converged"] else "<span class='bad'>NOT converged</span>")
                 + (f" (last cycle moved the points by {d['cycle_corrections_m'][-1] * 1e3:.3g}"
                    " mm)." if d["cycle_corrections_m"] else ".") + "</p>")
    sel = d["selection"]
    if d["condition_growth"] is None:
        parts.append("<p>No data selection: every placement kept.</p>")
    else:
        parts.append(f"<h3>Data selection by the condition number</h3><p>A placement is "
                     f"discarded when it makes the condition number of the scaled "
                     f"identification matrix grow by more than a factor "
                     f"{d['condition_growth']:g}. Kept {len(d['kept'])} of "
                     f"{len(d['kept']) + len(d['discarded'])} placements"
                     + (": discarded " + e(", ".join(f"{x['block']}:{x['placement']}"
                                                     for x in d["discarded"]))
                        if d["discarded"] else "") + ".</p>")
        rows = "".join(
            f"<tr class='{'' if s['kept'] else 'no'}'><td class='l'>{e(s['block'])}</td>"
            f"<td class='l'>{e(str(s['placement']))}</td><td>{_fmt_cond(s['previous'])}</td>"
            f"<td>{_fmt_cond(s['condition'])}</td>"
            f"<td class='l'>{'kept' if s['kept'] else 'discarded'}</td></tr>" for s in sel)
        parts.append("<table><tr><th class='l'>block</th><th class='l'>placement</th>"
                     "<th>cond before</th><th>cond with it</th><th class='l'>decision</th>"
                     f"</tr>{rows}</table><p class='small'>cond = inf while the matrix is "
                     "rank deficient (every placement is kept until it is not).</p>")
    comp = d.get("comparison")
    if comp:
        runs = [("patent", comp["patent"]), ("one-stage LM, same parameters",
                                              comp["one_stage"]),
                ("one-stage LM, automatic parameters", comp["automatic"])]
        keys = sorted({k for _, s in runs for k in s if k.startswith("rms_")})
        from kincal.report import quantity

        head = "".join(f"<th>RMS {e(quantity(k[4:])[0])} [{e(quantity(k[4:])[2])}]</th>"
                       for k in keys)
        body = "".join(f"<tr><td class='l'>{e(n)}</td><td>{s['estimated']}</td>"
                       f"<td>{s['sigma0']:.4g}</td><td class='l'>"
                       f"{'yes' if s['converged'] else 'no'}</td>{_rms_cells(s, keys)}</tr>"
                       for n, s in runs)
        same = comp["same_parameters"]
        parts.append("<h3>Comparison with one-stage Levenberg-Marquardt (same data)</h3>"
                     "<table><tr><th class='l'>solver</th><th>estimated</th><th>sigma0</th>"
                     f"<th class='l'>converged</th>{head}</tr>{body}</table>"
                     f"<p>Same parameters: the largest difference is "
                     f"{same['max_sigmas']:.3g} standard errors"
                     + (f" ({e(same['worst'])})" if same["worst"] else "") + ".</p>")
        if same["rows"]:
            rows = []
            for r in same["rows"]:
                f, u = {"m": (1e3, "mm"), "rad": (180 / math.pi, "deg")}.get(
                    (units or {}).get(r["name"], ""), (1.0, "SI"))
                rows.append(f"<tr><td class='l'>{e(r['name'])}</td><td>{r['a'] * f:.5f}</td>"
                            f"<td>{r['b'] * f:.5f}</td><td>{r['diff'] * f:.2e}</td>"
                            f"<td class='l'>{u}</td><td>{r['sigmas']:.3g}</td></tr>")
            parts.append("<table><tr><th class='l'>parameter</th><th>patent</th>"
                         "<th>one-stage</th><th>difference</th><th class='l'>unit</th>"
                         f"<th>in std</th></tr>{''.join(rows)}</table>")
    if figures:
        parts.append(figures_section_html(figures, heading="h3"))
    return "\n".join(parts)


def figures_section_html(figures: Mapping[str, tuple[str, bytes]], heading: str = "h2") -> str:
    """The patent's figures 4 and 5 (``{key: (file, PNG bytes)}``) as a report section."""
    e = html.escape
    parts = [f"<{heading}>Artifact lengths from the joint readings (the patent's figures 4 "
             f"and 5)</{heading}><p class='small'>figure 4: nominal model, figure 5: "
             "calibrated model, same scale; the files are next to the report.</p>"]
    for key, (path, png) in figures.items():
        b64 = base64.b64encode(png).decode("ascii")
        parts.append(f"<p class='small'>{e(key)} ({e(Path(path).name)})</p>"
                     f"<img alt='{e(key)}' src='data:image/png;base64,{b64}'>")
    return "\n".join(parts)


def _render_report(result: Any, comparisons: Sequence[Any], inputs: Mapping[str, str],
                   truth: Mapping[str, float] | None, sections: Sequence[str]) -> str:
    """:func:`kincal.report.render_html` with extra sections before the footer."""
    from kincal.report import render_html

    return render_html(result, comparisons, inputs=inputs, truth=truth,
                       extra_sections=list(sections))


def render_outputs(flow: FlowResult, output: str | None = None, urdf: str | None = None,
                   json_out: str | None = None, report: str | None = None,
                   inputs: Mapping[str, str] | None = None,
                   truth: Mapping[str, float] | None = None,
                   extra: Mapping[str, Any] | None = None
                   ) -> tuple[dict[str, str], dict[str, str | bytes]]:
    """Render every output of a calibration in memory.

    Returns ``(planned, contents)``: ``planned`` maps ``robot``, ``urdf``, ``report``,
    ``json`` and each figure key to its path; ``contents`` maps the same keys to the
    text (or PNG bytes) to write.  A URDF robot's ``urdf`` entry is None: it is
    written by :func:`~kincal.robots.urdf.write_calibrated_urdf` from the original file.
    """
    from kincal.io import _jsonable
    from kincal.report import result_json
    from kincal.robots.files import robot_yaml_text

    res = flow.result
    inputs = dict(inputs or {})
    planned = {k: v for k, v in (("robot", output), ("urdf", urdf), ("report", report)) if v}
    contents: dict[str, str | bytes] = {}
    info = getattr(res, "patent", None)
    figures = _artifact_figures(flow, report) if report else {}
    for key, (path, png) in figures.items():
        planned[key] = path
        contents[key] = png
    if report:
        units = dict(zip(res.names, res.problem.units, strict=True))
        sections = ([patent_section_html(info, figures, units)] if info is not None else
                    [figures_section_html(figures)] if figures else [])
        contents["report"] = _render_report(res, flow.comparisons, inputs, truth, sections)
    if output:
        contents["robot"] = robot_yaml_text(res.robot)
    if urdf and res.robot.meta.get("convention") != "urdf":
        from kincal.robots.urdf import urdf_text

        contents["urdf"] = urdf_text(res.robot)[0]
    if json_out:
        more = dict(extra or {})
        if info is not None:
            more["patent"] = info.to_dict()
        doc = result_json(res, flow.comparisons, {"inputs": inputs, **more})
        doc["outputs"] = dict(planned)
        contents["json"] = json.dumps(doc, indent=2, default=_jsonable) + "\n"
        planned["json"] = json_out
    return planned, contents


def write_outputs(flow: FlowResult, output: str | None = None, urdf: str | None = None,
                  json_out: str | None = None, report: str | None = None,
                  inputs: Mapping[str, str] | None = None,
                  truth: Mapping[str, float] | None = None,
                  extra: Mapping[str, Any] | None = None) -> dict[str, str]:
    """Render everything (:func:`render_outputs`), then write each file atomically, the
    JSON last, so a failure while rendering leaves no output behind.

    Returns ``{what: path}`` of the files written (``robot``, ``urdf``, ``report``,
    figure keys, ``json``).
    """
    from kincal.io import atomic_write_bytes, atomic_write_text

    planned, contents = render_outputs(flow, output, urdf, json_out, report, inputs, truth,
                                       extra)
    for key, path in planned.items():
        if key == "json" or key not in contents:
            continue
        data = contents[key]
        if isinstance(data, bytes):
            atomic_write_bytes(path, data)
        else:
            atomic_write_text(path, data)
    if urdf and "urdf" not in contents:
        from kincal.robots.urdf import write_calibrated_urdf

        write_calibrated_urdf(None, flow.result.robot, urdf)
    if json_out:
        atomic_write_text(json_out, str(contents["json"]))
    return {k: v for k, v in planned.items() if k != "json"}
