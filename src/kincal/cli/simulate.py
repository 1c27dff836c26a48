"""Simulation commands: ``instruments`` and ``simulate``.

``kincal simulate`` builds a true robot (nominal + random geometric errors), measures
it with a registered instrument plus noise, and writes the measurement CSV (and the
truth) for ``kincal calibrate``.  Everything is computed before anything is written;
every file is written atomically.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.calibration_common import (
    AngleUnit,
    JsonOpt,
    LengthUnit,
    check_unit,
    load,
    out_console,
    serial,
)
from kincal.cli.common import BaseLink, RobotArg, TipLink, console
from kincal.cli.options import SeedOpt, SiOpt, Units, quantity
from kincal.errors import KincalError
from kincal.io import check_outputs

if TYPE_CHECKING:                 # types only: the workflow loads lazily (start-up time)
    from rich.console import Console

    from kincal.workflow.simulation import SimulatedExperiment

#: First-class artifact flags -> the instrument options they set (first one present) and
#: the dimension of their value.
ARTIFACT_FLAGS: dict[str, tuple[tuple[str, ...], str]] = {
    "--placements": (("placements",), "count"),
    "--bar-length": (("bar_length_mm", "socket_distance_mm"), "length"),
    "--probe-length": (("probe_length_mm",), "length"),
    "--encoder-noise": (("encoder_noise_deg",), "angle"),
}


@app.command("instruments")
def instruments_cmd(json_out: JsonOpt = None) -> None:
    """List the measurement instruments (for `kincal simulate --instrument`) and options."""
    from kincal.io import write_json
    from kincal.measure.registry import LOAD_ERRORS, instruments

    if json_out:
        write_json(json_out, {"instruments": [
            {"name": name, "description": inst.description, "noise_unit": inst.noise_unit,
             "options": {k: {"default": v, "help": h} for k, (v, h) in inst.options.items()}}
            for name, inst in sorted(instruments().items())],
            "load_errors": dict(LOAD_ERRORS)})
        if json_out == "-":
            return

    t = Table(title="Instruments (use with --instrument; options with --option KEY=VALUE)")
    for c in ("name", "description", "noise unit", "options (default)"):
        t.add_column(c, overflow="fold")
    for name, inst in sorted(instruments().items()):
        opts = "\n".join(f"{k}={v!r}: {h}" for k, (v, h) in inst.options.items())
        t.add_row(name, inst.description, inst.noise_unit, opts or "-")
    console.print(t)
    for mod, err in LOAD_ERRORS.items():
        console.print(f"[red]{escape(mod)} failed to load[/red]: {escape(err)}")


def parse_options(items: Sequence[str] | None, inst: Any) -> dict[str, Any]:
    """``--option KEY=VALUE`` (repeatable, ``;`` separated) typed like the defaults."""
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


def artifact_options(inst: Any, flags: dict[str, str | int | None]) -> dict[str, Any]:
    """Map ``--placements``, ``--bar-length 300mm``, ``--probe-length 100mm`` and
    ``--encoder-noise 0.001deg`` to ``inst``'s options (in their mm / deg spelling); an
    error when it has none."""
    from kincal.units import parse_quantity

    out: dict[str, Any] = {}
    for flag, value in flags.items():
        if value is None:
            continue
        keys, dim = ARTIFACT_FLAGS[flag]
        key = next((k for k in keys if k in inst.options), None)
        if key is None:
            have = [f for f, (ks, _) in ARTIFACT_FLAGS.items()
                    if any(k in inst.options for k in ks)]
            raise KincalError(f"option {flag}: instrument {inst.name!r} has no such option "
                              f"(it is for cross-bar, ball-bar, two-socket"
                              + (f"; {inst.name} takes {', '.join(have)}" if have else "")
                              + ")")
        if dim == "count":
            out[key] = type(inst.options[key][0])(value)
            continue
        si = parse_quantity(str(value), dim, flag, positive=flag == "--bar-length",
                            minimum=0.0)
        out[key] = type(inst.options[key][0])(si * (1e3 if dim == "length" else
                                                    180.0 / math.pi))
    return out


def parse_noise(noise: str | None, inst: Any, option: str = "--noise") -> float:
    """The instrument's main noise in its SI unit from ``--noise 0.01mm`` (its dimension:
    length, angle or pixel); the instrument's default otherwise."""
    dim = {"m": "length", "rad": "angle", "px": "pixel"}.get(inst.noise_unit, "dimensionless")
    value = quantity(noise, dim, option, minimum=0.0)
    if value is None:
        value = {"length": 1e-5, "angle": 2e-6, "pixel": 0.2}.get(dim, 1e-5)
    return float(value)


