"""One CLI style (docs/conventions.md), checked on every command's parameters.

The test walks the click command tree typer builds and fails, naming the command and
the option, when one breaks the conventions: the output options' spellings, counts as
``-n``, quantities with their unit in the value (no unit in the flag, no bare float for
a dimensioned quantity), ``--json`` on every command that prints results, ``--deg`` on
every command that reads joint values, ``--si`` on every command that prints lengths or
angles, ROBOT first, and user-facing names without document numbers.  Old spellings may
stay as hidden aliases; hidden options are not checked.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

import pytest
import typer

from kincal.cli import app

ROOT = typer.main.get_command(app)


def _commands(cmd=ROOT, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, object]]:
    subs = getattr(cmd, "commands", None)
    if subs:
        for name, sub in subs.items():
            yield from _commands(sub, prefix + (name,))
    elif prefix:
        yield " ".join(prefix), cmd


COMMANDS = dict(_commands())


def _options(cmd) -> list:
    return [p for p in cmd.params
            if p.param_type_name == "option" and not getattr(p, "hidden", False)
            and "--help" not in p.opts]


def _arguments(cmd) -> list:
    return [p for p in cmd.params if p.param_type_name == "argument"
            and not getattr(p, "hidden", False)]


def _long(p) -> list[str]:
    return [o for o in p.opts + p.secondary_opts if o.startswith("--")]


#: Floating-point options that are plain numbers by nature (factors, fractions,
#: probabilities, gains): everything else dimensioned takes its unit in the value.
DIMENSIONLESS = {"--loss-scale", "--condition-growth", "--margin", "--false-alarm",
                 "--drift-sigma", "--gain", "--holdout"}

#: Commands that print no results a machine would read (so no --json), and why.
NO_JSON = {"init": "writes a setup file for people", "fivebar-mobility": "a fixed table",
           "fleet export": "-o FILE.json is its JSON"}

#: Commands whose console output holds lengths or angles (so --si).
PRINTS_QUANTITIES = {"show", "fk", "jacobian", "ik", "trajectory", "simulate", "calibrate",
                     "validate", "identifiability", "compensate", "plan", "demo", "clik"}

#: Positional arguments that are not the robot: the command and what they are.
OTHER_ARGUMENTS = {"compensate": "CALIBRATED", "filter": "PROGRAM", "import ur": "FILE",
                   "import bag": "BAG", "import images": "FOLDER", "board": "KIND",
                   "fleet calibrate": "MANIFEST", "fleet history": "SERIAL"}

UNIT_SUFFIX = re.compile(r"[a-z]-(m|mm|cm|um|rad|deg|mrad|urad|arcsec|arcmin|s|ms|px)$")
JOINT_OPTIONS = {"--q", "--q0", "--start", "--end", "--via"}
#: Commands whose option of a JOINT_OPTIONS name is something else.
NOT_JOINT_VALUES = {"fleet simulate": "--start is the first session's date"}
DOCUMENT_WORDS = re.compile(r"seed\s*0\d\d|figures?\s*\d|patent's figures|tol_step|"
                            r"thesis's|seed00\d", re.IGNORECASE)


def test_there_are_commands():
    assert {"fk", "calibrate", "simulate", "plan"} <= set(COMMANDS)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_output_options(name):
    """-o/--output for the main output file, --out-dir for a folder, never --out."""
    bad = []
    for p in _options(COMMANDS[name]):
        if "--out" in p.opts or "--outdir" in p.opts:
            bad.append(f"{'/'.join(p.opts)}: use -o/--output for a file, --out-dir for a "
                       "folder")
        if "-o" in p.opts and "--output" not in p.opts:
            bad.append(f"{'/'.join(p.opts)}: -o is -o/--output")
        if "--output" in p.opts and "-o" not in p.opts:
            bad.append(f"{'/'.join(p.opts)}: --output is -o/--output")
    assert not bad, f"kincal {name}: " + "; ".join(bad)


#: An option that writes into a folder: DIR as its metavar, or help saying it writes one.
WRITES_FOLDER = re.compile(r"\bwrites?\b.{0,60}\b(DIR|folder)\b", re.IGNORECASE)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_folder_of_outputs_is_out_dir(name):
    """An option that writes into a folder is --out-dir, whatever it writes there (the
    robot files of a fleet, figures, a demo's files); input folders (--data) are not
    outputs."""
    bad = [f"{'/'.join(p.opts)}: a folder of outputs is --out-dir"
           for p in _options(COMMANDS[name])
           if ("DIR" in (p.metavar or "") or WRITES_FOLDER.search(p.help or ""))
           and "--out-dir" not in p.opts]
    assert not bad, f"kincal {name}: " + "; ".join(bad)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_counts_are_dash_n(name):
    bad = [f"{'/'.join(p.opts)}: a count is -n/--<what is counted>"
           for p in _options(COMMANDS[name]) if "--n" in p.opts]
    bad += [f"{'/'.join(p.opts)}: -n needs a long name saying what it counts"
            for p in _options(COMMANDS[name]) if "-n" in p.opts and not _long(p)]
    assert not bad, f"kincal {name}: " + "; ".join(bad)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_quantities_carry_their_unit_in_the_value(name):
    bad = []
    for p in _options(COMMANDS[name]):
        for o in _long(p):
            if UNIT_SUFFIX.search(o):
                bare = o.rsplit("-", 1)[0]
                bad.append(f"{o}: the unit goes in the value ({bare} 0.01mm), not in the "
                           "flag")
        type_name = getattr(p.type, "name", "")
        if type_name == "float" and not set(_long(p)) & DIMENSIONLESS:
            bad.append(f"{'/'.join(p.opts)}: a bare number; take the value with its unit "
                       "(or add it to DIMENSIONLESS in this test and docs/conventions.md if "
                       "it has none)")
    assert not bad, f"kincal {name}: " + "; ".join(bad)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_json_on_every_command_that_prints_results(name):
    if name in NO_JSON:
        return
    opts = {o for p in _options(COMMANDS[name]) for o in p.opts}
    assert "--json" in opts, f"kincal {name}: no --json (results for machines; '-' = stdout)"


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_deg_where_joint_values_are_read(name):
    opts = {o for p in _options(COMMANDS[name]) for o in p.opts}
    if opts & JOINT_OPTIONS and name not in NOT_JOINT_VALUES:
        assert "--deg" in opts, f"kincal {name}: reads joint values but has no --deg"


@pytest.mark.parametrize("name", sorted(PRINTS_QUANTITIES))
def test_si_where_lengths_and_angles_are_printed(name):
    opts = {o for p in _options(COMMANDS[name]) for o in p.opts}
    assert "--si" in opts, f"kincal {name}: prints lengths / angles but has no --si"


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_robot_is_the_first_argument(name):
    args = _arguments(COMMANDS[name])
    if not args:
        return
    want = OTHER_ARGUMENTS.get(name, "ROBOT")
    got = (args[0].metavar or args[0].name).strip("[]{}").upper()
    assert got == want, f"kincal {name}: first argument is {got}, expected {want}"


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_names_from_the_users_world(name):
    """No document numbers (seed 003, figure 4, the patent's figures) in what users see."""
    cmd = COMMANDS[name]
    texts = [cmd.help or "", cmd.short_help or ""]
    for p in cmd.params:
        if getattr(p, "hidden", False):
            continue
        texts += [getattr(p, "help", "") or "", str(p.default) if isinstance(p.default, str)
                  else "", *p.opts]
    bad = sorted({m.group(0) for t in texts for m in DOCUMENT_WORDS.finditer(t)})
    assert not bad, f"kincal {name}: {bad} in its help or defaults"


def test_conventions_page_lists_the_dimensionless_options():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "conventions.md").read_text()
    missing = [o for o in sorted(DIMENSIONLESS) if f"`{o}`" not in doc]
    assert not missing, f"docs/conventions.md does not name {missing} as dimensionless"


def test_no_document_numbers_in_the_package():
    """Docstrings (the API reference), library files and messages name the founding documents
    by what they are (the cross-bar patent, the spherical-manipulator report), never by the
    project's internal numbers."""
    from pathlib import Path

    seed = re.compile(r"seed[\s_-]*0\d\d", re.IGNORECASE)
    root = Path(__file__).resolve().parents[1] / "src" / "kincal"
    bad = [f"{p.relative_to(root)}:{i}" for p in sorted(root.rglob("*"))
           if p.suffix in (".py", ".yaml", ".html", ".css")
           for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
           if seed.search(line)]
    assert not bad, f"document numbers in {bad}"
