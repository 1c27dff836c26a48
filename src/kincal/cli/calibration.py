"""Calibration commands: ``instruments``, ``simulate``, ``identifiability``, ``calibrate``,
``validate``, ``compensate`` and ``demo``.

Every command reads all its inputs and runs all its numerics before writing any
output, and every output is written atomically, so a bad file or an unreachable
target leaves nothing behind (the error is one line, exit code 2).  Tables show mm
and degrees; files are SI unless ``--length-unit`` / ``--angle-unit`` say otherwise.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.common import console, err_console
from kincal.errors import KincalError, MeasurementFileError

# --------------------------------------------------------------------------- options
RobotArg = Annotated[str, typer.Argument(help="Built-in robot name (see `kincal robots`), or a "
                                         "path to a YAML robot file or a URDF file.")]
DataOpt = Annotated[list[str], typer.Option("--data", "-d", help="Measurement CSV file "
                                            "(repeat for several instruments / sessions; each "
                                            "file is one block with its own instrument frame).")]
UnitsOpt = Annotated[str | None, typer.Option(
    "--units", help="Units of columns whose header has none, e.g. "
    "'x1=m,y1=m,z1=m,arm_1_joint=rad'; keys may use * and ? ('x?=m').")]
IgnoreOpt = Annotated[list[str] | None, typer.Option(
    "--ignore", help="Columns to drop on purpose, comma separated, * and ? allowed "
    "('x2,y2,z2' or '?2,?3'). Columns that look like joints or measurements are never "
    "dropped silently.")]
JsonOpt = Annotated[str | None, typer.Option("--json", help="Also write the result as JSON "
                                             "to this path ('-' for stdout).")]
BaseLink = Annotated[str | None, typer.Option("--base-link", help="URDF only: first link of "
                                              "the chain.")]
TipLink = Annotated[str | None, typer.Option("--tip-link", help="URDF only: last link of the "
                                             "chain.")]
LengthUnit = Annotated[str, typer.Option("--length-unit", help="Length unit of written CSV "
                                         "files: m, mm, um.")]
AngleUnit = Annotated[str, typer.Option("--angle-unit", help="Angle unit of written CSV files: "
                                        "rad, deg.")]


def _out(json_path: str | None) -> Console:
    """Tables go to stdout unless the JSON does (``--json -``)."""
    return err_console if json_path == "-" else console


def _load(spec: str, base_link: str | None = None, tip_link: str | None = None) -> Any:
    from kincal.robots.files import load_robot

    return load_robot(spec, base_link=base_link, tip_link=tip_link)


def _is_fivebar(robot: Any) -> bool:
    return type(robot).__name__ == "FiveBar"


def _serial(robot: Any, command: str) -> Any:
    if _is_fivebar(robot):
        raise KincalError(f"`kincal {command}` works on serial robots; for the five-bar use "
                          "`kincal calibrate` or the fivebar-* commands")
    return robot


def _check_unit(unit: str, dimension: str, option: str) -> str:
    from kincal.measure.files import UNITS

    if unit not in UNITS or UNITS[unit][0] != dimension:
        ok = [u for u, (d, _) in UNITS.items() if d == dimension]
        raise KincalError(f"option {option}: {unit!r} is not a {dimension} unit "
                          f"({', '.join(ok)})")
    return unit


# --------------------------------------------------------------------------- reading data
def read_blocks(paths: Sequence[str], robot: Any, units: str | None,
                ignore: Sequence[str] | None, out: Console | None = None) -> list[Any]:
    """Read measurement files (one block each), renaming blocks whose names clash.

    Prints, for each file, the columns that were not read (bookkeeping columns).
    """
    from kincal.measure.files import parse_list_option, parse_units_option
    from kincal.measure.registry import read_measurements

    umap = parse_units_option(units)
    drop = parse_list_option(ignore)
    blocks: list[Any] = []
    taken: set[str] = set()
    for path in paths:
        if not Path(path).is_file():
            raise MeasurementFileError("no such measurement file", source=str(path))
        # --units / --ignore entries may belong to another file: keep those matching here
        got = read_measurements(path, robot, _matching(path, umap), _matching_list(path, drop))
        for b in got:
            if b.name in taken:
                k = 2
                while f"{b.name}{k}" in taken:
                    k += 1
                got = read_measurements(path, robot, _matching(path, umap),
                                        _matching_list(path, drop), name=f"{b.name}{k}")
                b = got[0]
            taken.add(b.name)
            b.source_path = str(path)  # type: ignore[attr-defined]
            blocks.append(b)
            table = getattr(b, "table", None)
            if out is not None and table is not None and table.ignored:
                out.print(f"[dim]{escape(str(path))}: not read (not joint or measurement "
                          f"columns): {escape(', '.join(table.ignored))}[/dim]")
    return blocks


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


def _check_options_used(paths: Sequence[str], units: str | None,
                        ignore: Sequence[str] | None) -> None:
    """Every --units / --ignore entry must match a column of some file (typo guard)."""
    from kincal.measure.files import glob_regex, parse_list_option, parse_units_option

    names = [n for p in paths for n in _header(p)]
    for key in list(parse_units_option(units)) + parse_list_option(ignore):
        if not any(glob_regex(key).match(n) for n in names):
            raise MeasurementFileError(f"--units/--ignore entry {key!r} matches no column of "
                                       f"{', '.join(paths)}")


# --------------------------------------------------------------------------- instruments
@app.command("instruments")
def instruments_cmd() -> None:
    """List the measurement instruments (for `kincal simulate --instrument`) and options."""
    from kincal.measure.registry import instruments

    t = Table(title="Instruments (use with --instrument; options with --option KEY=VALUE)")
    for c in ("name", "description", "noise unit", "options (default)"):
        t.add_column(c, overflow="fold")
    for name, inst in sorted(instruments().items()):
        opts = "\n".join(f"{k}={v!r}: {h}" for k, (v, h) in inst.options.items())
        t.add_row(name, inst.description, inst.noise_unit, opts or "-")
    console.print(t)
    from kincal.measure.registry import LOAD_ERRORS

    for mod, err in LOAD_ERRORS.items():
        console.print(f"[red]{escape(mod)} failed to load[/red]: {escape(err)}")


def _parse_options(items: Sequence[str] | None, inst: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items or []:
        for part in item.split(";"):
            if not part.strip():
                continue
            if "=" not in part:
                raise KincalError(f"option --option: {part!r} is not KEY=VALUE")
            k, v = (s.strip() for s in part.split("=", 1))
            if k not in inst.options:
                raise KincalError(f"instrument {inst.name!r} has no option {k!r} (options: "
                                  f"{', '.join(inst.options) or 'none'})")
            default = inst.options[k][0]
            try:
                if isinstance(default, bool):
                    if v.lower() not in ("true", "false", "1", "0", "yes", "no"):
                        raise ValueError
                    out[k] = v.lower() in ("true", "1", "yes")
                elif isinstance(default, int):
                    out[k] = int(v)
                elif isinstance(default, float):
                    out[k] = float(v)
                else:
                    out[k] = v
            except ValueError:
                raise KincalError(f"option {k}: {v!r} is not a {type(default).__name__}"
                                  ) from None
    return out


def _noise(noise_mm: float | None, noise: str | None, inst: Any) -> float:
    """The instrument's main noise in its SI unit from --noise-mm or --noise VALUE+UNIT."""
    import re

    from kincal.measure.files import UNITS

    dim = {"m": "length", "rad": "angle", "px": "pixel"}.get(inst.noise_unit, "dimensionless")
    if noise_mm is not None and noise is not None:
        raise KincalError("give either --noise-mm or --noise, not both")
    if noise is not None:
        m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*([a-z1]+)\s*", noise)
        if not m or m.group(2) not in UNITS:
            raise KincalError(f"option --noise: {noise!r} is not VALUE+UNIT (e.g. 0.02mm, "
                              "1arcsec, 0.3px)")
        try:
            v = float(m.group(1))
        except ValueError:
            raise KincalError(f"option --noise: {m.group(1)!r} is not a number") from None
        d, f = UNITS[m.group(2)]
        if d != dim:
            raise KincalError(f"option --noise: instrument {inst.name!r} has {dim} noise; "
                              f"{m.group(2)} is {d}")
        value = v * f
    elif noise_mm is not None:
        if dim != "length":
            raise KincalError(f"instrument {inst.name!r} has {dim} noise: use --noise "
                              "VALUE+UNIT")
        value = noise_mm * 1e-3
    else:
        value = {"length": 1e-5, "angle": 2e-6, "pixel": 0.2}.get(dim, 1e-5)
    if not math.isfinite(value) or value < 0:
        raise KincalError("the noise must be a finite number >= 0")
    return float(value)


