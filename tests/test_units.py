"""kincal.units: one unit table, quantities with their unit, one-line errors naming the option."""

from __future__ import annotations

import math

import pytest

from kincal.errors import KincalError
from kincal.units import UNITS, parse_quantities, parse_quantity, units_of


def test_one_table_for_files_robot_files_and_options():
    from kincal.measure import files as mfiles
    from kincal.robots import files as rfiles

    assert mfiles.UNITS is UNITS
    for table, dim in ((rfiles.LENGTH_UNITS, "length"), (rfiles.ANGLE_UNITS, "angle")):
        for u, f in table.items():
            assert UNITS[u] == (dim, f)


@pytest.mark.parametrize("text, dim, si", [
    ("0.01mm", "length", 1e-5), ("1 arcsec", "angle", math.pi / 648000),
    ("2ms", "time", 2e-3), ("0.5deg", "angle", math.radians(0.5)), ("3um", "length", 3e-6),
    ("-1.5e-1m", "length", -0.15), ("1arcmin", "angle", math.radians(1 / 60)),
    ("0.3px", "pixel", 0.3), ("2°", "angle", math.radians(2))])
def test_quantity_to_si(text, dim, si):
    assert parse_quantity(text, dim, "--x") == pytest.approx(si, rel=1e-15)


@pytest.mark.parametrize("text, words", [
    ("0.01", ["--noise", "needs a unit", "m, mm, um, cm", "e.g. 0.01m"]),
    ("1arcsec", ["--noise", "is an angle", "takes a length"]),
    ("1mmm", ["--noise", "unknown unit 'mmm'"]),
    ("abc", ["--noise", "not a number"]),
    ("nan mm", ["--noise"]), ("1e999mm", ["--noise", "not finite"]),
    ("-1mm", ["--noise", "must be > 0"])])
def test_bad_quantity_is_one_line_naming_the_option(text, words):
    with pytest.raises(KincalError) as e:
        parse_quantity(text, "length", "--noise", positive=True)
    msg = str(e.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_several_dimensions_and_bare_default():
    assert parse_quantity("1deg", ("length", "angle"), "--tol") == pytest.approx(math.pi / 180)
    assert parse_quantity("2", "length", "--x", bare="mm") == pytest.approx(2e-3)


def test_lists_with_one_unit_at_the_end_or_one_per_value():
    assert parse_quantities("400,0,300mm", "length", "--position", count=3) == \
        pytest.approx([0.4, 0.0, 0.3])
    q = parse_quantities("10deg,20deg,0.1m", ["angle", "angle", "length"], "--q",
                         bare=["rad", "rad", "m"])
    assert q == pytest.approx([math.radians(10), math.radians(20), 0.1])
    assert parse_quantities("0.1,0.2", ["angle", "length"], "--q", bare=["rad", "m"]) == \
        pytest.approx([0.1, 0.2])
    with pytest.raises(KincalError, match="expected 3 comma-separated values, got 2"):
        parse_quantities("1,2mm", "length", "--position", count=3)
    with pytest.raises(KincalError, match="--position"):
        parse_quantities("1,,2mm", "length", "--position")
    with pytest.raises(KincalError, match="needs a unit"):
        parse_quantities("1,2,3", "length", "--position")


def test_units_of_lists_a_dimension():
    assert units_of("length") == ["m", "mm", "um", "cm"]
    assert "arcsec" in units_of("angle") and "ms" in units_of("time")
