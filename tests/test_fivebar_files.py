"""Five-bar robot files (YAML) and measurement files (CSV): units, validation, round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from kincal.errors import MeasurementFileError, RobotFileError
from kincal.parallel.data import read_fivebar_csv, write_fivebar_csv
from kincal.parallel.files import fivebar_from_dict, load_fivebar, write_fivebar

THESIS = {
    "kind": "fivebar",
    "name": "t",
    "source": "test",
    "units": {"length": "m", "angle": "rad"},
    "links": {"l1": 2.0, "l2": 2.0, "l3": 3.0, "l4": 3.0},
    "bases": {"base1": {"x": 1.0, "y": 0.0}, "base2": {"x": -1.0, "y": 0.0}},
}


def test_library_files_load_with_their_source() -> None:
    thesis = load_fivebar("fivebar_reference")
    assert thesis.param_values[:8].tolist() == [2, 2, 3, 3, 1, 0, -1, 0]
    assert "Pittr" in thesis.source and thesis.assembly == -1 and thesis.working_mode == "-+"
    generic = load_fivebar("fivebar")
    assert generic.source and generic.l3 == 0.25


def test_generic_loader_returns_a_fivebar() -> None:
    from kincal.parallel.fivebar import FiveBar
    from kincal.workflow.robots import load_any_robot

    assert isinstance(load_any_robot("fivebar_reference"), FiveBar)


def test_units_are_converted_at_the_border() -> None:
    data = dict(THESIS, units={"length": "mm", "angle": "deg"},
                links={"l1": 2000, "l2": 2000, "l3": 3000, "l4": 3000},
                bases={"base1": {"x": 1000, "y": 0}, "base2": {"x": -1000, "y": 0}},
                offsets={"offset1": 90.0}, limits={"q1": [0, 90], "q2": [90, 180]})
    robot = fivebar_from_dict(data, "mm.yaml")
    assert robot.l1 == pytest.approx(2.0) and robot.base2_x == pytest.approx(-1.0)
    assert robot.offset1 == pytest.approx(math.pi / 2) and robot.offset2 == 0.0
    assert robot.limits[1] == pytest.approx((math.pi / 2, math.pi))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"links": {"l1": 2, "l2": 2, "l3": -3, "l4": 3}},
         "fivebar.yaml: field 'links.l3' must be a positive number"),
        ({"links": {"l1": 2, "l2": 2, "l3": "x", "l4": 3}}, "field 'links.l3' must be a positive"),
        ({"links": {"l1": 2, "l2": 2, "l4": 3}}, "field 'links.l3' is missing"),
        ({"units": {"length": "inch", "angle": "rad"}}, "field 'units.length' must be one of"),
        ({"units": None}, "field 'units' is missing"),
        ({"assembly": 2}, "field 'assembly' must be +1 or -1"),
        ({"working_mode": "+"}, "field 'working_mode' must be one of"),
        ({"bases": {"base1": {"x": 1.0}, "base2": {"x": -1.0, "y": 0.0}}},
         "field 'bases.base1.y' is missing"),
        ({"colour": "red"}, "field 'colour' is not a five-bar field"),
        ({"limits": {"q1": [1.0, 0.0], "q2": [0.0, 1.0]}}, "field 'limits.q1' must be"),
        ({"offsets": {"offset1": True}}, "field 'offsets.offset1' must be a number"),
    ],
)
def test_bad_fields_are_named_in_one_line(change: dict, message: str) -> None:
    data = {**THESIS, **change}
    data = {k: v for k, v in data.items() if v is not None}
    with pytest.raises(RobotFileError, match=message.replace("+", r"\+")) as err:
        fivebar_from_dict(data, "/some/where/fivebar.yaml")
    assert "\n" not in str(err.value)


def test_robot_file_round_trip(tmp_path) -> None:
    robot = load_fivebar("fivebar_reference").with_params({"l1": 1.86, "offset2": -0.01})
    path = write_fivebar(robot, tmp_path / "r.yaml")
    back = load_fivebar(path)
    assert np.array_equal(back.param_values, robot.param_values)
    assert (back.assembly, back.working_mode, back.limits) == (
        robot.assembly, robot.working_mode, robot.limits)
    assert not list(tmp_path.glob(".*tmp*")), "no temporary file left"
    assert yaml.safe_load(path.read_text())["units"] == {"length": "m", "angle": "rad"}


def test_bad_yaml_and_unknown_robot(tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: fivebar\nlinks: [1, 2\n")
    with pytest.raises(RobotFileError, match="bad.yaml: line 3: not valid YAML"):
        load_fivebar(bad)
    with pytest.raises(RobotFileError, match="no robot file or built-in five-bar"):
        load_fivebar("no_such_robot")


def test_measurement_csv_round_trip_in_any_units(tmp_path) -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, (25, 2))
    x = rng.uniform(-4, 4, (25, 2))
    for au, lu in (("deg", "mm"), ("rad", "m")):
        path = write_fivebar_csv(tmp_path / f"{au}.csv", q, x, au, lu, comment="made\nby test")
        data = read_fivebar_csv(path)
        assert np.allclose(data.q, q, rtol=0, atol=1e-14)
        assert np.allclose(data.x, x, rtol=0, atol=1e-14)
        assert data.lines.tolist() == list(range(4, 29))  # 2 comments + header first


def test_measurement_csv_accepts_beta_names_and_extra_columns(tmp_path) -> None:
    path = tmp_path / "m.csv"
    path.write_text("id,beta2_rad,beta1_rad,y_m,x_m\nA,2.5,0.6,2.0,0.1\n")
    data = read_fivebar_csv(path)
    assert data.q.tolist() == [[0.6, 2.5]] and data.x.tolist() == [[0.1, 2.0]]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("q1_deg,q2_deg,x,y_mm\n1,2,3,4\n", "m.csv: line 1: column 'x' has no unit"),
        ("q1_deg,q2_deg,x_ft,y_mm\n1,2,3,4\n", "column 'x_ft' has unknown unit 'ft'"),
        ("q1_deg,x_mm,y_mm\n1,3,4\n", "line 1: missing column.* q2"),
        ("# c\nq1_deg,q2_deg,x_mm,y_mm\n1,2,3,4\n1,2,abc,4\n",
         "m.csv: line 4: column 'x_mm' value 'abc' is not a finite number"),
        ("q1_deg,q2_deg,x_mm,y_mm\n1,2,3\n", "line 2: 3 fields, the header has 4"),
        ("q1_deg,q2_deg,x_mm,y_mm\n", "header but no measurements"),
        ("", "no header line"),
    ],
)
def test_bad_measurement_files_name_file_and_line(tmp_path, text: str, message: str) -> None:
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(MeasurementFileError, match=message):
        read_fivebar_csv(path)
