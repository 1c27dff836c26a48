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


def _outputs(program: str, output: str, texts: dict[str, str]) -> dict[str, str]:
    """Output path per input file: ``-o OUT.src`` also writes ``OUT.dat`` beside it."""
    out = Path(output)
    mapping: dict[str, str] = {}
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



def _warning_cell(r: Any) -> str:
    """The warnings of one target, then why it was not filtered; a warning the reason
    starts with is said once (``unreachable: outside the workspace``, not
    ``unreachable: unreachable: ...``)."""
    reason = r.reason if r.reason and r.status == "not filtered" else ""
    said = [w for w in r.warnings if not (reason and reason.startswith(w))]
    return ": ".join(x for x in (", ".join(said), reason) if x)

@app.command("filter")
def filter_cmd(
    program: Annotated[str, typer.Argument(help="Robot program: KRL .src (its .dat beside it), "
                                           "RAPID .mod/.prg, URScript .script, FANUC .ls.")],
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
                                               "TOOL_DATA/BASE_DATA, FANUC UTOOL/UFRAME).")
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
                                               "joint ranges and workspace) are flagged.")] = None,
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
    check_outputs({"-o": output, "--csv": csv_out, "--json": json_out},
                  {"PROGRAM": [program], "--robot": [robot], "--nominal": [nominal],
                   "--frames": frames, "--result": result})
    if joint_targets not in ("taught", "offline"):
        raise KincalError(f"option --joint-targets: use taught or offline, not {joint_targets!r}")
    if not Path(program).is_file():
        raise KincalError("no such program file", source=program)
    cal = serial(load(robot, base_link, tip_link), "filter")
    nom = serial(load(nominal, base_link, tip_link), "filter")
    fr = read_frames(frames)
    accuracy = None
    if result:
        from kincal.workflow.flow import accuracy_from_result

        accuracy = accuracy_from_result(result, cal)
    res = filter_program(program, cal, nom, dialect, fr, joint_targets == "offline", accuracy)
    if not res.reports:
        raise KincalError(f"no motion target found: is this a {res.dialect} program? (nothing "
                          "written)", source=program)
    targets = _outputs(program, output, res.texts)
    texts = dict(res.texts)
    if res.dialect == "krl":            # DEF name( and DEFDAT name follow the file name
        from kincal.compensation.programs.krl import rename_module

        texts = {f: rename_module(t, Path(f).stem, Path(targets[f]).stem, targets[f])
                 for f, t in texts.items()}
    for f, o in targets.items():
        atomic_write_bytes(o, texts[f].encode("latin-1"))
    rows = res.reports
    n_f = sum(r.status == "filtered" for r in rows)
    shifts = [r.shift_mm for r in rows if r.status == "filtered"]
    table = Table(title=f"{escape(Path(program).name)} ({res.dialect}): {len(rows)} targets, "
                        f"{n_f} filtered, {len(res.failed)} not filtered")
    for col in ("target", "line", "kind", "status", "shift [mm]", "shift [deg]",
                "predicted std [mm]", "warnings"):
        table.add_column(escape(col), justify="right" if "[" in col or col == "line" else "left")
    shown = rows if len(rows) <= _SHOWN else [r for r in rows if r.warnings or
                                              r.status == "not filtered"][:_SHOWN]
    for r in shown:
        table.add_row(escape(r.name), str(r.line), r.kind, r.status,
                      f"{r.shift_mm:.4f}", f"{r.shift_deg:.4f}",
                      "-" if math.isnan(r.predicted_std_mm) else f"{r.predicted_std_mm:.4f}",
                      escape(_warning_cell(r)))
    out.print(table)
    if len(rows) > _SHOWN:
        out.print(f"({len(rows) - len(shown)} rows without warnings not shown; all rows in "
                  "--csv / --json)")
    if shifts:
        out.print(f"shift of the filtered targets: RMS "
                  f"{math.sqrt(sum(s * s for s in shifts) / len(shifts)):.4f} mm, max "
                  f"{max(shifts):.4f} mm")
    out.print("filtered program -> " + ", ".join(escape(o) for o in targets.values()))
    if csv_out:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["target", "file", "line", "kind", "status", "shift_mm", "shift_deg",
                    "predicted_std_mm", "warnings", "reason"])
        for r in rows:
            w.writerow([r.name, r.file, r.line, r.kind, r.status, f"{r.shift_mm:.6f}",
                        f"{r.shift_deg:.6f}", "" if math.isnan(r.predicted_std_mm)
                        else f"{r.predicted_std_mm:.6f}", ";".join(r.warnings), r.reason])
        atomic_write_text(csv_out, buf.getvalue())
    if json_out:
        write_json(json_out, res.to_dict(outputs=list(targets.values())))
    if res.failed:
        first = res.failed[0]
        print(f"error: {len(res.failed)} of {len(rows)} targets could not be filtered and were "
              f"left unchanged (first: {first.name}, {first.file}:{first.line}: {first.reason})",
              file=sys.stderr)
        raise typer.Exit(1)
