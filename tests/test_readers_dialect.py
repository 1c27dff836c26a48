"""CSV dialects: ``;`` with ``,`` decimals and tab-separated files read as recorded.

The truth is the same table written in kincal's own dialect by hand: both spellings must
give the same SI numbers; a file mixing decimal marks is refused on the right line.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from kincal.errors import MeasurementFileError
from kincal.measure.dialect import Dialect, normalise, sniff
from kincal.measure.registry import read_measurements
from kincal.robots.files import load_serial_robot

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")

HEAD = ["q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg", "x_mm", "y_mm", "z_mm"]
ROWS = [["10.5", "-20.25", "30", "40", "50", "60", "1000.125", "-2.5", "3"],
        ["1", "2", "3", "4", "5", "6.75", "1.5", "2", "-3.25e2"]]


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def _file(tmp_path: Path, name: str, delimiter: str, decimal: str) -> Path:
    p = tmp_path / name
    rows = [[c.replace(".", decimal) for c in r] for r in ROWS]
    text = "# kincal measurements: instrument=position\n" + "\n".join(
        delimiter.join(r) for r in [HEAD, *rows]) + "\n"
    p.write_text(text)
    return p


@pytest.mark.parametrize("delimiter,decimal", [(";", ","), (";", "."), ("\t", "."),
                                               ("\t", ",")])
def test_other_dialects_read_as_the_comma_file(tmp_path, puma, delimiter, decimal):
    ref = read_measurements(_file(tmp_path, "ref.csv", ",", "."), puma)[0]
    (b,) = read_measurements(_file(tmp_path, "other.csv", delimiter, decimal), puma)
    np.testing.assert_array_equal(b.q, ref.q)
    np.testing.assert_array_equal(b.positions, ref.positions)
    assert b.positions[0, 0] == pytest.approx(1.000125)      # 1000,125 mm, not 1000 or 125
    note = b.provenance.table.notes[0]
    assert note.startswith("read as ") and repr(decimal) in note
    assert not ref.provenance.table.notes                       # the usual file: no note


def test_mixed_decimal_marks_refused_on_their_line(tmp_path, puma):
    p = tmp_path / "mixed.csv"
    p.write_text(";".join(HEAD) + "\n" + ";".join(c.replace(".", ",") for c in ROWS[0])
                 + "\n" + ";".join(ROWS[1]) + "\n")
    with pytest.raises(MeasurementFileError,
                       match=r"line 3: column 6 \(q6_deg\): the file has both ',' and '\.'"):
        read_measurements(p, puma)


def test_semicolon_file_row_with_missing_field_names_the_row(tmp_path, puma):
    p = tmp_path / "short.csv"
    p.write_text(";".join(HEAD) + "\n" + ";".join(ROWS[0]) + "\n" + ";".join(ROWS[1][:-1])
                 + "\n")
    with pytest.raises(MeasurementFileError, match="line 3: 8 values, but the header has 9"):
        read_measurements(p, puma)


def test_sniff_and_normalise_against_the_csv_module():
    header = "a;b;c"
    rows = ['1,5;"x;y";-2', "3;4,25e-3;5"]
    d = sniff(header, rows)
    assert d == Dialect(";", ",")
    out = normalise([header, *rows], d)
    parsed = list(csv.reader(out))
    assert parsed == [["a", "b", "c"], ["1.5", "x;y", "-2"], ["3", "4.25e-3", "5"]]
    assert sniff("a,b", ["1,2"]) == Dialect(",", ".")
    assert sniff("a\tb", ["1,5\t2"]) == Dialect("\t", ",")


def test_ipa_ur10_file_reads_as_recorded():
    """The IPA file (``;`` and ``,`` decimals, ROS joint names): its numbers against a
    parse with Python's csv module and float() after swapping the decimal mark."""
    f = DATA / "ipa_ur10" / "Series_B" / "measurements_joint_configurations.csv"
    if not f.exists():
        pytest.skip("IPA data not present")
    cols = ("measurement_x=x_mm,measurement_y=y_mm,measurement_z=z_mm,measurement_rx=rx_deg,"
            "measurement_ry=ry_deg,measurement_rz=rz_deg")
    (b,) = read_measurements(f, load_serial_robot("ur10"), tags={
        "instrument": "pose", "columns": cols, "orientation": "euler:XYZ"})
    with open(f, newline="") as fh:
        rows = list(csv.reader(fh, delimiter=";"))
    head = rows[0]
    num = np.array([[float(c.replace(",", ".")) for c in r] for r in rows[1:]])
    q = num[:, [head.index(n) for n in ("shoulder_pan_joint", "shoulder_lift_joint",
                                        "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                                        "wrist_3_joint")]]
    xyz = num[:, [head.index(f"measurement_{a}") for a in "xyz"]] / 1000
    assert b.N == 1495
    np.testing.assert_allclose(b.q, q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(b.poses[:, :3, 3], xyz, rtol=1e-15, atol=1e-15)
    notes = b.provenance.table.notes
    assert any("semicolon" in n for n in notes) and any("ROS joint names" in n for n in notes)


def test_instrument_detected_from_a_semicolon_header(tmp_path, puma):
    """No tag line: the instrument comes from the header, which must be split on ';'."""
    p = tmp_path / "pose.csv"
    p.write_text(";".join(HEAD[:6] + ["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"])
                 + "\n" + ";".join(["0"] * 6 + ["1,5", "2", "3", "90", "0", "0"]) + "\n")
    (b,) = read_measurements(p, puma)
    assert type(b).__name__ == "PoseMeasurement"
    np.testing.assert_allclose(b.poses[0, :3, 3], [1.5e-3, 2e-3, 3e-3])
    np.testing.assert_allclose(b.poses[0, :3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
                               atol=1e-15)
