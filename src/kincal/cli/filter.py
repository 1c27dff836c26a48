"""The ``filter`` command: a robot program through the calibrated model.

Reads a KUKA KRL, ABB RAPID, UR URScript or FANUC ``.ls`` program
(:mod:`kincal.compensation.programs`), filters every Cartesian target
(:func:`kincal.compensation.programs.driver.filter_program`) and writes the same program
with only the numbers of changed targets rewritten.  Exit status 1 when some targets
could not be filtered (they are left unchanged and listed), 2 for bad input (nothing
written).
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.calibration_common import JsonOpt, load, out_console, serial
from kincal.cli.common import BaseLink, TipLink
from kincal.errors import KincalError

_SHOWN = 40


def _outputs(program: str, output: str, texts: dict[str, str],
             several: bool = False) -> dict[str, str]:
    """Output path per input file: ``-o OUT.src`` also writes ``OUT.dat`` beside it; a
    program of several files or a folder (RAPID modules) is written into the folder ``-o``
    with the same relative paths."""
    out = Path(output)
    mapping: dict[str, str] = {}
    if several:     # by file name when the names differ, else relative to the common folder
        common = Path(os.path.commonpath([str(Path(f).resolve().parent) for f in texts]))
        unique = len({Path(f).name for f in texts}) == len(texts) and not Path(program).is_dir()
        for f in texts:
            mapping[f] = str(out / (Path(f).name if unique else
                                    Path(f).resolve().relative_to(common)))
        texts = {}
    for f in texts:
        p = Path(f)
        if p.resolve() == Path(program).resolve() or len(texts) == 1:
            mapping[f] = str(out)
        else:
            mapping[f] = str(out.with_suffix(p.suffix))
    for f, o in mapping.items():
        if Path(o).resolve() == Path(f).resolve():
            raise KincalError(f"output {o} is an input file; write elsewhere")
    return mapping


#: What a file of each language starts a routine or module with: a file with one but no
#: motion target is a program with nothing to filter (an RSI / EKI driver, a homing
#: routine of joint moves or calls).
_PROGRAM = {"krl": r"^[ \t]*(?:GLOBAL[ \t]+)?DEF(?:FCT|DAT)?[ \t]+\w",
            "urscript": r"^[ \t]*def[ \t]+\w+[ \t]*\(", "rapid": r"^[ \t]*MODULE[ \t]+\w",
            "fanuc-ls": r"^/PROG[ \t]"}


def _is_program(dialect: str, texts: dict[str, str]) -> bool:
    pattern = re.compile(_PROGRAM.get(dialect, "$^"), re.IGNORECASE | re.MULTILINE)
    return any(pattern.search(t) for t in texts.values())


def _targets_table(rows: list[Any], res: Any, programs: list[str]
                   ) -> tuple[Table, list[Any]]:
    """The table of the filtered targets (at most ``_SHOWN`` rows: those with a warning or
    not filtered first) and the rows it shows."""
    n_f = sum(r.status == "filtered" for r in rows)
    n_p = sum(r.status == "partial" for r in rows)
    shown_name = ", ".join(Path(p).name for p in programs)
    table = Table(title=f"{escape(shown_name)} ({res.dialect}): {len(rows)} targets, "
                        f"{n_f} filtered, {len(res.failed)} not filtered"
                        + (f", {n_p} partial" if n_p else ""))
    for col in ("target", "line", "kind", "status", "shift [mm]", "shift [deg]",
                "predicted std [mm]", "warnings"):
        table.add_column(escape(col), justify="right" if "[" in col or col == "line" else "left")
    shown = rows if len(rows) <= _SHOWN else [r for r in rows if r.warnings or
                                              r.status in ("not filtered", "partial")][:_SHOWN]
    for r in shown:
        table.add_row(escape(r.name), str(r.line), r.kind, r.status,
                      f"{r.shift_mm:.4f}", f"{r.shift_deg:.4f}",
                      "-" if math.isnan(r.predicted_std_mm) else f"{r.predicted_std_mm:.4f}",
                      escape(_warning_cell(r)))
    return table, shown


def _targets_csv(rows: list[Any]) -> str:
    """The ``--csv`` table: one row per target (mm, deg; SI names in the header)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["target", "file", "line", "kind", "status", "shift_mm", "shift_deg",
                "predicted_std_mm", "warnings", "reason"])
    for r in rows:
        w.writerow([r.name, r.file, r.line, r.kind, r.status, f"{r.shift_mm:.6f}",
                    f"{r.shift_deg:.6f}", "" if math.isnan(r.predicted_std_mm)
                    else f"{r.predicted_std_mm:.6f}", ";".join(r.warnings), r.reason])
    return buf.getvalue()


def _warning_cell(r: Any) -> str:
    """The warnings of one target, then why it was not filtered; a warning the reason
    starts with is said once (``unreachable: outside the workspace``, not
    ``unreachable: unreachable: ...``)."""
    reason = r.reason if r.reason and r.status in ("not filtered", "kept", "partial") else ""
    said = [w for w in r.warnings if not (reason and reason.startswith(w))]
    return ": ".join(x for x in (", ".join(said), reason) if x)


