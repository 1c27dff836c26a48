"""Options of the calibration workflow, checked and parsed before any file is read.

What ``kincal calibrate`` / ``identifiability`` / ``validate`` do with their option text,
usable from Python (:mod:`kincal.workflow.flow` re-exports every name):

* :func:`check_flow_options` - one-line errors for options that do not fit together;
* :func:`check_options_used` - every ``--units`` / ``--ignore`` entry matches a column;
* :func:`parse_selection` - ``--free`` / ``--fix`` patterns -> parameter names;
* :func:`parse_prior_text` - ``--prior`` text -> the typed :data:`Prior` of the API;
* :func:`prior_spec` - a :data:`Prior` -> the parsed tolerance entries;
* :func:`parse_prior` - ``--prior`` entries -> prior standard deviations [m / rad];
* :func:`parse_stages` - ``--stages`` text -> the one-stage solver's stages.

Every error is a one-line :class:`~kincal.errors.KincalError` naming the option.

The Python API takes typed values, the command line and the setup file text: a
:data:`Prior` is ``None`` or ``"tolerances"`` (Gaussian priors of the manufacturing
tolerances), ``"none"`` (plain least squares), a mapping ``{role, name or pattern:
sigma [m / rad] or None}`` that overrides the tolerances of the parameters it matches
(None: no prior for them), or a parsed :class:`~kincal.identify.tolerances.TolSpec`
(what :func:`parse_prior_text` makes of ``"length=0.5mm,offset=0.05deg,scale=3"``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal, TypeAlias

from kincal.errors import KincalError, MeasurementFileError
from kincal.identify.solver import LOSSES, METHODS, STAGE_KEYWORDS
from kincal.identify.tolerances import Entry, TolSpec, parse_tolerance_entries

__all__ = ["check_options_used", "parse_selection", "parse_stages", "parse_prior",
           "parse_prior_text", "prior_spec", "prior_given", "Prior", "check_flow_options",
           "PROCEDURES", "METHODS", "LOSSES", "STAGES"]

#: The prior of a calibration, typed (module docstring).
Prior: TypeAlias = TolSpec | Mapping[str, float | None] | Literal["tolerances", "none"] | None

PROCEDURES = ("lm", "staged-selection")
STAGES = STAGE_KEYWORDS


def check_options_used(paths: Sequence[str | Path], units: str | None,
                       ignore: Sequence[str] | None) -> None:
    """Every ``--units`` / ``--ignore`` entry must match a column of some file (typo guard)."""
    from kincal.measure.files import (
        glob_regex,
        parse_list_option,
        parse_units_option,
        read_header,
    )

    for p in paths:
        if not Path(p).is_file():
            raise MeasurementFileError("no such measurement file", source=str(p))
    names = [n for p in paths for n in read_header(str(p))[1]]
    for key in list(parse_units_option(units)) + parse_list_option(ignore):
        if not any(glob_regex(key).match(n) for n in names):
            raise MeasurementFileError(f"--units/--ignore entry {key!r} matches no column of "
                                       f"{', '.join(map(str, paths))}")


def parse_selection(names: Sequence[str], roles: Sequence[str], free: str | None,
                    fix: str | None) -> tuple[list[str] | None, list[str]]:
    """``--free`` / ``--fix`` patterns (comma separated; ``role:offset`` selects a role).

    Returns ``(free names or None for automatic, fixed names)``.
    """
    from kincal.identify.names import match_names

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


def parse_prior_text(text: str | None, option: str = "option --prior") -> TolSpec | None:
    """``--prior`` / setup ``prior:`` text -> a :class:`~kincal.identify.tolerances.TolSpec`
    (None stays None): roles, names or ``*`` patterns with a value and its unit, ``none``,
    ``scale=K`` (:func:`~kincal.identify.tolerances.parse_tolerance_entries`); one-line
    errors name ``option``."""
    return None if text is None else parse_tolerance_entries(text, option)


def prior_spec(prior: Prior) -> TolSpec:
    """The tolerance entries of a typed :data:`Prior` (module docstring).

    ``None`` and ``"tolerances"``: no entries (the tolerances as they are); ``"none"``: no
    prior; a mapping: one entry per key, its value in SI applied to every parameter the key
    matches whatever its unit (None: no prior for them).
    """
    if prior is None or prior == "tolerances":
        return TolSpec()
    if prior == "none":
        return TolSpec(use_prior=False)
    if isinstance(prior, TolSpec):
        return prior
    if isinstance(prior, str):
        raise KincalError(f"prior {prior!r}: the Python API takes 'tolerances', 'none', a "
                          "mapping {role, name or pattern: sigma [m / rad]} or a TolSpec "
                          "(parse_prior_text parses command-line text)")
    entries = []
    for target, sigma in prior.items():
        if sigma is not None and not (math.isfinite(sigma) and sigma > 0):
            raise KincalError(f"prior {target!r}: the standard deviation must be positive "
                              f"(got {sigma!r})")
        value = None if sigma is None else float(sigma)
        entries.append(Entry(str(target), value, None,
                             f"{target}={'none' if value is None else f'{value:g}'}"))
    return TolSpec(tuple(entries))


def prior_given(prior: Prior) -> bool:
    """Does ``prior`` change anything (entries, a scale, or no prior)?"""
    return prior_spec(prior) != TolSpec()


def parse_prior(text: str | None, names: Sequence[str], units: Sequence[str]
                ) -> dict[str, float]:
    """``--prior`` entries alone -> prior standard deviations ``{parameter name: s}``
    [m / rad], without the role defaults or a robot file.

    ``text`` is ``PATTERN=SIGMA_WITH_UNIT`` entries, comma separated, e.g.
    ``"*.origin.*=1mm,*.origin.*=0.1deg"`` (an entry applies to the matched parameters
    of its unit's dimension; later entries win; ``scale=K`` multiplies them); see
    :func:`kincal.identify.tolerances.parse_tolerance_entries`.  A calibration's full
    set of tolerances (defaults, robot file, ``--prior``) is
    :func:`kincal.workflow.flow.tolerances_of`.
    """
    from kincal.identify.tolerances import resolve_tolerances

    return resolve_tolerances(names, units, [""] * len(names), None, text,
                              defaults={}).prior()


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


def check_flow_options(*, procedure: str = "lm", method: str = "lm", loss: str = "linear",
                       stages: Sequence[str] | None = None, validation_frames: str = "auto",
                       condition_growth: float | None = None, cycles: int | None = None,
                       tolerance: float | None = None, prior: Prior = None) -> None:
    """One-line errors for options of :func:`run_flow` that do not fit together (checked
    before any file is read; ``tolerance`` in m)."""
    _choice(procedure, "--procedure", PROCEDURES)
    _choice(method, "--method", METHODS)
    _choice(loss, "--loss", LOSSES)
    _choice(validation_frames, "--validation-frames", ("auto", "training", "register"))
    if procedure == "staged-selection":
        if method != "lm" or loss != "linear" or stages or prior_given(prior):
            raise KincalError("--method, --loss, --stages and --prior choose the one-stage "
                              "solver (--procedure lm); the staged-selection procedure has its own "
                              "two stages")
    elif condition_growth is not None or cycles is not None or tolerance is not None:
        raise KincalError("--condition-growth, --cycles and --tolerance need "
                          "--procedure staged-selection")
    if condition_growth is not None and not condition_growth >= 1.0:
        raise KincalError(f"option --condition-growth: must be >= 1 (got {condition_growth:g})")
    if cycles is not None and cycles < 1:
        raise KincalError(f"option --cycles: must be >= 1 (got {cycles})")
    if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
        raise KincalError(f"option --tolerance: must be > 0 (got {tolerance * 1e3:g} mm)")