@app.command()
def simulate(
    robot: RobotArg,
    output: Annotated[str, typer.Option("-o", "--output", help="Measurement CSV to write.")],
    truth: Annotated[str | None, typer.Option("--truth", help="Write the simulated true robot "
                                              "here (YAML robot file, SI).")] = None,
    poses: Annotated[int, typer.Option("--poses", "-n", min=1, help="Number of measured "
                                       "configurations.")] = 100,
    noise_mm: Annotated[float | None, typer.Option("--noise-mm", help="Measurement noise "
                                                   "(standard deviation per coordinate) [mm]; "
                                                   "default 0.01.")] = None,
    noise: Annotated[str | None, typer.Option("--noise", help="Noise with its unit for "
                                              "non-length instruments: '1arcsec', '0.3px'.")
                     ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    instrument: Annotated[str, typer.Option("--instrument", "-i", help="Instrument (see "
                                            "`kincal instruments`): position, pose, ...")
                          ] = "position",
    option: Annotated[list[str] | None, typer.Option("--option", help="Instrument option "
                                                     "KEY=VALUE (repeatable), e.g. "
                                                     "markers=3.")] = None,
    holdout: Annotated[str | None, typer.Option("--holdout", help="Also write held-out "
                                                "measurements (same robot, same instrument "
                                                "placement) to this CSV.")] = None,
    holdout_poses: Annotated[int, typer.Option("--holdout-poses", min=1, help="Poses in the "
                                               "held-out file.")] = 50,
    length_error_mm: Annotated[float, typer.Option(help="Std of the injected length errors "
                                                   "[mm].")] = 0.5,
    angle_error_deg: Annotated[float, typer.Option(help="Std of the injected angle errors "
                                                   "[deg].")] = 0.05,
    offset_error_deg: Annotated[float, typer.Option(help="Std of the injected joint offset "
                                                    "errors [deg].")] = 0.1,
    perturb: Annotated[str | None, typer.Option(help="Only perturb these parameters (names or "
                                                "* patterns, comma separated).")] = None,
    length_unit: LengthUnit = "m", angle_unit: AngleUnit = "rad",
    base_link: BaseLink = None, tip_link: TipLink = None, json_out: JsonOpt = None,
) -> None:
    """Simulate a calibration experiment: a true robot (nominal + errors) measured by an
    instrument with noise. Writes the measurements (and the truth) for `kincal calibrate`."""
    from kincal.io import write_json
    from kincal.measure.registry import (
        accepts,
        get_instrument,
        simulate_measurements,
        write_measurements,
    )
    from kincal.measure.simulate import perturb_robot
    from kincal.robots.files import write_robot_yaml

    out = _out(json_out)
    nominal = _serial(_load(robot, base_link, tip_link), "simulate")
    inst = get_instrument(instrument)
    opts = _parse_options(option, inst)
    sd = _noise(noise_mm, noise, inst)
    units = {"length": _check_unit(length_unit, "length", "--length-unit"),
             "angle": _check_unit(angle_unit, "angle", "--angle-unit")}
    rng = np.random.default_rng(seed)
    names = None
    if perturb:
        from kincal.identify.solver import match_names

        names = [nominal.param_names[i] for i in
                 match_names(nominal.param_names, [p.strip() for p in perturb.split(",")])]
    true = perturb_robot(nominal, rng, length_std=length_error_mm * 1e-3,
                         angle_std=math.radians(angle_error_deg),
                         offset_std=math.radians(offset_error_deg),
                         base_std=(length_error_mm * 1e-3, math.radians(angle_error_deg)),
                         tool_std=(length_error_mm * 1e-3, math.radians(angle_error_deg)),
                         names=names)
    blocks, inst_truth = simulate_measurements(inst, true, rng, poses, sd, opts)
    held = None
    if holdout:
        hopts = dict(opts)
        same = accepts(inst.simulate, "truth")
        if not same and "name" in inst.options:
            hopts["name"] = f"{opts.get('name', inst.options['name'][0])}_holdout"
        held, _ = simulate_measurements(inst, true, rng, holdout_poses, sd, hopts,
                                        truth=inst_truth)
    note = (f"Simulated by `kincal simulate`: {nominal.name} + errors (seed {seed}), measured "
            f"by {inst.name} with noise {sd:g} {inst.noise_unit}; instrument truth: "
            + ", ".join(f"{k}={v:.9g}" for k, v in inst_truth.items()))
    true = dataclasses.replace(true, meta={**dict(true.meta), "notes": note})
    write_measurements(inst, blocks, output, units, nominal)
    if held is not None:
        write_measurements(inst, held, holdout, units, nominal)
    if truth:
        write_robot_yaml(true, truth)
    delta = true.param_values - nominal.param_values
    out.print(f"simulated {poses} measurements of {escape(nominal.name)} with "
              f"{inst.name} (noise {sd:g} {inst.noise_unit}) -> {escape(output)}")
    if held is not None:
        out.print(f"held-out: {holdout_poses} measurements -> {escape(str(holdout))}")
    lin = np.array([u == "m" for u in nominal.param_units])
    out.print(f"injected errors: {int(np.count_nonzero(delta))} parameters, largest "
              f"{np.max(np.abs(delta[lin]), initial=0) * 1e3:.3f} mm / "
              f"{math.degrees(np.max(np.abs(delta[~lin]), initial=0)):.4f} deg"
              + (f"; truth -> {escape(truth)}" if truth else ""))
    if json_out:
        write_json(json_out, {
            "robot": nominal.name, "instrument": inst.name, "poses": poses,
            "noise": sd, "noise_unit": inst.noise_unit, "seed": seed, "output": output,
            "holdout": holdout, "truth_file": truth, "instrument_truth": inst_truth,
            "true_parameters": true.params(),
            "nominal_parameters": nominal.params()})


# --------------------------------------------------------------------------- selection
def _selection(names: Sequence[str], roles: Sequence[str], free: str | None,
               fix: str | None) -> tuple[list[str] | None, list[str]]:
    """``--free`` / ``--fix`` patterns (comma separated; ``role:offset`` selects a role)."""
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


@app.command()
def identifiability(
    robot: RobotArg, data: DataOpt, units: UnitsOpt = None, ignore: IgnoreOpt = None,
    free: Annotated[str | None, typer.Option("--free", help="Candidate parameters: names or * "
                                             "patterns, 'role:offset' (default: all).")] = None,
    fix: Annotated[str | None, typer.Option("--fix", help="Parameters to hold fixed.")] = None,
    base_link: BaseLink = None, tip_link: TipLink = None, json_out: JsonOpt = None,
) -> None:
    """Which parameters can these measurements identify? Zero and dependent columns,
    the base parameter set and the condition number, in plain sentences."""
    from kincal.identify.identifiability import analyze
    from kincal.io import write_json
    from kincal.measure.base import stack

    out = _out(json_out)
    r = _serial(_load(robot, base_link, tip_link), "identifiability")
    _check_options_used(data, units, ignore)
    blocks = read_blocks(data, r, units, ignore, out)
    prob, theta0 = stack(r, blocks)
    _, J = prob.residuals_and_jacobian(theta0)
    free_names, fixed = _selection(prob.names, prob.roles, free, fix)
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
        t.add_row(escape(n), {"m": "mm", "rad": "deg"}.get(prob.units[i], prob.units[i]), status)
    out.print(t)
    for s in rep.describe():
        out.print(f"- {escape(s)}")
    if json_out:
        write_json(json_out, {**rep.to_dict(), "measurements": n_meas,
                              "candidates": [prob.names[i] for i in cand]})


# --------------------------------------------------------------------------- calibration flow
@dataclasses.dataclass
class FlowResult:
    """Everything one calibration run produced (used by `calibrate` and `demo`)."""

    result: Any
    comparisons: list[Any]
    seconds: float
    warnings: list[str] = dataclasses.field(default_factory=list)


class _Progress:
    """A rich progress bar fed by the solver's per-iteration callback."""

    def __init__(self, total: int, enabled: bool = True) -> None:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.total = total
        self.enabled = enabled
        self.progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                                 TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                                 console=err_console, transient=True, disable=not enabled)
        self.task = None
        self.stage = None

    def __enter__(self) -> _Progress:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.__exit__(*exc)

    def __call__(self, rec: Any) -> None:
        if rec.stage != self.stage:
            if self.task is not None:
                self.progress.update(self.task, completed=self.total)
            self.stage = rec.stage
            self.task = self.progress.add_task(f"stage {rec.stage}", total=self.total,
                                               info="")
        self.progress.update(self.task, completed=min(rec.iteration, self.total),
                             info=f"iteration {rec.iteration}  RMS {rec.rms:.4g} sigma")


