"""Setup files on the command line: ``--config setup.yaml`` and ``kincal init``.

:func:`uses_setup` wraps a command so that ``--config FILE`` fills every option the
command line did not give from the setup file (:mod:`kincal.workflow.config`): the
robot, its links, ``data:`` and ``validate:`` (as
:class:`~kincal.workflow.sources.DataSource`, each with its own reading options),
every ``calibration:`` key (the option of the same long name) and ``outputs:``.
Flags win: ``--data`` on the command line replaces the file's ``data:`` list.

``kincal init ROBOT --data F`` writes a commented setup file from what it finds in the
data files.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.common import BaseLink, RobotArg, TipLink, console, err_console
from kincal.errors import KincalError

ConfigOpt = Annotated[str | None, typer.Option(
    "--config", metavar="SETUP.yaml", help="Setup file holding the robot, data files (each "
    "with its own --units/--ignore/instrument), calibration options and outputs (`kincal "
    "init` writes one); options on the command line override it.")]
HoldOpt = Annotated[list[str] | None, typer.Option(
    "--hold", metavar="JOINT=VALUE", help="A joint that never moves, held at this value "
    "with its unit (e.g. tool_mount_joint=0deg); repeatable.")]
InstrumentOpt = Annotated[str | None, typer.Option(
    "--instrument", "-i", help="Read the data files as this instrument (overrides their tag "
    "line), e.g. two-socket for a folder of per-socket files.")]
OptionOpt = Annotated[list[str] | None, typer.Option(
    "--option", metavar="KEY=VALUE", help="Instrument option for the data files, with its "
    "unit (repeatable): length=50mm, probe=tool, point_std=0.05mm.")]

#: Where ``ctx.meta`` keeps the loaded setup for the command.
SETUP_META = "kincal.setup"


def _long_options(command: Any) -> dict[str, str]:
    """``{"--cross-validate": "cross_validate", ...}`` of a click command."""
    out = {}
    for p in command.params:
        for o in getattr(p, "opts", []):
            if o.startswith("--"):
                out[o] = p.name
    return out


def setup_values(setup: Any, command: Any) -> dict[str, Any]:
    """``{parameter name: value}`` a setup gives a command (click parameter names)."""
    opts = _long_options(command)
    vals: dict[str, Any] = {}

    def put(key: str, value: Any, what: str) -> None:
        name = opts.get("--" + key.replace("_", "-"))
        if name is None:
            raise KincalError(f"{setup.where(what, key) if what else setup.where(key)}: "
                              f"`kincal {command.name}` has no option --"
                              f"{key.replace('_', '-')}")
        vals[name] = value

    if setup.robot is not None:
        vals["robot"] = setup.robot
    for key in ("base_link", "tip_link"):
        if getattr(setup, key) is not None:
            put(key, getattr(setup, key), "")
    if setup.data:
        put("data", list(setup.data), "")
    if setup.validate:
        put("validate", list(setup.validate), "")
    for k, v in setup.calibration.items():
        put(k, v, "calibration")
    for k, v in setup.outputs.items():
        put(k, v, "outputs")
    return vals


def uses_setup(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Let a command take ``--config FILE``: options not on the command line come from it.

    The command's first parameter must be ``ctx: typer.Context`` and it must have a
    ``config`` parameter; the loaded :class:`~kincal.workflow.config.Setup` is in
    ``ctx.meta["kincal.setup"]`` (:func:`current_setup`).
    """

    @functools.wraps(fn)
    def wrapper(ctx: typer.Context, **kwargs: Any) -> Any:
        path = kwargs.get("config")
        if path:
            from kincal.workflow.config import load_setup

            setup = load_setup(path)
            ctx.meta[SETUP_META] = setup
            for name, value in setup_values(setup, ctx.command).items():
                source = ctx.get_parameter_source(name)
                if getattr(source, "name", "") != "COMMANDLINE":
                    kwargs[name] = value
        return fn(ctx, **kwargs)

    return wrapper


def current_setup(ctx: typer.Context) -> Any:
    """The setup of the running command's ``--config`` (None without one)."""
    return ctx.meta.get(SETUP_META)


