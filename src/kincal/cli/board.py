"""``kincal board KIND -o board.pdf``: a printable calibration board and its board file.

Writes the board as a vector PDF page of the board's true size (``.pdf``) or as a PNG at
``--dpi`` (``.png``), and beside it the board file (same name, ``.yaml``) that
``kincal import images --board`` and ``kincal hand-eye --board`` read
(:mod:`kincal.measure.board_render`, :mod:`kincal.measure.camera_board`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import out_console
from kincal.cli.common import JsonOut
from kincal.errors import KincalError

#: The kinds and their defaults (each fits an A4 or US Letter sheet with a 10 mm margin).
KINDS: dict[str, dict[str, Any]] = {
    "charuco": {"columns": 5, "rows": 7, "square": "30mm", "marker": "22mm",
                "dictionary": "DICT_6X6_250"},
    "chessboard": {"columns": 7, "rows": 10, "square": "25mm"},
    "aruco_grid": {"columns": 4, "rows": 6, "marker": "35mm", "separation": "10mm",
                   "dictionary": "DICT_6X6_250"},
    "apriltag_grid": {"columns": 4, "rows": 6, "marker": "35mm", "separation": "10mm",
                      "dictionary": "DICT_APRILTAG_36H11"},
    "circles": {"columns": 6, "rows": 8, "spacing": "25mm", "diameter": "12.5mm"},
    "asymmetric_circles": {"columns": 4, "rows": 11, "spacing": "20mm", "diameter": "12mm"},
}
#: The board file's key of the counts, per kind.
_COUNT_KEY = {"charuco": "squares", "chessboard": "squares", "aruco_grid": "markers",
              "apriltag_grid": "markers", "circles": "circles", "asymmetric_circles": "circles"}


def _board_of(kind: str, given: dict[str, Any]) -> Any:
    """The :class:`~kincal.measure.camera_board.Board` the options state (defaults of the
    kind for the rest); an option the kind does not take is refused."""
    from kincal.measure.camera_board import board_from_mapping
    from kincal.units import parse_quantity

    name = kind.strip().lower().replace("-", "_")
    if name not in KINDS:
        raise KincalError(f"argument KIND: {kind!r}; use one of "
                          f"{', '.join(k.replace('_', '-') for k in KINDS)}")
    takes = KINDS[name]
    for key, value in given.items():
        if value is not None and key not in takes:
            allowed = ", ".join(f"--{k}" for k in takes)
            raise KincalError(f"option --{key}: not for a {name.replace('_', ' ')} board "
                              f"(it takes {allowed})")
    v = {k: (given.get(k) if given.get(k) is not None else d) for k, d in takes.items()}
    data: dict[str, Any] = {"type": name, _COUNT_KEY[name]: [v.pop("columns"), v.pop("rows")]}
    for key in ("square", "marker", "separation", "spacing", "diameter"):
        if key in v:
            data[key] = parse_quantity(str(v.pop(key)), "length", f"--{key}", positive=True)
    data.update(v)
    try:
        return board_from_mapping(data, "")
    except KincalError as exc:                  # the board file's key -> the option
        key, _, why = str(exc).partition(": ")
        opt = "--columns, --rows" if key == _COUNT_KEY[name] else f"--{key}"
        raise KincalError(f"option {opt}: {why}") from None


def _paper(width: float, height: float) -> str:
    """``fits A4 (portrait)`` or what it needs."""
    from kincal.measure.board_render import PAPER

    for name, (w, h) in PAPER.items():
        if width <= w + 1e-9 and height <= h + 1e-9:
            return f"fits {name} portrait"
        if height <= w + 1e-9 and width <= h + 1e-9:
            return f"fits {name} landscape"
    return "larger than A3: print on a larger sheet"


@app.command("board")
def board_command(
    kind: Annotated[str, typer.Argument(help="charuco, chessboard, aruco-grid, apriltag-grid, "
                                        "circles or asymmetric-circles.")],
    output: Annotated[str, typer.Option("-o", "--output", help="The board to print: .pdf "
                                        "(vector, true size) or .png (at --dpi); the board "
                                        "file is written beside it as .yaml.")],
    columns: Annotated[int | None, typer.Option("--columns", min=1, help="Squares, markers "
                                                "or circles along x (a circle grid: circles "
                                                "in a row).")] = None,
    rows: Annotated[int | None, typer.Option("--rows", min=1, help="Squares, markers or "
                                             "circles along y (rows).")] = None,
    square: Annotated[str | None, typer.Option("--square", help="Side of a square "
                                               "(charuco, chessboard), e.g. 30mm.")] = None,
    marker: Annotated[str | None, typer.Option("--marker", help="Side of a marker (charuco, "
                                               "marker grids), e.g. 22mm.")] = None,
    separation: Annotated[str | None, typer.Option("--separation", help="Gap between the "
                                                   "markers of a grid, e.g. 10mm.")] = None,
    spacing: Annotated[str | None, typer.Option("--spacing", help="Circle grids: distance "
                                                "between rows (asymmetric: half the distance "
                                                "in a row), e.g. 20mm.")] = None,
    diameter: Annotated[str | None, typer.Option("--diameter", help="Diameter of the "
                                                 "circles, e.g. 12mm.")] = None,
    dictionary: Annotated[str | None, typer.Option("--dictionary", help="OpenCV marker "
                                                   "dictionary, e.g. DICT_6X6_250, "
                                                   "DICT_APRILTAG_36H11.")] = None,
    dpi: Annotated[int, typer.Option("--dpi", min=10, max=2400, help="Pixels per inch of a "
                                     "PNG.")] = 300,
    margin: Annotated[str, typer.Option("--margin", help="White margin round the pattern "
                                        "(a length).")] = "10mm",
    json_out: JsonOut = None,
) -> None:
    """Write a printable calibration board (PDF at true size, or PNG) and its board file.
    Print at 100 % (no "fit to page"), then measure a square (or the circle spacing)
    with a ruler: if it differs, put the measured length in the board file."""
    from kincal.io import atomic_write_bytes, atomic_write_text, check_outputs, write_json
    from kincal.measure.board_render import (
        board_shapes,
        page_layout,
        pdf_bytes,
        png_bytes,
        render_pixels,
    )
    from kincal.measure.camera_board import board_yaml
    from kincal.units import parse_quantity

    console = out_console(json_out)
    out = Path(output)
    suffix = out.suffix.lower()
    if suffix not in (".pdf", ".png"):
        raise KincalError(f"option -o: {output!r}: the board is written as .pdf or .png")
    board_file = out.with_suffix(".yaml")
    check_outputs({"-o": output, "board file": str(board_file), "--json": json_out}, {})
    b = _board_of(kind, {"columns": columns, "rows": rows, "square": square, "marker": marker,
                         "separation": separation, "spacing": spacing, "diameter": diameter,
                         "dictionary": dictionary})
    page = page_layout(b, parse_quantity(margin, "length", "--margin", minimum=0.0))
    shapes = board_shapes(b)
    title = f"kincal board: {b.description()['type']}"
    if suffix == ".pdf":
        data, pixels = pdf_bytes(shapes, page, title), None
    else:
        img = render_pixels(shapes, page, dpi)
        data, pixels = png_bytes(img, dpi), (int(img.shape[1]), int(img.shape[0]))
    atomic_write_bytes(out, data)
    atomic_write_text(board_file, board_yaml(b))
    what = b.description()
    circles = b.kind in ("circles", "asymmetric_circles")
    console.print(f"{what['type']} {b.columns} x {b.rows} {_COUNT_KEY[what['type']]} "
                  f"({b.num_corners} {'centres' if circles else 'corners'}); page "
                  f"{page.width * 1e3:.1f} x {page.height * 1e3:.1f} mm, "
                  f"{_paper(page.width, page.height)}"
                  + (f"; {pixels[0]} x {pixels[1]} px at {dpi} dpi" if pixels else ""))
    console.print(f"board -> {escape(output)}, board file -> {escape(str(board_file))}")
    console.print("print at 100 % (no 'fit to page'), then check "
                  + ("the spacing" if circles else "a square") + " with a ruler")
    if b.kind == "asymmetric_circles" and b.rows % 2 == 0:
        console.print(f"[yellow]note[/yellow]: {b.rows} rows (even): the grid reads the same "
                      "turned by 180 deg; an odd number of rows gives it one reading")
    if json_out:
        write_json(json_out, {"board": str(out), "board_file": str(board_file),
                              "description": what, "page_mm": [page.width * 1e3,
                                                               page.height * 1e3],
                              "pixels": list(pixels) if pixels else None,
                              "dpi": dpi if pixels else None,
                              "corners": b.num_corners})