def _errors_with(robot: Any, block: Any, extra: np.ndarray) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, dtype=float) for k, v in block.errors(robot, extra).items()}


def run_flow(robot: Any, blocks: list[Any], holdouts: list[Any], *, free: str | None = None,
             fix: str | None = None, stages: list[str] | None = None, method: str = "lm",
             loss: str = "linear", loss_scale: float = 3.0, max_iter: int = 100,
             validation_frames: str = "auto", progress: bool = True) -> FlowResult:
    """Calibrate, then compute the errors before/after on the training and held-out data.

    *Before* = the nominal robot with the instruments registered to it (only the
    blocks' own parameters fitted: the "registration only" baseline); *after* = the
    calibrated robot with the frames estimated with it.

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
    from kincal.identify.solver import calibrate
    from kincal.measure.base import stack
    from kincal.report import ErrorComparison, error_keys, error_metrics, merge_errors, quantity

    prob, _ = stack(robot, blocks)
    free_names, fixed = _selection(prob.names, prob.roles, free, fix)
    t0 = time.perf_counter()
    with _Progress(max_iter, progress) as bar:
        res = calibrate(robot, blocks, free=free_names, fixed=fixed, method=method,
                        stages=stages, loss=loss, loss_scale=loss_scale, max_iter=max_iter,
                        progress=bar)
    seconds = time.perf_counter() - t0
    before = {b.name: _reregister(robot, b, None, None) for b in blocks}
    after = {b.name: res.theta[res.problem.block_slice(b.name)] for b in blocks}
    comps = [ErrorComparison(
        "train", "train" + _files(blocks),
        merge_errors([_errors_with(robot, b, before[b.name]) for b in blocks]),
        merge_errors([_errors_with(res.robot, b, after[b.name]) for b in blocks]),
        "before: nominal robot, instrument frames and markers fitted to it; after: "
        "calibrated robot and frames")]
    warnings: list[str] = []
    if holdouts:
        eb, ea, notes = [], [], []
        for h in holdouts:
            twin = _training_twin(h, blocks)
            if validation_frames not in ("auto", "training", "register"):
                raise KincalError(f"option --validation-frames: {validation_frames!r} is not "
                                  "auto, training or register")
            if validation_frames == "training" and twin is None:
                raise KincalError(f"held-out block {h.name!r} has no training block of its "
                                  "kind to take frames from")
            same = twin is not None and (validation_frames == "training" or (
                validation_frames == "auto" and twin.name == h.name and _explicit_name(h)))
            if same:
                xb, xa = before[twin.name], after[twin.name]
                notes.append(f"{h.name}: same session, frames and markers from training "
                             "(no refit)")
                check = _reregister(res.robot, h, twin, after[twin.name])
                e1, e2 = _errors_with(res.robot, h, xa), _errors_with(res.robot, h, check)
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
                xb = _reregister(robot, h, twin, before[twin.name] if twin else None)
                xa = _reregister(res.robot, h, twin, after[twin.name] if twin else None)
                what = f"marker/target from training block {twin.name!r}" if twin else \
                    "all its parameters"
                notes.append(f"{h.name}: instrument frame re-registered on the held-out "
                             f"data ({what})")
            eb.append(_errors_with(robot, h, xb))
            ea.append(_errors_with(res.robot, h, xa))
        comps.append(ErrorComparison("validation", "held-out" + _files(holdouts),
                                     merge_errors(eb), merge_errors(ea), "; ".join(notes)))
    return FlowResult(res, comps, seconds, warnings)


def _block(blocks: Sequence[Any], name: str) -> Any:
    return next(b for b in blocks if b.name == name)


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


def _reregister(robot: Any, h: Any, twin: Any, twin_values: np.ndarray | None) -> np.ndarray:
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


def _vec(values: dict[str, float], block: Any) -> np.ndarray:
    return np.array([values[n] for n in block.parameters().names])


def _files(blocks: Sequence[Any]) -> str:
    names = [Path(getattr(b, "source_path", "")).name for b in blocks]
    names = [n for n in names if n]
    return f" ({', '.join(names)})" if names else ""


def print_errors(out: Console, comparisons: Sequence[Any]) -> None:
    """The before/after table: RMS and max of every measured error kind (mm, deg, px)."""
    from kincal.report import error_keys, error_metrics, quantity

    captions = [escape(c.title) for c in comparisons if " (" in c.title]
    t = Table(title="Errors before -> after calibration", caption="; ".join(captions) or None)
    for c in ("data", "quantity", "n", "RMS before", "RMS after", "max before", "max after"):
        t.add_column(c, justify="left" if c in ("data", "quantity") else "right",
                     overflow="fold", no_wrap=c == "quantity")
    for c in comparisons:
        for k, key in enumerate(error_keys(c.before, c.after)):
            name, f, unit = quantity(key)
            b = error_metrics({key: c.before[key]}) if key in c.before else {}
            a = error_metrics({key: c.after[key]}) if key in c.after else {}
            t.add_row(escape(c.title.split(" (")[0]) if k == 0 else "", escape(f"{name} [{unit}]"),
                      str(a.get("n", b.get("n", ""))), _scaled(b.get(f"rms_{key}"), f),
                      f"[bold]{_scaled(a.get(f'rms_{key}'), f)}[/bold]",
                      _scaled(b.get(f"max_{key}"), f), _scaled(a.get(f"max_{key}"), f))
    out.print(t)


def _scaled(v: float | None, factor: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v * factor:.4f}"


def print_parameters(out: Console, res: Any, everything: bool = False) -> None:
    """Estimated parameters: nominal, estimate, change, std (mm / deg)."""
    d = res.to_dict()
    t = Table(title=f"Estimated parameters ({d['estimated_count']} of {len(d['parameters'])}; "
              "lengths mm, angles deg)")
    for c in ("parameter", "nominal", "estimate", "change", "std (1σ)", "status"):
        t.add_column(c, justify="left" if c in ("parameter", "status") else "right")
    for p in d["parameters"]:
        if not everything and not p["estimated"]:
            continue
        f = {"m": lambda v: _scaled(v, 1e3), "rad": lambda v: _scaled(v, 180 / math.pi)
             }.get(p["unit"], lambda v: f"{v:g}")
        t.add_row(escape(p["name"]), f(p["nominal"]), f(p["estimate"]),
                  f(p["estimate"] - p["nominal"]),
                  f(p["std"]) if p["std"] is not None else "-", escape(p["status"]))
    out.print(t)


def print_identifiability(out: Console, res: Any, limit: int = 8) -> None:
    """What the data could not identify, grouped by what absorbs it."""
    from kincal.report import identifiability_groups

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


def _write_outputs(res: Any, comparisons: list[Any], output: str | None,
                   urdf: str | None, json_out: str | None, report: str | None,
                   inputs: dict[str, str], truth: dict[str, float] | None = None,
                   extra: dict[str, Any] | None = None) -> dict[str, str]:
    """Render everything first (HTML, JSON, YAML, URDF text), then write each atomically,
    so a failure while rendering leaves no output behind."""
    from kincal.io import _jsonable, atomic_write_text
    from kincal.report import render_html, result_json
    from kincal.robots.files import robot_to_dict

    planned = {k: v for k, v in (("robot", output), ("urdf", urdf), ("report", report)) if v}
    texts: dict[str, str] = {}
    if report:
        texts["report"] = render_html(res, comparisons, inputs=inputs, truth=truth)
    if output:
        import yaml

        texts["robot"] = yaml.safe_dump(robot_to_dict(res.robot), sort_keys=False,
                                        default_flow_style=None, width=100)
    if urdf:
        if res.robot.meta.get("convention") != "urdf":
            from kincal.robots.urdf import urdf_text

            texts["urdf"] = urdf_text(res.robot)
    json_text = None
    if json_out:
        doc = result_json(res, comparisons, {"inputs": inputs, **(extra or {})})
        doc["outputs"] = planned
        json_text = json.dumps(doc, indent=2, default=_jsonable) + "\n"
    for key in ("robot", "urdf", "report"):
        if key in texts:
            atomic_write_text(planned[key], texts[key])
    if urdf and "urdf" not in texts:
        from kincal.robots.urdf import write_calibrated_urdf

        write_calibrated_urdf(None, res.robot, urdf)
    if json_text is not None and json_out:
        atomic_write_text(json_out, json_text)
    return planned


def _stages(text: str | None) -> list[str] | None:
    if not text:
        return None
    st = [s.strip() for s in text.split(",") if s.strip()]
    for s in st:
        if s not in ("offsets", "all", "registration"):
            raise KincalError(f"option --stages: unknown stage {s!r} (use offsets, all, "
                              "registration, comma separated)")
    return st


@app.command("calibrate")
def calibrate_cmd(
    robot: RobotArg, data: DataOpt,
    output: Annotated[str | None, typer.Option("-o", "--output", help="Calibrated robot file "
                                               "(YAML, SI units).")] = None,
    validate_files: Annotated[list[str] | None, typer.Option(
        "--validate", help="Held-out measurement CSV (repeatable): errors before/after.")
    ] = None,
    report: Annotated[str | None, typer.Option("--report", help="Write a single-file HTML "
                                               "report here.")] = None,
    json_out: JsonOpt = None,
    urdf: Annotated[str | None, typer.Option("--urdf", help="Also write the calibrated robot as "
                                             "URDF (URDF robots: the original file with "
                                             "corrected joint origins). Default for URDF "
                                             "robots: next to -o.")] = None,
    stages: Annotated[str | None, typer.Option("--stages", help="Comma-separated stages, e.g. "
                                               "'offsets,all' (encoder offsets first).")] = None,
    method: Annotated[str, typer.Option("--method", help="lm | gauss-newton.")] = "lm",
    loss: Annotated[str, typer.Option("--loss", help="linear | huber | cauchy (robust to "
                                      "outliers).")] = "linear",
    loss_scale: Annotated[float, typer.Option("--loss-scale", help="Robust threshold in "
                                              "standard deviations.")] = 3.0,
    free: Annotated[str | None, typer.Option("--free", help="Parameters to estimate: names, * "
                                             "patterns or role:offset (default: every "
                                             "identifiable one).")] = None,
    fix: Annotated[str | None, typer.Option("--fix", help="Parameters to hold at their "
                                            "nominal values.")] = None,
    max_iter: Annotated[int, typer.Option("--max-iter", min=1)] = 100,
    units: UnitsOpt = None, ignore: IgnoreOpt = None,
    validation_frames: Annotated[str, typer.Option(
        "--validation-frames", help="Instrument frames on held-out files: 'training' (same "
        "session: use the training frames and markers, no refit), 'register' (the "
        "instrument moved: refit its frame only), 'auto' (training when the file's name tag "
        "matches a training file's, else register).")] = "auto",
    truth: Annotated[str | None, typer.Option("--truth", help="Simulations: the true robot "
                                              "file, shown in the report.")] = None,
    all_parameters: Annotated[bool, typer.Option("--all", help="List every parameter, not only "
                                                 "the estimated ones.")] = False,
    base_link: BaseLink = None, tip_link: TipLink = None,
) -> None:
    """Calibrate ROBOT from measurement files: estimate the identifiable parameters, report
    errors before/after (training and held-out), write the calibrated robot, JSON and report."""
    out = _out(json_out)
    r = _load(robot, base_link, tip_link)
    if _is_fivebar(r):
        from kincal.cli.fivebar import calibrate_fivebar_file

        if len(data) != 1:
            raise KincalError("five-bar calibration takes one --data file")
        calibrate_fivebar_file(r, data[0], output, json_out, report, method)
        return
    if method not in ("lm", "gauss-newton"):
        raise KincalError(f"option --method: {method!r} is not lm or gauss-newton")
    if loss not in ("linear", "huber", "cauchy"):
        raise KincalError(f"option --loss: {loss!r} is not linear, huber or cauchy")
    all_files = list(data) + list(validate_files or [])
    for p in all_files:
        if not Path(p).is_file():
            raise MeasurementFileError("no such measurement file", source=p)
    _check_options_used(all_files, units, ignore)
    blocks = read_blocks(data, r, units, ignore, out)
    holdouts = read_blocks(validate_files or [], r, units, ignore, out)
    truth_values = _truth_values(truth, r) if truth else None
    if urdf is None and output and r.meta.get("convention") == "urdf":
        urdf = str(Path(output).with_suffix(".urdf"))
    flow = run_flow(r, blocks, holdouts, free=free, fix=fix, stages=_stages(stages),
                    method=method, loss=loss, loss_scale=loss_scale, max_iter=max_iter,
                    validation_frames=validation_frames, progress=json_out != "-")
    res = flow.result
    inputs = {"robot": robot, "data": ", ".join(data),
              "validation": ", ".join(validate_files or []) or "-",
              "method": method, "loss": loss, "stages": stages or "all",
              "validation frames": validation_frames,
              "free": free or "automatic (identifiable set)", "fixed": fix or "-"}
    written = _write_outputs(res, flow.comparisons, output, urdf, json_out, report, inputs,
                             truth_values, {"seconds": flow.seconds})
    conv = "[green]converged[/green]" if res.converged else "[red]did not converge[/red]"
    out.print(f"{conv} in {res.iterations} iterations ({flow.seconds:.2f} s), "
              f"{len(res.estimated)} parameters estimated, sigma0 = {res.sigma0:.3g}")
    print_parameters(out, res, all_parameters)
    print_errors(out, flow.comparisons)
    print_identifiability(out, res)
    for w in flow.warnings:
        out.print(f"[yellow]warning[/yellow]: {escape(w)}")
    if res.outliers:
        out.print(f"[yellow]{len(res.outliers)} outlier measurement(s)[/yellow]: " + ", ".join(
            f"{b} row {i + 1}" for b, i in res.outliers[:10]))
    for k, v in written.items():
        out.print(f"{k}: {escape(v)}")


def _truth_values(path: str, robot: Any) -> dict[str, float]:
    """True parameter values from a robot file (and instrument truth from its notes)."""
    t = _load(path)
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


# --------------------------------------------------------------------------- validate
def _extras_from_result(path: str) -> dict[str, float]:
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        return {p["name"]: float(p["estimate"]) for p in doc["parameters"]}
    except FileNotFoundError:
        raise KincalError("no such result file", source=path) from None
    except (ValueError, KeyError, TypeError) as exc:
        raise KincalError(f"not a kincal result JSON ({exc.__class__.__name__}: {exc})",
                          source=path) from None


@app.command("validate")
def validate_cmd(
    robot: RobotArg, data: DataOpt,
    result: Annotated[str | None, typer.Option("--result", help="Result JSON of `kincal "
                                               "calibrate`: use its instrument frames and "
                                               "markers as they are (same session, no refit)."
                                               )] = None,
    nominal: Annotated[str | None, typer.Option("--before", help="Also evaluate this robot "
                                                "(e.g. the nominal one) the same way, for a "
                                                "before/after table.")] = None,
    units: UnitsOpt = None, ignore: IgnoreOpt = None,
    base_link: BaseLink = None, tip_link: TipLink = None, json_out: JsonOpt = None,
) -> None:
    """Errors of ROBOT on held-out measurements: RMS, mean and max of every measured kind
    (position, orientation, range ...).

    Without --result each file's instrument parameters (frame and marker) are re-registered
    to the robot: they absorb a little of any robot error."""
    from kincal.identify.validation import validate
    from kincal.io import write_json
    from kincal.report import ErrorComparison, error_keys, error_metrics, quantity

    out = _out(json_out)
    r = _serial(_load(robot, base_link, tip_link), "validate")
    before = _serial(_load(nominal, base_link, tip_link), "validate") if nominal else None
    _check_options_used(data, units, ignore)
    blocks = read_blocks(data, r, units, ignore, out)
    extras = _extras_from_result(result) if result else None
    files: dict[str, Any] = {}
    comps = []
    for b in blocks:
        if extras is not None:
            xa = _vec(validate(r, [b], extras=extras)["extras"][b.name], b)
        else:
            xa = _reregister(r, b, None, None)
        ea = _errors_with(r, b, xa)
        eb = ea
        if before is not None:
            xb = _vec(validate(before, [b], extras=extras)["extras"][b.name], b) \
                if extras is not None else _reregister(before, b, None, None)
            eb = _errors_with(before, b, xb)
        how = "frames from " + result if result else "instrument re-registered on this file"
        comps.append(ErrorComparison("validation", Path(b.source_path).name, eb, ea, how))
        files[b.source_path] = {**error_metrics(ea), "protocol": how}
        if before is not None:
            files[b.source_path]["before"] = error_metrics(eb)
    if before is not None:
        print_errors(out, comps)
    else:
        t = Table(title=f"Errors of {escape(r.name)} on held-out data")
        for c in ("file", "quantity", "n", "RMS", "mean", "max"):
            t.add_column(c, justify="left" if c in ("file", "quantity") else "right")
        for c in comps:
            for k, key in enumerate(error_keys(c.after)):
                name, f, unit = quantity(key)
                m = error_metrics({key: c.after[key]})
                t.add_row(escape(c.title) if k == 0 else "", escape(f"{name} [{unit}]"),
                          str(m["n"]),
                          *(_scaled(m.get(f"{s}_{key}"), f) for s in ("rms", "mean", "max")))
        out.print(t)
    out.print(f"[dim]protocol: {escape(comps[0].note)}[/dim]")
    if json_out:
        from kincal.report import merge_errors

        overall = error_metrics(merge_errors([c.after for c in comps]))
        doc: dict[str, Any] = {"robot": r.name, "overall": overall, "files": files}
        if before is not None:
            doc["overall_before"] = error_metrics(merge_errors([c.before for c in comps]))
        write_json(json_out, doc)


# --------------------------------------------------------------------------- compensate
def _target_fields() -> tuple[Any, ...]:
    from kincal.measure.files import Field

    return (Field(r"[xyz]", "length", "x, y, z"),
            Field(r"r[xyz]", "angle", "rx, ry, rz (roll-pitch-yaw)"))


def read_targets(path: str, robot: Any, units: str | None, ignore: Sequence[str] | None
                 ) -> tuple[np.ndarray, np.ndarray | None, Any]:
    """Targets (N, 4, 4) poses or (N, 3) positions, optional joint seeds (N, n), the table."""
    from kincal.measure.files import (
        parse_list_option,
        parse_units_option,
        read_header,
        read_table,
        split_unit,
    )
    from kincal.spatial import homogeneous, rpy_to_matrix

    if not Path(path).is_file():
        raise MeasurementFileError("no such targets file", source=path)
    names = read_header(path)[1]
    has_joints = any(split_unit(n)[0] in robot.joint_names or n in robot.joint_names
                     for n in names)
    t = read_table(path, robot, _target_fields(), parse_units_option(units),
                   parse_list_option(ignore), joints=has_joints)
    for c in "xyz":
        if c not in t.values:
            raise t.error(f"missing target column {c!r} (with its unit, e.g. {c}_mm)")
    p = np.stack([t.values[c] for c in "xyz"], axis=1)
    rot = [c for c in ("rx", "ry", "rz") if c in t.values]
    if rot and len(rot) != 3:
        raise t.error("orientation targets need all of rx, ry, rz (roll-pitch-yaw)")
    targets = homogeneous(rpy_to_matrix(np.stack([t.values[c] for c in ("rx", "ry", "rz")],
                                                 axis=1)), p) if rot else p
    return targets, (t.q if has_joints else None), t


@app.command("compensate")
def compensate_cmd(
    calibrated: Annotated[str, typer.Argument(help="The calibrated robot file (from `kincal "
                                              "calibrate -o`).")],
    targets: Annotated[str, typer.Option("--targets", "-t", help="Target CSV: x, y, z (and rx, "
                                         "ry, rz roll-pitch-yaw) with units; optional joint "
                                         "columns seed the IK.")],
    output: Annotated[str, typer.Option("-o", "--output", help="Joint commands CSV to write.")],
    nominal: Annotated[str | None, typer.Option("--nominal", help="The controller's nominal "
                                                "robot: needed for --filtered, and seeds the IK "
                                                "on the controller's branch.")] = None,
    filtered: Annotated[str | None, typer.Option("--filtered", help="Write filtered targets "
                                                 "here: FK_nominal(q_cmd), to send to a "
                                                 "controller that only knows the nominal "
                                                 "model.")] = None,
    units: UnitsOpt = None, ignore: IgnoreOpt = None,
    length_unit: LengthUnit = "m", angle_unit: AngleUnit = "rad",
    base_link: BaseLink = None, tip_link: TipLink = None, json_out: JsonOpt = None,
) -> None:
    """Joint commands that put the calibrated (real) robot on the targets, and filtered
    targets for a controller that only knows the nominal model."""
    from kincal.compensate import compensate, require_all
    from kincal.io import write_json
    from kincal.measure.files import format_table, joint_columns
    from kincal.spatial import matrix_to_rpy

    out = _out(json_out)
    cal = _serial(_load(calibrated, base_link, tip_link), "compensate")
    nom = _serial(_load(nominal, base_link, tip_link), "compensate") if nominal else None
    if filtered and nom is None:
        raise KincalError("--filtered needs --nominal (the controller's model)")
    _check_unit(length_unit, "length", "--length-unit")
    _check_unit(angle_unit, "angle", "--angle-unit")
    T, seeds, table = read_targets(targets, cal, units, ignore)
    comp = compensate(cal, T, nominal=nom, q0=seeds)
    require_all(comp, targets, table.lines)
    from kincal.measure.files import UNITS

    cols = [(name, comp.q[:, k] * f) for k, (name, f) in
            enumerate(joint_columns(cal, cal.n, angle_unit, length_unit))]
    jtext = format_table(cols, comments=[f"joint commands for {cal.name} from {targets}: "
                                         "the calibrated robot reaches each target"])
    ftext = None
    if filtered and comp.filtered is not None:
        lf, af = 1.0 / UNITS[length_unit][1], 1.0 / UNITS[angle_unit][1]
        F = comp.filtered
        fcols = [(f"{c}_{length_unit}", F[:, i, 3] * lf) for i, c in enumerate("xyz")]
        if comp.mask == "pose":
            rpy = matrix_to_rpy(F[:, :3, :3])
            fcols += [(f"{c}_{angle_unit}", rpy[:, i] * af)
                      for i, c in enumerate(("rx", "ry", "rz"))]
        ftext = format_table(fcols, comments=["filtered targets: send these to the nominal "
                                              "controller (its IK gives the joint commands)"])
    from kincal.io import atomic_write_text

    atomic_write_text(output, jtext)
    if ftext is not None and filtered:
        atomic_write_text(filtered, ftext)
    out.print(f"{len(comp)} targets ({comp.mask}): calibrated FK of the commands matches the "
              f"targets to {np.max(comp.position_error) * 1e3:.2e} mm"
              + (f" / {math.degrees(np.max(comp.orientation_error)):.2e} deg"
                 if comp.mask == "pose" else ""))
    if comp.branch_changes.size:
        lines = ", ".join(str(int(table.lines[i])) for i in comp.branch_changes[:10])
        out.print(f"[yellow]warning[/yellow]: {comp.branch_changes.size} target(s) (lines "
                  f"{lines}) needed a different joint configuration than the nominal IK "
                  "(near a singularity or a limit); check them before sending.")
    if comp.correction is not None:
        out.print(f"compensation size |filtered - target|: RMS "
                  f"{math.sqrt(np.mean(comp.correction**2)) * 1e3:.4f} mm, max "
                  f"{np.max(comp.correction) * 1e3:.4f} mm")
    out.print(f"joint commands -> {escape(output)}"
              + (f"; filtered targets -> {escape(filtered)}" if ftext else ""))
    if json_out:
        doc = {"robot": cal.name, "targets": targets, "mask": comp.mask,
               "branch_changes": comp.branch_changes,
               "q": comp.q, "position_error_m": comp.position_error,
               "orientation_error_rad": comp.orientation_error,
               "joint_names": list(cal.joint_names), "output": output}
        if comp.filtered is not None:
            doc["filtered"] = comp.filtered
            doc["correction_m"] = comp.correction
        write_json(json_out, doc)


# --------------------------------------------------------------------------- demo
@app.command()
def demo(
    out_dir: Annotated[str, typer.Option("--out", help="Folder for the demo's files.")
                       ] = "kincal-demo",
    seed: Annotated[int, typer.Option(help="Random seed.")] = 7,
    poses: Annotated[int, typer.Option(min=10, help="Training poses.")] = 80,
    holdout_poses: Annotated[int, typer.Option(min=1, help="Held-out poses.")] = 40,
    noise_mm: Annotated[float, typer.Option(help="Tracker noise per coordinate [mm].")
                        ] = 0.01,
) -> None:
    """A complete calibration in ~10 s: PUMA 560 measured by a simulated laser tracker,
    calibrated, validated on held-out poses; writes the report into ./kincal-demo/."""
    from kincal.measure.registry import get_instrument, simulate_measurements, write_measurements
    from kincal.measure.simulate import perturb_robot
    from kincal.robots.files import load_robot, write_robot_yaml

    t0 = time.perf_counter()
    folder = Path(out_dir)
    nominal = load_robot("puma560")
    rng = np.random.default_rng(seed)
    true = perturb_robot(nominal, rng, length_std=5e-4, angle_std=math.radians(0.05),
                         offset_std=math.radians(0.1))
    inst = get_instrument("position")
    train, inst_truth = simulate_measurements(inst, true, rng, poses, noise_mm * 1e-3,
                                              {"name": "tracker"})
    held, _ = simulate_measurements(inst, true, rng, holdout_poses, noise_mm * 1e-3,
                                    {"name": "tracker"}, truth=inst_truth)
    console.print(f"[bold]kincal demo[/bold]: PUMA 560 with injected geometric errors "
                  f"(lengths 0.5 mm, angles 0.05°, encoder offsets 0.1°), measured by a "
                  f"simulated laser tracker (noise {noise_mm} mm) at {poses} poses; "
                  f"{holdout_poses} more poses held out.")
    folder.mkdir(parents=True, exist_ok=True)
    files = {"train": folder / "train.csv", "holdout": folder / "holdout.csv",
             "truth": folder / "truth.yaml"}
    units = {"length": "mm", "angle": "deg"}
    write_measurements(inst, train, files["train"], units, nominal)
    write_measurements(inst, held, files["holdout"], units, nominal)
    write_robot_yaml(true, files["truth"])
    for b, p in ((train[0], files["train"]), (held[0], files["holdout"])):
        b.source_path = str(p)
    flow = run_flow(nominal, train, held, stages=["offsets", "all"])
    res = flow.result
    truth_vals = {**true.params(), **inst_truth}
    inputs = {"robot": "puma560 (built-in)", "data": str(files["train"]),
              "validation": str(files["holdout"]), "truth": str(files["truth"]),
              "stages": "offsets, all", "method": "lm"}
    _write_outputs(res, flow.comparisons, str(folder / "calibrated.yaml"), None,
                   str(folder / "result.json"), str(folder / "report.html"), inputs, truth_vals)
    conv = "converged" if res.converged else "did NOT converge"
    console.print(f"calibration {conv} in {res.iterations} iterations "
                  f"({flow.seconds:.2f} s); {len(res.estimated)} parameters estimated.")
    print_errors(console, flow.comparisons)
    # Independent check against the truth: the measured point predicted by the calibrated
    # model vs the true robot on the held-out poses, in the tracker frame.
    q = held[0].q
    yt = held[0].predict(true, _vec(inst_truth, held[0]))
    yc = held[0].predict(res.robot, res.theta[res.problem.block_slice("tracker")])
    dev = np.linalg.norm((yc - yt).reshape(-1, 3), axis=1)
    console.print(f"model vs truth on the {len(q)} held-out poses (noise-free): RMS "
                  f"{math.sqrt(np.mean(dev**2)) * 1e3:.4f} mm, max {np.max(dev) * 1e3:.4f} mm")
    print_identifiability(console, res)
    for w in flow.warnings:
        console.print(f"[yellow]warning[/yellow]: {escape(w)}")
    console.print(f"report: [bold]{escape(str(folder / 'report.html'))}[/bold]  (also "
                  f"calibrated.yaml, result.json, train.csv, holdout.csv, truth.yaml in "
                  f"{escape(str(folder))}/)   [{time.perf_counter() - t0:.1f} s]")