def require_robot(robot: str | None, command: str) -> str:
    """ROBOT from the command line or the setup file; a one-line error without either."""
    if not robot:
        raise KincalError(f"`kincal {command}` needs ROBOT (a built-in name, a YAML or URDF "
                          "file) or --config with robot:")
    return robot


def parse_pairs(items: Sequence[str] | None, option: str, example: str, sep: str = ","
                ) -> dict[str, str]:
    """``KEY=VALUE`` items of a repeatable option (also ``sep`` separated) -> a dict."""
    out: dict[str, str] = {}
    for item in items or []:
        for part in item.split(sep):
            if not part.strip():
                continue
            key, eq, value = (s.strip() for s in part.partition("="))
            if not eq or not key or not value:
                raise KincalError(f"option {option}: {part.strip()!r} is not KEY=VALUE "
                                  f"(e.g. {example})")
            out[key] = value
    return out


def parse_hold(items: Sequence[str] | None) -> dict[str, str]:
    """``--hold JOINT=VALUE`` items -> ``{joint: value text}``."""
    return parse_pairs(items, "--hold", "tool_mount_joint=0deg")


def held_robot(ctx: typer.Context, robot: Any, hold: Sequence[str] | None) -> Any:
    """``robot`` with the joints of ``--hold`` and of the setup's ``hold:`` held."""
    from kincal.workflow.config import hold_robot, parse_setup

    setup = current_setup(ctx)
    if setup is not None and setup.hold:
        robot = hold_robot(robot, setup)
    given = parse_hold(hold)
    if given:
        robot = hold_robot(robot, parse_setup({"hold": given}, "."))
    return robot


def as_sources(*groups: Sequence[Any] | None, units: str | None = None,
               ignore: Sequence[str] | None = None, instrument: str | None = None,
               options: Sequence[str] | None = None) -> list[list[Any]]:
    """Measurement sources, one list per group (``--data``, ``--validate``), from the
    command line (paths) or the setup file (sources).

    Paths take ``--units`` / ``--ignore`` (each entry for the files it matches, in any
    group; an entry matching none is an error), ``--instrument`` and ``--option``;
    sources from a setup file carry their own, and take ``--instrument`` / ``--option``
    when given on the command line.
    """
    import dataclasses

    from kincal.workflow.sources import DataSource, instrument_tags, sources_from_options

    opts = parse_option_items(options)
    lists = [list(g or []) for g in groups]
    paths = [f for g in lists for f in g if not isinstance(f, DataSource)]
    converted = iter(sources_from_options(paths, units, ignore, instrument, opts)
                     if paths else [])
    tags = instrument_tags(opts)
    out = []
    for g in lists:
        group = []
        for f in g:
            if not isinstance(f, DataSource):
                group.append(next(converted))
            elif instrument or tags:
                group.append(dataclasses.replace(f, instrument=instrument or f.instrument,
                                                 tags={**f.tags, **tags}))
            else:
                group.append(f)
        out.append(group)
    return out


def parse_option_items(items: Sequence[str] | None) -> dict[str, str]:
    """``--option KEY=VALUE`` items (also ``;`` separated) -> ``{key: value}``."""
    return parse_pairs(items, "--option", "length=50mm", sep=";")


# --------------------------------------------------------------------------- kincal init
def _yaml_scalar(value: Any) -> str:
    import yaml

    return yaml.safe_dump(value, default_flow_style=True, width=10**6).strip().removesuffix(
        "\n...").strip()


def _relative(path: str, base: Path) -> str:
    import os

    try:
        return os.path.relpath(Path(path).resolve(), base.resolve())
    except ValueError:
        return str(Path(path).resolve())