def noise_used(inst: Any, opts: dict[str, Any], sd: float, si: bool = False
               ) -> tuple[float, str]:
    """The noise the simulation really applies, in SI, and a phrase for people in the
    console's units (mm and deg; m and rad with ``si``; pixels as they are).

    Artifact instruments use ``encoder_noise_deg`` when it is >= 0, else ``sd`` [rad].
    """
    from kincal.workflow.simulation import applied_noise

    cu = Units(si)
    if "encoder_noise_deg" in inst.options:
        value = applied_noise(inst, opts, sd)
        return value, f"encoder noise {cu.value(value, 'rad')} per joint"
    if inst.noise_unit in ("m", "rad"):
        return sd, f"noise {cu.value(sd, inst.noise_unit)}"
    return sd, f"noise {sd:g} {inst.noise_unit}"


@app.command()
def simulate(
    robot: RobotArg,
    output: Annotated[str, typer.Option("-o", "--output", help="Measurement CSV to write.")],
    truth: Annotated[str | None, typer.Option("--truth", help="Write the simulated true robot "
                                              "here (YAML robot file, SI).")] = None,
    poses: Annotated[int, typer.Option("--poses", "-n", min=1, help="Number of measured "
                                       "configurations (artifacts: poses / sockets "
                                       "placements unless --placements).")] = 100,
    noise: Annotated[str | None, typer.Option("--noise", help="Measurement noise (standard "
                                              "deviation per coordinate) with its unit: "
                                              "0.01mm, 1arcsec, 0.3px (default 0.01 mm, "
                                              "2 urad, 0.2 px).")] = None,
    seed: SeedOpt = 0,
    instrument: Annotated[str, typer.Option("--instrument", "-i", help="Instrument (see "
                                            "`kincal instruments`): position, pose, "
                                            "cross-bar, ...")] = "position",
    option: Annotated[list[str] | None, typer.Option("--option", help="Instrument option "
                                                     "KEY=VALUE (repeatable), e.g. "
                                                     "markers=3.")] = None,
    placements: Annotated[int | None, typer.Option(
        "--placements", min=1, help="Artifacts (cross-bar, ball-bar, two-socket): number of "
        "artifact placements.")] = None,
    bar_length: Annotated[str | None, typer.Option(
        "--bar-length", metavar="LENGTH", help="Artifacts: the known length with its unit "
        "(300mm): cross-bar |AC| = |BD|, ball-bar length, two-socket socket distance.")
    ] = None,
    probe_length: Annotated[str | None, typer.Option(
        "--probe-length", metavar="LENGTH", help="Artifacts: probe length along the flange z "
        "axis, with its unit.")] = None,
    encoder_noise: Annotated[str | None, typer.Option(
        "--encoder-noise", metavar="ANGLE", help="Artifacts: encoder noise per joint "
        "(standard deviation) with its unit, e.g. 0.001deg; replaces --noise.")] = None,
    holdout: Annotated[str | None, typer.Option("--holdout", help="Also write held-out "
                                                "measurements (same robot, same instrument "
                                                "placement) to this CSV.")] = None,
    holdout_poses: Annotated[int, typer.Option("--holdout-poses", min=1, help="Poses in the "
                                               "held-out file.")] = 50,
    length_error: Annotated[str, typer.Option(help="Standard deviation of the injected length "
                                              "errors, with its unit.")] = "0.5mm",
    angle_error: Annotated[str, typer.Option(help="Standard deviation of the injected angle "
                                             "errors.")] = "0.05deg",
    offset_error: Annotated[str, typer.Option(help="Standard deviation of the injected joint "
                                              "offset errors.")] = "0.1deg",
    perturb: Annotated[str | None, typer.Option(help="Only perturb these parameters (names or "
                                                "* patterns, comma separated).")] = None,
    length_unit: LengthUnit = "m", angle_unit: AngleUnit = "rad",
    base_link: BaseLink = None, tip_link: TipLink = None, si: SiOpt = False,
    json_out: JsonOpt = None,
) -> None:
    """Simulate a calibration experiment: a true robot (nominal + errors) measured by an
    instrument with noise. Writes the measurements (and the truth) for `kincal calibrate`.

    Artifact instruments (cross-bar, ball-bar, two-socket) seat a probe in the sockets
    of the artifact by IK on the true robot and record noisy joint readings."""
    from kincal.measure.registry import get_instrument
    from kincal.workflow.simulation import simulate_experiment

    out = out_console(json_out)
    errors = {what: quantity(text, "length" if what == "length" else "angle",
                             f"--{what}-error", minimum=0.0)
              for what, text in (("length", length_error), ("angle", angle_error),
                                 ("offset", offset_error))}
    check_outputs({"-o": output, "--holdout": holdout, "--truth": truth, "--json": json_out},
                  {"ROBOT": [robot] if Path(robot).is_file() else []})
    nominal = serial(load(robot, base_link, tip_link), "simulate")
    inst = get_instrument(instrument)
    opts = parse_options(option, inst)
    flags = artifact_options(inst, {"--placements": placements, "--bar-length": bar_length,
                                    "--probe-length": probe_length,
                                    "--encoder-noise": encoder_noise})
    both = sorted(set(flags) & set(opts))
    if both:
        raise KincalError(f"option {both[0]} is given twice (as a flag and as --option)")
    opts.update(flags)
    if encoder_noise is not None and noise is not None:
        raise KincalError("give either --encoder-noise or --noise, not both")
    sd = parse_noise(noise, inst)
    _, noise_text = noise_used(inst, opts, sd, si)
    units = {"length": check_unit(length_unit, "length", "--length-unit"),
             "angle": check_unit(angle_unit, "angle", "--angle-unit")}
    sim = simulate_experiment(
        nominal, inst, poses=poses, noise=sd, options=opts, seed=seed,
        length_std=errors["length"], angle_std=errors["angle"], offset_std=errors["offset"],
        perturb=[p.strip() for p in perturb.split(",")] if perturb else None,
        holdout_poses=holdout_poses if holdout else None).with_notes(noise_text)
    _write_simulation(sim, output, holdout, truth, units)
    _print_simulation(out, sim, output, holdout, truth, noise_text, si)
    if json_out:
        from kincal.io import write_json

        write_json(json_out, sim.to_dict(output=output, holdout=holdout, truth_file=truth))


