"""Measurement CSV files: units at the border, one-line errors, real data sets.

Truth is independent of the reader: values are written by hand (or by the writer
in a different unit) and compared with known SI numbers; the real files are
cross-checked against Python's own ``csv`` module.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from kincal.errors import MeasurementFileError
from kincal.measure.files import parse_units_option, read_header, split_unit
from kincal.measure.registry import (
    detect_instrument,
    get_instrument,
    instruments,
    read_measurements,
    simulate_measurements,
    write_measurements,
)
from kincal.robots.files import load_serial_robot

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def _write(tmp_path: Path, text: str, name: str = "m.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


HEAD = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg"
ROW = "10,20,30,40,50,60"


def test_split_unit():
    assert split_unit("x1_mm") == ("x1", "mm")
    assert split_unit("arm_3_joint") == ("arm_3_joint", None)
    assert split_unit("sigma_rot_deg") == ("sigma_rot", "deg")
    assert split_unit("S_rad") == ("S", "rad")


def test_hand_written_position_file_converts_units(tmp_path, puma):
    p = _write(tmp_path, "# kincal measurements: instrument=position; name=lt\n"
               f"{HEAD},x_mm,y_mm,z_mm,sigma_um\n{ROW},1000,-2.5,3,10\n{ROW},1,2,3,20\n")
    (b,) = read_measurements(p, puma)
    assert b.name == "lt"
    np.testing.assert_allclose(b.q[0], np.deg2rad([10, 20, 30, 40, 50, 60]), rtol=1e-15)
    np.testing.assert_allclose(b.positions[0], [1.0, -0.0025, 0.003], rtol=1e-15)
    np.testing.assert_allclose(np.ravel(b.sigma), [1e-5, 2e-5], rtol=1e-15)


def test_tagless_files_are_detected(tmp_path, puma):
    pos = _write(tmp_path, f"pose_id,{HEAD},x_m,y_m,z_m\n1,{ROW},1,2,3\n", "pos.csv")
    pose = _write(tmp_path, f"{HEAD},x_m,y_m,z_m,rx_deg,ry_deg,rz_deg\n{ROW},1,2,3,90,0,0\n",
                  "pose.csv")
    assert detect_instrument(pos) == "position"
    assert detect_instrument(pose) == "pose"
    (b,) = read_measurements(pose, puma)
    np.testing.assert_allclose(b.poses[0, :3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
                               atol=1e-15)
    assert b.provenance.table.ignored == []
    assert read_measurements(pos, puma)[0].provenance.table.ignored == ["pose_id"]
    odd = _write(tmp_path, f"{HEAD},range_mm\n{ROW},3\n", "odd.csv")
    with pytest.raises(MeasurementFileError, match="odd.csv: line 1: no '# kincal"):
        detect_instrument(odd)


@pytest.mark.parametrize("instrument,options", [("position", {}), ("position", {"markers": 3}),
                                                ("pose", {})])
@pytest.mark.parametrize("length,angle", [("m", "rad"), ("mm", "deg")])
def test_round_trip_every_unit(tmp_path, puma, instrument, options, length, angle):
    rng = np.random.default_rng(3)
    blocks, truth = simulate_measurements(instrument, puma, rng, 25, 2e-5, options)
    path = tmp_path / "rt.csv"
    write_measurements(instrument, blocks, path, {"length": length, "angle": angle}, puma)
    header = read_header(path)[1]
    assert header[0] == f"q1_{angle}" and f"x{'1' if 'markers' in options else ''}_{length}" \
        in header
    (back,) = read_measurements(path, puma)
    b = blocks[0]
    np.testing.assert_allclose(back.q, b.q, rtol=0, atol=1e-13)
    if instrument == "pose":
        np.testing.assert_allclose(back.poses, b.poses, rtol=0, atol=1e-12)
        np.testing.assert_allclose(back.sigma_orientation, b.sigma_orientation, rtol=1e-13)
    else:
        np.testing.assert_allclose(back.positions, b.positions, rtol=0, atol=1e-12)
        np.testing.assert_allclose(back.sigma, b.sigma, rtol=1e-13)
    # the simulated data sit at the noise level of the true robot and instrument
    theta = np.array([truth[n] for n in back.parameters().names])
    e = np.ravel(back.errors(puma, theta)["position_m"])
    assert np.sqrt(np.mean(e**2)) == pytest.approx(2e-5 * math.sqrt(3), rel=0.35)


def test_every_instrument_in_the_registry_is_complete():
    for name, inst in instruments().items():
        assert inst.name == name and callable(inst.read) and callable(inst.write)
    assert {"position", "pose"} <= set(instruments())
    with pytest.raises(MeasurementFileError, match="unknown instrument 'laser'; known: "):
        get_instrument("laser")


BAD = {
    "wrong joint count": ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,x_mm,y_mm,z_mm\n"
                          "1,2,3,4,5,1,2,3\n", r"line 2: no column for joint 'q6'.*has 6 "
                          r"joints.*5 joint columns"),
    "extra joint": (f"{HEAD},q7_deg,x_mm,y_mm,z_mm\n{ROW},7,1,2,3\n",
                    r"line 2: column 7 \(q7_deg\) looks like a joint column"),
    "text in numbers": (f"{HEAD},x_mm,y_mm,z_mm\n{ROW},1,2,3\n{ROW},1,abc,3\n",
                        r"line 4: column 8 \(y_mm\): 'abc' is not a number"),
    "nan": (f"{HEAD},x_mm,y_mm,z_mm\n{ROW},1,2,3\n10,nan,30,40,50,60,1,2,3\n",
            r"line 4: column 2 \(q2_deg\): 'nan' is not a finite number"),
    "inf": (f"{HEAD},x_mm,y_mm,z_mm\n{ROW},1,2,inf\n",
            r"line 3: column 9 \(z_mm\): 'inf' is not a finite number"),
    "empty cell": (f"{HEAD},x_mm,y_mm,z_mm\n{ROW},1,,3\n",
                   r"line 3: column 8 \(y_mm\): is empty"),
    "no units": (f"{HEAD},x,y,z\n{ROW},1,2,3\n",
                 r"line 2: 3 columns have no unit: x, y, z: name them with their unit "
                 r"\(like x_mm\) or pass --units 'x=m,y=m,z=m'"),
    "joint without unit": ("q1,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
                           f"{ROW},1,2,3\n", r"column 1 \(q1\) has no unit"),
    "empty": ("", r"line 1: the file is empty"),
    "only comments": ("# kincal measurements: instrument=position\n# nothing\n",
                      r"line 2: no header line"),
    "header only": (f"{HEAD},x_mm,y_mm,z_mm\n", r"line 2: no data rows"),
    "ragged": (f"{HEAD},x_mm,y_mm,z_mm\n{ROW},1,2\n", r"line 3: 8 values, but the header "
               "has 9 columns"),
    "wrong dimension": (f"{HEAD},x_deg,y_mm,z_mm\n{ROW},1,2,3\n",
                        r"column 7 \(x_deg\): unit deg is an angle, expected a length"),
    "unknown unit": (f"{HEAD},x_inch,y_mm,z_mm\n{ROW},1,2,3\n",
                     r"column 7 \(x_inch\): unknown unit 'inch'"),
    "unexpected observation": (f"{HEAD},x_mm,y_mm,z_mm,rz_deg\n{ROW},1,2,3,4\n",
                               r"column 10 \(rz_deg\) looks like a measurement.*--ignore"),
    "duplicate": (f"{HEAD},x_mm,y_mm,z_mm,x_m\n{ROW},1,2,3,4\n",
                  r"column 10 \(x_m\) repeats 'x' \(column 7\)"),
    "case": (f"Q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n{ROW},1,2,3\n",
             r"column 1 \(Q1_deg\) differs from joint 'q1' only in case"),
    "mixed markers": (f"{HEAD},x_mm,y_mm,z_mm,x1_mm,y1_mm,z1_mm\n{ROW},1,2,3,4,5,6\n",
                      r"both x, y, z and numbered marker columns"),
    "negative sigma": (f"{HEAD},x_mm,y_mm,z_mm,sigma_mm\n{ROW},1,2,3,0\n",
                       r"line 3: column sigma_mm: a standard deviation must be positive"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_give_one_line_naming_file_and_line(tmp_path, puma, case):
    text, pattern = BAD[case]
    tag = "" if case in ("empty", "only comments") else \
        "# kincal measurements: instrument=position; name=tracker\n"
    p = _write(tmp_path, tag + text, "bad.csv")
    with pytest.raises(MeasurementFileError, match=pattern) as err:
        read_measurements(p, puma)
    msg = str(err.value)
    assert msg.startswith(f"{p}: line ") and "\n" not in msg


def test_units_option_and_ignore(tmp_path, puma):
    assert parse_units_option("x1=m, y*=mm") == {"x1": "m", "y*": "mm"}
    with pytest.raises(MeasurementFileError, match="unknown unit 'meter'"):
        parse_units_option("x=meter")
    with pytest.raises(MeasurementFileError, match="'x' is not COLUMN=UNIT"):
        parse_units_option("x")
    p = _write(tmp_path, f"{HEAD},x,y,z,x2_mm,run\n{ROW},1,2,3,9,a\n")
    (b,) = read_measurements(p, puma, {"x": "m", "y": "m", "z": "mm"}, ignore=["x2_mm"])
    np.testing.assert_allclose(b.positions[0], [1, 2, 0.003])
    assert b.provenance.table.ignored == ["x2_mm", "run"]
    with pytest.raises(MeasurementFileError, match=r"--ignore 'x9' matches no column"):
        read_measurements(p, puma, {"x": "m", "y": "m", "z": "m"}, ignore=["x2_mm", "x9"])
    with pytest.raises(MeasurementFileError, match=r"--units 'w' matches no column"):
        read_measurements(p, puma, {"w": "m"}, ignore=["x2_mm"])
    q = _write(tmp_path, f"{HEAD},x_mm,y_mm,z_mm\n{ROW},1,2,3\n", "q.csv")
    with pytest.raises(MeasurementFileError, match="says its unit is mm; --units says m"):
        read_measurements(q, puma, {"x_mm": "m"})


def _csv_columns(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_real_motoman_leica_file_reads_as_is():
    path = DATA / "motoman_leica" / "right_arm_grid_6x6x6.csv"
    if not path.is_file():
        pytest.skip("shared data not available")
    robot = load_serial_robot("motoman_right")
    (b,) = read_measurements(path, robot)
    ref = _csv_columns(path)
    assert b.q.shape == (212, 7) and b.provenance.table.ignored == ["pose_id"]
    np.testing.assert_array_equal(b.q[:, 3], ref["U_rad"])
    np.testing.assert_array_equal(b.positions[:, 2], ref["z_m"])
    np.testing.assert_array_equal(np.ravel(b.sigma), ref["sigma_m"])


def test_real_tiago_mocap_file_needs_units_and_reads_with_them():
    path = DATA / "tiago_mocap" / "train_2021-11-30.csv"
    if not path.is_file():
        pytest.skip("shared data not available")
    from kincal.robots.urdf import load_urdf

    robot = load_urdf(path.parent / "tiago_48_schunk.urdf", tip_link="wrist_ft_tool_link")
    with pytest.raises(MeasurementFileError, match=r"line 1: 12 columns have no unit: x1, y1, "
                       r"z1, .* --units 'x\?=m,y\?=m,z\?=m'"):
        read_measurements(path, robot)
    units = parse_units_option("x?=m,y?=m,z?=m")
    (b,) = read_measurements(path, robot, units)
    ref = _csv_columns(path)
    assert b.positions.shape == (37, 4, 3)
    np.testing.assert_array_equal(b.positions[:, 3, 1], ref["y4"])
    # URDF joints are rad / m by the URDF standard, so bare joint names are accepted
    np.testing.assert_array_equal(b.q[:, 0], ref["torso_lift_joint"])
    np.testing.assert_array_equal(b.q[:, 7], ref["arm_7_joint"])
    assert b.provenance.table.ignored == ["shipped_row", "t_start_robot", "t_end_robot",
                                          "marker_std_mm"]
    (one,) = read_measurements(path, robot, units, ignore=["?2", "?3", "?4"])
    assert one.K == 1
    np.testing.assert_array_equal(np.reshape(one.positions, (37, 3))[:, 0], ref["x1"])