def _guess_units(path: str, robot: Any) -> tuple[dict[str, str], list[str]]:
    """Units for bare measurement columns, guessed from their magnitudes (for people to
    check), and notes on what was guessed."""
    import numpy as np

    from kincal.measure.files import LOOKS_MEASURED, read_header, split_unit

    _, names, line = read_header(path)
    joints = set(getattr(robot, "joint_names", ()))
    bare = [n for n in names if split_unit(n)[1] is None and n not in joints
            and LOOKS_MEASURED.fullmatch(n)]
    if not bare:
        return {}, []
    from kincal.measure.dialect import normalise, sniff

    text = Path(path).read_text(encoding="utf-8-sig").splitlines()
    rows = [r for r in text[line:] if r.strip() and not r.lstrip().startswith("#")][:200]
    rows = normalise(rows, sniff(text[line - 1], rows, path, line))   # ';' and ',' decimals
    import csv

    cols = {n: i for i, n in enumerate(names)}
    units: dict[str, str] = {}
    notes = []
    families: dict[str, list[str]] = {}
    for n in bare:
        fam = n.rstrip("0123456789") + ("?" if n[-1:].isdigit() else "")
        families.setdefault(fam, []).append(n)
    for fam, members in families.items():
        vals = []
        for r in csv.reader(rows):
            for n in members:
                try:
                    vals.append(abs(float(r[cols[n]])))
                except (ValueError, IndexError):
                    pass
        if not vals:
            continue
        big = float(np.percentile(vals, 95))
        if fam.startswith(("x", "y", "z")):
            unit = "m" if big < 5 else "mm"
        elif fam.startswith(("r", "roll", "pitch", "yaw")):
            unit = "rad" if big <= math.pi + 1e-6 else "deg"
        else:
            continue
        units[fam] = unit
        notes.append(f"{fam}: {unit} (CHECK: guessed from the values, 95% below {big:.4g})")
    return units, notes


def _held_out_frames(f: str, data: Sequence[str]) -> list[str]:
    """The ``frames:`` line of held-out file ``f``, from what the files say: ``training``
    when its ``name=`` tag is a training file's (the user stated one instrument set-up),
    else ``register`` (another set-up: its frame is refitted), marked CHECK."""
    from kincal.measure.files import read_header
    from kincal.workflow.sources import detect_format

    name = read_header(f)[0].get("name")
    shared = [d for d in data if detect_format(d) == "kincal" and name is not None
              and read_header(d)[0].get("name") == name]
    if shared:
        return [f"    frames: training     # same instrument set-up: name={name} as in "
                f"{Path(shared[0]).name}"]
    return ["    frames: register     # CHECK: no name= shared with a training file, so another",
            "                         # instrument set-up: its frame is refitted here. Write",
            "                         # training only if it is the same set-up (nothing moved)"]


def _column_map_hint(names: Sequence[str]) -> list[str]:
    """Commented ``columns:`` maps for observation columns under a prefix (``meas_x``,
    ``meas_std_x`` ...) when the file has no plain ``x, y, z``: one per candidate prefix,
    marked CHECK (the units and which prefix is the measurement are the user's)."""
    import re

    if {"x", "y", "z"} <= {n.rsplit("_", 1)[0] for n in names} | set(names):
        return []
    out = []
    for m in dict.fromkeys(re.fullmatch(r"(.+?[_ ])x", n) for n in names):
        if m is None:
            continue
        pre = m.group(1)
        if pre.lower().endswith(("std_", "std ", "sigma_", "sigma ")) or \
                not all(f"{pre}{c}" in names for c in "yz"):
            continue
        entry = {f"{pre}{c}": f"{c}_mm" for c in "xyz"}
        entry |= {f"{pre}{c}": f"{c}_deg" for c in ("rx", "ry", "rz") if f"{pre}{c}" in names}
        entry |= {f"{pre}std_{c}": f"sigma_{c}_{'deg' if c[0] == 'r' else 'mm'}"
                  for c in ("x", "y", "z", "rx", "ry", "rz") if f"{pre}std_{c}" in names}
        out.append(f"    # columns: {_yaml_scalar(entry)}    # CHECK: are {pre!r}* the "
                   "measurements, and these their units?")
    return out