@app.command("filter")
def filter_cmd(
    programs: Annotated[list[str], typer.Argument(
        metavar="PROGRAM", help="Robot program: KRL .src (its .dat beside it), RAPID "
        ".mod/.prg (several modules, or a folder: a controller backup's task or a "
        "RobotStudio project; -o is then a folder), URScript .script, FANUC .ls.")],
    robot: Annotated[str, typer.Option("--robot", help="The calibrated robot (from `kincal "
                                       "calibrate -o`).")],
    nominal: Annotated[str, typer.Option("--nominal", help="The controller's nominal robot "
                                         "(built-in name or file): its IK runs on the "
                                         "controller.")],
    output: Annotated[str, typer.Option("-o", "--output", help="The filtered program (KRL: "
                                        "OUT.src, and OUT.dat beside it, their DEF / DEFDAT "
                                        "renamed OUT).")],
    dialect: Annotated[str, typer.Option("--dialect", help="auto (from the suffix), krl, "
                                         "rapid, urscript, fanuc-ls.")] = "auto",
    frames: Annotated[str | None, typer.Option("--frames", help="YAML with the controller's "
                                               "tool and base/user frames by number (KRL "
                                               "TOOL_DATA/BASE_DATA, FANUC UTOOL/UFRAME) "
                                               "or name (RAPID tooldata / wobjdata).")
                      ] = None,
    joint_targets: Annotated[str, typer.Option("--joint-targets", help="taught: joint targets "
                                               "stay (taught on the real robot); offline: "
                                               "correct them as offline-programmed ones.")
                             ] = "taught",
    result: Annotated[str | None, typer.Option("--result", help="Result JSON of the "
                                               "calibration (`kincal calibrate --json`): each "
                                               "target gets the calibrated model's predicted "
                                               "accuracy (std at its TCP) there, and targets "
                                               "outside the calibrated region (training "
                                               "joint ranges and workspace) are flagged. "
                                               "Default: the envelope the calibrated robot "
                                               "file carries.")] = None,
    csv_out: Annotated[str | None, typer.Option("--csv", help="Also write the per-target "
                                                "table as CSV.")] = None,
    json_out: JsonOpt = None, base_link: BaseLink = None, tip_link: TipLink = None,
) -> None:
    """Filter a robot program through the calibrated model: every Cartesian target becomes
    the pose to send to a controller that only knows the nominal model, so that the real
    robot reaches the original target."""
    from kincal.compensation.programs.base import read_frames
    from kincal.compensation.programs.driver import filter_program
    from kincal.io import atomic_write_bytes, atomic_write_text, check_outputs, write_json

    out = out_console(json_out)
    several = len(programs) > 1 or Path(programs[0]).is_dir()
    program: str | list[str] = programs if len(programs) > 1 else programs[0]
    check_outputs({"-o": None if several else output, "--csv": csv_out, "--json": json_out},
                  {"PROGRAM": programs, "--robot": [robot], "--nominal": [nominal],
                   "--frames": frames, "--result": result})
    if joint_targets not in ("taught", "offline"):
        raise KincalError(f"option --joint-targets: use taught or offline, not {joint_targets!r}")
    for p in programs:
        if not (Path(p).is_file() or Path(p).is_dir()):
            raise KincalError("no such program file", source=p)
    cal = serial(load(robot, base_link, tip_link), "filter")
    nom = serial(load(nominal, base_link, tip_link), "filter")
    fr = read_frames(frames)
    accuracy = None
    if result:
        from kincal.workflow.flow import accuracy_from_result

        accuracy = accuracy_from_result(result, cal)
    else:                               # the envelope the calibrated robot carries
        from kincal.identify.envelope import robot_and_accuracy

        cal, accuracy = robot_and_accuracy(cal)
    res = filter_program(program, cal, nom, dialect, fr, joint_targets == "offline", accuracy)
    if not res.reports and not _is_program(res.dialect, res.originals):
        raise KincalError(f"no motion target found: is this a {res.dialect} program? (nothing "
                          "written)", source=programs[0])
    targets = _outputs(programs[0], output, res.texts, several)
    texts = dict(res.texts)
    if res.dialect == "krl":            # DEF name( and DEFDAT name follow the file name
        from kincal.compensation.programs.krl import rename_module

        texts = {f: rename_module(t, Path(f).stem, Path(targets[f]).stem, targets[f])
                 for f, t in texts.items()}
    for f, o in targets.items():
        atomic_write_bytes(o, texts[f].encode("latin-1"))
    rows = res.reports
    shifts = [r.shift_mm for r in rows if r.status == "filtered"]
    table, shown = _targets_table(rows, res, programs)
    out.print(table)
    if len(rows) > _SHOWN:
        out.print(f"({len(rows) - len(shown)} rows without warnings not shown; all rows in "
                  "--csv / --json)")
    if all(r.status in ("kept", "unused") for r in rows):
        out.print("nothing to filter: " + ("no motion target in this program" if not rows else
                                           "every motion target is kept as it is (joint "
                                           "targets, relative or computed at run time)"))
    if shifts:
        out.print(f"shift of the filtered targets: RMS "
                  f"{math.sqrt(sum(s * s for s in shifts) / len(shifts)):.4f} mm, max "
                  f"{max(shifts):.4f} mm")
    out.print("filtered program -> " + ", ".join(escape(o) for o in targets.values()))
    if csv_out:
        atomic_write_text(csv_out, _targets_csv(rows))
    if json_out:
        write_json(json_out, res.to_dict(outputs=list(targets.values())))
    if res.failed:
        first = res.failed[0]
        print(f"error: {len(res.failed)} of {len(rows)} targets could not be filtered and were "
              f"left unchanged (first: {first.name}, {first.file}:{first.line}: {first.reason})",
              file=sys.stderr)
        raise typer.Exit(1)