def _write_simulation(sim: SimulatedExperiment, output: str, holdout: str | None,
                      truth: str | None, units: dict[str, str]) -> None:
    """The measurement CSV, the held-out CSV and the true robot's YAML, each rendered
    before it is written atomically."""
    from kincal.measure.registry import write_measurements
    from kincal.robots.files import robot_yaml_text

    truth_text = robot_yaml_text(sim.true) if truth else None
    write_measurements(sim.instrument, sim.blocks, output, units, sim.nominal)
    if sim.held is not None and holdout is not None:
        write_measurements(sim.instrument, sim.held, holdout, units, sim.nominal)
    if truth and truth_text is not None:
        from kincal.io import atomic_write_text

        atomic_write_text(truth, truth_text)


def _print_simulation(out: Console, sim: SimulatedExperiment, output: str,
                      holdout: str | None, truth: str | None, noise_text: str,
                      si: bool) -> None:
    """What was simulated and written, and the size of the injected errors."""
    import numpy as np

    nominal = sim.nominal
    n_pl = sim.placements
    out.print(f"simulated {sim.measurements} measurements"
              + (f" ({n_pl} placements)" if n_pl else "")
              + f" of {escape(nominal.name)} with {sim.instrument.name} ({noise_text}) -> "
              f"{escape(output)}")
    if sim.held is not None:
        out.print(f"held-out: {sim.held_measurements} measurements -> {escape(str(holdout))}")
    delta = sim.true.param_values - nominal.param_values
    lin = np.array([u == "m" for u in nominal.param_units])
    cu = Units(si)
    out.print(f"injected errors: {int(np.count_nonzero(delta))} parameters, largest "
              f"{cu.value(np.max(np.abs(delta[lin]), initial=0), 'm', 3)} / "
              f"{cu.value(np.max(np.abs(delta[~lin]), initial=0), 'rad', 4)}"
              + (f"; truth -> {escape(truth)}" if truth else ""))