def data_checks(blocks: Sequence[Any], robot: Any) -> dict[str, list[str]]:
    """What a person should know about each file before calibrating: ``{file: [line]}``.

    * no standard deviation stated (no ``sigma`` column, no ``sigma_<unit>`` tag): every
      row then weighs as the default 0.01 mm, whatever the instrument;
    * a joint that never moves (range below 1e-4 rad / m over the file): its parameters
      cannot be identified from this file; hold it at its value.
    """
    import numpy as np

    from kincal.measure.files import HELD_TOLERANCE

    out: dict[str, list[str]] = {}
    for b in blocks:
        table = b.provenance.table if b.provenance is not None else None
        path = b.provenance.path if b.provenance is not None else ""
        lines = out.setdefault(path, [])
        if table is not None and not any(k.startswith("sigma") for k in table.values) and \
                not any(k.startswith("sigma") for k in table.tags):
            lines.append("no sigma column or sigma_<unit> option: every row weighs as 0.01 mm; "
                         "state the instrument's (options: {sigma: 0.05mm})")
        q = np.asarray(getattr(b, "q", np.zeros((0, 0))), dtype=float)
        joints = list(getattr(robot, "joints", []))
        if q.ndim == 2 and len(q) > 1:
            span = q.max(axis=0) - q.min(axis=0)
            for k in np.flatnonzero(span < HELD_TOLERANCE):
                j = joints[k].name if k < len(joints) else f"{k + 1}"
                value = (f"{np.degrees(q[0, k]):.4g}deg" if k >= len(joints) or
                         joints[k].kind == "revolute" else f"{q[0, k] * 1000:.4g}mm")
                lines.append(f"joint {j} never moves (range {span[k]:.2g} over {len(q)} rows): "
                             f"its parameters are not identifiable here; hold it (hold: "
                             f"{{{j}: {value}}})")
    return {k: v for k, v in out.items() if v}


def setup_text(robot: str, robot_obj: Any, data: Sequence[str], validate: Sequence[str],
               base_link: str | None, tip_link: str | None, base: Path,
               checks: dict[str, list[str]] | None = None) -> str:
    """The text of a commented setup file for ``robot`` and these files (``checks``: lines
    to mark CHECK under a file, from :func:`data_checks`)."""
    from kincal.measure.files import read_header
    from kincal.workflow.config import CALIBRATION_KEYS
    from kincal.workflow.sources import detect_format

    lines = ["# kincal setup file: kincal calibrate --config THIS_FILE",
             "# Paths are relative to this file. Options given on the command line override",
             "# the values here. Written by `kincal init`; check every line marked CHECK.",
             ""]
    is_file = Path(robot).exists()
    lines.append(f"robot: {_yaml_scalar(_relative(robot, base) if is_file else robot)}"
                 "    # built-in name, YAML or URDF robot file")
    if base_link:
        lines.append(f"base_link: {_yaml_scalar(base_link)}")
    if tip_link:
        lines.append(f"tip_link: {_yaml_scalar(tip_link)}")
    joints = list(getattr(robot_obj, "joint_names", ()))
    lines.append(f"# hold: {{{joints[-1] if joints else 'JOINT'}: 0deg}}    # joints that "
                 "never move, at this value")
    for key, files in (("data", data), ("validate", validate)):
        if not files:
            continue
        lines += ["", f"{key}:" + ("    # training files, each with its own reading "
                                   "options" if key == "data" else
                                   "    # held-out files: errors before/after")]
        for f in files:
            lines.append(f"  - file: {_yaml_scalar(_relative(f, base))}")
            lines += [f"    # CHECK: {c}" for c in (checks or {}).get(f, [])]
            if Path(f).is_dir():
                lines += ["    format: mukca        # a folder of per-socket files (radians)",
                          "    instrument: two-socket",
                          "    options: {length: 50mm, probe: tool}    # CHECK: the "
                          "socket distance and the probe"]
                continue
            if detect_format(f) == "ros-industrial":
                lines += ["    format: ros-industrial    # a ROS-I observation YAML (pose "
                          "instrument, static camera)",
                          "    name: camera"]
                continue
            tags, names, _ = read_header(f)
            units, notes = _guess_units(f, robot_obj)
            if units:
                lines.append(f"    units: {_yaml_scalar(units)}")
                lines += [f"    # {n}" for n in notes]
            if not tags:
                lines.append("    # name: mocap          # the instrument's name (its "
                             "parameters are NAME.x ...)")
            else:
                lines.append(f"    # tag line: {'; '.join(f'{k}={v}' for k, v in tags.items())}")
            lines.append(f"    # columns: {', '.join(names)}")
            lines += _column_map_hint(names)
            if key == "validate":
                lines += _held_out_frames(f, data)
    lines += ["", "calibration:              # every `kincal calibrate` option, by its long "
              "name"]
    for k, spec in CALIBRATION_KEYS.items():
        example = {"free": "[role:offset]", "fix": "[]", "prior": "{'*.origin.*': 1mm}",
                   "joint_model": "[hysteresis]", "stages": "[offsets, all]",
                   "procedure": "lm", "method": "lm", "loss": "linear", "loss_scale": "3",
                   "max_iter": "100", "cross_validate": "10",
                   "validation_frames": "auto", "condition_growth": "1.5", "cycles": "1",
                   "tolerance": "0.1um", "truth": "truth.yaml", "all": "false",
                   "force": "false"}.get(k, "...")
        lines.append(f"  # {k}: {example}    # {spec.help}")
    lines += ["", "outputs:", "  output: calibrated.yaml", "  json: result.json",
              "  report: report.html"]
    if getattr(robot_obj, "meta", {}).get("convention") == "urdf":
        lines.append("  urdf: calibrated.urdf")
    return "\n".join(lines) + "\n"


@app.command("init")
def init_cmd(
    robot: RobotArg,
    data: Annotated[list[str], typer.Option("--data", "-d", help="Training measurement file "
                                            "(repeatable); a folder of per-socket files is "
                                            "read as MUKCa data.")],
    validate: Annotated[list[str] | None, typer.Option("--validate", help="Held-out "
                                                       "measurement file (repeatable).")
                        ] = None,
    output: Annotated[str, typer.Option("-o", "--output", help="Setup file to write.")
                      ] = "setup.yaml",
    force: Annotated[bool, typer.Option("--force", help="Replace an existing setup file.")
                     ] = False,
    base_link: BaseLink = None, tip_link: TipLink = None,
) -> None:
    """Write a commented setup file for ROBOT and these data files (`kincal calibrate
    --config` reads it): the units of bare columns, the columns found, every calibration
    option with an example."""
    import yaml

    from kincal.io import atomic_write_text, check_outputs
    from kincal.workflow.config import parse_setup
    from kincal.workflow.robots import load_any_robot
    from kincal.workflow.sources import read_sources

    files = list(data) + list(validate or [])
    check_outputs({"-o": output}, {"--data": list(data), "--validate": list(validate or [])})
    if Path(output).exists() and not force:
        raise KincalError(f"option -o: {output!r} exists; use --force to replace it")
    r = load_any_robot(robot, base_link=base_link, tip_link=tip_link)
    for f in files:
        if not Path(f).exists():
            raise KincalError("no such measurement file", source=f)
    base = Path(output).resolve().parent
    text = setup_text(robot, r, list(data), list(validate or []), base_link, tip_link, base)
    parsed = yaml.safe_load(text)
    setup = parse_setup(parsed, base, source=output)
    problems = []
    blocks = []
    for src in setup.data + setup.validate:
        try:
            blocks += read_sources([src], r)
        except KincalError as exc:
            problems.append(str(exc))
    by_path = {str(s.path): f for s, f in zip(setup.data + setup.validate, files, strict=True)}
    checks = {by_path.get(k, k): v for k, v in data_checks(blocks, r).items()}
    if checks:
        text = setup_text(robot, r, list(data), list(validate or []), base_link, tip_link,
                          base, checks)
        for f, lines in checks.items():
            for c in lines:
                err_console.print(f"[yellow]warning:[/yellow] {escape(f)}: {escape(c)}")
    if problems:
        text += "\n# Reading the files with these settings failed (fix, then run kincal " \
                "calibrate --config):\n" + "".join(f"#   {p}\n" for p in problems)
    atomic_write_text(output, text)
    console.print(f"wrote {output}: robot {getattr(r, 'name', robot)}, {len(data)} data and "
                  f"{len(validate or [])} validation file(s)"
                  + (f"; [yellow]{len(problems)} file(s) do not read yet[/yellow] (see the end "
                     "of the file)" if problems else "")
                  + f"\nnext: kincal calibrate --config {output}")
